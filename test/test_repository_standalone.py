"""The repository stands alone: no tracked file points outside it.

The model is specified in ``doc/model.md`` and the package's own docs; no
file may send the reader to a specification kept beside the repository or to
numbered tickets of a tracker the reader cannot see. This scans every tracked
text file (``git ls-files``; without git, the source tree minus build and run
outputs) and names each offending ``file:line``.

The patterns are assembled from pieces so that this file never contains the
strings it looks for.
"""
import re
import shutil
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

_DOT_MD = '.' + 'md'
#: name -> compiled pattern of a reference that points outside the repository.
FORBIDDEN = {
    # the specification directory kept beside the checkout
    'sibling spec directory': re.compile(re.escape('..' + '/' + 'shared')
                                         + '|' + r'\bshared' + re.escape('/')),
    # the specification files by name (case-sensitive: doc/model.md is ours)
    'external spec file': re.compile(r'(?<![A-Za-z0-9_])(?:' + 'MOD' + 'EL' + '|' + 'FE' + 'S'
                                     + ')' + re.escape(_DOT_MD)),
    # numbered tracker tickets (the spellings: test_patterns_flag_the_references_they_are_for)
    'tracker issue number': re.compile(r'\b' + 'iss' + r'ues?' + r'[ \t]*[-#]?[ \t]*#?\d',
                                       re.IGNORECASE),
}

#: (path, pattern name) -> why that file may keep the reference.
ALLOWED: dict[tuple[str, str], str] = {}

#: Directories never scanned when there is no git index to list the files.
SKIP_DIRS = {'.git', '.venv', 'build', 'install', 'log', 'runs', '__pycache__',
             '.pytest_cache', '.hypothesis'}


def tracked_files() -> list[Path]:
    """Repository-relative paths of the files to scan."""
    git = shutil.which('git')
    if git and (REPO / '.git').exists():
        out = subprocess.run([git, '-C', str(REPO), 'ls-files', '-z'], check=True,
                             capture_output=True).stdout
        return [Path(p) for p in out.decode('utf-8').split('\0') if p]
    files = []
    for path in REPO.rglob('*'):
        rel = path.relative_to(REPO)
        if any(part in SKIP_DIRS or part.endswith('.egg-info') for part in rel.parts):
            continue
        if path.is_file():
            files.append(rel)
    return files


def read_text(path: Path) -> str | None:
    """The file's text, or None for a binary file (a NUL byte or not UTF-8)."""
    data = path.read_bytes()
    if b'\0' in data:
        return None
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError:
        return None


def find_references(rel: Path, text: str) -> list[str]:
    """``file:line: kind: line text`` for each forbidden reference in ``text``."""
    found = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        for kind, pattern in FORBIDDEN.items():
            if pattern.search(line) and (rel.as_posix(), kind) not in ALLOWED:
                found.append(f'{rel.as_posix()}:{lineno}: {kind}: {line.strip()}')
    return found


def test_no_tracked_file_points_outside_the_repository():
    offences = []
    scanned = 0
    for rel in tracked_files():
        path = REPO / rel
        if not path.is_file():   # listed by git but deleted in the working tree
            continue
        text = read_text(path)
        if text is None:
            continue
        scanned += 1
        offences.extend(find_references(rel, text))
    assert scanned > 10, f'only {scanned} text files found under {REPO}'
    assert not offences, ('references outside the repository (write the content here, '
                          'e.g. "see doc/model.md"):\n' + '\n'.join(offences))


def test_every_allowed_exception_is_still_needed():
    """An exception whose reference is gone must be removed from ALLOWED."""
    stale = []
    for (name, kind) in ALLOWED:
        path = REPO / name
        text = read_text(path) if path.is_file() else None
        if text is None or not FORBIDDEN[kind].search(text):
            stale.append(f'{name} ({kind})')
    assert not stale, f'ALLOWED entries no longer needed: {", ".join(stale)}'


def _flags(line: str) -> list[str]:
    return [kind for kind, pattern in FORBIDDEN.items() if pattern.search(line)]


def test_patterns_flag_the_references_they_are_for():
    spec_dir, spec = '..' + '/' + 'shared', 'MOD' + 'EL' + _DOT_MD
    assert _flags(f'see [{spec}]({spec_dir}/{spec})') == ['sibling spec directory',
                                                          'external spec file']
    assert _flags('FE' + 'S' + _DOT_MD + ' section 2') == ['external spec file']
    for text in ('iss' + 'ue 5', '(' + 'iss' + 'ue 6)', 'iss' + 'ue-5 targets',
                 'Iss' + 'ue 5, item 6', 'iss' + 'ue #12', 'iss' + 'ues 2 and 3'):
        assert _flags(text) == ['tracker issue number'], text


def test_patterns_pass_ordinary_words():
    for text in ('in a shared `/**` section', 'a shared 2-core machine',
                 'see doc/model.md section 3', 'a known issue with DDS',
                 'the issue is the latency', 'tissue 5 mm', 'share/hill_muscle_ros/config'):
        assert _flags(text) == [], text

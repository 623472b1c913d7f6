"""Every relative link of README.md and doc/*.md resolves.

A link ``[text](path)`` or ``![alt](path)`` that is not a URL must name a file
(or directory) of the repository, relative to the page; a ``#anchor``, on the
same page or on another Markdown page of the repository, must be one of that
page's headings as GitHub turns it into an anchor. Code blocks and inline
code are skipped.
"""
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / 'README.md', *sorted((REPO / 'doc').glob('*.md'))]
#: ``[text](target)`` and ``![alt](target)``; the target ends at a space or ``)``.
LINK = re.compile(r'!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^)\s]+)(?:\s+"[^"]*")?\)')
FENCE = re.compile(r'^\s*(```|~~~)')
INLINE_CODE = re.compile(r'`[^`]*`')


def _prose_lines(text: str):
    """(line number, line without inline code) outside fenced code blocks."""
    fenced = False
    for lineno, line in enumerate(text.splitlines(), start=1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield lineno, INLINE_CODE.sub('', line)


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped,
    spaces to hyphens (``9.2 A seated knee: `config/knee.yaml` `` ->
    ``92-a-seated-knee-configkneeyaml``)."""
    text = heading.strip().lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def anchors(page: Path) -> set[str]:
    """Every heading anchor of a Markdown page (repeats get -1, -2, ...)."""
    seen: dict[str, int] = {}
    found = set()
    fenced = False
    for line in page.read_text(encoding='utf-8').splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        match = re.match(r'^#{1,6}\s+(.*?)\s*#*\s*$', line)
        if fenced or not match:
            continue
        base = github_anchor(match.group(1))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f'{base}-{count}')
    return found


def broken_links(page: Path) -> list[str]:
    problems = []
    for lineno, line in _prose_lines(page.read_text(encoding='utf-8')):
        for target in LINK.findall(line):
            if re.match(r'^[a-z][a-z0-9+.-]*:', target):   # http:, https:, mailto:
                continue
            path_part, _, anchor = target.partition('#')
            where = f'{page.relative_to(REPO)}:{lineno}: {target}'
            dest = (page.parent / path_part).resolve() if path_part else page
            if not dest.exists():
                problems.append(f'{where}: no such file')
                continue
            if anchor and dest.suffix == '.md' and anchor not in anchors(dest):
                problems.append(f'{where}: no heading with anchor #{anchor}')
    return problems


@pytest.mark.parametrize('page', PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_resolves(page):
    assert not broken_links(page), '\n'.join(broken_links(page))


def test_the_anchor_rule_matches_github():
    assert github_anchor('9.2 A seated knee: `config/knee.yaml`') == (
        '92-a-seated-knee-configkneeyaml')
    assert github_anchor("The simulator's main topics and parameters") == (
        'the-simulators-main-topics-and-parameters')
    assert github_anchor('`make demo`') == 'make-demo'
    assert github_anchor('Fitting parameters to a recorded bag: `hill-muscle fit`') == (
        'fitting-parameters-to-a-recorded-bag-hill-muscle-fit')


def test_the_checker_sees_a_broken_link(tmp_path):
    page = tmp_path / 'page.md'
    page.write_text('# Title\n\n[ok](#title) [bad](#nope) [gone](missing.md)\n'
                    '```\n[in code](missing_too.md)\n```\n', encoding='utf-8')
    problems = broken_links_in(page, tmp_path)
    assert len(problems) == 2 and 'nope' in problems[0] and 'missing.md' in problems[1]


def broken_links_in(page: Path, root: Path) -> list[str]:
    """broken_links for a page outside the repository (the checker's own test)."""
    global REPO
    saved, REPO = REPO, root
    try:
        return broken_links(page)
    finally:
        REPO = saved

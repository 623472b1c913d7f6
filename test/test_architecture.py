"""The package's architecture, read off its source: no import cycle, layers that
import downward only, and modules of at most 800 lines.

Every module of hill_muscle_ros is parsed with :mod:`ast` (nothing is imported)
and each ``import`` statement counts wherever it stands: at the top, inside a
function (a lazy import), under ``if TYPE_CHECKING:`` or in a ``try``. A
relative import is resolved to the module it names: ``from . import x`` is an
edge to the submodule ``x`` where there is one (else to the package, for a
name defined there), ``from .x import y`` an edge to ``x`` (or to its submodule
``x.y``). Importing a submodule does not count as importing its parent
packages, whose ``__init__`` runs first: a package that re-exports its
submodules would otherwise be on a cycle with each of them. A module named in
a string and loaded with :func:`importlib.import_module` is no edge either:
``hill-muscle simulator`` starts a node that way, by its name, as
``ros2 run`` does.

The rules:

- **cycle**: no import cycle among the package's modules (each cycle's
  members are named);
- **layers**: the model (``hill_muscle_ros.model``) imports nothing of the
  nodes, the tools, the recording, the controllers, the gym environments, nor
  rclpy; the tools (``hill_muscle_ros.tools``) import no node module; no module
  of ``hill_muscle_ros.nodes`` imports a node other than itself (the nodes are
  the console scripts of setup.py; what nodes share lives in modules that are
  no node, such as ``nodes._parameters``);
- **size**: every module has at most :data:`MAX_LINES` lines.

:data:`KNOWN_EXCEPTIONS` names the modules that break a rule today while
their owners split them. Each exception excuses its module from one rule only,
and an exception that is no longer needed fails
:func:`test_every_known_exception_is_still_needed`: the list can only shrink.
"""
from __future__ import annotations

import ast
from pathlib import Path
from typing import Iterable, Mapping

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE = 'hill_muscle_ros'
#: Most lines a module may have.
MAX_LINES = 800

#: (rule, module) pairs excused today, each from that rule only; the rules are
#: ``cycle``, ``layers`` and ``size`` (see the module docstring). Remove an
#: entry once its module keeps the rule: the test below fails until you do.
KNOWN_EXCEPTIONS = frozenset({
})

#: Packages the model must not import (of this package, and rclpy).
MODEL_FORBIDDEN = tuple(f'{PACKAGE}.{name}' for name in
                        ('nodes', 'tools', 'recording', 'control', 'gym')) + ('rclpy',)


# --------------------------------------------------------------------------- reading

def module_files(root: Path, package: str) -> dict[str, Path]:
    """Every module of ``package`` under ``root``, by dotted name (a package by
    the name of its ``__init__.py``)."""
    modules = {}
    for path in sorted((root / package).rglob('*.py')):
        if '__pycache__' in path.parts:
            continue
        parts = path.relative_to(root).with_suffix('').parts
        if parts[-1] == '__init__':
            parts = parts[:-1]
        modules['.'.join(parts)] = path
    return modules


def _is_package(path: Path) -> bool:
    return path.name == '__init__.py'


def _known(name: str, modules: Iterable[str]) -> str | None:
    """The longest prefix of dotted ``name`` that is one of ``modules``, if any."""
    parts = name.split('.')
    for end in range(len(parts), 0, -1):
        prefix = '.'.join(parts[:end])
        if prefix in modules:
            return prefix
    return None


def imported_names(module: str, path: Path, tree: ast.AST) -> list[str]:
    """The absolute dotted names ``tree`` imports, wherever the import stands:
    ``import a.b`` gives ``a.b``; ``from a import b, c`` gives ``a.b`` and
    ``a.c`` (the caller decides whether each is a module or a name in ``a``);
    relative imports are resolved against ``module``."""
    package = module if _is_package(path) else module.rpartition('.')[0]
    names = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = package.split('.')
                base_parts = parts[:len(parts) - (node.level - 1)]
                if node.level - 1 > len(parts) - 1:
                    raise ValueError(f'{path}:{node.lineno}: relative import beyond the '
                                     f'top-level package')
                base = '.'.join(base_parts + ([node.module] if node.module else []))
            else:
                base = node.module
            names += [f'{base}.{alias.name}' for alias in node.names if alias.name != '*']
            if any(alias.name == '*' for alias in node.names):
                names.append(base)
    return names


def import_graph(root: Path = REPO, package: str = PACKAGE
                 ) -> tuple[dict[str, set[str]], dict[str, set[str]], dict[str, Path]]:
    """The package's import graph.

    :return: module -> the package's modules it imports; module -> every
        absolute name it imports (external ones too, e.g. ``rclpy.node.Node``);
        module -> its file
    """
    modules = module_files(root, package)
    graph, names = {}, {}
    for module, path in modules.items():
        tree = ast.parse(path.read_text(encoding='utf-8'), str(path))
        names[module] = set(imported_names(module, path, tree))
        graph[module] = {target for target in (_known(n, modules) for n in names[module])
                         if target is not None and target != module}
    return graph, names, modules


def find_cycles(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: its strongly connected components of two or
    more modules, each sorted, the components in sorted order (Tarjan's algorithm,
    without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, edges = work[-1]
            for target in edges:
                if target not in index:
                    index[target] = low[target] = len(index)
                    stack.append(target)
                    on_stack.add(target)
                    work.append((target, iter(sorted(graph.get(target, ())))))
                    break
                if target in on_stack:
                    low[node] = min(low[node], index[target])
            else:
                work.pop()
                if work:
                    parent = work[-1][0]
                    low[parent] = min(low[parent], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        cycles.append(sorted(component))
    return sorted(cycles)


def node_modules(root: Path = REPO, package: str = PACKAGE) -> set[str]:
    """The node modules: those that setup.py's console scripts run from
    ``<package>.nodes``."""
    tree = ast.parse((root / 'setup.py').read_text(encoding='utf-8'))
    scripts = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if isinstance(key, ast.Constant) and key.value == 'console_scripts':
                    scripts += [ast.literal_eval(v) for v in value.elts]
    targets = {script.partition('=')[2].strip().partition(':')[0] for script in scripts}
    return {t for t in targets if t.startswith(f'{package}.nodes.')}


# --------------------------------------------------------------------------- the rules

def _within(name: str, prefix: str) -> bool:
    return name == prefix or name.startswith(prefix + '.')


def cycle_offences(graph: Mapping[str, set[str]]) -> dict[str, str]:
    """module -> the cycle it is on, for every module on a cycle."""
    offences = {}
    for cycle in find_cycles(graph):
        for module in cycle:
            offences[module] = 'on the import cycle ' + ' <-> '.join(cycle)
    return offences


def layer_offences(names: Mapping[str, set[str]], nodes: set[str],
                   package: str = PACKAGE) -> dict[str, str]:
    """module -> the imports that go against the layers."""
    offences = {}
    for module, imported in names.items():
        if _within(module, f'{package}.model'):
            bad = sorted(n for n in imported if any(_within(n, f) for f in MODEL_FORBIDDEN))
            what = 'the model imports'
        elif _within(module, f'{package}.tools'):
            bad = sorted(n for n in imported if _within(n, f'{package}.nodes'))
            what = 'a tool imports node code'
        elif _within(module, f'{package}.nodes'):
            bad = sorted(n for n in imported
                         if any(_within(n, node) for node in nodes - {module}))
            what = 'imports another node'
        else:
            continue
        if bad:
            offences[module] = f'{what}: {", ".join(bad)}'
    return offences


def size_offences(modules: Mapping[str, Path]) -> dict[str, str]:
    """module -> its length, for every module over MAX_LINES lines."""
    offences = {}
    for module, path in modules.items():
        lines = len(path.read_text(encoding='utf-8').splitlines())
        if lines > MAX_LINES:
            offences[module] = f'{path.relative_to(REPO)} has {lines} lines (at most {MAX_LINES})'
    return offences


@pytest.fixture(scope='module')
def offences() -> dict[str, dict[str, str]]:
    """rule -> module -> what it breaks, for the package as it is."""
    graph, names, modules = import_graph()
    return {'cycle': cycle_offences(graph),
            'layers': layer_offences(names, node_modules()),
            'size': size_offences(modules)}


def _unexcused(rule: str, found: Mapping[str, str]) -> list[str]:
    return [f'{module}: {why}' for module, why in sorted(found.items())
            if (rule, module) not in KNOWN_EXCEPTIONS]


def test_no_import_cycle(offences):
    cycles = sorted({why for module, why in offences['cycle'].items()
                     if ('cycle', module) not in KNOWN_EXCEPTIONS})
    assert not cycles, 'import cycles:\n' + '\n'.join(cycles)


def test_layers_import_downward_only(offences):
    bad = _unexcused('layers', offences['layers'])
    assert not bad, 'imports against the layers:\n' + '\n'.join(bad)


def test_every_module_is_at_most_800_lines(offences):
    bad = _unexcused('size', offences['size'])
    assert not bad, 'modules too long:\n' + '\n'.join(bad)


def test_every_known_exception_is_still_needed(offences):
    stale = sorted(f'{rule}: {module}' for rule, module in KNOWN_EXCEPTIONS
                   if module not in offences[rule])
    assert not stale, ('known exceptions that no module needs any more (remove them from '
                       'KNOWN_EXCEPTIONS):\n' + '\n'.join(stale))


def test_every_known_exception_names_a_rule():
    assert {rule for rule, _ in KNOWN_EXCEPTIONS} <= {'cycle', 'layers', 'size'}


# --------------------------------------------------------------------------- the checker itself

def test_find_cycles_names_the_members_of_each_cycle():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a', 'd'}, 'd': set(), 'e': {'f'}, 'f': {'e'},
             'g': {'a'}}
    assert find_cycles(graph) == [['a', 'b', 'c'], ['e', 'f']]
    assert find_cycles({'a': {'b'}, 'b': {'c'}, 'c': set()}) == []


def test_a_synthetic_cycle_fails_the_rule():
    found = cycle_offences({'pkg.x': {'pkg.y'}, 'pkg.y': {'pkg.x'}, 'pkg.z': {'pkg.x'}})
    assert found == {'pkg.x': 'on the import cycle pkg.x <-> pkg.y',
                     'pkg.y': 'on the import cycle pkg.x <-> pkg.y'}
    assert _unexcused('cycle', found)


def _write(root: Path, files: Mapping[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding='utf-8')


def test_imports_at_any_depth_resolve_to_the_modules_they_name(tmp_path):
    _write(tmp_path, {
        'pkg/__init__.py': '',
        'pkg/a.py': 'from . import b, CONSTANT\nfrom .sub import c\n',
        'pkg/b.py': ('from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n'
                     '    from .sub.c import Thing\n'),
        'pkg/sub/__init__.py': 'from .c import Thing\nfrom .. import b\n',
        'pkg/sub/c.py': ('def late():\n    from ..a import x\n    import pkg.b\n'
                         '    from rclpy.node import Node\n'),
    })
    graph, names, _ = import_graph(tmp_path, 'pkg')
    assert graph == {
        'pkg': set(),
        'pkg.a': {'pkg.b', 'pkg', 'pkg.sub.c'},   # CONSTANT is a name in pkg
        'pkg.b': {'pkg.sub.c'},
        'pkg.sub': {'pkg.sub.c', 'pkg.b'},
        'pkg.sub.c': {'pkg.a', 'pkg.b'},
    }
    assert 'rclpy.node.Node' in names['pkg.sub.c']
    assert find_cycles(graph) == [['pkg.a', 'pkg.b', 'pkg.sub.c']]


def test_the_package_graph_is_read(offences):
    """The rules above are not checked on an empty graph: the graph has the
    package's modules and the edges everyone knows of."""
    graph, names, modules = import_graph()
    assert len(modules) > 50
    assert f'{PACKAGE}.tools.common' in graph[f'{PACKAGE}.tools.cli']
    assert f'{PACKAGE}.tools.cli' not in set().union(*graph.values())
    assert node_modules() >= {f'{PACKAGE}.nodes.simulator', f'{PACKAGE}.nodes.limb'}

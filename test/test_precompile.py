"""``hill-muscle compile``: every compiled kernel set of the model, built ahead of use."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

from hill_muscle_ros.model import engine, precompile
from hill_muscle_ros.tools import cli

MODEL = Path(precompile.__file__).parent
#: [s] bound on the command: it loads from the cache here (the suite compiled
#: the kernels before this module), a clean clone's compile takes about 25 s.
COMPILE_TIMEOUT_S = 300.0


def _builders_in_the_model() -> set[tuple[str, str]]:
    """(module, function) of every top-level ``compiled*`` function of the model
    and its subpackages (the module dotted from the model, ``limb.kernels``):
    the functions that build a kernel set with numba."""
    found = set()
    for path in MODEL.rglob('*.py'):
        module = '.'.join(path.relative_to(MODEL).with_suffix('').parts)
        for node in ast.parse(path.read_text(encoding='utf-8')).body:
            if isinstance(node, ast.FunctionDef) and node.name.startswith('compiled'):
                found.add((module, node.name))
    return found


def test_the_kernel_sets_are_every_builder_of_the_model():
    assert set(precompile.KERNEL_SETS.values()) == _builders_in_the_model()


def test_the_groups_hold_every_kernel_set_once():
    names = [name for group in precompile.KERNEL_GROUPS for name in group]
    assert sorted(names) == sorted(precompile.KERNEL_SETS)


def test_the_sets_that_call_the_fes_muscle_build_after_it_in_its_process():
    # The limb and the FES batch call the FES muscle's compiled functions: in
    # another process they would compile it a second time.
    [group] = [g for g in precompile.KERNEL_GROUPS if 'muscle' in g]
    assert group.index('muscle') < group.index('limb')
    assert group.index('muscle') < group.index('batch')


def test_an_unknown_kernel_set_is_a_value_error_naming_it():
    with pytest.raises(ValueError, match=r"`name` must be one of .*, got 'knee'"):
        precompile.compile_kernel_set('knee')


def test_without_numba_the_command_says_so_and_compiles_nothing(monkeypatch, capsys):
    monkeypatch.setattr(engine, 'numba_available', lambda: False)
    assert cli.main(['compile']) == cli.EXIT_USAGE
    assert 'numba is not installed' in capsys.readouterr().err


@pytest.mark.skipif(not engine.numba_available(), reason='numba is not installed')
def test_the_command_builds_every_kernel_set_and_a_second_run_only_loads():
    runs = [subprocess.run([sys.executable, '-m', 'hill_muscle_ros.tools.cli', 'compile'],
                           capture_output=True, text=True, timeout=COMPILE_TIMEOUT_S, check=True)
            for _ in range(2)]
    for run in runs:
        lines = run.stdout.splitlines()
        assert sorted(line.split(':')[0] for line in lines[:-1]) == sorted(precompile.KERNEL_SETS)
        assert lines[-1].startswith("every kernel in numba's cache")
    # However the first found the cache, the second finds everything in it.
    assert all('loaded from the cache' in line for line in runs[1].stdout.splitlines()[:-1])

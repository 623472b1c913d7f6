"""A clean install works: every runtime import is declared.

Run by ``make check-install``, not ``make test``: the two venvs' pip installs
are a quarter of the offline tests' CPU, and what they check is the set-up, not
the package's behaviour.

A fresh virtual environment gets only what a user installs: the ROS 2 wheels
of ``requirements-ros.txt`` and ``pip install .`` (which brings
``install_requires``), none of the development pins. Then every module of the
package must import there, the installed requirements must be consistent and
the installed command must find the data files it ships. A module that
imports something neither file declares fails here, naming the module.

pip uses this machine's configuration (its cache and local indexes, as
``make`` does), so after the first run the set-up mostly reuses cached wheels.
The source is copied first: pip builds a ``setup.py`` project in its source
directory, and the checkout must stay untouched. ``--no-compile``: byte-compiling
the ROS wheels' files is a large part of the install time, and the imports
compile what they need anyway. The venv is made ``--without-pip`` and this
interpreter's pip installs into it (``pip --python``): seeding pip (and, on
Python 3.11, setuptools) took 4.7 s of the set-up, and a venv without them is
stricter still, as setuptools is there only because ``install_requires``
names it.
"""
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.install]

REPO = Path(__file__).resolve().parents[1]
#: [s] generous bound on venv creation plus both installs; a warm pip cache
#: needs far less, a cold one downloads the ROS wheels.
INSTALL_TIMEOUT_S = 900.0
#: [s] bound on one command run in the new environment.
RUN_TIMEOUT_S = 120.0
#: What the copy of the source leaves out: VCS data, environments, build and
#: run outputs (the same as .gitignore, plus .git).
COPY_IGNORE = shutil.ignore_patterns('.git', '.venv', 'build', 'install', 'log', 'runs',
                                     '__pycache__', '*.egg-info', '.pytest_cache',
                                     '.hypothesis')
#: Modules that need an optional extra of setup.py (``pip install .`` leaves
#: it out): they must fail with an ImportError that names the extra.
OPTIONAL = {'hill_muscle_ros.gym': 'gym'}
#: Imports every module of the installed package and prints those that fail.
IMPORT_ALL = '''
import importlib, pkgutil, sys
import hill_muscle_ros
print('package at', hill_muscle_ros.__file__)
optional = %r
names = ['hill_muscle_ros'] + [m.name for m in pkgutil.walk_packages(
    hill_muscle_ros.__path__, 'hill_muscle_ros.', onerror=lambda name: None)]
names += [n for n in optional if n not in names]
failed = []
for name in names:
    extra = next((e for prefix, e in optional.items()
                  if name == prefix or name.startswith(prefix + '.')), None)
    try:
        importlib.import_module(name)
    except ImportError as err:
        if extra is None or f'hill_muscle_ros[{extra}]' not in str(err):
            failed.append(f'{name}: ImportError: {err}')
    except Exception as err:  # report every module, not just the first
        failed.append(f'{name}: {type(err).__name__}: {err}')
print(len(names), 'modules imported,', len(failed), 'failed')
print('\\n'.join(failed))
sys.exit(1 if failed else 0)
''' % (OPTIONAL,)


def _clean_env() -> dict:
    """The environment of a user's shell: nothing that points at this checkout,
    its venv or a ROS install; pip's own configuration is kept."""
    env = dict(os.environ)
    for name in ('PYTHONPATH', 'PYTHONHOME', 'VIRTUAL_ENV', 'AMENT_PREFIX_PATH',
                 'COLCON_PREFIX_PATH', 'COVERAGE_PROCESS_START'):
        env.pop(name, None)
    return env


def _run(args, cwd: Path, timeout_s: float, **env) -> subprocess.CompletedProcess:
    """``args`` in a user's environment (:func:`_clean_env`) with ``env`` added."""
    return subprocess.run([str(a) for a in args], cwd=cwd, env={**_clean_env(), **env},
                          text=True, capture_output=True, timeout=timeout_s)


def _pip(venv: Path) -> list:
    """This interpreter's pip, acting on the environment ``venv``."""
    return [sys.executable, '-m', 'pip', '--python', venv / 'bin' / 'python']


@pytest.fixture(scope='module')
def clean_venv(tmp_path_factory):
    """[Path] a new venv with the ROS wheels and this package installed."""
    root = tmp_path_factory.mktemp('install_clean')
    source = root / 'src'
    shutil.copytree(REPO, source, ignore=COPY_IGNORE)
    venv = root / 'venv'
    python = shutil.which('python3.11') or sys.executable
    start = time.monotonic()
    made = _run([python, '-m', 'venv', '--without-pip', venv], root, RUN_TIMEOUT_S)
    assert made.returncode == 0, f'python -m venv failed:\n{made.stderr}'
    installed = _run([*_pip(venv), 'install', '--disable-pip-version-check', '-q',
                      '--no-compile', '-r', source / 'requirements-ros.txt', source],
                     root, INSTALL_TIMEOUT_S)
    elapsed_s = time.monotonic() - start
    print(f'\nclean venv + requirements-ros.txt + pip install .: {elapsed_s:.1f} s')
    assert installed.returncode == 0, (f'pip install failed after {elapsed_s:.0f} s:\n'
                                       f'{installed.stdout[-3000:]}\n{installed.stderr[-3000:]}')
    return venv


def test_every_module_imports_in_a_clean_install(clean_venv, tmp_path):
    # Run outside the checkout so that only the installed package can be imported.
    proc = _run([clean_venv / 'bin' / 'python', '-c', IMPORT_ALL], tmp_path, RUN_TIMEOUT_S)
    assert proc.returncode == 0, f'modules that do not import:\n{proc.stdout}\n{proc.stderr}'
    assert str(clean_venv) in proc.stdout, f'imported from elsewhere:\n{proc.stdout}'


def test_installed_requirements_are_consistent(clean_venv, tmp_path):
    proc = _run([*_pip(clean_venv), 'check'], tmp_path, RUN_TIMEOUT_S)
    assert proc.returncode == 0, f'pip check:\n{proc.stdout}\n{proc.stderr}'


def test_installed_command_finds_its_shipped_protocol_and_parameters(clean_venv, tmp_path):
    """``--protocol II`` and the default parameters file are data files of the
    package: they must be found without a source tree or a ROS environment."""
    # On the plain-Python build: the claim is the data files, and the new
    # venv's numba cache is empty, so the compiled build compiled the muscle's
    # kernels first (45 CPU-s, 80 s of the module's wall time beside the ROS
    # tests; the Python build runs Protocol II in under a second). Compiling
    # and loading the kernels is test_precompile's claim.
    proc = _run([clean_venv / 'bin' / 'hill-muscle', 'simulate', '--protocol', 'II'],
                tmp_path, RUN_TIMEOUT_S, HILL_MUSCLE_ENGINE='python')
    assert proc.returncode == 0, f'hill-muscle simulate failed:\n{proc.stderr}'
    assert proc.stdout.startswith('Protocol II: units=multi, length=initial, 1000 Hz'), \
        proc.stdout


#: The Python 3.11 a plain user's shell finds first on Debian: its venv seeds
#: an old pip (23.0.1), whose legacy editable install honours setup.cfg's
#: ament_python ``script_dir`` and put the console scripts outside ``bin/``.
SYSTEM_PYTHON = Path('/usr/bin/python3.11')


@pytest.mark.skipif(not SYSTEM_PYTHON.exists(), reason=f'no {SYSTEM_PYTHON} on this machine')
def test_make_puts_the_commands_in_the_venvs_bin_on_the_systems_python(tmp_path):
    """``make``'s editable install, from the system's Python 3.11 and its own
    old pip (the Makefile brings pip to its pinned version first)."""
    source = tmp_path / 'src'
    shutil.copytree(REPO, source, ignore=COPY_IGNORE)
    venv = tmp_path / 'venv'
    proc = _run(['make', '-C', source, 'editable', f'VENV={venv}', f'PYTHON={SYSTEM_PYTHON}'],
                tmp_path, INSTALL_TIMEOUT_S)
    assert proc.returncode == 0, f'make editable failed:\n{proc.stdout}\n{proc.stderr}'
    for command in ('hill-muscle', 'simulator', 'protocol_player', 'recorder'):
        script = venv / 'bin' / command
        assert script.is_file(), (f'{script} is missing: ' + ', '.join(
            str(p.relative_to(venv)) for p in venv.rglob(command)))
        assert script.read_text().startswith(f'#!{venv}/bin/python'), script.read_text()[:200]

"""The package builds with colcon as an ament_python package and runs from the install.

``ros2 run hill_muscle_ros simulator`` looks the package up with
``ament_index_python.get_package_prefix`` and runs
``<prefix>/lib/hill_muscle_ros/simulator``; this test does the same by hand.
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from std_msgs.msg import Float64

from conftest import REPO
from ros_helpers import VENV_BIN, Probe, ProcessGroup, node_command, ros_env

pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.install]

PACKAGE = 'hill_muscle_ros'
#: What an ament_python source package consists of (no venv, git or build trees).
SOURCE_ITEMS = ('package.xml', 'setup.py', 'setup.cfg', 'resource', 'config', PACKAGE)
#: [s] a cold colcon build on a loaded 2-core machine
BUILD_TIMEOUT_S = 300.0
EXECUTABLES = ('simulator', 'protocol_player', 'limb_simulator', 'joint_controller')


@pytest.fixture(scope='module')
def install(tmp_path_factory):
    """A colcon workspace with a copy of the package, built; its install prefix."""
    ws = tmp_path_factory.mktemp('colcon_ws')
    src = ws / 'src' / PACKAGE
    src.mkdir(parents=True)
    # A copy, not a symlink: the build must not write into the shared checkout.
    for item in SOURCE_ITEMS:
        if (REPO / item).is_dir():
            shutil.copytree(REPO / item, src / item,
                            ignore=shutil.ignore_patterns('__pycache__', '*.egg-info'))
        else:
            shutil.copy2(REPO / item, src / item)
    env = ros_env(PATH=f'{VENV_BIN}{os.pathsep}{os.environ.get("PATH", "")}')
    result = subprocess.run(
        [str(VENV_BIN / 'colcon'), 'build', '--base-paths', 'src', '--build-base', 'build',
         '--install-base', 'install', '--event-handlers', 'console_direct-'],
        cwd=ws, env=env, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return ws / 'install' / PACKAGE


def _install_env(prefix: Path) -> dict[str, str]:
    """What sourcing install/setup.bash sets for this package."""
    site = prefix / 'lib' / f'python{sys.version_info.major}.{sys.version_info.minor}' \
        / 'site-packages'
    return ros_env(AMENT_PREFIX_PATH=str(prefix), PYTHONPATH=str(site))


def _run_python(code: str, install: Path) -> str:
    """Run ``python -c code`` in the install's environment; its stdout.

    Not from the checkout: ``python -c`` puts the working directory first
    on sys.path, which would import the source tree instead.
    """
    return subprocess.run([sys.executable, '-c', code], env=_install_env(install),
                          cwd=install, capture_output=True, text=True, timeout=60,
                          check=True).stdout


@pytest.mark.parametrize('name', EXECUTABLES)
def test_executables_are_installed(install, name):
    path = install / 'lib' / PACKAGE / name
    assert path.is_file() and os.access(path, os.X_OK)


def test_package_is_in_the_ament_index(install):
    assert (install / 'share' / 'ament_index' / 'resource_index' / 'packages' / PACKAGE).is_file()


def test_package_xml_and_config_are_installed(install):
    share = install / 'share' / PACKAGE
    assert (share / 'package.xml').is_file()
    assert (share / 'config' / 'muscle.yaml').is_file()
    assert {p.name for p in (share / 'config' / 'protocols').glob('*.yaml')} >= {
        'protocol_I.yaml', 'protocol_II.yaml'}


def test_ament_index_finds_the_install(install):
    code = ('from ament_index_python.packages import get_package_prefix; '
            f'print(get_package_prefix({PACKAGE!r}))')
    out = _run_python(code, install)
    assert Path(out.strip()) == install


def test_installed_simulator_publishes_force(install, tmp_path):
    params = install / 'share' / PACKAGE / 'config' / 'muscle.yaml'
    with ProcessGroup(tmp_path) as procs, Probe() as probe:
        force = probe.record('/colcon/force', Float64)
        # The installed copy's kernels are not in numba's cache (it keys on the
        # file's path): its compiled build would compile first, 20-45 s of CPU
        # that `hill-muscle compile` after an install saves a user. The claim
        # here is the install's, so the node takes the plain-Python build of
        # the same code, loaded at once.
        env = {**_install_env(install), 'HILL_MUSCLE_ENGINE': 'python'}
        sim = procs.start('installed_sim', node_command(
            'simulator', ns='/colcon', params_files=[params], params={'rate_hz': 100.0},
            bin_dir=install / 'lib' / PACKAGE), env=env)
        probe.wait_for_messages(force, procs=[sim])
    assert force.messages[0].data == 0.0


def test_install_env_runs_the_installed_code(install):
    code = f'import {PACKAGE}; print({PACKAGE}.__file__)'
    out = _run_python(code, install)
    assert Path(out.strip()).is_relative_to(install)

"""Where the package's installed data lives (protocols, parameter files)."""
from __future__ import annotations

import sysconfig
from pathlib import Path

PACKAGE = 'hill_muscle_ros'
#: Protocol names that ship with the package and the files that hold them.
BUILTIN_PROTOCOLS = {'I': 'protocol_I.yaml', 'II': 'protocol_II.yaml'}


def config_dir() -> Path:
    """The package's ``config`` directory.

    Under a colcon install it is ``share/hill_muscle_ros/config`` found through
    the ament index; in a source checkout (editable install) it is the
    repository's ``config/``; after a plain ``pip install .`` (no ament
    environment) it is ``<prefix>/share/hill_muscle_ros/config``, where pip
    puts the package's data files.
    """
    try:
        from ament_index_python.packages import get_package_share_directory
        share = Path(get_package_share_directory(PACKAGE)) / 'config'
        if share.is_dir():
            return share
    except (ImportError, LookupError, OSError, ValueError):
        pass  # not on AMENT_PREFIX_PATH: try the source tree, then pip's data prefix
    source = Path(__file__).resolve().parents[1] / 'config'
    if (source / 'muscle.yaml').is_file():
        return source
    return Path(sysconfig.get_path('data')) / 'share' / PACKAGE / 'config'


def protocol_path(spec: str) -> Path:
    """Resolve ``I``, ``II`` or a path to a protocol YAML file.

    :param spec: a built-in protocol name or a file path
    """
    if spec in BUILTIN_PROTOCOLS:
        return config_dir() / 'protocols' / BUILTIN_PROTOCOLS[spec]
    return Path(spec).expanduser()


def default_params_file() -> Path:
    """The shipped ``muscle.yaml`` with the paper's defaults."""
    return config_dir() / 'muscle.yaml'

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


def builtin_protocol(spec: str) -> str | None:
    """The built-in protocol ``spec`` names, in any case, or ``None``.

    ``I`` and ``II`` always name the built-in ones; ``ii`` (or ``i``) does too
    unless a file of that name exists in the working directory.
    """
    name = spec.upper()
    if name not in BUILTIN_PROTOCOLS:
        return None
    if spec != name and Path(spec).expanduser().exists():
        return None   # the user's file named ``ii``
    return name


def protocol_path(spec: str) -> Path:
    """Resolve ``I``, ``II`` (in any case: :func:`builtin_protocol`) or a path
    to a protocol YAML file.

    :param spec: a built-in protocol name or a file path
    """
    name = builtin_protocol(spec)
    if name is not None:
        return config_dir() / 'protocols' / BUILTIN_PROTOCOLS[name]
    return Path(spec).expanduser()


def find_protocol(spec: str) -> Path:
    """:func:`protocol_path`, checked to exist.

    :raises ValueError: naming ``spec`` and the built-in protocols
    """
    path = protocol_path(spec)
    if not path.exists():
        raise ValueError(f'{spec}: no such protocol file; the built-in protocols are '
                                f'{" and ".join(BUILTIN_PROTOCOLS)}')
    return path


def knee_plant_file() -> Path:
    """The shipped knee preset, ``knee.yaml`` (a plant file for the limb nodes)."""
    return config_dir() / 'knee.yaml'


def default_params_file() -> Path:
    """The shipped ``muscle.yaml`` with the paper's defaults."""
    return config_dir() / 'muscle.yaml'

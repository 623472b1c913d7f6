"""Read a ROS 2 parameters file (``config/muscle.yaml``) without ROS.

The offline CLI and the simulator node load the same file; this module does it
for the CLI, with the same names and the same validation as the node.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from .model import MuscleParams
from .control.joint import JOINT_CONTROLLER_KEYS
from .model.limb import LimbPlant
from .model.protocol import safe_load_yaml

#: Parameters of the simulator node that are not muscle parameters. They are
#: valid in the file; the offline CLI reads ``rate_hz`` and ignores the rest.
SIMULATOR_NODE_KEYS = ('rate_hz', 'real_time_factor', 'input_timeout_s', 'frame_id',
                       'publish_clock', 'publish_every_n_steps', 'use_sim_time')

#: Parameters of ROS 2's standard QoS overrides start with this key (the node
#: checks them; the offline CLI has no topics and passes over them).
QOS_OVERRIDES_KEY = 'qos_overrides'

#: Section names that apply to the simulator: every node, or the node by name.
_WILDCARD = '/**'
_NODE_NAME = 'simulator'


def read_ros_parameters(path: str | Path, node_name: str = _NODE_NAME) -> dict[str, Any]:
    """The ``ros__parameters`` that a ROS 2 params file gives a node.

    Sections ``/**`` and those naming the node (``simulator``, ``/simulator``,
    ``/ns/simulator``, ``/**/simulator``) are merged in file order, later ones
    winning, as ``--params-file`` does.

    :param path: the YAML file
    :param node_name: the node's name (``simulator``, ``limb``)
    :raises ValueError: naming the file if it cannot be read or has no section
        for the simulator
    """
    path = Path(path)
    try:
        doc = safe_load_yaml(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError) as err:
        raise ValueError(f'{path}: cannot read parameters file: {err}') from None
    except yaml.YAMLError as err:
        raise ValueError(f'{path}: not valid YAML: {err}') from None
    if not isinstance(doc, dict):
        raise ValueError(f'{path}: expected `/**:` or a node name, then '
                         f'`ros__parameters:`; got {type(doc).__name__}')
    merged: dict[str, Any] = {}
    found = False
    for node, section in doc.items():
        name = str(node)
        if name != _WILDCARD and name.rstrip('/').split('/')[-1] != node_name:
            continue
        if not isinstance(section, dict) or 'ros__parameters' not in section:
            raise ValueError(f'{path}: section `{name}` must contain `ros__parameters:`')
        params = section['ros__parameters']
        if not isinstance(params, dict):
            raise ValueError(f'{path}: `{name}.ros__parameters` must be a mapping, '
                             f'got {params!r}')
        merged.update(params)
        found = True
    if not found:
        raise ValueError(f'{path}: no `/**` or `{node_name}` section with '
                         f'`ros__parameters`')
    return merged


def load_muscle_params(path: str | Path) -> tuple[MuscleParams, dict[str, Any]]:
    """Muscle parameters and the simulator-node settings from a params file.

    :param path: the YAML file
    :return: the validated :class:`MuscleParams` and a dict of the node keys
        present in the file (``rate_hz`` and the like)
    :raises ValueError: on an unknown key or invalid value, naming the file
    """
    values = read_ros_parameters(path)
    # QoS overrides configure the node's publishers and subscriptions, nothing
    # offline: nested (``qos_overrides: {/force: ...}``) or flat dotted keys.
    values = {k: v for k, v in values.items()
              if k != QOS_OVERRIDES_KEY and not str(k).startswith(QOS_OVERRIDES_KEY + '.')}
    params = MuscleParams.from_mapping(values, source=str(path), ignore=SIMULATOR_NODE_KEYS)
    node = {k: v for k, v in values.items() if k in SIMULATOR_NODE_KEYS}
    return params, node


#: Parameters of the limb node that are not part of the plant.
LIMB_NODE_KEYS = SIMULATOR_NODE_KEYS


def load_plant(path: str | Path) -> tuple[LimbPlant, dict[str, Any]]:
    """A limb plant (joint and muscles) and the node settings from a plant file.

    :param path: the YAML file (``/**`` or ``limb`` sections)
    :return: the validated :class:`LimbPlant` and a dict of the node keys present
    :raises ValueError: naming the file and the key on any defect
    """
    values = read_ros_parameters(path, 'limb')
    values = {k: v for k, v in values.items()
              if k != QOS_OVERRIDES_KEY and not str(k).startswith(QOS_OVERRIDES_KEY + '.')}
    # The joint controller's gains may share the plant file (one section for both nodes).
    plant = LimbPlant.from_mapping(values, source=str(path),
                                   ignore=LIMB_NODE_KEYS + JOINT_CONTROLLER_KEYS)
    node = {k: v for k, v in values.items() if k in LIMB_NODE_KEYS}
    return plant, node

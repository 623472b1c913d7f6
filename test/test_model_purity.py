"""The model core is pure Python and NumPy: nothing under model/ touches rclpy."""
import ast
import subprocess
import sys
from pathlib import Path

import hill_muscle_ros.model as model

MODEL_DIR = Path(model.__file__).parent


def test_no_module_under_model_imports_rclpy_or_ros_messages():
    forbidden = ('rclpy', 'std_msgs', 'geometry_msgs', 'rosgraph_msgs', 'std_srvs')
    for path in MODEL_DIR.rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            for name in names:
                assert name.split('.')[0] not in forbidden, f'{path.name} imports {name}'


def test_importing_the_model_loads_no_rclpy():
    code = 'import sys, hill_muscle_ros.model; print("rclpy" in sys.modules)'
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == 'False'

"""The core stays free of rclpy (DESIGN.md section 1): statically and at import time."""

import ast
import os
import pkgutil
import subprocess
import sys

import microball_ros.core

CORE_DIR = os.path.dirname(microball_ros.core.__file__)
CORE_MODULES = sorted(f'microball_ros.core.{m.name}' for m in pkgutil.iter_modules([CORE_DIR]))


def _imported_names(path):
    tree = ast.parse(open(path).read(), path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            yield node.module


def test_no_core_source_imports_ros():
    offenders = []
    for name in os.listdir(CORE_DIR):
        if name.endswith('.py'):
            for module in _imported_names(os.path.join(CORE_DIR, name)):
                root = module.split('.')[0]
                if root in ('rclpy', 'microball_msgs', 'std_msgs', 'sensor_msgs', 'rosgraph_msgs'):
                    offenders.append(f'{name}: {module}')
    assert offenders == []


def test_importing_the_whole_core_loads_no_rclpy():
    assert CORE_MODULES, 'the core has no modules?'
    code = ('import sys\n'
            + ''.join(f'import {m}\n' for m in CORE_MODULES)
            + "print(sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy'))")
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            check=True)
    assert result.stdout.strip() == '[]'

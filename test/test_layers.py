"""The layers of docs/design.md section 1, checked on the source.

core stays free of rclpy (statically and at import time); imports point down the layers
cli > app > nodes > io > core; no module imports another module's private names; the package
root holds only the entry points.
"""

import ast
import os
import pathlib
import pkgutil
import subprocess
import sys

import microball_ros
import microball_ros.core

PACKAGE_DIR = pathlib.Path(microball_ros.__file__).parent
CORE_DIR = os.path.dirname(microball_ros.core.__file__)
CORE_MODULES = sorted(f'microball_ros.core.{m.name}'
                      for m in pkgutil.walk_packages([CORE_DIR]))
ROS_PACKAGES = ('rclpy', 'microball_msgs', 'std_msgs', 'sensor_msgs', 'rosgraph_msgs',
                'builtin_interfaces', 'diagnostic_msgs', 'rcl_interfaces', 'std_srvs')
# Lower rank = lower layer; a module may import from its own rank or below.
# testing/ is the kit for users' node tests: it may use every layer, nothing uses it.
LAYERS = {'core': 0, 'io': 1, 'nodes': 2, 'app': 3, 'testing': 4, 'cli': 4, '__main__': 4,
          '__init__': 0, 'config': 0}


def _sources():
    for path in sorted(PACKAGE_DIR.rglob('*.py')):
        yield path, ast.parse(path.read_text(), str(path))


def _module_name(path):
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix('').parts
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def _imports(tree, module):
    """Yield (imported module, imported names) for every import, relative ones resolved."""
    package = module if module.count('.') == 0 else module.rsplit('.', 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, ()
        elif isinstance(node, ast.ImportFrom):
            target = node.module or ''
            if node.level:
                base = package.split('.')[:len(package.split('.')) - node.level + 1]
                target = '.'.join([*base, target] if target else base)
            yield target, tuple(alias.name for alias in node.names)


def _layer(module):
    parts = module.split('.')
    return LAYERS[parts[1]] if len(parts) > 1 else LAYERS['__init__']


def test_no_core_source_imports_ros():
    offenders = []
    for path, tree in _sources():
        if path.is_relative_to(CORE_DIR):
            offenders += [f'{path.name}: {target}' for target, _ in _imports(tree, 'x.y')
                          if target.split('.')[0] in ROS_PACKAGES]
    assert offenders == []


def test_importing_the_whole_core_loads_no_rclpy():
    assert CORE_MODULES, 'the core has no modules?'
    code = ('import sys\n'
            + ''.join(f'import {m}\n' for m in CORE_MODULES)
            + "print(sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy'))")
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            check=True)
    assert result.stdout.strip() == '[]'


def test_no_module_imports_private_names_of_another():
    offenders = []
    for path, tree in _sources():
        module = _module_name(path)
        for target, names in _imports(tree, module):
            if not target.startswith('microball_ros') or target == module:
                continue
            private = [n for n in names if n.startswith('_') and not n.startswith('__')]
            private_module = [p for p in target.split('.') if p.startswith('_')
                              and not p.startswith('__')]
            if private or private_module:
                offenders.append(f'{module}: from {target} import {", ".join(names)}')
    assert offenders == []


def test_imports_point_down_the_layers():
    offenders = []
    for path, tree in _sources():
        module = _module_name(path)
        for target, _ in _imports(tree, module):
            if not target.startswith('microball_ros.'):
                continue
            if _layer(target) > _layer(module):
                offenders.append(f'{module} imports {target}')
    assert offenders == []


def test_the_package_root_holds_only_the_entry_points():
    loose = sorted(p.name for p in PACKAGE_DIR.glob('*.py'))
    assert set(loose) <= {'__init__.py', '__main__.py', 'cli.py'}, loose
    folders = sorted(p.name for p in PACKAGE_DIR.iterdir()
                     if p.is_dir() and p.name != '__pycache__')
    assert folders == ['app', 'config', 'core', 'io', 'nodes', 'testing']

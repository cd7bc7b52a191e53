"""The lab files: config/microball.yaml, launch/microball.launch.xml and setup.py agree.

launch is not installable here, so the launch file is parsed as XML; every node is started as
a process with the YAML as --params-file and its parameters read back through the standard
rcl_interfaces GetParameters service of that node.
"""

import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python
import yaml

from microball_ros.io.video import write_image_sequence
from microball_ros.testing import Harness

pytestmark = pytest.mark.ros

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(ROOT, 'config', 'microball.yaml')
LAUNCH = os.path.join(ROOT, 'launch', 'microball.launch.xml')
NODES = ('servo_commander', 'bench_simulator', 'camera_source', 'camera_tracker',
         'three_stage_estimator', 'friction_identifier', 'recorder')


def _setup_call():
    """Return the keyword arguments setup.py passes to setup(), by running it (setup stubbed)."""
    import runpy
    from unittest import mock

    captured = {}
    cwd = os.getcwd()
    try:
        os.chdir(ROOT)  # setup.py globs paths relative to the package root, as pip runs it
        with mock.patch('setuptools.setup', lambda **kwargs: captured.update(kwargs)):
            runpy.run_path('setup.py', run_name='__main__')
    finally:
        os.chdir(cwd)
    return captured


def console_scripts():
    """Return console-script name -> 'module:function' from setup.py."""
    entry_points = _setup_call()['entry_points']
    return dict(line.replace(' ', '').split('=') for line in entry_points['console_scripts'])


def data_files():
    """Return the data_files of setup.py as (directory, [files])."""
    return _setup_call()['data_files']


def flatten(mapping, prefix=''):
    """Return a nested ros__parameters mapping as dotted name -> value."""
    flat = {}
    for key, value in mapping.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            flat.update(flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def _config():
    with open(CONFIG) as handle:
        return yaml.safe_load(handle)


def test_the_yaml_has_every_parameter_of_every_node():
    import importlib

    config = _config()
    assert sorted(config) == sorted(NODES)
    for name in NODES:
        params = importlib.import_module(f'microball_ros.nodes.{name}').PARAMS
        assert set(flatten(config[name]['ros__parameters'])) == set(params), name


def test_the_launch_file_starts_console_scripts_with_the_params_file():
    scripts = console_scripts()
    root = ElementTree.parse(LAUNCH).getroot()
    assert root.tag == 'launch'
    args = {arg.get('name'): arg.get('default') for arg in root.iter('arg')}
    assert args['params_file'] == '$(find-pkg-share microball_ros)/config/microball.yaml'
    nodes = list(root.iter('node'))
    assert {node.get('exec') for node in nodes} == set(NODES)
    for node in nodes:
        assert node.get('pkg') == 'microball_ros'
        module = scripts[node.get('exec')].split(':')[0]
        assert module == f"microball_ros.nodes.{node.get('exec')}"
        assert node.get('name') in _config()  # its section of the params file
        assert [p.get('from') for p in node.iter('param')] == ['$(var params_file)']


def test_setup_installs_the_config_and_the_launch_file():
    installed = dict((d, f) for d, f in data_files())
    assert installed['share/microball_ros/config'] == ['config/microball.yaml']
    assert installed['share/microball_ros/launch'] == ['launch/microball.launch.xml']
    for files in installed.values():
        for path in files:
            assert '*' in path or os.path.isfile(os.path.join(ROOT, path)), path


def _same(value, expected):
    if isinstance(expected, float) or isinstance(value, float):
        return value == pytest.approx(expected, rel=1e-12)
    if isinstance(expected, list):
        return len(value) == len(expected) and all(_same(v, e) for v, e in
                                               zip(value, expected, strict=True))
    return value == expected


def test_every_node_starts_with_the_yaml_and_declares_each_of_its_parameters(
        ros_context, tmp_path):
    frames = tmp_path / 'frames'
    write_image_sequence(frames, [np.full((8, 8), k, np.uint8) for k in range(3)])
    # The YAML's camera device does not exist here: a later -p overrides it (and fps) only.
    extra = {'camera_source': ['-p', f'device:={frames}', '-p', 'fps:=30.0']}
    config = _config()
    harness = Harness(ros_context)
    processes = {}
    try:
        for name in NODES:
            processes[name] = subprocess.Popen(
                [sys.executable, '-m', f'microball_ros.nodes.{name}', '--ros-args',
                 '--params-file', CONFIG, *extra.get(name, [])],
                cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for name in NODES:
            expected = flatten(config[name]['ros__parameters'])
            if name == 'camera_source':
                expected.update(device=str(frames), fps=30.0)
            client = harness.probe.create_client(GetParameters, f'/{name}/get_parameters')
            deadline = time.monotonic() + 60
            while not client.service_is_ready():
                assert processes[name].poll() is None, processes[name].communicate()[0]
                assert time.monotonic() < deadline, f'{name}: no get_parameters service'
                harness.executor.spin_once(timeout_sec=0.05)
            future = client.call_async(GetParameters.Request(names=list(expected)))
            harness.spin_until(future.done, 30, f'{name} get_parameters')
            values = future.result().values
            assert len(values) == len(expected)
            for (parameter, wanted), value in zip(expected.items(), values, strict=True):
                assert value.type != ParameterType.PARAMETER_NOT_SET, (name, parameter)
                got = parameter_value_to_python(value)
                assert _same(got, wanted), (name, parameter, got, wanted)
    finally:
        for process in processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGINT)
        codes = {}
        for name, process in processes.items():
            try:
                process.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.communicate()
            codes[name] = process.returncode
        harness.close()
    assert codes == dict.fromkeys(NODES, 0)


def test_experiment_params_file_overrides_the_scenario_per_node(tmp_path):
    from microball_ros.app.experiment import node_parameters
    from microball_ros.core.errors import InputError

    plain = node_parameters('paper', 10.0, 1.0, output=str(tmp_path / 'bag'))
    given = node_parameters('paper', 10.0, 1.0, output=str(tmp_path / 'bag'),
                            params_file=CONFIG)
    config = {name: flatten(section['ros__parameters']) for name, section in _config().items()}
    assert given['three_stage_estimator']['exposure'] == 0.0  # the file's, not 1/60
    assert plain['three_stage_estimator']['exposure'] == pytest.approx(1 / 60)
    assert given['friction_identifier'] == config['friction_identifier']
    assert given['servo_commander']['heartbeat'] == 1.0
    # The run control stays the experiment's: duration, start-up, bag directory.
    assert given['bench_simulator']['duration'] == 10.0
    assert given['bench_simulator']['wait_for_subscribers'] == 2
    assert given['recorder']['output'] == str(tmp_path / 'bag')
    assert given['recorder']['compression'] == 'zstd'
    # Only the file's nodes change; qos_overrides pass through as dotted names.
    small = tmp_path / 'small.yaml'
    small.write_text('/three_stage_estimator:\n  ros__parameters:\n    epsilon: 0.05\n'
                     '    qos_overrides:\n      /tracking/positions:\n        subscription:\n'
                     '          depth: 500\n')
    changed = node_parameters('paper', 10.0, 1.0, params_file=str(small))
    assert changed['three_stage_estimator'] == {
        **plain['three_stage_estimator'], 'epsilon': 0.05,
        'qos_overrides./tracking/positions.subscription.depth': 500}
    assert changed['camera_tracker'] == plain['camera_tracker']
    for text, message in (('estimator:\n  ros__parameters: {a: 1}\n', 'unknown node'),
                          ('friction_identifier:\n  ros__parameters: {refit: 2}\n',
                           'has no parameter refit'),
                          ('[1, 2]\n', 'not a ROS 2 parameters file'),
                          (': : :\n', 'not YAML')):
        bad = tmp_path / 'bad.yaml'
        bad.write_text(text)
        with pytest.raises(InputError, match=message):
            node_parameters('paper', 10.0, 1.0, params_file=str(bad))
    with pytest.raises(InputError, match='No such file'):
        node_parameters('paper', 10.0, 1.0, params_file=str(tmp_path / 'missing.yaml'))

"""ament_python package microball_ros (pip installs it too: `pip install -e .`)."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'microball_ros'

# The node sample bags of microball_ros.testing (bags/make_node_samples.py), installed where
# pip (a venv) and colcon (an install space) put data: <prefix>/share/microball_ros/bags/.
SAMPLE_BAGS = ('camera_tracker', 'three_stage_estimator', 'friction_identifier')

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={package_name: ['config/*.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/msg_defs/msg', glob('msg_defs/msg/*.msg')),
        ('share/' + package_name + '/config', ['config/microball.yaml']),
        ('share/' + package_name + '/launch', ['launch/microball.launch.xml']),
        *((f'share/{package_name}/bags/{name}', sorted(glob(f'bags/{name}/*')))
          for name in SAMPLE_BAGS),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='microball_ros developers',
    maintainer_email='microball@example.org',
    description='Measure and model friction in MEMS microball bearings on ROS 2.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'microball = microball_ros.cli:main',
            'servo_commander = microball_ros.nodes.servo_commander:main',
            'bench_simulator = microball_ros.nodes.bench_simulator:main',
            'camera_tracker = microball_ros.nodes.camera_tracker:main',
            'three_stage_estimator = microball_ros.nodes.three_stage_estimator:main',
            'friction_identifier = microball_ros.nodes.friction_identifier:main',
            'recorder = microball_ros.nodes.recorder:main',
            'camera_source = microball_ros.nodes.camera_source:main',
        ],
        # The node-testing kit's fixtures, in every pytest session of the environment.
        'pytest11': [
            'microball_ros.testing.plugin = microball_ros.testing.plugin',
        ],
    },
)

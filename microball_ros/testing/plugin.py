"""The pytest plugin of microball_ros (entry point pytest11): fixtures for node-level tests.

Loaded in every pytest session of an environment where microball_ros is installed
(``-p no:microball_ros.testing.plugin`` leaves it out). Before any test runs it gives the
session a ROS domain of its own: a free domain ID claimed through app/isolation.py (a lock
file per ID, held for the session, shared with ``microball experiment``, so two test runs on
one machine never see each other's nodes), ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, and
the Fast DDS lock-step profile (loaded before any rclpy.init, as lock-step replay needs).
Child processes inherit all three. The previous values come back when the session ends.

Fixtures:

- ``ros_domain`` (session): the DomainClaim (``.domain_id``).
- ``ros_context``: a fresh initialised rclpy Context, shut down after the test.
- ``ros_harness``: a Harness (probe node + executor) on ``ros_context``, closed after.
- ``node_process``: start a console script as a process, ready in the graph, stopped after
  (SIGINT, deadline, SIGKILL); returns the NodeProcess (``.returncode``, ``.log``).
- ``node_replay``: ``replay(bag, node, ...)`` in ``ros_context``, node logs in tmp_path.
- ``sample_bag``: ``sample_bag(name)``, the path of one of the package's sample bags.
"""

import os

import pytest

from microball_ros.app.isolation import claim_domain
from microball_ros.app.play import use_lockstep_profile

_SET = ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'RMW_IMPLEMENTATION',
        'FASTDDS_DEFAULT_PROFILES_FILE')
_CLAIM = pytest.StashKey()
_SAVED = pytest.StashKey()


def pytest_configure(config):
    """Claim a domain ID and set the ROS environment before any test (or rclpy) runs."""
    config.stash[_SAVED] = {name: os.environ.get(name) for name in _SET}
    claim = claim_domain()
    config.stash[_CLAIM] = claim
    os.environ['ROS_DOMAIN_ID'] = str(claim.domain_id)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    use_lockstep_profile()
    config.addinivalue_line('markers', 'ros: talks over DDS (nodes, processes, topics)')


def pytest_report_header(config):
    """Show the isolation settings in the test header."""
    return (f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
            f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']} "
            '(microball_ros.testing)')


def pytest_unconfigure(config):
    """Release the domain ID and restore the environment."""
    claim = config.stash.get(_CLAIM, None)
    if claim is not None:
        claim.release()
    for name, value in config.stash.get(_SAVED, {}).items():
        if value is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = value


@pytest.fixture(scope='session')
def ros_domain(pytestconfig):
    """Return this session's DomainClaim (its ``domain_id`` is in ROS_DOMAIN_ID)."""
    return pytestconfig.stash[_CLAIM]


@pytest.fixture
def ros_context():
    """Give a test its own initialised rclpy Context, shut down afterwards."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    if context.ok():
        rclpy.shutdown(context=context)


@pytest.fixture
def ros_harness(ros_context):
    """Give a Harness (a probe node and one executor) on the test's context."""
    from microball_ros.testing.harness import Harness

    harness = Harness(ros_context)
    yield harness
    harness.close()


@pytest.fixture
def node_process(ros_harness, tmp_path):
    """Return start(executable, parameters=None, *, ready=None, timeout=30.0, **options).

    It starts a NodeProcess (options as NodeProcess takes them; logs in tmp_path), waits until
    ``ready()`` holds (default: the node is in the graph) and returns it; every process still
    running at the end of the test is stopped (SIGINT, then SIGKILL after 10 s).
    """
    from microball_ros.testing.process import NodeProcess

    started = []

    def start(executable, parameters=None, *, ready=None, timeout=30.0, **options):
        options.setdefault('log_dir', tmp_path)
        process = NodeProcess(executable, parameters, **options)
        started.append(process.start())
        return process.wait_until_ready(ros_harness, ready, timeout)

    yield start
    for process in started:
        process.stop()


@pytest.fixture
def node_replay(ros_context, tmp_path):
    """Return replay(bag, node, **options) bound to the test's context, logs in tmp_path."""
    from microball_ros.testing.replay import replay

    def run(bag, node, **options):
        options.setdefault('context', ros_context)
        options.setdefault('log_dir', tmp_path)
        return replay(bag, node, **options)

    return run


@pytest.fixture(scope='session')
def sample_bag():
    """Return the function that gives the path of a sample bag of the package by name."""
    from microball_ros.testing.samples import sample_bag as find

    return find

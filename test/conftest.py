"""Test-session set-up: an exclusive ROS_DOMAIN_ID and localhost-only discovery.

Every pytest session locks a free domain ID on this machine (a lock file per ID, held for the
whole session), so two test runs, even of different checkouts, never see each other's nodes.
Child processes inherit the environment.
"""

import fcntl
import os
import tempfile

import pytest

_DOMAIN_IDS = range(1, 101)


def _lock_free_domain_id():
    for domain_id in _DOMAIN_IDS:
        path = os.path.join(tempfile.gettempdir(), f'microball-ros-domain-{domain_id}.lock')
        handle = open(path, 'w')
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        return domain_id, handle
    raise RuntimeError('no free ROS_DOMAIN_ID in 1..100 for this test session')


def pytest_configure(config):
    """Claim a domain ID before any test (or rclpy) runs."""
    domain_id, handle = _lock_free_domain_id()
    config._microball_domain_lock = handle
    os.environ['ROS_DOMAIN_ID'] = str(domain_id)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


def pytest_report_header(config):
    """Show the isolation settings in the test header."""
    return (f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
            f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}")


def pytest_unconfigure(config):
    """Release the domain ID."""
    handle = getattr(config, '_microball_domain_lock', None)
    if handle is not None:
        handle.close()


@pytest.fixture
def ros_context():
    """Give a test its own initialised rclpy Context, shut down afterwards."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    if context.ok():
        rclpy.shutdown(context=context)

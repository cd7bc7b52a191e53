"""Test-session set-up: an exclusive ROS_DOMAIN_ID and localhost-only discovery.

Every pytest session claims a free domain ID on this machine (app/isolation.py: a lock file per
ID, held for the whole session, shared with `microball experiment`), so two test runs, even of
different checkouts, never see each other's nodes. Child processes inherit the environment.
"""

import os

import pytest

from microball_ros.app.isolation import claim_domain


def pytest_configure(config):
    """Claim a domain ID before any test (or rclpy) runs."""
    claim = claim_domain()
    config._microball_domain = claim
    os.environ['ROS_DOMAIN_ID'] = str(claim.domain_id)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


def pytest_report_header(config):
    """Show the isolation settings in the test header."""
    return (f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
            f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}")


def pytest_unconfigure(config):
    """Release the domain ID."""
    claim = getattr(config, '_microball_domain', None)
    if claim is not None:
        claim.release()


@pytest.fixture
def ros_context():
    """Give a test its own initialised rclpy Context, shut down afterwards."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    if context.ok():
        rclpy.shutdown(context=context)

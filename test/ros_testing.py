"""Kept for the node tests not yet migrated: the harness is microball_ros.testing.Harness.

Delete this file once no test imports it (import Harness from microball_ros.testing instead).
"""

from microball_ros.testing.harness import Harness

__all__ = ['Harness']

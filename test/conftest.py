"""Test-session set-up: the package's own pytest plugin (microball_ros.testing.plugin).

Installed, the package registers the plugin through its ``pytest11`` entry point; naming it here
too makes a run from a checkout on PYTHONPATH (without the installed entry point) the same.
The plugin claims an exclusive ROS_DOMAIN_ID for the session (app/isolation.py), keeps
discovery on localhost, loads the lock-step Fast DDS profile, and gives the fixtures
(``ros_context``, ``ros_harness``, ``node_process``, ``node_replay``, ``sample_bag``).
"""

pytest_plugins = ['microball_ros.testing.plugin']

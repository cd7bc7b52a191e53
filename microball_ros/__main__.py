"""``python -m microball_ros``: the same as the ``microball`` command."""

import sys

from microball_ros.cli import main

sys.exit(main())

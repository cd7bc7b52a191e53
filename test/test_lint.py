"""Lint as the ROS 2 ecosystem does (ament_flake8 / ament_pep257 rules), via ruff."""

import os
import shutil
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_ruff_finds_nothing():
    ruff = shutil.which('ruff', path=os.path.dirname(sys.executable)) or shutil.which('ruff')
    if ruff is None:
        pytest.fail('ruff is not installed (make setup installs it from requirements-dev.txt)')
    result = subprocess.run([ruff, 'check', '--no-cache', ROOT], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr

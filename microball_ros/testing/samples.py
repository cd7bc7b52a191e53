"""Find the package's sample bags, from a checkout or from an installed package.

The bags live in the repository's ``bags/`` folder and are installed with the package as data
files under ``<prefix>/share/microball_ros/bags`` (setup.py data_files: where pip puts them in
a venv, and colcon in an install space). ``sample_bag(name)`` looks, in order, in the folder
named by ``MICROBALL_SAMPLE_BAGS``, in the checkout this package was imported from (an editable
install or PYTHONPATH), and in ``share/microball_ros/bags`` of this Python's prefix and of every
ament prefix (``AMENT_PREFIX_PATH``).

One bag per node, each holding that node's input topics and the outputs the real node
published for them (custom_data ``microball.testing`` names which are which, and
``microball.<node>`` the parameters it ran with):

- ``camera_tracker``: /camera/image_raw -> /tracking/positions
- ``three_stage_estimator``: /tracking/positions -> /estimation/derivatives
- ``friction_identifier``: /estimation/derivatives -> /friction/model
"""

import os
import sys

import microball_ros

SAMPLE_BAGS = ('camera_tracker', 'three_stage_estimator', 'friction_identifier')
ENVIRONMENT_VARIABLE = 'MICROBALL_SAMPLE_BAGS'


def sample_bag_folders():
    """Return the folders searched for sample bags, in order (existing ones only)."""
    checkout = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(
        microball_ros.__file__))), 'bags')
    candidates = [os.environ.get(ENVIRONMENT_VARIABLE, ''), checkout]
    prefixes = [sys.prefix, *os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)]
    candidates += [os.path.join(p, 'share', 'microball_ros', 'bags') for p in prefixes if p]
    seen, folders = set(), []
    for folder in candidates:
        if folder and os.path.isdir(folder) and os.path.realpath(folder) not in seen:
            seen.add(os.path.realpath(folder))
            folders.append(folder)
    return folders


def sample_bag(name):
    """Return the path of the sample bag ``name`` (a bag directory), e.g. 'camera_tracker'."""
    folders = sample_bag_folders()
    for folder in folders:
        path = os.path.join(folder, name)
        if os.path.isfile(os.path.join(path, 'metadata.yaml')):
            return path
    raise FileNotFoundError(
        f'no sample bag {name!r} in {", ".join(folders) or "any folder"} (known: '
        f'{", ".join(SAMPLE_BAGS)}; set {ENVIRONMENT_VARIABLE} to a folder holding it)')

"""Node-level testing kit for microball_ros and for labs that change or add a node.

A pytest plugin (microball_ros.testing.plugin, registered through the ``pytest11`` entry
point, so installing the package is enough) gives every test session a ROS domain of its own
and the fixtures ``ros_context``, ``ros_harness``, ``node_process``, ``node_replay`` and
``sample_bag``. The same tools as plain Python:

- ``Harness``: nodes in this process on one executor with a probe node; waits on conditions
  with deadlines (``spin_until``, ``wait_for_subscribers``, ``wait_for_node``), never sleeps.
- ``NodeProcess``: a console script as a process with parameters; ready when its node is in
  the graph; stopped with SIGINT, then SIGKILL after a deadline; exit code and log kept.
- ``replay``: a bag's input topics through one node, lock-step; its outputs compared with the
  recorded ones (byte-identical on the recording platform, relative 1e-9 elsewhere), with the
  first differing message, field and values when they differ.
- ``sample_bag``: the package's sample bags, one per node (inputs and recorded outputs).

It also holds test doubles (``dynamixel_emulator``: a Dynamixel servo on a pseudo-terminal).
See README.md beside this file: "Testing your own node".
"""

from microball_ros.testing.harness import Harness
from microball_ros.testing.process import NodeExited, NodeProcess, killable_env
from microball_ros.testing.replay import Replay, replay, testing_spec
from microball_ros.testing.samples import SAMPLE_BAGS, sample_bag

__all__ = ['Harness', 'NodeExited', 'NodeProcess', 'Replay', 'SAMPLE_BAGS', 'killable_env',
           'replay', 'sample_bag', 'testing_spec']

"""``microball record``: a recorder node in this process, until Ctrl-C or a duration."""

import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from microball_ros.nodes.recorder import Recorder


def spin_until_interrupted(node, done=lambda: False):
    """Spin node in a fresh context until Ctrl-C (or done()); return True if interrupted."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        while not done():
            executor.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        return True
    finally:
        executor.shutdown()
    return False


def record(output, topics=None, duration=None, started=None):
    """Record ``topics`` (all if None) into the bag ``output``; return (counts, lost) per topic.

    Runs until Ctrl-C or ``duration`` wall seconds; ``started()`` is called once recording.
    """
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        recorder = Recorder(context=context, parameter_overrides=[
            Parameter('output', value=output), Parameter('topics', value=topics or [''])])
        if started is not None:
            started()
        end = None if duration is None else time.monotonic() + duration
        spin_until_interrupted(recorder, lambda: end is not None and time.monotonic() > end)
        counts, lost = recorder.close(), dict(recorder.lost)
        recorder.destroy_node()
    finally:
        if context.ok():
            rclpy.shutdown(context=context)
    return counts, lost

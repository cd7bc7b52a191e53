"""Helpers for node tests: spin an executor until a condition holds, with a deadline."""

import time

from rclpy.executors import SingleThreadedExecutor


class Harness:
    """Nodes under test plus a probe node, all on one executor of one context."""

    def __init__(self, context, *nodes):
        import rclpy

        self.context = context
        self.probe = rclpy.create_node('probe', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.nodes = list(nodes)
        for node in (self.probe, *nodes):
            self.executor.add_node(node)

    def spin_until(self, condition, timeout=60.0, message='condition'):
        """Spin until condition() is true; fail the test after timeout seconds."""
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout:g} s waiting for {message}')
            self.executor.spin_once(timeout_sec=0.05)

    def wait_for_subscribers(self, publisher, count=1, timeout=30.0):
        """Spin until publisher has at least count matched subscriptions."""
        self.spin_until(lambda: publisher.get_subscription_count() >= count, timeout,
                        f'{count} subscriber(s) on {publisher.topic_name}')

    def close(self):
        """Destroy every node and the executor."""
        self.executor.shutdown()
        for node in (*self.nodes, self.probe):
            node.destroy_node()

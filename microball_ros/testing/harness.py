"""Nodes under test on one executor, and waits on conditions with deadlines (never sleeps)."""

import time

from rclpy.executors import SingleThreadedExecutor

from microball_ros.nodes.common import DATA_QOS, diagnostic_values, subscribers_key


class Harness:
    """Nodes under test plus a probe node, all on one executor of one context.

    The probe is the test's own node: publishers, subscriptions and service clients the test
    needs go on it (``collect`` is a shortcut for a subscription into a list). Node processes
    handed to ``watch`` are checked on every spin, so a node that dies fails the wait at once
    with its log instead of at the deadline.
    """

    def __init__(self, context, *nodes):
        import rclpy

        self.context = context
        self.probe = rclpy.create_node('probe', context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.nodes = []
        self.processes = []
        self._statuses = None
        self.executor.add_node(self.probe)
        for node in nodes:
            self.add(node)

    def add(self, node):
        """Spin ``node`` on this harness's executor (it is destroyed by close()); return it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def watch(self, process):
        """Check ``process`` (a NodeProcess) on every spin: raise NodeExited if it exits."""
        self.processes.append(process)
        return process

    def check(self):
        """Raise NodeExited if a watched process has exited."""
        for process in self.processes:
            process.check()

    def collect(self, message_type, topic, qos=DATA_QOS, raw=False):
        """Subscribe the probe to ``topic``; return the list every message is appended to."""
        received = []
        self.probe.create_subscription(message_type, topic, received.append, qos, raw=raw)
        return received

    def spin_once(self, timeout=0.05):
        """Spin the executor once (at most ``timeout`` s), then check the watched processes."""
        self.executor.spin_once(timeout_sec=timeout)
        self.check()

    def spin_until(self, condition, timeout=60.0, message='condition'):
        """Spin until condition() is true; fail the test after timeout seconds."""
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline:
                raise AssertionError(f'timed out after {timeout:g} s waiting for {message}')
            self.spin_once()

    def wait_for_subscribers(self, publisher, count=1, timeout=30.0):
        """Spin until publisher has at least count matched subscriptions."""
        self.spin_until(lambda: publisher.get_subscription_count() >= count, timeout,
                        f'{count} subscriber(s) on {publisher.topic_name}')

    def wait_for_publishers(self, subscription, count=1, timeout=30.0):
        """Spin until subscription has at least count matched publishers."""
        self.spin_until(lambda: subscription.get_publisher_count() >= count, timeout,
                        f'{count} publisher(s) on {subscription.topic_name}')

    def diagnostics(self):
        """Return {status name: {key: value}}, each node's newest status on /diagnostics.

        The first call subscribes the probe; the dictionary it returns fills as the harness
        spins.
        """
        if self._statuses is None:
            from diagnostic_msgs.msg import DiagnosticArray

            self._statuses = {}

            self.probe.create_subscription(
                DiagnosticArray, '/diagnostics',
                lambda msg: self._statuses.update(diagnostic_values(msg)), 10)
        return self._statuses

    def wait_for_output_subscribers(self, node, topic, count=1, timeout=30.0):
        """Spin until node's publisher on topic has matched count subscriptions.

        The node reports it on /diagnostics (``subscribers: /topic``, NodeDiagnostics
        .watch_output). Unlike the graph, or this probe's own matches, that is the writer's side:
        what the node publishes after it reaches count is delivered to those subscriptions,
        even to another node's. ``node`` is the status name (``ns/name`` without a leading
        slash); ``topic`` is resolved as the node resolved it (a leading slash added).
        """
        statuses = self.diagnostics()
        key = subscribers_key(topic)
        self.spin_until(lambda: int(statuses.get(node, {}).get(key, 0)) >= count, timeout,
                        f'{count} subscriber(s) matched by {node} on {topic}')

    def wait_for_node(self, name, namespace='/', timeout=30.0):
        """Spin until a node of that name (and namespace) is in the ROS graph."""
        self.spin_until(lambda: (name, namespace) in
                        self.probe.get_node_names_and_namespaces(), timeout,
                        f'node {namespace.rstrip("/")}/{name} in the graph')

    def close(self):
        """Destroy every node and the executor."""
        self.executor.shutdown()
        for node in (*self.nodes, self.probe):
            node.destroy_node()

"""Bag-driven node tests: a recorded bag's inputs through one node, its outputs compared.

``replay(bag, node)`` publishes the bag's input topics, lock-step (each message only once the
node has acknowledged the previous one: app/play.py's Player), to one node, in this process
(a Node class) or as a process (its console script name), with the parameters the bag recorded
for it; collects what the node publishes on the output topics as the bytes that came through
DDS; and compares them with the bag's recorded outputs under the determinism contract
(docs/design.md section 4) with ``microball_ros.io.compare``: ``byte-identical``, ``within
tolerance`` (relative 1e-9, counts, integers and strings identical) or ``differs`` with the
first differing message, field, recorded value and new value. ``Replay.assert_reproduces()``
asks for byte identity where the bag was recorded on this platform (its fingerprint's key is
this process's) and for the tolerance elsewhere.

The Fast DDS lock-step profile must be loaded before rclpy.init in every process involved:
the pytest plugin does it for the test session (and so for every node process it starts);
outside pytest call ``microball_ros.app.play.use_lockstep_profile()`` first thing.

A bag says which topics are a node's inputs and outputs in custom_data ``microball.testing``
(YAML: node, inputs, outputs), as the sample bags do; for another bag name them.
"""

import os
import time

import yaml

from microball_ros.app.play import Player, replay_qos
from microball_ros.app.reprocess import Check
from microball_ros.io import fingerprint
from microball_ros.io.bags.reader import BagMessage, TopicInfo, open_bag, recorded_parameters
from microball_ros.io.bags.schema import qos_profiles_yaml
from microball_ros.io.bags.writer import BagWriter
from microball_ros.io.compare import BYTE_IDENTICAL, compare_bags, decode
from microball_ros.io.conversions import message_class
from microball_ros.nodes.common import matching_qos, subscribers_key
from microball_ros.nodes.recorder import publish_time
from microball_ros.testing.harness import Harness
from microball_ros.testing.process import NodeProcess

SPEC_KEY = 'microball.testing'
PROFILE_VARIABLE = 'FASTDDS_DEFAULT_PROFILES_FILE'


def testing_spec(bag):
    """Return the bag's custom_data ``microball.testing`` (node, inputs, outputs) or {}."""
    text = bag.custom_data.get(SPEC_KEY)
    spec = yaml.safe_load(text) if text else {}
    return spec if isinstance(spec, dict) else {}


class Received:
    """The messages a replay collected, shaped like an opened Bag (for io.compare)."""

    def __init__(self, types):
        self.types = dict(types)  # topic -> type name
        self.qos = dict.fromkeys(self.types, '')  # topic -> offered QoS profiles (YAML)
        self._messages = []

    def add(self, topic, data, info):
        """Keep one serialized message with its receipt time and source timestamp."""
        received = time.time_ns()
        self._messages.append(BagMessage(topic, self.types[topic], bytes(data), received,
                                         publish_time(info, received)))

    def count(self, topic):
        """Return how many messages arrived on topic."""
        return sum(m.topic == topic for m in self._messages)

    @property
    def topics(self):
        """Return {topic: TopicInfo}, as Bag.topics."""
        return {t: TopicInfo(t, kind, self.count(t), self.qos[t]) for t, kind in
                self.types.items()}

    def messages(self, topics=None):
        """Yield the received messages (of the given topics) in arrival order."""
        for message in self._messages:
            if topics is None or message.topic in topics:
                yield message


class Replay:
    """What one replay gave: the verdict, the collected messages, the node's log.

    ``check`` is an app.reprocess.Check (verdict, topics, both platforms); ``received`` the
    collected messages (a Bag-like ``Received``); ``process`` the NodeProcess or None;
    ``timed_out`` whether the node stopped publishing before the recorded counts.
    """

    def __init__(self, bag, node_name, inputs, outputs, parameters, published, received,
                 check, timed_out, process):
        self.bag = bag
        self.node_name = node_name
        self.inputs = tuple(inputs)
        self.outputs = tuple(outputs)
        self.parameters = parameters
        self.published = published
        self.received = received
        self.check = check
        self.timed_out = timed_out
        self.process = process

    @property
    def verdict(self):
        """Return the io.compare Verdict (status, line, per-topic comparisons)."""
        return self.check.verdict

    @property
    def same_platform(self):
        """Return True if the bag was recorded on this platform (byte identity expected)."""
        return self.check.same_platform

    def messages(self, topic):
        """Return the node's new messages on topic, decoded."""
        return decode(self.received, topic)

    def recorded(self, topic):
        """Return the bag's recorded messages on topic, decoded."""
        return decode(self.bag, topic)

    def report(self):
        """Return the lines that explain the outcome (verdict first)."""
        lines = [f'{self.node_name}: {self.verdict.line}', *self.check.platform_lines()]
        if self.timed_out:
            lines.append('the node stopped publishing before the recorded message counts '
                         f'({", ".join(f"{t}: {self.received.count(t)}" for t in self.outputs)}'
                         ' received)')
        if self.process is not None:
            lines.append(f'node log: {self.process.log_path} (exit code '
                         f'{self.process.returncode})')
        return lines

    def assert_reproduces(self):
        """Fail unless the outputs meet the determinism contract (docs/design.md section 4).

        Byte-identical where the bag carries this platform's fingerprint key, within relative
        1e-9 (every count, integer and string identical) anywhere else.
        """
        if not self.verdict.ok:
            raise AssertionError('\n'.join(self.report()))
        if self.same_platform and self.verdict.status != BYTE_IDENTICAL:
            raise AssertionError('\n'.join([
                f'{self.node_name}: not byte-identical on the platform that recorded the bag',
                *self.report()]))

    def write_bag(self, path, compression='zstd'):
        """Write the inputs and the new outputs as a bag that replay() takes as it is.

        Inputs keep their recorded bytes and times; outputs are the collected bytes with their
        receipt time as log time (as the recorder does). custom_data: the source bag's
        ``microball.*`` entries, the node's parameters, the ``microball.testing`` spec and this
        platform's fingerprint (BagWriter adds it).
        """
        custom = {k: v for k, v in self.bag.custom_data.items()
                  if k.startswith('microball.') and k != fingerprint.CUSTOM_DATA_KEY}
        custom[f'microball.{self.node_name}'] = yaml.safe_dump(self.parameters)
        custom[SPEC_KEY] = yaml.safe_dump({'node': self.node_name, 'inputs': list(self.inputs),
                                           'outputs': list(self.outputs)})
        with BagWriter(str(path), compression=compression, custom_data=custom) as writer:
            for topic in self.inputs:
                info = self.bag.topics[topic]
                writer.add_topic(topic, info.type, info.qos_profiles_yaml)
            for topic, info in self.received.topics.items():
                writer.add_topic(topic, info.type, info.qos_profiles_yaml)
            merged = sorted([*self.bag.messages(list(self.inputs)),
                             *self.received.messages()], key=lambda m: m.log_time_ns)
            for message in merged:
                writer.write(message.topic, message.data, message.log_time_ns,
                             message.publish_time_ns)
        return str(path)


def _require_lockstep_profile():
    if not os.environ.get(PROFILE_VARIABLE):
        raise RuntimeError(
            'lock-step replay needs the Fast DDS lock-step profile loaded before rclpy.init: '
            'run under pytest with microball_ros installed (its plugin loads it), or call '
            'microball_ros.app.play.use_lockstep_profile() before anything initialises rclpy')


def _node_name(node, node_name, spec):
    if node_name:
        return node_name
    if isinstance(node, str):
        return os.path.basename(node)
    if isinstance(node, (list, tuple)):
        return os.path.basename(node[0])
    return spec.get('node') or getattr(node, '__name__', 'node')


def _output_types(bag, outputs, inputs, spec):
    if outputs is None:
        outputs = spec.get('outputs') or [t for t in sorted(bag.topics) if t not in inputs]
    if isinstance(outputs, dict):
        return dict(outputs)
    missing = [t for t in outputs if t not in bag.topics]
    if missing:
        raise ValueError(f'{bag.path}: no recorded {", ".join(missing)}; give outputs as '
                         '{topic: type} to collect topics the bag does not have')
    return {t: bag.topics[t].type for t in outputs}


def replay(bag, node, *, inputs=None, outputs=None, parameters=None, node_name=None,
           context=None, expected=None, timeout=30.0, connect_timeout=60.0, log_dir=None):
    """Replay a bag's input topics through one node and compare its outputs; return a Replay.

    ``bag``: a bag path or an opened Bag. ``node``: a Node class or factory (called with
    ``context=`` and ``parameter_overrides=``), a Node already made (in ``context``), or a
    console script name / argv list (run as a NodeProcess). ``inputs``, ``outputs``: topics
    (default: the bag's ``microball.testing`` entry; outputs may be {topic: type} for topics
    the bag lacks). ``parameters``: values that override the ones the bag recorded for the node
    (custom_data ``microball.<node>``). ``expected``: {output topic: count} to wait for
    (default: the recorded counts). ``timeout``: seconds a wait for a message may go without
    progress; ``connect_timeout``: seconds the node may take to start and connect.
    ``context``: an initialised rclpy Context (default: one of its own, shut down after).
    """
    import rclpy
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    _require_lockstep_profile()
    bag = open_bag(str(bag)) if isinstance(bag, (str, os.PathLike)) else bag
    spec = testing_spec(bag)
    inputs = list(inputs or spec.get('inputs') or [])
    if not inputs:
        raise ValueError(f'{bag.path}: name the input topics (inputs=[...]); the bag has no '
                         f'{SPEC_KEY} entry')
    types = _output_types(bag, outputs, inputs, spec)
    name = _node_name(node, node_name, spec)
    # Lock-step publishes the next message once the node's reader has the previous one, not
    # once the node has processed it: every input subscription must be reliable and deep
    # enough to hold the whole replay (a camera node subscribes best effort, depth 5, by
    # default). The standard qos_overrides parameters say so.
    reliable_inputs = {}
    for topic in inputs:
        depth = min(max(bag.topics[topic].count if topic in bag.topics else 1, 1), 100000)
        reliable_inputs[f'qos_overrides.{topic}.subscription.reliability'] = 'reliable'
        reliable_inputs[f'qos_overrides.{topic}.subscription.depth'] = depth
    values = {**recorded_parameters(bag, spec.get('node') or name), **(parameters or {})}
    node_values = {**reliable_inputs, **values}
    expected = dict(expected or {t: bag.topics[t].count if t in bag.topics else 0
                                 for t in types})
    own_context = context is None and not isinstance(node, Node)
    if isinstance(node, Node):
        context = node.context
    elif own_context:
        context = rclpy.Context()
        rclpy.init(context=context)
    harness = Harness(context)
    received = Received(types)
    subscriptions = [
        harness.probe.create_subscription(
            message_class(kind), topic, lambda data, info, t=topic: received.add(t, data, info),
            replay_qos(bag.topics[topic].qos_profiles_yaml) if topic in bag.topics
            else matching_qos(True, False), raw=True)
        for topic, kind in types.items()]
    statuses = harness.diagnostics()
    player = harness.add(Player(bag, topics=inputs, context=context))
    process = None
    try:
        if player.skipped_types:
            raise ValueError(f'{bag.path}: cannot publish {player.skipped_types}')
        if isinstance(node, (str, list, tuple)):
            process = harness.watch(NodeProcess(node, node_values, name=name,
                                                log_dir=log_dir))
            process.start()
        elif isinstance(node, Node):
            harness.executor.add_node(node)
        else:
            harness.add(node(context=context, parameter_overrides=[
                Parameter(k, value=v) for k, v in node_values.items()]))
        harness.spin_until(
            lambda: all(p.get_subscription_count() >= 1
                        for p in player.publishers_by_topic.values())
            and all(s.get_publisher_count() >= 1 for s in subscriptions), connect_timeout,
            f'{name} to connect to {", ".join([*inputs, *types])}')
        _wait_for_writers(harness, statuses, list(types), connect_timeout)
        for topic in types:
            received.qos[topic] = qos_profiles_yaml(
                [i.qos_profile for i in harness.probe.get_publishers_info_by_topic(topic)])
        published = player.play(harness.executor, lockstep=True, ready=harness.check,
                                ack_timeout=timeout)
        timed_out = not _wait_for(harness, received, expected, timeout)
    finally:
        if process is not None:
            process.stop()
        if isinstance(node, Node):
            harness.executor.remove_node(node)
        harness.close()
        if own_context:
            rclpy.shutdown(context=context)
    verdict = compare_bags(bag, received, list(types))
    check = Check(verdict, tuple(types), bag.platform, fingerprint.fingerprint())
    return Replay(bag, name, inputs, types, values, published, received, check, timed_out,
                  process)


def _wait_for_writers(harness, statuses, outputs, timeout, first_status=5.0):
    """Spin until the node's writer of each output has matched a subscription.

    The probe's subscriptions see the node's writers before those writers have matched them,
    and what a writer publishes before its match is lost. Our nodes report their writers'
    matches on /diagnostics (``subscribers: /topic``, once a second); a node that has sent no
    status within ``first_status`` seconds is taken not to report them.
    """
    deadline = time.monotonic() + first_status
    while not statuses and time.monotonic() < deadline:
        harness.spin_once()
    keys = {subscribers_key(topic) for topic in outputs}

    def matched():
        return all(int(value) >= 1 for values in statuses.values()
                   for key, value in values.items() if key in keys)
    harness.spin_until(matched, timeout, "the node's writers to match this probe")


def _wait_for(harness, received, expected, timeout):
    """Spin until every output has its expected count; False if progress stops for timeout."""
    def counts():
        return tuple(received.count(t) for t in expected)

    deadline, seen = time.monotonic() + timeout, counts()
    while any(received.count(t) < n for t, n in expected.items()):
        harness.spin_once()
        if counts() != seen:
            deadline, seen = time.monotonic() + timeout, counts()
        elif time.monotonic() > deadline:
            return False
    # Take what has already arrived beyond the expected counts (a node that publishes more).
    for _ in range(100):
        before = counts()
        harness.executor.spin_once(timeout_sec=0)
        if counts() == before:
            break
    return True

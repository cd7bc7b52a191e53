"""What every node shares: QoS, parameter declaration and validation, diagnostics, main().

QoS: every publisher and subscription of the nodes goes through ``create_publisher`` /
``create_subscription`` below, which take a copy of the profile and declare rclpy's standard
``qos_overrides.<topic>.<publisher|subscription>.<history|depth|reliability>`` parameters
(read-only, set with ``--ros-args -p`` or a ``--params-file``). Input screening:
``InputGuard`` drops messages from a foreign publisher and stamps or frame indices that go
backwards, counted per kind on /diagnostics (NodeDiagnostics).
"""

from collections import Counter
from dataclasses import dataclass
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions

from microball_ros.core.errors import InputError, MicroballError

# Data path (positions, estimates, models; messages of at most a few kB): reliable, and deep
# enough that a burst of a minute at 30 fps is kept while a subscriber is busy
# (docs/design.md section 4): at most a few MB per endpoint.
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)

# Camera frames as published (bench_simulator, camera_source): reliable, so a reliable
# subscriber (lock-step replay, a recorder) gets every frame, but only two seconds deep at
# 30 fps: a 720 x 480 mono8 frame is 345 kB, and 2000 of them would hold 690 MB per endpoint.
IMAGE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=60,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)

# Camera frames as subscribed (camera_tracker). A best-effort subscription matches both
# best-effort publishers (camera drivers' sensor-data QoS: best effort, depth 5, such as
# v4l2_camera and usb_cam) and reliable ones (bench_simulator, camera_source), so it connects
# to any camera without configuration; a queue of 5 keeps at most 5 frames waiting (a tracker
# that falls behind skips frames instead of lagging further). Lock-step replay of frames
# (app/reprocess.py) needs every frame: it sets the subscription reliable and deeper through
# the qos_overrides parameters, e.g. for camera_tracker
#   qos_overrides./camera/image_raw.subscription.reliability: reliable
#   qos_overrides./camera/image_raw.subscription.depth: 60
IMAGE_SUBSCRIPTION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                                    reliability=ReliabilityPolicy.BEST_EFFORT,
                                    durability=DurabilityPolicy.VOLATILE)

# A publisher silent this long (wall clock) may be replaced by a new one that continues its
# sequence (InputGuard): a killed node restarted. Needed because the graph keeps a killed
# process's endpoints for Fast DDS's participant lease (20 s, measured), and Fast DDS reports
# no liveliness change to a subscription that requests no lease (ours request none, so they
# match every publisher).
TAKEOVER_SILENCE = 1.0

# The largest queue a QoS override may ask for (a typo such as depth 1e9 would exhaust memory).
MAX_DEPTH = 100000

# Latest-value topics (commands, models): late joiners get the last message.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


def copy_qos(profile):
    """Return an independent copy of a QoSProfile (rclpy's overrides modify the one given)."""
    return QoSProfile(**{slot[1:]: getattr(profile, slot[1:]) for slot in QoSProfile.__slots__})


def image_subscription_qos():
    """Return the QoS for subscribing to camera frames: best effort, depth 5.

    It matches sensor-data (best effort, depth 5) and reliable publishers alike, with a
    bounded queue; see IMAGE_SUBSCRIPTION_QOS for why, and for the qos_overrides parameters
    that make it reliable for lock-step replay. Create the subscription with
    ``create_subscription`` so those overrides apply.
    """
    return copy_qos(IMAGE_SUBSCRIPTION_QOS)


def check_qos(profile):
    """Return None if an (overridden) QoS profile is usable, else a one-line reason."""
    if profile.history == HistoryPolicy.KEEP_LAST and not 1 <= profile.depth <= MAX_DEPTH:
        return f'depth must be 1..{MAX_DEPTH} with history keep_last, got {profile.depth}'
    return None


def _overriding_options():
    def callback(profile):
        reason = check_qos(profile)
        return SetParametersResult(successful=reason is None, reason=reason or '')
    return QoSOverridingOptions.with_default_policies(callback=callback)


def _overridden(create, topic):
    """Call create(); turn a bad qos_overrides value into an InputError (exit 2)."""
    try:
        return create()
    except InvalidQosOverridesError as error:
        raise InputError(f'qos_overrides of {topic}: {error}') from None
    except RuntimeError as error:
        if 'QoS override' not in str(error):
            raise
        raise InputError(f'qos_overrides of {topic}: {error}') from None


def create_publisher(node, message_type, topic, qos):
    """Create a publisher with a copy of ``qos``, overridable by qos_overrides parameters."""
    profile = copy_qos(qos)
    return _overridden(lambda: node.create_publisher(
        message_type, topic, profile, qos_overriding_options=_overriding_options()), topic)


def create_subscription(node, message_type, topic, callback, qos, **kwargs):
    """Create a subscription with a copy of ``qos``, overridable by qos_overrides parameters."""
    profile = copy_qos(qos)
    return _overridden(lambda: node.create_subscription(
        message_type, topic, callback, profile, qos_overriding_options=_overriding_options(),
        **kwargs), topic)


def matching_qos(reliable, latched):
    """Return a data-path QoS that is reliable / transient local as asked (recorder, player)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DATA_QOS.depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                      else DurabilityPolicy.VOLATILE)


@dataclass(frozen=True)
class Param:
    """A parameter: default, description, and optional numeric range (inclusive)."""

    default: object
    description: str
    low: float = None
    high: float = None
    read_only: bool = False

    def descriptor(self, name):
        """Return the ParameterDescriptor of this parameter."""
        descriptor = ParameterDescriptor(name=name, description=self.description,
                                         read_only=self.read_only)
        if self.low is not None and isinstance(self.default, float):
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.low), to_value=float(self.high), step=0.0)]
        elif self.low is not None and isinstance(self.default, int) \
                and not isinstance(self.default, bool):
            descriptor.integer_range = [IntegerRange(
                from_value=int(self.low), to_value=int(self.high), step=0)]
        return descriptor


class NodeDiagnostics:
    """A node's health on /diagnostics (diagnostic_msgs/DiagnosticArray), once a period.

    The node calls ``received()`` for each input message it accepts, ``dropped(kind, detail)``
    for each it refuses (logged once per kind, then only counted), ``count(name)`` for other
    events (lost marks), and ``error(text)`` for a failure it survived. Each period one status
    is published: the input rate over the period, the totals, the drops per kind and the last
    error; level WARN while drops or errors are new in the period, else OK. rqt_robot_monitor
    and Foxglove's diagnostics panel show it. Wall-clock rate only: nothing downstream of a
    node's data depends on it (determinism: docs/design.md section 4).

    ``watch_output(publisher)`` adds ``subscribers: <topic>``, the subscriptions that output's
    writer has matched (a subscriber the writer has not matched yet gets nothing it publishes):
    how a lab sees that nothing listens, and how a test knows a node-to-node link is up.
    """

    def __init__(self, node, period=1.0, hardware_id=''):
        self._node = node
        self._outputs = []
        self._name = f'{node.get_namespace().rstrip("/")}/{node.get_name()}'.lstrip('/')
        self._hardware_id = hardware_id
        self._publisher = create_publisher(node, DiagnosticArray, '/diagnostics',
                                           QoSProfile(depth=10))
        self.received_total = 0
        self.drops = Counter()
        self.counts = Counter()
        self.last_error = ''
        self._received_at_last = 0
        self._problems_at_last = 0
        self._last_time = time.monotonic()
        # A steady clock: a node on simulated time (use_sim_time) reports before /clock runs,
        # which is when a launcher waits on the report (the matched subscriptions).
        node.create_timer(period, self.publish, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def received(self):
        """Count one accepted input message."""
        self.received_total += 1

    def dropped(self, kind, detail=''):
        """Count one refused input message; log the first of each kind."""
        if not self.drops[kind]:
            self._node.get_logger().warning(
                f'dropped {kind}{": " + detail if detail else ""} (logged once; see '
                '/diagnostics for the count)')
        self.drops[kind] += 1

    def watch_output(self, publisher):
        """Report the subscriptions ``publisher`` has matched in each status; return it."""
        self._outputs.append(publisher)
        return publisher

    def count(self, name, n=1):
        """Count another event (for example a lost mark)."""
        self.counts[name] += n

    def error(self, text, log=True):
        """Record a failure the node survived (logged each time, unless already logged)."""
        self.last_error = text
        if log:
            self._node.get_logger().error(text)
        self.counts['errors'] += 1

    def status(self):
        """Return the DiagnosticStatus of the period since the last call."""
        now = time.monotonic()
        rate = (self.received_total - self._received_at_last) / max(now - self._last_time, 1e-9)
        problems = sum(self.drops.values()) + self.counts['errors']
        new_problems = problems - self._problems_at_last
        self._received_at_last, self._problems_at_last = self.received_total, problems
        self._last_time = now
        values = {'rate': f'{rate:.3f}', 'received': str(self.received_total),
                  'dropped': str(sum(self.drops.values())), 'last error': self.last_error}
        values.update({f'dropped: {kind}': str(n) for kind, n in sorted(self.drops.items())})
        values.update({name: str(n) for name, n in sorted(self.counts.items())})
        values.update({subscribers_key(p.topic_name): str(p.get_subscription_count())
                       for p in self._outputs})
        level = DiagnosticStatus.WARN if new_problems else DiagnosticStatus.OK
        message = (f'{new_problems} dropped or failed in the last period' if new_problems
                   else 'ok')
        return DiagnosticStatus(level=level, name=self._name, message=message,
                                hardware_id=self._hardware_id,
                                values=[KeyValue(key=k, value=v) for k, v in values.items()])

    def publish(self):
        """Publish the status of the period (the timer's callback)."""
        array = DiagnosticArray(status=[self.status()])
        array.header.stamp = self._node.get_clock().now().to_msg()
        self._publisher.publish(array)


def subscribers_key(topic):
    """Return the /diagnostics key of an output's matched subscriptions (``watch_output``)."""
    return f'subscribers: /{topic.lstrip("/")}'


def diagnostic_values(array):
    """Return {status name: {key: value}} of a diagnostic_msgs/DiagnosticArray."""
    return {status.name: {kv.key: kv.value for kv in status.values} for status in array.status}


def stamp_nanoseconds(stamp):
    """Return a builtin_interfaces/Time as integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def non_finite(msg, fields):
    """Return the names of the float fields (scalars or sequences) of msg that are NaN or inf."""
    bad = []
    for name in fields:
        value = getattr(msg, name)
        values = value if hasattr(value, '__len__') else (value,)
        if not all(math.isfinite(v) for v in values):
            bad.append(name)
    return bad


class InputGuard:
    """One input topic of a node, screened: what a foreign or broken publisher sends is dropped.

    A subscription made by ``subscribe`` passes a message on to the node's callback only if
      * it comes from one of the ``expected`` publishers the node locked onto first (the graph
        may list more publishers: another rig on this ROS domain, whose messages are dropped
        as 'foreign publisher'; 0 accepts any number). A publisher that left the graph may be
        replaced by a new one (a restart: the sequence checks start afresh and ``on_restart``
        is called); so may one silent for TAKEOVER_SILENCE s (a killed node, which the graph
        lists for 20 s more) by a new one whose stamps continue its sequence;
      * ``check(msg)`` (the node's content check) returns None, else (kind, detail);
      * its header stamp is later than the last one ('stamp going backwards', 'duplicated
        stamp'; equal stamps pass with ``allow_equal_stamps``), and with ``frame_index`` its
        frame_index is larger than the last one ('frame index going backwards').
    Every drop is counted per kind in ``diagnostics`` (logged once per kind); every accepted
    message is counted as received. Only the take-over of a silent publisher looks at the wall
    clock, and only while the topic has more publishers than expected.
    """

    def __init__(self, node, diagnostics, topic, expected=1, check=None, frame_index=False,
                 allow_equal_stamps=False, on_restart=None):
        self._node = node
        self._diagnostics = diagnostics
        self.topic = node.resolve_topic_name(topic)
        self.expected = expected
        self._check = check
        self._frame_index = frame_index
        self._allow_equal = allow_equal_stamps
        self._on_restart = on_restart
        self._owned = {}            # publisher gid -> when it last sent (monotonic s)
        self._last_stamp = None
        self._last_index = None

    def subscribe(self, message_type, callback, qos):
        """Create the guarded subscription (overridable QoS); return it."""
        def on_message(msg, info):
            if self.accept(msg, info):
                callback(msg)
        return create_subscription(self._node, message_type, self.topic, on_message, qos)

    def _publisher_problem(self, gid, msg):
        if not self.expected or gid is None:
            return None
        now = time.monotonic()
        if gid in self._owned:
            self._owned[gid] = now
            return None
        restart = takeover = False
        if len(self._owned) >= self.expected:
            listed = {bytes(info.endpoint_gid)
                      for info in self._node.get_publishers_info_by_topic(self.topic)}
            gone = [g for g in self._owned if g not in listed]
            for g in gone:
                del self._owned[g]
            restart = bool(gone)
            if len(self._owned) >= self.expected:
                silent = min(self._owned, key=self._owned.get)
                if now - self._owned[silent] >= TAKEOVER_SILENCE \
                        and self._sequence_problem(msg) is None:
                    del self._owned[silent]
                    takeover = True
            if len(self._owned) >= self.expected:
                return ('foreign publisher', f'{len(listed)} publishers on {self.topic}, '
                        f'{self.expected} expected: another rig on this ROS domain?')
        self._owned[gid] = now
        if takeover:
            self._node.get_logger().info(f'{self.topic}: a new publisher continues the '
                                         'sequence of a silent one (restarted?)')
        elif restart:
            self._node.get_logger().info(f'{self.topic}: a new publisher replaces one that '
                                         'went away; its sequence starts afresh')
            self._last_stamp = self._last_index = None
            if self._on_restart is not None:
                self._on_restart()
        return None

    def _sequence_problem(self, msg):
        stamp = stamp_nanoseconds(msg.header.stamp)
        if self._last_stamp is not None:
            if stamp < self._last_stamp:
                return ('stamp going backwards', f'{stamp} ns after {self._last_stamp} ns')
            if stamp == self._last_stamp and not self._allow_equal:
                return ('duplicated stamp', f'{stamp} ns twice')
        if self._frame_index and self._last_index is not None \
                and msg.frame_index <= self._last_index:
            return ('frame index going backwards',
                    f'{msg.frame_index} after {self._last_index}')
        return None

    def accept(self, msg, info=None):
        """Return True if msg passes (and count it), else count the drop and return False."""
        gid = None
        if info and info.get('publisher_gid'):
            gid = bytes(info['publisher_gid']['data'])
        problem = self._publisher_problem(gid, msg)
        if problem is None and self._check is not None:
            problem = self._check(msg)
        if problem is None:
            problem = self._sequence_problem(msg)
        if problem is not None:
            self._diagnostics.dropped(*problem)
            return False
        self._last_stamp = stamp_nanoseconds(msg.header.stamp)
        if self._frame_index:
            self._last_index = msg.frame_index
        self._diagnostics.received()
        return True


def declare_parameters(node, params, validate):
    """Declare every Param of ``params`` (name -> Param) and guard changes with ``validate``.

    ``validate(values)`` is a pure function of the full name -> value mapping that returns
    None or a one-line reason; a change it rejects leaves the old values in place.
    Returns the current values as a dict.
    """
    for name, param in params.items():
        node.declare_parameter(name, param.default, param.descriptor(name))
    values = {name: node.get_parameter(name).value for name in params}
    reason = validate(values)
    if reason:
        raise InputError(f'{node.get_name()}: bad parameters: {reason}')

    def on_set(changes):
        proposed = {name: node.get_parameter(name).value for name in params}
        proposed.update({p.name: p.value for p in changes if p.name in params})
        problem = validate(proposed)
        return SetParametersResult(successful=problem is None, reason=problem or '')

    node.add_on_set_parameters_callback(on_set)
    return values


def run(node_class, args=None):
    """Create node_class, spin it until Ctrl-C or shutdown; return the exit status.

    0 after Ctrl-C or shutdown; 2 with one line on stderr for a bad parameter (one the node's
    validation refuses, or one of the wrong type or out of its declared range).
    Once a signal has shut the context down, an error from the teardown it interrupted (rclpy's
    shutdown races, ros2/rclpy#398: an RCLError about an invalid context or wait set) is part
    of the orderly stop, not a failure; before that, any error is a bug and propagates.
    """
    rclpy.init(args=args)
    node = None
    try:
        node = node_class()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (MicroballError, ParameterException) as error:
        print(f'{node_class.__name__}: error: {error}', file=sys.stderr)
        return 2
    except Exception:  # noqa: B902 - only a stop already under way excuses it
        if rclpy.ok():
            raise
    finally:
        _teardown(node)
    return 0


def _teardown(node):
    """Destroy the node and shut rclpy down; errors of a stop a signal began are expected."""
    try:
        if node is not None:
            node.destroy_node()
    except Exception:  # noqa: B902
        if rclpy.ok():
            raise
    finally:
        if rclpy.ok():
            rclpy.shutdown()

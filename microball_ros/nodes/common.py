"""What every node shares: QoS, parameter declaration and validation, diagnostics, main()."""

from collections import Counter
from dataclasses import dataclass
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
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from microball_ros.core.errors import InputError, MicroballError

# Data path: reliable, and deep enough that nothing is dropped at 30 fps even if a subscriber
# stalls for a minute (DESIGN.md section 4).
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)

# Latest-value topics (commands, models): late joiners get the last message.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


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
    """

    def __init__(self, node, period=1.0, hardware_id=''):
        self._node = node
        self._name = f'{node.get_namespace().rstrip("/")}/{node.get_name()}'.lstrip('/')
        self._hardware_id = hardware_id
        self._publisher = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.received_total = 0
        self.drops = Counter()
        self.counts = Counter()
        self.last_error = ''
        self._received_at_last = 0
        self._problems_at_last = 0
        self._last_time = time.monotonic()
        node.create_timer(period, self.publish)

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

    def count(self, name, n=1):
        """Count another event (for example a lost mark)."""
        self.counts[name] += n

    def error(self, text):
        """Record a failure the node survived (logged each time)."""
        self.last_error = text
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
    """
    rclpy.init(args=args)
    node = None
    try:
        node = node_class()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError as error:
        # rclpy's shutdown race (ros2/rclpy#398): a SIGINT or SIGTERM that invalidates the
        # context while the executor builds its wait set surfaces as an RCLError (a
        # RuntimeError) instead of ExternalShutdownException: an orderly stop all the same.
        if 'context' not in str(error) or 'not valid' not in str(error):
            raise
    except (MicroballError, ParameterException) as error:
        print(f'{node_class.__name__}: error: {error}', file=sys.stderr)
        return 2
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0

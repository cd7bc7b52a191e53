"""What every node shares: data-path QoS, parameter declaration and validation, main()."""

from dataclasses import dataclass
import sys

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

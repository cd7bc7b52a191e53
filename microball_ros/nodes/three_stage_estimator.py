"""three_stage_estimator: /tracking/positions -> /estimation/derivatives, one message a window.

Windows are whole numbers of stator periods (core.windowing); each gets velocity and
acceleration by the chosen method (three-stage by default) and the memory test
(core.memory.relative_memory_test). Invalid samples and frame gaps are never filled in: the
stretch around them is skipped with a logged reason (and counted as 'lost marks' on
/diagnostics). Input that no working tracker sends is dropped and counted per kind
(common.InputGuard): a position that is NaN or infinite but flagged valid, a stamp or frame
index that does not move forward, a message from a publisher beyond ``expected_publishers``.
"""

import sys

from microball_msgs.msg import DerivativeEstimate, TrackedPositions
from rclpy.node import Node
from std_msgs.msg import Header

from microball_ros.core import estimation, memory
from microball_ros.core.windowing import PositionWindower, Skip, WindowSettings
from microball_ros.io import conversions
from microball_ros.nodes.common import (
    DATA_QOS,
    InputGuard,
    NodeDiagnostics,
    Param,
    create_publisher,
    declare_parameters,
    non_finite,
    run,
)
from microball_ros.nodes.worker import OrderedWorker

PARAMS = {
    'method': Param('three-stage', 'derivative estimator: ' + ', '.join(estimation.METHODS)),
    'epsilon': Param(0.0, 'three-stage amplitude-filter threshold (fraction of the largest '
                          'component) of the published estimates; 0 keeps every component, '
                          "which the friction fit's intervals need (they assume the noise is "
                          'still there); the paper used 0.02-0.18', 0.0, 0.99),
    'exposure': Param(0.0, 'camera exposure time, s; the three-stage method undoes the '
                           'averaging of each frame over it (0: instantaneous samples)',
                      0.0, 1.0),
    'window_periods': Param(8.0, 'analysis window, stator periods', 4.0, 1000.0),
    'hop_periods': Param(4.0, 'advance between windows, stator periods', 0.1, 1000.0),
    'min_amplitude': Param(1e-5, 'stator amplitude below which a window is skipped, m',
                           0.0, 1.0),
    'frequency_tolerance': Param(0.02, 'relative frequency change that starts a new window',
                                 0.001, 0.5),
    'memory_k': Param(3.0, 'memory test: sigmas of phase uncertainty allowed', 0.0, 100.0),
    'memory_margin': Param(0.1, 'memory test: bias margin around pi, rad', 0.0, 3.1416),
    'expected_publishers': Param(1, 'publishers of tracking/positions this node accepts '
                                    'messages from (the first ones heard); more are another '
                                    "rig's, dropped; 0 accepts any number", 0, 100,
                                 read_only=True),
}


def position_problem(msg):
    """Return None, or (kind, detail) for a TrackedPositions no working tracker sends."""
    flagged = [name for name, valid in (('slider_position', msg.slider_valid),
                                        ('stator_position', msg.stator_valid)) if valid]
    bad = non_finite(msg, flagged)
    if bad:
        return ('NaN position', f'{", ".join(bad)} not finite but flagged valid '
                                f'(frame {msg.frame_index})')
    return None


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    if values['method'] not in estimation.METHODS:
        known = ', '.join(estimation.METHODS)
        return f"unknown method {values['method']!r}; choose one of {known}"
    return _settings(values).check()


def _settings(values):
    return WindowSettings(window_periods=values['window_periods'],
                          hop_periods=values['hop_periods'],
                          min_amplitude=values['min_amplitude'],
                          frequency_tolerance=values['frequency_tolerance'])


class ThreeStageEstimator(Node):
    """Estimate v_rel and a_slider per window of tracked positions; publish with the verdict."""

    def __init__(self, **kwargs):
        super().__init__('three_stage_estimator', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        self.add_post_set_parameters_callback(self._on_parameters_set)
        self._windower = PositionWindower(_settings(self._values))
        self._publisher = create_publisher(
            self, DerivativeEstimate, 'estimation/derivatives', DATA_QOS)
        self._worker = OrderedWorker('estimator', self._on_job_error)
        self.diagnostics = NodeDiagnostics(self)
        self.diagnostics.watch_output(self._publisher)
        self.guard = InputGuard(self, self.diagnostics, 'tracking/positions',
                                expected=self._values['expected_publishers'],
                                check=position_problem, frame_index=True,
                                on_restart=self._restart)
        self.guard.subscribe(TrackedPositions, self._on_positions, DATA_QOS)
        self.windows_published = 0

    def _restart(self):
        """Start the windows afresh: a new tracker replaced the old one."""
        self._windower = PositionWindower(_settings(self._values))

    def _on_parameters_set(self, parameters):
        self._values.update({p.name: p.value for p in parameters if p.name in PARAMS})
        if any(p.name in ('window_periods', 'hop_periods', 'min_amplitude',
                          'frequency_tolerance') for p in parameters):
            self._windower = PositionWindower(_settings(self._values))

    def _on_positions(self, msg):
        valid = msg.slider_valid and msg.stator_valid
        if not valid:
            self.diagnostics.count('lost marks')
        stamp = conversions.stamp_to_seconds(msg.header.stamp)
        for event in self._windower.push(stamp, msg.frame_index, msg.stator_position,
                                         msg.slider_position, valid):
            if isinstance(event, Skip):
                self.get_logger().info(f'skipped {event.count} samples: {event.reason}')
            else:
                header = Header(stamp=conversions.seconds_to_stamp(event.time[0]),
                                frame_id=msg.header.frame_id)
                values = dict(self._values)
                self._worker.submit(lambda w=event, h=header, v=values: self._analyse(w, h, v))

    def _analyse(self, window, header, values):
        options = ({'epsilon': values['epsilon'], 'exposure': values['exposure']}
                   if values['method'] == 'three-stage' else {})
        est, test = memory.relative_memory_test(
            window.time, window.stator_position, window.slider_position, values['method'],
            frequency=window.frequency, k=values['memory_k'], margin=values['memory_margin'],
            **options)
        self._publisher.publish(conversions.derivative_estimate(
            header, window, est, test, values['epsilon']))
        self.windows_published += 1

    def _on_job_error(self, job, error):
        self.diagnostics.error(f'window not analysed: {error}')

    def destroy_node(self):
        """Finish the queued windows, then destroy the node."""
        self._worker.stop()
        super().destroy_node()


def main(args=None):
    """Run the node (console script three_stage_estimator)."""
    return run(ThreeStageEstimator, args)


if __name__ == '__main__':
    sys.exit(main())

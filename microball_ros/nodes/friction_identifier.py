"""friction_identifier: /estimation/derivatives -> /friction/model, refitted as windows arrive.

Every window carries the positions it was estimated from; the node analyses the union of the
positions received so far with the one core pipeline (core.pipeline.analyze_windows) that
``microball analyze`` runs on a file, with the same policy and options (method, epsilon,
exposure): the same samples give the same model, intervals, memory verdict and warnings. The
model is validated as in the paper's Fig. 9, and the verdict and warnings travel with it.
"""

import sys

from microball_msgs.msg import DerivativeEstimate, FrictionModel
from rclpy.node import Node
from std_msgs.msg import Header

from microball_ros.core import pipeline
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
    'max_windows': Param(0, 'fit the newest N windows only; 0 keeps every window', 0, 1000000),
    'refit_every': Param(1, 'refit after every N new windows', 1, 10000),
    'memoryless_only': Param(False, 'fit only windows the memory test called memoryless'),
    'method': Param('three-stage', 'derivative method of the analysis: three-stage, forward '
                                   'or lowpass-forward', read_only=True),
    'epsilon': Param(-1.0, 'amplitude-filter threshold of the three-stage method; -1 (default) '
                           'takes the noise-adaptive threshold', -1.0, 0.99, read_only=True),
    'exposure': Param(0.0, 'camera exposure, s, whose averaging the analysis undoes', 0.0, 1.0,
                      read_only=True),
    'expected_publishers': Param(1, 'publishers of estimation/derivatives this node accepts '
                                    'messages from (the first ones heard); more are another '
                                    "rig's, dropped; 0 accepts any number", 0, 100,
                                 read_only=True),
}

ESTIMATE_ARRAYS = ('time', 'relative_velocity', 'slider_acceleration')
ESTIMATE_SCALARS = ('fundamental_frequency', 'phase_difference')


def estimate_problem(msg):
    """Return None, or (kind, detail) for a DerivativeEstimate no working estimator sends."""
    lengths = {name: len(getattr(msg, name)) for name in ESTIMATE_ARRAYS}
    if len(set(lengths.values())) != 1 or not lengths['time']:
        return ('malformed estimate', ', '.join(f'{k} {n}' for k, n in lengths.items()))
    bad = non_finite(msg, ESTIMATE_ARRAYS + ESTIMATE_SCALARS)
    if bad:
        return ('NaN estimate', f'{", ".join(bad)} not finite')
    return None


def check_parameters(values):
    """Return None if the parameter values are consistent, else a one-line reason."""
    if values['method'] not in pipeline.METHODS:
        return f"method must be one of {', '.join(pipeline.METHODS)}, got {values['method']!r}"
    return None


def pipeline_options(values):
    """Return the core pipeline's Options for the node's parameter values."""
    return pipeline.Options(method=values['method'],
                            epsilon=None if values['epsilon'] < 0 else values['epsilon'],
                            exposure=values['exposure'])


class FrictionIdentifier(Node):
    """Fit the friction model to every window received so far and publish it."""

    def __init__(self, **kwargs):
        super().__init__('friction_identifier', **kwargs)
        self._values = declare_parameters(self, PARAMS, check_parameters)
        self.add_post_set_parameters_callback(
            lambda ps: self._values.update({p.name: p.value for p in ps if p.name in PARAMS}))
        self._windows = []
        self._since_fit = 0
        self._publisher = create_publisher(self, FrictionModel, 'friction/model', DATA_QOS)
        self._worker = OrderedWorker('identifier', self._on_job_error)
        self.diagnostics = NodeDiagnostics(self)
        self.diagnostics.watch_output(self._publisher)
        self.guard = InputGuard(self, self.diagnostics, 'estimation/derivatives',
                                expected=self._values['expected_publishers'],
                                check=estimate_problem)
        self.guard.subscribe(DerivativeEstimate, self._on_estimate, DATA_QOS)

    def _on_estimate(self, msg):
        if self._values['memoryless_only'] and not msg.memoryless:
            self.get_logger().info('window with memory left out of the fit')
            return
        self._windows.append(msg)
        if self._values['max_windows']:
            del self._windows[:-self._values['max_windows']]
        self._since_fit += 1
        if self._since_fit >= self._values['refit_every']:
            self._since_fit = 0
            windows, values = list(self._windows), dict(self._values)
            self._worker.submit(lambda: self._fit(windows, values))

    def _fit(self, windows, values):
        arrays = [conversions.estimate_arrays(msg) for msg in windows]
        result = pipeline.analyze_windows([(t, stator, slider)
                                           for t, _, _, stator, slider in arrays],
                                          options=pipeline_options(values),
                                          source='estimation/derivatives')
        newest = windows[-1]
        header = Header(stamp=newest.header.stamp, frame_id=newest.header.frame_id)
        self._publisher.publish(conversions.friction_model(header, result, len(windows)))

    def _on_job_error(self, job, error):
        self.diagnostics.error(f'fit failed: {error}')

    def destroy_node(self):
        """Finish the queued fits, then destroy the node."""
        self._worker.stop()
        super().destroy_node()


def main(args=None):
    """Run the node (console script friction_identifier)."""
    return run(FrictionIdentifier, args)


if __name__ == '__main__':
    sys.exit(main())

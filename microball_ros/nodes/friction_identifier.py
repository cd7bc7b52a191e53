"""friction_identifier: /estimation/derivatives -> /friction/model, refitted as windows arrive.

Accumulates the (v_rel, a_slider) samples of every window (across sweep frequencies), fits the
Langevin law by least squares with profile-likelihood intervals (core.friction), and validates
it as in the paper's Fig. 9 by simulating the slider under the stator motion of the newest
window. Estimates no working estimator sends are dropped and counted per kind on /diagnostics
(common.InputGuard): arrays of different lengths or with NaN or infinite values, a stamp that
does not move forward, a message from a publisher beyond ``expected_publishers``.
"""

import sys

from microball_msgs.msg import DerivativeEstimate, FrictionModel
import numpy as np
from rclpy.node import Node
from std_msgs.msg import Header

from microball_ros.core import friction
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
    'validation_step': Param(0.001, 'RK4 step of the Fig. 9 validation, s', 1e-5, 0.01),
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
    """Return None: the ranges of the descriptors are the only constraints."""
    return None


def unique_samples(arrays):
    """Return (v_rel, a_slider) with every time stamp once (the first window's estimate).

    Windows overlap when the hop is shorter than the window; counting a sample twice would
    shrink the intervals by a factor up to sqrt(window / hop) for no new information.
    """
    time = np.concatenate([a[0] for a in arrays])
    _, first = np.unique(np.round(time * 1e9).astype(np.int64), return_index=True)
    first.sort()
    return (np.concatenate([a[1] for a in arrays])[first],
            np.concatenate([a[2] for a in arrays])[first])


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
        v, a = unique_samples(arrays)
        fit = friction.fit_least_squares(v, a, 'langevin')
        newest, (time, _, _, stator, slider) = windows[-1], arrays[-1]
        validation = friction.validate(fit.law, time, stator, slider,
                                       newest.fundamental_frequency,
                                       dt=values['validation_step'])
        header = Header(stamp=newest.header.stamp, frame_id=newest.header.frame_id)
        self._publisher.publish(conversions.friction_model(header, fit, validation,
                                                           len(windows)))

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

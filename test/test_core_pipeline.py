"""core.pipeline: one analysis for analyze and the identifier node, whole records, verdicts.

Records come from an independent model written here (not core.bench): the slider ODE
a = -F(v_rel) (or a first-order lag of it) integrated by scipy's solve_ivp (RK45, tight
tolerances) under a pure sinusoidal stator, sampled at the frame times.
"""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from microball_ros.core import estimation, pipeline
from microball_ros.core.windowing import PositionWindower, Window


def _langevin(v, A=1.2, alpha=110.0):
    x = alpha * v
    small = np.abs(x) < 1e-3
    safe = np.where(small, 1.0, x)
    return A * np.where(small, x / 3, 1 / np.tanh(safe) - 1 / safe)


def _record(duration, *, fps=30.0, frequency=2.95, amplitude=1.2e-3, noise=2e-6, tau=0.0,
            law=_langevin, seed=0):
    """Independent rig: stator X sin(w t); slider a = -F, F = law(v_rel) or lagged by tau."""
    w = 2 * math.pi * frequency

    def rhs(t, y):
        v_rel = y[1] - amplitude * w * math.cos(w * t)
        force = y[2] if tau else law(np.array([v_rel]))[0]
        dforce = (law(np.array([v_rel]))[0] - y[2]) / tau if tau else 0.0
        return [y[1], -force, dforce]

    settle = 3.0
    t = np.arange(int(duration * fps)) / fps
    solution = solve_ivp(rhs, (-settle, t[-1]), [0.0, 0.0, 0.0], t_eval=t, rtol=1e-10,
                         atol=1e-13, max_step=2e-3)
    rng = np.random.default_rng(seed)
    stator = amplitude * np.sin(w * t) + rng.normal(0, noise, t.size)
    slider = solution.y[0] + rng.normal(0, noise, t.size)
    return t, stator, slider


def _node_windows(t, stator, slider, epsilon=0.0):
    """Cut positions as the estimator node does; return what its messages carry."""
    windower = PositionWindower()
    out = []
    for k in range(t.size):
        for event in windower.push(t[k], k, stator[k], slider[k]):
            if isinstance(event, Window):
                est = estimation.estimate_relative(event.time, event.stator_position,
                                                   event.slider_position, epsilon=epsilon,
                                                   fundamental=event.frequency)
                out.append((event.time[est.index], event.stator_position[est.index],
                            event.slider_position[est.index]))
    return out


def test_the_node_entry_point_gives_the_numbers_analyze_gives():
    t, stator, slider = _record(30.0)
    windows = _node_windows(t, stator, slider)
    node = pipeline.analyze_windows(windows)
    stamps = np.unique(np.concatenate([w[0] for w in windows]))
    keep = np.isin(t, stamps)
    direct = pipeline.analyze_positions(t[keep], stator[keep], slider[keep])
    assert node.samples_used == direct.samples_used
    assert node.fit.params == direct.fit.params
    assert node.fit.ci95 == direct.fit.ci95
    assert node.loop == direct.loop
    assert node.memory_verdict == direct.memory_verdict == 'memoryless'
    # The windows cover all but the record's tail: the union is nearly the whole record.
    assert keep.mean() > 0.85


def test_every_sample_is_used_and_intervals_shrink_as_one_over_root_n():
    widths, used = [], []
    for duration in (20.0, 80.0):
        t, stator, slider = _record(duration, seed=3)
        result = pipeline.analyze_positions(t, stator, slider)
        assert result.samples_used / result.samples_total >= 0.99
        lo, hi = result.fit.ci95['A']
        assert lo < 1.2 < hi
        widths.append(hi - lo)
        used.append(result.samples_used)
    # 4x the samples: half the width, within the spread of one seed's interval estimate.
    assert widths[0] / widths[1] == pytest.approx(math.sqrt(used[1] / used[0]), rel=0.3)


@pytest.mark.parametrize('name, law, tau, verdict', [
    ('paper Langevin', _langevin, 0.0, 'memoryless'),
    ('saturating Langevin alpha 2000', lambda v: _langevin(v, 1.2, 2000.0), 0.0,
     'memoryless'),
    ('lag 10 ms', _langevin, 0.010, 'memory'),
    ('lag 40 ms', _langevin, 0.040, 'memory'),
])
def test_the_loop_test_is_right_for_saturating_laws_and_catches_lags(name, law, tau, verdict):
    t, stator, slider = _record(20.0, law=law, tau=tau)
    result = pipeline.analyze_positions(t, stator, slider)
    assert result.memory_verdict == verdict, (name, result.loop)
    if tau:
        # For a lag the statistic is about atan(w tau).
        expected = math.atan(2 * math.pi * 2.95 * tau)
        assert result.loop.statistic == pytest.approx(expected, rel=0.15)
        assert result.dynamic_model is not None


def test_gaps_duplicates_and_jitter_are_analysed_with_a_gaps_warning():
    t, stator, slider = _record(20.0, seed=5)
    rng = np.random.default_rng(1)
    keep = np.ones(t.size, dtype=bool)
    keep[200:215] = False  # a 0.5 s gap
    keep[rng.choice(np.arange(20, t.size - 20), 6, replace=False)] = False  # dropped frames
    stamps = t + rng.uniform(-1e-3, 1e-3, t.size)  # jittered stamps, positions on the grid
    stamps[400] = stamps[399]  # a duplicated stamp
    clean = pipeline.analyze_positions(t, stator, slider)
    messy = pipeline.analyze_positions(stamps[keep], stator[keep], slider[keep])
    assert 'gaps' in {code for code, _ in messy.warnings}
    assert not [code for code, _ in clean.warnings if code == 'gaps']
    assert messy.samples_used / messy.samples_total >= 0.9
    assert messy.memory_verdict == 'memoryless'
    lo, hi = messy.fit.ci95['A']
    assert lo < 1.2 < hi
    # A and alpha trade off along their valley; their product (the slope at 0) is sharp.
    def slope(result):
        return result.fit.params['A'] * result.fit.params['alpha'] / 3

    assert slope(messy) == pytest.approx(slope(clean), rel=0.01)
    assert slope(messy) == pytest.approx(44.0, rel=0.02)


def test_a_linear_record_is_reported_as_its_viscous_limit():
    t, stator, slider = _record(20.0, law=lambda v: 30.0 * v)
    result = pipeline.analyze_positions(t, stator, slider)
    assert 'degenerate' in {code for code, _ in result.warnings}
    c, (lo, hi) = result.viscous_limit
    assert lo < 30.0 < hi and math.isfinite(hi)
    assert c == pytest.approx(30.0, rel=0.02)


def test_near_nyquist_is_warned_and_not_called_memoryless():
    t, stator, slider = _record(20.0, fps=15.0, frequency=4.9, amplitude=0.8e-3)
    result = pipeline.analyze_positions(t, stator, slider)
    assert 'near-nyquist' in {code for code, _ in result.warnings}
    assert result.memory_verdict == 'undetermined'


def test_every_sample_of_a_run_is_estimated_when_both_passes_pick_half_of_it():
    """A run whose two whole-period windows leave its middle out is estimated everywhere.

    253 samples at 30 fps, 2.95 Hz: from either end three_stage picks 12 whole periods (the
    best fit to the sampling), leaving 7 samples in the middle to a third pass; they were left
    unset once (whatever memory held: a fit-failed or a wrong 'saturated' on a gapped record).
    Viscous friction c: the steady slider is analytic, G X sin(w t - phi), G = c / |c + i w|.
    """
    c, amplitude, frequency = 44.0, 1.2e-3, 2.95
    t, stator, slider = _record(253 / 30, law=lambda v: c * v, noise=0.0)
    assert t.size == 253
    result = pipeline.analyze_positions(t, stator, slider)
    w = 2 * math.pi * frequency
    gain, lag = c / math.hypot(c, w), math.atan2(w, c)
    time = result.estimate.time
    v_rel = amplitude * w * (gain * np.cos(w * time - lag) - np.cos(w * time))
    a_slid = -amplitude * w ** 2 * gain * np.sin(w * time - lag)
    assert result.samples_used == 251
    # Noise-free: the three-stage estimates are within 1 % of the peaks at every sample.
    assert np.max(np.abs(result.velocity_for_fit - v_rel)) < 0.01 * np.max(np.abs(v_rel))
    assert np.max(np.abs(result.fit_acceleration - a_slid)) < 0.01 * np.max(np.abs(a_slid))
    viscous = next(entry for entry in result.comparison if entry.name == 'viscous')
    assert viscous.fit.params['c'] == pytest.approx(c, rel=0.01)


@pytest.mark.parametrize('seed', [0, 2, 3])
def test_intervals_cover_at_ten_frames_per_period(seed):
    """Intervals hold the truth at 10 frames per period, unwarned.

    15 fps, 1.5 Hz, 2.4 mm, 2 um (issue 13): the curvature of the Langevin law rests on
    v_rel's third harmonic (0.4 % of its fundamental), under the filter's noise floor. Dropped,
    it put A 40 to 60 % high with intervals that missed the truth in 5 of 6 seeds; kept (every
    harmonic bin), its noise is coherent over the record and its variance is added to the
    intervals. No warning is due here, and both intervals hold the truth without being vacuous.
    (Seed 1 reaches only alpha max|v_rel| = 0.5 by its estimate and is warned 'degenerate'.)
    """
    t, stator, slider = _record(20.0, fps=15.0, frequency=1.5, amplitude=2.4e-3, seed=seed)
    result = pipeline.analyze_positions(t, stator, slider)
    assert [code for code, _ in result.warnings] == []
    for name, truth in (('A', 1.2), ('alpha', 110.0)):
        lo, hi = result.fit.ci95[name]
        assert lo <= truth <= hi, (name, result.fit.params[name], lo, hi)
        assert hi / lo < 3.0


def test_a_fit_biased_by_the_velocity_noise_is_warned():
    """A nearly linear law bent by the noise in v_rel is warned 'noise-bias'.

    15 fps, 0.5 Hz, 3 mm, 5 um (alpha max|v_rel| ~ 0.1): A 0.06 [0.05, 0.08], alpha 2400 for
    1.2 and 110, intervals that miss. Refitted with the noise doubled, the estimates move by
    more than their intervals.
    """
    t, stator, slider = _record(60.0, fps=15.0, frequency=0.5, amplitude=3e-3, noise=5e-6)
    result = pipeline.analyze_positions(t, stator, slider)
    lo, hi = result.fit.ci95['A']
    assert not lo <= 1.2 <= hi  # the bias the warning is for
    assert 'noise-bias' in {code for code, _ in result.warnings}


def test_the_frame_period_of_epoch_stamps_does_not_depend_on_their_offset():
    # The least-squares line through the stamps is fitted to the time since the first one:
    # through 1.7e9 s stamps its slope was off by 1e-7 of dt (and CPU-dependent).
    from microball_ros.core.timebase import regularise

    frames = np.arange(61)
    stamps_ns = 1_700_000_000_708_333_333 + np.round(frames * 1e9 / 30).astype(np.int64)
    epoch_stamps = stamps_ns * 1e-9  # 1.7e9 s as doubles: quantised to 2.4e-7 s
    x = 1e-3 * np.sin(2 * np.pi * 2.95 * frames / 30)
    epoch = regularise(epoch_stamps, x, 0.5 * x)
    near = regularise(epoch_stamps - epoch_stamps[0], x, 0.5 * x)  # the same stamps, exactly
    assert epoch.dt == pytest.approx(near.dt, rel=1e-13)
    assert near.dt == pytest.approx(1 / 30, rel=1e-7)  # the stamps' quantisation

"""Friction laws, RK4 integration, identification and validation against analytic answers."""

import decimal
import math

import numpy as np
import pytest

from microball_ros.core import friction
from microball_ros.core.friction import (
    STATIC_LAWS,
    CoulombViscous,
    LaggedFriction,
    Langevin,
    LuGre,
    Stribeck,
    Viscous,
    compare_laws,
    fit_least_squares,
    fit_sinusoid,
    fit_two_slope,
    integrate_rk4,
    langevin,
    langevin_slope,
    simulate_slider,
    validate,
)

A, ALPHA = 1.2, 110.0
FREQUENCY = 2.95
W = 2 * math.pi * FREQUENCY
X_STATOR = 1.2e-3


def _reference_unit_langevin(x, digits=60):
    """Return coth(x) - 1/x in 60-digit decimal arithmetic (cancellation costs < 20 digits)."""
    with decimal.localcontext() as context:
        context.prec = digits
        x = decimal.Decimal(x)
        e2 = (2 * x).exp()
        return (e2 + 1) / (e2 - 1) - 1 / x


def _reference_unit_slope(x, digits=60):
    """Return 1/x^2 - 1/sinh(x)^2 in 60-digit decimal arithmetic."""
    with decimal.localcontext() as context:
        context.prec = digits
        x = decimal.Decimal(x)
        sinh = (x.exp() - (-x).exp()) / 2
        return 1 / (x * x) - 1 / (sinh * sinh)


def _exact_product(alpha, v):
    """Return alpha * v exactly, as a Decimal (the reference sees the same float inputs)."""
    return decimal.Decimal(alpha) * decimal.Decimal(v)


# --- the modified Langevin function ------------------------------------------------------------

def test_langevin_matches_the_papers_exponential_formula_away_from_zero():
    v = np.concatenate([np.linspace(0.01, 0.3, 50), -np.linspace(0.01, 0.3, 50)])
    x = ALPHA * v
    printed = A * ((np.exp(x) + np.exp(-x)) / (np.exp(x) - np.exp(-x)) - 1 / x)
    np.testing.assert_allclose(langevin(v, A, ALPHA), printed, rtol=1e-14)


@pytest.mark.parametrize('x', np.concatenate([
    np.logspace(-8, -2, 13), [0.1, 0.5, np.nextafter(1.0, 0.0), 1.0, np.nextafter(1.0, 2.0)],
    [1.5, 2.0, 5.0, 20.0]]))
def test_langevin_is_accurate_to_a_few_ulps_near_and_away_from_zero(x):
    v = x / ALPHA
    reference = float(_reference_unit_langevin(_exact_product(ALPHA, v)))
    assert langevin(v, 1.0, ALPHA) == pytest.approx(reference, rel=1e-15, abs=0)
    slope_reference = float(_reference_unit_slope(_exact_product(ALPHA, v)))
    assert langevin_slope(v, 1.0, ALPHA) / ALPHA == pytest.approx(slope_reference, rel=2e-15,
                                                                   abs=0)


def test_langevin_is_odd_zero_at_zero_and_has_the_viscous_and_saturation_limits():
    v = np.linspace(-0.05, 0.05, 1001)
    np.testing.assert_array_equal(langevin(-v, A, ALPHA), -langevin(v, A, ALPHA))
    assert langevin(0.0, A, ALPHA) == 0.0
    assert langevin_slope(0.0, A, ALPHA) == pytest.approx(A * ALPHA / 3, rel=1e-15)
    assert langevin(1e-9, A, ALPHA) == pytest.approx(A * ALPHA * 1e-9 / 3, rel=1e-12)
    # coth(x) - 1/x = 1 - 1/x + O(exp(-2x)), and the slope is 1/x^2, at large x.
    for sign in (1, -1):
        assert langevin(sign * 100.0, A, ALPHA) == pytest.approx(
            sign * A * (1 - 1 / (ALPHA * 100.0)), rel=1e-15)
    assert langevin_slope(100.0, A, ALPHA) == pytest.approx(A / (ALPHA * 100.0 ** 2), rel=1e-12)


def test_langevin_does_not_overflow_and_keeps_scalars_scalar():
    with np.errstate(over='raise', divide='raise', invalid='raise'):
        huge = langevin(np.array([-1e6, 1e6]), A, ALPHA)
        slope = langevin_slope(np.array([-1e6, 0.0, 1e6]), A, ALPHA)
    np.testing.assert_allclose(huge, [-A, A], rtol=1e-7)
    assert np.all(np.isfinite(slope)) and slope[1] == pytest.approx(A * ALPHA / 3)
    assert isinstance(langevin(0.003, A, ALPHA), float)
    assert langevin(np.zeros((2, 3)), A, ALPHA).shape == (2, 3)


def test_langevin_slope_matches_a_numerical_derivative():
    v = np.linspace(-0.04, 0.04, 161)
    h = 1e-7
    numerical = (langevin(v + h, A, ALPHA) - langevin(v - h, A, ALPHA)) / (2 * h)
    np.testing.assert_allclose(langevin_slope(v, A, ALPHA), numerical, rtol=1e-7)


# --- the laws ---------------------------------------------------------------------------------

@pytest.mark.parametrize('law', [cls() for cls in STATIC_LAWS.values()], ids=list(STATIC_LAWS))
def test_force_gradient_is_the_derivative_in_each_fitted_parameter(law):
    # The fits use these as analytic Jacobians; check them against central differences,
    # across and beyond the paper's velocities (|alpha v| up to 3.3 for the Langevin law).
    v = np.linspace(-0.03, 0.03, 241)
    gradient = law.force_gradient(v)
    assert len(gradient) == len(law.fit_parameters)
    for name, analytic in zip(law.fit_parameters, gradient, strict=True):
        value = law.params[name]
        h = 1e-6 * value
        up = type(law)(**{**law.params, name: value + h}).force(v)
        down = type(law)(**{**law.params, name: value - h}).force(v)
        np.testing.assert_allclose(analytic, (up - down) / (2 * h), rtol=1e-6,
                                   atol=1e-9 * np.abs(law.force(v)).max() / value)


@pytest.mark.parametrize('law', [cls() for cls in STATIC_LAWS.values()], ids=list(STATIC_LAWS))
def test_static_laws_share_the_interface_are_odd_and_oppose_sliding(law):
    v = np.linspace(-0.03, 0.03, 301)
    force = law.force(v)
    np.testing.assert_allclose(law.force(-v), -force, rtol=1e-13, atol=1e-15)
    assert np.all(force[v > 0] > 0)
    np.testing.assert_array_equal(law.acceleration(v), -force)
    assert law.n_states == 0 and law.initial_state().shape == (0,)
    assert law.state_derivative(law.initial_state(), 0.004).shape == (0,)
    assert law.acceleration_from_state(law.initial_state(), 0.004) == pytest.approx(
        -law.force(0.004), rel=1e-15)
    assert set(law.fit_parameters) <= set(law.params)
    assert STATIC_LAWS[law.name] is type(law)


def test_static_laws_evaluate_their_formulas():
    v = 0.01
    assert Viscous(30.0).force(v) == pytest.approx(0.3)
    assert friction.Coulomb(0.4, 1e-3).force(v) == pytest.approx(0.4 * math.tanh(10.0))
    assert CoulombViscous(0.1, 25.0, 1e-3).force(v) == pytest.approx(0.1 * math.tanh(10) + 0.25)
    stribeck = Stribeck(Fc=0.1, Fs=0.3, vs=0.005, c=20.0, v_smooth=1e-3)
    assert stribeck.force(v) == pytest.approx(
        (0.1 + 0.2 * math.exp(-4.0)) * math.tanh(10.0) + 0.2)


def test_laws_reject_non_positive_parameters():
    with pytest.raises(ValueError, match='alpha'):
        Langevin(1.2, -1.0)
    with pytest.raises(ValueError, match='v_smooth'):
        CoulombViscous(0.1, 25.0, 0.0)
    with pytest.raises(ValueError, match='tau'):
        LaggedFriction(Langevin(), 0.0)


def _settle_state(law, v_rel, duration=20.0, dt=1e-3):
    """Integrate the law's own state at a constant v_rel by explicit Euler; return the state."""
    state = law.initial_state()
    for _ in range(int(duration / dt)):
        state = state + dt * law.state_derivative(state, v_rel)
    return state


@pytest.mark.parametrize('v_rel', [-0.008, 0.001, 0.02])
def test_laws_with_memory_settle_to_their_steady_state_force(v_rel):
    lugre = LuGre()
    z = _settle_state(lugre, v_rel)
    g = lugre.Fc + (lugre.Fs - lugre.Fc) * math.exp(-(v_rel / lugre.vs) ** 2)
    assert z[0] == pytest.approx(math.copysign(g / lugre.sigma0, v_rel), rel=1e-6)
    assert lugre.acceleration_from_state(z, v_rel) == pytest.approx(-lugre.force(v_rel),
                                                                   rel=1e-6)
    lagged = LaggedFriction(Langevin(A, ALPHA), 0.035)
    F = _settle_state(lagged, v_rel)
    assert lagged.acceleration_from_state(F, v_rel) == pytest.approx(
        -langevin(v_rel, A, ALPHA), rel=1e-9)
    assert lagged.name == 'lagged_langevin' and lagged.params['tau'] == 0.035


def _steady_run(law, duration=6.0, dt=1e-3):
    """Drive the slider with the paper's stator X sin(w t); return t, states, v_rel, a (t > 3)."""
    n = round(duration / dt)
    half_steps = 0.5 * dt * np.arange(2 * n + 1)
    stator_velocity = X_STATOR * W * np.cos(W * half_steps)
    states = integrate_rk4(law, np.r_[0.0, X_STATOR * W, law.initial_state()], stator_velocity,
                           dt)
    t = half_steps[::2]
    v_rel = states[:, 1] - X_STATOR * W * np.cos(W * t)
    a = np.array([law.acceleration_from_state(state[2:], v)
                  for state, v in zip(states, v_rel, strict=True)])
    late = t > 3.0
    return t[late], states[late], v_rel[late], a[late]


def _fundamental_phase_difference(t, a, v):
    _, phase_a = fit_sinusoid(t, a, FREQUENCY)
    _, phase_v = fit_sinusoid(t, v, FREQUENCY)
    return math.remainder(phase_a - phase_v, 2 * math.pi)


def test_memory_shows_as_a_phase_offset_between_acceleration_and_relative_velocity():
    # docs/paper.md section 2: pi for a memoryless law. The lag adds atan(w tau) (up to the small
    # harmonics of v_rel); LuGre's presliding memory shifts it the other way.
    t, _, v_rel, a = _steady_run(Langevin(A, ALPHA))
    assert math.pi - abs(_fundamental_phase_difference(t, a, v_rel)) < 1e-3
    t, _, v_rel, a = _steady_run(LaggedFriction(Langevin(A, ALPHA), 0.035))
    lagged = _fundamental_phase_difference(t, a, v_rel)
    assert math.pi - abs(lagged) == pytest.approx(math.atan(W * 0.035), abs=0.01)
    t, _, v_rel, a = _steady_run(LuGre())
    assert math.pi - abs(_fundamental_phase_difference(t, a, v_rel)) > 0.2


# --- RK4 --------------------------------------------------------------------------------------

def _viscous_exact(c, t, v0):
    """Return slider (x, v) for v' = -c (v - V cos(w t)), x(0) = 0, v(0) = v0, V = X w."""
    V = X_STATOR * W
    gain, lag = c / math.hypot(c, W), math.atan2(W, c)
    steady_v = V * gain * np.cos(W * t - lag)
    steady_x = X_STATOR * gain * np.sin(W * t - lag)
    transient = (v0 - V * gain * math.cos(lag)) * np.exp(-c * t)
    x = steady_x - X_STATOR * gain * math.sin(-lag) + (v0 - V * gain * math.cos(lag)) * (
        1 - np.exp(-c * t)) / c
    return x, steady_v + transient


def test_rk4_matches_the_analytic_viscous_response_with_fourth_order_convergence():
    c = 44.0
    errors = []
    for dt in (2e-3, 1e-3):
        n = round(3.0 / dt)
        half_steps = 0.5 * dt * np.arange(2 * n + 1)
        states = integrate_rk4(Viscous(c), [0.0, 0.0],
                               X_STATOR * W * np.cos(W * half_steps), dt)
        x, v = _viscous_exact(c, half_steps[::2], 0.0)
        errors.append(np.abs(states[:, 1] - v).max() / (X_STATOR * W))
        np.testing.assert_allclose(states[:, 0], x, rtol=0, atol=1e-5 * X_STATOR)
    assert errors[1] < 1e-5
    assert 12 < errors[0] / errors[1] < 20  # 2^4 = 16


def test_rk4_steady_amplitude_and_phase_match_the_analytic_first_order_system():
    c = 44.0
    t, states, _, _ = _steady_run(Viscous(c))
    amplitude, phase = fit_sinusoid(t, states[:, 0], FREQUENCY)
    assert amplitude == pytest.approx(X_STATOR * c / math.hypot(c, W), rel=1e-5)
    assert -phase == pytest.approx(math.atan2(W, c), rel=1e-5)


def test_rk4_rejects_inconsistent_inputs():
    with pytest.raises(ValueError, match='half step'):
        integrate_rk4(Viscous(), [0.0, 0.0], np.zeros(4), 1e-3)
    with pytest.raises(ValueError, match='needs 3'):
        integrate_rk4(LuGre(), [0.0, 0.0], np.zeros(5), 1e-3)


def test_simulate_slider_from_sampled_stator_positions_matches_the_analytic_response():
    c = 44.0
    t = np.arange(0, 10, 1 / 30)
    simulated = simulate_slider(Viscous(c), t, X_STATOR * np.sin(W * t), run_in=2 / FREQUENCY)
    gain, lag = c / math.hypot(c, W), math.atan2(W, c)
    exact = X_STATOR * gain * np.sin(W * t - lag)
    amplitude, phase = fit_sinusoid(t, simulated, FREQUENCY)
    # The spline through 30 frames/s costs a few 1e-4 of amplitude, nothing at the fundamental.
    assert amplitude == pytest.approx(X_STATOR * gain, rel=5e-4)
    assert -phase == pytest.approx(lag, abs=5e-4)
    offset = np.mean(simulated - exact)
    assert np.abs(simulated - exact - offset).max() < 3e-3 * X_STATOR * gain
    with pytest.raises(ValueError, match='run_in'):
        simulate_slider(Viscous(c), t, X_STATOR * np.sin(W * t), run_in=20.0)


# --- identification ---------------------------------------------------------------------------

def _samples(law, v_max, n=1000, noise=0.1, seed=1):
    """Return (v_rel, a_slid): v_rel of a sinusoid at random phases, a with white noise."""
    rng = np.random.default_rng(seed)
    v = v_max * np.sin(rng.uniform(0, 2 * math.pi, n))
    return v, law.acceleration(v) + noise * rng.standard_normal(n)


def test_least_squares_recovers_langevin_spanning_saturation_with_honest_intervals():
    v, a = _samples(Langevin(A, ALPHA), v_max=0.04)
    fit = fit_least_squares(v, a, 'langevin')
    assert fit.name == 'langevin' and fit.n == 1000
    assert fit.params['A'] == pytest.approx(A, rel=0.05)
    assert fit.params['alpha'] == pytest.approx(ALPHA, rel=0.05)
    for name, truth in (('A', A), ('alpha', ALPHA)):
        low, high = fit.ci95[name]
        assert low < truth < high and high / low < 1.2
    assert fit.identifiable
    assert fit.rmse == pytest.approx(0.1, rel=0.1)
    assert isinstance(fit.law, Langevin) and fit.law.A == fit.params['A']
    assert fit.covariance.shape == (2, 2) and fit.correlation[0, 0] == pytest.approx(1.0)


def test_least_squares_in_the_papers_regime_flags_a_alpha_trade_off_but_gets_the_slope():
    v, a = _samples(Langevin(A, ALPHA), v_max=0.009, noise=0.05)
    fit = fit_least_squares(v, a, 'langevin')
    assert abs(fit.correlation[0, 1]) > 0.9
    low, high = fit.ci95['alpha']
    assert low < ALPHA < high and high > 2 * low  # wide: alpha v <= 1 shows little curvature
    low, high = fit.ci95['A']
    assert low < A < high and high > 2 * low
    slope = fit.params['A'] * fit.params['alpha'] / 3
    assert slope == pytest.approx(A * ALPHA / 3, rel=0.05)


def test_profile_interval_reports_inf_when_the_data_cannot_bound_a_parameter():
    # Purely viscous data: any large A with alpha = 3 c / A fits as well, so A has no upper end.
    v, a = _samples(Viscous(44.0), v_max=0.005, noise=0.05)
    fit = fit_least_squares(v, a, 'langevin')
    assert fit.ci95['A'][1] == math.inf and fit.ci95['alpha'][0] == 0.0
    assert not fit.identifiable


def test_two_slope_method_recovers_a_and_alpha_from_clean_data():
    v = np.linspace(-0.025, 0.025, 2001)
    result = fit_two_slope(v, Langevin(A, ALPHA).acceleration(v), v1=0.015)
    assert result.A == pytest.approx(A, rel=0.01)
    assert result.alpha == pytest.approx(ALPHA, rel=0.01)
    assert result.slope0 == pytest.approx(A * ALPHA / 3, rel=1e-3)
    assert result.slope1 == pytest.approx(langevin_slope(0.015, A, ALPHA), rel=0.01)
    assert result.law == Langevin(result.A, result.alpha)


def test_two_slope_method_refuses_data_that_do_not_reach_v1():
    v, a = _samples(Langevin(A, ALPHA), v_max=0.009)
    with pytest.raises(ValueError, match='v1 = 0.015'):
        fit_two_slope(v, a, v1=0.015)
    v = np.linspace(-0.025, 0.025, 2001)
    with pytest.raises(ValueError, match='Langevin'):
        fit_two_slope(v, -30.0 * v - 5e4 * v ** 3)  # slope grows with |v|


@pytest.mark.parametrize('law, expected', [(Langevin(A, ALPHA), 'langevin'),
                                           (CoulombViscous(0.1, 25.0), 'coulomb_viscous')])
def test_aic_picks_the_law_that_generated_the_data(law, expected):
    v, a = _samples(law, v_max=0.03)
    fits = compare_laws(v, a)
    assert [fit.name for fit in fits][0] == expected
    assert sorted(fit.name for fit in fits) == sorted(STATIC_LAWS)
    assert [fit.aic for fit in fits] == sorted(fit.aic for fit in fits)
    best = fits[0]
    for name, value in law.params.items():
        if name in best.params:
            low, high = best.ci95[name]
            assert low < value < high


def test_fits_reject_bad_input():
    with pytest.raises(ValueError, match='unknown law'):
        fit_least_squares([0.1, 0.2, 0.3], [1, 2, 3], 'magic')
    with pytest.raises(ValueError, match='finite'):
        fit_least_squares([0.1, np.nan, 0.3, 0.4], [1, 2, 3, 4])
    with pytest.raises(ValueError, match='length'):
        fit_least_squares([0.1, 0.2], [1.0])


# --- validation (docs/paper.md section 8, Fig. 9) ------------------------------------------

def test_fit_sinusoid_removes_mean_and_linear_drift():
    t = np.arange(0, 10, 1 / 30)
    x = 2e-3 + 1e-5 * t + 1.1e-3 * np.sin(W * t - 0.46)
    amplitude, phase = fit_sinusoid(t, x, FREQUENCY)
    assert amplitude == pytest.approx(1.1e-3, rel=1e-12)
    assert phase == pytest.approx(-0.46, abs=1e-12)


def test_validation_reproduces_the_papers_simulated_amplitude_and_phase():
    t = np.arange(0, 10, 1 / 30)
    stator = X_STATOR * np.sin(W * t)
    measured_slider = 1.26e-3 * np.sin(W * t - 0.46) + 3e-6 * t
    result = validate(Langevin(A, ALPHA), t, stator, measured_slider, FREQUENCY)
    # docs/paper.md section 8 says "about 1.11 mm and 0.41 rad"; those are rounded, so allow 0.03.
    assert result.slider_amplitude_simulated == pytest.approx(1.11e-3, abs=0.03e-3)
    assert result.phase_simulated == pytest.approx(0.41, abs=0.03)
    # Converged reference (RK4 at 0.1 ms with the analytic stator): 1.09769 mm, 0.41559 rad.
    # The spline through 30 frames/s and the 1 ms step change it by < 3e-4 relative.
    assert result.slider_amplitude_simulated == pytest.approx(1.09769e-3, rel=1e-3)
    assert result.phase_simulated == pytest.approx(0.41559, abs=2e-3)
    assert result.stator_amplitude == pytest.approx(X_STATOR, rel=1e-12)
    assert result.slider_amplitude_measured == pytest.approx(1.26e-3, rel=1e-9)
    assert result.phase_measured == pytest.approx(0.46, abs=1e-9)
    assert result.simulated_slider_position.shape == t.shape


def test_validation_on_epoch_stamps_equals_validation_on_stamps_from_zero():
    # Stamps since 1970 (1.7e9 s): w t rounded to 4e-6 rad per sample once moved amplitudes
    # and phases by 1e-7 and made them depend on the frequency's last bit.
    epoch_stamps = 1.7e9 + np.arange(0, 4, 1 / 30)  # quantised to 2.4e-7 s
    t = epoch_stamps - 1.7e9  # the same instants, exactly
    stator = X_STATOR * np.sin(W * t)
    slider = 1.26e-3 * np.sin(W * t - 0.46) + 3e-6 * t
    near = validate(Langevin(A, ALPHA), t, stator, slider, FREQUENCY)
    for frequency in (FREQUENCY, np.nextafter(FREQUENCY, 4.0)):
        epoch = validate(Langevin(A, ALPHA), epoch_stamps, stator, slider, frequency)
        for name in ('stator_amplitude', 'slider_amplitude_simulated',
                     'slider_amplitude_measured'):
            assert getattr(epoch, name) == pytest.approx(getattr(near, name), rel=1e-11), name
        for name in ('phase_simulated', 'phase_measured'):
            assert getattr(epoch, name) == pytest.approx(getattr(near, name), abs=1e-10), name
    amplitude, phase = fit_sinusoid(epoch_stamps, slider, FREQUENCY, origin=1.7e9)
    assert amplitude == pytest.approx(1.26e-3, rel=1e-9)
    assert phase == pytest.approx(-0.46, abs=1e-9)


def test_validation_of_the_first_periods_only_agrees_with_the_whole_record():
    t = np.arange(0, 20, 1 / 30)
    stator = X_STATOR * np.sin(W * t)
    slider = simulate_slider(Langevin(A, ALPHA), t, stator, run_in=2 / FREQUENCY)
    whole = validate(Langevin(A, ALPHA), t, stator, slider, FREQUENCY)
    first = validate(Langevin(A, ALPHA), t, stator, slider, FREQUENCY, max_periods=10)
    compared = t < 10 / FREQUENCY
    assert np.all(np.isfinite(first.simulated_slider_position[compared]))
    assert np.all(np.isnan(first.simulated_slider_position[~compared]))
    # The steady response is the same over 10 periods as over 59.
    assert first.slider_amplitude_simulated == pytest.approx(whole.slider_amplitude_simulated,
                                                             rel=1e-4)
    assert first.phase_simulated == pytest.approx(whole.phase_simulated, abs=1e-4)
    assert first.slider_amplitude_measured == pytest.approx(first.slider_amplitude_simulated,
                                                            rel=1e-3)
    with pytest.raises(ValueError, match='max_periods'):
        validate(Langevin(A, ALPHA), t, stator, slider, FREQUENCY, max_periods=0)


def test_validation_skips_lost_samples_and_needs_a_run_in():
    t = np.arange(0, 10, 1 / 30)
    stator = X_STATOR * np.sin(W * t)
    slider = simulate_slider(Langevin(A, ALPHA), t, stator, run_in=2 / FREQUENCY)
    holey = slider.copy()
    holey[100:110] = np.nan
    result = validate(Langevin(A, ALPHA), t, stator, holey, FREQUENCY)
    assert np.all(np.isfinite(result.simulated_slider_position))
    assert result.slider_amplitude_measured == pytest.approx(result.slider_amplitude_simulated,
                                                             rel=1e-3)
    assert result.phase_measured == pytest.approx(result.phase_simulated, abs=1e-3)
    with pytest.raises(ValueError, match='run-in'):
        validate(Langevin(A, ALPHA), t[:15], stator[:15], slider[:15], FREQUENCY)

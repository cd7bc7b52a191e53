"""The simulated bench: crank-slider kinematics, scenarios, integrator and camera record."""

import dataclasses
import math

import numpy as np
import pytest

from microball_ros.core import bench, friction
from microball_ros.core.bench import (
    SCENARIOS,
    BenchIntegrator,
    Scenario,
    crank_slider_motion,
    crank_slider_position,
    get_scenario,
    scenario_names,
    simulate,
)

R, L_ROD = 1.2e-3, 0.05


# --- crank-slider -----------------------------------------------------------------------------

def test_an_infinite_rod_gives_a_pure_cosine():
    theta = np.linspace(0, 4 * math.pi, 1001)
    omega = 18.5
    x, v, a = crank_slider_motion(theta, omega, R, math.inf)
    np.testing.assert_array_equal(x, R * np.cos(theta))
    np.testing.assert_allclose(v, -R * omega * np.sin(theta), rtol=1e-15, atol=1e-30)
    np.testing.assert_allclose(a, -R * omega ** 2 * np.cos(theta), rtol=1e-15, atol=1e-30)
    np.testing.assert_array_equal(crank_slider_position(theta, R, math.inf), x)


def test_a_finite_rod_adds_a_second_harmonic_of_r_squared_over_4l():
    n = 1024
    theta = 2 * math.pi * np.arange(n) / n
    x = crank_slider_position(theta, R, L_ROD)
    np.testing.assert_allclose(
        x, R * np.cos(theta) + np.sqrt(L_ROD ** 2 - (R * np.sin(theta)) ** 2) - L_ROD,
        rtol=0, atol=1e-17)
    spectrum = np.fft.rfft(x) / n
    expected = R ** 2 / (4 * L_ROD)
    assert 2 * abs(spectrum[1]) == pytest.approx(R, rel=1e-6)
    assert 2 * abs(spectrum[2]) == pytest.approx(expected, rel=1e-3)  # next term: r^2/(4 l^2)
    assert spectrum[0].real == pytest.approx(-expected, rel=1e-3)
    assert 2 * abs(spectrum[3]) < 1e-3 * expected


def test_crank_slider_velocity_and_acceleration_match_finite_differences():
    omega, h = 18.5, 1e-5
    t = np.linspace(0, 0.5, 97)
    r, rod = 5e-3, 0.012  # a short rod makes its terms large

    def position(time):
        return crank_slider_position(omega * time, r, rod)

    _, v, a = crank_slider_motion(omega * t, omega, r, rod)
    np.testing.assert_allclose(v, (position(t + h) - position(t - h)) / (2 * h),
                               rtol=0, atol=1e-8 * r * omega)
    np.testing.assert_allclose(a, (position(t + h) - 2 * position(t) + position(t - h)) / h ** 2,
                               rtol=0, atol=1e-4 * r * omega ** 2)


# --- scenarios --------------------------------------------------------------------------------

def test_scenarios_include_the_presets_and_are_read_only():
    assert {'paper', 'paper-clean', 'saturating', 'lugre', 'lagged',
            'coulomb-viscous'} <= set(scenario_names())
    paper = get_scenario('paper')
    assert (paper.frequency, paper.stator_amplitude, paper.frame_rate) == (2.95, 1.2e-3, 30.0)
    assert paper.law == friction.Langevin(1.2, 110.0)
    clean = get_scenario('paper-clean')
    assert clean.noise_std == 0 and clean.drift_velocity == 0 and clean.law == paper.law
    with pytest.raises(TypeError):
        SCENARIOS['mine'] = paper
    for name in scenario_names():
        assert get_scenario(name).description


def test_get_scenario_applies_overrides_and_names_the_known_scenarios_on_error():
    assert get_scenario('paper', seed=7, noise_std=0.0).seed == 7
    with pytest.raises(ValueError, match='known: paper, paper-clean'):
        get_scenario('papre')
    with pytest.raises(ValueError, match='noise'):
        get_scenario('paper', noisestd=1.0)


@pytest.mark.parametrize('overrides, message', [
    ({'frequency': 0.0}, 'frequency'), ({'noise_std': -1.0}, 'noise_std'),
    ({'rod_length': 1e-3}, 'rod_length'), ({'exposure': 0.05}, 'exposure')])
def test_scenario_rejects_impossible_values(overrides, message):
    with pytest.raises(ValueError, match=message):
        get_scenario('paper', **overrides)


# --- integrator -------------------------------------------------------------------------------

def test_integrator_integrates_the_crank_angle_through_speed_changes():
    scenario = get_scenario('paper')
    integrator = BenchIntegrator(scenario, crank_angle=0.3)
    integrator.step_to(0.5, 10.0)
    state = integrator.step_to(1.25, 20.0)
    assert state.crank_angle == pytest.approx(0.3 + 0.5 * 10.0 + 0.75 * 20.0, rel=1e-14)
    x, v, _ = crank_slider_motion(state.crank_angle, 20.0, R, L_ROD)
    assert (state.stator_position, state.stator_velocity) == pytest.approx((x, v), rel=1e-14)
    assert state.slider_acceleration == pytest.approx(
        -scenario.law.force(state.relative_velocity), rel=1e-12)
    assert integrator.step_to(1.25, 20.0) == state
    with pytest.raises(ValueError, match='step back'):
        integrator.step_to(1.0, 20.0)


def test_integrator_result_does_not_depend_on_how_the_time_is_split():
    scenario = get_scenario('paper')
    whole = BenchIntegrator(scenario)
    pieces = BenchIntegrator(scenario)
    end = whole.step_to(2.0, scenario.angular_frequency)
    for t in np.linspace(0.0371, 2.0, 54):
        split = pieces.step_to(t, scenario.angular_frequency)
    assert split.slider_position == pytest.approx(end.slider_position, abs=1e-9 * R)
    assert split.slider_velocity == pytest.approx(end.slider_velocity, abs=1e-8 * R * 18.5)


# --- simulate ---------------------------------------------------------------------------------

def test_simulate_is_seeded_and_only_the_noise_depends_on_the_seed():
    first = simulate(get_scenario('paper'), 3.0)
    again = simulate(get_scenario('paper'), 3.0)
    other = simulate(get_scenario('paper', seed=1), 3.0)
    for name, column in first.to_columns().items():
        np.testing.assert_array_equal(column, again.to_columns()[name])
    np.testing.assert_array_equal(first.true_slider_position, other.true_slider_position)
    assert not np.any(first.slider_position == other.slider_position)
    assert not np.any(first.stator_position == other.stator_position)


def test_simulate_record_layout_and_time_base():
    record = simulate(get_scenario('paper'), 2.0)
    columns = record.to_columns()
    assert list(columns)[:3] == ['time', 'stator_position', 'slider_position']
    assert all(name.startswith('true_') for name in list(columns)[3:])
    assert len(columns) == 10 and all(len(c) == 60 for c in columns.values())
    np.testing.assert_allclose(record.time, np.arange(60) / 30.0, rtol=0, atol=1e-15)
    assert len(simulate(get_scenario('paper'), 2.0, frame_rate=60.0).time) == 120
    with pytest.raises(ValueError, match='fewer than 2 frames'):
        simulate(get_scenario('paper'), 0.01)
    with pytest.raises(ValueError, match='exposure'):
        simulate(get_scenario('paper'), 1.0, frame_rate=100.0)


def test_simulated_stator_is_the_papers_sine_and_blur_scales_its_amplitude():
    scenario = get_scenario('paper-clean', rod_length=math.inf)
    record = simulate(scenario, 4.0)
    w, exposure = scenario.angular_frequency, scenario.exposure
    sine = 1.2e-3 * np.sin(w * record.time)
    np.testing.assert_allclose(record.true_stator_position, sine, rtol=0, atol=1e-15)
    blur = math.sin(w * exposure / 2) / (w * exposure / 2)
    # Simpson's rule over the exposure: error (w exposure / 2)^4 / 180 = 3e-6 relative.
    np.testing.assert_allclose(record.stator_position, blur * sine, rtol=0, atol=5e-6 * 1.2e-3)


@pytest.mark.parametrize('name', ['paper', 'saturating', 'coulomb-viscous'])
def test_ground_truth_acceleration_is_the_static_law(name):
    scenario = get_scenario(name)
    record = simulate(scenario, 2.0)
    np.testing.assert_allclose(record.true_relative_velocity,
                               record.true_slider_velocity - record.true_stator_velocity,
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(record.true_slider_acceleration,
                               -scenario.law.force(record.true_relative_velocity), rtol=1e-12)


def test_measured_positions_carry_the_configured_noise_and_drift():
    scenario = get_scenario('paper', exposure=0.0, noise_std=2e-6, drift_velocity=5e-6)
    record = simulate(scenario, 30.0)
    stator_error = record.stator_position - record.true_stator_position
    slider_error = record.slider_position - record.true_slider_position - record.true_slider_drift
    assert np.std(stator_error) == pytest.approx(2e-6, rel=0.1)
    assert np.std(slider_error) == pytest.approx(2e-6, rel=0.1)
    assert abs(np.corrcoef(stator_error, slider_error)[0, 1]) < 0.15
    assert record.true_slider_drift[0] == 0 and np.ptp(record.true_slider_drift) > 1e-5
    clean = simulate(get_scenario('paper-clean', exposure=0.0), 3.0)
    np.testing.assert_allclose(clean.slider_position, clean.true_slider_position, rtol=1e-15,
                               atol=0)


def test_drift_velocity_is_an_ornstein_uhlenbeck_process_of_the_configured_rms():
    period, rms, correlation_time = 1 / 30, 5e-6, 2.0
    drift = bench.slider_drift(np.random.default_rng(3), 300_000, period, rms, correlation_time)
    velocity = np.diff(drift) / period  # mid-step velocities, smoothed by half a step only
    assert np.std(velocity) == pytest.approx(rms, rel=0.05)
    lag = round(correlation_time / period)
    correlation = np.corrcoef(velocity[:-lag], velocity[lag:])[0, 1]
    assert correlation == pytest.approx(math.exp(-1), abs=0.05)


def test_presets_are_in_the_regimes_they_claim():
    def phase_offset(record, frequency):
        _, phase_a = friction.fit_sinusoid(record.time, record.true_slider_acceleration,
                                           frequency)
        _, phase_v = friction.fit_sinusoid(record.time, record.true_relative_velocity, frequency)
        return math.pi - abs(math.remainder(phase_a - phase_v, 2 * math.pi))

    paper = simulate(get_scenario('paper-clean'), 4.0)
    assert phase_offset(paper, 2.95) < 1e-3
    assert np.abs(paper.true_relative_velocity).max() < 0.01
    assert phase_offset(simulate(get_scenario('lagged'), 4.0), 2.95) > 0.4
    assert phase_offset(simulate(get_scenario('lugre'), 4.0), 2.95) > 0.2
    saturating = simulate(get_scenario('saturating'), 4.0)
    assert 110.0 * np.abs(saturating.true_relative_velocity).max() > 3


def test_validation_of_a_clean_paper_record_agrees_with_the_paper():
    scenario = get_scenario('paper-clean')
    record = simulate(scenario, 10.0)
    result = friction.validate(scenario.law, record.time, record.stator_position,
                               record.slider_position, scenario.frequency)
    assert result.slider_amplitude_measured == pytest.approx(
        result.slider_amplitude_simulated, rel=1e-3)
    assert result.phase_measured == pytest.approx(result.phase_simulated, abs=1e-3)
    assert result.phase_measured == pytest.approx(0.41, abs=0.03)


def test_scenario_is_a_frozen_dataclass():
    with pytest.raises(dataclasses.FrozenInstanceError):
        get_scenario('paper').frequency = 3.0
    assert Scenario(1.0, 1e-3, friction.Viscous()).rod_length == math.inf

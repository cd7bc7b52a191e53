"""The determinism comparison of reprocessed with recorded messages, without ROS."""

import math

import numpy as np
import pytest

from microball_ros.io.compare import (
    BYTE_IDENTICAL,
    DIFFERS,
    FLOOR,
    TOLERANCE,
    WITHIN_TOLERANCE,
    compare_messages,
    flatten,
    relative_differences,
    verdict,
)

ESTIMATES = '/estimation/derivatives'
MODELS = '/friction/model'


def _estimate(k):
    """Return a decoded DerivativeEstimate-like message (nested mappings, arrays, scalars)."""
    t = 1.0 + np.arange(64) / 30
    return {'header': {'stamp': {'sec': 1 + k, 'nanosec': 500}, 'frame_id': 'camera'},
            'method': 'three-stage', 'sample_period': 1 / 30, 'fundamental_frequency': 2.95,
            'time': t, 'relative_velocity': 1e-2 * np.cos(2 * math.pi * 2.95 * t),
            'phase_difference': 3.1413, 'memoryless': True, 'sample_count': 64}


def _model(k):
    return {'header': {'stamp': {'sec': 1 + k, 'nanosec': 0}, 'frame_id': ''},
            'name': 'langevin', 'a': 1.19 + 1e-3 * k, 'alpha': 110.9, 'a_ci95': [1.17, 1.21],
            'alpha_ci95': [109.6, math.inf], 'rmse': 1.08e-3, 'window_count': k + 1}


def _copy(message):
    return {k: _copy(v) if isinstance(v, dict) else
            (v.copy() if isinstance(v, (np.ndarray, list)) else v) for k, v in message.items()}


def _bump(value, relative):
    """Return value changed by the given relative amount (at least one last bit)."""
    bumped = value * (1 + relative)
    return bumped if bumped != value else np.nextafter(value, math.inf)


def test_identical_messages_are_within_tolerance_with_every_number_equal():
    recorded = [_estimate(k) for k in range(3)]
    comparison = compare_messages(recorded, [_copy(m) for m in recorded], ESTIMATES)
    assert not comparison.differs
    assert comparison.largest is None and comparison.first is None
    assert (comparison.recorded_count, comparison.new_count) == (3, 3)
    result = verdict([comparison])
    assert result.ok and result.status == WITHIN_TOLERANCE
    assert result.line == 'within tolerance (every number equal)'
    assert verdict([comparison], byte_identical=True).line == BYTE_IDENTICAL


def test_a_last_bit_difference_is_within_tolerance_and_named():
    recorded = [_model(k) for k in range(4)]
    new = [_copy(m) for m in recorded]
    new[2]['alpha_ci95'][0] = np.nextafter(109.6, math.inf)  # one ulp: 1.3e-16 relative
    new[1]['alpha'] = np.nextafter(110.9, 0.0)  # one ulp too, but relatively smaller
    comparison = compare_messages(recorded, new, MODELS)
    assert not comparison.differs
    largest = comparison.largest
    assert (largest.message, largest.field) == (2, 'alpha_ci95[0]')
    assert largest.relative == pytest.approx(math.ulp(109.6) / 109.6, rel=1e-6)
    assert largest.recorded == 109.6 and largest.new == np.nextafter(109.6, math.inf)
    result = verdict([compare_messages([_estimate(0)], [_estimate(0)], ESTIMATES), comparison])
    assert result.status == WITHIN_TOLERANCE
    figure = f'{largest.relative:.2g}'
    assert result.line == (f'within tolerance (largest relative difference {figure} in '
                           f'{MODELS} field alpha_ci95[0], message 2)')


def test_a_difference_of_1e_6_differs_and_is_shown_with_both_values():
    recorded = [_model(k) for k in range(3)]
    new = [_copy(m) for m in recorded]
    new[1]['a'] = recorded[1]['a'] * (1 + 1e-6)
    new[2]['rmse'] = recorded[2]['rmse'] * (1 + 1e-6)  # later: not the first
    comparison = compare_messages(recorded, new, MODELS)
    assert comparison.differs
    first = comparison.first
    assert (first.message, first.field) == (1, 'a')
    assert first.relative == pytest.approx(1e-6 / (1 + 1e-6))  # relative to the larger
    result = verdict([comparison])
    assert not result.ok and result.status == DIFFERS
    assert result.line == (f'differs: first differing message 1 on {MODELS}, field a: recorded '
                           f"{recorded[1]['a']!r}, new {new[1]['a']!r} (relative difference "
                           '1e-06)')


def test_the_tolerance_is_relative_1e_9():
    recorded = [_model(0)]
    for relative, differs in ((0.5e-9, False), (2e-9, True)):
        new = [_copy(recorded[0])]
        new[0]['alpha'] = _bump(recorded[0]['alpha'], relative)
        assert compare_messages(recorded, new, MODELS).differs is differs, relative


@pytest.mark.parametrize('field, value', [('memoryless', False), ('method', 'forward'),
                                          ('sample_count', 63)])
def test_a_changed_boolean_string_or_integer_differs(field, value):
    recorded = [_estimate(k) for k in range(2)]
    new = [_copy(m) for m in recorded]
    new[1][field] = value
    result = verdict([compare_messages(recorded, new, ESTIMATES)])
    assert result.status == DIFFERS
    assert result.line == (f'differs: first differing message 1 on {ESTIMATES}, field {field}: '
                           f'recorded {recorded[1][field]!r}, new {value!r}')


def test_a_changed_nested_integer_is_named_by_its_path():
    recorded = [_estimate(0)]
    new = [_copy(recorded[0])]
    new[0]['header']['stamp']['nanosec'] = 501
    first = compare_messages(recorded, new, ESTIMATES).first
    assert (first.field, first.recorded, first.new, first.relative) == (
        'header.stamp.nanosec', 500, 501, None)


def test_a_different_message_count_differs():
    recorded = [_model(k) for k in range(3)]
    comparison = compare_messages(recorded, recorded[:2], MODELS)
    assert comparison.differs and comparison.first is None
    result = verdict([comparison])
    assert result.line == f'differs: message count on {MODELS}: recorded 3, new 2'


def test_a_different_array_length_differs():
    recorded = [_estimate(0)]
    new = [_copy(recorded[0])]
    new[0]['time'] = new[0]['time'][:-1]
    first = compare_messages(recorded, new, ESTIMATES).first
    assert (first.field, first.recorded, first.new) == ('time.length', 64, 63)


def test_the_first_topic_with_a_difference_decides_the_verdict():
    models = [_model(0)]
    changed = [_copy(models[0])]
    changed[0]['name'] = 'stribeck'
    estimates = [_estimate(0)]
    worse = [_copy(estimates[0])]
    worse[0]['phase_difference'] = 1.0
    result = verdict([compare_messages(estimates, worse, ESTIMATES),
                      compare_messages(models, changed, MODELS)])
    assert result.line.startswith(f'differs: first differing message 0 on {ESTIMATES}, '
                                  'field phase_difference: recorded 3.1413, new 1.0')


def test_nan_equals_nan_and_infinities_compare_exactly():
    assert list(relative_differences([math.nan, math.inf, 1.0], [math.nan, math.inf, 1.0],
                                     1.0)) == [0, 0, 0]
    assert list(relative_differences([math.nan, math.inf, math.inf], [1.0, 1e300, -math.inf],
                                     1.0)) == [math.inf] * 3
    recorded = [_model(0)]
    new = [_copy(recorded[0])]
    new[0]['alpha_ci95'][1] = 1e6  # the recorded upper bound is +inf
    first = compare_messages(recorded, new, MODELS).first
    assert (first.field, first.relative) == ('alpha_ci95[1]', math.inf)


def test_numbers_zero_up_to_rounding_are_held_to_the_floor_of_their_field():
    # A velocity sample at a reversal: 1e-19 against a field whose largest value is 1e-2. Its
    # rounding error (here 1e-19, about the unit roundoff of 1e-3) is tiny against the floor,
    # 1e-3 of the field's largest value, though it is as large as the number itself.
    recorded = [_estimate(0)]
    recorded[0]['relative_velocity'][5] = 1e-19
    new = [_copy(recorded[0])]
    new[0]['relative_velocity'][5] = 2e-19
    comparison = compare_messages(recorded, new, ESTIMATES)
    assert not comparison.differs
    scale = float(np.max(np.abs(recorded[0]['relative_velocity'])))
    assert comparison.largest.field == 'relative_velocity[5]'
    assert comparison.largest.relative == pytest.approx(1e-19 / (FLOOR * scale))
    # ... while above the floor the plain relative difference holds.
    new[0]['relative_velocity'][5] = 1e-19
    new[0]['relative_velocity'][0] = recorded[0]['relative_velocity'][0] * (1 + 1e-8)
    comparison = compare_messages(recorded, new, ESTIMATES)
    assert comparison.differs and comparison.first.field == 'relative_velocity[0]'
    assert comparison.first.relative == pytest.approx(1e-8, rel=1e-6)
    assert comparison.first.relative > TOLERANCE


def test_flatten_names_every_leaf_in_definition_order():
    flat = flatten(_model(0))
    assert list(flat)[:5] == ['header.stamp.sec', 'header.stamp.nanosec', 'header.frame_id',
                              'name', 'a']
    assert flat['a_ci95'][0] == 'float' and flat['window_count'] == ('exact', 1)


def test_rclpy_messages_compare_like_mappings():
    msgs = pytest.importorskip('microball_msgs.msg')
    recorded = msgs.FrictionModel(name='langevin', a=1.19, alpha=110.9, a_ci95=[1.17, 1.21])
    new = msgs.FrictionModel(name='langevin', a=1.19, alpha=110.9, a_ci95=[1.17, 1.21 * 1.01])
    first = compare_messages([recorded], [new], MODELS).first
    assert first.field == 'a_ci95[1]' and first.relative == pytest.approx(0.01 / 1.01)
    assert compare_messages([recorded], [recorded], MODELS).largest is None

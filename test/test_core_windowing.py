"""Windows of whole stator periods from a stream of tracked positions."""

import numpy as np
import pytest

from microball_ros.core.windowing import PositionWindower, Skip, Window, WindowSettings

DT = 1 / 30


def _stream(windower, time, stator, slider, valid=None, index=None):
    events = []
    for k, t in enumerate(time):
        events += windower.push(t, k if index is None else index[k], stator[k], slider[k],
                                True if valid is None else bool(valid[k]))
    return events


def _sine(frequency, n, start=0.0, phase=0.0):
    t = start + np.arange(n) * DT
    return t, 1e-3 * np.sin(2 * np.pi * frequency * t + phase)


def test_windows_span_whole_periods_and_hop_as_asked():
    t, stator = _sine(2.95, 600)
    events = _stream(PositionWindower(WindowSettings(window_periods=8, hop_periods=4)), t,
                     stator, 0.9 * stator)
    windows = [e for e in events if isinstance(e, Window)]
    assert not [e for e in events if isinstance(e, Skip)]
    length, hop = round(8 / 2.95 / DT), round(4 / 2.95 / DT)  # 81 and 41 samples
    assert len(windows) == (600 - length) // hop + 1
    for window in windows:
        assert window.frequency == pytest.approx(2.95, rel=1e-4)
        assert window.periods == pytest.approx(8, abs=0.5 * 2.95 * DT)
    starts = np.array([w.time[0] for w in windows])
    np.testing.assert_allclose(np.diff(starts), round(4 / 2.95 / DT) * DT, atol=1e-9)


def test_a_frequency_step_starts_a_new_window():
    t1, x1 = _sine(2.0, 300)
    t2, x2 = _sine(3.0, 300, start=t1[-1] + DT)
    events = _stream(PositionWindower(), np.r_[t1, t2], np.r_[x1, x2], np.r_[x1, x2])
    windows = [e for e in events if isinstance(e, Window)]
    skips = [e for e in events if isinstance(e, Skip)]
    assert any('frequency changed' in s.reason for s in skips)
    frequencies = [w.frequency for w in windows]
    assert frequencies[0] == pytest.approx(2.0, rel=1e-3)
    assert frequencies[-1] == pytest.approx(3.0, rel=1e-3)
    # A window may reach at most a fraction of a segment past the step before the change is
    # seen; none straddles it by more than 20 % of its samples.
    step = t2[0]
    for window in windows:
        before = np.mean(window.time < step)
        assert before < 0.2 or before > 0.8


def test_lost_marks_and_frame_gaps_are_skipped_never_filled():
    t, stator = _sine(2.95, 600)
    valid = np.ones(600, bool)
    valid[200] = False
    index = np.arange(600)
    index[400:] += 5  # five frames dropped by the camera
    events = _stream(PositionWindower(), t, stator, stator, valid, index)
    reasons = [e.reason for e in events if isinstance(e, Skip)]
    assert 'invalid sample (lost mark)' in reasons
    assert 'frame gap or irregular time stamps' in reasons
    for window in (e for e in events if isinstance(e, Window)):
        assert t[200] not in window.time
        frames = window.frame_index
        assert np.all(np.diff(frames) == 1)


def test_a_resting_stator_is_skipped():
    t = np.arange(600) * DT
    events = _stream(PositionWindower(), t, np.full(600, 1e-4), np.full(600, 2e-4))
    assert [e.reason for e in events if isinstance(e, Skip)][0] == 'stator not oscillating'
    assert not [e for e in events if isinstance(e, Window)]


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match='window_periods'):
        PositionWindower(WindowSettings(window_periods=2))
    with pytest.raises(ValueError, match='hop_periods'):
        PositionWindower(WindowSettings(hop_periods=20))

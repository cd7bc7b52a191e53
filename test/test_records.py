"""Position CSV contract: strict reading, one-line errors, NaN-as-empty round trip."""

import numpy as np
import pytest

from microball_ros.core.records import RecordError
from microball_ros.io.positions_csv import read_positions_csv, write_positions_csv


def _write(tmp_path, text):
    path = tmp_path / 'positions.csv'
    path.write_text(text)
    return str(path)


def test_round_trip_keeps_values_extra_columns_and_gaps(tmp_path):
    time = np.arange(10) / 30.0
    stator = 1e-3 * np.sin(2 * np.pi * 2.95 * time)
    slider = 0.9 * stator
    slider[4] = np.nan
    path = str(tmp_path / 'out' / 'p.csv')
    write_positions_csv(path, {'time': time, 'stator_position': stator,
                               'slider_position': slider, 'true_x': stator * 2})
    assert open(path).readline().strip() == 'time,stator_position,slider_position,true_x'
    record = read_positions_csv(path)
    np.testing.assert_array_equal(record.time, time)
    np.testing.assert_array_equal(record.stator_position, stator)
    np.testing.assert_array_equal(record.slider_position[~np.isnan(slider)],
                                  slider[~np.isnan(slider)])
    assert record.valid.tolist() == [k != 4 for k in range(10)]
    np.testing.assert_array_equal(record.extra['true_x'], stator * 2)
    assert record.sample_period == pytest.approx(1 / 30.0)


@pytest.mark.parametrize('text, message', [
    ('time,stator_position\n0,1\n', 'missing column(s) slider_position'),
    ('time,stator_position,slider_position\n', 'no data rows'),
    ('time,stator_position,slider_position\n0,1,2\n0.1,abc,2\n0.2,1,2\n',
     "row 3, column 'stator_position': 'abc' is not a number"),
    ('time,stator_position,slider_position\n0,1,2\n0.1,nan,2\n0.2,1,2\n',
     "'nan' is not a finite number"),
    ('time,stator_position,slider_position\n0,1,2\n0.1,1,2\n0.1,1,2\n0.2,1,2\n',
     'duplicated time stamp 0.1'),
    ('time,stator_position,slider_position\n0,1,2\n0.1,1,2\n0.2,1,2\n0.35,1,2\n0.45,1,2\n',
     'non-uniform sampling'),
    ('time,stator_position,slider_position\n0,1,2\n0.1,1\n', 'row 3 has 2 cells'),
    ('time,stator_position,slider_position\n0,1,2\n,1,2\n0.2,1,2\n', 'row 3 has no time stamp'),
])
def test_malformed_files_raise_one_line_errors(tmp_path, text, message):
    with pytest.raises(RecordError) as error:
        read_positions_csv(_write(tmp_path, text))
    assert message in str(error.value)
    assert '\n' not in str(error.value)


def test_missing_file(tmp_path):
    with pytest.raises(RecordError, match='no such file'):
        read_positions_csv(str(tmp_path / 'absent.csv'))

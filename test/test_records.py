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
    ('time,stator_position,slider_position\n0,1,2\n0.1,1,2\n0.05,1,2\n0.2,1,2\n',
     'decreasing time stamp 0.05 after 0.1'),
    ('time,stator_position,slider_position\n0.1,1,2\n0.1,1,2\n0.1,1,2\n',
     'every time stamp is 0.1'),
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


def _sine_rows(time_scale=1.0, position_scale=1.0, n=90):
    time = np.arange(n) / 30.0
    stator = 1.2e-3 * np.sin(2 * np.pi * 2.95 * time)
    return [(t * time_scale, x * position_scale, 0.9 * x * position_scale)
            for t, x in zip(time, stator, strict=True)]


def _text(rows, delimiter=',', decimal='.', newline='\n'):
    lines = [delimiter.join(('time', 'stator_position', 'slider_position'))]
    lines += [delimiter.join(repr(float(v)).replace('.', decimal) for v in row) for row in rows]
    return newline.join(lines) + newline


@pytest.mark.parametrize('encoding, delimiter, decimal, newline', [
    ('utf-8-sig', ',', '.', '\r\n'),  # Excel's "CSV UTF-8": byte-order mark, CRLF
    ('utf-8', ';', ',', '\n'),        # a European Excel: semicolons and decimal commas
    ('utf-8', '\t', '.', '\n'),       # tab-separated
])
def test_files_as_labs_save_them_read_the_same(tmp_path, encoding, delimiter, decimal, newline):
    rows = _sine_rows()
    path = tmp_path / 'lab.csv'
    path.write_bytes(_text(rows, delimiter, decimal, newline).encode(encoding))
    record = read_positions_csv(str(path))
    np.testing.assert_array_equal(record.time, [r[0] for r in rows])
    np.testing.assert_array_equal(record.slider_position, [r[2] for r in rows])


def test_gzip_compressed_csv_reads_like_the_plain_one(tmp_path):
    import gzip

    rows = _sine_rows()
    path = tmp_path / 'p.csv.gz'
    with gzip.open(path, 'wt') as handle:
        handle.write(_text(rows))
    np.testing.assert_array_equal(read_positions_csv(str(path)).stator_position,
                                  [r[1] for r in rows])


@pytest.mark.parametrize('head, kind', [
    (b'\x1a\x45\xdf\xa3\x01\x00\x00\x00', 'Matroska/WebM video: track it first'),
    (b'\x89MCAP0\r\n', 'MCAP bag file'),
    (b'\x89PNG\r\n\x1a\n', 'PNG image'),
    (b'\x00\x00\x00\x18ftypmp42', 'MP4/MOV video'),
    (b'\xff\xfe\x00\x01garbage\x00', 'not a text file'),
])
def test_a_file_that_is_not_a_csv_is_named_for_what_it_is(tmp_path, head, kind):
    path = tmp_path / 'paper.csv'
    path.write_bytes(head + bytes(range(256)) * 4)
    with pytest.raises(RecordError) as error:
        read_positions_csv(str(path))
    assert str(error.value).startswith(f'{path}: not a position CSV')
    assert kind in str(error.value)


@pytest.mark.parametrize('time_scale, position_scale, message', [
    (1e3, 1.0, 'time steps of 33.3333 look like milliseconds'),
    (1e9, 1.0, 'look like nanoseconds'),
    (1.0, 1e3, 'stator_position spans 2.399, which looks like millimetres'),
    (1.0, 1e6, 'which looks like micrometres'),
])
def test_wrong_units_are_refused_saying_what_they_look_like(tmp_path, time_scale,
                                                            position_scale, message):
    path = tmp_path / 'units.csv'
    path.write_text(_text(_sine_rows(time_scale, position_scale)))
    with pytest.raises(RecordError) as error:
        read_positions_csv(str(path))
    assert message in str(error.value) and str(path) in str(error.value)


def test_gaps_duplicates_and_jitter_are_read_for_the_analysis(tmp_path):
    # Issue 13: a missing row, a duplicated stamp or jittered stamps are analysed (the
    # pipeline puts them on the frame grid), so the reader no longer refuses them.
    text = 'time,stator_position,slider_position\n0,1,2\n0.1,1,2\n0.1,1,2\n0.35,1,2\n0.401,1,2\n'
    record = read_positions_csv(_write(tmp_path, text))
    assert record.time.tolist() == [0, 0.1, 0.1, 0.35, 0.401]

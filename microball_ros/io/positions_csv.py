"""Position CSV files: the contract of DESIGN.md section 5, read strictly and written plainly.

A position CSV has the header ``time,stator_position,slider_position`` (s, m, m); extra columns
are kept but not needed. An empty cell means "no measurement" (a lost mark in a tracked video);
the literal text ``nan`` or any other non-number is an error, so a broken file is never mistaken
for a tracked one.
"""

import csv
import os

import numpy as np

from microball_ros.core.records import (
    REQUIRED_COLUMNS,
    PositionRecord,
    RecordError,
    check_time_base,
)


def _parse_cell(text, row_number, column):
    text = text.strip()
    if text == '':
        return np.nan
    try:
        value = float(text)
    except ValueError:
        message = f'row {row_number}, column {column!r}: {text!r} is not a number'
        raise RecordError(message) from None
    if not np.isfinite(value):
        raise RecordError(f'row {row_number}, column {column!r}: {text!r} is not a finite number')
    return value


def read_positions_csv(path):
    """Read a position CSV into a PositionRecord, raising RecordError on anything malformed."""
    if not os.path.isfile(path):
        raise RecordError(f'{path}: no such file')
    with open(path, newline='') as handle:
        reader = csv.reader(handle)
        header = [name.strip() for name in next(reader, [])]
        missing = [name for name in REQUIRED_COLUMNS if name not in header]
        if missing:
            raise RecordError(f'{path}: missing column(s) {", ".join(missing)} '
                              f'(need a header {",".join(REQUIRED_COLUMNS)})')
        rows = []
        for row_number, row in enumerate(reader, start=2):
            if not row or all(cell.strip() == '' for cell in row):
                continue
            if len(row) != len(header):
                raise RecordError(f'{path}: row {row_number} has {len(row)} cells, '
                                  f'the header has {len(header)}')
            rows.append([_parse_cell(cell, row_number, name)
                         for cell, name in zip(row, header, strict=True)])
    if not rows:
        raise RecordError(f'{path}: no data rows')
    data = np.array(rows, dtype=float)
    columns = {name: data[:, k] for k, name in enumerate(header)}
    if np.isnan(columns['time']).any():
        row = int(np.flatnonzero(np.isnan(columns['time']))[0]) + 2
        raise RecordError(f'{path}: row {row} has no time stamp')
    record = PositionRecord(
        time=columns.pop('time'), stator_position=columns.pop('stator_position'),
        slider_position=columns.pop('slider_position'), extra=columns)
    check_time_base(record.time, source=path)
    return record


def write_positions_csv(path, columns):
    """Write an ordered mapping of column name -> array to a CSV; NaN becomes an empty cell."""
    names = list(columns)
    missing = [name for name in REQUIRED_COLUMNS if name not in names]
    if missing:
        raise ValueError(f'cannot write a position CSV without {", ".join(missing)}')
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    arrays = [np.asarray(columns[name], dtype=float) for name in names]
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for values in zip(*arrays, strict=True):
            writer.writerow(['' if np.isnan(v) else repr(float(v)) for v in values])

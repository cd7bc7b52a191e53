"""Position CSV files: the contract of docs/design.md section 5, read strictly and written plainly.

A position CSV has the header ``time,stator_position,slider_position`` (s, m, m); extra columns
are kept but not needed. An empty cell means "no measurement" (a lost mark in a tracked video);
the literal text ``nan`` or any other non-number is an error, so a broken file is never mistaken
for a tracked one.
"""

import csv
import gzip
import os

import numpy as np

from microball_ros.core.records import (
    REQUIRED_COLUMNS,
    PositionRecord,
    RecordError,
    check_time_base,
    check_units,
)

# What a file that is not a CSV usually is, by its first bytes, and which command reads it.
_MAGIC = (
    (b'\x1a\x45\xdf\xa3', 'a Matroska/WebM video: track it first with `microball track`'),
    (b'RIFF', 'a RIFF (AVI) video: track it first with `microball track`'),
    (b'\x89MCAP', 'an MCAP bag file: give its path to `microball analyze` as a .mcap file'),
    (b'\x89PNG', 'a PNG image: track an image sequence with `microball track DIRECTORY`'),
    (b'\xff\xd8\xff', 'a JPEG image: track an image sequence with `microball track DIRECTORY`'),
    (b'II*\x00', 'a TIFF image: track an image sequence with `microball track DIRECTORY`'),
    (b'MM\x00*', 'a TIFF image: track an image sequence with `microball track DIRECTORY`'),
    (b'PK\x03\x04', 'a ZIP archive (an .xlsx workbook?): save it as CSV first'),
)
_VIDEO_BOX = b'ftyp'  # MP4 / MOV: 'ftyp' at byte 4


def _kind_of_binary(head):
    """Return what a non-text file probably is (for the error message)."""
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    if head[4:8] == _VIDEO_BOX:
        return 'an MP4/MOV video: track it first with `microball track`'
    return 'not a text file'


def _open_text(path):
    """Open a CSV (or .csv.gz) as text, the byte-order mark of Excel's 'CSV UTF-8' removed."""
    with open(path, 'rb') as raw:
        head = raw.read(4096)
    if head.startswith(b'\x1f\x8b'):  # gzip
        return gzip.open(path, 'rt', encoding='utf-8-sig', newline='')
    if b'\x00' in head or not _decodes(head):
        raise RecordError(f'{path}: not a position CSV: {_kind_of_binary(head)}')
    return open(path, encoding='utf-8-sig', newline='')


def _decodes(head):
    try:
        head.decode('utf-8')
    except UnicodeDecodeError as error:
        return error.start >= len(head) - 3  # a multi-byte character cut at the 4 KiB edge
    return True


def _dialect(first_line):
    """Return the delimiter of the header line: ',' (the contract), ';' or a tab."""
    counts = {delimiter: first_line.count(delimiter) for delimiter in (',', ';', '\t')}
    best = max(counts, key=counts.get)
    return best if counts[best] else ','


def _parse_cell(text, row_number, column, decimal_comma, path):
    text = text.strip()
    if text == '':
        return np.nan
    if decimal_comma:
        text = text.replace(',', '.')
    try:
        value = float(text)
    except ValueError:
        message = f'{path}: row {row_number}, column {column!r}: {text!r} is not a number'
        raise RecordError(message) from None
    if not np.isfinite(value):
        raise RecordError(f'{path}: row {row_number}, column {column!r}: {text!r} is not a '
                          'finite number (leave the cell empty where a mark was lost)')
    return value


def read_positions_csv(path):
    """Read a position CSV into a PositionRecord, raising RecordError on anything malformed.

    Read as a lab's files come: UTF-8 with or without a byte-order mark, any line ending,
    comma-separated (the contract) or ';' / tab separated (a ';' file may use decimal
    commas), optionally gzip-compressed. Every error names the file and says what is wrong in
    the user's terms; a video, bag or image given by mistake is named as such.
    """
    if not os.path.isfile(path):
        raise RecordError(f'{path}: no such file')
    try:
        with _open_text(path) as handle:
            rows = _read_rows(handle, path)
    except UnicodeDecodeError:
        raise RecordError(f'{path}: not a position CSV: not UTF-8 text') from None
    except (OSError, EOFError, csv.Error) as error:  # a truncated .gz, a broken quote
        raise RecordError(f'{path}: cannot read as CSV: {error}') from None
    header, data = rows
    columns = {name: data[:, k] for k, name in enumerate(header)}
    if np.isnan(columns['time']).any():
        row = int(np.flatnonzero(np.isnan(columns['time']))[0]) + 2
        raise RecordError(f'{path}: row {row} has no time stamp')
    record = PositionRecord(
        time=columns.pop('time'), stator_position=columns.pop('stator_position'),
        slider_position=columns.pop('slider_position'), extra=columns)
    check_time_base(record.time, source=path)
    check_units(record, source=path)
    return record


def _read_rows(handle, path):
    """Return (header, float array of the rows) of an open CSV."""
    first = handle.readline()
    delimiter = _dialect(first)
    header = [name.strip() for name in next(csv.reader([first], delimiter=delimiter), [])]
    missing = [name for name in REQUIRED_COLUMNS if name not in header]
    if missing:
        raise RecordError(f'{path}: missing column(s) {", ".join(missing)} '
                          f'(need a header {",".join(REQUIRED_COLUMNS)})')
    rows = []
    for row_number, row in enumerate(csv.reader(handle, delimiter=delimiter), start=2):
        if not row or all(cell.strip() == '' for cell in row):
            continue
        if len(row) != len(header):
            raise RecordError(f'{path}: row {row_number} has {len(row)} cells, '
                              f'the header has {len(header)}')
        rows.append([_parse_cell(cell, row_number, name, delimiter != ',', path)
                     for cell, name in zip(row, header, strict=True)])
    if not rows:
        raise RecordError(f'{path}: no data rows')
    return header, np.array(rows, dtype=float)


def write_positions_csv(path, columns):
    """Write an ordered mapping of column name -> array to a CSV; NaN becomes an empty cell."""
    names = list(columns)
    missing = [name for name in REQUIRED_COLUMNS if name not in names]
    if missing:  # a programming error: every caller builds the columns itself
        raise ValueError(f'cannot write a position CSV without {", ".join(missing)}')
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    arrays = [np.asarray(columns[name], dtype=float) for name in names]
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for values in zip(*arrays, strict=True):
            writer.writerow(['' if np.isnan(v) else repr(float(v)) for v in values])

"""Compare reproduced messages with recorded ones: the determinism contract (docs/design.md 4).

Three verdicts, in this order of strength:

- ``byte-identical``: every message of every compared topic has the recorded CDR bytes (both
  went through DDS, so their padding bytes are defined). Contract (a), same platform.
- ``within tolerance``: decoded field by field, every number is within relative
  ``TOLERANCE`` (1e-9) of the recorded one, and every integer, boolean and string, every
  array length and every message count is identical. Contract (b), another platform.
- ``differs``: anything else; the verdict names the first difference.

(``not compared``: no topic to compare, e.g. a bag of only camera frames has no recorded
outputs.)

Relative difference of two numbers a (recorded) and b (new)::

    |a - b| / max(|a|, |b|, FLOOR * scale)

where ``scale`` is the largest finite magnitude the same field takes anywhere in the topic
(every element of an array field, every message, recorded and new). The floor matters only for
numbers that are zero up to rounding, such as a velocity sample at a reversal: such a number is
a difference of terms of the field's size, so its rounding error is a multiple of the unit
roundoff of the field's scale, not of its own magnitude. Below ``FLOOR`` (1e-3) of the scale a
number is therefore held to an absolute ``TOLERANCE * FLOOR * scale`` (1e-12 of the field's
largest value); above it, to the plain relative 1e-9. NaN equals NaN and an infinity equals
the same infinity; NaN or an infinity against anything else differs.

``compare_messages()`` is pure (decoded messages in, a ``TopicComparison`` out): messages may be
rclpy messages, rosbags messages or plain mappings. ``decode()`` and ``compare_bags()`` read
bags; ``decode()`` needs rclpy and the message packages, imported only when called.
"""

import array
from collections.abc import Mapping
import dataclasses
import importlib
import math
from typing import NamedTuple

import numpy as np

from microball_ros.core.errors import BagError

TOLERANCE = 1e-9
FLOOR = 1e-3

BYTE_IDENTICAL = 'byte-identical'
WITHIN_TOLERANCE = 'within tolerance'
DIFFERS = 'differs'
NOT_COMPARED = 'not compared'


class Difference(NamedTuple):
    """One compared value: message index (from 0), field path, values, relative difference.

    ``relative`` is None for a value compared exactly (integer, boolean, string, a length).
    """

    message: int
    field: str
    recorded: object
    new: object
    relative: float | None = None


class TopicComparison(NamedTuple):
    """What comparing one topic found.

    ``largest``: the number with the largest relative difference (None if no number differs
    at all); ``first``: the first value beyond tolerance or compared exactly and not equal, in
    message then field order (None if none).
    """

    topic: str
    recorded_count: int
    new_count: int
    largest: Difference | None
    first: Difference | None

    @property
    def differs(self):
        """Return True if the counts differ or some value is beyond tolerance."""
        return self.recorded_count != self.new_count or self.first is not None


class Verdict(NamedTuple):
    """The outcome of a comparison: ``status`` (one of the three constants) and its line."""

    status: str
    line: str
    comparisons: tuple = ()

    @property
    def ok(self):
        """Return True for byte-identical or within tolerance."""
        return self.status != DIFFERS


# ----------------------------------------------------------------------------------------------
# Flattening a decoded message into (field path, kind, value) leaves.

_FLOAT, _EXACT = 'float', 'exact'


def _field_names(message):
    """Return the field names of a decoded message, in definition order, or None."""
    if isinstance(message, Mapping):
        return list(message)
    fields = getattr(type(message), 'get_fields_and_field_types', None)
    if fields is not None:  # rclpy
        return list(fields())
    if dataclasses.is_dataclass(message):  # rosbags
        return [f.name for f in dataclasses.fields(message)]
    return None


def _get(message, name):
    return message[name] if isinstance(message, Mapping) else getattr(message, name)


def _leaves(value, path):
    """Yield (path, kind, value) for every leaf of a decoded value."""
    names = _field_names(value)
    if names is not None:
        for name in names:
            yield from _leaves(_get(value, name), f'{path}.{name}' if path else name)
        return
    if isinstance(value, (str, bytes, bool, np.bool_)):
        yield path, _EXACT, value
        return
    if isinstance(value, (int, np.integer)):
        yield path, _EXACT, int(value)
        return
    if isinstance(value, (float, np.floating)):
        yield path, _FLOAT, np.float64(value)
        return
    if isinstance(value, (np.ndarray, array.array)):
        values = np.asarray(value)
        if values.dtype.kind == 'f':
            yield path, _FLOAT, values.astype(np.float64).ravel()
        elif values.dtype.kind in 'iub':
            yield path, _EXACT, values.ravel()
        else:  # an object array: a sequence of messages or strings
            yield from _leaves(list(values), path)
        return
    if isinstance(value, (list, tuple)):
        if value and all(isinstance(v, (float, np.floating)) for v in value):
            yield path, _FLOAT, np.asarray(value, dtype=np.float64)
        elif all(isinstance(v, (bool, int, np.integer, np.bool_)) for v in value):
            yield path, _EXACT, np.asarray(value, dtype=np.int64)
        else:
            yield f'{path}.length', _EXACT, len(value)
            for index, item in enumerate(value):
                yield from _leaves(item, f'{path}[{index}]')
        return
    raise TypeError(f'cannot compare a field of type {type(value).__name__} at {path!r}')


def flatten(message):
    """Return {field path: (kind, value)} of a decoded message, in definition order.

    kind is 'float' (a float64 scalar or 1-d array, compared with the tolerance) or 'exact'
    (an integer, boolean, string or bytes, or an integer array, compared exactly).
    """
    return {path: (kind, value) for path, kind, value in _leaves(message, '')}


# ----------------------------------------------------------------------------------------------
# The comparison.

def relative_differences(recorded, new, scale, floor=FLOOR):
    """Return |a - b| / max(|a|, |b|, floor * scale) elementwise (0 where equal, NaN = NaN)."""
    a = np.asarray(recorded, dtype=np.float64)
    b = np.asarray(new, dtype=np.float64)
    with np.errstate(invalid='ignore', divide='ignore', over='ignore'):
        equal = (a == b) | (np.isnan(a) & np.isnan(b))
        denominator = np.maximum(np.maximum(np.abs(a), np.abs(b)), floor * scale)
        relative = np.abs(a - b) / denominator
    relative = np.where(np.isfinite(relative), relative, np.inf)
    return np.where(equal, 0.0, relative)


def _scales(flats):
    """Return {field path: largest finite magnitude of that float field over all messages}."""
    scales = {}
    for flat in flats:
        for path, (kind, value) in flat.items():
            if kind != _FLOAT:
                continue
            finite = np.abs(value[np.isfinite(value)])
            if finite.size:
                scales[path] = max(scales.get(path, 0.0), float(finite.max()))
    return scales


def _as_python(value):
    if isinstance(value, np.generic):
        return value.item()
    return value


def _element(path, value, index):
    """Return (path with the element index, the element) of a scalar or 1-d array field."""
    if np.ndim(value) == 0:
        return path, _as_python(value)
    return f'{path}[{index}]', _as_python(value[index])


def _exact_difference(number, path, a, b):
    """Return the Difference of two exact values, or None if equal."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.atleast_1d(a), np.atleast_1d(b)
        if a.shape != b.shape:
            return Difference(number, f'{path}.length', len(a), len(b))
        unequal = np.flatnonzero(a != b)
        if unequal.size == 0:
            return None
        index = int(unequal[0])
        return Difference(number, f'{path}[{index}]', _as_python(a[index]),
                          _as_python(b[index]))
    return None if a == b and type(a) is type(b) else Difference(number, path, a, b)


def compare_messages(recorded, new, topic='', tolerance=TOLERANCE, floor=FLOOR):
    """Compare two lists of decoded messages of one topic; return a TopicComparison.

    Pure: no files, no ROS. Messages are compared pairwise in order; with different counts the
    common prefix is compared and the count decides the verdict.
    """
    recorded_flats = [flatten(m) for m in recorded]
    new_flats = [flatten(m) for m in new]
    scales = _scales([*recorded_flats, *new_flats])
    largest = first = None
    for number, (old, fresh) in enumerate(zip(recorded_flats, new_flats, strict=False)):
        for path in [*old, *(p for p in fresh if p not in old)]:
            if path not in old or path not in fresh:
                # A sequence of messages of another length (its .length leaf came first) or
                # another message definition.
                if first is None:
                    first = Difference(number, path, 'present' if path in old else 'absent',
                                       'present' if path in fresh else 'absent')
                continue
            kind, a = old[path]
            b = fresh[path][1]
            if kind == _EXACT or fresh[path][0] == _EXACT:
                difference = _exact_difference(number, path, a, b)
                if difference is not None and first is None:
                    first = difference
                continue
            if np.shape(a) != np.shape(b):
                if first is None:
                    first = Difference(number, f'{path}.length', np.size(a), np.size(b))
                continue
            relative = relative_differences(a, b, scales.get(path, 0.0), floor)
            if relative.size == 0:
                continue
            index = int(np.argmax(relative))
            worst = float(relative.flat[index])
            if worst > 0 and (largest is None or worst > largest.relative):
                field, x = _element(path, a, index)
                largest = Difference(number, field, x, _element(path, b, index)[1], worst)
            if first is None and worst > tolerance:
                index = int(np.flatnonzero(relative.ravel() > tolerance)[0])
                field, x = _element(path, a, index)
                first = Difference(number, field, x, _element(path, b, index)[1],
                                   float(relative.flat[index]))
    return TopicComparison(topic, len(recorded), len(new), largest, first)


def _figure(relative):
    return f'{relative:.2g}' if math.isfinite(relative) else 'inf'


def _value(value):
    return repr(value) if isinstance(value, (float, str, bytes)) else str(value)


def verdict(comparisons, byte_identical=False):
    """Return the Verdict of a sequence of TopicComparison (topics in causal order).

    ``byte_identical``: the caller found every compared message's bytes equal.
    """
    comparisons = tuple(comparisons)
    if byte_identical:
        return Verdict(BYTE_IDENTICAL, BYTE_IDENTICAL, comparisons)
    for comparison in comparisons:
        if comparison.recorded_count != comparison.new_count:
            return Verdict(DIFFERS, f'{DIFFERS}: message count on {comparison.topic}: '
                                    f'recorded {comparison.recorded_count}, '
                                    f'new {comparison.new_count}', comparisons)
        first = comparison.first
        if first is not None:
            line = (f'{DIFFERS}: first differing message {first.message} on '
                    f'{comparison.topic}, field {first.field}: recorded {_value(first.recorded)}'
                    f', new {_value(first.new)}')
            if first.relative is not None:
                line += f' (relative difference {_figure(first.relative)})'
            return Verdict(DIFFERS, line, comparisons)
    largest = [c for c in comparisons if c.largest is not None]
    if not largest:
        return Verdict(WITHIN_TOLERANCE, f'{WITHIN_TOLERANCE} (every number equal)', comparisons)
    worst = max(largest, key=lambda c: c.largest.relative)
    return Verdict(WITHIN_TOLERANCE,
                   f'{WITHIN_TOLERANCE} (largest relative difference '
                   f'{_figure(worst.largest.relative)} in {worst.topic} field '
                   f'{worst.largest.field}, message {worst.largest.message})', comparisons)


# ----------------------------------------------------------------------------------------------
# Bags.

def message_class(type_name):
    """Return the rclpy message class of a type name such as 'microball_msgs/msg/FrictionModel'."""
    package, _, name = type_name.rpartition('/')
    module = package.replace('/', '.')
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        raise BagError(f'message type {type_name} is not installed here; cannot decode '
                       'it') from None


def decode(bag, topic):
    """Return the messages of one topic of an opened bag, deserialized by rclpy, in order."""
    from rclpy.serialization import deserialize_message

    cls = message_class(bag.topics[topic].type)
    return [deserialize_message(m.data, cls) for m in bag.messages([topic])]


def compare_bags(recorded, new, topics, tolerance=TOLERANCE):
    """Compare the topics of two opened bags; return their Verdict.

    Byte-identical when every message's CDR bytes are equal; otherwise decoded and compared
    field by field (compare_messages). A topic missing from a bag has no messages there.
    """
    def data(bag, topic):
        return [m.data for m in bag.messages([topic])] if topic in bag.topics else []

    if not topics:
        return Verdict(NOT_COMPARED, f'{NOT_COMPARED}: no recorded topic to compare with')
    if all(data(recorded, t) == data(new, t) for t in topics):
        counts = [TopicComparison(t, len(data(recorded, t)), len(data(new, t)), None, None)
                  for t in topics]
        return verdict(counts, byte_identical=True)
    comparisons = []
    for topic in topics:
        old = decode(recorded, topic) if topic in recorded.topics else []
        fresh = decode(new, topic) if topic in new.topics else []
        comparisons.append(compare_messages(old, fresh, topic, tolerance))
    return verdict(comparisons)

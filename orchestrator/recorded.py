"""Loading and validating recorded machine data (CSV files).

A recording is a CSV file with a header line and one row per sample.  The caller
says which columns to use through :class:`ChannelSpec` objects; each becomes a
channel of :class:`RecordedData`, converted to SI units (see
:mod:`milling_twin.models.units`) or to booleans.

Nothing is dropped, filled or guessed: every problem is a
:class:`RecordedDataError` whose message names the file and, where it applies, the
line (1-based line number in the file; the header is line 1, so the first data row
is line 2) and the column.

Time comes either from a column (``time_column``, converted from ``time_unit`` to
seconds; it must be strictly increasing) or from a fixed ``sample_period`` in
seconds (``time = row_index * sample_period``, starting at 0).

Boolean channels:

* ``ChannelSpec(..., above=x)``: ``True`` where the numeric column value (in the
  channel's ``unit``, i.e. the unit of the file, *not* SI) is strictly greater
  than ``x``. Between samples such a channel switches where the linearly
  interpolated column crosses ``x`` (``at(..., "linear")``): an edge lies
  between two samples, and the column says where (a spindle running up from
  0 to 53 rev/s in one 0.1 s sample is on after 2 ms, not 0.1 s later).
* ``ChannelSpec(..., match=regex)``: the column holds text; ``True`` where
  ``re.search(regex, text)`` matches.  ``unit`` must be ``"bool"``.
* ``ChannelSpec(..., unit="bool")`` without ``above``/``match``: the column holds
  ``0``/``1`` or ``true``/``false`` (any case).
"""

from __future__ import annotations

import codecs
import csv
import math
import os
import re
from array import array
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

try:  # the parser of the re module, to check a pattern's structure before it is run
    import re._constants as _sre
    import re._parser as _sre_parse
except ImportError:  # Python < 3.11
    import sre_constants as _sre  # type: ignore[no-redef]
    import sre_parse as _sre_parse  # type: ignore[no-redef]

from milling_twin.models.units import UnitError, convert, parse_unit, si_unit_of
from milling_twin.orchestrator.input_files import InputFileError, open_input, text_position
from milling_twin.orchestrator.recording_checks import RecordingCheck

__all__ = [
    "ChannelSpec",
    "RecordedData",
    "RecordedDataError",
    "load_recorded",
]

#: Cell texts that count as missing values (compared after stripping whitespace).
_MISSING_TEXTS = frozenset({"", "nan", "na", "n/a", "null", "none", "-nan", "+nan"})
_TRUE_TEXTS = frozenset({"1", "1.0", "true"})
_FALSE_TEXTS = frozenset({"0", "0.0", "false"})
_INTERPOLATIONS = ("linear", "hold")


class RecordedDataError(ValueError):
    """Invalid recorded data, an invalid request for it, or an invalid channel spec."""


@dataclass(frozen=True)
class ChannelSpec:
    """One channel to load from a recording.

    ``name``: channel name in :class:`RecordedData`; ``column``: header name in the
    file; ``unit``: unit of the values in the file (a unit known to
    :mod:`milling_twin.models.units`, or ``"bool"``).  At most one of ``above`` (numeric
    threshold in ``unit``) and ``match`` (regular expression) may be set; either
    makes the channel boolean.  The spec is checked by :func:`load_recorded`, so
    that the error can name the file.
    """

    name: str
    column: str
    unit: str
    above: float | None = None
    match: str | None = None


@dataclass
class RecordedData:
    """Recorded channels on a common time base.

    ``time``: seconds, float64, strictly increasing, at least 2 samples.
    ``channels``: float64 arrays in SI units, or bool arrays.
    ``units``: SI unit string of each channel, or ``"bool"``.
    ``thresholds``: for boolean channels defined by a threshold (``above``), the
    column in SI and the threshold in SI: :meth:`at` places their edges between
    samples.
    ``check``: what :mod:`milling_twin.orchestrator.recording_checks` found and which
    segments are used (None: the recording was not checked).
    """

    path: Path
    time: np.ndarray
    channels: dict[str, np.ndarray]
    units: dict[str, str] = field(default_factory=dict)
    thresholds: dict[str, tuple[np.ndarray, float]] = field(default_factory=dict)
    check: RecordingCheck | None = None

    def __post_init__(self) -> None:
        self.path = Path(self.path)
        time = np.asarray(self.time, dtype=np.float64)
        if time.ndim != 1 or time.size < 2:
            raise RecordedDataError(
                f"{self.path}: time must be a 1-D array with at least 2 samples, "
                f"got shape {time.shape}"
            )
        if not np.all(np.isfinite(time)):
            raise RecordedDataError(f"{self.path}: time contains non-finite values")
        steps = np.diff(time)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0))
            raise RecordedDataError(
                f"{self.path}: time must be strictly increasing, but sample {i + 1} "
                f"({float(time[i + 1])!r}) follows sample {i} ({float(time[i])!r})"
            )
        self.time = time
        if set(self.units) != set(self.channels):
            raise RecordedDataError(
                f"{self.path}: units given for {sorted(self.units)} but channels are "
                f"{sorted(self.channels)}"
            )
        for name, values in self.channels.items():
            if values.shape != time.shape:
                raise RecordedDataError(
                    f"{self.path}: channel {name!r} has shape {values.shape}, "
                    f"time has shape {time.shape}"
                )
            if (values.dtype == np.bool_) != (self.units[name] == "bool"):
                raise RecordedDataError(
                    f"{self.path}: channel {name!r} has dtype {values.dtype} but unit "
                    f"{self.units[name]!r} (bool arrays need unit 'bool' and vice versa)"
                )
        for name, (column, threshold) in self.thresholds.items():
            if name not in self.channels or self.channels[name].dtype != np.bool_ \
                    or np.shape(column) != time.shape or not math.isfinite(threshold):
                raise RecordedDataError(
                    f"{self.path}: threshold of channel {name!r}: a boolean channel's column "
                    f"(one value per sample) and a finite threshold are needed"
                )

    def consistent(self, t: np.ndarray) -> np.ndarray:
        """Where times ``t`` lie in a segment the recording's check uses, after the segment's first sample
        (the interval into a segment joins two moments of the machine: what a simulation computes there
        belongs to neither). All True for an unchecked recording."""
        tt = np.asarray(t, dtype=np.float64)
        if self.check is None:
            return np.ones(tt.shape, dtype=bool)
        mask = np.zeros(tt.shape, dtype=bool)
        for segment in self.check.segments:
            mask |= (tt > self.time[segment.start]) & (tt <= self.time[segment.stop - 1])
        return mask

    @property
    def t_start(self) -> float:
        return float(self.time[0])

    @property
    def t_end(self) -> float:
        return float(self.time[-1])

    def at(
        self, name: str, t: float | np.ndarray, interpolation: str = "linear"
    ) -> float | bool | np.ndarray:
        """Value of channel ``name`` at time(s) ``t`` (seconds).

        ``interpolation``: ``"linear"`` or ``"hold"`` (zero-order hold: the sample at
        or before ``t``).  Boolean channels hold, except those defined by a threshold,
        which with ``"linear"`` switch where the interpolated column crosses it.  A scalar ``t`` gives a
        ``float`` (or ``bool``), an array gives an array of the same shape.

        ``t`` must lie in ``[t_start, t_end]``; a time beyond either end by at most
        1e-9 of the recording's duration (floating-point round-off of a caller's
        clock) is treated as that end.  Anything further out raises
        :class:`RecordedDataError` naming the channel and the range.
        """
        if name not in self.channels:
            raise RecordedDataError(
                f"{self.path}: no channel {name!r}; channels: {sorted(self.channels)}"
            )
        if interpolation not in _INTERPOLATIONS:
            raise RecordedDataError(
                f"{self.path}: channel {name!r}: unknown interpolation "
                f"{interpolation!r}, expected one of {list(_INTERPOLATIONS)}"
            )
        scalar = np.ndim(t) == 0
        tt = np.asarray(t, dtype=np.float64)
        t0, t1 = self.t_start, self.t_end
        tol = 1e-9 * (t1 - t0)
        bad = ~((tt >= t0 - tol) & (tt <= t1 + tol))  # also catches NaN
        if np.any(bad):
            first = float(tt[bad].flat[0])
            raise RecordedDataError(
                f"{self.path}: channel {name!r}: time {first!r} s is outside the "
                f"recorded range [{t0!r}, {t1!r}] s"
            )
        tt = np.clip(tt, t0, t1)
        values = self.channels[name]
        if name in self.thresholds and interpolation == "linear":
            column, threshold = self.thresholds[name]
            result = np.interp(tt, self.time, column) > threshold
        elif interpolation == "hold" or values.dtype == np.bool_:
            idx = np.searchsorted(self.time, tt, side="right") - 1
            result = values[np.clip(idx, 0, values.size - 1)]
        else:
            result = np.interp(tt, self.time, values)
        if scalar:
            item = np.asarray(result).item()
            return bool(item) if values.dtype == np.bool_ else float(item)
        return np.asarray(result)


# --------------------------------------------------------------------------- patterns

#: Bounds of a channel's ``match``: its length, the characters of a cell it is matched against, the unbounded
#: repeats (``*``, ``+``, ``{n,}``) it may hold. With no repeat inside another, no alternation inside a repeat and
#: no backreference, the backtracking engine's time is polynomial in the cell's length, of a degree at most the
#: number of unbounded repeats: at most 1000^2 steps for a cell.
MAX_PATTERN_LENGTH = 200
MAX_MATCH_TEXT = 1000
MAX_UNBOUNDED_REPEATS = 2


class PatternError(ValueError):
    """A ``match`` pattern refused: invalid, or of a structure whose matching time can explode."""


def check_pattern(pattern: str) -> None:
    """Refuse a regular expression that is invalid, longer than MAX_PATTERN_LENGTH, or can take exponential time:
    a backreference, a repeat inside a repeat (``(a+)+``), an alternation inside a repeat (``(a|aa)*``), more than
    MAX_UNBOUNDED_REPEATS unbounded repeats."""
    if len(pattern) > MAX_PATTERN_LENGTH:
        raise PatternError(f"a pattern of {len(pattern)} characters, more than {MAX_PATTERN_LENGTH}")
    try:
        parsed = _sre_parse.parse(pattern)
    except re.error as exc:
        raise PatternError(f"invalid regular expression: {exc}") from None
    unbounded = [0]

    def walk(items: Any, in_repeat: bool) -> None:
        for op, av in items:
            if op in (_sre.GROUPREF, _sre.GROUPREF_EXISTS):
                raise PatternError("a backreference (\\1, (?P=name), (?(1)...)) can take exponential time: "
                                   "not allowed")
            if op in (_sre.MAX_REPEAT, _sre.MIN_REPEAT, getattr(_sre, "POSSESSIVE_REPEAT", None)):
                low, high, body = av
                repeats = high > 1
                if repeats and in_repeat:
                    raise PatternError("a repeat inside a repeat (like (a+)+) can take exponential time: "
                                       "write it with one quantifier")
                unbounded[0] += high == _sre.MAXREPEAT
                walk(body, in_repeat or repeats)
            elif op is _sre.BRANCH:
                if in_repeat:
                    raise PatternError("an alternation inside a repeat (like (a|ab)*) can take exponential time: "
                                       "use a character class or several channels")
                for branch in av[1]:
                    walk(branch, in_repeat)
            elif op is _sre.SUBPATTERN:
                walk(av[3], in_repeat)
            elif op in (_sre.ASSERT, _sre.ASSERT_NOT):
                walk(av[1], in_repeat)
            elif op is getattr(_sre, "ATOMIC_GROUP", None):
                walk(av, in_repeat)

    walk(parsed, False)
    if unbounded[0] > MAX_UNBOUNDED_REPEATS:
        raise PatternError(f"{unbounded[0]} unbounded repeats (*, +, {{n,}}), more than {MAX_UNBOUNDED_REPEATS}: "
                           f"the matching time grows as the cell's length to that power")


# --------------------------------------------------------------------------- loading


def _where(path: Path, line: int | None = None, column: str | None = None) -> str:
    parts = [str(path)]
    if line is not None:
        parts.append(f"line {line}")
    if column is not None:
        parts.append(f"column {column!r}")
    return ", ".join(parts)


def _check_specs(path: Path, channels: Sequence[ChannelSpec]) -> None:
    seen: set[str] = set()
    for spec in channels:
        if not isinstance(spec, ChannelSpec):
            raise RecordedDataError(
                f"{path}: channels must be ChannelSpec objects, got {spec!r}"
            )
        where = f"{path}: channel {spec.name!r} (column {spec.column!r})"
        if spec.name in seen:
            raise RecordedDataError(f"{where}: duplicate channel name {spec.name!r}")
        seen.add(spec.name)
        try:
            unit = parse_unit(spec.unit)
        except UnitError as exc:
            raise RecordedDataError(f"{where}: unit {spec.unit!r}: {exc}") from None
        if spec.above is not None and spec.match is not None:
            raise RecordedDataError(
                f"{where}: set at most one of 'above' and 'match' "
                f"(got above={spec.above!r}, match={spec.match!r})"
            )
        if spec.above is not None:
            if unit.boolean:
                raise RecordedDataError(
                    f"{where}: 'above' needs a numeric unit, got unit 'bool'"
                )
            if not isinstance(spec.above, (int, float)) or not math.isfinite(spec.above):
                raise RecordedDataError(
                    f"{where}: 'above' must be a finite number, got {spec.above!r}"
                )
        if spec.match is not None:
            if not unit.boolean:
                raise RecordedDataError(
                    f"{where}: a 'match' channel is boolean, its unit must be 'bool', "
                    f"got {spec.unit!r}"
                )
            try:
                check_pattern(spec.match)
            except PatternError as exc:
                raise RecordedDataError(f"{where}: match {spec.match!r}: {exc}") from None


@dataclass
class _Rows:
    """What one pass over the file keeps: the header, the text of the needed columns (by field index) and the
    file line at which each kept data row starts."""
    header: list[str]
    texts: dict[int, list[str]]
    row_lines: array


#: Bytes that never occur in a CSV text file (C0 controls but tab, line feed, form feed and carriage return).
_BINARY = re.compile(rb"[\x00-\x08\x0b\x0e-\x1f\x7f]")
_SNIFF_BYTES = 65536
_SHOWN_COLUMNS = 30  # header names listed in a message


def _not_csv(path: Path, why: str) -> RecordedDataError:
    return RecordedDataError(f"{path}: not a CSV recording ({why})")


def _sniff(path: Path, fh: BinaryIO) -> None:
    """Refuse a file that is not CSV text at all, without quoting it: control bytes in its first 64 KiB."""
    start = fh.read(_SNIFF_BYTES)
    fh.seek(0)
    if not start.strip():
        raise RecordedDataError(f"{path}: file is empty")
    binary = _BINARY.search(start)
    if binary:
        line, column = text_position(start, binary.start())
        raise _not_csv(path, f"binary content: byte 0x{start[binary.start()]:02x} at line {line}, column {column}")


def _text_lines(path: Path, fh: BinaryIO) -> Iterator[str]:
    """The file's lines decoded one at a time (a byte that is not UTF-8 is named by its line and column)."""
    for number, raw in enumerate(fh, 1):
        if number == 1 and raw.startswith(codecs.BOM_UTF8):
            raw = raw[len(codecs.BOM_UTF8):]
        try:
            yield raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            column = len(raw[:exc.start].decode("utf-8", errors="replace")) + 1
            raise RecordedDataError(f"{_where(path, number)}, column {column}: byte 0x{raw[exc.start]:02x} is not "
                                    f"valid UTF-8: a recording must be UTF-8 text") from None


def _read(path: Path, needed: Callable[[list[str]], dict[str, int]], stop: Callable[[int, list[str]], bool]
          ) -> _Rows:
    """One pass over the file: the header (``needed`` gives the field index of each column wanted), then the
    data rows, each checked for its field count, keeping the text of the needed fields, until ``stop(rows, record)``
    (after the row is kept: the run uses no later row)."""
    if not os.path.lexists(path):
        raise RecordedDataError(f"{path}: file not found")
    try:
        fh = open_input(path, "recording")
    except InputFileError as exc:
        raise RecordedDataError(exc.detail) from None
    with fh:
        _sniff(path, fh)
        reader = csv.reader(_text_lines(path, fh))
        header: list[str] | None = None
        indices: list[int] = []
        texts: dict[int, list[str]] = {}
        row_lines = array("q")
        previous_end = 0
        try:
            for record in reader:
                start = previous_end + 1
                previous_end = reader.line_num
                if header is None:
                    header = record
                    _check_header(path, header)
                    indices = sorted(set(needed(header).values()))
                    texts = {i: [] for i in indices}
                    continue
                if len(record) != len(header):
                    what = "blank line" if not record else f"{len(record)} fields"
                    kind = "truncated line" if len(record) < len(header) else "too many fields"
                    raise RecordedDataError(
                        f"{_where(path, start)}: {kind}: {what}, but the header "
                        f"(line 1) has {len(header)} fields"
                    )
                for i in indices:
                    texts[i].append(record[i])
                row_lines.append(start)
                if stop(len(row_lines), record):
                    break
        except csv.Error as exc:
            raise RecordedDataError(f"{_where(path, reader.line_num)}: {exc}") from None
    if header is None:  # only whitespace beyond the first 64 KiB: unreachable
        raise RecordedDataError(f"{path}: file is empty")
    return _Rows(header=header, texts=texts, row_lines=row_lines)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _check_header(path: Path, header: list[str]) -> None:
    cells = [c.strip() for c in header]
    if not any(cells):
        raise RecordedDataError(f"{_where(path, 1)}: header missing (line 1 is empty)")
    if all(_is_number(c) for c in cells if c):
        raise RecordedDataError(
            f"{_where(path, 1)}: header missing: line 1 holds only numbers "
            f"({', '.join(header[:5])}{', ...' if len(header) > 5 else ''})"
        )


def _column_index(path: Path, header: list[str], column: str, role: str) -> int:
    hits = [i for i, name in enumerate(header) if name == column]
    if not hits and len(header) < 2:  # no comma in line 1: not a table of named columns
        raise _not_csv(path, f"line 1 is not a header of comma-separated column names; looked for the column "
                             f"{column!r}")
    if not hits:
        shown = ", ".join(repr(h if len(h) <= 40 else h[:40] + "...") for h in header[:_SHOWN_COLUMNS])
        more = f", ... ({len(header)} columns)" if len(header) > _SHOWN_COLUMNS else ""
        raise RecordedDataError(
            f"{_where(path, 1, column)}: {role}: column not found in header; "
            f"available columns: {shown}{more}"
        )
    if len(hits) > 1:
        raise RecordedDataError(
            f"{_where(path, 1, column)}: {role}: column appears {len(hits)} times in "
            f"the header (fields {', '.join(str(i + 1) for i in hits)})"
        )
    return hits[0]


def _missing_check(path: Path, column: str, texts: np.ndarray, lines: list[int]) -> None:
    missing = np.array([t.strip().lower() in _MISSING_TEXTS for t in texts], dtype=bool)
    if missing.any():
        first = int(np.argmax(missing))
        raise RecordedDataError(
            f"{_where(path, lines[first], column)}: empty or NaN cell "
            f"({texts[first]!r}); {int(missing.sum())} such cell(s) in this column"
        )


def _parse_numeric(path: Path, column: str, texts: np.ndarray, lines: list[int]) -> np.ndarray:
    import pandas as pd  # here, not at import: scenarios without recorded data do not load pandas

    _missing_check(path, column, texts, lines)
    stripped = pd.Series(texts, dtype=object).map(str.strip)
    values = pd.to_numeric(stripped, errors="coerce").to_numpy(dtype=np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        first = int(np.argmax(bad))
        raise RecordedDataError(
            f"{_where(path, lines[first], column)}: non-numeric or non-finite value "
            f"{texts[first]!r}; {int(bad.sum())} such cell(s) in this column"
        )
    return values


def _parse_bool(path: Path, column: str, texts: np.ndarray, lines: list[int]) -> np.ndarray:
    _missing_check(path, column, texts, lines)
    lowered = [t.strip().lower() for t in texts]
    for i, t in enumerate(lowered):
        if t not in _TRUE_TEXTS and t not in _FALSE_TEXTS:
            raise RecordedDataError(
                f"{_where(path, lines[i], column)}: value {texts[i]!r} is not a "
                f"boolean (expected 0, 1, true or false)"
            )
    return np.array([t in _TRUE_TEXTS for t in lowered], dtype=bool)


def load_recorded(
    path: str | Path,
    channels: Sequence[ChannelSpec],
    *,
    time_column: str | None = None,
    time_unit: str = "s",
    sample_period: float | None = None,
    until: float | None = None,
) -> RecordedData:
    """Load the requested channels of a CSV recording, validated and in SI units.

    Exactly one of ``time_column`` (values in ``time_unit``) and ``sample_period``
    (seconds) must be given.  ``until`` (seconds): the file is read up to and including
    the first row at or after this time, and no further (what a run ending there uses);
    None reads it all.  Raises :class:`RecordedDataError` for any problem, with
    the file, line and column in the message.
    """
    path = Path(path)
    if (time_column is None) == (sample_period is None):
        raise RecordedDataError(
            f"{path}: give exactly one of time_column and sample_period "
            f"(got time_column={time_column!r}, sample_period={sample_period!r})"
        )
    if sample_period is not None and (
        isinstance(sample_period, bool)
        or not isinstance(sample_period, (int, float))
        or not math.isfinite(sample_period)
        or sample_period <= 0
    ):
        raise RecordedDataError(
            f"{path}: sample_period must be a positive finite number of seconds, "
            f"got {sample_period!r}"
        )
    if time_column is not None:
        try:
            tunit = parse_unit(time_unit)
        except UnitError as exc:
            raise RecordedDataError(f"{path}: time_unit {time_unit!r}: {exc}") from None
        if si_unit_of(time_unit) != "s" or tunit.boolean:
            raise RecordedDataError(
                f"{path}: time_unit {time_unit!r} is not a unit of time"
            )
    _check_specs(path, channels)

    needed: dict[str, int] = {}

    def find_columns(header: list[str]) -> dict[str, int]:
        if time_column is not None:
            needed[time_column] = _column_index(path, header, time_column, "time column")
        for spec in channels:
            needed[spec.column] = _column_index(path, header, spec.column, f"channel {spec.name!r}")
        return needed

    limit = None if until is None or not math.isfinite(until) else float(until)
    factor = float(convert(1.0, time_unit, "s")) if time_column is not None else 0.0

    def stop(rows: int, record: list[str]) -> bool:
        """The first row at or after ``until`` ends the reading (the row is kept: it brackets ``until``)."""
        if limit is None or rows < 2:
            return False
        if sample_period is not None:
            return (rows - 1) * sample_period >= limit
        try:
            return float(record[needed[time_column]]) * factor >= limit
        except ValueError:  # not a number: the time column's check names it
            return False

    read = _read(path, find_columns, stop)
    n_rows = len(read.row_lines)
    if n_rows < 2:
        raise RecordedDataError(
            f"{path}: fewer than 2 data rows (found {n_rows}); a recording needs at "
            f"least 2 samples"
        )
    texts = {idx: np.array(values, dtype=object) for idx, values in read.texts.items()}
    lines = read.row_lines

    if time_column is not None:
        raw = _parse_numeric(path, time_column, texts[needed[time_column]], lines)
        time = np.asarray(convert(raw, time_unit, "s"), dtype=np.float64)
        steps = np.diff(time)
        if np.any(steps <= 0):
            i = int(np.argmax(steps <= 0)) + 1
            col_texts = texts[needed[time_column]]
            raise RecordedDataError(
                f"{_where(path, lines[i], time_column)}: time not strictly increasing: "
                f"{col_texts[i].strip()!r} follows {col_texts[i - 1].strip()!r} "
                f"(line {lines[i - 1]})"
            )
    else:
        assert sample_period is not None
        time = np.arange(n_rows, dtype=np.float64) * float(sample_period)

    out: dict[str, np.ndarray] = {}
    units: dict[str, str] = {}
    thresholds: dict[str, tuple[np.ndarray, float]] = {}
    for spec in channels:
        col = texts[needed[spec.column]]
        if spec.match is not None:
            _missing_check(path, spec.column, col, lines)
            long = np.flatnonzero([len(v) > MAX_MATCH_TEXT for v in col])
            if long.size:
                raise RecordedDataError(
                    f"{_where(path, lines[long[0]], spec.column)}: a cell of {len(col[long[0]])} characters, more "
                    f"than the {MAX_MATCH_TEXT} a 'match' channel reads (channel {spec.name!r})"
                )
            pattern = re.compile(spec.match)
            distinct, where_in = np.unique(col.astype(str), return_inverse=True)  # a label repeats over rows
            hits = np.array([pattern.search(str(v)) is not None for v in distinct], dtype=bool)
            out[spec.name] = hits[where_in.reshape(-1)]
            units[spec.name] = "bool"
        elif spec.above is not None:
            values = _parse_numeric(path, spec.column, col, lines)
            si = si_unit_of(spec.unit)  # the edges between samples are placed on the column in SI
            column = np.asarray(convert(values, spec.unit, si), dtype=np.float64)
            threshold = float(convert(spec.above, spec.unit, si))
            out[spec.name] = column > threshold
            units[spec.name] = "bool"
            thresholds[spec.name] = (column, threshold)
        elif parse_unit(spec.unit).boolean:
            out[spec.name] = _parse_bool(path, spec.column, col, lines)
            units[spec.name] = "bool"
        else:
            values = _parse_numeric(path, spec.column, col, lines)
            si = si_unit_of(spec.unit)
            out[spec.name] = np.asarray(convert(values, spec.unit, si), dtype=np.float64)
            units[spec.name] = si

    return RecordedData(path=path, time=time, channels=out, units=units, thresholds=thresholds)

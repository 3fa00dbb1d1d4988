"""The ``[recorded.checks]`` table of a scenario: which channels the physical checks of
:mod:`milling_twin.orchestrator.recording_checks` read, the machine's limits, and the policy.

    [recorded.checks]
    positions = ["x", "y", "z"]                    # channels of [recorded.channels], lengths
    velocities = ["vx", "vy", "vz"]                # optional: the same axes' velocity channels
    line = "line"                                  # optional: the program line channel (policy "reorder")
    max_axis_speed = { value = 50.0, unit = "mm/s" }  # one value for every axis, or value = [..] per axis
    significant_digits = 3                         # positions stored with 3 significant digits, or
    # resolution = { value = [1.0, 0.1, 0.1], unit = "mm" }   the storage step per axis
    timing_jitter = { value = 0.05, unit = "s" }   # how far a row's sampling moment may be off (default)
    min_segment = 3                                # shorter segments are dropped and counted (rows)
    [recorded.checks.rates]                        # optional: channels with a physical rate limit (per second)
    spindle_speed = { value = 150.0, unit = "rev/s2" }
    policy = "segment"                             # segment | drop | reorder (recording_checks)

Plain numbers are SI (m/s, m, s).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any, NoReturn

import numpy as np

from milling_twin.models.units import UnitError, convert, si_unit_of
from milling_twin.orchestrator.recorded import RecordedData
from milling_twin.orchestrator.recording_checks import (POLICIES, CheckLimits, RateLimit, RecordingCheck,
                                                        RepairError, check_recording)

__all__ = ["KEYS", "check_table"]

KEYS = ("positions", "velocities", "line", "max_axis_speed", "significant_digits", "resolution", "timing_jitter",
        "min_segment", "policy", "rates")
KEY = "[recorded.checks]"
_RATE_UNITS = {"m": "m/s", "m/s": "m/s2", "rad": "rad/s", "rad/s": "rad/s2"}  # SI unit -> SI unit per second


def _quantity(fail: Callable[[str, str], NoReturn], table: dict, name: str, si: str, count: int,
              default: Any = ...) -> tuple[float, ...] | None:
    """A number or list (SI) or ``{ value = number or list, unit = "..." }``, as ``count`` SI values."""
    if name not in table:
        if default is ...:
            fail(f"{KEY}.{name}", "missing required key")
        return default
    raw, unit = table[name], si
    if isinstance(raw, dict):
        unknown = sorted(set(raw) - {"value", "unit"})
        if unknown or "value" not in raw:
            fail(f"{KEY}.{name}", f"expected {{ value = ..., unit = \"...\" }}, got {raw!r}")
        raw, unit = raw["value"], raw.get("unit", si)
        try:
            if si_unit_of(unit) != si:
                fail(f"{KEY}.{name}", f"unit {unit!r} is not a unit of {si}")
        except UnitError as exc:
            fail(f"{KEY}.{name}", f"unit {unit!r}: {exc}")
    values = raw if isinstance(raw, list) else [raw] * count
    if len(values) != count or any(isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v)
                                   for v in values):
        fail(f"{KEY}.{name}", f"expected a number or a list of {count} numbers, got {raw!r}")
    return tuple(float(convert(float(v), unit, si)) for v in values)


def _channels(fail: Callable[[str, str], NoReturn], data: RecordedData, table: dict, name: str, unit: str,
              count: int | None) -> list[str]:
    names = table[name]
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names) \
            or (count is not None and len(names) != count):
        what = f"{count} channel names" if count else "channel names"
        fail(f"{KEY}.{name}", f"expected a list of {what}, got {names!r}")
    for n in names:
        if n not in data.channels:
            fail(f"{KEY}.{name}", f"unknown recorded channel {n!r}; channels: {', '.join(data.channels)}")
        if data.units[n] != unit:
            fail(f"{KEY}.{name}", f"channel {n!r} is in {data.units[n]}, expected a channel in {unit}")
    return names


def check_table(fail: Callable[[str, str], NoReturn], table: Any, data: RecordedData) -> RecordingCheck:
    """Check ``data`` as ``table`` (the parsed ``[recorded.checks]``) says; ``fail(key, message)`` reports a
    mistake in the table."""
    if not isinstance(table, dict):
        fail(KEY, f"expected a table, got {table!r}")
    unknown = [k for k in table if k not in KEYS]
    if unknown:
        fail(f"{KEY}.{unknown[0]}", f"unknown key {unknown[0]!r}; known keys: {', '.join(KEYS)}")
    if "positions" not in table:
        fail(f"{KEY}.positions", "missing required key")
    positions = _channels(fail, data, table, "positions", "m", None)
    n_axes = len(positions)
    velocities = _channels(fail, data, table, "velocities", "m/s", n_axes) if "velocities" in table else None
    line = table.get("line")
    if line is not None and (not isinstance(line, str) or line not in data.channels):
        fail(f"{KEY}.line", f"expected the name of a recorded channel, got {line!r}; channels: "
                            f"{', '.join(data.channels)}")
    policy = table.get("policy", "segment")
    if policy not in POLICIES:
        fail(f"{KEY}.policy", f"{policy!r} is not one of {', '.join(POLICIES)}")
    digits = table.get("significant_digits")
    if digits is not None and (isinstance(digits, bool) or not isinstance(digits, int)):
        fail(f"{KEY}.significant_digits", f"expected a whole number, got {digits!r}")
    min_segment = table.get("min_segment", 3)
    if isinstance(min_segment, bool) or not isinstance(min_segment, int):
        fail(f"{KEY}.min_segment", f"expected a whole number of rows, got {min_segment!r}")
    jitter = _quantity(fail, table, "timing_jitter", "s", 1, (0.05,))
    speeds = _quantity(fail, table, "max_axis_speed", "m/s", n_axes)
    resolution = _quantity(fail, table, "resolution", "m", n_axes, None)
    try:  # what is left: relations between the values (CheckLimits says which)
        limits = CheckLimits(max_axis_speed=speeds, timing_jitter=jitter[0], resolution=resolution,
                             significant_digits=digits, min_segment=min_segment)
    except ValueError as exc:
        fail(KEY, str(exc))
    rates = []
    raw_rates = table.get("rates", {})
    if not isinstance(raw_rates, dict):
        fail(f"{KEY}.rates", f"expected a table of channel = {{ value, unit }}, got {raw_rates!r}")
    for name in raw_rates:
        if name not in data.channels or data.units[name] == "bool":
            fail(f"{KEY}.rates.{name}", f"expected a numeric recorded channel; channels: {', '.join(data.channels)}")
        per_second = _RATE_UNITS.get(data.units[name])
        if per_second is None:
            fail(f"{KEY}.rates.{name}", f"channel {name!r} is in {data.units[name]}: rate limits are known for "
                                        f"channels in {', '.join(_RATE_UNITS)}")
        (max_rate,) = _quantity(lambda key, message: fail(key.replace(KEY, f"{KEY}.rates"), message), raw_rates,
                                name, per_second, 1)
        rates.append(RateLimit(name, data.channels[name], max_rate, significant_digits=digits))
    try:
        return check_recording(np.column_stack([data.channels[n] for n in positions]), data.time, limits,
                               policy=policy, lines=None if line is None else data.channels[line], rates=rates,
                               velocities=None if velocities is None else
                               np.column_stack([data.channels[n] for n in velocities]))
    except RepairError as exc:
        fail(f"{KEY}.policy", f"{data.path}: {exc}")

"""Fitted parameters in SI units: bounds, scaling for the optimiser, display units, multi-start draws."""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NoReturn

import numpy as np

from milling_twin.models.units import UnitError, conversion_factor
from milling_twin.orchestrator.calibrate.spec import ParameterSpec
from milling_twin.orchestrator.scenario import Ref

__all__ = ["Parameter", "draw_starts", "resolve_parameter", "unit_factor"]


def unit_factor(from_unit: str, to_unit: str) -> float:
    """value_in_from * factor = value_in_to (identical strings need no table entry)."""
    return 1.0 if from_unit == to_unit else conversion_factor(from_unit, to_unit)


@dataclass(frozen=True)
class Parameter:
    """A fitted quantity. ``initial``, ``lower``, ``upper``, ``scale`` and ``start_range`` are SI;
    the optimiser works on value / scale. ``nuisance`` ones (e.g. the spindle phase of a recording)
    are estimated with the others but are no model parameters: they are not written to the
    parameter set. ``ref``: the FMU parameter (None for a nuisance parameter); ``name`` its text."""

    name: str
    initial: float
    lower: float
    upper: float
    scale: float
    unit: str
    display_unit: str
    display_factor: float  # SI value * display_factor = value in display_unit
    start_range: tuple[float, float]
    log_start: bool
    nuisance: bool = False
    key: str = ""
    ref: Ref | None = None

    def display(self, value: float) -> float:
        return value * self.display_factor


def _default_start_range(initial: float, lower: float, upper: float, scale: float) -> tuple[tuple[float, float], bool]:
    if math.isfinite(lower) and math.isfinite(upper) and upper - lower <= 100 * scale:
        return (lower, upper), False
    if initial > 0:
        lo, hi = max(initial / 4, lower), min(initial * 4, upper)
        return (lo, hi), lo > 0
    return (max(initial - 2 * scale, lower), min(initial + 2 * scale, upper)), False


def resolve_parameter(spec: ParameterSpec, unit: str, default: float, fmu_min: float | None,
                      fmu_max: float | None, display_unit: str,
                      fail: Callable[[str, str], NoReturn], default_source: str = "the scenario") -> Parameter:
    """The spec's values converted to SI and checked against the FMU's range; ``default`` is the
    scenario's (or the FMU's start) value, SI; ``fail(key, message)`` reports a problem."""
    factor = 1.0
    if spec.unit is not None:
        try:
            factor = unit_factor(spec.unit, unit)
        except UnitError as exc:
            fail(f"{spec.key}.unit", f"unit {spec.unit!r} does not fit {spec.name} (unit {unit or '1'!r}): {exc}")
    u = f" {unit}" if unit else ""  # a dimensionless parameter has no unit to print
    lo_fmu = -math.inf if fmu_min is None else fmu_min
    hi_fmu = math.inf if fmu_max is None else fmu_max
    lower = lo_fmu if spec.min is None else spec.min * factor
    upper = hi_fmu if spec.max is None else spec.max * factor
    if lower < lo_fmu or upper > hi_fmu:
        which = "min" if lower < lo_fmu else "max"
        fail(f"{spec.key}.{which}", f"bounds [{lower!r}, {upper!r}]{u} leave the FMU's range "
                                    f"[{lo_fmu!r}, {hi_fmu!r}]{u} of {spec.name}")
    if lower >= upper:
        fail(f"{spec.key}.max", f"bounds reversed or empty: [{lower!r}, {upper!r}]{u}")
    initial = default if spec.initial is None else spec.initial * factor
    if not lower <= initial <= upper:
        key = f"{spec.key}.initial" if spec.initial is not None else f"{spec.key}.min"
        fail(key, f"initial value {initial!r}{u} (from {'the spec' if spec.initial is not None else default_source})"
                  f" lies outside the bounds [{lower!r}, {upper!r}]{u}")
    scale = spec.scale * factor if spec.scale is not None else (abs(initial) if initial != 0 else 1.0)
    if spec.start_range is not None:
        start = (max(spec.start_range[0] * factor, lower), min(spec.start_range[1] * factor, upper))
        if start[0] >= start[1]:
            fail(f"{spec.key}.start_range", f"start range {spec.start_range} does not overlap the bounds")
        log_start = start[0] > 0 and start[1] / start[0] > 10
    else:
        start, log_start = _default_start_range(initial, lower, upper, scale)
    shown = spec.unit or display_unit or unit
    try:
        display_factor = unit_factor(unit, shown)
    except UnitError:
        shown, display_factor = unit, 1.0
    return Parameter(spec.name, initial, lower, upper, scale, unit, shown, display_factor, start, log_start, key=spec.key,
                     ref=spec.ref)


def draw_starts(parameters: Sequence[Parameter], starts: int, seed: int) -> np.ndarray:
    """starts x parameters, SI: row 0 the initial values, then a Latin hypercube over each
    parameter's start range (log-uniform where ``log_start``)."""
    p = len(parameters)
    out = np.empty((starts, p))
    out[0] = [q.initial for q in parameters]
    if starts > 1:
        rng = np.random.default_rng(seed)
        n = starts - 1
        u = (np.argsort(rng.random((p, n)), axis=1).T + rng.random((n, p))) / n
        for j, q in enumerate(parameters):
            lo, hi = q.start_range
            out[1:, j] = np.exp(np.log(lo) + u[:, j] * (np.log(hi) - np.log(lo))) if q.log_start else lo + u[:, j] * (hi - lo)
    return out

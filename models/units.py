"""Unit handling for the orchestrator.

The FMUs work in SI units and name them with the unit strings used in FMI model
descriptions (``"m"``, ``"m/s"``, ``"N.m"``, ...).  Recorded data and scenario files
may use other ("user") units such as ``"mm/min"`` or ``"rpm"``.  This module
converts between the two by a fixed table: every unit is a :class:`Unit` with a
dimension vector and a factor to the SI unit of that dimension, so that::

    value_in_SI = value_in_unit * unit.factor

Dimensions
----------
The dimension vector holds the exponents of ``(kg, m, s, A, rad)``, see
:data:`BASE_DIMENSIONS`.  The plane angle (``rad``) is treated as a *base
dimension* of its own, although SI counts it as dimensionless.  Consequences, by
design:

* ``"rad/s"``, ``"rpm"``, ``"rev/s"``, ``"1/min"`` and ``"deg"`` carry the angle
  dimension, so ``rpm -> rad/s`` converts with the factor 2*pi/60.
* ``"Hz"`` and ``"kHz"`` are plain frequencies (s^-1) *without* angle, so converting
  ``"Hz"`` to ``"rad/s"`` (or ``"rpm"`` to ``"Hz"``) is an error: a frequency is
  never silently taken as an angular velocity, nor the other way round.
* ``"rev/s"`` and ``"1/min"`` are **rotational speeds**: ``"rev/s"`` counts
  revolutions per second (1 rev/s = 2*pi rad/s) and ``"1/min"`` is the machining
  convention for spindle speed (min^-1, i.e. revolutions per minute, identical to
  ``"rpm"``).  They therefore convert to ``"rad/s"``, not to ``"Hz"``.
* Because the angle is a dimension, torque times angular velocity (``N.m*rad/s``) is
  not dimensionally ``W``; this module does no unit algebra, so that never matters
  here.

``"1"``, ``""`` (empty string, same as ``"1"``) and ``"%"`` (factor 0.01) are
dimensionless.  ``"bool"`` marks boolean signals: it has no dimension and no factor
and converts only to itself.

The known units are exactly the keys of :data:`UNITS`; there is no parsing of
compound expressions, so a misspelt unit is reported rather than guessed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, overload

import numpy as np
import numpy.typing as npt

__all__ = [
    "BASE_DIMENSIONS",
    "DISPLAY_UNITS",
    "SI_UNITS",
    "UNITS",
    "Unit",
    "UnitError",
    "conversion_factor",
    "convert",
    "dimension_name",
    "display_unit_of",
    "display_value",
    "format_quantity",
    "known_units",
    "parse_unit",
    "si_unit_of",
]

#: Names of the base dimensions, in the order of :attr:`Unit.dimensions`.
BASE_DIMENSIONS: Final[tuple[str, ...]] = ("kg", "m", "s", "A", "rad")

Dimensions = tuple[int, int, int, int, int]


class UnitError(ValueError):
    """An unknown unit, or a conversion between incompatible units."""


@dataclass(frozen=True)
class Unit:
    """A unit: its name, its dimension vector over :data:`BASE_DIMENSIONS` and
    the factor that converts a value in this unit to SI (``si = value * factor``).

    ``boolean`` is True only for the ``"bool"`` pseudo-unit.
    """

    name: str
    dimensions: tuple[int, ...]
    factor: float
    boolean: bool = False


def _d(kg: int = 0, m: int = 0, s: int = 0, a: int = 0, rad: int = 0) -> Dimensions:
    return (kg, m, s, a, rad)


_DIMENSIONLESS: Final = _d()
_LENGTH: Final = _d(m=1)
_VELOCITY: Final = _d(m=1, s=-1)
_ACCELERATION: Final = _d(m=1, s=-2)
_JERK: Final = _d(m=1, s=-3)
_TIME: Final = _d(s=1)
_ANGLE: Final = _d(rad=1)
_ANGULAR_VELOCITY: Final = _d(s=-1, rad=1)
_ANGULAR_ACCELERATION: Final = _d(s=-2, rad=1)
_POWER: Final = _d(kg=1, m=2, s=-3)
_FORCE: Final = _d(kg=1, m=1, s=-2)
_TORQUE: Final = _d(kg=1, m=2, s=-2)
_POWER_PER_ANGULAR_VELOCITY: Final = _d(kg=1, m=2, s=-2, rad=-1)
_TORQUE_PER_ANGULAR_VELOCITY: Final = _d(kg=1, m=2, s=-1, rad=-1)
_MOMENT_OF_INERTIA: Final = _d(kg=1, m=2)
_STIFFNESS: Final = _d(kg=1, s=-2)
_PRESSURE: Final = _d(kg=1, m=-1, s=-2)
_VOLUME_FLOW: Final = _d(m=3, s=-1)
_VOLUME: Final = _d(m=3)
_CURRENT: Final = _d(a=1)
_VOLTAGE: Final = _d(kg=1, m=2, s=-3, a=-1)
_FREQUENCY: Final = _d(s=-1)
_MASS: Final = _d(kg=1)

#: Human-readable names of the dimensions that occur in :data:`UNITS`.
_DIMENSION_NAMES: Final[dict[tuple[int, ...], str]] = {
    _DIMENSIONLESS: "dimensionless",
    _LENGTH: "length",
    _VELOCITY: "velocity",
    _ACCELERATION: "acceleration",
    _JERK: "jerk",
    _TIME: "time",
    _ANGLE: "angle",
    _ANGULAR_VELOCITY: "angular velocity",
    _ANGULAR_ACCELERATION: "angular acceleration",
    _POWER: "power",
    _FORCE: "force",
    _TORQUE: "torque",
    _POWER_PER_ANGULAR_VELOCITY: "power per angular velocity",
    _TORQUE_PER_ANGULAR_VELOCITY: "torque per angular velocity",
    _MOMENT_OF_INERTIA: "moment of inertia",
    _STIFFNESS: "stiffness",
    _PRESSURE: "pressure",
    _VOLUME_FLOW: "volume flow rate",
    _VOLUME: "volume",
    _CURRENT: "electric current",
    _VOLTAGE: "voltage",
    _FREQUENCY: "frequency",
    _MASS: "mass",
}

#: Canonical SI unit string (as in the FMUs' model descriptions) per dimension.
SI_UNITS: Final[dict[tuple[int, ...], str]] = {
    _DIMENSIONLESS: "1",
    _LENGTH: "m",
    _VELOCITY: "m/s",
    _ACCELERATION: "m/s2",
    _JERK: "m/s3",
    _TIME: "s",
    _ANGLE: "rad",
    _ANGULAR_VELOCITY: "rad/s",
    _ANGULAR_ACCELERATION: "rad/s2",
    _POWER: "W",
    _FORCE: "N",
    _TORQUE: "N.m",
    _POWER_PER_ANGULAR_VELOCITY: "W.s/rad",
    _TORQUE_PER_ANGULAR_VELOCITY: "N.m.s/rad",
    _MOMENT_OF_INERTIA: "kg.m2",
    _STIFFNESS: "N/m",
    _PRESSURE: "N/m2",
    _VOLUME_FLOW: "m3/s",
    _VOLUME: "m3",
    _CURRENT: "A",
    _VOLTAGE: "V",
    _FREQUENCY: "Hz",
    _MASS: "kg",
}

_TWO_PI: Final = 2.0 * math.pi


def _table() -> dict[str, Unit]:
    entries: list[tuple[str, Dimensions, float]] = [
        # SI units used by the FMUs
        ("m", _LENGTH, 1.0),
        ("m/s", _VELOCITY, 1.0),
        ("m/s2", _ACCELERATION, 1.0),
        ("m/s3", _JERK, 1.0),
        ("s", _TIME, 1.0),
        ("rad", _ANGLE, 1.0),
        ("rad/s", _ANGULAR_VELOCITY, 1.0),
        ("rad/s2", _ANGULAR_ACCELERATION, 1.0),
        ("W", _POWER, 1.0),
        ("N", _FORCE, 1.0),
        ("N.m", _TORQUE, 1.0),
        ("W.s/rad", _POWER_PER_ANGULAR_VELOCITY, 1.0),
        ("N.m.s/rad", _TORQUE_PER_ANGULAR_VELOCITY, 1.0),
        ("kg.m2", _MOMENT_OF_INERTIA, 1.0),
        ("N/m", _STIFFNESS, 1.0),
        ("N/m2", _PRESSURE, 1.0),
        ("m3/s", _VOLUME_FLOW, 1.0),
        ("m3", _VOLUME, 1.0),
        ("1", _DIMENSIONLESS, 1.0),
        ("A", _CURRENT, 1.0),
        ("V", _VOLTAGE, 1.0),
        ("Hz", _FREQUENCY, 1.0),
        ("kg", _MASS, 1.0),
        # user units
        ("mm", _LENGTH, 1e-3),
        ("um", _LENGTH, 1e-6),
        ("mm/s", _VELOCITY, 1e-3),
        ("mm/min", _VELOCITY, 1e-3 / 60.0),
        ("m/min", _VELOCITY, 1.0 / 60.0),
        ("mm/s2", _ACCELERATION, 1e-3),
        ("mm/s3", _JERK, 1e-3),
        ("min", _TIME, 60.0),
        ("ms", _TIME, 1e-3),
        ("rpm", _ANGULAR_VELOCITY, _TWO_PI / 60.0),
        ("rev/s", _ANGULAR_VELOCITY, _TWO_PI),
        ("rev/s2", _ANGULAR_ACCELERATION, _TWO_PI),
        ("1/min", _ANGULAR_VELOCITY, _TWO_PI / 60.0),
        ("deg", _ANGLE, math.pi / 180.0),
        ("kW", _POWER, 1e3),
        ("mW", _POWER, 1e-3),
        ("kN", _FORCE, 1e3),
        ("N.mm", _TORQUE, 1e-3),
        ("mm3/s", _VOLUME_FLOW, 1e-9),
        ("cm3/s", _VOLUME_FLOW, 1e-6),
        ("cm3/min", _VOLUME_FLOW, 1e-6 / 60.0),
        ("mm3/min", _VOLUME_FLOW, 1e-9 / 60.0),
        ("mm3", _VOLUME, 1e-9),
        ("cm3", _VOLUME, 1e-6),
        ("kHz", _FREQUENCY, 1e3),
        ("W/rpm", _POWER_PER_ANGULAR_VELOCITY, 60.0 / _TWO_PI),
        ("N/um", _STIFFNESS, 1e6),
        ("N/mm", _STIFFNESS, 1e3),
        ("N/mm2", _PRESSURE, 1e6),
        ("MPa", _PRESSURE, 1e6),
        ("%", _DIMENSIONLESS, 0.01),
    ]
    table = {name: Unit(name, dims, factor) for name, dims, factor in entries}
    table["bool"] = Unit("bool", _DIMENSIONLESS, 1.0, boolean=True)
    return table


#: All known units by name (read-only by convention; build your own dict to extend).
UNITS: Final[dict[str, Unit]] = _table()


def known_units() -> list[str]:
    """The names of all known units, in table order."""
    return list(UNITS)


def parse_unit(unit: str) -> Unit:
    """Look up a unit string.  ``""`` is the dimensionless unit ``"1"``.

    Raises :class:`UnitError` (naming the unit and listing the known units) for an
    unknown unit or a non-string argument.
    """
    if not isinstance(unit, str):
        raise UnitError(f"unit must be a string, got {unit!r} ({type(unit).__name__})")
    key = "1" if unit == "" else unit
    try:
        return UNITS[key]
    except KeyError:
        raise UnitError(
            f"unknown unit {unit!r}; known units: {', '.join(repr(u) for u in UNITS)}"
        ) from None


def dimension_name(dimensions: tuple[int, ...]) -> str:
    """A readable name for a dimension vector ("length", "power", ...)."""
    name = _DIMENSION_NAMES.get(tuple(dimensions))
    if name is not None:
        return name
    parts = [f"{base}^{exp}" for base, exp in zip(BASE_DIMENSIONS, dimensions) if exp]
    return " ".join(parts) if parts else "dimensionless"


def _describe(unit: Unit) -> str:
    return "boolean" if unit.boolean else dimension_name(unit.dimensions)


def conversion_factor(from_unit: str, to_unit: str) -> float:
    """The factor ``f`` with ``value_in_to_unit = value_in_from_unit * f``.

    Raises :class:`UnitError` for unknown units or if the dimensions differ, e.g.
    ``cannot convert 'mm' to 'W': dimensions differ (length vs power)``.
    ``"bool"`` converts only to ``"bool"`` (factor 1).
    """
    src = parse_unit(from_unit)
    dst = parse_unit(to_unit)
    if src.boolean or dst.boolean:
        if src.boolean and dst.boolean:
            return 1.0
        raise UnitError(
            f"cannot convert {from_unit!r} to {to_unit!r}: "
            f"booleans convert only to 'bool' ({_describe(src)} vs {_describe(dst)})"
        )
    if src.dimensions != dst.dimensions:
        raise UnitError(
            f"cannot convert {from_unit!r} to {to_unit!r}: dimensions differ "
            f"({_describe(src)} vs {_describe(dst)})"
        )
    if src.factor == dst.factor:
        return 1.0
    return src.factor / dst.factor


@overload
def convert(values: float, from_unit: str, to_unit: str) -> float: ...
@overload
def convert(values: np.ndarray, from_unit: str, to_unit: str) -> np.ndarray: ...
@overload
def convert(values: npt.ArrayLike, from_unit: str, to_unit: str) -> float | np.ndarray: ...


def convert(values: npt.ArrayLike, from_unit: str, to_unit: str) -> float | bool | np.ndarray:
    """Convert ``values`` from ``from_unit`` to ``to_unit``.

    Scalars (Python or NumPy) give a Python ``float``; anything array-like gives a new
    float64 :class:`numpy.ndarray` (the input is never modified).  ``"bool"`` to
    ``"bool"`` returns a ``bool`` or a bool array.
    """
    factor = conversion_factor(from_unit, to_unit)
    if parse_unit(from_unit).boolean:
        if np.ndim(values) == 0:
            return bool(np.asarray(values).item())
        return np.array(values, dtype=bool)
    if np.ndim(values) == 0:
        return float(np.asarray(values, dtype=np.float64)) * factor
    arr = np.array(values, dtype=np.float64)
    if factor != 1.0:
        arr *= factor
    return arr


def si_unit_of(unit: str) -> str:
    """The canonical SI unit string for the dimension of ``unit``.

    ``"mm/min" -> "m/s"``, ``"rpm" -> "rad/s"``, ``"kW" -> "W"``, ``"%" -> "1"``,
    ``"bool" -> "bool"``.
    """
    u = parse_unit(unit)
    if u.boolean:
        return "bool"
    try:
        return SI_UNITS[u.dimensions]
    except KeyError:  # only reachable if UNITS gains a unit of a new dimension
        raise UnitError(
            f"no SI unit known for {unit!r} (dimension {dimension_name(u.dimensions)})"
        ) from None


#: Units people read more easily than the SI units the FMUs compute in (the summaries and plots show
#: quantities in these; the FMUs' model descriptions declare the same ones as their variables' displayUnit).
DISPLAY_UNITS: Final[dict[str, str]] = {"W": "kW", "m3/s": "cm3/min", "m/s": "mm/min", "rad/s": "rpm", "m": "mm"}


def display_unit_of(unit: str) -> str:
    """The display unit of a quantity given in ``unit``: that of its SI unit in :data:`DISPLAY_UNITS`
    (``"W"`` and ``"kW"`` -> ``"kW"``), else ``unit`` itself (also for an unknown unit)."""
    try:
        si = si_unit_of(unit)
    except UnitError:
        return unit
    return DISPLAY_UNITS.get(si, unit)


def display_value(value: float, unit: str, display_unit: str | None = None) -> tuple[float, str]:
    """``value`` (in ``unit``) converted to ``display_unit`` (default :func:`display_unit_of`), and the
    unit it is in: ``unit`` itself when the display unit does not fit it or is unknown."""
    shown = display_unit_of(unit) if display_unit is None else display_unit
    if shown == unit:
        return value, unit
    try:
        return value * conversion_factor(unit, shown), shown
    except UnitError:
        return value, unit


def format_quantity(value: float, unit: str, display_unit: str | None = None, spec: str = ".4g") -> str:
    """``value`` (in ``unit``) as text in its display unit (see :func:`display_value`), formatted with
    ``spec``: ``format_quantity(1234.5, "W")`` -> ``"1.234 kW"``, ``format_quantity(0.5, "1")`` -> ``"0.5"``."""
    shown_value, shown = display_value(value, unit, display_unit)
    text = format(shown_value, spec)
    return f"{text} {shown}" if shown not in ("", "1") else text

"""Tests for models.units."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from milling_twin.models.units import (
    UNITS,
    Unit,
    UnitError,
    conversion_factor,
    convert,
    parse_unit,
    si_unit_of,
)

SI = ["m", "m/s", "m/s2", "s", "rad", "rad/s", "rad/s2", "W", "N", "N.m", "N.m.s/rad", "m3/s", "1", "A", "V", "Hz",
      "kg", "kg.m2"]
USER = [
    "mm", "um", "mm/s", "mm/min", "m/min", "mm/s2", "min", "ms", "rpm", "rev/s", "rev/s2", "1/min",
    "deg", "kW", "mW", "kN", "N.mm", "mm3/s", "cm3/s", "cm3/min", "mm3/min", "kHz", "%", "1",
    "bool",
]


@pytest.mark.parametrize("name", SI + USER)
def test_all_listed_units_are_known(name: str) -> None:
    unit = parse_unit(name)
    assert unit.name == name
    assert len(unit.dimensions) == 5


@pytest.mark.parametrize("name", SI)
def test_si_units_have_factor_one_and_are_their_own_si_unit(name: str) -> None:
    assert parse_unit(name).factor == 1.0
    assert si_unit_of(name) == name


def test_unit_is_frozen() -> None:
    unit = parse_unit("mm")
    assert isinstance(unit, Unit)
    with pytest.raises(dataclasses.FrozenInstanceError):
        unit.factor = 2.0  # type: ignore[misc]


def test_empty_string_is_dimensionless() -> None:
    assert parse_unit("") == parse_unit("1")
    assert si_unit_of("") == "1"
    assert conversion_factor("", "%") == pytest.approx(100.0)


def test_unknown_unit_names_unit_and_lists_known() -> None:
    with pytest.raises(UnitError) as info:
        parse_unit("furlong/fortnight")
    msg = str(info.value)
    assert "'furlong/fortnight'" in msg
    assert "known units" in msg
    for name in ("'mm/min'", "'rpm'", "'N.m'", "'bool'"):
        assert name in msg
    assert isinstance(info.value, ValueError)


def test_unit_lookup_is_case_sensitive() -> None:
    # "MW" (megawatt) must not silently become "mW" (milliwatt)
    with pytest.raises(UnitError, match="'MW'"):
        parse_unit("MW")


def test_non_string_unit_raises() -> None:
    with pytest.raises(UnitError, match="must be a string"):
        parse_unit(None)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("src", "dst", "factor"),
    [
        ("mm", "m", 1e-3),
        ("um", "mm", 1e-3),
        ("mm/s", "m/s", 1e-3),
        ("mm/min", "m/s", 1e-3 / 60),
        ("m/min", "mm/s", 1000 / 60),
        ("mm/s2", "m/s2", 1e-3),
        ("min", "s", 60.0),
        ("ms", "s", 1e-3),
        ("rpm", "rad/s", 2 * math.pi / 60),
        ("rev/s", "rad/s", 2 * math.pi),
        ("rev/s", "rpm", 60.0),
        ("rev/s2", "rad/s2", 2 * math.pi),
        ("1/min", "rpm", 1.0),
        ("deg", "rad", math.pi / 180),
        ("kW", "W", 1e3),
        ("mW", "W", 1e-3),
        ("kW", "mW", 1e6),
        ("kN", "N", 1e3),
        ("N.mm", "N.m", 1e-3),
        ("mm3/s", "m3/s", 1e-9),
        ("cm3/s", "m3/s", 1e-6),
        ("cm3/min", "m3/s", 1e-6 / 60),
        ("mm3/min", "m3/s", 1e-9 / 60),
        ("cm3/min", "mm3/s", 1000 / 60),
        ("kHz", "Hz", 1e3),
        ("%", "1", 0.01),
        ("1", "%", 100.0),
        ("bool", "bool", 1.0),
    ],
)
def test_conversion_factors(src: str, dst: str, factor: float) -> None:
    assert conversion_factor(src, dst) == pytest.approx(factor, rel=1e-12)
    if src != "bool":
        assert conversion_factor(dst, src) == pytest.approx(1 / factor, rel=1e-12)


def test_3200_rpm() -> None:
    assert convert(3200.0, "rpm", "rad/s") == pytest.approx(335.1032163829112)
    assert convert(53.3, "rev/s", "rpm") == pytest.approx(3198.0)


@pytest.mark.parametrize(
    ("src", "dst", "dims"),
    [
        ("mm", "W", "length vs power"),
        ("kW", "N.m", "power vs torque"),
        ("Hz", "rad/s", "frequency vs angular velocity"),
        ("rpm", "Hz", "angular velocity vs frequency"),
        ("deg", "1", "angle vs dimensionless"),
        ("mm/min", "mm/s2", "velocity vs acceleration"),
        ("cm3/min", "m/s", "volume flow rate vs velocity"),
        ("A", "V", "electric current vs voltage"),
        ("kg", "N", "mass vs force"),
        ("s", "Hz", "time vs frequency"),
        ("kg.m2", "kg", "moment of inertia vs mass"),
        ("rad/s2", "m/s2", "angular acceleration vs acceleration"),
        ("rad/s2", "rad/s", "angular acceleration vs angular velocity"),
        ("N.m.s/rad", "W.s/rad", "torque per angular velocity vs power per angular velocity"),
        ("N.m.s/rad", "N.m", "torque per angular velocity vs torque"),
    ],
)
def test_incompatible_dimensions(src: str, dst: str, dims: str) -> None:
    with pytest.raises(UnitError) as info:
        conversion_factor(src, dst)
    assert str(info.value) == f"cannot convert {src!r} to {dst!r}: dimensions differ ({dims})"


@pytest.mark.parametrize(("src", "dst"), [("bool", "1"), ("1", "bool"), ("%", "bool"), ("bool", "W")])
def test_bool_converts_only_to_bool(src: str, dst: str) -> None:
    with pytest.raises(UnitError) as info:
        conversion_factor(src, dst)
    msg = str(info.value)
    assert f"cannot convert {src!r} to {dst!r}" in msg
    assert "bool" in msg


def test_conversion_with_unknown_unit_names_it() -> None:
    with pytest.raises(UnitError, match="unknown unit 'inch'"):
        conversion_factor("inch", "m")
    with pytest.raises(UnitError, match="unknown unit 'inch'"):
        convert(1.0, "m", "inch")


def test_convert_scalar_returns_float() -> None:
    out = convert(1500, "mm/min", "m/s")
    assert isinstance(out, float)
    assert out == pytest.approx(0.025)
    out = convert(np.float32(2.0), "kW", "W")
    assert isinstance(out, float)
    assert out == 2000.0


def test_convert_array_returns_new_float_array() -> None:
    values = np.array([0, 1, 2], dtype=np.int64)
    out = convert(values, "kW", "W")
    assert isinstance(out, np.ndarray)
    assert out.dtype == np.float64
    np.testing.assert_allclose(out, [0.0, 1000.0, 2000.0])
    assert values.tolist() == [0, 1, 2]  # input untouched

    same = np.array([1.0, 2.0])
    out2 = convert(same, "m", "m")
    assert out2 is not same
    out2[0] = 99.0
    assert same[0] == 1.0


def test_convert_2d_array_and_list() -> None:
    out = convert([[60.0, 120.0], [0.0, 30.0]], "rpm", "rev/s")
    assert isinstance(out, np.ndarray)
    assert out.shape == (2, 2)
    np.testing.assert_allclose(out, [[1.0, 2.0], [0.0, 0.5]])


def test_convert_bool() -> None:
    assert convert(True, "bool", "bool") is True
    out = convert(np.array([1, 0, 1]), "bool", "bool")
    assert out.dtype == np.bool_
    assert out.tolist() == [True, False, True]


@pytest.mark.parametrize(
    ("unit", "si"),
    [
        ("mm/min", "m/s"),
        ("rpm", "rad/s"),
        ("rev/s", "rad/s"),
        ("1/min", "rad/s"),
        ("kW", "W"),
        ("mW", "W"),
        ("cm3/min", "m3/s"),
        ("mm3/s", "m3/s"),
        ("mm", "m"),
        ("um", "m"),
        ("mm/s2", "m/s2"),
        ("min", "s"),
        ("ms", "s"),
        ("deg", "rad"),
        ("kN", "N"),
        ("N.mm", "N.m"),
        ("kHz", "Hz"),
        ("%", "1"),
        ("bool", "bool"),
    ],
)
def test_si_unit_of(unit: str, si: str) -> None:
    assert si_unit_of(unit) == si
    if unit != "bool":
        assert conversion_factor(si, si) == 1.0
        assert parse_unit(si).dimensions == parse_unit(unit).dimensions


def test_si_unit_of_unknown() -> None:
    with pytest.raises(UnitError, match="unknown unit 'parsec'"):
        si_unit_of("parsec")


def test_every_table_unit_has_an_si_unit() -> None:
    for name, unit in UNITS.items():
        si = si_unit_of(name)
        if unit.boolean:
            assert si == "bool"
        else:
            assert convert(1.0, name, si) == pytest.approx(unit.factor)


def test_units_of_the_spindle_dynamics() -> None:
    """SpindlePower's J_spindle (kg.m2), k_speed_loop (N.m.s/rad) and spindle_acceleration (rad/s2): each the SI
    unit of a dimension of its own, which the model descriptions declare with these base units."""
    assert parse_unit("kg.m2").dimensions == (1, 2, 0, 0, 0)
    assert parse_unit("N.m.s/rad").dimensions == (1, 2, -1, 0, -1)
    assert parse_unit("rad/s2").dimensions == (0, 0, -2, 0, 1)
    for name in ("kg.m2", "N.m.s/rad", "rad/s2"):
        assert si_unit_of(name) == name and parse_unit(name).factor == 1.0

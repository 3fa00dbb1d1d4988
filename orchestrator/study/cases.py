"""The cases of a study file: ``[study.grid]``, ``[study.list]``, ``[study.sample]``, ``[study.distributions]``.

Each section is a table or an array of tables (``[[study.grid]]``); the cases of all sections are concatenated in
file order (grid, list, sample, distributions), then ``[study.set]`` is added to every case. A case is
``{"instance.variable": value}`` in the form :func:`~milling_twin.orchestrator.scenario.with_values` takes: a number
(SI), true/false, text, or ``{"value": v, "unit": "rpm"}``. Text goes through the ``--set`` parser
(:func:`milling_twin.cli.parse_override`), so ``"6000rpm"`` is 6000 rpm; ``{ path = "..." }`` is a file relative to
the study file. Variables are named ``"instance.variable"`` (quoted) or as a table per instance (``force.axial_depth
= ...`` in TOML).

- grid: per variable a list of values, ``{ values = [...], unit = "mm" }`` or ``{ start, stop, num, unit }``
  (``num`` evenly spaced values, both ends included, to 15 significant digits); the cases are the cartesian
  product (the first variable varies slowest).
- list: per variable a list of values, all of one length; case i takes the i-th value of each (explicit cases).
- sample: ``method = "lhs"`` (Latin hypercube) or ``"sobol"`` (scrambled; ``n`` a power of 2), ``n``, ``seed``
  (default 0) and per variable ``{ min, max, unit }`` (``scipy.stats.qmc``); a range of two whole numbers without
  unit gives whole numbers (rounded).
- distributions (Monte Carlo): ``n``, ``seed`` (default 0) and per variable ``{ kind = "normal", mean, std }``,
  ``{ kind = "uniform", min, max }`` or ``{ kind = "lognormal", median, sigma }`` (``sigma`` of the logarithm),
  each with an optional ``unit``; drawn with ``numpy.random.default_rng(seed)``, variable by variable in file order.

The case id is the first 16 hex digits of the SHA-256 of the case's values (canonical JSON, keys sorted) and of the
study's ``stop_time`` when it sets one: the same values give the same id in every study run, which ``--resume`` uses.
"""
from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Iterator, Mapping
from itertools import product
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

Fail = Callable[[str, str], NoReturn]
Value = Any  # float | int | bool | str | {"value": float, "unit": str}

SECTIONS = ("grid", "list", "sample", "distributions")
SAMPLE_KEYS = ("method", "n", "seed")
DISTRIBUTION_KEYS = ("n", "seed")
DISTRIBUTIONS = {"normal": ("mean", "std"), "uniform": ("min", "max"), "lognormal": ("median", "sigma")}


def case_id(values: Mapping[str, Value], stop_time: float | None = None) -> str:
    """The stable id of a case (see the module docstring)."""
    payload: dict[str, Any] = {"values": dict(values)}
    if stop_time is not None:
        payload["stop_time"] = stop_time
    text = json.dumps(payload, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def variables_of(table: Mapping[str, Any], key: str, fail: Fail,
                 reserved: tuple[str, ...] = ()) -> Iterator[tuple[str, str, Any]]:
    """(``"instance.variable"``, its TOML key, its entry) of a section's table, in file order; an instance may be
    a table of its variables. ``reserved`` keys (n, seed, ...) are skipped."""
    for name, entry in table.items():
        if name in reserved:
            continue
        if "." in name:
            instance, _, variable = name.partition(".")
            if not instance or not variable:
                fail(f"{key}.{name}", 'expected "instance.variable"')
            yield name, f'{key}."{name}"', entry
        elif isinstance(entry, dict) and entry and all(isinstance(v, (list, dict)) for v in entry.values()):
            for variable, inner in entry.items():
                yield f"{name}.{variable}", f"{key}.{name}.{variable}", inner
        else:
            known = f"; keys of this section: {', '.join(reserved)}" if reserved else ""
            fail(f"{key}.{name}", f"expected a variable \"instance.variable\" or a table of an instance's "
                                  f"variables, got {entry!r}{known}")


def _number(value: Any, key: str, fail: Fail, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(key, f"expected a finite number, got {value!r}")
    if positive and value <= 0:
        fail(key, f"must be > 0, got {value!r}")
    return float(value)


def _unit(table: Mapping[str, Any], key: str, fail: Fail) -> str | None:
    unit = table.get("unit")
    if unit is not None and (not isinstance(unit, str) or not unit.strip()):
        fail(f"{key}.unit", f"expected a unit, e.g. \"mm\", got {unit!r}")
    return unit


def _with_unit(x: float, unit: str | None) -> Value:
    return {"value": x, "unit": unit} if unit else x


def value_of(raw: Any, name: str, key: str, fail: Fail, base: Path, unit: str | None = None) -> Value:
    """One value as with_values takes it (see the module docstring); ``unit`` applies to a bare number."""
    from milling_twin.cli import UsageError, parse_override

    if isinstance(raw, bool):
        return raw
    if isinstance(raw, (int, float)):
        if not math.isfinite(raw):
            fail(key, f"expected a finite number, got {raw!r}")
        return _with_unit(raw, unit)
    if isinstance(raw, str):
        if unit is not None:
            fail(key, f"{raw!r}: a text value takes no unit={unit!r}")
        try:
            return parse_override(f"{name}={raw}")[1]
        except UsageError as exc:
            fail(key, str(exc))
    if isinstance(raw, dict) and set(raw) == {"path"} and isinstance(raw["path"], str):
        return str((base / raw["path"]).resolve())
    if isinstance(raw, dict) and "value" in raw and set(raw) <= {"value", "unit"}:
        if unit is not None:
            fail(key, f"{raw!r} has its own unit; remove unit={unit!r}")
        _number(raw["value"], f"{key}.value", fail)
        if "unit" not in raw:
            return raw["value"]
        if not isinstance(raw["unit"], str) or not raw["unit"].strip():
            fail(f"{key}.unit", f"expected a unit, e.g. \"mm\", got {raw['unit']!r}")
        return {"value": raw["value"], "unit": raw["unit"]}
    fail(key, f"expected a number, true/false, text (\"6000rpm\"), {{ value = ..., unit = ... }} or "
              f"{{ path = ... }}, got {raw!r}")


def _value_list(entry: Any, name: str, key: str, fail: Fail, base: Path, grid: bool) -> list[Value]:
    if isinstance(entry, list):
        raw, unit = entry, None
    elif isinstance(entry, dict) and "values" in entry:
        extra = set(entry) - {"values", "unit"}
        if extra:
            fail(f"{key}.{sorted(extra)[0]}", "unknown key; with values = [...] only unit is allowed")
        raw, unit = entry["values"], _unit(entry, key, fail)
        if not isinstance(raw, list):
            fail(f"{key}.values", f"expected a list, got {raw!r}")
    elif grid and isinstance(entry, dict) and {"start", "stop", "num"} <= set(entry):
        extra = set(entry) - {"start", "stop", "num", "unit"}
        if extra:
            fail(f"{key}.{sorted(extra)[0]}", "unknown key; a range takes start, stop, num and unit")
        num = entry["num"]
        if isinstance(num, bool) or not isinstance(num, int) or num < 1:
            fail(f"{key}.num", f"expected a whole number >= 1, got {num!r}")
        start = _number(entry["start"], f"{key}.start", fail)
        stop = _number(entry["stop"], f"{key}.stop", fail)
        # 15 significant digits: 0.02, not linspace's 0.019999999999999997
        raw, unit = [float(f"{x:.15g}") for x in np.linspace(start, stop, num)], _unit(entry, key, fail)
    else:
        forms = "a list, { values = [...], unit = ... }" + (" or { start, stop, num, unit }" if grid else "")
        fail(key, f"expected {forms}, got {entry!r}")
    if not raw:
        fail(key, "no values")
    return [value_of(v, name, f"{key}[{i}]", fail, base, unit) for i, v in enumerate(raw)]


def grid_cases(table: Mapping[str, Any], key: str, fail: Fail, base: Path) -> list[dict[str, Value]]:
    axes = [(name, _value_list(entry, name, k, fail, base, grid=True)) for name, k, entry in
            variables_of(table, key, fail)]
    if not axes:
        fail(key, "no variables")
    names = [name for name, _ in axes]
    return [dict(zip(names, combo)) for combo in product(*(values for _, values in axes))]


def list_cases(table: Mapping[str, Any], key: str, fail: Fail, base: Path) -> list[dict[str, Value]]:
    columns = [(name, k, _value_list(entry, name, k, fail, base, grid=False)) for name, k, entry in
               variables_of(table, key, fail)]
    if not columns:
        fail(key, "no variables")
    n = len(columns[0][2])
    for name, k, values in columns[1:]:
        if len(values) != n:
            fail(k, f"{len(values)} values, but {columns[0][0]} has {n}: each list gives one value per case")
    return [{name: values[i] for name, _, values in columns} for i in range(n)]


def _count(table: Mapping[str, Any], key: str, fail: Fail) -> tuple[int, int]:
    n, seed = table.get("n"), table.get("seed", 0)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        fail(f"{key}.n", f"expected the number of cases, a whole number >= 1, got {n!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        fail(f"{key}.seed", f"expected a whole number >= 0, got {seed!r}")
    return n, seed


def sample_cases(table: Mapping[str, Any], key: str, fail: Fail) -> list[dict[str, Value]]:
    from scipy.stats import qmc

    method = table.get("method")
    if method not in ("lhs", "sobol"):
        fail(f"{key}.method", f"expected \"lhs\" (Latin hypercube) or \"sobol\", got {method!r}")
    n, seed = _count(table, key, fail)
    ranges = []
    for name, k, entry in variables_of(table, key, fail, SAMPLE_KEYS):
        if not isinstance(entry, dict) or not {"min", "max"} <= set(entry) or set(entry) - {"min", "max", "unit"}:
            fail(k, f"expected {{ min = ..., max = ..., unit = ... }}, got {entry!r}")
        lo, hi = _number(entry["min"], f"{k}.min", fail), _number(entry["max"], f"{k}.max", fail)
        if not lo < hi:
            fail(k, f"min {lo!r} must be < max {hi!r}")
        unit = _unit(entry, k, fail)
        whole = unit is None and all(isinstance(entry[b], int) and not isinstance(entry[b], bool)
                                     for b in ("min", "max"))
        ranges.append((name, lo, hi, unit, whole))
    if not ranges:
        fail(key, "no variables to sample")
    d = len(ranges)
    if method == "sobol":
        m = n.bit_length() - 1
        if n != 1 << m:
            fail(f"{key}.n", f"{n}: a Sobol sample needs a power of 2 (e.g. {1 << m} or {2 << m})")
        unit_cube = qmc.Sobol(d, scramble=True, rng=np.random.default_rng(seed)).random_base2(m)
    else:
        unit_cube = qmc.LatinHypercube(d, rng=np.random.default_rng(seed)).random(n)
    points = qmc.scale(unit_cube, [r[1] for r in ranges], [r[2] for r in ranges])
    cases = []
    for row in points:
        case: dict[str, Value] = {}
        for (name, _, _, unit, whole), x in zip(ranges, row):
            case[name] = int(round(float(x))) if whole else _with_unit(float(x), unit)
        cases.append(case)
    return cases


def distribution_cases(table: Mapping[str, Any], key: str, fail: Fail) -> list[dict[str, Value]]:
    n, seed = _count(table, key, fail)
    rng = np.random.default_rng(seed)
    columns = []
    for name, k, entry in variables_of(table, key, fail, DISTRIBUTION_KEYS):
        if not isinstance(entry, dict):
            fail(k, f"expected {{ kind = \"normal\", mean = ..., std = ... }} (or uniform, lognormal), got {entry!r}")
        kind = entry.get("kind")
        if kind not in DISTRIBUTIONS:
            fail(f"{k}.kind", f"expected one of {', '.join(DISTRIBUTIONS)}, got {kind!r}")
        params = DISTRIBUTIONS[kind]
        extra = set(entry) - {"kind", "unit", *params}
        if extra:
            fail(f"{k}.{sorted(extra)[0]}", f"unknown key; a {kind} distribution takes {', '.join(params)}, unit")
        a = _number(entry.get(params[0]), f"{k}.{params[0]}", fail, positive=kind == "lognormal")
        b = _number(entry.get(params[1]), f"{k}.{params[1]}", fail, positive=kind != "uniform")
        unit = _unit(entry, k, fail)
        if kind == "normal":
            draws = rng.normal(a, b, n)
        elif kind == "uniform":
            if not a < b:
                fail(k, f"min {a!r} must be < max {b!r}")
            draws = rng.uniform(a, b, n)
        else:
            draws = a * np.exp(rng.normal(0.0, b, n))
        columns.append((name, unit, draws))
    if not columns:
        fail(key, "no variables to draw")
    return [{name: _with_unit(float(draws[i]), unit) for name, unit, draws in columns} for i in range(n)]

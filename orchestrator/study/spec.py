"""A study file, read and checked: the base scenario, the cases and the reductions (docs/studies.md).

    [study]
    name = "spindle_depth"
    base = "../scenarios/chatter.toml"    # a plain or whole-part scenario, relative to this file
    stop_time = 0.05                      # optional: every case ends here (s) instead of the scenario's stop time
    [study.set]                           # optional: values every case takes
    [study.grid] / [study.list] / [study.sample] / [study.distributions]   (orchestrator/study/cases.py)
    [[study.reduce]]                      # what each case gives the summary (orchestrator/study/reduce.py)
    kind = "max"
    variable = "force.Fx"
    [study.refine]                        # optional: more cases where an output crosses a threshold (refine.py)

Every error is a :class:`StudyError` naming the study file and the key. The variables and values of grids and lists
are checked against the base scenario here (``with_values``: causality, type, unit, range), those of samples at
their bounds and of distributions once; a drawn value outside a variable's range fails its case only.
"""
from __future__ import annotations

import inspect
import math
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from milling_twin.orchestrator.safe_names import name_problem
from milling_twin.orchestrator.scenario import Scenario, ScenarioError, load_scenario, with_values
from milling_twin.orchestrator.study import cases as cases_mod
from milling_twin.orchestrator.study.reduce import PROCESS_FIGURES, STATISTICS, get_reduction
from milling_twin.orchestrator.study.refine import RefineSpec, read_refine
from milling_twin.orchestrator.toml_access import FileKeyError, TomlAccess

__all__ = ["Case", "ReduceSpec", "Study", "StudyError", "load_study"]

STUDY_KEYS = ("name", "description", "base", "stop_time", "set", "grid", "list", "sample", "distributions",
              "reduce", "post", "refine")


class StudyError(FileKeyError):
    """An invalid study file: names the file and the key."""


@dataclass(frozen=True)
class Case:
    case_id: str
    values: dict[str, Any]  # {"instance.variable": value as with_values takes it}
    source: str  # the section that made it, e.g. "[study.grid]", "[[study.sample]][1]"


@dataclass(frozen=True)
class ReduceSpec:
    kind: str
    options: dict[str, Any]
    key: str  # "[[study.reduce]][i]", for messages


@dataclass(frozen=True)
class Study:
    path: Path
    name: str
    description: str
    base: Scenario  # FMU paths absolute: the cases run in other processes and folders
    stop_time: float | None
    cases: tuple[Case, ...]
    reductions: tuple[ReduceSpec, ...]
    post: str | None = None  # [study] post: the post-processor run after the cases (orchestrator/study/post.py)
    post_config: Any = field(default=None, compare=False)  # what its check made of [study.<its table>]
    refine: RefineSpec | None = None  # [study.refine]: rounds of cases where an output crosses a threshold

    @property
    def variables(self) -> tuple[str, ...]:
        """Every variable some case sets, in order of first appearance (the summary's input columns)."""
        return variables_of_cases(self.cases)

    def scenario(self) -> Scenario:
        """The base scenario as every case starts from (with the study's stop time)."""
        return self.base if self.stop_time is None else replace(self.base, stop_time=self.stop_time)


def variables_of_cases(cases: Iterable[Case]) -> tuple[str, ...]:
    """Every variable some of ``cases`` sets, in order of first appearance."""
    return tuple(dict.fromkeys(name for case in cases for name in case.values))


class _Reader(TomlAccess):
    error = StudyError


def _blocks(reader: _Reader, study: dict, name: str) -> list[tuple[str, dict]]:
    value = study.get(name)
    if value is None:
        return []
    if isinstance(value, dict):
        return [(f"[study.{name}]", value)]
    if isinstance(value, list) and all(isinstance(v, dict) for v in value):
        return [(f"[[study.{name}]][{i}]", v) for i, v in enumerate(value)]
    reader.fail(f"study.{name}", f"expected a table or an array of tables, got {value!r}")


def _check_values(reader: _Reader, scenario: Scenario, key: str, values: dict[str, Any]) -> None:
    try:
        with_values(scenario, values)
    except ScenarioError as exc:
        reader.fail(key, exc.detail)


def _reductions(reader: _Reader, study: dict, scenario: Scenario) -> tuple[ReduceSpec, ...]:
    value = study.get("reduce", [])
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        reader.fail("study.reduce", f"expected [[study.reduce]] tables, got {value!r}")
    recorded = [str(r) for r in scenario.outputs]
    specs = []
    for i, table in enumerate(value):
        key = f"[[study.reduce]][{i}]"
        kind = table.get("kind")
        if not isinstance(kind, str):
            reader.fail(f"{key}.kind", f"expected the reduction's name (max, min, mean, rms, machining_time, "
                                       f"rms_error, a registered one), got {kind!r}")
        try:
            fn = get_reduction(kind)
        except KeyError as exc:
            reader.fail(f"{key}.kind", str(exc.args[0]))
        options = {k: v for k, v in table.items() if k != "kind"}
        if kind in STATISTICS:
            for option in options:
                if option not in ("variable", "where", "name"):
                    reader.fail(f"{key}.{option}", f"unknown key; {kind} takes variable, where and name")
            for option in ("variable", "where"):
                if option not in options and option == "where":
                    continue
                ref = options.get(option)
                if ref not in recorded:
                    reader.fail(f"{key}.{option}", f"{ref!r} is not a recorded output of {scenario.path.name} "
                                                   f"([outputs].record: {', '.join(recorded)})")
        if kind == "process_report":
            if scenario.part is None:
                reader.fail(f"{key}.kind", f"process_report needs a whole-part scenario ([part]); {scenario.path} "
                                           "is not one")
            fields = options.get("fields", list(PROCESS_FIGURES))
            if not isinstance(fields, list) or not fields or any(f not in PROCESS_FIGURES for f in fields):
                reader.fail(f"{key}.fields", f"expected a list of {', '.join(PROCESS_FIGURES)}, got {fields!r}")
        if kind == "rms_error" and not scenario.compare:
            reader.fail(f"{key}.kind", f"rms_error needs [[compare]] pairs; {scenario.path} has none")
        if "name" in options and not isinstance(options["name"], str):
            reader.fail(f"{key}.name", f"expected the output's name, got {options['name']!r}")
        try:
            inspect.signature(fn).bind(None, **options)
        except TypeError as exc:
            reader.fail(key, f"{kind}: {exc}")
        except ValueError:  # a builtin without a signature: checked when it runs
            pass
        specs.append(ReduceSpec(kind, options, key))
    if not specs:
        reader.fail("study.reduce", "no [[study.reduce]]: say what each case gives the summary (e.g. kind = "
                                    "\"max\", variable = \"force.Fx\")")
    return tuple(specs)


def load_study(path: str | Path, fmu_dir: str | Path) -> Study:
    """Read and check a study file; the base scenario is loaded with ``fmu_dir`` (made absolute)."""
    path = Path(path)
    reader = _Reader(path)
    _, doc = reader.parse("study file")
    if set(doc) != {"study"}:
        other = sorted(set(doc) - {"study"})
        if "study" not in doc:
            hint = " (a scenario file: use `milling-twin run`)" if "scenario" in doc else ""
            reader.fail("study", f"missing required table [study]{hint}")
        reader.fail(other[0], "unknown table; a study file holds [study] and its sub-tables only")
    study = doc["study"]
    if not isinstance(study, dict):
        reader.fail("study", f"expected a table, got {study!r}")
    post_name, post_config, post_table = _post(reader, study)
    known_keys = (*STUDY_KEYS, *((post_table,) if post_table else ()))
    for name in study:
        if name not in known_keys:
            reader.fail(f"study.{name}", f"unknown key {name!r}; known keys: {', '.join(known_keys)}")
    name = study.get("name")
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "_-." for c in name):
        reader.fail("study.name", f"expected a name of letters, digits, '_', '-', '.' (the output folder), "
                                  f"got {name!r}")
    if name_problem(name) is not None:
        reader.fail("study.name", f"{name!r} {name_problem(name)}: it names the output folder <out>/<name>/")
    description = study.get("description", "")
    if not isinstance(description, str):
        reader.fail("study.description", f"expected text, got {description!r}")
    base_text = study.get("base")
    if not isinstance(base_text, str):
        reader.fail("study.base", f"expected the base scenario's path (relative to the study file), got {base_text!r}")
    base_path = (path.parent / base_text).resolve()
    if not base_path.is_file():
        reader.fail("study.base", f"no scenario file {base_path}")
    try:
        base = load_scenario(base_path, Path(fmu_dir).resolve())
    except ScenarioError as exc:
        reader.fail("study.base", f"the base scenario is invalid: {exc}")
    stop_time = study.get("stop_time")
    if stop_time is not None:
        if isinstance(stop_time, bool) or not isinstance(stop_time, (int, float)) or not math.isfinite(stop_time) \
                or stop_time <= base.start_time:
            reader.fail("study.stop_time", f"expected a time in s after the scenario's start "
                                           f"({base.start_time:g} s), got {stop_time!r}")
        stop_time = float(stop_time)
    folder = path.parent.resolve()
    fixed: dict[str, Any] = {}
    set_table = study.get("set", {})
    if not isinstance(set_table, dict):
        reader.fail("study.set", f"expected a table of values, got {set_table!r}")
    for variable, key, raw in cases_mod.variables_of(set_table, "[study.set]", reader.fail):
        fixed[variable] = cases_mod.value_of(raw, variable, key, reader.fail, folder)
    if fixed:
        _check_values(reader, base, "[study.set]", fixed)
    made: list[tuple[str, dict[str, Any]]] = []
    for section in cases_mod.SECTIONS:
        for key, table in _blocks(reader, study, section):
            if section == "grid":
                found = cases_mod.grid_cases(table, key, reader.fail, folder)
            elif section == "list":
                found = cases_mod.list_cases(table, key, reader.fail, folder)
            elif section == "sample":
                found = cases_mod.sample_cases(table, key, reader.fail)
            else:
                found = cases_mod.distribution_cases(table, key, reader.fail)
            _check_section(reader, base, key, section, table, found)
            made.extend((key, case) for case in found)
    if not made:
        reader.fail("study", "no cases: give [study.grid], [study.list], [study.sample] or [study.distributions]")
    overlap = [name for name in fixed if any(name in case for _, case in made)]
    if overlap:
        reader.fail(f"[study.set].{overlap[0]}", "also varied by the cases; set it in one place")
    cases: dict[str, Case] = {}
    for source, values in made:
        values = {**values, **fixed}
        cid = cases_mod.case_id(values, stop_time)
        cases.setdefault(cid, Case(cid, values, source))  # the same values twice: one case
    refine = read_refine(study["refine"], variables_of_cases(cases.values()), reader.fail) if "refine" in study \
        else None
    return Study(path, name, description, base, stop_time, tuple(cases.values()), _reductions(reader, study, base),
                 post_name, post_config, refine)


def _post(reader: _Reader, study: dict) -> tuple[str | None, Any, str | None]:
    """``[study] post`` and its options' table: (name, config, table name)."""
    from milling_twin.orchestrator.study.post import get_post

    name = study.get("post")
    if name is None:
        return None, None, None
    if not isinstance(name, str):
        reader.fail("study.post", f"expected the name of a post-processor, got {name!r}")
    try:
        post = get_post(name)
    except KeyError as exc:
        reader.fail("study.post", str(exc.args[0]))
    table = study.get(post.table, {})
    try:
        config = post.check(table, str(reader.path))
    except StudyError:
        raise
    except ValueError as exc:
        detail = str(exc).removeprefix(f"{reader.path}: ")
        key = f"[study.{post.table}]"
        if detail.startswith(key):
            key, _, detail = detail.partition(": ")
        reader.fail(key, detail)
    return name, config, post.table


def _check_section(reader: _Reader, base: Scenario, key: str, section: str, table: dict,
                   found: list[dict[str, Any]]) -> None:
    """Grids and lists: every distinct value; samples: the bounds (the first and the extreme cases);
    distributions: the first case (names, types and units)."""
    if section in ("grid", "list"):
        seen: set[tuple[str, str]] = set()
        for case in found:
            for variable, value in case.items():
                token = (variable, repr(value))
                if token not in seen:
                    seen.add(token)
                    _check_values(reader, base, f"{key}.{variable}", {variable: value})
        return
    if section == "sample":
        for variable, entry_key, entry in cases_mod.variables_of(table, key, reader.fail, cases_mod.SAMPLE_KEYS):
            unit = entry.get("unit")
            for bound in ("min", "max"):
                value = cases_mod.value_of(entry[bound], variable, f"{entry_key}.{bound}", reader.fail,
                                           reader.path.parent, unit)
                _check_values(reader, base, f"{entry_key}.{bound}", {variable: value})
        return
    _check_values(reader, base, key, found[0])

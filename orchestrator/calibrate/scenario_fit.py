"""Kind "scenario": fit parameters of a scenario's FMU instances to its recorded data, closing the loop.

Stages (each timed for the report):

1. **check**: the spec's names against the scenario and its FMUs (fail fast, naming the spec key);
   the derivative path (``[solver].derivatives``): **exact**, the casadi graph of the fitted outputs
   from models/ (:mod:`milling_twin.orchestrator.calibrate.graph`), each FMU's instantiation token equal to its
   models/ definition's (the FMU was generated from these very equations; otherwise: rebuild); or
   **FMU finite differences** (:mod:`milling_twin.orchestrator.calibrate.fmu_outputs`) where the graph cannot
   express the outputs ("auto") or on request: every evaluation re-simulates the scenario.
2. **simulate**: the scenario with the initial values through the orchestrator (FMUs), recording
   the fitted outputs, the inputs the graph reads as data, and the alignment channels.
3. **align**: recorded samples -> simulated rows (:mod:`milling_twin.orchestrator.calibrate.pairing`), split into
   learning and validation segments; the graph (or the FMU re-simulation) evaluated at the initial
   values must reproduce the FMU's outputs at the learning pairs (reported, and an error beyond 1e-8
   relative).
4. **fit**: multi-start on the learning pairs (:mod:`milling_twin.orchestrator.calibrate.fit`; IPOPT on the exact path,
   projected Levenberg-Marquardt on the FMU path), statistics.
   With an alignment method, the fit is repeated once on identity pairs to show what the alignment
   changed.
5. **write**: the parameter set (TOML the scenarios apply by name, and an .ssv copy) into the output
   folder, under the file name of the spec's ``parameter_set``.
6. **re-simulate**: ``calibrated_scenario`` if the spec names one (it must apply the spec's
   ``parameter_set`` by name; the set just written is applied after it, so it wins), else the scenario
   with the set applied; errors before/after on learning and validation data from the FMU runs. Then,
   only if asked (``write_set``), the set is published (e.g. to the spec's ``parameter_set``).

Overrides (``calibrate(..., overrides=...)``) change the scenario before stage 1, as a parameter set's
values would; in the re-simulation they apply before the calibrated set (a fitted value wins).
"""
from __future__ import annotations

import inspect
import os
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
import pandas as pd

from milling_twin.models import MODELS
from milling_twin.models.definition import ModelDefinition
from milling_twin.models.units import UnitError
from milling_twin.orchestrator.calibrate.errors import CalibrationError
from milling_twin.orchestrator.calibrate.fit import FitOutcome, fit
from milling_twin.orchestrator.calibrate.fmu_outputs import FmuOutputs, fmu_residuals
from milling_twin.orchestrator.calibrate.graph import ModelGraph, NotExpressible, build_graph
from milling_twin.orchestrator.calibrate.pairing import LEARNING, VALIDATION, Pairs, make_pairs
from milling_twin.orchestrator.calibrate.parameters import Parameter, resolve_parameter, unit_factor
from milling_twin.orchestrator.calibrate.parallel import calibration_executor
from milling_twin.orchestrator.calibrate.paramset import write_parameter_set, write_ssv
from milling_twin.orchestrator.calibrate.residuals import ResidualModel, build_residuals
from milling_twin.orchestrator.calibrate.result import CalibrationResult, Series, Table, error_row
from milling_twin.orchestrator.calibrate.spec import AlignmentSpec, CalibrationSpec, SolverSpec
from milling_twin.orchestrator.master import SimulationError, run
from milling_twin.orchestrator.results import load_results, sha256_of, software_versions
from milling_twin.orchestrator.scenario import Ref, Scenario, load_scenario, with_values

__all__ = ["Prepared", "calibrate_scenario", "check_tokens", "identities", "prepare", "resolve_outputs"]

CONSISTENCY_TOLERANCE = 1e-8


@dataclass(frozen=True)
class ResolvedOutput:
    ref: Ref
    channel: str
    factor: float  # recorded SI value * factor = output unit
    unit: str
    display_unit: str
    display_factor: float
    weight: float
    sigma: float | None  # SI of the output

    @property
    def column(self) -> str:
        """The output's column in the results."""
        return str(self.ref)


@dataclass
class Prepared:
    """Everything up to the fit: reused by the synthetic benchmarks for many noisy data sets."""

    spec: CalibrationSpec
    scenario: Scenario  # initial values applied, extra outputs recorded
    parameters: tuple[Parameter, ...]
    outputs: tuple[ResolvedOutput, ...]
    graph: ModelGraph | None  # None: the FMU finite-difference path
    results: pd.DataFrame
    run_dir: Path
    timings: dict[str, float]
    fd_reason: str = ""  # why the FMU path was taken

    @property
    def data_columns(self) -> list[str]:
        return [c.ref for c in self.graph.data] if self.graph is not None else []

    def residual_model(self, pairs: Pairs, solver: SolverSpec | None = None) -> ResidualModel:
        """The residuals on ``pairs`` (one segment) through the path chosen at the check."""
        solver = solver or self.spec.solver
        if self.graph is not None:
            return build_residuals(self.graph, pairs, self.parameters, self.results, solver.shooting,
                                   solver.shooting_interval)
        fmu = FmuOutputs(self.scenario, self.parameters, [o.ref for o in self.outputs], pairs.row_time,
                         self.run_dir.parent / "evaluations", method=solver.fd_method, step=solver.fd_step)
        return fmu_residuals(fmu, pairs)


def _model(spec: CalibrationSpec, scenario: Scenario, instance: str, key: str) -> ModelDefinition:
    m = MODELS.get(scenario.instance(instance).model_identifier)
    if m is None:
        spec.fail(key, f"instance {instance!r} runs {scenario.instance(instance).model_identifier}, which has no "
                       "models/ definition")
    return m


def _instance(spec: CalibrationSpec, scenario: Scenario, ref: Ref, key: str):
    names = list(scenario.execution_order)
    if ref.instance not in names:
        spec.fail(key, f"unknown instance {ref.instance!r} in {scenario.path.name}; instances: {', '.join(names)}")
    inst = scenario.instance(ref.instance)
    return inst, inst.variables.get(ref.variable)


def resolve_parameters(spec: CalibrationSpec, scenario: Scenario) -> tuple[Parameter, ...]:
    out = []
    for ps in spec.parameters:
        inst, var = _instance(spec, scenario, ps.ref, ps.key)
        candidates = [v.name for v in inst.variables.values() if v.causality == "parameter" and v.type == "real"]
        if var is None or var.causality != "parameter" or var.type != "real":
            what = "unknown parameter" if var is None else f"{var.causality} variable" if var.causality != "parameter" \
                else f"{var.type} parameter (only Float64 parameters are fitted)"
            spec.fail(ps.key, f"{what} {ps.variable!r} of {inst.name} ({inst.model_identifier}); Float64 parameters: "
                              f"{', '.join(candidates)}")
        model = _model(spec, scenario, inst.name, ps.key)
        definition = model.variable(ps.variable)
        default = float(inst.parameters.get(ps.variable, definition.start))
        out.append(resolve_parameter(ps, var.unit, default, var.min, var.max, definition.display_unit, spec.fail))
    return tuple(out)


def resolve_outputs(spec: CalibrationSpec, scenario: Scenario) -> tuple[ResolvedOutput, ...]:
    rec = scenario.recorded
    out = []
    for o in spec.outputs:
        inst, var = _instance(spec, scenario, o.simulated, f"{o.key}.simulated")
        if var is None or var.causality != "output" or var.type != "real":
            outputs = [v.name for v in inst.variables.values() if v.causality == "output" and v.type == "real"]
            spec.fail(f"{o.key}.simulated", f"{o.simulated} is not a Float64 output of {inst.model_identifier}; "
                                            f"outputs: {', '.join(outputs)}")
        if rec is None:
            spec.fail(f"{o.key}.recorded", f"the scenario {scenario.path.name} has no [recorded] data")
        if o.recorded not in rec.channels:
            spec.fail(f"{o.key}.recorded", f"unknown recorded channel {o.recorded!r}; channels: {', '.join(rec.channels)}")
        if rec.units[o.recorded] == "bool":
            spec.fail(f"{o.key}.recorded", f"channel {o.recorded!r} is boolean")
        try:
            factor = unit_factor(rec.units[o.recorded], var.unit)
        except UnitError as exc:
            spec.fail(f"{o.key}.recorded", f"channel {o.recorded!r} ({rec.units[o.recorded]}) cannot be compared with "
                                           f"{o.simulated} ({var.unit or '1'}): {exc}")
        model = _model(spec, scenario, inst.name, f"{o.key}.simulated")
        display = o.unit or model.variable(var.name).display_unit or var.unit
        try:
            display_factor = unit_factor(var.unit, display)
        except UnitError as exc:
            if o.unit is not None:
                spec.fail(f"{o.key}.unit", f"display unit {o.unit!r} does not fit {o.simulated} ({var.unit}): {exc}")
            display, display_factor = var.unit, 1.0
        sigma = o.sigma / display_factor if o.sigma is not None else None
        out.append(ResolvedOutput(o.simulated, o.recorded, factor, var.unit, display, display_factor, o.weight, sigma))
    return tuple(out)


def _check_alignment(spec: CalibrationSpec, scenario: Scenario) -> None:
    a = spec.alignment
    for i, ref in enumerate(a.simulated):
        inst, var = _instance(spec, scenario, ref, f"[alignment].simulated[{i}]")
        if var is None or var.type != "real":
            spec.fail(f"[alignment].simulated[{i}]", f"{ref} is not a Float64 variable of {inst.model_identifier}")
    for i, channel in enumerate(a.recorded):
        if scenario.recorded is None or channel not in scenario.recorded.channels:
            known = ", ".join(scenario.recorded.channels) if scenario.recorded else "none"
            spec.fail(f"[alignment].recorded[{i}]", f"unknown recorded channel {channel!r}; channels: {known}")
    for ref in spec.input_floors:
        key = f'[inputs."{ref}"]'
        inst, var = _instance(spec, scenario, ref, key)
        if var is None or var.causality != "input":
            spec.fail(key, f"{ref} is not an input of {inst.model_identifier}")


def _check_segments(spec: CalibrationSpec, scenario: Scenario) -> None:
    """Fail fast when a segment list does not overlap the recording at all."""
    rec = scenario.recorded
    a, b = rec.t_start, rec.t_end
    for name, windows in (("learning", spec.learning), ("validation", spec.validation)):
        if windows and not any(lo <= b and hi >= a for lo, hi in windows):
            spec.fail(f"[segments].{name}", f"the windows {list(windows)} do not overlap the recording "
                                            f"{rec.path.name} ({a:g} .. {b:g} s)")


def check_tokens(scenario: Scenario, instances: list[str], require: bool = True) -> list[dict]:
    """Each instance's FMU against its models/ definition: the instantiation tokens must agree
    (``require``; else the rows say whether they do)."""
    rows = []
    for name in instances:
        inst = scenario.instance(name)
        model = MODELS.get(inst.model_identifier)
        if model is None and not require:
            rows.append({"instance": name, "model": inst.model_identifier, "fmu": str(inst.path),
                         "fmu_sha256": sha256_of(inst.path), "fmi_version": inst.fmi_version,
                         "instantiation_token": inst.instantiation_token, "models_definition": "none"})
            continue
        token = model.instantiation_token()
        if not require:
            source = Path(inspect.getsourcefile(model.equations) or "")
            rows.append({"instance": name, "model": model.identifier, "fmu": str(inst.path),
                         "fmu_sha256": sha256_of(inst.path), "fmi_version": inst.fmi_version,
                         "instantiation_token": inst.instantiation_token,
                         "models_source": str(source), "models_token_matches": token == inst.instantiation_token})
            continue
        if token != inst.instantiation_token:
            raise CalibrationError(
                f"{inst.path}: the FMU's instantiation token {inst.instantiation_token} differs from "
                f"{token} of models/ ({model.identifier}): it was built from other equations; rebuild the FMUs "
                "(cmake --build build) so that what is fitted is what the FMU runs")
        source = Path(inspect.getsourcefile(model.equations) or "")
        rows.append({"instance": name, "model": model.identifier, "fmu": str(inst.path), "fmu_sha256": sha256_of(inst.path),
                     "fmi_version": inst.fmi_version, "instantiation_token": token,
                     "models_source": str(source), "models_source_sha256": sha256_of(source) if source.is_file() else ""})
    return rows


def identities(spec: CalibrationSpec, scenario: Scenario, fmus: list[dict]) -> dict:
    rec = scenario.recorded
    return {
        "spec": {"path": str(spec.path), "sha256": spec.sha256},
        "scenario": {"path": str(scenario.path), "sha256": sha256_of(scenario.path)},
        "recorded": None if rec is None else {"path": str(rec.path), "sha256": sha256_of(rec.path)},
        "fmus": fmus,
        "versions": {**software_versions(), "casadi": ca.__version__},
    }


def simulate_for_fit(scenario: Scenario, out: Path, progress: bool) -> tuple[pd.DataFrame, Path]:
    """Run ``scenario`` into ``out``; its rows, and the run folder. A failed or incomplete run is a CalibrationError."""
    try:
        result = run(scenario, out, progress=progress)
    except SimulationError as exc:
        raise CalibrationError(f"simulation of {scenario.name} failed: {exc}") from exc
    if result.status != "completed":
        raise CalibrationError(f"simulation of {scenario.name} ended {result.status}")
    return load_results(result.run_dir), result.run_dir


def recording_also(scenario: Scenario, refs: list[Ref]) -> Scenario:
    """``scenario`` recording ``refs`` too (the inputs and outputs a fit reads from its results)."""
    return replace(scenario, outputs=tuple(dict.fromkeys(scenario.outputs + tuple(refs))))


def with_overrides(scenario: Scenario, overrides: Mapping[str, Any] | None, fitted: Sequence[Ref] = ()) -> Scenario:
    """``scenario`` with a caller's values (``calibrate(..., overrides=...)``, ``{"instance.variable": value}``)
    applied as a parameter set's are, checked like the scenario's own; after the fit, those naming a
    ``fitted`` parameter are left out (the calibrated value wins)."""
    skip = {str(r) for r in fitted}
    values = {k: v for k, v in (overrides or {}).items() if str(k) not in skip}
    return with_values(scenario, values) if values else scenario


def describe_overrides(overrides: Mapping[str, Any]) -> str:
    """``power.c1 = 0.3; power.P_idle = 0.25 kW``: the overrides as the report and the parameter set say them."""
    return "; ".join(f"{k} = {v['value']!r} {v.get('unit', '')}".rstrip() if isinstance(v, Mapping) else f"{k} = {v!r}"
                     for k, v in overrides.items())


def record_and_publish(ident: dict[str, Any], set_path: Path, set_args: tuple, write_set: Path | None,
                       overrides: Mapping[str, Any] | None) -> Path | None:
    """Name the parameter set written under the output folder (with its hash) and the overrides in the
    identities, then publish the set to ``write_set`` when asked (after the re-simulation succeeded).
    Returns the published file, or None."""
    ident["parameter_set"] = {"path": str(set_path), "sha256": sha256_of(set_path)}
    if overrides:
        ident["overrides"] = describe_overrides(overrides)
    published = write_parameter_set(write_set, *set_args) if write_set is not None else None
    if published is not None:
        ident["parameter_set"]["published"] = str(published)
    return published


def prepare(spec: CalibrationSpec, fmu_dir: Path, out_dir: Path, progress: bool = False,
            overrides: Mapping[str, Any] | None = None) -> Prepared:
    """Stages 1 and 2: checks, graph, tokens and the simulation with the initial values (``overrides``
    applied to the scenario first)."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    scenario = with_overrides(load_scenario(spec.scenario, fmu_dir), overrides)
    parameters = resolve_parameters(spec, scenario)
    outputs = resolve_outputs(spec, scenario)
    _check_alignment(spec, scenario)
    _check_segments(spec, scenario)
    graph, reason = _derivative_path(spec, scenario, parameters, outputs)
    if graph is not None:
        for ref in spec.input_floors:
            if ref not in graph.inputs:
                spec.fail(f'[inputs."{ref}"]', f"{ref} is not an input of the fitted outputs' equations "
                                              f"({', '.join(map(str, graph.inputs)) or 'none'})")
    timings["check"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    initial = with_values(scenario, {q.ref: q.initial for q in parameters}, name=f"{scenario.name}_initial")
    data = [c.input for c in graph.data] if graph is not None else []
    initial = recording_also(initial, data + list(spec.alignment.simulated) + [o.ref for o in outputs])
    results, run_dir = simulate_for_fit(initial, out_dir / "runs", progress)
    timings["simulate (initial parameters)"] = time.perf_counter() - t0
    return Prepared(spec, initial, parameters, outputs, graph, results, run_dir, timings, reason)


def _derivative_path(spec: CalibrationSpec, scenario: Scenario, parameters: tuple[Parameter, ...],
                     outputs: tuple[ResolvedOutput, ...]) -> tuple[ModelGraph | None, str]:
    """(the models/ graph, "") for exact derivatives, or (None, why) for FMU finite differences."""
    keys = {p.ref: p.key for p in spec.parameters} | {o.simulated: f"{o.key}.simulated" for o in spec.outputs}
    names, refs = [q.ref for q in parameters], [o.ref for o in outputs]
    if spec.solver.derivatives != "finite-differences":
        try:
            return build_graph(scenario, names, refs, spec.fail, keys, spec.input_floors), ""
        except NotExpressible as exc:
            if spec.solver.derivatives == "exact":
                spec.fail(exc.key, f"{exc.message}; [solver].derivatives = \"exact\" needs the models/ expressions "
                                   "(\"auto\" or \"finite-differences\" fit through the FMUs instead)")
            reason = f"the models/ expressions cannot give the fitted outputs ({exc.key}: {exc.message})"
    else:
        reason = "[solver].derivatives = \"finite-differences\""
    out_instances = {r.instance for r in refs}
    for q, key in zip(names, (p.key for p in spec.parameters)):
        inst = q.instance
        if inst not in out_instances and not any(_feeds(scenario, i, inst) for i in out_instances):
            spec.fail(key, f"no fitted output depends on {q}: the outputs come from {', '.join(sorted(out_instances))}, "
                           f"and {inst} does not feed them through connections")
    return None, reason


def _feeds(scenario: Scenario, target: str, source: str) -> bool:
    """Is ``source`` upstream of ``target`` along connections (delayed or not)?"""
    frontier, seen = [target], {target}
    while frontier:
        node = frontier.pop()
        for c in scenario.connections:
            if c.target.instance == node and c.source.instance not in seen:
                if c.source.instance == source:
                    return True
                seen.add(c.source.instance)
                frontier.append(c.source.instance)
    return False


def pairs_for(prepared: Prepared, recorded=None, alignment: AlignmentSpec | None = None):
    """Stage 3: pairs of ``recorded`` (default the scenario's recording) with the initial run."""
    spec = prepared.spec
    recorded = recorded if recorded is not None else prepared.scenario.recorded
    pairs, summary, time_map = make_pairs(recorded, prepared.results, prepared.data_columns,
                                          [o.column for o in prepared.outputs],
                                          [o.channel for o in prepared.outputs], [o.factor for o in prepared.outputs],
                                          alignment or spec.alignment, spec.learning, spec.validation)
    t = prepared.results["time"].to_numpy()
    where = (f"recorded {recorded.t_start:g} .. {recorded.t_end:g} s, simulated {t[0]:g} .. {t[-1]:g} s, "
             f"{len(pairs)} samples paired")
    if summary.learning == 0:
        spec.fail("[segments].learning", f"no paired sample lies in the learning windows {list(spec.learning)} "
                                         f"({where})")
    if spec.validation and summary.validation == 0:
        spec.fail("[segments].validation", f"no paired sample lies in the validation windows {list(spec.validation)} "
                                           f"({where})")
    return pairs, summary, time_map


def consistency(prepared: Prepared, model, learning: Pairs) -> float:
    """max |models/ - FMU| / max |FMU| at the initial values, on the results rows the learning pairs use
    (rows, not the pairs' interpolated times: between rows an output is not the model of interpolated inputs)."""
    theta0 = np.array([q.initial for q in prepared.parameters])
    if prepared.graph is None:  # the FMU re-run at the initial values against the initial run, at the pairs
        predicted, fmu = model.predict(theta0), learning.fmu
        scale = max(float(np.max(np.abs(fmu))), 1e-300)
        deviation = float(np.max(np.abs(predicted - fmu))) / scale
        if not deviation <= CONSISTENCY_TOLERANCE:
            raise CalibrationError(
                f"re-simulating the scenario at the initial values does not reproduce the initial run: relative "
                f"deviation {deviation:.3g} at the learning pairs; the FMUs are not deterministic, or a run failed "
                f"({'; '.join(f.message for f in model.keep_alive.fmu.failures[:1]) or 'no failure recorded'})")
        return deviation
    rows = np.unique(learning.rows) if prepared.graph.dynamic is None else learning.rows
    fmu = prepared.results[[o.column for o in prepared.outputs]].to_numpy(dtype=float)[rows]
    if prepared.graph.dynamic is None:
        data = prepared.results[[c.ref for c in prepared.graph.data]].to_numpy(dtype=float)[rows]
        mapped = prepared.graph.sample.map(len(rows))
        predicted = np.asarray(mapped(np.repeat(theta0[:, None], len(rows), axis=1), data.T), dtype=float).T
    else:
        predicted = model.predict(theta0)
    scale = max(float(np.max(np.abs(fmu))), 1e-300)
    deviation = float(np.max(np.abs(predicted - fmu))) / scale
    if not deviation <= CONSISTENCY_TOLERANCE:
        worst = int(np.argmax(np.max(np.abs(predicted - fmu), axis=1)))
        raise CalibrationError(
            f"the models/ equations do not reproduce the FMU's outputs of the initial run: relative deviation "
            f"{deviation:.3g} (at t = {prepared.results['time'].to_numpy()[rows][worst]:g} s of the run); the data "
            "columns or the co-simulation semantics differ from what the graph assumes")
    return deviation


def _fit(prepared: Prepared, learning: Pairs, solver: SolverSpec, progress: bool, executor: Executor | None = None):
    spec = prepared.spec
    model = prepared.residual_model(learning, solver)
    outcome = fit(model, learning.recorded, weights=[o.weight for o in prepared.outputs],
                  sigma=[o.sigma if spec.solver.noise == "sigma" else None for o in prepared.outputs],
                  solver=solver, statistics=spec.statistics, progress=progress, executor=executor)
    return model, outcome


def _notes(outcome: FitOutcome) -> list[str]:
    good = [p.name for p in outcome.statistics.parameters if not p.flags]
    weak = [p.name for p in outcome.statistics.parameters if p.flags and p.identifiable]
    bad = [p.name for p in outcome.statistics.parameters if not p.identifiable]
    notes = []
    if good:
        notes.append(f"Identified by these data (no flag): {', '.join(good)}.")
    if weak:
        notes.append(f"Estimated, with a flag (wide interval or strong correlation): {', '.join(weak)}.")
    if bad:
        notes.append(f"Not identified by these data (near-singular direction, no effect, or at a bound): "
                     f"{', '.join(bad)}; their values in the parameter set are what the optimiser left, not "
                     "measurements.")
    if outcome.note:
        notes.append(outcome.note)
    return notes


def calibrate_scenario(spec: CalibrationSpec, fmu_dir: Path, out_dir: Path, progress: bool = False, *,
                       write_set: Path | None = None, overrides: Mapping[str, Any] | None = None) -> CalibrationResult:
    """The calibration of a kind "scenario" spec; the parameter set goes to ``out_dir`` under the file name
    of the spec's ``parameter_set``, and to ``write_set`` too (after the re-simulation) if given. With
    ``[solver] workers``/``scheduler``, the fit's simulations run on that executor
    (:mod:`milling_twin.orchestrator.calibrate.parallel`)."""
    prepared = prepare(spec, fmu_dir, out_dir, progress, overrides)
    # the workers take simulations: the exact path has none in its fit
    solver = spec.solver if prepared.graph is None else replace(spec.solver, workers=0, scheduler=None)
    t0 = time.perf_counter()
    with calibration_executor(solver) as executor:
        if executor is not None:
            prepared.timings["start the workers"] = time.perf_counter() - t0
        return _calibrate_scenario(prepared, fmu_dir, out_dir, progress, write_set, overrides, executor)


def _calibrate_scenario(prepared: Prepared, fmu_dir: Path, out_dir: Path, progress: bool, write_set: Path | None,
                        overrides: Mapping[str, Any] | None, executor: Executor | None) -> CalibrationResult:
    spec = prepared.spec
    timings = prepared.timings
    t0 = time.perf_counter()
    if prepared.graph is not None:
        tokens = check_tokens(prepared.scenario, list(prepared.graph.instances))
    else:  # the FMUs are the model: their identities, and whether models/ still describes them
        tokens = check_tokens(prepared.scenario, list(prepared.scenario.execution_order), require=False)
    timings["check"] += time.perf_counter() - t0
    t0 = time.perf_counter()
    pairs, summary, _ = pairs_for(prepared)
    timings["align"] = time.perf_counter() - t0
    learning, validation = pairs.select(LEARNING), pairs.select(VALIDATION)
    t0 = time.perf_counter()
    model, outcome = _fit(prepared, learning, spec.solver, progress, executor)
    deviation = consistency(prepared, model, learning)
    timings["fit (build, starts, statistics)"] = time.perf_counter() - t0
    tables: list[Table] = []
    notes = [f"Derivatives: {outcome.derivatives}."]
    if prepared.graph is None:
        fmu = model.keep_alive.fmu
        where = (f"{spec.solver.workers} local worker processes" if spec.solver.workers else
                 f"the cluster of {spec.solver.scheduler}")
        notes += [f"Fitted through the FMUs because {prepared.fd_reason}.",
                  *([f"Parallel fit on {where}: the simulations as tasks, the starts at once, a Jacobian's "
                     "columns together, accounted in the serial order (the serial result, bit for bit)."]
                    if executor is not None else []),
                  f"FMU evaluations: {fmu.simulations} simulations ({fmu.simulation_time:.3g} s) for the starts and "
                  f"the statistics, {len(fmu.failures)} failed; re-run at the initial values vs the initial run at "
                  f"the learning pairs: max relative deviation {deviation:.3g}."]
        if spec.input_floors:
            notes.append("The [inputs] floors apply to the models/ expressions only: not used on this path.")
    else:
        notes.append(f"models/ vs FMU at the initial values on the rows of the learning pairs: max relative "
                     f"deviation {deviation:.3g}.")
        if spec.solver.workers or spec.solver.scheduler is not None:
            notes.append("[solver] workers / scheduler: not used (the fit evaluates the models/ equations, it runs "
                         "no simulation to dispatch).")
    if spec.alignment.method != "none":
        t0 = time.perf_counter()
        plain, _, _ = pairs_for(prepared, alignment=AlignmentSpec("none"))
        single = replace(spec.solver, starts=1)
        model_id = prepared.residual_model(plain.select(LEARNING))
        other = fit(model_id, plain.select(LEARNING).recorded, weights=[o.weight for o in prepared.outputs],
                    sigma=[None] * len(prepared.outputs), solver=single, statistics=spec.statistics,
                    starts=outcome.theta[None, :], executor=executor)
        tables.append(Table(
            f"What the alignment ({spec.alignment.method}) changed",
            ("parameter", "estimate on aligned pairs", "estimate on identity pairs", "difference / standard error"),
            tuple((q.name, f"{q.display(a):.6g}", f"{q.display(b):.6g}",
                   f"{(a - b) / st.standard_error:+.3g}" if np.isfinite(st.standard_error) and st.standard_error > 0
                   else "n/a")
                  for q, a, b, st in zip(prepared.parameters, outcome.theta, other.theta, outcome.statistics.parameters)),
            f"Recorded samples were mapped to simulated times {summary.median_shift:.3g} s (median), "
            f"{summary.max_shift:.3g} s (max) away from the identity."))
        timings["fit on identity pairs (alignment effect)"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    rec = prepared.scenario.recorded
    source: dict[str, str | Path] = {  # paths relative to where the set is written
        "calibration": spec.name, "spec": spec.path, "spec_sha256": spec.sha256, "scenario": spec.scenario,
        "scenario_sha256": sha256_of(spec.scenario), "recorded": rec.path, "recorded_sha256": sha256_of(rec.path),
        "learning": str(list(spec.learning))}
    if overrides:
        source["overrides"] = describe_overrides(overrides)
    set_args = (prepared.parameters, outcome.theta, outcome.statistics.parameters, spec.description or spec.name,
                source, f"milling-twin calibrate {os.path.relpath(spec.path)}")
    set_path = write_parameter_set(out_dir / spec.parameter_set.name, *set_args)
    ssv = write_ssv(out_dir / f"{spec.parameter_set.stem}.ssv", spec.name, prepared.parameters, outcome.theta)
    timings["write parameter set"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fitted = [q.ref for q in prepared.parameters]
    if spec.calibrated_scenario is not None:  # it names the spec's parameter_set; the set just written wins
        after = with_overrides(load_scenario(spec.calibrated_scenario, fmu_dir, parameter_sets=[set_path]),
                               overrides, fitted)
        own_sets = after.parameter_sets[:-1]  # the set just written is applied last
        if spec.parameter_set.resolve() not in {p.resolve() for p in own_sets}:
            spec.fail("[calibration].calibrated_scenario",
                      f"{spec.calibrated_scenario.name} does not apply the parameter set {spec.parameter_set.name} "
                      "(add it to [scenario].parameter_sets)")
        for q, value in zip(prepared.parameters, outcome.theta):
            applied = after.instance(q.ref.instance).parameters.get(q.ref.variable)
            if applied is None or abs(applied - value) > 1e-12 * max(abs(value), 1e-300):
                spec.fail("[calibration].calibrated_scenario",
                          f"{spec.calibrated_scenario.name} does not apply the parameter set {set_path.name}: "
                          f"{q.name} = {applied!r} there, {value!r} calibrated (add it to [scenario].parameter_sets)")
    else:
        after = with_overrides(load_scenario(spec.scenario, fmu_dir, parameter_sets=[set_path]), overrides, fitted)
    after = recording_also(replace(after, name=f"{prepared.scenario.name.removesuffix('_initial')}_calibrated"),
                               [o.ref for o in prepared.outputs])
    results_after, run_after = simulate_for_fit(after, out_dir / "runs", progress)
    timings["re-simulate (calibrated parameter set)"] = time.perf_counter() - t0
    series = []
    names = [o.column for o in prepared.outputs]
    for dataset, subset in (("learning", learning), ("validation", validation)):
        if not len(subset):
            continue
        fmu_after = subset.with_fmu(results_after, names).fmu
        for k, o in enumerate(prepared.outputs):
            series.append(Series(o.column, o.channel, dataset, subset.recorded_time, subset.recorded[:, k],
                                 subset.fmu[:, k], fmu_after[:, k], o.unit, o.display_unit, o.display_factor))
    ident = identities(spec, prepared.scenario, tokens)
    ident["runs"] = {"initial": str(prepared.run_dir), "calibrated": str(run_after)}
    ident["calibrated_scenario"] = str(spec.calibrated_scenario or f"{spec.scenario} + {set_path}")
    published = record_and_publish(ident, set_path, set_args, write_set, overrides)
    return CalibrationResult(spec, outcome, series, [error_row(s) for s in series], ident, timings, out_dir, set_path,
                             ssv, summary, notes + _notes(outcome), [], tables, published_set=published)

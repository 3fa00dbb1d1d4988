"""Kind "runs": one machine, several recordings. Shared machine parameters fitted to all runs at once,
leave-one-run-out cross-validation, intervals that hold for autocorrelated residuals.

A model fitted to one recording proves little: one run of the UMich mill cannot tell the spindle's idle
power from its speed term (constant speed), and a set fitted to run 01 alone predicts the other runs worse
than the priors. Stages (each timed for the report):

1. **check**: the spec against the scenario (the template every recording runs through); the fitted outputs
   must be those of one FMU instance, computed from its parameters, its inputs (data: the values the FMU
   held, from its results) and, for a model with states, the states it exposes as outputs (SpindlePower's
   ``spindle_acceleration``): :func:`sample_model`. States the outputs read but the FMU does not expose
   are refused. The FMU's instantiation token must be the models/ definition's.
2. **simulate**: every run through the FMUs with the initial values (``[recorded].file`` replaced by the
   run's file), its ``[recorded.checks]`` applied: pairs are the recorded samples inside consistent
   segments, after each segment's first sample (:meth:`RecordedData.consistent`); the graph at the initial
   values must reproduce the FMU's outputs at every pair.
3. **fit**: all runs together (``[runs].per_run`` parameters get one copy per run, nuisance, not written to
   the set); each run alone (how far the runs agree); leave-one-run-out: for each run, the fit without it,
   predicting it with the shared estimates (per-run parameters at their initial values). Intervals
   (:mod:`.statistics`): a moving-block bootstrap within each run's segments (default) or the Newey-West
   sandwich, not ``sigma2 (J^T J)^-1``, which treats the swinging residuals of a 10 Hz recording as
   independent and the five rows of a run-up as if they were many: its intervals exclude each other from
   run to run.
4. **write**: the parameter set of the joint fit; ``runs.csv`` and ``cross_validation.csv`` are written as
   each run and fold completes (a killed calibration leaves them readable).
5. **re-simulate**: every run through the FMUs with the written set: errors before/after per run.
"""
from __future__ import annotations

import csv
import io
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NoReturn

import casadi as ca
import numpy as np
import pandas as pd
from tqdm import tqdm

from milling_twin.models import MODELS
from milling_twin.models.definition import State
from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.calibrate.errors import CalibrationError
from milling_twin.orchestrator.calibrate.fit import FitOutcome, fit
from milling_twin.orchestrator.calibrate.pairing import at_rows
from milling_twin.orchestrator.calibrate.parameters import Parameter
from milling_twin.orchestrator.calibrate.paramset import write_parameter_set, write_ssv
from milling_twin.orchestrator.calibrate.plots import figure_png
from milling_twin.orchestrator.calibrate.residuals import ResidualModel, from_outputs
from milling_twin.orchestrator.calibrate.result import CalibrationResult, Figure, Series, Table, error_row
from milling_twin.orchestrator.calibrate.scenario_fit import (ResolvedOutput, check_tokens, describe_overrides,
                                                              identities, record_and_publish, recording_also,
                                                              resolve_outputs, resolve_parameters, simulate_for_fit,
                                                              with_overrides)
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec
from milling_twin.orchestrator.calibrate.statistics import (BetweenRuns, between_runs, block_bootstrap,
                                                            fit_statistics, newey_west_lags, with_intervals)
from milling_twin.orchestrator.results import sha256_of
from milling_twin.orchestrator.scenario import Ref, Scenario, load_scenario, with_values

__all__ = ["RunData", "SampleModel", "calibrate_runs", "run_files", "sample_model"]


@dataclass(frozen=True)
class SampleModel:
    """The fitted outputs of one instance at one sample: ``function(theta, d) -> y``; ``data``: the results
    columns of ``d`` (inputs and exposed states), in order."""

    instance: str
    function: ca.Function
    data: tuple[str, ...]

    def outputs(self, theta: np.ndarray, data: np.ndarray) -> np.ndarray:
        """Outputs (pairs x outputs) at SI ``theta`` on ``data`` (pairs x columns)."""
        n = data.shape[0]
        if n == 0:
            return np.zeros((0, self.function.size1_out(0)))
        y = self.function.map(n)(np.tile(np.asarray(theta, dtype=float)[:, None], (1, n)), data.T)
        return np.asarray(y, dtype=float).T


def sample_model(scenario: Scenario, parameters: Sequence[Parameter], outputs: Sequence[ResolvedOutput],
                 floors: Mapping[Ref, float], fail: Callable[[str, str], NoReturn]) -> SampleModel:
    """The models/ expressions of the fitted outputs with the fitted parameters as symbols, every other
    parameter at its scenario value, inputs and exposed states as data (module text, stage 1)."""
    instances = sorted({q.ref.instance for q in parameters} | {o.ref.instance for o in outputs})
    if len(instances) != 1:
        fail("[parameters]", f"kind \"runs\" fits the outputs of one instance with its own parameters; the spec "
                             f"names {', '.join(instances)}")
    name = instances[0]
    inst = scenario.instance(name)
    m = MODELS.get(inst.model_identifier)
    if m is None:
        fail("[parameters]", f"{name} runs {inst.model_identifier}, which has no models/ definition")
    symbols = {a.name: ca.SX.sym(f"{name}.{a.name}") for a in m.arguments}
    probe = m.equations(symbols)
    exposed = {s.name: o for s in m.states for o, e in probe.items() if ca.is_equal(e, symbols[s.name])}
    fitted = {q.ref.variable: i for i, q in enumerate(parameters)}
    theta = ca.SX.sym("theta", len(parameters))
    values: dict[str, ca.SX] = {}
    columns: list[str] = []
    data: list[ca.SX] = []
    for a in m.arguments:
        if isinstance(a, State):
            values[a.name] = symbols[a.name]
            if a.name in exposed:
                columns.append(f"{name}.{exposed[a.name]}")
                data.append(symbols[a.name])
        elif a.causality == "parameter":
            values[a.name] = theta[fitted[a.name]] if a.name in fitted else \
                ca.SX(float(inst.parameters.get(a.name, a.start)))
        else:
            columns.append(f"{name}.{a.name}")
            data.append(symbols[a.name])
            ref = Ref(name, a.name)
            values[a.name] = ca.fmax(symbols[a.name], floors[ref]) if ref in floors else symbols[a.name]
    equations = m.equations(values)
    y = [equations[o.ref.variable] for o in outputs]
    for s in m.states:
        if s.name not in exposed and any(ca.depends_on(e, symbols[s.name]) for e in y):
            fail("[[outputs]]", f"{', '.join(str(o.ref) for o in outputs)} read the state {s.name} of {name}, which "
                                f"{m.identifier} does not expose as an output: not expressible from its results")
    function = ca.Function("sample", [theta, ca.vertcat(*data)], [ca.vertcat(*y)], ["theta", "d"], ["y"],
                           {"is_diff_in": [True, False]})
    return SampleModel(name, function, tuple(columns))


@dataclass
class RunData:
    """One recording paired with its simulation at the initial values."""

    name: str
    path: Path
    run_dir: Path
    n_rows: int
    time: np.ndarray  # recorded time of every pair, s
    data: np.ndarray  # pairs x SampleModel.data
    recorded: np.ndarray  # pairs x outputs, each output's SI unit
    fmu: np.ndarray  # pairs x outputs: the FMU with the initial values
    groups: np.ndarray  # consistent segment of every pair
    check: list[str]  # what the recording's check found and did

    def rms_recorded(self) -> np.ndarray:
        return np.sqrt(np.mean(self.recorded ** 2, axis=0))


def run_files(spec: CalibrationSpec, data: str | Path | None) -> list[tuple[str, Path]]:
    """(name, file) of every run: ``[runs].files`` in ``data`` (``--data``) or ``[runs].folder``."""
    folder = Path(data) if data is not None else spec.runs.folder
    if not folder.is_dir():
        from milling_twin.datasets import DataMissing
        raise DataMissing(f"the runs' folder {folder} does not exist ([runs].folder of {spec.path}; give another "
                          "with --data DIR)")
    if spec.runs.pattern is not None:
        paths = sorted(p for p in folder.glob(spec.runs.pattern) if p.is_file())
        if not paths:
            spec.fail("[runs].files", f"no file in {folder} matches {spec.runs.pattern!r}")
        return [(p.stem, p) for p in paths]
    out = []
    for file in spec.runs.files:
        path = folder / file
        if not path.is_file():
            spec.fail("[runs].files", f"{path} not found")
        out.append((Path(file).stem, path))
    return out


def _pairs(name: str, path: Path, scenario: Scenario, results: pd.DataFrame, run_dir: Path, model: SampleModel,
           outputs: Sequence[ResolvedOutput]) -> RunData:
    rec = scenario.recorded
    t = results["time"].to_numpy(dtype=float)
    keep = (rec.time >= t[0]) & (rec.time <= t[-1] + 1e-9) & rec.consistent(rec.time)
    times = rec.time[keep]
    groups = rec.check.segment_index()[keep] if rec.check is not None else np.zeros(times.size, dtype=int)
    recorded = np.column_stack([rec.channels[o.channel][keep] * o.factor for o in outputs])
    fmu = at_rows(results, [o.column for o in outputs], times)
    check = rec.check.summary() if rec.check is not None else ["not checked (no [recorded.checks])"]
    return RunData(name, path, run_dir, int(rec.time.size), times, at_rows(results, list(model.data), times),
                   recorded, fmu, groups, check)


def _layout(parameters: Sequence[Parameter], per_run: set[Ref], names: Sequence[str]
            ) -> tuple[tuple[Parameter, ...], dict[str, np.ndarray]]:
    """The joint fit's parameters (shared ones, then one copy of every per-run parameter per run) and, per
    run, the indices into them of the model's parameters in model order."""
    shared = [q for q in parameters if q.ref not in per_run]
    full = list(shared)
    index: dict[str, np.ndarray] = {}
    copies: dict[tuple[str, str], int] = {}
    for name in names:
        for q in parameters:
            if q.ref in per_run:
                copies[(name, q.name)] = len(full)
                full.append(replace(q, name=f"{q.name} [{name}]", nuisance=True))
    for name in names:
        index[name] = np.array([copies[(name, q.name)] if q.ref in per_run else shared.index(q)
                                for q in parameters], dtype=int)
    return tuple(full), index


def _model(model: SampleModel, runs: Sequence[RunData], parameters: tuple[Parameter, ...],
           index: Mapping[str, np.ndarray], n_out: int) -> ResidualModel:
    maps = [(model.function.map(max(len(r.time), 1)), ca.DM(r.data.T), len(r.time), index[r.name]) for r in runs]

    def y_of(theta: ca.MX) -> ca.MX:
        parts = []
        for mapped, data, n, idx in maps:
            if n:
                th = ca.vertcat(*[theta[int(i)] for i in idx])
                parts.append(mapped(ca.repmat(th, 1, n), data))
        return ca.horzcat(*parts)

    return from_outputs(y_of, parameters, n_out, sum(len(r.time) for r in runs))


@dataclass
class _Fit:
    outcome: FitOutcome
    parameters: tuple[Parameter, ...]
    index: dict[str, np.ndarray]


def _fit_runs(spec: CalibrationSpec, model: SampleModel, runs: Sequence[RunData], parameters: Sequence[Parameter],
              outputs: Sequence[ResolvedOutput], progress: bool) -> _Fit:
    per_run = set(spec.runs.per_run)
    full, index = _layout(parameters, per_run, [r.name for r in runs])
    residuals = _model(model, runs, full, index, len(outputs))
    recorded = np.vstack([r.recorded for r in runs])
    outcome = fit(residuals, recorded, weights=[o.weight for o in outputs], sigma=[o.sigma for o in outputs],
                  solver=spec.solver, statistics=spec.statistics, progress=progress)
    # the autocorrelation-consistent covariance over every run's segments
    p = residuals.data_vector(recorded, np.sqrt(outcome.weights) / outcome.sigma)
    r, jac = residuals.residual_jacobian(outcome.theta, p)
    groups = np.concatenate([k * 1_000_000 + run.groups for k, run in enumerate(runs)])
    lags = spec.runs.hac_lags if spec.runs.hac_lags is not None else newey_west_lags(len(groups))
    stats = fit_statistics(jac, r, outcome.theta, full, spec.statistics, hac=(groups, lags))
    if spec.runs.intervals == "bootstrap":
        stats = with_intervals(stats, block_bootstrap(jac, r, outcome.theta, groups, spec.runs.block,
                                                      spec.runs.replicates, spec.solver.seed))
    return _Fit(replace(outcome, statistics=stats), full, index)


def _predict(model: SampleModel, run: RunData, theta: np.ndarray) -> np.ndarray:
    return model.outputs(theta, run.data)


def _rms(error: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(error ** 2, axis=0)) if error.size else np.full(error.shape[1], math.nan)


class _Csv:
    """A CSV rewritten whole (atomically) at every row: a killed calibration leaves the rows it had, a full disk
    an error naming the file and no partial row."""

    def __init__(self, path: Path, header: Sequence[str]) -> None:
        self.path = path
        self.text = io.StringIO(newline="")
        self._add(header)

    def row(self, values: Sequence[Any]) -> None:
        self._add([f"{v:.6g}" if isinstance(v, float) else v for v in values])

    def _add(self, values: Sequence[Any]) -> None:
        csv.writer(self.text).writerow(values)
        atomic_files.write_text(self.path, self.text.getvalue())


def calibrate_runs(spec: CalibrationSpec, fmu_dir: Path, out_dir: Path, data: str | Path | None, progress: bool = False,
                   *, write_set: Path | None = None, overrides: Mapping[str, Any] | None = None) -> CalibrationResult:
    """The calibration of a kind "runs" spec (module text); ``data``: the runs' folder (``--data``)."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    files = run_files(spec, data)
    template = with_overrides(load_scenario(spec.scenario, fmu_dir, recording=files[0][1]), overrides)
    parameters = resolve_parameters(spec, template)
    outputs = resolve_outputs(spec, template)
    model = sample_model(template, parameters, outputs, spec.input_floors, spec.fail)
    tokens = check_tokens(template, [model.instance])
    theta0 = np.array([q.initial for q in parameters])
    timings["check"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    runs: list[RunData] = []
    log = _Csv(out_dir / "runs.csv", ("run", "rows", "pairs", "segments used", "rows dropped", "problems",
                                      "RMS recorded", "RMS error (initial)"))
    for name, path in tqdm(files, desc="runs (initial values)", unit="run", disable=not progress, leave=False):
        scenario = with_overrides(load_scenario(spec.scenario, fmu_dir, recording=path), overrides)
        scenario = with_values(scenario, {q.ref: q.initial for q in parameters}, name=f"{name}_initial")
        scenario = recording_also(scenario, [Ref.parse(c) for c in model.data] + [o.ref for o in outputs])
        results, run_dir = simulate_for_fit(scenario, out_dir / "runs", progress=False)
        run = _pairs(name, path, scenario, results, run_dir, model, outputs)
        if not len(run.time):
            raise CalibrationError(f"{path}: no consistent samples to fit ({'; '.join(run.check[:2])})")
        deviation = np.abs(_predict(model, run, theta0) - run.fmu).max() / max(np.abs(run.fmu).max(), 1e-300)
        if deviation > 1e-8:
            raise CalibrationError(f"{path}: the models/ expressions at the initial values differ from the FMU's "
                                   f"outputs by {deviation:.3g} (relative): the FMU does not compute what is fitted")
        runs.append(run)
        check = scenario.recorded.check
        log.row((name, run.n_rows, len(run.time), len(check.segments) if check else 1,
                 check.dropped_rows if check else 0, len(check.problems) if check else 0,
                 float(run.rms_recorded()[0]), float(_rms(run.fmu - run.recorded)[0])))
    timings["simulate (initial values)"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    joint = _fit_runs(spec, model, runs, parameters, outputs, progress)
    timings["fit (all runs)"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    alone = {run.name: _fit_runs(replace(spec, runs=replace(spec.runs, per_run=())), model, [run], parameters,
                                 outputs, False)
             for run in tqdm(runs, desc="fits per run", unit="run", disable=not progress, leave=False)}
    timings["fit (each run alone)"] = time.perf_counter() - t0

    shared_initial = [(q.name, q.initial) for q in parameters]
    cross: dict[str, np.ndarray] = {}
    t0 = time.perf_counter()
    if spec.runs.cross_validation and len(runs) > 1:
        folds = _Csv(out_dir / "cross_validation.csv",
                     ("run", "pairs", "RMS recorded", "RMS error priors", "RMS error fitted without it",
                      "RMS error fitted with it", *(q.name for q in parameters)))
        for run in tqdm(runs, desc="leave-one-run-out", unit="fold", disable=not progress, leave=False):
            others = [r for r in runs if r is not run]
            fold = _fit_runs(spec, model, others, parameters, outputs, False)
            theta = np.array([dict((q.name, v) for q, v in zip(fold.parameters, fold.outcome.theta)
                                   if not q.nuisance).get(n, v) for n, v in shared_initial])
            cross[run.name] = theta
            folds.row((run.name, len(run.time), float(run.rms_recorded()[0]),
                       float(_rms(_predict(model, run, theta0) - run.recorded)[0]),
                       float(_rms(_predict(model, run, theta) - run.recorded)[0]),
                       float(_rms(_predict(model, run, joint.outcome.theta[joint.index[run.name]])
                                  - run.recorded)[0]), *map(float, theta)))
    timings["leave-one-run-out"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    rms_of = lambda run, theta: _rms(_predict(model, run, theta) - run.recorded)  # noqa: E731
    source: dict[str, str | Path] = {
        "calibration": spec.name, "spec": spec.path, "spec_sha256": spec.sha256, "scenario": spec.scenario,
        "scenario_sha256": sha256_of(spec.scenario), "runs": ", ".join(r.name for r in runs),
        "runs_sha256": ", ".join(sha256_of(r.path)[:16] for r in runs)}
    if overrides:
        source["overrides"] = describe_overrides(overrides)
    set_args = (joint.parameters, joint.outcome.theta, joint.outcome.statistics.parameters,
                spec.description or spec.name, source, f"milling-twin calibrate {os.path.relpath(spec.path)}")
    set_path = write_parameter_set(out_dir / spec.parameter_set.name, *set_args)
    ssv = write_ssv(out_dir / f"{spec.parameter_set.stem}.ssv", spec.name, joint.parameters, joint.outcome.theta)
    timings["write parameter set"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    series: list[Series] = []
    worst = 0.0
    fitted_refs = [q.ref for q in parameters]
    template_after = spec.calibrated_scenario or spec.scenario
    for run in tqdm(runs, desc="runs (calibrated set)", unit="run", disable=not progress, leave=False):
        after = with_overrides(load_scenario(template_after, fmu_dir, parameter_sets=[set_path], recording=run.path),
                               overrides, fitted_refs)
        own = {q.ref: v for q, v in zip(parameters, joint.outcome.theta[joint.index[run.name]])
               if q.ref in set(spec.runs.per_run)}
        after = recording_also(with_values(after, own, name=f"{run.name}_calibrated"), [o.ref for o in outputs])
        results_after, _ = simulate_for_fit(after, out_dir / "runs", progress=False)
        fmu_after = at_rows(results_after, [o.column for o in outputs], run.time)
        graph_after = _predict(model, run, joint.outcome.theta[joint.index[run.name]])
        worst = max(worst, float(np.abs(graph_after - fmu_after).max() / max(np.abs(fmu_after).max(), 1e-300)))
        for k, o in enumerate(outputs):
            series.append(Series(o.column, o.channel, "run", run.time, run.recorded[:, k], run.fmu[:, k],
                                 fmu_after[:, k], o.unit, o.display_unit, o.display_factor, label=run.name))
    timings["re-simulate (calibrated parameter set)"] = time.perf_counter() - t0

    tables = [_runs_table(runs, outputs[0]), _cross_table(runs, cross, joint, theta0, outputs[0], rms_of),
              _intervals_table(parameters, joint, alone)]
    figures = [_cross_figure(runs, cross, joint, theta0, outputs[0], rms_of),
               _intervals_figure(parameters, joint, alone)]
    ident = identities(spec, template, tokens)
    ident["runs"] = {r.name: {"path": str(r.path), "sha256": sha256_of(r.path), "initial": str(r.run_dir)}
                     for r in runs}
    published = record_and_publish(ident, set_path, set_args, write_set, overrides)
    notes = [f"Derivatives: {joint.outcome.derivatives}.",
             f"models/ vs FMU at the calibrated values on every pair of every run: max relative deviation "
             f"{worst:.3g}.",
             _intervals_note(spec)]
    if spec.runs.per_run:
        notes.append(f"Per-run parameters (nuisance, one per run, not in the set): "
                     f"{', '.join(map(str, spec.runs.per_run))}; held-out runs are predicted with their initial "
                     "values.")
    extra = {"runs": [r.name for r in runs], "cross_validation": _cross_rows(runs, cross, joint, theta0, rms_of),
             "agreement": {q.name: agreement_of(j, alone) for j, q in enumerate(parameters)},
             "alone": {name: {"theta": f.outcome.theta.tolist(),
                              "ci": [[s.ci_low, s.ci_high] for s in f.outcome.statistics.parameters],
                              "flags": [list(s.flags) for s in f.outcome.statistics.parameters]}
                       for name, f in alone.items()}}
    return CalibrationResult(spec, joint.outcome, series, [error_row(s) for s in series], ident, timings, out_dir,
                             set_path, ssv, None, notes, figures, tables, extra=extra, published_set=published)


def _intervals_note(spec: CalibrationSpec) -> str:
    r = spec.runs
    if r.intervals == "bootstrap":
        return (f"Intervals: estimate -/+ t * the standard error of a moving-block bootstrap (blocks of {r.block} "
                f"pairs within each run's consistent segments, {r.replicates} replicates, one Gauss-Newton step "
                "each); flags from the HAC covariance.")
    return (f"Intervals: Newey-West (HAC) over each run's consistent segments, "
            f"{r.hac_lags if r.hac_lags is not None else 'Newey-West rule'} lags.")


def _cross_rows(runs, cross, joint, theta0, rms_of) -> list[dict[str, Any]]:
    rows = []
    for run in runs:
        rec = float(run.rms_recorded()[0])
        row = {"run": run.name, "pairs": len(run.time), "rms_recorded": rec,
               "priors": float(rms_of(run, theta0)[0]),
               "with_it": float(rms_of(run, joint.outcome.theta[joint.index[run.name]])[0])}
        if run.name in cross:
            row["without_it"] = float(rms_of(run, cross[run.name])[0])
        rows.append(row)
    return rows


def _runs_table(runs: Sequence[RunData], output: ResolvedOutput) -> Table:
    d = output.display_factor
    rows = tuple((r.name, str(r.n_rows), str(len(r.time)), str(len(np.unique(r.groups))),
                  f"{d * float(r.rms_recorded()[0]):.4g}", r.check[0] if r.check else "")
                 for r in runs)
    return Table("Runs: what each recording holds and what its check found",
                 ("run", "rows", "pairs used", "segments", f"RMS recorded [{output.display_unit}]", "check"), rows,
                 "Pairs: recorded samples inside the consistent segments after each segment's first sample.")


def _cross_table(runs, cross, joint, theta0, output: ResolvedOutput, rms_of) -> Table:
    d, unit = output.display_factor, output.display_unit
    rows = []
    for row in _cross_rows(runs, cross, joint, theta0, rms_of):
        rec = row["rms_recorded"]
        cell = lambda v: f"{d * v:.4g} ({100 * v / rec:.1f} %)" if rec > 0 else f"{d * v:.4g}"  # noqa: E731
        rows.append((row["run"], str(row["pairs"]), cell(row["priors"]),
                     cell(row["without_it"]) if "without_it" in row else "n/a", cell(row["with_it"]),
                     "yes" if "without_it" in row and row["without_it"] < row["priors"] else
                     "n/a" if "without_it" not in row else "no"))
    return Table(f"Leave-one-run-out: RMS error of {output.ref} [{unit}] (% of the run's RMS recorded)",
                 ("run", "pairs", "priors", "fitted without it", "fitted with it", "without it better than priors"),
                 tuple(rows), "Each run predicted by the set fitted to the other runs (it never saw the run).")


def _identifies(st) -> bool:
    """Does a run's fit fix this parameter on its own (see the intervals table's note)?"""
    return st.identifiable and np.isfinite(st.standard_error) and not any(f.startswith("correlated")
                                                                          for f in st.flags)


def _overlap(intervals: Sequence[tuple[float, float]]) -> tuple[int, int]:
    """(pairs of intervals that overlap, pairs)."""
    n = len(intervals)
    both = sum(1 for i in range(n) for j in range(i + 1, n)
               if max(intervals[i][0], intervals[j][0]) <= min(intervals[i][1], intervals[j][1]))
    return both, n * (n - 1) // 2


@dataclass(frozen=True)
class Agreement:
    """How the runs fitted alone agree on one parameter (those that identify it): pairs of overlapping 95 %
    intervals, within each run and with the spread between runs added; None where fewer than two identify it."""

    identifying: tuple[str, ...]
    overlap: tuple[int, int]
    between: BetweenRuns | None
    overlap_with_spread: tuple[int, int] | None


def agreement_of(j: int, alone: Mapping[str, _Fit]) -> Agreement:
    runs = [(name, f.outcome.statistics.parameters[j]) for name, f in alone.items()
            if _identifies(f.outcome.statistics.parameters[j])]
    overlap = _overlap([(st.ci_low, st.ci_high) for _, st in runs])
    if len(runs) < 2 or not all(st.standard_error > 0 for _, st in runs):
        return Agreement(tuple(n for n, _ in runs), overlap, None, None)
    spread = between_runs([st.estimate for _, st in runs], [st.standard_error for _, st in runs])
    widened = _overlap([spread.interval(st.estimate, st.standard_error) for _, st in runs])
    return Agreement(tuple(n for n, _ in runs), overlap, spread, widened)


def _intervals_table(parameters: Sequence[Parameter], joint: _Fit, alone: Mapping[str, _Fit]) -> Table:
    rows = []
    for j, q in enumerate(parameters):
        shown = []
        for name, f in alone.items():
            st = f.outcome.statistics.parameters[j]
            shown.append(f"{name}: {q.display(st.estimate):.4g} [{q.display(st.ci_low):.4g}, "
                         f"{q.display(st.ci_high):.4g}]{' (' + '; '.join(st.flags) + ')' if st.flags else ''}")
        a = agreement_of(j, alone)
        js = next((s for s, p in zip(joint.outcome.statistics.parameters, joint.parameters) if p.name == q.name),
                  None)
        b = a.between
        between = "n/a (fewer than two runs identify it)" if b is None else (
            f"{q.display(b.mean):.4g} [{q.display(b.mean - 1.96 * b.standard_error):.4g}, "
            f"{q.display(b.mean + 1.96 * b.standard_error):.4g}]; spread {q.display(b.tau):.3g}, I2 {100 * b.i2:.0f} %")
        rows.append((q.name, q.display_unit or "1",
                     f"{q.display(js.estimate):.4g} [{q.display(js.ci_low):.4g}, {q.display(js.ci_high):.4g}]"
                     if js else "per run", between,
                     f"{a.overlap[0]} of {a.overlap[1]} ({len(a.identifying)} runs identify it)",
                     "n/a" if a.overlap_with_spread is None else
                     f"{a.overlap_with_spread[0]} of {a.overlap_with_spread[1]}", "; ".join(shown)))
    return Table("Estimates with 95 % intervals: all runs together and each run alone",
                 ("parameter", "unit", "all runs (one fit)", "between runs (random effects): mean [95 %], spread",
                  "runs whose intervals overlap (pairs)", "... with the spread between runs", "each run alone"),
                 tuple(rows), "A run identifies a parameter when its fit flags it neither not identifiable, nor at "
                              "a bound, nor correlated with another beyond [statistics].correlation (then the run "
                              "fixes a combination of the two, not each). Between runs: DerSimonian-Laird over the "
                              "identifying runs; the spread is what one run's interval cannot see (I2: its share "
                              "of the estimates' variance); a run's interval widened by it is what another run of "
                              "the machine may give.")


def _cross_figure(runs, cross, joint, theta0, output: ResolvedOutput, rms_of) -> Figure:
    from matplotlib.figure import Figure as MplFigure

    rows = _cross_rows(runs, cross, joint, theta0, rms_of)
    fig = MplFigure(figsize=(10, 4.5), layout="constrained")
    ax = fig.subplots()
    x = np.arange(len(rows))
    width = 0.27
    for k, (key, label, color) in enumerate((("priors", "priors", "tab:orange"),
                                             ("without_it", "fitted without the run", "tab:blue"),
                                             ("with_it", "fitted with the run", "tab:gray"))):
        values = [100 * r.get(key, math.nan) / r["rms_recorded"] if r["rms_recorded"] > 0 else math.nan for r in rows]
        ax.bar(x + (k - 1) * width, values, width, label=label, color=color)
    ax.set_xticks(x, [r["run"] for r in rows], rotation=30, ha="right")
    ax.set_ylabel("RMS error [% of RMS recorded]")
    ax.set_title(f"{output.ref}: leave-one-run-out prediction error per run")
    ax.legend()
    ax.grid(True, axis="y", alpha=0.3)
    return Figure("Leave-one-run-out prediction error", figure_png(fig),
                  "Each run's RMS error with the priors, with the set fitted to the other runs, and with the set "
                  "fitted to all runs.")


def _intervals_figure(parameters: Sequence[Parameter], joint: _Fit, alone: Mapping[str, _Fit]) -> Figure:
    from matplotlib.figure import Figure as MplFigure

    fig = MplFigure(figsize=(10, 2.2 * len(parameters) + 1), layout="constrained")
    axes = np.atleast_1d(fig.subplots(len(parameters), 1))
    names = list(alone)
    for j, (q, ax) in enumerate(zip(parameters, axes)):
        for i, name in enumerate(names):
            st = alone[name].outcome.statistics.parameters[j]
            ok = _identifies(st)
            lo, hi = (q.display(st.ci_low), q.display(st.ci_high)) if ok else (math.nan, math.nan)
            ax.plot([lo, hi], [i, i], color="tab:blue" if ok else "tab:gray")
            ax.plot(q.display(st.estimate), i, "o", color="tab:blue" if ok else "tab:gray")
        js = [s for s, p in zip(joint.outcome.statistics.parameters, joint.parameters) if p.name == q.name]
        if js:
            ax.axvspan(q.display(js[0].ci_low), q.display(js[0].ci_high), color="tab:orange", alpha=0.25)
            ax.axvline(q.display(js[0].estimate), color="tab:orange")
        ax.set_yticks(range(len(names)), names)
        ax.set_xlabel(f"{q.name} [{q.display_unit or '1'}]")
        ax.grid(True, alpha=0.3)
    return Figure("Estimates per run with 95 % intervals", figure_png(fig),
                  "Each run fitted alone (blue: interval of an estimate the run identifies; gray: not identified, "
                  "at a bound or correlated with another parameter: estimate only); orange: all runs together.")

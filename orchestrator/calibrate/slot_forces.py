"""Kind "slot_forces": the cutting-force coefficients from the slot-milling recordings.

The recordings are read, folded and compared exactly as ``milling_twin.orchestrator.validation.slot_milling``
does (its functions are reused: ``read_recordings``, ``recorded_waveform``, ``simulate``,
``compare``). Two fits on the learning feeds, both casadi least squares on the models/ expressions:

What is fitted follows the scenario (:func:`fitted_names`): the coefficients of the force instance's
``chip_law`` (linear, Kienzle's exponential, power with edge terms), the runout, and, when the scenario has a
MeasuringChain instance named "chain", its modes (the model of a recording: :mod:`.slot_model`).

1. **Regression of the means**: the per-revolution mean forces against the feed per tooth,
   through ``milling_twin.models.cutting_force.mean_slot_forces`` (closed form for every law; linear in the six
   coefficients of the linear law, Altintas' identification), giving the waveform fit its start.
2. **Waveform fit**: nonlinear least squares of the force time series on the CuttingForce
   equations (``milling_twin.models.cutting_force.equations``: 16 slices, helix, runout) with the coefficients,
   optionally the runout (offset and angle of the tool axis), and one spindle phase per recording
   (nuisance: the recordings' spindle angle is unknown). With 2 flutes the runout enters the chip only
   as offset*cos(angle) (the two flutes' radius difference), so only the offset is fitted (angle 0; a
   phase shift of half a turn swaps the flutes, which gives the other sign). Flute 0's angle at sample k is
   ``phase + omega*k/fs`` (the FMU's angle state integrates exactly this). Only whole revolutions
   are used; the spindle runs at the nominal speed to 4e-5 (a drift of 1.4 deg of spindle angle
   over a 1 s recording, below the 3.6 deg between samples), so sample k and sample k + one
   revolution see the same angle and the time-series sum of squares equals, up to a constant,
   the sum over the per-revolution mean waveform weighted by the number of revolutions: the fit
   uses that exact reduction (100 points per recording instead of 10,000) and the statistics the
   full time series (n samples, the within-bin scatter included). The objective jumps where a
   phase change moves a sample across an edge force switching on (the chip crossing zero), so the
   phases are found by exhaustive search on a 0.1 deg grid (:class:`PhaseSearch`, global over the
   turn) and the coefficients and runout by the least-squares solver (Levenberg-Marquardt unless
   ``[solver].algorithm`` says otherwise) with the phases fixed, alternating until the
   objective stops decreasing. Starts: the regression's coefficients, then drawn ones. With a chain: first
   without it, then the chain's modes from the harmonics with that force (:func:`.slot_model.identify_chain`),
   then everything from there (:func:`fit_slot`). Intervals: :func:`revolution_bootstrap`.

Held-out check (closing the loop): the parameter set is written, the slot-milling scenario is
re-run with it through the FMUs at every recording's conditions, and ``slot_milling.compare``
gives the mean-force relative errors and the waveform r^2 on learning and held-out feeds, next to
the scenario's prior coefficients and the regression's.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import casadi as ca
import numpy as np
from matplotlib.figure import Figure as MplFigure

from milling_twin import datasets
from milling_twin.models.cutting_force import CHIP_LAW_POWER_EDGE, CUTTING_FORCE, mean_slot_forces
from milling_twin.models.measuring_chain import MEASURING_CHAIN
from milling_twin.orchestrator.calibrate.compiled import jit_options
from milling_twin.orchestrator.calibrate.errors import CalibrationError
from milling_twin.orchestrator.calibrate.fit import FitOutcome, fit
from milling_twin.orchestrator.calibrate.graph import NO_DATA_DERIVATIVE
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresSolver, StartOutcome, with_algorithm
from milling_twin.orchestrator.calibrate.parameters import Parameter, resolve_parameter
from milling_twin.orchestrator.calibrate.paramset import write_parameter_set, write_ssv
from milling_twin.orchestrator.calibrate.plots import figure_png
from milling_twin.orchestrator.calibrate.residuals import ResidualModel, from_outputs
from milling_twin.orchestrator.calibrate.result import CalibrationResult, Figure, Series, Table, error_row
from milling_twin.orchestrator.calibrate.slot_model import (CHAIN_INSTANCE, LAW_COEFFICIENTS, MODEL_AXES,
                                                           RECORDED_AXES, SlotModel, chain_harmonics,
                                                           chain_parameter_names, identify_chain)
from milling_twin.orchestrator.calibrate.statistics import with_intervals
from milling_twin.orchestrator.calibrate.scenario_fit import (check_tokens, describe_overrides, identities,
                                                            record_and_publish, with_overrides)
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec, ParameterSpec
from milling_twin.orchestrator.master import SimulationError
from milling_twin.orchestrator.results import sha256_of
from milling_twin.orchestrator.scenario import Ref, Scenario, load_scenario
from milling_twin.orchestrator.validation import slot_milling as sm

__all__ = ["SlotData", "calibrate_slot_forces", "load_slot_data", "regression_model", "waveform_model"]

RUNOUT = ("runout_offset", "runout_angle")
RUNOUT_DEFAULTS = {"runout_offset": ParameterSpec(Ref("force", "runout_offset"), '[parameters."force.runout_offset"]',
                                                  initial=5.0, min=0.0, max=100.0, unit="um",
                                                  start_range=(0.0, 30.0)),
                   "runout_angle": ParameterSpec(Ref("force", "runout_angle"), '[parameters."force.runout_angle"]',
                                                 initial=0.0, min=-360.0, max=360.0, unit="deg", scale=90.0,
                                                 start_range=(-180.0, 180.0))}


class SlotData:
    """The recordings of one fit: folded waveforms and per-revolution means, in the files' axes."""

    def __init__(self, recordings: list[datasets.Recording], revolutions: int, n_flutes: int) -> None:
        self.recordings = recordings
        self.waves, self.within, self.revs, self.rev_means, self.folded = [], [], [], [], []
        for r in recordings:
            points = round(r.sample_rate * 60.0 / r.rpm)
            use = r if revolutions <= 0 else replace(r, forces=r.forces[: revolutions * points],
                                                     time=r.time[: revolutions * points])
            if revolutions > 0 and len(use.forces) < revolutions * points:
                raise ValueError(f"{r.path}: fewer than {revolutions} revolutions")
            wave, std, revs = sm.recorded_waveform(use)
            self.waves.append(wave)
            self.within.append(revs * np.sum(std ** 2, axis=0))
            self.revs.append(revs)
            self.folded.append(use.forces[: revs * points].reshape(revs, points, 3))  # revolutions x points x 3
            self.rev_means.append(self.folded[-1].mean(axis=1))
        self.feed_per_tooth = [r.feed / (r.rpm * n_flutes) / 1000 for r in recordings]  # m

    @property
    def labels(self) -> list[str]:
        return [r.label for r in self.recordings]


def load_slot_data(folder: Path, feeds: tuple[float, ...], key: str, spec: CalibrationSpec, revolutions: int,
                   n_flutes: int) -> SlotData:
    recordings = datasets.read_recordings(folder)
    by_feed = {r.feed: r for r in recordings}
    missing = [f for f in feeds if f not in by_feed]
    if missing:
        spec.fail(key, f"no recording at {missing} mm/min in {folder}; feeds there: {sorted(by_feed)}")
    chosen = [by_feed[f] for f in feeds]
    for r in chosen:
        if r.axial_depth != chosen[0].axial_depth or r.rpm != chosen[0].rpm:
            spec.fail(key, f"{r.path.name}: all recordings of a fit need one spindle speed and axial depth")
    return SlotData(chosen, revolutions, n_flutes)


def _constants(scenario: Scenario, recording: datasets.Recording) -> dict[str, float]:
    """The force instance's parameters and inputs at the recording's conditions (SI)."""
    inst = scenario.instance(sm.INSTANCE)
    values = {**CUTTING_FORCE.defaults(), **{k: float(v) for k, v in inst.parameters.items()},
              **{k: float(v) for k, v in inst.inputs.items()}}
    values.update(spindle_speed=recording.rpm * 2 * math.pi / 60, feed_velocity_x=recording.feed / 60_000,
                  feed_velocity_y=0.0, axial_depth=recording.axial_depth / 1000, displacement_x=0.0,
                  displacement_y=0.0, delayed_displacement_x=0.0, delayed_displacement_y=0.0)
    return values


def slot_model(scenario: Scenario, spec: CalibrationSpec, recordings: list[datasets.Recording],
               points: list[int]) -> SlotModel:
    """The model of ``recordings``: the force instance's chip-thickness law and, when the scenario has a
    MeasuringChain instance named "chain", its n_modes modes (what :func:`fitted_names` lists is fitted);
    compiled to machine code unless ``[slot_forces] compile = false``."""
    names = fitted_names(scenario, spec)
    return SlotModel([_constants(scenario, r) for r in recordings], names[sm.INSTANCE],
                     len(names.get(CHAIN_INSTANCE, [])) // len(chain_parameter_names(1)),
                     [r.rpm / 60 for r in recordings], points,
                     compile_options=jit_options() if spec.slot_forces is None or spec.slot_forces.compile else {})


def waveform_model(model: SlotModel, data: SlotData, parameters: list[Parameter]) -> ResidualModel:
    """Residuals of the mean waveforms (weighted by revolutions) for the model parameters followed by one
    phase per recording (``parameters`` lists both, phases last)."""
    n_model = model.n_model

    def y_of(theta: ca.MX) -> ca.MX:
        return ca.horzcat(*[model.waveform(theta, i, theta[n_model + i]).T for i in range(len(data.waves))])

    counts = np.concatenate([np.full(len(w), rv, dtype=float) for w, rv in zip(data.waves, data.revs)])
    within = np.sum(data.within, axis=0)
    labels = [(data.labels[i], j) for i, w in enumerate(data.waves) for j in range(len(w))]

    def describe(k: int) -> str:
        pair, o = divmod(k, 3)
        label, j = labels[pair]
        return f"{RECORDED_AXES[o]} of {label} at point {j} of the revolution"

    return from_outputs(y_of, parameters, 3, len(counts), counts=counts, within=within, describe_residual=describe,
                        describe_variable=lambda j: parameters[j].name)


def regression_model(data: SlotData, parameters: list[Parameter], n_flutes: int, law: int) -> ResidualModel:
    """Per-revolution mean forces against the feed per tooth through mean_slot_forces (closed form for every
    chip-thickness law; ``parameters``: the law's coefficients, in :data:`LAW_COEFFICIENTS` order)."""
    names = LAW_COEFFICIENTS[law]
    k = ca.SX.sym("K", len(names))
    c = ca.SX.sym("c")
    a = data.recordings[0].axial_depth / 1000
    given = {name: 0.0 for name in LAW_COEFFICIENTS[CHIP_LAW_POWER_EDGE]}
    given.update({name: k[j] for j, name in enumerate(names)})
    means = mean_slot_forces(**given, n_flutes=n_flutes, axial_depth=a, feed_per_tooth=c, chip_law=law)
    f = ca.Function("mean", [k, c], [ca.vertcat(*[means[m] for m in MODEL_AXES])], NO_DATA_DERIVATIVE)
    c_all = np.concatenate([np.full(len(m), ft) for m, ft in zip(data.rev_means, data.feed_per_tooth)])
    mapped = f.map(len(c_all))
    return from_outputs(lambda th: mapped(ca.repmat(th, 1, len(c_all)), ca.DM(c_all).T), parameters, 3, len(c_all),
                        describe_variable=lambda j: parameters[j].name)


class PhaseSearch:
    """The spindle phase of each recording that minimises the fit's own weighted sum of squares for
    given model parameters, by exhaustive search on a grid of ``sm.FINE`` phases per turn (0.1 deg;
    the samples are 3.6 deg apart): the objective is discontinuous in the phase (edge forces switch
    where the chip crosses zero), which gradient steps cannot follow, but it is exact on the grid."""

    def __init__(self, model: SlotModel, data: SlotData) -> None:
        self.model = model
        self.data = data
        self.grid = 2 * math.pi * np.arange(sm.FINE) / sm.FINE

    def __call__(self, theta_model: np.ndarray, weights: np.ndarray) -> np.ndarray:
        return np.array([self.phase(theta_model, weights, i) for i in range(len(self.data.waves))])

    def phase(self, theta_model: np.ndarray, weights: np.ndarray, i: int, wave: np.ndarray | None = None) -> float:
        """The best phase of recording ``i`` (or of ``wave``, a waveform at its conditions)."""
        fine = self.model.fine_waveform(theta_model, i, sm.FINE)
        wave = self.data.waves[i] if wave is None else wave
        points = len(wave)
        index = (np.arange(sm.FINE)[:, None] + np.arange(points)[None, :] * (sm.FINE // points)) % sm.FINE
        error = fine[index] - wave[None, :, :]  # phases x points x axes
        return float(self.grid[int(np.argmin(np.einsum("spa,a->s", error ** 2, weights ** 2)))])


def alternating(search: PhaseSearch, n_model: int, scale: np.ndarray, rounds: int = 12, stationary: float = 1e-6):
    """A start's solution strategy: phases by :class:`PhaseSearch`, then the least-squares solver (at most the
    solver's max_iterations) on the model parameters with the phases fixed; repeated while the
    objective decreases by more than ``stationary`` (relative) per round. A round whose solver result
    is worse than its start (a bounce at a discontinuity) is not taken, and ends the start."""

    def solve(lsq: LeastSquaresSolver, x0: np.ndarray, p: np.ndarray, index: int) -> StartOutcome:
        t0 = time.perf_counter()
        x = np.array(x0, dtype=float)
        weights = p[-3:]
        trace: list[float] = []
        iterations, objective, why = 0, math.inf, f"no decrease by {stationary:g} within {rounds} rounds"
        converged = False
        for k in range(rounds):
            x[n_model:] = search(x[:n_model] * scale[:n_model], weights) / scale[n_model:]
            lbx, ubx = lsq.problem.lbx.copy(), lsq.problem.ubx.copy()
            lbx[n_model:] = ubx[n_model:] = x[n_model:]
            run = lsq.solve(x, p, index, lbx=lbx, ubx=ubx)
            iterations += run.iterations
            trace += run.trace.get("obj", [])
            if run.x is None:
                return StartOutcome(index, np.asarray(x0), "failed", f"round {k + 1}: {run.message}",
                                    wall_time=time.perf_counter() - t0, iterations=iterations, trace={"obj": trace})
            if run.objective >= objective:
                converged, why = True, f"round {k + 1} gave no decrease ({lsq.name}: {run.message})"
                break
            decrease = (objective - run.objective) / run.objective if math.isfinite(objective) else math.inf
            x, objective = run.x, run.objective
            if decrease <= stationary:
                converged, why = True, f"relative decrease {decrease:.2g} in round {k + 1} ({lsq.name}: {run.message})"
                break
        return StartOutcome(index, np.asarray(x0), "converged" if converged else "not converged",
                            f"phase search + {lsq.name}, {k + 1} rounds: {why}", x, objective, iterations,
                            time.perf_counter() - t0, {"obj": trace})

    return solve


LAW_NAMES = {1: "linear", 2: "exponential (Kienzle)", 3: "power with edge"}
CHAIN_DEFAULTS = {  # start ranges of the measuring chain's parameters when the spec does not give them
    "frequency": dict(min=200.0, max=5000.0, unit="Hz", start_range=(500.0, 2500.0)),
    "damping": dict(min=0.005, max=0.5, start_range=(0.02, 0.2)),
    "gain": dict(min=-5.0, max=5.0, start_range=(-0.5, 0.5)),
}
EXPONENT_DEFAULTS = dict(min=-0.5, max=0.95, start_range=(0.0, 0.6))


def fitted_names(scenario: Scenario, spec: CalibrationSpec) -> dict[str, list[str]]:
    """instance -> the parameters kind slot_forces fits: the force law's coefficients, the runout (offset; with
    more than 2 flutes also its angle) and, with a measuring chain, its active modes."""
    law = int(scenario.instance(sm.INSTANCE).parameters.get("chip_law", CUTTING_FORCE.variable("chip_law").start))
    if law not in LAW_COEFFICIENTS:
        raise CalibrationError(f"{scenario.path}: {sm.INSTANCE}.chip_law = {law} is not one of "
                               f"{sorted(LAW_COEFFICIENTS)}")
    runout = [n for n in RUNOUT if n != "runout_angle" or sm._n_flutes(scenario) > 2]
    names = {sm.INSTANCE: list(LAW_COEFFICIENTS[law]) + (runout if spec.slot_forces.runout else [])}
    if CHAIN_INSTANCE in scenario.execution_order:
        modes = int(scenario.instance(CHAIN_INSTANCE).parameters.get("n_modes", 0))
        names[CHAIN_INSTANCE] = chain_parameter_names(modes)
    return names


def _default_spec(instance: str, name: str) -> ParameterSpec:
    key = f'[parameters."{instance}.{name}"]'
    if name in RUNOUT_DEFAULTS:
        return RUNOUT_DEFAULTS[name]
    if name.startswith("mc_"):
        return ParameterSpec(Ref(instance, name), key, **EXPONENT_DEFAULTS)
    kind = name.split("_")[0]
    if instance == CHAIN_INSTANCE and kind in CHAIN_DEFAULTS:
        return ParameterSpec(Ref(instance, name), key, **CHAIN_DEFAULTS[kind])
    return ParameterSpec(Ref(instance, name), key)


def _parameters(spec: CalibrationSpec, scenario: Scenario, names: Mapping[str, list[str]], initial: dict[str, float],
                source: str = "the scenario") -> list[Parameter]:
    """The fitted parameters in ``names`` order (instance by instance), each from the spec's section, else the
    defaults above; ``initial``: start values by "instance.name" from an earlier stage (``source``). A section for
    a coefficient the scenario's chip_law does not use is ignored (one spec serves every law); any other section
    naming something not fitted is an error."""
    specs = {p.name: p for p in spec.parameters}
    allowed = {f"{i}.{n}" for i, group in fitted_names(scenario, spec).items() for n in group}
    other_laws = {f"{sm.INSTANCE}.{n}" for n in LAW_COEFFICIENTS[CHIP_LAW_POWER_EDGE]}  # a section for another law
    for p in spec.parameters:
        if p.name not in allowed and p.name not in other_laws:
            spec.fail(p.key, f"kind slot_forces fits {', '.join(sorted(allowed))} with this scenario (the force's "
                             f"chip_law, the runout setting and the chain's n_modes decide); not {p.name}")
        if p.variable == "runout_angle" and sm._n_flutes(scenario) == 2:
            spec.fail(p.key, "with 2 flutes the forces depend on the runout only through offset*cos(angle) (the "
                             "difference of the two flute radii), so offset and angle cannot both be fitted; the "
                             "angle stays 0 and the spindle phase (free) covers both signs")
    out = []
    for instance, group in names.items():
        inst = scenario.instance(instance)
        definition = CUTTING_FORCE if instance == sm.INSTANCE else MEASURING_CHAIN
        for name in group:
            full = f"{instance}.{name}"
            ps = specs.get(full) or _default_spec(instance, name)
            var = inst.variables[name]
            default = initial.get(full, float(inst.parameters.get(name, definition.variable(name).start)))
            out.append(resolve_parameter(ps, var.unit, default, var.min, var.max, definition.variable(name).display_unit,
                                         spec.fail, source if full in initial else "the scenario"))
    return out


def _phase_parameters(data: SlotData) -> list[Parameter]:
    return [Parameter(f"phase[{label}]", 0.0, -4 * math.pi, 4 * math.pi, 1.0, "rad", "deg", 180 / math.pi,
                      (0.0, 2 * math.pi), False, nuisance=True) for label in data.labels]


def _means_png(learn: SlotData, held: SlotData, regression: FitOutcome, waveform: FitOutcome, n_flutes: int,
               law: int) -> bytes:
    fig = MplFigure(figsize=(12, 3.8))
    fig.subplots_adjust(left=0.06, right=0.98, top=0.9, bottom=0.14, wspace=0.28)
    axes = fig.subplots(1, 3)
    a = learn.recordings[0].axial_depth / 1000
    ft = np.linspace(0, max(learn.feed_per_tooth + held.feed_per_tooth) * 1.1, 50)
    names = [q.ref.variable for q in regression.parameters]
    zero = {name: 0.0 for name in LAW_COEFFICIENTS[CHIP_LAW_POWER_EDGE]}
    reg = {**zero, **dict(zip(names, regression.theta))}
    wav = {**zero, **dict(zip(names, waveform.theta[:len(names)]))}
    for k, axis in enumerate(RECORDED_AXES):
        ax = axes[k]
        for data, style, label in ((learn, "ko", "learning feeds"), (held, "rs", "held-out feeds")):
            ax.plot(np.array(data.feed_per_tooth) * 1000, [m[:, k].mean() for m in data.rev_means], style,
                    mfc="none" if data is held else None, label=f"recorded mean, {label}")
        for coefficients, color, label in ((reg, "tab:blue", "regression"), (wav, "tab:green", "waveform fit")):
            line = [mean_slot_forces(**coefficients, n_flutes=n_flutes, axial_depth=a, feed_per_tooth=c,
                                     chip_law=law)[MODEL_AXES[k]] for c in ft]
            ax.plot(ft * 1000, line, color=color, label=f"closed-form mean, {label} coefficients")
        ax.set_title(f"mean {axis} (file) = model {MODEL_AXES[k]}")
        ax.set_xlabel("feed per tooth [mm]")
        ax.set_ylabel("force [N]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7)
    return figure_png(fig)


@dataclass
class SlotFit:
    """The two stages of a fit on some recordings: the regression of the means (starting values) and the
    waveform fit, with the model and the residuals the waveform fit used."""

    model: SlotModel
    regression: FitOutcome
    waveform: FitOutcome
    residuals: ResidualModel
    timings: dict[str, float]

    @property
    def model_parameters(self) -> list[Parameter]:
        return [q for q in self.waveform.parameters if not q.nuisance]


def fit_slot(spec: CalibrationSpec, scenario: Scenario, learn: SlotData, n_flutes: int,
             progress: bool = False) -> SlotFit:
    """The regression of the per-revolution means for the scenario's chip-thickness law, then the waveform fit
    (law, runout, measuring chain and phases; :func:`alternating`), with revolution-bootstrap intervals when
    ``[slot_forces].bootstrap`` asks for them."""
    timings = {}
    t0 = time.perf_counter()
    names = fitted_names(scenario, spec)
    law = int(_constants(scenario, learn.recordings[0])["chip_law"])
    law_names = list(LAW_COEFFICIENTS[law])
    coefficient_params = _parameters(spec, scenario, {sm.INSTANCE: law_names}, {})
    regression = fit(regression_model(learn, coefficient_params, n_flutes, law), np.concatenate(learn.rev_means),
                     weights=[1.0] * 3, sigma=[None] * 3, solver=replace(spec.solver, starts=1),
                     statistics=spec.statistics)
    timings["fit: regression of per-revolution means"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    initial = {f"{sm.INSTANCE}.{n}": v for n, v in zip(law_names, regression.theta)}
    model_params = _parameters(spec, scenario, names, initial, "the regression of the means")
    model = slot_model(scenario, spec, learn.recordings, [len(w) for w in learn.waves])
    force_params = [q for q in model_params if q.ref.instance == sm.INSTANCE]
    force_model = replace(model, chain_modes=0) if model.chain_modes else model
    waveform, residuals = _waveform_fit(force_model, learn, force_params, spec, progress)
    timings["fit: waveform (law, runout, phases)"] = time.perf_counter() - t0
    if model.chain_modes:
        # the chain from the tooth-passing harmonics with that force, then everything together from there
        t0 = time.perf_counter()
        n_force = len(force_params)
        phases = waveform.theta[n_force:]
        weights = np.sqrt(waveform.weights) / waveform.sigma
        chain_params = [q for q in model_params if q.ref.instance == CHAIN_INSTANCE]
        bounds = {q.ref.variable: (q.lower, q.upper) for q in chain_params}
        chain = identify_chain(chain_harmonics(force_model, waveform.theta, phases, learn.waves, learn.revs),
                               model.chain_modes, weights, bounds["frequency_1"], bounds["damping_1"])
        timings["fit: measuring chain from the harmonics"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        start = np.concatenate([waveform.theta[:n_force], [np.clip(chain[q.ref.variable], q.lower, q.upper)
                                                           for q in chain_params], phases])
        waveform, residuals = _waveform_fit(model, learn, model_params, spec, progress, start)
        timings["fit: waveform with the chain (law, runout, chain, phases)"] = time.perf_counter() - t0
    if spec.slot_forces.bootstrap:
        t0 = time.perf_counter()
        replicates = revolution_bootstrap(residuals, waveform, learn, spec.slot_forces.bootstrap, spec.solver.seed)
        waveform = replace(waveform, statistics=with_intervals(waveform.statistics, replicates))
        timings["intervals: revolution bootstrap"] = time.perf_counter() - t0
    return SlotFit(model, regression, waveform, residuals, timings)


def _waveform_fit(model: SlotModel, learn: SlotData, model_params: list[Parameter], spec: CalibrationSpec,
                  progress: bool, start: np.ndarray | None = None) -> tuple[FitOutcome, ResidualModel]:
    """The waveform fit of ``model`` (its parameters then one phase per recording): the spec's starts, or the one
    ``start`` given (SI, phases included)."""
    params = model_params + _phase_parameters(learn)
    residuals = waveform_model(model, learn, params)
    strategy = alternating(PhaseSearch(model, learn), model.n_model, residuals.scale())
    solver = spec.solver if start is None else replace(spec.solver, starts=1)
    # not expanded to SX: the graph is a few mapped SX functions and constant DFT products, which casadi's MX
    # machine evaluates about as fast as the expansion, and expanding it cost 40 to 70 s of a 70 s fit
    # Levenberg-Marquardt unless [solver].algorithm says otherwise: on the five recordings it reached a lower
    # objective than IPOPT in a third of the time (docs/calibration.md)
    problem = with_algorithm(replace(residuals.problem, algorithm="levenberg-marquardt"), solver.algorithm)
    lsq = LeastSquaresSolver(problem, max_iterations=solver.max_iterations, tolerance=solver.tolerance,
                             hessian=solver.hessian)
    outcome = fit(residuals, np.concatenate(learn.waves), weights=[1.0] * 3, sigma=[None] * 3, solver=solver,
                  statistics=spec.statistics, progress=progress, strategy=strategy, lsq=lsq,
                  starts=None if start is None else np.asarray(start, dtype=float)[None, :])
    return outcome, residuals


def revolution_bootstrap(residuals: ResidualModel, outcome: FitOutcome, data: SlotData, replicates: int,
                         seed: int = 0) -> np.ndarray:
    """Replicates (replicates x parameters, SI) of the waveform fit's estimates: each recording's revolutions
    drawn with replacement (blocks of one whole revolution: the autocorrelation inside a revolution, the
    dynamometer's ringing among it, is kept; every recording keeps its number of revolutions), the mean waveforms
    recomputed, and one Gauss-Newton step from the estimate (as ``statistics.block_bootstrap``; the phases move
    with the rest). The spread is what the revolution-to-revolution variation of the recordings allows; a model
    error that repeats every revolution does not enter it (the leave-one-feed-out report shows that part)."""
    theta = outcome.theta
    weights = np.sqrt(outcome.weights) / outcome.sigma
    recorded = np.concatenate(data.waves)
    r, jac = residuals.residual_jacobian(theta, residuals.data_vector(recorded, weights))
    norms = np.linalg.norm(jac, axis=0)
    norms = np.where(norms > 0, norms, 1.0)  # columns of unit length: SI parameters span 15 decades
    step = np.linalg.pinv(jac / norms) / norms[:, None]
    scale = np.repeat(np.sqrt(residuals.counts), 3) * np.tile(weights, len(residuals.counts))
    rng = np.random.default_rng(seed)
    out = np.empty((replicates, theta.size))
    for b in range(replicates):
        waves = [f[rng.integers(0, len(f), len(f))].mean(axis=0) for f in data.folded]
        r_b = np.asarray(r).ravel() - scale * (np.concatenate(waves) - recorded).ravel()
        out[b] = theta - step @ r_b
    return out


def calibrate_slot_forces(spec: CalibrationSpec, fmu_dir: Path, out_dir: Path, data_option: str | Path | None,
                          progress: bool = False, *, write_set: Path | None = None,
                          overrides: Mapping[str, Any] | None = None) -> CalibrationResult:
    """The parameter set goes to ``out_dir`` under the file name of the spec's ``parameter_set``, and to
    ``write_set`` too (after the re-simulation) if given; ``overrides`` change the scenario first."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    folder = datasets.data_dir(data_option)
    scenario = with_overrides(load_scenario(spec.scenario, fmu_dir), overrides)
    sm._check_scenario(scenario)
    n_flutes = sm._n_flutes(scenario)
    cfg = spec.slot_forces
    learn = load_slot_data(folder, cfg.learning_feeds, "[slot_forces].learning_feeds", spec, cfg.revolutions, n_flutes)
    held = load_slot_data(folder, cfg.validation_feeds, "[slot_forces].validation_feeds", spec, cfg.revolutions,
                          n_flutes)
    if held.recordings[0].axial_depth != learn.recordings[0].axial_depth:
        spec.fail("[slot_forces].validation_feeds", "held-out recordings differ in axial depth from the learning ones")
    # what is fitted is what the FMUs run: the force's and the chain's FMUs against models/
    tokens = check_tokens(scenario, [sm.INSTANCE] + [CHAIN_INSTANCE] * (CHAIN_INSTANCE in scenario.execution_order))
    timings["read and fold the recordings"] = time.perf_counter() - t0

    # 1. the regression of per-revolution means, 2. the waveform fit starting from it
    t0 = time.perf_counter()
    result_fit = fit_slot(spec, scenario, learn, n_flutes, progress)
    regression, waveform, model_params = result_fit.regression, result_fit.waveform, result_fit.model_parameters
    coefficient_params = list(regression.parameters)
    law_names = [q.ref.variable for q in coefficient_params]
    prior = {name: float(scenario.instance(sm.INSTANCE).parameters.get(name, CUTTING_FORCE.variable(name).start))
             for name in law_names}
    timings.update(result_fit.timings)
    timings["fit (total)"] = time.perf_counter() - t0
    params = list(waveform.parameters)

    # 3. parameter set and re-simulation through the FMUs
    t0 = time.perf_counter()
    source: dict[str, str | Path] = {  # paths relative to where the set is written
        "calibration": spec.name, "spec": spec.path, "spec_sha256": spec.sha256, "scenario": spec.scenario,
        "data": "slot-milling recordings (" + ", ".join(r.path.name for r in learn.recordings) + "; not in the "
                "repository: " + sm.SOURCE + ")",
        "data_sha256": ", ".join(sha256_of(r.path)[:16] for r in learn.recordings)}
    if overrides:
        source["overrides"] = describe_overrides(overrides)
    set_args = (params, waveform.theta, waveform.statistics.parameters, spec.description or spec.name, source,
                f"milling-twin calibrate {os.path.relpath(spec.path)}")
    set_path = write_parameter_set(out_dir / spec.parameter_set.name, *set_args)
    ssv = write_ssv(out_dir / f"{spec.parameter_set.stem}.ssv", spec.name, params, waveform.theta)
    calibrated = with_overrides(load_scenario(spec.scenario, fmu_dir, parameter_sets=[set_path]), overrides,
                                [q.ref for q in model_params])
    runs = out_dir / "runs"
    cases: dict[str, list[tuple[str, datasets.Recording, dict]]] = {"prior": [], "regression": [], "calibrated": []}
    reg_coefficients = dict(zip(law_names, regression.theta))
    try:
        for dataset, group in (("learning", learn), ("validation", held)):
            for r in group.recordings:
                for name, case, coefficients in (("prior", scenario, None), ("regression", scenario, reg_coefficients),
                                                 ("calibrated", calibrated, None)):
                    results = sm.simulate(case, r, runs, coefficients, f"_{name}")
                    cases[name].append((dataset, r, sm.compare(r, results)))
    except SimulationError as exc:
        raise CalibrationError(f"re-simulation of the slot-milling scenario failed: {exc}") from exc
    timings["re-simulate (FMU, 3 coefficient sets x all feeds)"] = time.perf_counter() - t0

    series, rows = [], []
    for (dataset, r, before), (_, _, after), (_, _, reg) in zip(cases["prior"], cases["calibrated"], cases["regression"]):
        rec_wave, _, sim_before = before["_waves"]
        sim_after = after["_waves"][2]
        angle = np.arange(len(rec_wave)) * 360.0 / len(rec_wave)
        for k, axis in enumerate(RECORDED_AXES):
            series.append(Series(f"{sm.INSTANCE}.{MODEL_AXES[k]}", f"{axis} (file)", dataset, angle, rec_wave[:, k],
                                 sim_before[:, k], sim_after[:, k], "N", "N", 1.0, label=r.label,
                                 x_label="spindle angle [deg] (per-revolution mean)"))
        for name, c in (("prior", before), ("regression", reg), ("waveform fit", after)):
            rows.append((r.label, dataset, name,
                         " / ".join(f"{100 * c['mean_relative_error'][a]:+.1f}" for a in RECORDED_AXES),
                         " / ".join(f"{c['waveform_r2'][a]:.3f}" for a in RECORDED_AXES)))
    held_errors = {name: np.array([[abs(c["mean_relative_error"][a]) for a in RECORDED_AXES]
                                   for d, _, c in cases[name] if d == "validation"]) for name in cases}
    held_r2 = {name: np.array([[c["waveform_r2"][a] for a in RECORDED_AXES] for d, _, c in cases[name]
                               if d == "validation"]) for name in cases}
    tables = [
        Table("Slot milling through the FMUs: mean-force relative error and waveform r2 per recording",
              ("recording", "data", "coefficients", "mean error Fx / Fy / Fz [%]", "waveform r2 Fx / Fy / Fz"),
              tuple(rows), "As orchestrator.validation.slot_milling computes them (phase aligned by cross-correlation "
                           "of the per-revolution waveform); files' axes: Fx cross-feed = model Fy, Fy feed = model Fx."),
        Table("Held-out feeds: mean over recordings and axes",
              ("coefficients", "mean |mean-force error| [%]", "mean waveform r2",
               "per axis |error| Fx / Fy / Fz [%]", "per axis r2 Fx / Fy / Fz"),
              tuple((name, f"{100 * held_errors[name].mean():.2f}", f"{held_r2[name].mean():.3f}",
                     " / ".join(f"{100 * v:.2f}" for v in held_errors[name].mean(axis=0)),
                     " / ".join(f"{v:.3f}" for v in held_r2[name].mean(axis=0))) for name in cases)),
        Table(f"Coefficients ({LAW_NAMES[result_fit.model.law]} law): regression of per-revolution means vs "
              "waveform fit (95 % CI)",
              ("coefficient", "unit", "prior (scenario)", "regression", "regression 95 % CI", "waveform fit",
               "waveform 95 % CI"),
              tuple((q.name, q.display_unit, f"{q.display(prior[q.ref.variable]):.4g}",
                     f"{q.display(rs.estimate):.5g}", f"[{q.display(rs.ci_low):.5g}, {q.display(rs.ci_high):.5g}]",
                     f"{q.display(ws.estimate):.5g}", f"[{q.display(ws.ci_low):.5g}, {q.display(ws.ci_high):.5g}]")
                    for q, rs, ws in zip(coefficient_params, regression.statistics.parameters,
                                         waveform.statistics.parameters)),
              f"Regression: {regression.statistics.n_residuals} per-revolution means x axes; waveform: "
              f"{waveform.statistics.n_residuals} samples x axes ({sum(learn.revs)} revolutions). "
              + (f"Waveform intervals: revolution bootstrap ({cfg.bootstrap} replicates: whole revolutions of each "
                 "recording drawn with replacement, so the autocorrelation within a revolution is kept)."
                 if cfg.bootstrap else "Waveform intervals assume independent residuals; the residuals are "
                 "correlated (resonance), so they are too narrow (set [slot_forces].bootstrap).")),
    ]
    if cfg.leave_one_out:
        from milling_twin.orchestrator.calibrate.slot_lofo import (bound_table, leave_one_feed_out, lofo_tables,
                                                                   recorded_bound, summary)

        t0 = time.perf_counter()
        folds = leave_one_feed_out(spec, scenario, folder, n_flutes)
        timings["leave one feed out (a fit per feed)"] = time.perf_counter() - t0
        label = LAW_NAMES[result_fit.model.law] + (f" law, chain of {result_fit.model.chain_modes} modes"
                                                   if result_fit.model.chain_modes else " law, no chain")
        tables += lofo_tables(folds, label)
        bound = recorded_bound(spec, folder, n_flutes)
        if bound:  # three feeds at least
            tables.append(bound_table(bound))
    figures = [Figure("Mean forces against the feed per tooth",
                      _means_png(learn, held, regression, waveform, n_flutes, result_fit.model.law),
                      "Recorded per-revolution means (learning filled, held-out open) and the closed-form means of "
                      "both coefficient sets.")]
    ident = identities(spec, scenario, tokens)
    ident["recorded"] = [{"path": str(r.path), "sha256": sha256_of(r.path), "role": d}
                         for d, g in (("learning", learn), ("validation", held)) for r in g.recordings]
    published = record_and_publish(ident, set_path, set_args, write_set, overrides)
    notes = [f"Data: {folder} (never copied into the repository; source {sm.SOURCE}).",
             "Learning feeds " + ", ".join(f"{f:g}" for f in cfg.learning_feeds) + " mm/min; held-out "
             + ", ".join(f"{f:g}" for f in cfg.validation_feeds) + " mm/min.",
             "Figures and errors per feed come from FMU runs of the slot-milling scenario (0.1 s, 10 revolutions), "
             "with the prior coefficients (orange), and with the calibrated parameter set applied by name (blue)."]
    if waveform.note:
        notes.append(waveform.note)
    result = CalibrationResult(spec, waveform, series, [error_row(s) for s in series], ident, timings, out_dir, set_path,
                               ssv, None, notes, figures, tables, published_set=published)
    result.extra.update(regression=regression, cases=cases,
                        held_out={"mean_abs_error": {k: v.tolist() for k, v in held_errors.items()},
                                  "r2": {k: v.tolist() for k, v in held_r2.items()}})
    if cfg.leave_one_out:
        result.extra["leave_one_out"] = {"folds": folds, "summary": summary(folds),
                                         "recorded_bound": {d: summary(f) for d, f in bound.items()}}
    return result

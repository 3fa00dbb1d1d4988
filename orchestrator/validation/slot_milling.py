"""Slot milling: the CuttingForce FMU against measured Kistler forces.

    milling-twin validate slot-milling [--data DIR] [--scenario FILE]
        [--fmu-dir DIR] [--out DIR]

The data (five DynoWare exports, 6000 rpm, 2 flutes, 3 mm axial depth, full slot, feeds 300 ...
1500 mm/min, forces at 10 kHz) have no licence to redistribute: they stay outside the repository.
Their folder is ``--data DIR``, else ``$MILLING_TWIN_SLOT_DATA``, else
``../shared/data/slot_milling_forces`` beside the repository; when it is missing the script says
where to put the files and exits with status 2.

For each recording the scenario (default ``scenarios/slot_milling.toml``) is run through the
orchestrator with the spindle speed, feed and axial depth taken from the file name
(``6-n6000f300ap3ae25.csv``: n rpm, f mm/min, ap mm, ae mm) as the force instance's constant inputs,
then compared with the recording:

* mean force per axis over the whole recording against the simulated mean over whole
  revolutions: relative error ``(simulated - recorded) / |recorded|``;
* the per-revolution waveform: the recording folded at the spindle period (all revolutions
  averaged), the simulation's waveform over its spindle angle; one phase shift for all three axes,
  the one maximizing their summed correlation (the recording's spindle phase is unknown), then per
  axis ``r2 = 1 - sum((rec - sim)^2) / sum((rec - mean(rec))^2)`` (waveform and its mean; negative
  when the simulation is worse than the recorded mean) and ``r2_shape`` = squared correlation
  (shape only, insensitive to offset and scale).

Axes: the files' Fy column is the feed direction and Fx the cross-feed (as the source's scripts
treat them), so recorded (Fx, Fy, Fz) is compared with simulated (Fy, Fx, Fz), signs unchanged:
with positive coefficients the mechanistic means on the tool (Fx < 0 along the feed, Fy > 0, Fz > 0)
have the recorded signs. That is the force on the workpiece (what a dynamometer measures) in a
right-handed frame with z pointing down (Kistler's convention), x_dyn = -y and y_dyn = -x.

Two coefficient sets are run: the scenario's (literature priors; the workpiece material of the
recordings is not stated) and the six coefficients identified from these five recorded means
(Altintas' linear regression, ``milling_twin.models.cutting_force.identify_slot_coefficients``): the latter's
mean errors are in-sample, its waveform r2 is not fitted. Writes ``slot_milling.json`` and PNG
plots into ``<out>/<scenario file name>/`` (the runs themselves into its ``runs/``).

The force instance may also be the force net (``scenarios/slot_milling_forcenet.toml``: the same scenario
with ``fmu = "ForceNet"``). It has no coefficients: its sets are the network packed in the FMU ("prior",
trained on the mechanistic model with the literature coefficients) and, with ``--finetuned DIR`` (written by
``milling-twin train forcenet-finetune``), for each recording the network fine-tuned on the four
other recordings ("finetuned", a left-out prediction), run as a copy of the FMU with those weights.
"""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from milling_twin.models.cutting_force import CUTTING_FORCE, identify_slot_coefficients, mean_slot_forces
from milling_twin.orchestrator.master import SimulationError, run
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Scenario, ScenarioError, load_scenario
from milling_twin.datasets import SOURCE, Recording, data_dir, read_recordings

REPO = Path(__file__).resolve().parents[2]
DEFAULT_SCENARIO = REPO / "scenarios" / "slot_milling.toml"
INSTANCE = "force"  # the CuttingForce instance of the scenario
# recorded column -> simulated output (model frame), see the module docstring
AXES = {"Fx": "Fy", "Fy": "Fx", "Fz": "Fz"}
COEFFICIENTS = ("Ktc", "Krc", "Kac", "Kte", "Kre", "Kae")
FINE = 3600  # points of the simulated waveform per revolution (0.1 deg)
SET_LABELS = {"prior": "prior coefficients", "identified": "identified coefficients",
              "finetuned": "network fine-tuned on the other feeds"}
NET_PRIOR_LABEL = "network trained on the mechanistic model"  # "prior" of a force model without coefficients


def set_labels(model: str) -> dict[str, str]:
    return SET_LABELS if model == "CuttingForce" else {**SET_LABELS, "prior": NET_PRIOR_LABEL}


def _n_flutes(scenario: Scenario) -> int:
    inst = scenario.instance(INSTANCE)
    return int(inst.parameters.get("n_flutes", 2))


FORCE_INPUTS = ("spindle_speed", "feed_velocity_x", "feed_velocity_y", "axial_depth")
FORCE_OUTPUTS = ("Fx", "Fy", "Fz", "spindle_angle")


def _check_scenario(scenario: Scenario) -> None:
    """A force instance named INSTANCE (CuttingForce, or any FMU with its inputs and outputs: ForceNet)."""
    if INSTANCE not in scenario.execution_order:
        raise ScenarioError(scenario.path, f"[fmus.{INSTANCE}]", "the slot-milling validation needs a CuttingForce "
                                                                 f"(or ForceNet) instance named {INSTANCE!r}")
    variables = scenario.instance(INSTANCE).variables
    missing = [n for n in FORCE_INPUTS + FORCE_OUTPUTS if n not in variables]
    if missing:
        raise ScenarioError(scenario.path, f"[fmus.{INSTANCE}]", f"{scenario.instance(INSTANCE).model_identifier} "
                            f"lacks {', '.join(missing)}: the slot-milling validation needs a force model with the "
                            "inputs and outputs of CuttingForce")
    wanted = {f"{INSTANCE}.{n}" for n in ("Fx", "Fy", "Fz", "spindle_angle")}
    missing = wanted - {str(r) for r in scenario.outputs}
    if missing:
        raise ScenarioError(scenario.path, "[outputs].record", f"must record {', '.join(sorted(missing))}")


def simulate(scenario: Scenario, recording: Recording, out_dir: Path, coefficients: dict | None = None,
             tag: str = "", fmu: Path | None = None) -> pd.DataFrame:
    """Run ``scenario`` at the recording's conditions (constant inputs of the force instance), with
    ``coefficients`` (parameters) changed and the force instance's FMU replaced by ``fmu`` if given (a copy
    with other resources, e.g. another network: the same model description)."""
    inst = scenario.instance(INSTANCE)
    inputs = {**inst.inputs, "spindle_speed": recording.rpm * 2 * math.pi / 60,
              "feed_velocity_x": recording.feed / 60_000, "feed_velocity_y": 0.0,
              "axial_depth": recording.axial_depth / 1000}
    force = replace(inst, inputs=inputs, parameters={**inst.parameters, **(coefficients or {})},
                    path=fmu or inst.path)
    case = replace(scenario, name=f"{recording.label}{tag}",
                   instances=tuple(force if i.name == INSTANCE else i for i in scenario.instances))
    result = run(case, out_dir, progress=False)
    if result.status != "completed":
        raise SimulationError(INSTANCE, result.end_time, result.status)
    return load_results(result.run_dir)


def recorded_waveform(recording: Recording) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean and standard deviation over revolutions (points per revolution x 3), number of revolutions."""
    per_rev = recording.sample_rate * 60.0 / recording.rpm
    points = round(per_rev)
    if abs(per_rev - points) > 1e-9 * per_rev:
        raise ValueError(f"{recording.path}: {per_rev} samples per revolution is not an integer")
    revs = len(recording.forces) // points
    folded = recording.forces[: revs * points].reshape(revs, points, 3)
    return folded.mean(axis=0), folded.std(axis=0), revs


CHAIN_INSTANCE = "chain"  # a MeasuringChain between the force and what the dynamometer records (optional)


def recorded_columns(results: pd.DataFrame) -> list[str]:
    """The result columns compared with the recorded Fx, Fy, Fz: the measuring chain's measured forces when the
    scenario has one (instance "chain", fed the force in the recorded axes), else the force model's outputs."""
    chain = [f"{CHAIN_INSTANCE}.measured_{a}" for a in ("x", "y", "z")]
    if all(c in results.columns for c in chain):
        return chain
    return [f"{INSTANCE}.{AXES[a]}" for a in ("Fx", "Fy", "Fz")]


def simulated_waveform(results: pd.DataFrame, rpm: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulated forces in the recorded axes over the last whole revolutions, as a function of
    the spindle angle on FINE points per revolution, and their mean over those revolutions. Through a measuring
    chain the first revolution is left out (the chain's transient from rest)."""
    t = results["time"].to_numpy()
    period = 60.0 / rpm
    columns = recorded_columns(results)
    settle = 1 if columns[0].startswith(CHAIN_INSTANCE + ".") else 0
    revs = math.floor((t[-1] - t[0]) / period + 1e-9) - settle
    if revs < 1:
        raise ValueError(f"the simulation covers {t[-1] - t[0]} s, less than {1 + settle} revolution(s) ({period} s)")
    last = t >= t[-1] - revs * period + 1e-12
    angle = results[f"{INSTANCE}.spindle_angle"].to_numpy()[last]
    forces = np.column_stack([results[c].to_numpy()[last] for c in columns])
    order = np.argsort(angle, kind="stable")
    grid = np.arange(FINE) * 2 * math.pi / FINE
    wave = np.column_stack([np.interp(grid, angle[order], forces[order, k], period=2 * math.pi) for k in range(3)])
    return wave, forces.mean(axis=0)


def align(recorded: np.ndarray, simulated_fine: np.ndarray) -> tuple[int, np.ndarray]:
    """The shift (in FINE steps) of the simulated waveform that best matches the recorded one (summed
    correlation of the three axes), and the simulated waveform at the recorded points so shifted."""
    points = len(recorded)
    index = (np.arange(FINE)[:, None] + np.round(np.arange(points) * FINE / points).astype(int)[None, :]) % FINE
    candidates = simulated_fine[index]  # shifts x points x axes
    rec = recorded - recorded.mean(axis=0)
    sim = candidates - candidates.mean(axis=1, keepdims=True)
    norm = np.sqrt((sim ** 2).sum(axis=1)) * np.sqrt((rec ** 2).sum(axis=0))
    correlation = np.where(norm > 0, (sim * rec[None]).sum(axis=1) / np.where(norm > 0, norm, 1), 0.0)
    shift = int(np.argmax(correlation.sum(axis=1)))
    return shift, candidates[shift]


def waveform_scores(recorded: np.ndarray, simulated: np.ndarray) -> tuple[list[float], list[float]]:
    """Per axis: r2 (coefficient of determination of the recorded waveform) and squared correlation."""
    r2, shape = [], []
    for k in range(recorded.shape[1]):
        rec, sim = recorded[:, k], simulated[:, k]
        total = float(np.sum((rec - rec.mean()) ** 2))
        r2.append(1.0 - float(np.sum((rec - sim) ** 2)) / total if total > 0 else math.nan)
        shape.append(float(np.corrcoef(rec, sim)[0, 1] ** 2) if np.std(sim) > 0 and total > 0 else math.nan)
    return r2, shape


def compare(recording: Recording, results: pd.DataFrame) -> dict:
    rec_wave, rec_std, revs = recorded_waveform(recording)
    sim_fine, sim_mean = simulated_waveform(results, recording.rpm)
    shift, sim_wave = align(rec_wave, sim_fine)
    rec_mean = recording.forces.mean(axis=0)
    r2, shape = waveform_scores(rec_wave, sim_wave)
    axes = list(AXES)
    return {
        "recorded_mean_N": dict(zip(axes, rec_mean.tolist())),
        "simulated_mean_N": dict(zip(axes, sim_mean.tolist())),
        "mean_relative_error": dict(zip(axes, ((sim_mean - rec_mean) / np.abs(rec_mean)).tolist())),
        "waveform_r2": dict(zip(axes, r2)),
        "waveform_r2_shape": dict(zip(axes, shape)),
        "phase_shift_deg": shift * 360.0 / FINE,
        "revolutions_averaged": revs,
        "_waves": (rec_wave, rec_std, sim_wave),
    }


def _plot_waveforms(path: Path, title: str, cases: list[tuple[str, Recording, dict]]) -> None:
    fig = Figure(figsize=(12, 2.6 * len(cases) + 0.8), layout="constrained")
    grid = fig.subplots(len(cases), 3, squeeze=False, sharex=True)
    for row, (label, recording, result) in enumerate(cases):
        rec_wave, rec_std, sim_wave = result["_waves"]
        angle = np.arange(len(rec_wave)) * 360.0 / len(rec_wave)
        for k, axis in enumerate(AXES):
            ax = grid[row][k]
            ax.fill_between(angle, rec_wave[:, k] - rec_std[:, k], rec_wave[:, k] + rec_std[:, k], color="tab:gray",
                            alpha=0.25, linewidth=0)
            ax.plot(angle, rec_wave[:, k], color="tab:gray", label="recorded (mean of revolutions, ±1 std)")
            ax.plot(angle, sim_wave[:, k], color="tab:blue", label=f"simulated {INSTANCE}.{AXES[axis]}")
            ax.set_title(f"{label}: {axis}  r2 {result['waveform_r2'][axis]:.2f}, "
                         f"mean err {100 * result['mean_relative_error'][axis]:+.0f} %", fontsize=9)
            ax.grid(True, alpha=0.3)
            if k == 0:
                ax.set_ylabel("force [N]")
            if row == len(cases) - 1:
                ax.set_xlabel("spindle angle [deg]")
    grid[0][0].legend(loc="best", fontsize=7)
    fig.suptitle(title)
    fig.savefig(path, dpi=90)


def _plot_means(path: Path, recordings: list[Recording], sets: dict[str, list[dict]], n_flutes: int,
                labels: dict[str, str] = SET_LABELS) -> None:
    fig = Figure(figsize=(12, 3.6), layout="constrained")
    axes = fig.subplots(1, 3)
    ft = [r.feed / (r.rpm * n_flutes) for r in recordings]
    styles = {"prior": ("tab:orange", "s"), "identified": ("tab:blue", "^"), "finetuned": ("tab:green", "v")}
    for k, axis in enumerate(AXES):
        ax = axes[k]
        ax.plot(ft, [c["recorded_mean_N"][axis] for c in sets["prior"]], "ko-", label="recorded")
        for name, cases in sets.items():
            color, marker = styles[name]
            ax.plot(ft, [c["simulated_mean_N"][axis] for c in cases], marker=marker, color=color, linestyle="--",
                    label=f"simulated, {labels.get(name, name)}")
        ax.set_title(f"mean {axis} (recorded) = simulated {AXES[axis]}")
        ax.set_xlabel("feed per tooth [mm]")
        ax.set_ylabel("force [N]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.savefig(path, dpi=90)


def run_sets(scenario: Scenario, recordings: list[Recording], runs: Path,
             sets: dict[str, Callable[[Recording], dict]]) -> dict[str, list[dict]]:
    """Simulate and compare every recording for each set; a set gives, per recording, the keyword arguments
    of :func:`simulate` (``coefficients``, ``fmu``). Returns the comparisons per set, in recording order."""
    results: dict[str, list[dict]] = {}
    for name, configure in sets.items():
        tag = "" if name == "prior" else f"_{name}"
        results[name] = [compare(r, simulate(scenario, r, runs, tag=tag, **configure(r))) for r in recordings]
    return results


def write_report(folder: Path, doc: dict, recordings: list[Recording], sets: dict[str, list[dict]],
                 n_flutes: int) -> dict:
    """Adds the cases of every set to ``doc``, writes the JSON and the plots (waveforms per set, means)."""
    for i, r in enumerate(recordings):
        case = doc["cases"][i] if i < len(doc["cases"]) else {}
        case.update({"file": r.path.name, "spindle_speed_rpm": r.rpm, "feed_mm_per_min": r.feed,
                     "feed_per_tooth_mm": r.feed / (r.rpm * n_flutes), "axial_depth_mm": r.axial_depth})
        for name in sets:
            case[name] = {k: v for k, v in sets[name][i].items() if not k.startswith("_")}
        if i >= len(doc["cases"]):
            doc["cases"].append(case)
    labels = set_labels(doc["model"])
    for name in sets:
        cases = [(r.label, r, sets[name][i]) for i, r in enumerate(recordings)]
        _plot_waveforms(folder / f"waveforms_{name}.png",
                        f"slot milling ({doc['model']}), per-revolution forces, {labels.get(name, name)}", cases)
    _plot_means(folder / "means.png", recordings, sets, n_flutes, labels)
    (folder / "slot_milling.json").write_text(json.dumps(_finite(doc), indent=2))
    return doc


def finetuned_fmus(scenario: Scenario, recordings: list[Recording], weights_dir: Path, folder: Path) -> dict:
    """Per recording, a copy of the scenario's ForceNet FMU holding the network fine-tuned without that
    recording (``<weights_dir>/finetuned_without_f<feed>.bin``)."""
    from milling_twin.models.force_net import install_weights

    fmus = {}
    for r in recordings:
        weights = weights_dir / f"finetuned_without_f{r.feed:g}.bin"
        if not weights.is_file():
            raise ValueError(f"{weights} is missing: run `milling-twin train forcenet-finetune --out "
                             f"{weights_dir}` first")
        fmus[r.feed] = install_weights(scenario.instance(INSTANCE).path, weights,
                                       folder / "fmus" / f"{weights.stem}_{scenario.instance(INSTANCE).path.name}")
    return fmus


def validate(data: Path, scenario_path: Path, fmu_dir: Path, out: Path, finetuned: Path | None = None) -> dict:
    """Run and compare every recording with each set (CuttingForce: prior and identified coefficients;
    ForceNet: the packed network and, with ``finetuned``, the left-out fine-tuned networks); writes JSON
    and plots into ``out/<scenario file stem>/``, returns the JSON."""
    recordings = read_recordings(data)
    scenario = load_scenario(scenario_path, fmu_dir)
    _check_scenario(scenario)
    n_flutes = _n_flutes(scenario)
    folder = out / Path(scenario_path).stem
    folder.mkdir(parents=True, exist_ok=True)
    runs = folder / "runs"
    force = scenario.instance(INSTANCE)
    doc = {"data": str(data), "source": SOURCE, "scenario": str(scenario_path), "model": force.model_identifier,
           "axes": {f"recorded {a}": f"simulated {INSTANCE}.{s}" for a, s in AXES.items()}, "cases": []}
    if not all(name in force.variables for name in COEFFICIENTS):  # a force model without coefficients
        sets: dict[str, Callable[[Recording], dict]] = {"prior": lambda r: {}}
        if finetuned is not None:
            fmus = finetuned_fmus(scenario, recordings, finetuned, folder)
            sets["finetuned"] = lambda r: {"fmu": fmus[r.feed]}
            doc["finetuned_weights"] = str(finetuned)
        return write_report(folder, doc, recordings, run_sets(scenario, recordings, runs, sets), n_flutes)
    for r in recordings:
        if r.rpm != recordings[0].rpm or r.axial_depth != recordings[0].axial_depth:
            raise ValueError(f"{r.path}: the identification needs one spindle speed and axial depth for all files")
    ft = [r.feed / (r.rpm * n_flutes) / 1000 for r in recordings]  # m per tooth
    means = np.array([r.forces.mean(axis=0) for r in recordings])  # recorded axes
    model_means = {AXES[a]: means[:, k] for k, a in enumerate(AXES)}  # model axes
    identified = identify_slot_coefficients(ft, model_means["Fx"], model_means["Fy"], model_means["Fz"], n_flutes,
                                            recordings[0].axial_depth / 1000)
    prior = {name: force.parameters.get(name, CUTTING_FORCE.variable(name).start) for name in COEFFICIENTS}
    sets = run_sets(scenario, recordings, runs, {"prior": lambda r: {}, "identified": lambda r: {"coefficients": identified}})
    doc["coefficients"] = {"prior": prior, "identified_from_recorded_means": identified,
                           "units": "Ktc, Krc, Kac in N/m2; Kte, Kre, Kae in N/m"}
    for i, r in enumerate(recordings):
        closed = mean_slot_forces(**identified, n_flutes=n_flutes, axial_depth=r.axial_depth / 1000,
                                  feed_per_tooth=ft[i])
        doc["cases"].append({"identified_closed_form_mean_N": {a: closed[AXES[a]] for a in AXES}})
    return write_report(folder, doc, recordings, sets, n_flutes)


def _finite(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def summary(doc: dict) -> str:
    lines = []
    labels = set_labels(doc.get("model", "CuttingForce"))
    for name in [n for n in labels if doc["cases"] and n in doc["cases"][0]]:
        lines.append(f"{doc.get('model', 'CuttingForce')}, {labels[name]}: mean relative error (Fx, Fy, Fz of "
                     "the recording) | waveform r2 | r2 of the shape")
        for case in doc["cases"]:
            c = case[name]
            err = ", ".join(f"{100 * c['mean_relative_error'][a]:+6.1f} %" for a in AXES)
            r2 = ", ".join(f"{c['waveform_r2'][a]:5.2f}" for a in AXES)
            shape = ", ".join(f"{c['waveform_r2_shape'][a]:4.2f}" for a in AXES)
            lines.append(f"  {case['feed_mm_per_min']:6.0f} mm/min ({case['feed_per_tooth_mm']:.3f} mm/tooth): "
                         f"{err} | {r2} | {shape}")
    return "\n".join(lines)


def command(args: argparse.Namespace) -> int:
    """``milling-twin validate slot-milling``."""
    doc = validate(data_dir(args.data), args.scenario, args.fmu_dir, args.out, args.finetuned)
    print(summary(doc))
    folder = args.out / args.scenario.stem
    names = sorted(p.name for p in folder.glob("*.json")) + sorted(p.name for p in folder.glob("*.png"))
    print(f"results: {folder} ({', '.join(names)})")
    return 0

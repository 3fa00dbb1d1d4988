"""Slot-milling forces, leave one feed out: every chip-thickness law with and without the measuring chain.

    .venv/bin/python tests/benchmarks/calibrate_slot_lofo.py [--data DIR] [--fmu-dir build/fmus]
        [--variants linear,exponential,power_edge,linear+chain,exponential+chain,power_edge+chain]
        [--chain-modes 2] [--starts N] [--out runs/benchmarks/calibrate_slot_lofo]

For each variant the spec scenarios/calibration/slot_forces_chain.toml (its scenario has the CuttingForce and a
MeasuringChain instance) is loaded with the force's chip_law and the chain's n_modes overridden (0 modes: the
chain passes the force through, nothing of it is fitted), and
``orchestrator.calibrate.slot_lofo.leave_one_feed_out`` fits on four feeds and predicts the fifth, for all five
feeds of the slot-milling recordings (../shared/data/slot_milling_forces, no licence: never copied into the
repository). Then the fit on all five feeds is timed. Printed per variant: per held-out feed the mean-force
error and waveform r^2 per axis, their means over the folds, the worst fold, the coverage of the intervals
(estimates of one fold inside the 95 % intervals of another) and the fit times. First, what the recordings allow
(``slot_lofo.recorded_bound``: the held-out feed predicted from the others' waveforms by a polynomial in the feed at
every angle, no model; milliseconds). The JSON is written after every variant (a killed run keeps the finished
ones).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from milling_twin import datasets
from milling_twin.models.cutting_force import CHIP_LAWS
from milling_twin.orchestrator.calibrate.scenario_fit import with_overrides
from milling_twin.orchestrator.calibrate.slot_forces import fit_slot, load_slot_data
from milling_twin.orchestrator.calibrate.slot_lofo import coverage, leave_one_feed_out, recorded_bound, summary
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec, load_spec
from milling_twin.orchestrator.scenario import Scenario, load_scenario
from milling_twin.orchestrator.validation import slot_milling as sm

REPO = Path(__file__).resolve().parents[2]
SPEC = REPO / "scenarios" / "calibration" / "slot_forces_chain.toml"
VARIANTS = ("linear", "exponential", "power_edge", "linear+chain", "exponential+chain", "power_edge+chain")


def slot_arguments(parser: argparse.ArgumentParser, out: str) -> None:
    """The options the slot-forces benchmarks share (this one and calibrate_slot_speed.py)."""
    parser.add_argument("--data", type=Path, default=None)
    parser.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get("MILLING_TWIN_FMU_DIR",
                                                                            REPO / "build" / "fmus")))
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "benchmarks" / out)


def variant_scenario(spec: CalibrationSpec, variant: str, chain_modes: int, fmu_dir: Path) -> Scenario:
    """The spec's scenario with the variant's chip-thickness law and a chain of ``chain_modes`` modes ("law+chain")
    or none ("law")."""
    law, _, chain = variant.partition("+")
    return with_overrides(load_scenario(spec.scenario, fmu_dir),
                          {"force.chip_law": CHIP_LAWS[law], "chain.n_modes": chain_modes if chain else 0})


def run_variant(variant: str, chain_modes: int, starts: int | None, fmu_dir: Path, folder: Path) -> dict:
    law, _, chain = variant.partition("+")
    spec = load_spec(SPEC)
    if starts is not None:
        spec = replace(spec, solver=replace(spec.solver, starts=starts))
    scenario = variant_scenario(spec, variant, chain_modes, fmu_dir)
    n_flutes = sm._n_flutes(scenario)
    print(f"\n### {variant}\n", flush=True)
    folds = leave_one_feed_out(spec, scenario, folder, n_flutes, progress=lambda s: print("  " + s, flush=True))
    feeds = tuple(f.held_feed for f in folds)
    t0 = time.perf_counter()
    every = load_slot_data(folder, feeds, "feeds", spec, spec.slot_forces.revolutions, n_flutes)
    final = fit_slot(replace(spec, slot_forces=replace(spec.slot_forces, learning_feeds=feeds)), scenario, every,
                     n_flutes)
    all_feeds_time = time.perf_counter() - t0
    params = final.model_parameters
    return {"variant": variant, "law": law, "chain_modes": chain_modes if chain else 0,
            "folds": [{"held_feed": f.held_feed, "mean_error": f.mean_error.tolist(), "r2": f.r2.tolist(),
                       "fit_time_s": f.fit_time,
                       "estimates": {n: [e * d[1], c[0] * d[1], c[1] * d[1], d[0], ident]
                                     for n, e, c, d, ident in zip(f.names, f.estimates, f.ci, f.display,
                                                                  f.identified)}} for f in folds],
            "summary": summary(folds), "coverage": coverage(folds), "all_feeds_fit_s": all_feeds_time,
            "all_feeds_timings": final.timings,
            "all_feeds_estimates": {q.name: [q.display(s.estimate), q.display(s.ci_low), q.display(s.ci_high),
                                             q.display_unit, list(s.flags)]
                                    for q, s in zip(params, final.waveform.statistics.parameters)}}


def bound_rows(folder: Path, fmu_dir: Path) -> list[dict]:
    """The interpolants of ``recorded_bound`` as result rows (no fit, no estimates)."""
    spec = load_spec(SPEC)
    scenario = load_scenario(spec.scenario, fmu_dir)
    rows = []
    for degree, folds in recorded_bound(spec, folder, sm._n_flutes(scenario)).items():
        rows.append({"variant": f"recorded, degree {degree} in the feed", "folds": [
            {"held_feed": f.held_feed, "mean_error": f.mean_error.tolist(), "r2": f.r2.tolist(), "fit_time_s": 0.0}
            for f in folds], "summary": summary(folds), "coverage": {}, "all_feeds_fit_s": 0.0,
            "all_feeds_estimates": {}})
    return rows


def print_variant(v: dict) -> None:
    print(f"\n| held-out feed ({v['variant']}) | mean-force error Fx / Fy / Fz | waveform r2 Fx / Fy / Fz | fit |")
    print("|---|---:|---:|---:|")
    for f in v["folds"]:
        print(f"| {f['held_feed']:g} mm/min | " + " / ".join(f"{100 * e:+.1f} %" for e in f["mean_error"]) + " | "
              + " / ".join(f"{r:.3f}" for r in f["r2"]) + f" | {f['fit_time_s']:.0f} s |")
    s = v["summary"]
    print("| mean | " + " / ".join(f"{100 * e:.1f} %" for e in s["mean_abs_error"]) + " | "
          + " / ".join(f"{r:.3f}" for r in s["mean_r2"]) + " | |")
    print(f"worst fold {s['worst_fold_feed']:g} mm/min: {100 * s['worst_fold_error']:.1f} % (mean over axes), "
          f"worst axis {100 * s['worst_axis_error']:.1f} %"
          + (f"; fit on all five feeds {v['all_feeds_fit_s']:.1f} s" if v["all_feeds_estimates"] else ""))
    if not v["all_feeds_estimates"]:  # an interpolant of the recordings: nothing fitted
        return
    print("coverage: " + ", ".join(f"{k} {100 * c:.0f} %" for k, c in v["coverage"].items()))
    print("all five feeds: " + ", ".join(f"{k} {e[0]:.4g} [{e[1]:.4g}, {e[2]:.4g}] {e[3]}"
                                         + (f" ({'; '.join(e[4])})" if e[4] else "")
                                         for k, e in v["all_feeds_estimates"].items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    slot_arguments(parser, "calibrate_slot_lofo")
    parser.add_argument("--chain-modes", type=int, default=2)
    parser.add_argument("--starts", type=int, default=None, help="starts of each fit (default: the spec's)")
    args = parser.parse_args()
    folder = datasets.data_dir(args.data)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "calibrate_slot_lofo.json"
    results = bound_rows(folder, args.fmu_dir)
    for v in results:
        print_variant(v)
    for variant in args.variants.split(","):
        results.append(run_variant(variant, args.chain_modes, args.starts, args.fmu_dir, folder))
        print_variant(results[-1])
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(results, indent=2, default=float))
        os.replace(tmp, path)
    print("\n| variant | mean error Fx / Fy / Fz | mean r2 Fx / Fy / Fz | worst fold | all-feeds fit |")
    print("|---|---:|---:|---:|---:|")
    for v in results:
        s = v["summary"]
        print(f"| {v['variant']} | " + " / ".join(f"{100 * e:.1f} %" for e in s["mean_abs_error"]) + " | "
              + " / ".join(f"{r:.3f}" for r in s["mean_r2"])
              + f" | {100 * s['worst_fold_error']:.1f} % ({s['worst_fold_feed']:g}) | {v['all_feeds_fit_s']:.0f} s |")
    fitted = [f["fit_time_s"] for v in results if v["all_feeds_estimates"] for f in v["folds"]]
    print(f"written: {path}" + (f"; mean fold fit {np.mean(fitted):.1f} s" if fitted else ""))


if __name__ == "__main__":
    main()

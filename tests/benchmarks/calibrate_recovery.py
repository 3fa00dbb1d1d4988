"""Calibration benchmark: synthetic recovery (data made by the FMUs with known parameters plus noise)
and the speed of the power-model fit on a real UMich run.

    .venv/bin/python tests/benchmarks/calibrate_recovery.py [--repeats 50] [--fmu-dir build/fmus]
        [--out runs/benchmarks/calibrate_recovery]

Cases (each: one FMU run with the true values; the true outputs at the recorded times plus Gaussian noise,
one seed per repeat, replace the recorded channel; the spec's fit on the learning window):

* ``power (synthetic inputs)``: SpindlePower + MrrEstimator on generated speed and feed steps
  (orchestrator.calibrate.synthetic.write_power_case), truth P_standby 350 W, P_idle 120 W, c1 0.8 W.s/rad,
  c2 1500 W, c3 0.85; noise 5 W.
* ``power (UMich run 01 inputs)``: scenarios/calibration/umich_power.toml (the demo's spec) with truth
  P_standby 30 W, P_idle 120 W, c1 0.15 W.s/rad, c2 800 W, c3 0.8 on the recorded speed and feeds; noise 5 W.
* ``modal (impulse)``: scenarios/calibration/modal_impulse.toml (ToolVibration, multiple shooting), truth
  850 Hz, 2 %, 1.0e6 N/m; noise 1 % of the peak acceleration.

Reported per parameter: the noise-free relative error, the share of repeats whose 95 % interval holds the
truth (coverage), how often the statistics called it identifiable, the median relative error; and the fit
time per repeat. Then the wall time of the fit stage of ``calibrate scenarios/calibration/umich_power.toml``
on the real recording (best of 3).
"""
from __future__ import annotations

import sys
import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.calibrate import calibrate, load_spec
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the generated cases (tests/cases)

from cases.calibration_recovery import RecoveryStudy
from cases.calibration_synthetic import IMPULSE_NOISE, IMPULSE_TRUTH, POWER_TRUTH, write_power_case

REPO = Path(__file__).resolve().parents[2]
UMICH_TRUTH = {"power.P_standby": 30.0, "power.P_idle": 120.0, "power.c1": 0.15, "power.c2": 800.0, "power.c3": 0.8}


def study_case(name: str, study: RecoveryStudy, sigma: list[float], repeats: int) -> dict:
    names = [q.name for q in study.prepared.parameters]
    free = study.run([0.0] * len(sigma), None)
    runs = study.repeats(sigma, range(repeats), progress=True)
    covered = np.array([r.covered for r in runs])
    identifiable = np.array([r.identifiable for r in runs])
    errors = np.array([r.relative_error for r in runs])
    rows = []
    for j, n in enumerate(names):
        rows.append({"parameter": n, "truth": float(study.truth[j]), "noise_free_relative_error": float(free.relative_error[j]),
                     "coverage": float(covered[:, j].mean()), "identifiable": float(identifiable[:, j].mean()),
                     "median_relative_error": float(np.median(errors[:, j]))})
    ident_all = identifiable.all(axis=0)
    return {"case": name, "repeats": repeats, "sigma": sigma, "parameters": rows,
            "fit_time_median_s": float(np.median([r.wall_time for r in runs])),
            "converged": int(sum(r.converged for r in runs)),
            "coverage_of_identifiable_min": float(covered[:, ident_all].mean(axis=0).min()) if ident_all.any() else None}


def print_case(case: dict) -> None:
    print(f"\n### {case['case']} ({case['repeats']} repeats, noise {case['sigma']}, fit {case['fit_time_median_s']:.3f} s "
          f"median, {case['converged']} converged)\n")
    print("| parameter | truth | noise-free rel. error | coverage of 95 % CI | identifiable | median rel. error |")
    print("|---|---:|---:|---:|---:|---:|")
    for r in case["parameters"]:
        print(f"| {r['parameter']} | {r['truth']:.6g} | {r['noise_free_relative_error']:.2e} | {100 * r['coverage']:.0f} % "
              f"| {100 * r['identifiable']:.0f} % | {r['median_relative_error']:.2e} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=50)
    parser.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get("MILLING_TWIN_FMU_DIR", REPO / "build" / "fmus")))
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "benchmarks" / "calibrate_recovery")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    cases = []
    with tempfile.TemporaryDirectory() as tmp:
        spec = load_spec(write_power_case(Path(tmp) / "power_case"))
        cases.append(study_case("power (synthetic inputs)", RecoveryStudy(spec, args.fmu_dir, Path(tmp) / "a", POWER_TRUTH),
                                [5.0], args.repeats))
        spec = load_spec(REPO / "scenarios" / "calibration" / "umich_power.toml")
        cases.append(study_case("power (UMich run 01 inputs)", RecoveryStudy(spec, args.fmu_dir, Path(tmp) / "b", UMICH_TRUTH),
                                [5.0], args.repeats))
        spec = load_spec(REPO / "scenarios" / "calibration" / "modal_impulse.toml")
        modal = RecoveryStudy(spec, args.fmu_dir, Path(tmp) / "c", IMPULSE_TRUTH)
        cases.append(study_case("modal (impulse, multiple shooting)", modal,
                                [IMPULSE_NOISE * float(np.max(np.abs(modal.clean)))], args.repeats))
        times = []
        for _ in range(3):
            result = calibrate(REPO / "scenarios" / "calibration" / "umich_power.toml", args.fmu_dir, Path(tmp) / "umich",
                               progress=False)
            times.append((result.fit.solve_time, result.timings["fit (build, starts, statistics)"]))
    for case in cases:
        print_case(case)
    best = min(times)
    print(f"\nUMich run 01 power fit (4 starts, 701 learning samples): solver {best[0]:.3f} s, fit stage with "
          f"building and statistics {best[1]:.3f} s (best of 3)")
    doc = {"cases": cases, "umich_power_fit_s": {"solver": best[0], "stage": best[1]}}
    (args.out / "calibrate_recovery.json").write_text(json.dumps(doc, indent=2))
    print(f"written: {args.out / 'calibrate_recovery.json'}")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"benchmark wall time {time.perf_counter() - t0:.0f} s")

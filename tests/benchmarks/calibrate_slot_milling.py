"""Slot-milling forces benchmark: fit the cutting coefficients on three of the five measured feeds, predict
the other two through the FMUs.

    .venv/bin/python tests/benchmarks/calibrate_slot_milling.py [--data DIR] [--fmu-dir build/fmus]
        [--out runs/benchmarks/calibrate_slot_milling]

Runs ``calibrate scenarios/calibration/slot_forces.toml`` (learning 300, 900, 1500 mm/min; held out 600,
1200: interpolation) and the same spec with learning 300, 600, 900 and held out 1200, 1500 (extrapolation
to higher feeds). The recordings (../shared/data/slot_milling_forces, no licence: never copied into the
repository) are found as orchestrator.validation.slot_milling finds them. Printed: the coefficients of the
linear regression of per-revolution means and of the waveform fit with their 95 % intervals, the
mean-force relative error and waveform r^2 per held-out feed and axis (prior, regression and waveform-fit
coefficients, all through the FMUs), and the wall time of each fit.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.calibrate import calibrate
from milling_twin.orchestrator.calibrate.slot_forces import RECORDED_AXES

REPO = Path(__file__).resolve().parents[2]
SPEC = REPO / "scenarios" / "calibration" / "slot_forces.toml"


def run_split(spec: Path, fmu_dir: Path, out: Path, data: Path | None) -> dict:
    t0 = time.perf_counter()
    result = calibrate(spec, fmu_dir, out, data=data, progress=False)
    wall = time.perf_counter() - t0
    regression = result.extra["regression"]
    coefficients = []
    for q, rs, ws in zip(regression.parameters, regression.statistics.parameters, result.fit.statistics.parameters):
        coefficients.append({"name": q.name, "unit": q.display_unit, "regression": q.display(rs.estimate),
                             "regression_ci": [q.display(rs.ci_low), q.display(rs.ci_high)],
                             "waveform": q.display(ws.estimate), "waveform_ci": [q.display(ws.ci_low), q.display(ws.ci_high)]})
    extra = [{"name": q.name, "unit": q.display_unit, "estimate": q.display(st.estimate),
              "ci": [q.display(st.ci_low), q.display(st.ci_high)], "flags": list(st.flags)}
             for q, st in zip(result.fit.parameters, result.fit.statistics.parameters) if q.name not in
             {c["name"] for c in coefficients}]
    held = []
    for name, cases in result.extra["cases"].items():
        for dataset, recording, c in cases:
            if dataset == "validation":
                held.append({"coefficients": name, "feed": recording.feed,
                             "mean_relative_error": [c["mean_relative_error"][a] for a in RECORDED_AXES],
                             "waveform_r2": [c["waveform_r2"][a] for a in RECORDED_AXES]})
    return {"learning": list(result.spec.slot_forces.learning_feeds),
            "validation": list(result.spec.slot_forces.validation_feeds),
            "coefficients": coefficients, "other": extra, "held_out": held,
            "fit_times_s": {k: v for k, v in result.timings.items() if k.startswith("fit")},
            "starts": [(o.status, o.objective) for o in result.fit.starts], "wall_time_s": wall,
            "report": str(result.report_html)}


def print_split(split: dict) -> None:
    print(f"\n### learning {split['learning']} mm/min, held out {split['validation']} mm/min\n")
    print("| coefficient | unit | regression (95 % CI) | waveform fit (95 % CI) |")
    print("|---|---|---:|---:|")
    for c in split["coefficients"]:
        print(f"| {c['name']} | {c['unit']} | {c['regression']:.4g} [{c['regression_ci'][0]:.4g}, {c['regression_ci'][1]:.4g}] "
              f"| {c['waveform']:.4g} [{c['waveform_ci'][0]:.4g}, {c['waveform_ci'][1]:.4g}] |")
    for c in split["other"]:
        print(f"| {c['name']} | {c['unit']} | | {c['estimate']:.4g} [{c['ci'][0]:.4g}, {c['ci'][1]:.4g}] |")
    print("\n| held-out feed | coefficients | mean-force error Fx / Fy / Fz | waveform r2 Fx / Fy / Fz |")
    print("|---|---|---:|---:|")
    for h in split["held_out"]:
        print(f"| {h['feed']:g} mm/min | {h['coefficients']} | "
              + " / ".join(f"{100 * e:+.1f} %" for e in h["mean_relative_error"]) + " | "
              + " / ".join(f"{r:.2f}" for r in h["waveform_r2"]) + " |")
    for name in ("prior", "regression", "calibrated"):
        rows = [h for h in split["held_out"] if h["coefficients"] == name]
        err = np.mean([np.abs(h["mean_relative_error"]) for h in rows])
        r2 = np.mean([h["waveform_r2"] for h in rows])
        print(f"held out, {name}: mean |mean-force error| {100 * err:.2f} %, mean waveform r2 {r2:.3f}")
    print("fit times: " + ", ".join(f"{k} {v:.2f} s" for k, v in split["fit_times_s"].items())
          + f"; whole calibration {split['wall_time_s']:.1f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None)
    parser.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get("MILLING_TWIN_FMU_DIR", REPO / "build" / "fmus")))
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "benchmarks" / "calibrate_slot_milling")
    args = parser.parse_args()
    splits = [run_split(SPEC, args.fmu_dir, args.out, args.data)]
    with tempfile.TemporaryDirectory() as tmp:
        text = SPEC.read_text().replace('scenario = "../slot_milling.toml"',
                                        f'scenario = "{REPO / "scenarios" / "slot_milling.toml"}"')
        text = text.replace("learning_feeds = [300, 900, 1500]", "learning_feeds = [300, 600, 900]")
        text = text.replace("validation_feeds = [600, 1200]", "validation_feeds = [1200, 1500]")
        text = text.replace('name = "slot_forces"', 'name = "slot_forces_extrapolation"')
        variant = Path(tmp) / "slot_forces_extrapolation.toml"
        variant.write_text(text)
        splits.append(run_split(variant, args.fmu_dir, args.out, args.data))
    for split in splits:
        print_split(split)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "calibrate_slot_milling.json").write_text(json.dumps(splits, indent=2, default=float))
    print(f"written: {args.out / 'calibrate_slot_milling.json'}")


if __name__ == "__main__":
    main()

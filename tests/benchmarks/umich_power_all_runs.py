"""Spindle power on every UMich run: recording checks, calibration on all runs, leave-one-run-out.

    .venv/bin/python tests/benchmarks/umich_power_all_runs.py [--data DIR] [--fmu-dir build/fmus]
        [--out runs/benchmarks/umich_power_all_runs]

Runs ``calibrate scenarios/calibration/umich_power_runs.toml`` on the twelve runs of ../shared/data/umich_cnc
(``--data``: elsewhere), and, as the baseline, the same spec on run 01 alone, whose set is then applied to every
run through the FMUs (``milling-twin run scenarios/umich_power.toml --recording ... --parameter-set ...``:
what a set calibrated on one recording predicts elsewhere). Printed per run: rows, consistent segments,
impossible transitions found, pairs used, RMS recorded power, and the RMS error (% of RMS recorded) with the
priors, with the run-01 set, with the set fitted without the run (leave-one-run-out) and with all runs; then
the mean leave-one-run-out error, the runs predicted better than by the priors, and per parameter the joint
estimate, the runs' random-effects mean and spread, and how many pairs of runs that identify it have
overlapping 95 % intervals (block bootstrap), also with the spread between runs. JSON with every figure in --out.
"""
from __future__ import annotations

import argparse
import json
import re
import logging
import time
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.calibrate import calibrate
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.report import write_report
from milling_twin.orchestrator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
SPEC = REPO / "scenarios" / "calibration" / "umich_power_runs.toml"
SCENARIO = REPO / "scenarios" / "umich_power.toml"


def single_run_spec(out: Path) -> Path:
    """The spec on run 01 alone, written into ``out`` (its paths made absolute)."""
    text = SPEC.read_text()
    text = text.replace('scenario = "../umich_power.toml"', f'scenario = "{SCENARIO}"')
    text = text.replace('folder = "../../../shared/data/umich_cnc"',
                        f'folder = "{(SPEC.parent / "../../../shared/data/umich_cnc").resolve()}"')
    text = re.sub(r'^files = .*$', 'files = ["experiment_01.csv"]', text, count=1, flags=re.M)
    text = text.replace('name = "umich_power_runs"', 'name = "umich_power_run01"')
    text = text.replace("cross_validation = true", "cross_validation = false")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "umich_power_run01.toml"
    path.write_text(text)
    return path


def applied(set_path: Path, recording: Path, fmu_dir: Path, out: Path) -> float:
    """RMS error of P_total over the run's consistent samples with ``set_path`` applied, through the FMUs."""
    scenario = load_scenario(SCENARIO, fmu_dir, parameter_sets=[set_path], recording=recording)
    result = run(scenario, out / recording.stem, progress=False)
    return write_report(scenario, result.run_dir).comparisons[0].rms_error


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="the UMich runs (default: the spec's folder)")
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus")
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "benchmarks" / "umich_power_all_runs")
    args = parser.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the FMUs' warnings (once per run) are in the reports
    t0 = time.perf_counter()
    result = calibrate(SPEC, args.fmu_dir, args.out, data=args.data, progress=False)
    wall_all = time.perf_counter() - t0
    t0 = time.perf_counter()
    first = calibrate(single_run_spec(args.out), args.fmu_dir, args.out, data=args.data, progress=False)
    wall_first = time.perf_counter() - t0
    folder = args.data or result.spec.runs.folder
    runs_table = {row[0]: row for row in next(t for t in result.tables if t.title.startswith("Runs:")).rows}
    rows = []
    for cv in result.extra["cross_validation"]:
        name = cv["run"]
        rec = cv["rms_recorded"]
        run01 = applied(first.parameter_set, folder / f"{name}.csv", args.fmu_dir, args.out / "run01_set")
        check = runs_table[name][5]
        rows.append({"run": name, "rows": int(runs_table[name][1]), "segments": int(runs_table[name][3]),
                     "problems": int(check.split("; ")[1].split()[0]) if "; " in check else 0,
                     "pairs": cv["pairs"], "rms_recorded_W": rec,
                     "priors_pct": 100 * cv["priors"] / rec, "run01_set_pct": 100 * run01 / rec,
                     "without_it_pct": 100 * cv["without_it"] / rec, "with_it_pct": 100 * cv["with_it"] / rec})
    header = ("run", "rows", "segments", "impossible", "pairs", "RMS rec [W]", "priors %", "run-01 set %",
              "without it %", "all runs %")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for r in rows:
        print(f"| {r['run']} | {r['rows']} | {r['segments']} | {r['problems']} | {r['pairs']} | "
              f"{r['rms_recorded_W']:.1f} | {r['priors_pct']:.1f} | {r['run01_set_pct']:.1f} | "
              f"{r['without_it_pct']:.1f} | {r['with_it_pct']:.1f} |")
    mean_loro = float(np.mean([r["without_it_pct"] for r in rows]))
    better = sum(r["without_it_pct"] < r["priors_pct"] for r in rows)
    print(f"\nleave-one-run-out: mean {mean_loro:.2f} % of RMS recorded; better than the priors on {better} of "
          f"{len(rows)} runs")
    table = next(t for t in result.tables if t.title.startswith("Estimates"))
    estimates = [{"parameter": r[0], "unit": r[1], "all_runs": r[2], "between_runs": r[3], "overlap": r[4],
                  "overlap_with_spread": r[5]} for r in table.rows]
    for e in estimates:
        print(f"{e['parameter']} [{e['unit']}]: all runs {e['all_runs']}; between runs {e['between_runs']}; "
              f"overlapping intervals {e['overlap']}, with the spread between runs {e['overlap_with_spread']}")
    print(f"wall time: all runs {wall_all:.1f} s (12 simulations, 25 fits), run 01 alone {wall_first:.1f} s")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "umich_power_all_runs.json").write_text(json.dumps(
        {"runs": rows, "mean_leave_one_run_out_pct": mean_loro, "better_than_priors": better,
         "estimates": estimates, "wall_time_s": {"all_runs": wall_all, "run01": wall_first},
         "report": str(result.report_html)}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

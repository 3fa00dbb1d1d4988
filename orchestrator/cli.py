"""Command line: ``python -m milling_twin.orchestrator run SCENARIO [--fmu-dir DIR] [--out DIR] [--no-progress] [--path P]``
and ``python -m milling_twin.orchestrator calibrate SPEC ...`` (:mod:`milling_twin.orchestrator.calibrate.cli`).

Exit codes: 0 completed, 1 simulation failed, 2 invalid scenario or recorded data,
130 interrupted (Ctrl-C).
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from milling_twin.orchestrator.calibrate import cli as calibrate_cli
from milling_twin.orchestrator.fastpath import FastPathUnavailable
from milling_twin.orchestrator.master import RunResult, SimulationError, run
from milling_twin.orchestrator.recorded import RecordedDataError
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario
from milling_twin.models.units import UnitError, conversion_factor

if TYPE_CHECKING:  # the report (pandas, matplotlib) is imported only for scenarios with comparisons
    from milling_twin.orchestrator.report import Report

FMU_DIR_ENV = "MILLING_TWIN_FMU_DIR"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m milling_twin.orchestrator",
                                     description="Co-simulate the milling digital twin's FMUs.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="run a scenario file",
                       description="Run a scenario: co-simulate, write results and the comparison report.")
    p.add_argument("scenario", type=Path, help="scenario TOML file")
    p.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get(FMU_DIR_ENV, "build/fmus")),
                   help=f"folder of the built FMUs (default: ${FMU_DIR_ENV} or build/fmus)")
    p.add_argument("--out", type=Path, default=Path("runs"),
                   help="results go to OUT/<scenario name>/ (default: runs)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--path", choices=("auto", "fast", "python"), default="auto",
                   help="stepping loop: fast (compiled), python (reference), or auto (fast when its "
                        "library is found and the scenario is supported; default)")
    calibrate_cli.add_parser(sub)
    return parser


def _summary(result: RunResult, report: Report | None) -> str:
    lines = [f"{result.status}: {result.steps} steps to t = {result.end_time:g} s "
             f"({result.fmu_steps} FMU steps) in {result.wall_time:.3g} s, "
             f"{result.steps_per_second:,.0f} steps/s; {result.rows} rows; "
             + ("fast path" if result.stepping == "fast" else f"python path ({result.stepping_reason})")]
    for c in report.comparisons if report else ():
        s = 1.0 if c.unit == c.display_unit else conversion_factor(c.unit, c.display_unit)
        rel = f"{100 * c.relative_rms:.1f} % of RMS recorded" if c.relative_rms is not None else "n/a"
        lines.append(f"{c.simulated} vs {c.recorded} ({c.n_samples} samples): RMS error "
                     f"{c.rms_error * s:.4g} {c.display_unit} ({rel}), mean |error| "
                     f"{c.mean_abs_error * s:.4g}, max |error| {c.max_error * s:.4g}, "
                     f"mean recorded {c.mean_recorded * s:.4g} {c.display_unit}")
        lines.append(f"plot: {result.run_dir / c.plot}")
    lines.append(f"results: {result.run_dir} (orchestrator.results.load_results)")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.command == "calibrate":
        return calibrate_cli.main(args)
    try:
        scenario = load_scenario(args.scenario, args.fmu_dir)
    except (ScenarioError, RecordedDataError, UnitError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        result = run(scenario, args.out, progress=not args.no_progress, stepping=args.path)
    except FastPathUnavailable as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except SimulationError as exc:
        print(f"error: {exc}; results so far in {args.out / scenario.name}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"interrupted; results so far in {args.out / scenario.name}", file=sys.stderr)
        return 130
    except OSError as exc:  # the results folder cannot be created or written (a file in the way, no space, ...)
        print(f"error: cannot write the results to {args.out / scenario.name}: {exc}", file=sys.stderr)
        return 1
    report = None
    if scenario.compare and result.rows:
        from milling_twin.orchestrator.report import write_report

        report = write_report(scenario, result.run_dir)
    print(_summary(result, report))
    return 130 if result.status == "interrupted" else 0

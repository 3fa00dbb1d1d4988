"""Handlers of ``milling-twin run`` and ``milling-twin calibrate``: the API call, then a summary to read.

What they raise is turned into the exit code and message by :data:`milling_twin.cli.EXIT_CODES`.
"""
from __future__ import annotations

import argparse
import logging
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from milling_twin import api
from milling_twin.cli import overrides_of
from milling_twin.models.units import conversion_factor
from milling_twin.orchestrator.master import SimulationError

if TYPE_CHECKING:
    from milling_twin.orchestrator.scenario import Scenario

_fmi_log = logging.getLogger("milling_twin.fmi")


def run_summary(results: api.Results) -> str:
    """What a run did and, per comparison, how far the simulation is from the recording (display units)."""
    result, report = results.run, results.report
    lines = [f"{result.status}: {result.steps} steps to t = {result.end_time:g} s "
             f"({result.fmu_steps} FMU steps) in {result.wall_time:.3g} s, "
             f"{result.steps_per_second:,.0f} steps/s; {result.rows} rows; "
             + ("fast path" if result.stepping == "fast" else f"python path ({result.stepping_reason})")]
    intervals = result.fine_intervals + result.coarse_intervals  # [stepping]: the variable step's intervals
    if intervals:
        lines.append(f"variable step: {result.fine_intervals} of {intervals} coarse intervals fine "
                     f"({100 * result.fine_intervals / intervals:.1f} %)")
    if results.scenario.on_change:  # [[on_change]]: the parameter changes made at events
        lines.append(f"on_change: {len(result.events)} events fired ({len(results.scenario.on_change)} entries)")
    check = results.scenario.recorded.check if results.scenario.recorded is not None else None
    if check is not None:
        lines.extend(f"recording check: {line}" for line in check.summary()[:2])
    for c in report.comparisons if report else ():
        s = 1.0 if c.unit == c.display_unit else conversion_factor(c.unit, c.display_unit)
        rel = f"{100 * c.relative_rms:.1f} % of RMS recorded" if c.relative_rms is not None else "n/a"
        lines.append(f"{c.simulated} vs {c.recorded} ({c.n_samples} samples): RMS error "
                     f"{c.rms_error * s:.4g} {c.display_unit} ({rel}), mean |error| "
                     f"{c.mean_abs_error * s:.4g}, max |error| {c.max_error * s:.4g}, "
                     f"mean recorded {c.mean_recorded * s:.4g} {c.display_unit}")
        lines.append(f"plot: {result.run_dir / c.plot}")
    process = results.process_report
    if process is not None:  # a whole-part scenario: the headline of its process report
        zmap = (f" (stock - final Z-map {process.removed_volume_zmap * 1e6:.6g} cm3)"
                if process.removed_volume_zmap is not None else "")
        lines.append(f"part: machining {process.machining_time:.2f} s, in material {process.cutting_time:.2f} s; "
                     f"max force {process.max_force:.4g} N, torque {process.max_torque:.4g} N.m, power "
                     f"{process.max_power / 1e3:.4g} kW, deflection {process.max_deflection * 1e6:.4g} um; removed "
                     f"{process.removed_volume * 1e6:.6g} cm3{zmap}; {process.blocks} blocks, "
                     f"{process.chatter_blocks} in chatter")
        lines.extend(f"part warning: {w}" for w in process.warnings)
        lines.append(f"process report: {process.html}" + (f", surface: {process.stl}" if process.stl else ""))
    lines.append(f"results: {result.run_dir} (milling_twin.load_results)")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.scenario.suffix.lower() == ".ssp":  # an SSP archive: run the scenario its SSD describes (docs/ssp.md)
        from milling_twin.orchestrator.ssp.importer import load_scenario, opened

        with opened(args.scenario) as scenario_file:
            return _run(args, scenario_file, load_scenario)
    return _run(args, args.scenario, api.load_scenario)


def _run(args: argparse.Namespace, scenario_file: Path, load: Callable[..., Scenario]) -> int:
    scenario = load(scenario_file, args.fmu_dir, parameter_sets=args.parameter_set,
                                 overrides=overrides_of(args), recording=args.recording)
    run_dir = args.out / scenario.name
    logger = None
    if args.fmi_logging:  # shown whatever --log-level says: the records propagate to main()'s handler
        _fmi_log.setLevel(logging.DEBUG)
        logger = _fmi_log.info
    try:
        results = api.simulate(scenario, out=args.out, stepping=args.path, progress=not args.no_progress,
                               fmi_call_logger=logger, if_busy=getattr(args, "if_busy", "refuse"))
    except (KeyboardInterrupt, SimulationError) as exc:
        exc.add_note(f"results so far in {run_dir}")
        raise
    except OSError as exc:  # the results folder cannot be created or written (a file in the way, no space, ...)
        raise OSError(f"cannot write the results to {run_dir}: {exc}") from exc
    print(run_summary(results))
    return 130 if results.status == "interrupted" else 0


def calibrate(args: argparse.Namespace) -> int:
    from milling_twin.orchestrator.calibrate.report import summary_lines

    result = api.calibrate(args.spec, fmu_dir=args.fmu_dir, out=args.out, data=args.data,
                           overrides=overrides_of(args), write_set=args.write_set, progress=not args.no_progress,
                           workers=args.workers, scheduler=args.scheduler)
    print("stages: " + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in result.timings.items()))
    print("\n".join(summary_lines(result)))
    print(f"parameter set: {result.parameter_set}")
    if args.write_set:
        print(f"published: {Path(args.write_set)}")
    print(f"report: {result.report_html} (and {result.report_md.name})")
    return 0

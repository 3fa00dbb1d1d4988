"""Command line: ``python -m milling_twin.orchestrator.align temporal|spatial ...`` (``--help`` on each).

temporal: align a recording (CSV, through orchestrator.recorded) with a simulated run (a run
folder of ``python -m milling_twin.orchestrator run`` or a CSV), write the time map as CSV (recorded_time,
simulated_time, confidence), optionally a figure. Positions are converted to SI on loading.

spatial: wall-thickness compensation from probe and design CSV files (columns x, y, z
[, thickness]; one length unit for all inputs); prints the work-offset shift, F and the G-code.

Exit status: 0 done; 1 bad input or alignment impossible (message on stderr); 2 bad command
line; 3 spatial registration rejected (F > k; the G-code is not printed).
"""
from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.multiscale import MultiscaleOptions
from milling_twin.orchestrator.align.spatial import (compensate_wall, load_cloud_csv, load_probe_csv,
                                        work_offset_gcode)
from milling_twin.orchestrator.align.temporal import METHODS, align
from milling_twin.orchestrator.align.trajectory import Trajectory
from milling_twin.orchestrator.recorded import ChannelSpec, RecordedDataError, load_recorded
from milling_twin.orchestrator.results import load_results


def _columns(text: str) -> list[str]:
    cols = [c.strip() for c in text.split(",") if c.strip()]
    if len(cols) != 3:
        raise argparse.ArgumentTypeError(f"give three comma-separated columns (x,y,z), got {text!r}")
    return cols


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m milling_twin.orchestrator.align", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    t = sub.add_parser("temporal", help="map recorded samples to simulated time")
    t.add_argument("--recorded", required=True, type=Path, help="recording (CSV)")
    t.add_argument("--columns", required=True, type=_columns,
                   help="recorded x,y,z position columns")
    t.add_argument("--unit", default="mm", help="unit of the recorded positions (default mm)")
    g = t.add_mutually_exclusive_group(required=True)
    g.add_argument("--sample-period", type=float, help="recorded rows are this many s apart")
    g.add_argument("--time-column", help="recorded time column")
    t.add_argument("--time-unit", default="s")
    s = t.add_mutually_exclusive_group(required=True)
    s.add_argument("--results", type=Path, help="run folder of the simulation")
    s.add_argument("--simulated", type=Path, help="simulated positions (CSV, column 'time')")
    t.add_argument("--sim-columns", required=True, type=_columns,
                   help="simulated x,y,z columns (results: instance.variable)")
    t.add_argument("--sim-unit", default="m", help="unit of --simulated columns (default m)")
    t.add_argument("--output-delay", type=float, default=0.0,
                   help="s to shift results back (see orchestrator.align.trajectory)")
    t.add_argument("--method", choices=sorted(METHODS), default="multiscale")
    t.add_argument("--out", type=Path, required=True, help="time map CSV to write")
    t.add_argument("--plot", type=Path, help="figure (PNG) to write")
    t.add_argument("--progress", action="store_true")
    p = sub.add_parser("spatial", help="wall-thickness compensation by work-offset shift")
    p.add_argument("--probes", required=True, type=Path, help="CSV: x, y, z, thickness")
    p.add_argument("--design", required=True, type=Path, help="CSV: x, y, z (design target S3)")
    p.add_argument("--design-thickness", required=True, type=float)
    p.add_argument("--threshold", required=True, type=float, help="k: largest accepted F")
    p.add_argument("--g54", required=True, type=float, nargs=3, metavar=("X", "Y", "Z"))
    p.add_argument("--register", type=int, default=2, help="2..6 = G55..G59 (default 2)")
    p.add_argument("--geometry", choices=("cylinder", "plane"), default="cylinder")
    p.add_argument("--outward", choices=("x", "y", "z"), default="x",
                   help="plane: axis the wall faces")
    p.add_argument("--centre", choices=("centroid", "registration"), default=None,
                   help="default: centroid for cylinder, registration for plane")
    p.add_argument("--plot", type=Path)
    p.add_argument("--out", type=Path, help="result JSON to write")
    return parser


def _temporal(args: argparse.Namespace) -> int:
    specs = [ChannelSpec(n, c, args.unit) for n, c in zip("xyz", args.columns)]
    rec = load_recorded(args.recorded, specs, sample_period=args.sample_period,
                        time_column=args.time_column, time_unit=args.time_unit)
    recorded = Trajectory.from_recorded(rec)
    if args.results is not None:
        simulated = Trajectory.from_results(load_results(args.results), args.sim_columns,
                                            args.output_delay, str(args.results))
    else:
        sim_specs = [ChannelSpec(n, c, args.sim_unit) for n, c in zip("xyz", args.sim_columns)]
        simulated = Trajectory.from_recorded(load_recorded(args.simulated, sim_specs,
                                                           time_column="time"))
    options = MultiscaleOptions(progress=True) if args.progress and args.method == "multiscale" \
        else None
    tm = align(recorded, simulated, args.method, options)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tm.frame().to_csv(args.out, index=False)
    print(f"{args.method}: {len(tm)} samples mapped to simulated "
          f"{tm.simulated_time[0]:.3f} .. {tm.simulated_time[-1]:.3f} s; median confidence "
          f"{np.median(tm.confidence):.2f}; wrote {args.out}")
    if args.plot:
        from milling_twin.orchestrator.align.plots import plot_temporal

        print(f"plot: {plot_temporal(recorded, simulated, tm, args.plot, unit='m')}")
    return 0


def _spatial(args: argparse.Namespace) -> int:
    probes = load_probe_csv(args.probes)
    design = load_cloud_csv(args.design)
    centre = args.centre or ("centroid" if args.geometry == "cylinder" else "registration")
    comp = compensate_wall(probes, design, args.design_thickness, args.threshold,
                           geometry=args.geometry, outward=args.outward, centre=centre,
                           design_source=str(args.design))
    dx, dy = comp.shift
    print(f"F = {comp.registration.mean_distance:.4f} (k = {comp.threshold:g}); rotation "
          f"{comp.rotation_deg:.4f} deg; shift dx = {dx:+.4f}, dy = {dy:+.4f}; remaining stock "
          f"{comp.info['stock_min']:.4f} .. {comp.info['stock_max']:.4f}"
          + (f" ({int(comp.info['undercut_points'])} design points outside the part)"
             if comp.info["undercut_points"] else ""))
    result = {"F": comp.registration.mean_distance, "threshold": comp.threshold,
              "accepted": comp.accepted, "dx": float(dx), "dy": float(dy),
              "rotation_deg": comp.rotation_deg,
              "rotation": comp.registration.rotation.tolist(),
              "translation": comp.registration.translation.tolist(), **comp.info}
    if comp.accepted:
        result["gcode"] = work_offset_gcode(comp.shift, tuple(args.g54), args.register)
        print("\n".join(result["gcode"]))
    else:
        print(f"registration rejected: F = {comp.registration.mean_distance:.4f} > k = "
              f"{comp.threshold:g}; no G-code", file=sys.stderr)
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
    if args.plot:
        from milling_twin.orchestrator.align.plots import plot_spatial

        print(f"plot: {plot_spatial(comp, args.plot)}")
    return 0 if comp.accepted else 3


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        return _temporal(args) if args.command == "temporal" else _spatial(args)
    except (AlignmentError, RecordedDataError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

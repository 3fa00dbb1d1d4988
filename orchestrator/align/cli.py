"""Handlers of ``milling-twin align temporal|spatial`` (options in :mod:`milling_twin.cli`).

temporal: align a recording (CSV, through orchestrator.recorded) with a simulated run (a run
folder of ``milling-twin run`` or a CSV), write the time map as CSV (recorded_time,
simulated_time, confidence), optionally a figure. Positions are converted to SI on loading.

spatial: wall-thickness compensation from probe and design CSV files (columns x, y, z
[, thickness]; one length unit for all inputs); prints the work-offset shift, F and the G-code;
returns 3 (``milling_twin.cli.REJECTED``) when the registration is rejected (F > k: no G-code).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from milling_twin.cli import REJECTED
from milling_twin.orchestrator.align.multiscale import MultiscaleOptions
from milling_twin.orchestrator.align.segments import PiecewiseTimeMap, SegmentMap
from milling_twin.orchestrator.align.spatial import (compensate_wall, load_cloud_csv, load_probe_csv,
                                        work_offset_gcode)
from milling_twin.orchestrator.align.temporal import align
from milling_twin.orchestrator.align.trajectory import Trajectory
from milling_twin.orchestrator.recorded import ChannelSpec, load_recorded
from milling_twin.orchestrator.results import load_results


def temporal(args: argparse.Namespace) -> int:
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
    piecewise = PiecewiseTimeMap(len(tm), (SegmentMap(0, 0, len(tm), tm),), str(args.recorded))
    for line in piecewise.report(args.min_confidence):
        print(line)
    if args.plot:
        from milling_twin.orchestrator.align.plots import plot_temporal

        print(f"plot: {plot_temporal(recorded, simulated, tm, args.plot, unit='m')}")
    return 0


def spatial(args: argparse.Namespace) -> int:
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
    return 0 if comp.accepted else REJECTED

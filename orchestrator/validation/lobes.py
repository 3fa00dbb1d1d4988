"""``milling-twin lobes SCENARIO``: the analytic (zero-order, Altintas-Budak) stability lobes of a scenario's
tool, modes and cutting coefficients, as a plot, a CSV and the stable pockets in the speed range.

The scenario names a CuttingForce instance ``force`` and a ToolVibration instance ``vibration`` (as
``scenarios/chatter.toml``); their parameters (with ``--set`` overrides) and the model defaults give the
modes, the cutting coefficients Ktc, Krc, the flute count and the immersion (entry/exit angles).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from milling_twin.orchestrator.scenario import Scenario, ScenarioError, load_scenario, with_values
from milling_twin.orchestrator.validation.chatter import analytic_limit

__all__ = ["command", "limit_curve", "pockets"]

REQUIRED = {"force": "CuttingForce", "vibration": "ToolVibration"}


def limit_curve(scenario: Scenario, speeds: np.ndarray) -> np.ndarray:
    """The limiting axial depth [m] at each spindle speed [rpm]."""
    for name, model in REQUIRED.items():
        if name not in scenario.execution_order or scenario.instance(name).model_identifier != model:
            raise ScenarioError(scenario.path, f"[fmus.{name}]", f"the lobes need a {model} instance named {name!r}")
    return analytic_limit(scenario, speeds)


def pockets(speeds: np.ndarray, depth: np.ndarray) -> list[tuple[float, float]]:
    """The stable pockets: (speed [rpm], limiting depth [m]) at each interior local maximum of the limit."""
    d = np.where(np.isfinite(depth), depth, -np.inf)
    peaks = np.nonzero((d[1:-1] > d[:-2]) & (d[1:-1] >= d[2:]))[0] + 1
    return [(float(speeds[i]), float(depth[i])) for i in peaks]


def _plot(path: Path, scenario: Scenario, speeds: np.ndarray, depth: np.ndarray,
          best: list[tuple[float, float]]) -> None:
    fig = Figure(figsize=(9, 4.5), layout="constrained")
    ax = fig.subplots()
    ax.fill_between(speeds, depth * 1e3, np.nanmax(depth) * 1e3 * 1.15, color="tab:red", alpha=0.12,
                    label="chatter (unstable)")
    ax.plot(speeds, depth * 1e3, color="k", lw=1.2, label="stability limit (zero-order)")
    for speed, a in best:
        ax.plot(speed, a * 1e3, "v", color="tab:green")
    ax.set_xlabel("spindle speed [rpm]")
    ax.set_ylabel("limiting axial depth [mm]")
    ax.set_xlim(speeds[0], speeds[-1])
    ax.set_ylim(0, np.nanmax(depth) * 1e3 * 1.15)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"Stability lobes of {scenario.path.name} (pockets marked)", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)


def command(args: argparse.Namespace) -> int:
    from milling_twin.cli import UsageError, overrides_of

    low, high = args.speeds
    if not 0 < low < high or args.points < 2:
        raise UsageError(f"--speeds {low:g} {high:g} --points {args.points}: need 0 < MIN < MAX and POINTS >= 2")
    scenario = load_scenario(args.scenario, args.fmu_dir)
    overrides = overrides_of(args)
    if overrides:
        scenario = with_values(scenario, overrides)
    speeds = np.linspace(low, high, args.points)
    depth = limit_curve(scenario, speeds)
    best = pockets(speeds, depth)
    _plot(args.out, scenario, speeds, depth, best)
    if args.csv:
        args.csv.parent.mkdir(parents=True, exist_ok=True)
        np.savetxt(args.csv, np.column_stack([speeds, depth * 1e3]), delimiter=",", header="speed_rpm,depth_mm",
                   comments="", fmt="%.6g")
    print(f"minimum limit {np.nanmin(depth) * 1e3:.3f} mm in {low:g}..{high:g} rpm")
    for speed, a in sorted(best, key=lambda p: -p[1])[:5]:
        print(f"pocket at {speed:.0f} rpm: {a * 1e3:.3f} mm")
    print(f"plot: {args.out}" + (f"; csv: {args.csv}" if args.csv else ""))
    return 0

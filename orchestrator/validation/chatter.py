"""Chatter: the onset of regenerative chatter in the co-simulation against the analytic lobes.

    milling-twin validate chatter [--speeds 6000 9000 ...] [--iterations 8]
        [--scenario scenarios/chatter.toml] [--fmu-dir build/fmus] [--out runs] [--figure PNG]

The scenario (default ``scenarios/chatter.toml``: CuttingForce and ToolVibration in a loop,
slotting with 2 flutes on a 922 Hz single-mode tool) is run at each spindle speed for a range of
axial depths. Whether a cut chatters is read from the co-simulation alone: the tool displacement sampled
once per tooth period (where the forced vibration repeats, so only free vibration varies from
sample to sample) has a standard deviation over 0.15..0.2 s and over 0.1..0.15 s; their ratio is
the ``growth``. A cut is unstable when it exceeds 1 in x or y: the free vibration excited by the
tool's entry grows instead of dying out. At each speed a bisection on the axial depth between
0.5 and 2 times the analytic limit finds the simulated limit, which is compared with the
zero-order (Altintas-Budak) limit of ``milling_twin.models.stability`` for the scenario's coefficients and
modes. Writes ``chatter.json`` (every run: speed, depth, growth, stable) and ``chatter.png``
(simulated stable and unstable cuts over the analytic lobes) into ``<out>/chatter/``.
"""
from __future__ import annotations

import argparse
import json
import math
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from milling_twin.models.stability import Mode, stability_lobes
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Scenario, load_scenario, with_values

if TYPE_CHECKING:
    import pandas as pd

REPO = Path(__file__).resolve().parents[2]
WINDOWS = ((0.10, 0.15), (0.15, 0.20))  # s: growth = peak-to-peak in the second / in the first
DEFAULT_SPEEDS = (6000.0, 8000.0, 9000.0, 11000.0, 12000.0, 16000.0, 20000.0, 24000.0)  # rpm


@dataclass(frozen=True)
class Cut:
    speed_rpm: float
    depth: float  # m
    growth: float
    stable: bool


@dataclass(frozen=True)
class Limit:
    speed_rpm: float
    analytic: float  # m
    simulated: float  # m, middle of the final bisection bracket
    bracket: tuple[float, float]  # m: (deepest stable, shallowest unstable)

    @property
    def relative_difference(self) -> float:
        return (self.simulated - self.analytic) / self.analytic


@dataclass(frozen=True)
class ToolAndCut:
    """What the stability models need from a scenario: the tool's modes, the cutting coefficients [N/m^2], the
    flute count and the immersion [rad] (the instances ``force`` and ``vibration``, with the models' defaults)."""

    modes_x: tuple[Mode, ...]
    modes_y: tuple[Mode, ...]
    ktc: float
    krc: float
    n_flutes: int
    entry: float
    exit: float


def tool_and_cut(scenario: Scenario) -> ToolAndCut:
    """The scenario's tool, coefficients and immersion for ``milling_twin.models.stability``."""
    force, vibration = scenario.instance("force").parameters, scenario.instance("vibration").parameters
    defaults = _defaults(scenario)
    value = lambda table, name: table.get(name, defaults[name])  # noqa: E731

    def modes(direction: str) -> tuple[Mode, ...]:
        count = int(value(vibration, f"n_modes_{direction}"))
        return tuple(Mode(value(vibration, f"frequency_{direction}{i}"), value(vibration, f"damping_{direction}{i}"),
                          value(vibration, f"stiffness_{direction}{i}")) for i in range(1, count + 1))

    inputs = scenario.instance("force").inputs
    return ToolAndCut(modes("x"), modes("y"), value(force, "Ktc"), value(force, "Krc"), int(value(force, "n_flutes")),
                      inputs.get("entry_angle", 0.0), inputs.get("exit_angle", math.pi))


def analytic_limit(scenario: Scenario, speeds: np.ndarray, lobes: int = 60) -> np.ndarray:
    """The zero-order limit [m] at ``speeds`` [rpm] for the scenario's coefficients, tool and modes."""
    c = tool_and_cut(scenario)
    result = stability_lobes(c.modes_x, c.modes_y, c.ktc, c.krc, c.n_flutes, c.entry, c.exit, lobes=lobes)
    return result.limit(speeds)


def _defaults(scenario: Scenario) -> dict[str, float]:
    """Start values of the models behind the scenario's FMUs (what the FMUs use when not set)."""
    from milling_twin.models import MODELS

    values: dict[str, float] = {}
    for inst in scenario.instances:
        for v in MODELS[inst.model_identifier].variables:
            if v.start is not None and not isinstance(v.start, str):
                values[v.name] = float(v.start)
    return values


def growth_of(scenario: Scenario, out: Path) -> float:
    """Run ``scenario`` and return the growth of its free (chatter) vibration (``displacement_growth``), the larger
    of x and y."""
    result = run(scenario, out, progress=False)
    if result.signal is not None:  # a signal stops the whole search, not only this run (whose rows are partial)
        raise KeyboardInterrupt(f"{result.signal} during the run of {scenario.name}")
    return max(displacement_growth(scenario, load_results(result.run_dir)))


def displacement_growth(scenario: Scenario, frame: "pd.DataFrame",
                        windows: tuple[tuple[float, float], tuple[float, float]] = WINDOWS) -> tuple[float, float]:
    """The growth in x and in y of the free (chatter) vibration in the results ``frame`` of ``scenario``: the tool
    displacement sampled once per tooth period, where the forced response repeats, so what varies from sample
    to sample is the free vibration; its standard deviation in the second of ``windows`` [s] over the first."""
    force = scenario.instance("force")
    tooth_period = 2 * math.pi / (int(force.parameters.get("n_flutes", 2)) * force.inputs["spindle_speed"])
    t = frame["time"].to_numpy()
    ratios = []
    for axis in ("x", "y"):
        x = frame[f"vibration.tip_displacement_{axis}"].to_numpy()
        spreads = []
        for start, stop in windows:
            samples = np.interp(np.arange(start, stop, tooth_period), t, x)
            spreads.append(np.std(samples))
        ratios.append(spreads[1] / spreads[0] if spreads[0] > 0 else math.inf)
    return ratios[0], ratios[1]


def cut(base: Scenario, speed: float, depth: float, out: Path) -> Cut:
    name = f"chatter_{speed:.0f}rpm_{depth * 1e6:.2f}um".replace(".", "p")
    force = base.instance("force")
    n_flutes = int(force.parameters.get("n_flutes", 2))
    # the same feed per tooth as the scenario's, whatever the speed
    feed_per_tooth = force.inputs["feed_velocity_x"] * 2 * math.pi / (n_flutes * force.inputs["spindle_speed"])
    omega = speed * 2 * math.pi / 60
    feed = feed_per_tooth * n_flutes * omega / (2 * math.pi)
    scenario = with_values(base, {"force.spindle_speed": omega, "force.axial_depth": depth,
                                  "force.feed_velocity_x": feed}, name=name)
    growth = growth_of(scenario, out)
    return Cut(speed, depth, float(growth), bool(growth <= 1.0))


def find_limit(base: Scenario, speed: float, analytic: float, iterations: int, out: Path,
               cuts: list[Cut], bar: tqdm) -> Limit:
    low, high = 0.5 * analytic, 2.0 * analytic
    for depth in (low, high):
        cuts.append(cut(base, speed, depth, out))
        bar.update()
    if not cuts[-2].stable or cuts[-1].stable:
        raise RuntimeError(f"{speed:.0f} rpm: expected stable at {low * 1e3:.4f} mm and chatter at "
                           f"{high * 1e3:.4f} mm (0.5 and 2 times the analytic limit); got growth "
                           f"{cuts[-2].growth:.3f} and {cuts[-1].growth:.3f}")
    for _ in range(iterations):
        middle = 0.5 * (low + high)
        cuts.append(cut(base, speed, middle, out))
        bar.update()
        low, high = (middle, high) if cuts[-1].stable else (low, middle)
    return Limit(speed, analytic, 0.5 * (low + high), (low, high))


def plot(base: Scenario, cuts: list[Cut], limits: list[Limit], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    speeds = np.linspace(0.8 * min(c.speed_rpm for c in cuts), 1.1 * max(c.speed_rpm for c in cuts), 1500)
    fig, ax = plt.subplots(figsize=(9, 5.5))
    ax.plot(speeds, analytic_limit(base, speeds) * 1e3, color="black", lw=1.2,
            label="analytic limit (zero-order lobes)")
    stable = [c for c in cuts if c.stable]
    unstable = [c for c in cuts if not c.stable]
    ax.scatter([c.speed_rpm for c in stable], [c.depth * 1e3 for c in stable], marker="o", s=18,
               facecolors="none", edgecolors="tab:green", label="co-simulation: stable")
    ax.scatter([c.speed_rpm for c in unstable], [c.depth * 1e3 for c in unstable], marker="x", s=22,
               color="tab:red", label="co-simulation: chatter")
    ax.scatter([lim.speed_rpm for lim in limits], [lim.simulated * 1e3 for lim in limits], marker="D", s=40,
               color="tab:blue", label="co-simulation: limit (bisection)", zorder=5)
    for lim in limits:
        ax.annotate(f"{100 * lim.relative_difference:+.1f} %", (lim.speed_rpm, lim.simulated * 1e3),
                    textcoords="offset points", xytext=(6, 6), fontsize=8)
    ax.set_xlabel("spindle speed [rpm]")
    ax.set_ylabel("axial depth of cut [mm]")
    ax.set_title("Regenerative chatter: co-simulated CuttingForce + ToolVibration vs analytic lobes\n"
                 "slotting, 2 flutes, 922 Hz single-mode tool")
    ax.set_ylim(0, 2.2 * max(lim.analytic for lim in limits) * 1e3)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def command(args: argparse.Namespace) -> int:
    """``milling-twin validate chatter``."""
    if args.speeds is None:
        args.speeds = list(DEFAULT_SPEEDS)

    base = load_scenario(args.scenario, args.fmu_dir)
    analytic = analytic_limit(base, np.array(args.speeds))
    out = args.out / "chatter"
    out.mkdir(parents=True, exist_ok=True)
    cuts: list[Cut] = []
    limits: list[Limit] = []
    with tempfile.TemporaryDirectory() as runs, tqdm(total=len(args.speeds) * (args.iterations + 2),
                                                     unit="run", desc="chatter") as bar:
        for speed, a_lim in zip(args.speeds, analytic):
            limits.append(find_limit(base, speed, float(a_lim), args.iterations, Path(runs), cuts, bar))
    report = {
        "scenario": str(args.scenario),
        "criterion": f"unstable when the once-per-tooth displacement spread grows from {WINDOWS[0]} s to {WINDOWS[1]} s",
        "limits": [{**asdict(lim), "relative_difference": lim.relative_difference} for lim in limits],
        "cuts": [asdict(c) for c in cuts],
    }
    (out / "chatter.json").write_text(json.dumps(report, indent=2))
    plot(base, cuts, limits, out / "chatter.png")
    if args.figure:
        plot(base, cuts, limits, args.figure)
    print(f"{'speed [rpm]':>12} {'analytic [mm]':>14} {'simulated [mm]':>15} {'difference':>11}")
    for lim in limits:
        print(f"{lim.speed_rpm:12.0f} {lim.analytic * 1e3:14.4f} {lim.simulated * 1e3:15.4f} "
              f"{100 * lim.relative_difference:+10.1f} %")
    worst = max(abs(lim.relative_difference) for lim in limits)
    print(f"largest difference {100 * worst:.1f} % (target: within 10 %); results in {out}")
    return 0

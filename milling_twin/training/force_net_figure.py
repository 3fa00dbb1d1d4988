"""The docs figure of the force net in slot milling (no recorded data in it: only errors and scores).

    milling-twin validate forcenet-figure [--runs runs] [--fmu-dir build/fmus] [--out scenarios/figures/forcenet_slot_milling.png]

Top: ``scenarios/slot_milling.toml`` and ``scenarios/slot_milling_forcenet.toml`` (the one-line swap) simulated
at 900 mm/min, forces over one revolution. Below, per recorded axis against the feed per tooth: the relative
error of the mean force and the waveform r^2 of the slot-milling validation (``runs/slot_milling/`` and
``runs/slot_milling_forcenet/slot_milling.json``, written by ``milling-twin validate slot-milling``
without and with ``--scenario scenarios/slot_milling_forcenet.toml --finetuned runs/forcenet_finetune``).
The recordings themselves have no licence to redistribute and are not drawn.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

REPO = Path(__file__).resolve().parents[2]
AXES = ("Fx", "Fy", "Fz")  # recorded axes (= simulated Fy, Fx, Fz)
SERIES = (  # (validation, set, label, style)
    ("slot_milling", "prior", "CuttingForce, literature coefficients", dict(color="tab:orange", marker="s", ls="--")),
    ("slot_milling", "identified", "CuttingForce, coefficients identified from all 5 (in-sample)",
     dict(color="tab:blue", marker="^", ls=":")),
    ("slot_milling_forcenet", "prior", "ForceNet, trained on the mechanistic model",
     dict(color="tab:red", marker="o", ls="-", mfc="none")),
    ("slot_milling_forcenet", "finetuned", "ForceNet, fine-tuned on the 4 other feeds (left-out prediction)",
     dict(color="tab:green", marker="v", ls="-")),
)


def simulate_both(fmu_dir: Path) -> dict:
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.results import load_results
    from milling_twin.orchestrator.scenario import load_scenario

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("slot_milling", "slot_milling_forcenet"):
            result = run(load_scenario(REPO / "scenarios" / f"{name}.toml", fmu_dir), Path(tmp), progress=False)
            if result.signal is not None:  # partial rows: the figure is not drawn
                raise KeyboardInterrupt(f"{result.signal} during the run of {name}")
            out[name] = load_results(result.run_dir)
    return out


def figure(runs: Path, fmu_dir: Path, path: Path) -> Path:
    needed = {name: runs / name / "slot_milling.json" for name in ("slot_milling", "slot_milling_forcenet")}
    missing = [str(p) for p in needed.values() if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"{', '.join(missing)} missing: run `milling-twin validate slot-milling --out {runs}` "
                                "and, with --scenario scenarios/slot_milling_forcenet.toml --finetuned DIR, for the "
                                "force net first")
    docs = {name: json.loads(path.read_text()) for name, path in needed.items()}
    simulated = simulate_both(fmu_dir)
    fig = Figure(figsize=(13, 10), layout="constrained")
    grid = fig.subplots(3, 3)
    for k, axis in enumerate(("Fx", "Fy", "Fz")):
        ax = grid[0][k]
        for name, label, style in (("slot_milling", "CuttingForce", dict(color="tab:orange", lw=2.5, alpha=0.6)),
                                   ("slot_milling_forcenet", "ForceNet", dict(color="k", lw=1))):
            data = simulated[name]
            angle = np.degrees(data["force.spindle_angle"].to_numpy())
            last = data["time"].to_numpy() >= data["time"].to_numpy()[-1] - 0.01  # the last revolution
            order = np.argsort(angle[last])
            ax.plot(angle[last][order], data[f"force.{axis}"].to_numpy()[last][order], label=label, **style)
        ax.set_title(f"simulated {axis} on the tool, slot, 900 mm/min", fontsize=9)
        ax.set_xlabel("spindle angle [deg]")
        ax.set_ylabel("force [N]")
        ax.grid(True, alpha=0.3)
    grid[0][0].legend(fontsize=8)
    for k, axis in enumerate(AXES):
        for row, (key, what, unit) in enumerate((("mean_relative_error", "mean force error vs recorded", "%"),
                                                 ("waveform_r2", "waveform r$^2$ vs recorded", ""))):
            ax = grid[row + 1][k]
            for validation, name, label, style in SERIES:
                cases = docs[validation]["cases"]
                if not cases or name not in cases[0]:
                    continue
                x = [c["feed_per_tooth_mm"] for c in cases]
                y = [c[name][key][axis] * (100 if unit else 1) for c in cases]
                ax.plot(x, y, label=label, **style)
            ax.axhline(0 if unit else 1, color="k", lw=0.8)
            ax.set_title(f"{what}, recorded {axis}", fontsize=9)
            ax.set_xlabel("feed per tooth [mm]")
            ax.set_ylabel(f"{what.split(' vs')[0]} [{unit or '1'}]")
            if not unit:
                ax.set_ylim(-1.0, 1.02)
            ax.grid(True, alpha=0.3)
    handles, labels = grid[1][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize=8)
    fig.suptitle("Force net in slot milling (6000 rpm, 2 flutes, 3 mm deep): against CuttingForce and the five "
                 "measured recordings")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    return path


def command(args: argparse.Namespace) -> int:
    """``milling-twin validate forcenet-figure``."""
    print(figure(args.runs, args.fmu_dir, args.out))
    return 0

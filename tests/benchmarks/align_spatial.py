"""Spatial alignment benchmark: recovered work-offset shift on generated thin-walled parts.

    .venv/bin/python tests/benchmarks/align_spatial.py [--parts 20]
        [--figure scenarios/figures/align_spatial.png]

Rings (outer radius 50 mm, wall 2 mm, height 30 mm): the inner wall's axis shifted by 0.5 mm in
a random direction, the cast outer surface off-centre by up to 0.2 mm with 0.4 mm stock and a
0.05 mm 3-lobe form error; probes with 2 um position noise and 5 um gauge noise, on grids of
angles x heights. Flat walls (80 x 30 mm, 3 mm): inner face shifted 0.5 mm and turned about z by
a random angle within +-0.5 deg. Reported: median and largest error of the shift (um), of the
rotation (wall), the mean ICP distance F, and the wall time per part.
"""
from __future__ import annotations

import sys
import argparse
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from milling_twin.orchestrator.align import compensate_wall, work_offset_gcode
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the generated cases (tests/cases)

from cases.align_parts import make_ring, make_wall
from milling_twin.orchestrator.align.plots import plot_spatial

REPO = Path(__file__).resolve().parents[2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--parts", type=int, default=20)
    parser.add_argument("--figure", type=Path, default=REPO / "scenarios" / "figures" /
                        "align_spatial.png")
    args = parser.parse_args()
    rng = np.random.default_rng(11)
    print("| part | probes | shift error median / max (um) | rotation error max (deg) | "
          "F median (mm) | time per part (s) |")
    print("|---|---:|---:|---:|---:|---:|")
    for grid in ((12, 3), (24, 5), (36, 8)):
        errs, fs, wall = [], [], 0.0
        for seed in tqdm(range(args.parts), desc=f"ring {grid}", leave=False):
            a, b = rng.uniform(0, 2 * np.pi, 2)
            part = make_ring(inner_shift=(0.5 * np.cos(a), 0.5 * np.sin(a)),
                             outer_shift=tuple(rng.uniform(0, 0.2) * np.array([np.cos(b),
                                                                              np.sin(b)])),
                             n_angles=grid[0], n_heights=grid[1], seed=seed)
            start = time.perf_counter()
            comp = compensate_wall(part.probes, part.design, part.design_thickness, 0.05)
            wall += time.perf_counter() - start
            errs.append(np.hypot(*(comp.shift - part.shift)) * 1000)
            fs.append(comp.registration.mean_distance)
        print(f"| ring, 0.5 mm shift | {grid[0]} x {grid[1]} | {np.median(errs):.1f} / "
              f"{np.max(errs):.1f} | - | {np.median(fs):.4f} | {wall / args.parts:.2f} |")
    errs, rot, fs, wall = [], [], [], 0.0
    for seed in tqdm(range(args.parts), desc="wall", leave=False):
        angle = float(rng.uniform(-0.5, 0.5))
        part = make_wall(inner_shift=0.5, angle_deg=angle, seed=seed)
        start = time.perf_counter()
        comp = compensate_wall(part.probes, part.design, part.design_thickness, 0.05,
                               geometry="plane", outward="x", centre="registration",
                               resolution=(81, 16))
        wall += time.perf_counter() - start
        errs.append(abs(comp.shift[0] - part.shift[0]) * 1000)
        rot.append(abs(Rotation.from_matrix(comp.registration.rotation).as_rotvec(
            degrees=True)[2] + angle))
        fs.append(comp.registration.mean_distance)
    print(f"| flat wall, 0.5 mm shift, +-0.5 deg turn | 9 x 4 | {np.median(errs):.1f} / "
          f"{np.max(errs):.1f} | {np.max(rot):.4f} | {np.median(fs):.4f} | "
          f"{wall / args.parts:.2f} |")
    part = make_ring(inner_shift=(0.4, 0.3), outer_shift=(0.1, -0.05), stock=0.6, seed=3)
    comp = compensate_wall(part.probes, part.design, part.design_thickness, 0.05)
    print(f"\nfigure part: true shift {part.shift.round(4).tolist()}, found "
          f"{comp.shift.round(4).tolist()}; G-code for G54 = (200, 100, -40):")
    print("\n".join(work_offset_gcode(comp.shift, (200.0, 100.0, -40.0))))
    if args.figure:
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        plot_spatial(comp, args.figure, title="generated ring: inner wall shifted by "
                     "(0.4, 0.3) mm, 24 x 5 probes")
        print(f"figure: {args.figure} ({args.figure.stat().st_size // 1024} kB)")


if __name__ == "__main__":
    main()

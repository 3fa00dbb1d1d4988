"""The machined surface: the Z-map file read into a grid, its volume, the closed STL (watertight, outward, its
volume the Z-map's) and the removed volume of a real Workpiece run against stock - final Z-map."""
from __future__ import annotations

from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.part.surface import ZMapGrid, load_zmap, stl_mesh, write_stl
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Ref, load_scenario, with_values

REPO = Path(__file__).resolve().parents[1]


def _grid(corner_cut: bool = False) -> ZMapGrid:
    nx, ny, d = 40, 24, 0.5e-3
    heights = np.full((ny, nx), 0.02)
    heights[8:16, 5:35] = 0.017        # a pocket
    heights[3, :] = 0.0                # a groove through to the bottom
    heights[10:12, 20:22] = np.nan     # NODATA: read as the bottom
    if corner_cut:
        heights[0, 0] = 0.01
    return ZMapGrid(100e-3 + (np.arange(nx) + 0.5) * d, -5e-3 + (np.arange(ny) + 0.5) * d, heights)


def _edges(vectors: np.ndarray) -> Counter:
    """Directed edges of all triangles, by vertex coordinates rounded to 1e-9 mm."""
    rounded = np.round(vectors, 9)
    edges: Counter = Counter()
    for tri in rounded:
        for i in range(3):
            edges[(tuple(tri[i]), tuple(tri[(i + 1) % 3]))] += 1
    return edges


@pytest.mark.parametrize("corner_cut", [False, True])
def test_stl_is_closed_and_holds_the_z_map_volume(tmp_path: Path, corner_cut: bool) -> None:
    grid = _grid(corner_cut)
    bottom = 0.0
    solid = stl_mesh(grid, bottom)
    edges = _edges(solid.vectors)
    # watertight and consistently oriented: every edge once in each direction (two triangles share it)
    assert all(count == 1 and edges[(b, a)] == 1 for (a, b), count in edges.items())
    volume_mm3, _, _ = solid.get_mass_properties()
    zmap_mm3 = grid.volume(bottom) * 1e9
    dx, dy = grid.dx * 1e3, grid.dy * 1e3
    h = np.nan_to_num(grid.heights, nan=bottom) * 1e3
    corner_term = dx * dy / 12 * (h[0, 0] + h[-1, -1] - h[0, -1] - h[-1, 0])   # the quads' diagonal
    assert volume_mm3 == pytest.approx(zmap_mm3 + corner_term, rel=1e-12)
    if not corner_cut:
        assert volume_mm3 == pytest.approx(zmap_mm3, rel=1e-12)
    assert abs(volume_mm3 - zmap_mm3) <= dx * dy * 20.0 / 6          # at most a sixth of a cell's column
    # in mm, binary
    path = tmp_path / "part.stl"
    triangles = write_stl(grid, bottom, path)
    assert path.read_bytes()[:5] != b"solid" and path.stat().st_size == 84 + 50 * triangles
    lo, hi = solid.vectors.reshape(-1, 3).min(axis=0), solid.vectors.reshape(-1, 3).max(axis=0)
    assert lo.tolist() == pytest.approx([100.0, -5.0, 0.0]) and hi.tolist() == pytest.approx([120.0, 7.0, 20.0])


def test_z_map_file_rows_run_from_the_largest_y_down(tmp_path: Path) -> None:
    """An ESRI ASCII grid as the Workpiece writes it, read with y ascending (row 0 the smallest y)."""
    heights = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]) * 1e-3      # row 0: the smallest y
    text = ["ncols 3", "nrows 2", "xllcorner 0.01", "yllcorner -0.02", "cellsize 0.0005", "NODATA_value -9999"]
    text += [" ".join(f"{v:.17g}" for v in row) for row in heights[::-1]]
    path = tmp_path / "z.asc"
    path.write_text("\n".join(text) + "\n")
    grid = load_zmap(path)
    assert grid.x.tolist() == pytest.approx([0.01025, 0.01075, 0.01125])
    assert grid.y.tolist() == pytest.approx([-0.01975, -0.01925])
    assert grid.heights.ravel().tolist() == pytest.approx(heights.ravel().tolist())
    assert grid.volume(0.0) == pytest.approx(21e-3 * 0.25e-6)


def test_removed_volume_of_a_workpiece_run_is_stock_minus_the_final_z_map(fmu_dir: Path, tmp_path: Path) -> None:
    """scenarios/slot_entry_forcenet.toml (a 25 mm slot 3 mm deep entering the default 100 x 60 x 30 mm block, 0.5 mm
    cells) with the Z-map written at the end: the Workpiece's removed_volume sums the same cells."""
    scenario = load_scenario(REPO / "scenarios" / "slot_entry_forcenet.toml", fmu_dir)
    zmap = tmp_path / "final.asc"
    scenario = with_values(scenario, {"workpiece.zmap_file": str(zmap)})
    scenario = replace(scenario, outputs=(*scenario.outputs, Ref("workpiece", "removed_volume")))
    frame = load_results(run(scenario, tmp_path, progress=False).run_dir)
    grid = load_zmap(zmap)
    assert (grid.x.size, grid.y.size) == (200, 120)
    stock = 0.1 * 0.06 * 0.03
    removed = stock - grid.volume(0.0)
    assert frame["workpiece.removed_volume"].iloc[-1] == pytest.approx(removed, rel=1e-9)
    # the slot: 25 mm wide, 3 mm deep, from the block's edge at x = 0 to the tool's last centre and the half disc
    # ahead of it: cells of 0.5 mm across 25 mm give the width to within 2 %
    centre = frame["interp.x"].iloc[-1]
    assert 2e-3 < centre < 30e-3
    analytic = (25e-3 * centre + np.pi * 12.5e-3 ** 2 / 2) * 3e-3
    assert removed == pytest.approx(analytic, rel=0.02)
    solid = stl_mesh(grid, 0.0)
    volume_mm3, _, _ = solid.get_mass_properties()
    assert volume_mm3 == pytest.approx(grid.volume(0.0) * 1e9, rel=1e-12)

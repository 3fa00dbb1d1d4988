"""Workpiece (Z-map) FMU, both FMI versions: equal to the numpy reference models.workpiece.ZMap to the
last bit on several tool paths; removed volumes against the exact volumes of straight slots within
the stated resolution error; entry and exit angles, depths and the engagement map for slotting and
side milling; rejected configurations and steps with their logged messages; per-step cost
independent of the stock size."""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np
import pytest

from fmu_helpers import ERROR, OK, WARNING, Slave, fmu_dir, fmu_id, require_fmu, status_of
from milling_twin.models.workpiece import (MAP_NAMES, N_THETA, N_Z, OUTPUTS, WORKPIECE, WorkpieceError, ZMap,
                                          ZMapFileError, map_name, read_zmap, reference_trajectory, validate)

FMUS = [fmu_dir() / "Workpiece.fmu", fmu_dir() / "Workpiece_fmi2.fmu"]
MM = 1e-3
H = 1e-3            # step size [s]
SPINDLE = 1000.0    # rad/s (~9550 rpm)
DEFAULTS = WORKPIECE.defaults()
TOP = DEFAULTS["stock_z_min"] + DEFAULTS["stock_height"]  # 30 mm


@pytest.fixture(params=FMUS, ids=fmu_id)
def fmu(request) -> Path:
    return require_fmu(request.param)


# ---- paths and runs ----


def polyline(waypoints: Sequence[Sequence[float]], feed: float) -> list[tuple[float, float, float]]:
    """Points along straight lines through the waypoints [m], at most ``feed`` [m] apart."""
    points = [tuple(float(c) for c in waypoints[0])]
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        n = max(1, math.ceil(float(np.linalg.norm(b - a)) / feed))
        points += [tuple(a + (b - a) * (k / n)) for k in range(1, n + 1)]
    return points


def chain(*pieces: list, link_feed: float = 1.0 * MM) -> list:
    """The pieces one after the other, joined by straight moves of at most ``link_feed`` per step."""
    points = list(pieces[0])
    for piece in pieces[1:]:
        if tuple(points[-1]) != tuple(piece[0]):
            points += polyline([points[-1], piece[0]], link_feed)[1:]
        points += list(piece[1:])
    return points


def arc(center: Sequence[float], radius: float, start: float, end: float, z: float, feed: float) -> list:
    n = max(1, math.ceil(abs(end - start) * radius / feed))
    return [(center[0] + radius * math.cos(a), center[1] + radius * math.sin(a), z)
            for a in np.linspace(start, end, n + 1)]


# The FMU's outputs: the scalars and the array "engagement" (FMI 3: one array variable, FMI 2: its
# elements); read through Slave.get they are the reference's OUTPUTS, in the same order.
FMU_OUTPUTS = [v.name for v in WORKPIECE.of("output")]
# the outputs of the engagement and the removal in the last step (not the clearance nor the running volume)
STEP_OUTPUTS = [k for k, name in enumerate(OUTPUTS) if name not in ("clearance", "removed_volume")]


def run_fmu(path: Path, parameters: dict, points: Sequence[Sequence[float]], spindle: float = SPINDLE,
            outputs: Sequence[str] = OUTPUTS) -> tuple[np.ndarray, Slave]:
    """Initialize at points[0], then one step of H to each point; outputs after each step."""
    outputs = FMU_OUTPUTS if list(outputs) == list(OUTPUTS) else outputs
    rows = []
    slave = Slave(path)
    slave.instantiate()
    x, y, z = points[0]
    slave.initialize({**parameters, "tool_x": x, "tool_y": y, "tool_z": z, "spindle_speed": spindle})
    for x, y, z in points:
        slave.set({"tool_x": x, "tool_y": y, "tool_z": z})
        assert slave.step(H) in (OK, WARNING), slave.messages[-3:]
        rows.append(slave.get(outputs))
    return np.array(rows), slave


def run_reference(parameters: dict, points: Sequence[Sequence[float]], spindle: float = SPINDLE,
                  outputs: Sequence[str] = OUTPUTS) -> tuple[np.ndarray, ZMap]:
    zmap = ZMap(parameters, points[0])
    rows = []
    for point in points:
        out = zmap.step(point, H, spindle)
        rows.append([out[n] for n in outputs])
    return np.array(rows), zmap


def removed_volume(rows: np.ndarray) -> float:
    return float(np.sum(rows[:, OUTPUTS.index("mrr")]) * H)


# ---- the FMU is its reference ----

PATHS = {
    # default block 100 x 60 x 30 mm, 10 mm flat end mill: ramp in, slot, side step, a diagonal,
    # a full circle (side milling against the slot), out of the block and back in at another depth
    "flat end mill": ({}, chain(
        polyline([(-8 * MM, 12 * MM, 31 * MM), (10 * MM, 12 * MM, 27 * MM), (40 * MM, 12 * MM, 27 * MM),
                  (40 * MM, 20 * MM, 27 * MM), (70 * MM, 45 * MM, 27 * MM)], 0.15 * MM),
        arc((55 * MM, 40 * MM), 8 * MM, 0.3, 0.3 + 2 * math.pi, 25 * MM, 0.15 * MM),
        polyline([(110 * MM, 40 * MM, 25 * MM), (110 * MM, 5 * MM, 26 * MM), (60 * MM, 5 * MM, 26 * MM)], 0.3 * MM))),
    # 8 mm ball end mill on a 0.4 mm grid: steep ramp (sub-segments), 3D contour, plunge and retract
    "ball end mill": ({"tool_diameter": 8 * MM, "corner_radius": 4 * MM, "resolution": 0.4 * MM},
                      polyline([(5 * MM, 30 * MM, 31 * MM), (9 * MM, 30 * MM, 26 * MM), (50 * MM, 36 * MM, 28.5 * MM),
                                (50 * MM, 36 * MM, 22 * MM), (50 * MM, 36 * MM, 29 * MM), (80 * MM, 10 * MM, 27 * MM)],
                               0.2 * MM)),
    # bull nose (corner 1.5 mm) on a 30 x 20 x 6 mm block offset from the origin: cuts through the
    # bottom, leaves the block sideways and re-enters, 2 ms steps
    "bull nose": ({"tool_diameter": 6 * MM, "corner_radius": 1.5 * MM, "resolution": 0.3 * MM,
                   "stock_x_min": -0.01, "stock_y_min": 0.02, "stock_z_min": -0.004, "stock_length": 0.03,
                   "stock_width": 0.02, "stock_height": 0.006},
                  polyline([(-0.013, 0.03, 0.0015), (0.005, 0.03, -0.005), (0.005, 0.045, -0.002),
                            (0.005, 0.035, 0.001), (0.025, 0.025, 0.0005)], 0.25 * MM)),
    # clearance (range 3 mm) against a slot, the block's faces and its top: a slot, out of it upwards, over
    # the block in air 1.5 mm above it, down beside its -x face and towards it, into it, up and diagonally
    # 0.8 mm above the top, down into a ramp
    "clearance tour": ({"clearance_range": 3 * MM}, polyline(
        [(-8 * MM, 30 * MM, 27 * MM), (50 * MM, 30 * MM, 27 * MM), (50 * MM, 30 * MM, 31.5 * MM),
         (-3 * MM, 12 * MM, 31.5 * MM), (-8 * MM, 12 * MM, 31.5 * MM), (-8 * MM, 12.1 * MM, 26 * MM),
         (-6.5 * MM, 12.1 * MM, 26 * MM), (10 * MM, 12.1 * MM, 26 * MM), (10 * MM, 12.1 * MM, 30.8 * MM),
         (70 * MM, 45 * MM, 30.8 * MM), (90 * MM, 50 * MM, 29 * MM)], 0.3 * MM)),
}


@pytest.mark.parametrize("name", PATHS)
def test_fmu_equals_the_numpy_reference_bit_for_bit(fmu: Path, name: str) -> None:
    parameters, points = PATHS[name]
    actual, slave = run_fmu(fmu, parameters, points)
    slave.unload()
    expected, zmap = run_reference(parameters, points)
    assert actual.shape == expected.shape
    differ = np.argwhere(actual != expected)
    if differ.size:
        first = tuple(differ[0])
        pytest.fail(f"{len(differ)} values differ, first at step {first[0]} output {OUTPUTS[first[1]]}: "
                    f"{actual[first]!r} != {expected[first]!r}")
    # the bull-nose path goes through the bottom of the block: both warn of it, nothing else
    assert zmap.warnings == (["bottom"] if name == "bull nose" else [])
    assert [m.status for m in slave.messages] == [WARNING] * len(zmap.warnings)
    # the paths exercise what they should: cutting, every engagement output, partial engagement
    mrr = expected[:, OUTPUTS.index("mrr")]
    assert np.count_nonzero(mrr) > len(points) // 3
    assert removed_volume(expected) == pytest.approx(zmap.removed_volume, rel=1e-12)
    cumulative = expected[:, OUTPUTS.index("removed_volume")]
    assert np.all(np.diff(cumulative) >= 0) and cumulative[-1] == zmap.removed_volume
    assert cumulative == pytest.approx(np.cumsum(expected[:, OUTPUTS.index("mrr")]) * H, rel=1e-9, abs=1e-18)
    # clearance: in material (0), near it (between 0 and the range) and away from it (the range)
    clearance = expected[:, OUTPUTS.index("clearance")]
    limit = zmap.p["clearance_range"]
    assert np.all((clearance >= 0) & (clearance <= limit))
    assert np.any(clearance == 0) and np.any((clearance > 0) & (clearance < limit))
    for output in ("axial_depth", "radial_depth", "exit_angle"):
        assert np.max(expected[:, OUTPUTS.index(output)]) > 0, output
    entry = expected[:, OUTPUTS.index("entry_angle")]
    assert 0 < np.count_nonzero(entry) < len(points)
    assert np.max(expected[:, [OUTPUTS.index(n) for n in MAP_NAMES]]) == 1.0


def test_slow_feed_equals_the_reference_also_after_restoring_a_state(fmu: Path) -> None:
    """A feed of 1/2500 of a cell per step (600 mm/min at 10 us steps on the 0.25 mm grid) into the block
    across its -x face, the axis on a cell boundary, then at rest, then diagonally: from step to step
    the FMU reuses what its probes of the stock found and keeps the disc under the tool as cleared
    (fmus/workpiece/model.c), which must change nothing: equal to the reference to the last bit, also
    when stepped again from a serialized FMU state taken midway."""
    y, z = 30 * MM, TOP - 0.03 * MM
    feed = 0.25 * MM / 2500
    points = polyline([(-4.9 * MM, y, z), (-4.8 * MM, y, z)], feed)
    points += [points[-1]] * 20
    points += polyline([points[-1], (-4.7 * MM, y + 0.05 * MM, z)], feed)[1:]
    expected, _ = run_reference({}, points)
    entry = expected[:, OUTPUTS.index("entry_angle")]
    assert np.count_nonzero(expected[:, OUTPUTS.index("mrr")]) > 0 and len(np.unique(entry)) > 10
    half = len(points) // 2
    with Slave(fmu) as slave:
        slave.instantiate()
        x0, y0, z0 = points[0]
        slave.initialize({"tool_x": x0, "tool_y": y0, "tool_z": z0, "spindle_speed": SPINDLE})
        runs = [[]]
        for k, (x, y, z) in enumerate(points):
            if k == half:
                state = slave.fmu.getFMUState()
                data = slave.fmu.serializeFMUState(state)
                slave.fmu.freeFMUState(state)
            slave.set({"tool_x": x, "tool_y": y, "tool_z": z})
            assert slave.step(H) == OK, slave.messages[-3:]
            runs[0].append(slave.get(FMU_OUTPUTS))
        slave.set_state(slave.fmu.deserializeFMUState(data))
        runs.append([])
        for x, y, z in points[half:]:
            slave.set({"tool_x": x, "tool_y": y, "tool_z": z})
            assert slave.step(H) == OK, slave.messages[-3:]
            runs[1].append(slave.get(FMU_OUTPUTS))
    for actual, wanted in ((np.array(runs[0]), expected), (np.array(runs[1]), expected[half:])):
        differ = np.argwhere(actual != wanted)
        assert not differ.size, (f"{len(differ)} values differ, first at step {differ[0][0]} output "
                                 f"{OUTPUTS[differ[0][1]]}")


def test_ball_path_cuts_in_several_sub_segments_and_through_the_bottom() -> None:
    """The steep ramp of the ball path descends more than a quarter cell per step (so each of those
    steps is cut in several sub-segments), and the bull-nose path empties cells down to the bottom."""
    parameters, points = PATHS["ball end mill"]
    zmap = ZMap(parameters, points[0])
    descents = [a[2] - b[2] for a, b in zip(points[:-1], points[1:]) if a[:2] != b[:2]]
    assert max(descents) > 0.25 * zmap.delta
    parameters, points = PATHS["bull nose"]
    _, zmap = run_reference(parameters, points)
    assert np.count_nonzero(zmap.heights == zmap.z0) > 100


# ---- clearance ----


def brute_clearance(zmap: ZMap, position: Sequence[float]) -> float:
    """The clearance by its definition (models/workpiece.py, step 3) over every cell of the grid."""
    x, y, z = position
    ex = zmap.x0 + (np.arange(zmap.nx) + 0.5) * zmap.dx - x
    ey = zmap.y0 + (np.arange(zmap.ny) + 0.5) * zmap.dy - y
    gh = np.maximum(np.sqrt(ex[None, :] ** 2 + ey[:, None] ** 2) - zmap.radius, 0.0)
    gv = np.maximum(z - zmap.heights, 0.0)
    distance = np.where(zmap.heights > zmap.z0, np.sqrt(gh * gh + gv * gv), math.inf)
    return min(zmap.p["clearance_range"], float(distance.min()))


def test_clearance_is_the_distance_to_the_nearest_material_over_the_whole_grid(fmu: Path) -> None:
    """After the clearance tour, 400 jumps of the tool (10 ms steps, max_tool_speed 100 m/s) to random positions
    around and in the cut block, each cutting what it sweeps: after every step the FMU's clearance is the
    reference's to the last bit (the FMU leaves out rows and cells that cannot be nearer, the reference
    searches a box around the tool) and the smallest distance over every cell of the grid."""
    parameters, tour = PATHS["clearance tour"]
    parameters = {**parameters, "max_tool_speed": 100.0}
    rng = np.random.default_rng(7)
    jumps = [(rng.uniform(-12 * MM, 112 * MM), rng.uniform(-12 * MM, 72 * MM), rng.uniform(24 * MM, 34 * MM))
             for _ in range(400)]
    zmap = ZMap(parameters, tour[0])
    with Slave(fmu) as slave:
        slave.instantiate()
        x, y, z = tour[0]
        slave.initialize({**parameters, "tool_x": x, "tool_y": y, "tool_z": z, "spindle_speed": SPINDLE})
        values = []
        for k, position in enumerate(tour + jumps):
            step = H if k < len(tour) else 10 * H
            slave.set(dict(zip(("tool_x", "tool_y", "tool_z"), position)))
            assert slave.step(step) in (OK, WARNING)
            wanted = zmap.step(position, step, SPINDLE)["clearance"]
            assert slave.get(["clearance"])[0] == wanted, (k, position)
            if k >= len(tour):
                assert wanted == brute_clearance(zmap, position), (k, position)
                values.append(wanted)
    values = np.array(values)
    assert np.count_nonzero(values == 0) > 20 and np.count_nonzero(values == 3 * MM) > 20
    assert np.count_nonzero((values > 0) & (values < 3 * MM)) > 100


def test_clearance_above_and_beside_the_block(fmu: Path) -> None:
    """A plunge from 5 mm above the top: the clearance is the height above the top (at most the range, 5 mm),
    0 from the first step into the block; then beside the block's -x face, the tool axis on a row of cell
    centres: the gap to the face cells' centres (half a cell inside the face)."""
    plunge = polyline([(50 * MM, 30 * MM, TOP + 6 * MM), (50 * MM, 30 * MM, TOP - 1 * MM)], 0.05 * MM)
    y = 30.125 * MM  # cell centres at (j + 1/2) * 0.25 mm
    beside = polyline([(-8 * MM, y, TOP + 1 * MM), (-8 * MM, y, TOP - 2 * MM), (-5.5 * MM, y, TOP - 2 * MM)],
                      0.05 * MM)
    points = chain(plunge, polyline([plunge[-1], (50 * MM, 30 * MM, TOP + 10 * MM)], 0.5 * MM),
                   polyline([(50 * MM, 30 * MM, TOP + 10 * MM), beside[0]], 1.0 * MM), beside)
    rows, slave = run_fmu(fmu, {}, points)
    slave.unload()
    clearance = rows[:, OUTPUTS.index("clearance")]
    z = np.array([p[2] for p in points])
    above = clearance[:len(plunge)]
    heights = z[:len(plunge)] - TOP
    assert np.array_equal(above, np.where(heights > 0, np.minimum(heights, 5 * MM), 0.0))
    x = np.array([p[0] for p in beside])
    gap = (0.125 * MM - x) - 5 * MM
    wanted = np.where(np.array([p[2] for p in beside]) > TOP, np.nan, np.minimum(gap, 5 * MM))
    low = ~np.isnan(wanted)
    assert np.count_nonzero(low) > 40
    assert clearance[-len(beside):][low] == pytest.approx(wanted[low], abs=1e-12)
    assert clearance[-1] == pytest.approx(0.625 * MM, abs=1e-12)


# ---- the tool through the bottom of the block ----


def test_a_tip_below_the_stock_bottom_over_the_stock_warns_once(fmu: Path) -> None:
    """Below stock_z_min beside the block: no warning; a plunge through the block into the fixture below it:
    a warning once (naming the time and the heights in mm), and the reference warns alike."""
    beside = polyline([(-8 * MM, 30 * MM, 5 * MM), (-8 * MM, 30 * MM, -2 * MM)], 0.2 * MM)
    plunge = polyline([(-8 * MM, 30 * MM, -2 * MM), (-8 * MM, 30 * MM, 35 * MM), (20 * MM, 30 * MM, 35 * MM),
                       (20 * MM, 30 * MM, -1 * MM), (20 * MM, 30 * MM, -2 * MM), (30 * MM, 30 * MM, -2 * MM)],
                      0.2 * MM)
    points = chain(beside, plunge)
    parameters = {"flute_length": 0.05}  # the plunge engages the whole 30 mm: no warning of the shank
    rows, slave = run_fmu(fmu, parameters, points)
    slave.unload()
    assert [m.status for m in slave.messages] == [WARNING]
    first = next(k for k, p in enumerate(points) if p[0] == 20 * MM and p[2] < 0)
    assert slave.warnings()[0] == (f"doStep: t = {first * H:g} s: the tool tip went to z = -0.2 mm, below the stock "
                                   "bottom stock_z_min = 0 mm, with the tool over the stock at x = 20 mm, y = 30 mm: "
                                   "the program plunges through the part (into the fixture?) (reported once)")
    expected, zmap = run_reference(parameters, points)
    assert np.array_equal(rows, expected) and zmap.warnings == ["bottom"]
    beside_only = ZMap({}, beside[0])
    for point in beside:
        beside_only.step(point, H)
    assert beside_only.warnings == []


# ---- the final Z-map as a file ----


def run_to_file(path: Path, parameters: dict, points: Sequence[Sequence[float]], zmap_file: str) -> Slave:
    """An instance with zmap_file set, initialized at points[0] and stepped to every point (not terminated)."""
    slave = Slave(path)
    slave.instantiate()
    slave.enter_initialization()
    slave.fmu.setString([slave.vr["zmap_file"]], [zmap_file])
    x, y, z = points[0]
    slave.set({**parameters, "tool_x": x, "tool_y": y, "tool_z": z, "spindle_speed": SPINDLE})
    slave.exit_initialization()
    for x, y, z in points:
        slave.set({"tool_x": x, "tool_y": y, "tool_z": z})
        assert slave.step(H) in (OK, WARNING), slave.messages[-3:]
    return slave


@pytest.mark.parametrize("name", ["flat end mill", "bull nose"])
def test_the_final_zmap_file_holds_the_reference_heights_bit_for_bit(fmu: Path, tmp_path: Path, name: str) -> None:
    """Written at Terminate as an ESRI ASCII grid (square cells: cellsize; the bull-nose grid's are not: dx and
    dy) and read back with read_zmap: the heights and the cell centres are the reference's to the last bit,
    cells cut through the bottom at stock_z_min."""
    parameters, points = PATHS[name]
    target = tmp_path / "final.asc"
    slave = run_to_file(fmu, parameters, points, str(target))
    assert status_of(slave.fmu.terminate) == OK
    slave.unload()
    _, zmap = run_reference(parameters, points)
    x, y, heights = read_zmap(target)
    assert np.array_equal(heights, zmap.heights)
    assert np.array_equal(x, zmap.x0 + (np.arange(zmap.nx) + 0.5) * zmap.dx)
    assert np.array_equal(y, zmap.y0 + (np.arange(zmap.ny) + 0.5) * zmap.dy)
    size = ["cellsize"] if zmap.dx == zmap.dy else ["dx", "dy"]
    header = ["ncols", "nrows", "xllcorner", "yllcorner", *size, "NODATA_value"]
    assert [line.split()[0] for line in target.read_text().splitlines()[:len(header)]] == header
    assert (name == "bull nose") == (size == ["dx", "dy"])
    if name == "bull nose":  # cells cut through the bottom: stock_z_min
        assert np.count_nonzero(heights == zmap.z0) > 100
    assert not (tmp_path / "final.asc.tmp").exists()


COMMA_LOCALES = ("de_DE", "fr_FR", "ru_RU")


@pytest.fixture
def comma_locale(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The process's LC_NUMERIC set to a locale whose decimal point is a comma, restored afterwards: an
    installed one (`locale -a`), else one compiled with localedef from the system's locale sources into a
    temporary LOCPATH (glibc reads it at each setlocale); skips with the reason when neither is possible."""
    import locale
    import os
    import shutil
    import subprocess

    def comma(name: str) -> bool:
        try:
            locale.setlocale(locale.LC_NUMERIC, name)
            return locale.localeconv()["decimal_point"] == ","
        except locale.Error:
            return False

    saved, saved_locpath = locale.setlocale(locale.LC_NUMERIC), os.environ.get("LOCPATH")
    try:
        found = next((f"{n}.UTF-8" for n in COMMA_LOCALES if comma(f"{n}.UTF-8") or comma(f"{n}.utf8")), None)
        sources = Path("/usr/share/i18n/locales")
        if found is None and shutil.which("localedef"):
            folder = tmp_path_factory.mktemp("locales")
            for name in COMMA_LOCALES:
                if (sources / name).exists() and subprocess.run(
                        ["localedef", "-i", name, "-f", "UTF-8", str(folder / f"{name}.UTF-8")],
                        capture_output=True).returncode in (0, 1):  # 1: warnings, the locale is written
                    os.environ["LOCPATH"] = str(folder)
                    if comma(f"{name}.UTF-8"):
                        found = f"{name}.UTF-8"
                        break
        if found is None:
            pytest.skip(f"no locale with a decimal comma: none of {COMMA_LOCALES} is installed (`locale -a`) and "
                        f"localedef cannot compile one from {sources}")
        yield found
    finally:
        if saved_locpath is None:
            os.environ.pop("LOCPATH", None)
        else:
            os.environ["LOCPATH"] = saved_locpath
        locale.setlocale(locale.LC_NUMERIC, saved)


def test_the_zmap_file_s_numbers_use_a_point_in_a_comma_locale(fmu: Path, tmp_path: Path, comma_locale: str) -> None:
    """An importer running with LC_NUMERIC a decimal-comma locale (C's printf then writes 1,5): the file is the
    same as in the C locale, a point in every number, and reads back to the reference's heights bit for bit."""
    import locale
    parameters, points = PATHS["bull nose"]  # dx != dy: the header's dx and dy too
    points = points[:200]
    assert locale.localeconv()["decimal_point"] == "," and "%.1f" % 1.5 == "1.5"  # Python's % ignores it
    target = tmp_path / "final.asc"
    slave = run_to_file(fmu, parameters, points, str(target))
    assert status_of(slave.fmu.terminate) == OK
    slave.unload()
    text = target.read_text()
    assert "," not in text and "." in text
    _, zmap = run_reference(parameters, points)
    x, y, heights = read_zmap(target)
    assert np.array_equal(heights, zmap.heights)
    assert np.array_equal(x, zmap.x0 + (np.arange(zmap.nx) + 0.5) * zmap.dx)


def test_a_relative_zmap_file_is_relative_to_the_working_directory(fmu: Path, tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    points = slot_points((-10 * MM, 30 * MM, 28 * MM), (10 * MM, 30 * MM, 28 * MM))
    slave = run_to_file(fmu, {}, points, "final.asc")
    assert status_of(slave.fmu.terminate) == OK
    slave.unload()
    _, _, heights = read_zmap(tmp_path / "final.asc")
    assert np.array_equal(heights, run_reference({}, points)[1].heights)


def test_no_zmap_file_by_default(fmu: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    rows, slave = run_fmu(fmu, {}, slot_points((-10 * MM, 30 * MM, 28 * MM), (10 * MM, 30 * MM, 28 * MM)))
    assert status_of(slave.fmu.terminate) == OK
    slave.unload()
    assert list(tmp_path.iterdir()) == []


def test_a_zmap_file_that_cannot_be_written_is_an_error_at_terminate(fmu: Path, tmp_path: Path) -> None:
    """A missing folder, a folder in the way of the final name (the rename fails) and a full disk (/dev/full
    behind the temporary name): Terminate returns Error naming zmap_file, the path and the system's reason;
    no temporary file is left and a file already under the final name keeps its content."""
    points = slot_points((-10 * MM, 30 * MM, 28 * MM), (10 * MM, 30 * MM, 28 * MM))
    terminate = "fmi3Terminate" if "fmi2" not in fmu.name else "fmi2Terminate"
    missing = tmp_path / "missing" / "final.asc"
    folder = tmp_path / "folder"
    folder.mkdir()
    cases = [(missing, f"{terminate}: zmap_file = '{missing}': cannot create '{missing}.tmp': No such file or "
              "directory"),
             (folder, f"{terminate}: zmap_file = '{folder}': cannot rename '{folder}.tmp' to '{folder}': Is a "
              "directory")]
    if Path("/dev/full").exists():
        full = tmp_path / "full.asc"
        full.write_text("the earlier Z-map\n")
        (tmp_path / "full.asc.tmp").symlink_to("/dev/full")
        cases.append((full, f"{terminate}: zmap_file = '{full}': cannot write '{full}.tmp': No space left on device"))
    for target, message in cases:
        slave = run_to_file(fmu, {}, points, str(target))
        assert status_of(slave.fmu.terminate) == ERROR
        assert slave.last_error() == message
        slave.unload()
        assert not Path(f"{target}.tmp").exists()
    assert not missing.parent.exists() and folder.is_dir() and list(folder.iterdir()) == []
    if Path("/dev/full").exists():
        assert full.read_text() == "the earlier Z-map\n"


BAD_ZMAP_FILES = {
    "no header": ("1 2 3\n", "line 1: the header has no 'ncols' (an ESRI ASCII grid?)"),
    "header value not a number": ("ncols 2\nnrows x\n", "line 2: 'x' is not a number"),
    "header line without its number": ("ncols 2\nnrows\n", "line 2: 'nrows': a header line is a key and a number"),
    "no cell size": ("ncols 2\nnrows 1\nxllcorner 0\nyllcorner 0\n1 2\n",
                     "line 5: the header has neither 'cellsize' nor 'dx' and 'dy'"),
    "a row too short": ("ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 2\n3\n",
                        "line 7: 1 values, ncols = 2"),
    "a value not a number": ("ncols 2\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n1 z\n",
                             "line 6: 'z' is not a number"),
    "rows missing": ("ncols 1\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n",
                     "line 7: the file ends after 1 of nrows = 3 rows"),
    "rows too many": ("ncols 1\nnrows 1\nxllcorner 0\nyllcorner 0\ncellsize 1\n1\n2\n",
                      "line 7: more than nrows = 1 rows"),
}


@pytest.mark.parametrize("case", BAD_ZMAP_FILES)
def test_read_zmap_names_the_file_and_line_of_a_malformed_file(tmp_path: Path, case: str) -> None:
    text, message = BAD_ZMAP_FILES[case]
    path = tmp_path / "bad.asc"
    path.write_text(text)
    with pytest.raises(ZMapFileError) as raised:
        read_zmap(path)
    assert str(raised.value) == f"{path} {message}"


def test_read_zmap_reads_gdal_s_variants(tmp_path: Path) -> None:
    """Cell centres given (xllcenter), keys in upper case, NODATA cells as NaN; rows from north to south."""
    path = tmp_path / "centres.asc"
    path.write_text("NCOLS 3\nNROWS 2\nXLLCENTER 1.5\nYLLCENTER -2\nDX 0.5\nDY 2\nNODATA_VALUE -1\n"
                    "1 2 3\n4 -1 6\n")
    x, y, heights = read_zmap(path)
    assert np.array_equal(x, [1.5, 2.0, 2.5]) and np.array_equal(y, [-2.0, 0.0])
    assert np.array_equal(heights, [[4, np.nan, 6], [1, 2, 3]], equal_nan=True)


# ---- removed volume against the exact volume of straight slots ----
#
# Resolution error. A cell is cut to the exact tool surface at its centre, so the Z-map's removed
# volume is the midpoint rule of the cut's depth over the cells. For a flat end mill (constant depth
# a_p) only the cells that the cut's outline passes through can be wrong, each by at most its own
# volume: |V - V_exact| <= a_p * dx * dy * N_outline, and a monotone piece of outline with extents
# (Lx, Ly) passes through at most Lx/dx + Ly/dy + 1 cells. Where the outline follows cell
# boundaries the volume is exact. For a ball end mill the depth profile across the slot (depth a,
# width 2w, wall slope s = w / (R - a) at its edges) adds the midpoint rule's error across the rows,
# per unit length at most dy^2 (2 s + w max|f''| / 12) with max|f''| = R^2 / (R - a)^3.


def slot_points(start: Sequence[float], end: Sequence[float], feed: float = 0.2 * MM) -> list:
    return polyline([start, end], feed)


def outline_cells(pieces: Sequence[tuple[float, float]], dx: float, dy: float) -> float:
    """Upper bound of the cells crossed by monotone outline pieces of extents (Lx, Ly)."""
    return sum(lx / dx + ly / dy + 1 for lx, ly in pieces)


def test_through_slot_along_cell_boundaries_removes_the_exact_volume(fmu: Path) -> None:
    """A 10 mm slot, 3 mm deep, through the whole 100 mm block with its walls on cell boundaries:
    exactly 40 rows of 400 cells are cut to exactly 3 mm."""
    points = slot_points((-10 * MM, 30 * MM, 27 * MM), (110 * MM, 30 * MM, 27 * MM))
    rows, slave = run_fmu(fmu, {}, points)
    slave.unload()
    exact = 100 * MM * 10 * MM * 3 * MM
    assert removed_volume(rows) == pytest.approx(exact, rel=1e-12)
    assert rows[-1, OUTPUTS.index("removed_volume")] == pytest.approx(exact, rel=1e-12)
    # steady state: slotting, full depth and width, MRR = a_p D v_f on average over whole cells
    steady = rows[100:-100]
    assert np.all(steady[:, OUTPUTS.index("axial_depth")] == pytest.approx(3 * MM, rel=1e-12))
    assert np.all(steady[:, OUTPUTS.index("radial_depth")] == 10 * MM)
    cells = 2 * 0.25 * MM / (0.2 * MM)  # steps per two cells
    window = int(round(cells * 10))
    assert np.mean(steady[:window, OUTPUTS.index("mrr")]) == pytest.approx(3 * MM * 10 * MM * 0.2 * MM / H, rel=1e-9)


@pytest.mark.parametrize("angle", [0.0, 30.0], ids=["along x, off the grid", "diagonal 30 deg"])
def test_slot_volume_equals_the_exact_volume_within_the_resolution_error(angle: float) -> None:
    """A 10 mm flat end mill, 2 mm deep, entering the block through its -x face and stopping 60 mm
    further inside: the removed volume is a_p (2 R L + pi R^2 / 2) within a_p dx dy N_outline."""
    radius, length, depth, resolution = 5 * MM, 60 * MM, 2 * MM, 0.25 * MM
    u = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle)), 0.0])
    origin = np.array([0.0, 30.1 * MM if angle == 0 else 20 * MM, TOP - depth])
    points = slot_points(origin - 10 * MM * u, origin + length * u)
    rows, zmap = run_reference({"resolution": resolution}, points)
    fmu_rows, slave = run_fmu(require_fmu(FMUS[0]), {"resolution": resolution}, points)
    slave.unload()
    assert np.array_equal(fmu_rows, rows)
    exact = depth * (2 * radius * length + math.pi * radius ** 2 / 2)
    # outline inside the block: the two walls and the half circle at the end (3 monotone pieces at most)
    walls = [(length * abs(u[0]), length * abs(u[1]))] * 2
    end = [(radius, radius)] * 3
    bound = depth * zmap.dx * zmap.dy * outline_cells(walls + end, zmap.dx, zmap.dy)
    error = removed_volume(rows) - exact
    assert abs(error) <= bound, (error, bound)
    assert bound / exact < (0.06 if angle == 0 else 0.08)  # the stated resolution error: 5.9 % and 7.6 %
    assert abs(error) / exact < 1e-3  # what it is: the boundary cells' errors mostly cancel


def test_ball_end_slot_volume_within_the_resolution_error(fmu: Path) -> None:
    """An 8 mm ball end mill, 1.5 mm deep, through the block along x off the grid: the removed volume
    is the circular segment's area times 100 mm, within the midpoint rule's error across the rows."""
    radius, depth = 4 * MM, 1.5 * MM
    parameters = {"tool_diameter": 2 * radius, "corner_radius": radius, "resolution": 0.25 * MM}
    points = slot_points((-10 * MM, 30.07 * MM, TOP - depth), (110 * MM, 30.07 * MM, TOP - depth))
    rows, slave = run_fmu(fmu, parameters, points)
    slave.unload()
    zmap = ZMap(parameters, points[0])
    half_width = math.sqrt(2 * radius * depth - depth ** 2)
    area = radius ** 2 * math.acos((radius - depth) / radius) - (radius - depth) * half_width
    exact = area * 100 * MM
    slope = half_width / (radius - depth)
    curvature = radius ** 2 / (radius - depth) ** 3
    bound = 100 * MM * zmap.dy ** 2 * (2 * slope + half_width * curvature / 12)
    error = removed_volume(rows) - exact
    assert abs(error) <= bound, (error, bound)
    assert abs(error) / exact < 2e-3
    steady = rows[200:-200]
    assert np.all(steady[:, OUTPUTS.index("axial_depth")] == pytest.approx(depth, rel=1e-12))
    # the slot's width at the top: 2 w, both walls resolved within half a cell plus the sampling
    assert np.all(np.abs(steady[:, OUTPUTS.index("radial_depth")] - 2 * half_width) <= zmap.dy)
    assert np.all(steady[:, OUTPUTS.index("entry_angle")] == 0.0)
    assert np.all(steady[:, OUTPUTS.index("exit_angle")] == math.pi)
    front = [map_name(i, j) for i in range(N_Z) for j in range(N_THETA // 2)]
    assert np.all(steady[:, [OUTPUTS.index(n) for n in front]] == 1.0)


# ---- entry and exit angles, depths, engagement map ----


def engagement_after(parameters: dict, points: list, steps: int = 60) -> dict[str, np.ndarray]:
    """The outputs over the last ``steps`` steps of the FMU (FMI 3) on the path, by name."""
    rows, slave = run_fmu(require_fmu(FMUS[0]), parameters, points)
    slave.unload()
    return {name: rows[-steps:, k] for k, name in enumerate(OUTPUTS)}


def angle_tolerance(zmap: ZMap, phi: float, wall_cut_by_cells: bool) -> float:
    """Stated accuracy of an entry/exit angle phi where the cutter meets a wall parallel to the
    feed: the wall's lateral position is resolved to half a cell if cells were cut to make it (to 0
    for a face of the block), plus the bisection's 1/1024 of an angle sample on the test circle of
    radius R + delta, seen from the cutter's circle."""
    sampling = (zmap.radius + zmap.delta) * math.pi / zmap.n_angles / 1024
    lateral = (0.5 * zmap.dy if wall_cut_by_cells else 0.0) + sampling
    return lateral / (zmap.radius * max(abs(math.sin(phi)), 0.2)) + 1e-12


def test_slotting_engages_the_whole_front_half(fmu: Path) -> None:
    points = slot_points((-10 * MM, 30.1 * MM, 27.5 * MM), (50 * MM, 30.1 * MM, 27.5 * MM))
    rows, slave = run_fmu(fmu, {}, points)
    slave.unload()
    out = {name: rows[-50:, k] for k, name in enumerate(OUTPUTS)}
    assert np.all(out["entry_angle"] == 0.0) and np.all(out["exit_angle"] == math.pi)
    assert np.all(out["axial_depth"] == pytest.approx(2.5 * MM, rel=1e-12))
    assert np.all(out["radial_depth"] == 10 * MM)
    for i in range(N_Z):
        for j in range(N_THETA):
            expected = 1.0 if (j + 0.5) * 2 * math.pi / N_THETA < math.pi else 0.0
            assert np.all(out[map_name(i, j)] == expected), map_name(i, j)


@pytest.mark.parametrize("mode", ["down", "up"])
@pytest.mark.parametrize("radial", [5.0, 2.0, 8.0])
def test_side_milling_against_a_face_of_the_block(mode: str, radial: float) -> None:
    """Feed +x along the block's +y face (down milling: material on the -y side, Altintas: entry
    pi - acos((R - a_e)/R), exit pi) or its -y face (up milling: entry 0, exit acos((R - a_e)/R))."""
    radius, ae = 5 * MM, radial * MM
    y = 60 * MM - ae + radius if mode == "down" else ae - radius
    points = slot_points((-10 * MM, y, 28 * MM), (50 * MM, y, 28 * MM), 0.05 * MM)
    out = engagement_after({}, points)
    zmap = ZMap({}, points[0])
    if mode == "down":
        entry, exit_ = math.pi - math.acos((radius - ae) / radius), math.pi
    else:
        entry, exit_ = 0.0, math.acos((radius - ae) / radius)
    assert np.all(np.abs(out["entry_angle"] - entry) <= angle_tolerance(zmap, entry, False))
    assert np.all(np.abs(out["exit_angle"] - exit_) <= angle_tolerance(zmap, exit_, False))
    assert np.all(np.abs(out["radial_depth"] - ae) <= 1e-3 * MM)
    assert np.all(out["axial_depth"] == pytest.approx(2 * MM, rel=1e-12))
    if radial == 5.0:  # half immersion: the map's columns of (pi/2, pi) or (0, pi/2)
        for j in range(N_THETA):
            phi = (j + 0.5) * 2 * math.pi / N_THETA
            engaged = (math.pi / 2 < phi < math.pi) if mode == "down" else phi < math.pi / 2
            for i in range(N_Z):
                assert np.all(out[map_name(i, j)] == float(engaged)), (map_name(i, j), phi)


def test_half_immersion_down_milling_next_to_a_previous_pass(fmu: Path) -> None:
    """A slot, then a parallel pass 5 mm to its -y side: half immersion down milling against the wall
    the Z-map cut (entry pi/2, exit pi), resolved to half a cell."""
    y = 30.1 * MM
    points = chain(slot_points((-10 * MM, y, 28 * MM), (70 * MM, y, 28 * MM), 0.2 * MM),
                   slot_points((70 * MM, y, 35 * MM), (-10 * MM, y - 5 * MM, 35 * MM), 1.0 * MM),
                   slot_points((-10 * MM, y - 5 * MM, 28 * MM), (50 * MM, y - 5 * MM, 28 * MM), 0.05 * MM))
    rows, slave = run_fmu(fmu, {}, points)
    slave.unload()
    out = {name: rows[-100:, k] for k, name in enumerate(OUTPUTS)}
    zmap = ZMap({}, points[0])
    assert np.all(np.abs(out["entry_angle"] - math.pi / 2) <= angle_tolerance(zmap, math.pi / 2, True))
    assert np.all(out["exit_angle"] == math.pi)
    assert np.all(np.abs(out["radial_depth"] - 5 * MM) <= 0.5 * zmap.dy + 1e-3 * MM)


@pytest.mark.parametrize("tool", ["flat", "ball"])
@pytest.mark.parametrize("angle", [0.0, 30.0])
def test_retracing_a_cut_is_no_engagement(fmu: Path, tool: str, angle: float) -> None:
    """A slot, then the same slot again (a spring pass): the second pass cuts nothing and reports no
    engagement, although the slot's walls touch the cutter along both flanks, and up to the end of the first
    cut, whose end wall the test circle sees over the last sqrt(2 R delta) (1.6 mm here): the tool lowers no
    cell, so there is no cut top."""
    parameters = {"corner_radius": 5 * MM} if tool == "ball" else {}
    u = np.array([math.cos(math.radians(angle)), math.sin(math.radians(angle)), 0.0])
    origin = np.array([0.0, 20.1 * MM, 28 * MM])
    a, b = origin - 10 * MM * u, origin + 50 * MM * u
    lifted = [(p[0], p[1], 35 * MM) for p in (b, a)]
    slot = slot_points(a, b, 0.1 * MM)
    rows, slave = run_fmu(fmu, parameters, chain(slot, slot_points(*lifted, 1.0 * MM), slot))
    slave.unload()
    first, again = rows[:len(slot)], rows[-len(slot):]
    assert np.max(first[:, OUTPUTS.index("radial_depth")]) > 0
    assert not np.any(again[:, STEP_OUTPUTS])
    assert np.all(again[:, OUTPUTS.index("mrr")] == 0.0)


def test_tracing_a_pocket_s_loop_again_is_no_engagement_up_to_its_corners(fmu: Path) -> None:
    """A rectangular loop cut at 1.5 mm (a pocket's walls), then the same loop again at that depth, as the
    plate's pocket levels end: the second loop cuts nothing and reports no engagement, also where it runs into
    each corner, whose uncut fillet (at the tool radius about the corner point) the test circle sees over the
    last half millimetre, and where it stops there (the test points alone gave the fillet's height there)."""
    corners = [(30 * MM, 20 * MM), (60 * MM, 20 * MM), (60 * MM, 40 * MM), (30 * MM, 40 * MM), (30 * MM, 20 * MM)]
    points, slices = levels(corners, [1.5 * MM, 1.5 * MM], 0.1 * MM)
    rows = run_both(fmu, {}, points)
    first, again = rows[slices[0]], rows[slices[1]]
    assert np.count_nonzero(first[:, OUTPUTS.index("axial_depth")]) > 0.9 * len(first)
    assert np.all(again[:, OUTPUTS.index("mrr")] == 0.0)
    assert not np.any(again[:, STEP_OUTPUTS])


# ---- second levels: a path cut again deeper reports the layer it cuts ----


def run_both(fmu: Path, parameters: dict, points: list) -> np.ndarray:
    """The FMU's rows on the path, asserted equal to the reference's to the last bit."""
    actual, slave = run_fmu(fmu, parameters, points)
    slave.unload()
    expected, _ = run_reference(parameters, points)
    differ = np.argwhere(actual != expected)
    assert not differ.size, (f"{len(differ)} values differ, first at step {differ[0][0]} output "
                             f"{OUTPUTS[differ[0][1]]}: {actual[tuple(differ[0])]!r} != {expected[tuple(differ[0])]!r}")
    return expected


def levels(path: Sequence[Sequence[float]], depths: Sequence[float], feed: float = 0.2 * MM) -> tuple[list, list]:
    """The waypoints (x, y) cut at each depth below the top in turn, lifted 5 mm above the block between
    the levels; returns the points and, per level, the slice of the points on it."""
    points, slices = [], []
    for depth in depths:
        piece = polyline([(x, y, TOP - depth) for x, y in path], feed)
        lift = [(path[0][0], path[0][1], TOP + 5 * MM)]
        if points:
            points += polyline([points[-1], (points[-1][0], points[-1][1], TOP + 5 * MM)] + lift, 1.0 * MM)[1:]
            points += polyline([lift[0], piece[0]], 1.0 * MM)[1:-1]
        slices.append(slice(len(points), len(points) + len(piece)))
        points += piece
    return points, slices


def on_level(rows: np.ndarray, points: list, level: slice, inside) -> dict[str, np.ndarray]:
    """The outputs at the level's points for which inside(x, y) holds, by name."""
    chosen = [k for k in range(level.start, level.stop) if inside(points[k][0] / MM, points[k][1] / MM)]
    assert len(chosen) > 20
    return {name: rows[chosen, k] for k, name in enumerate(OUTPUTS)}


@pytest.mark.parametrize("tool,angle,depths", [("flat", 0.0, (1.5, 3.0)), ("flat", 30.0, (1.0, 2.5)),
                                               ("flat", 0.0, (1.5, 3.0, 4.5)), ("ball", 0.0, (1.5, 3.0))])
def test_a_slot_cut_again_deeper_reports_the_layer(fmu: Path, tool: str, angle: float, depths: tuple) -> None:
    """A slot at depth d1, then the same path at d2 > d1 (the levels of a roughing program): the walls the
    first level left at the tool radius stand above the layer along both flanks, but only the layer is
    cut: axial_depth = d2 - d1 (the first level's floor is flat: exact up to rounding, also diagonally
    to the grid), entry 0, exit pi, the front half of the map engaged; the first level as before. A ball
    end mill widens the groove at its top edges, so there the second level cuts up to the stock top: d2."""
    parameters = {"corner_radius": 5 * MM} if tool == "ball" else {}
    u = (math.cos(math.radians(angle)), math.sin(math.radians(angle)))
    origin = (0.0, 30.1 * MM if angle == 0 else 20 * MM)
    path = [(origin[0] - 10 * MM * u[0], origin[1] - 10 * MM * u[1]),
            (origin[0] + 60 * MM * u[0], origin[1] + 60 * MM * u[1])]
    points, slices = levels(path, [d * MM for d in depths])
    rows = run_both(fmu, parameters, points)
    front = [map_name(i, j) for i in range(N_Z) for j in range(N_THETA // 2)]
    for level, (above, depth) in enumerate(zip((0.0,) + depths, depths)):
        steady = rows[slices[level]][100:-50]  # from 10 mm inside the block to 10 mm before the end
        out = {name: steady[:, k] for k, name in enumerate(OUTPUTS)}
        layer = depth if tool == "ball" else depth - above
        assert np.all(out["axial_depth"] == pytest.approx(layer * MM, rel=1e-12)), np.unique(out["axial_depth"])
        assert np.all(out["entry_angle"] == 0.0) and np.all(out["exit_angle"] == math.pi)
        if tool == "flat" or level == 0:
            assert np.all(steady[:, [OUTPUTS.index(n) for n in front]] == 1.0)
        if tool == "flat":
            assert np.all(out["radial_depth"] == 10 * MM)
        elif level > 0:  # the ball's crescent: all engaged below the first level's floor, above it the flanks
            below = [map_name(i, j) for i in range(N_Z) for j in range(N_THETA // 2)
                     if (i + 0.5) * layer / N_Z < depth - above]
            assert np.all(steady[:, [OUTPUTS.index(n) for n in below]] == 1.0)
            top_row = {j: out[map_name(N_Z - 1, j)] for j in range(N_THETA // 2)}
            assert np.all(top_row[0] == 1.0) and np.all(top_row[N_THETA // 2 - 1] == 1.0)
            assert not np.any(top_row[N_THETA // 4 - 1]) and not np.any(top_row[N_THETA // 4])


@pytest.mark.parametrize("path_radius", [10.0, 5.0, 3.5])
def test_an_arc_cut_again_deeper_reports_the_layer(fmu: Path, path_radius: float) -> None:
    """Three quarters of a circle of path radius 2R, R and 0.7 R (R = 5 mm) at 1.5 mm, then at 3 mm: the
    first level's outer wall along the arc meets the probe circle delta (R + delta/2) / path radius farther
    inside the cutter's radius than a straight wall does (0.13, 0.26 and 0.37 mm here, on top of the half cell
    diagonal of the cells' rounding, 0.18 mm), and the heights come from the points farther in than
    arc_margin (made for path radii down to R/2: 0.69 mm on this grid): the layer, 1.5 mm,
    along the arc (taking the cutting points' heights gave 3 mm over 14 %, 69 % and 92 % of it), but for its
    last 4 mm, where the end wall of the first level's arc comes into view."""
    rho, centre = path_radius * MM, (50 * MM, 30 * MM)
    points, slices = [], []
    for depth in (1.5 * MM, 3.0 * MM):
        turn = arc(centre, rho, -math.pi / 2, 0.75 * 1.5 * math.pi, TOP - depth, 0.1 * MM)
        lead = polyline([(30 * MM, centre[1] - rho, TOP - depth), turn[0]], 0.1 * MM)
        points = chain(points, lead, turn) if points else chain(lead, turn)
        slices.append(slice(len(points) - len(turn), len(points) - 40))  # not the last 4 mm: the end wall
        points = chain(points, [(points[-1][0], points[-1][1], TOP + 5 * MM)])
    rows = run_both(fmu, {}, points)
    for level in range(2):
        axial = rows[slices[level], OUTPUTS.index("axial_depth")]
        assert np.all(axial == pytest.approx(1.5 * MM, rel=1e-12)), (level, np.unique(axial))


@pytest.mark.parametrize("radial", [0.3, 0.6])
def test_a_thin_side_cut_reports_its_height(fmu: Path, radial: float) -> None:
    """A finishing cut 0.3 or 0.6 mm wide along the block's -y face, 2 mm deep: its cutting points all lie
    within arc_margin of the radius (none farther in), so its height is theirs: 2 mm, the radial depth
    a_e within a thousandth of a mm (up milling: entry 0)."""
    radius, ae = 5 * MM, radial * MM
    points = slot_points((-10 * MM, ae - radius, 28 * MM), (50 * MM, ae - radius, 28 * MM), 0.1 * MM)
    rows = run_both(fmu, {}, points)
    zmap = ZMap({}, points[0])
    assert zmap.half_diagonal < ae < zmap.arc_margin
    out = {name: rows[-200:, k] for k, name in enumerate(OUTPUTS)}
    assert np.all(out["axial_depth"] == pytest.approx(2 * MM, rel=1e-12))
    assert np.all(out["entry_angle"] == 0.0)
    assert np.all(np.abs(out["radial_depth"] - ae) <= 1e-3 * MM)


def test_a_pocket_s_second_level_reports_the_layer(fmu: Path) -> None:
    """A pocket roughed in two levels (1.5 mm, then 4 mm): a loop around the 30 x 20 mm rectangle of
    the tool's path, then a loop offset 3 mm inside it, on each level. On the second level the outer
    loop's sides slot through the layer (2.5 mm; entry 0, exit pi) along the pocket's wall; the inner
    loop's sides cut a 3 mm wide strip of it beside the outer loop's cut (entry 0, exit acos((R - 3)/R),
    the radial depth within half a cell), with the first level's wall or island at the radius on their
    other side. Along the middle of the bottom sides (fed +x)."""
    def loop(inset: float) -> list:
        x0, y0, x1, y1 = 30 + inset, 20 + inset, 60 - inset, 40 - inset
        return [(x * MM, y * MM) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))]

    points, slices = levels(loop(0.0) + loop(3.0), [1.5 * MM, 4.0 * MM])
    rows = run_both(fmu, {}, points)
    zmap = ZMap({}, points[0])
    ae_exit = math.acos((5 - 3) / 5)
    for level, layer in enumerate((1.5, 2.5)):
        outer = on_level(rows, points, slices[level], lambda x, y: y == pytest.approx(20) and 38 < x < 50)
        inner = on_level(rows, points, slices[level], lambda x, y: y == pytest.approx(23) and 38 < x < 50)
        for out in (outer, inner):
            assert np.all(out["axial_depth"] == pytest.approx(layer * MM, rel=1e-12)), np.unique(out["axial_depth"])
            assert np.all(out["entry_angle"] == 0.0)
        assert np.all(outer["exit_angle"] == math.pi) and np.all(outer["radial_depth"] == 10 * MM)
        assert np.all(np.abs(inner["exit_angle"] - ae_exit) <= angle_tolerance(zmap, ae_exit, True))
        assert np.all(np.abs(inner["radial_depth"] - 3 * MM) <= 0.5 * zmap.dy + 1e-3 * MM)


def test_a_pocket_s_second_level_reports_the_layer_up_to_the_corners_of_its_loops(fmu: Path) -> None:
    """A pocket roughed in two levels (1.5 mm, then 3 mm) as the bracket's: a loop 3 mm inside the 30 x 20 mm
    rectangle of the tool's path, a diagonal out to its corner, the loop around it, then a retract at the corner.
    Running into each corner of the outer loop the tool has the pocket's wall, which the first level left at the
    tool radius about the corner point, ahead within the test offset, but cuts only the layer: 1.5 mm on every
    engaged step of the second level, up to every corner and into the corner it closes the loop in (the test
    points alone gave 3 mm over the last 0.4-0.6 mm before each corner), and nothing while it retracts: a
    vertical rise that lowers no cell cuts nothing (the test points alone gave 2.9 mm, the cut top alone the
    layer shrinking to 0)."""
    def loop(inset: float) -> list:
        x0, y0, x1, y1 = 30 + inset, 20 + inset, 60 - inset, 40 - inset
        return [(x * MM, y * MM) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0))]

    points, slices = levels(loop(3.0) + loop(0.0), [1.5 * MM, 3.0 * MM], 0.1 * MM)
    retract = polyline([points[-1], (points[-1][0], points[-1][1], TOP + 2 * MM)], 0.1 * MM)[1:]
    rows = run_both(fmu, {}, points + retract)
    axial = rows[:, OUTPUTS.index("axial_depth")]
    for level in range(2):
        engaged = axial[slices[level]][axial[slices[level]] > 0]
        assert len(engaged) > 0.9 * (slices[level].stop - slices[level].start)
        assert np.all(engaged == pytest.approx(1.5 * MM, rel=1e-12)), (level, np.unique(engaged))
    assert not np.any(rows[-len(retract):, STEP_OUTPUTS]), np.max(axial[-len(retract):])


def test_a_second_level_entering_the_first_level_s_corner_reports_the_layer(fmu: Path) -> None:
    """An outside profile cut in two levels (4 mm, then 8 mm) as the bracket's: from beside the block a diagonal
    move into its corner, then 1 mm off its -x face. On the second level the move enters the corner the first level
    cut, with that level's wall 1 mm off the face in view: it cuts the 4 mm layer, and reports it on every engaged
    step (the test points alone gave 8 mm over the entry's last 0.4 mm and the last 0.6 mm before the end of the
    first level's cut)."""
    path = [(-10 * MM, -10 * MM), (-4 * MM, 0.5 * MM), (-4 * MM, 40 * MM)]
    points, slices = levels(path, [4.0 * MM, 8.0 * MM], 0.1 * MM)
    rows = run_both(fmu, {}, points)
    axial = rows[:, OUTPUTS.index("axial_depth")]
    for level, layer in enumerate((4.0, 4.0)):
        engaged = axial[slices[level]][axial[slices[level]] > 0]
        assert len(engaged) > 300
        assert np.all(engaged == pytest.approx(layer * MM, rel=1e-12)), (level, np.unique(engaged))


def test_a_step_down_into_full_height_material_is_reported_when_the_tool_cuts_it(fmu: Path) -> None:
    """A slot at 1.5 mm ending at x = 40 mm, then the same path at 3 mm on to x = 80 mm: beyond the first level's
    end wall (the tool radius about its end point) the material stands the full 3 mm. The second level reports the
    layer, 1.5 mm, up to the step that first lowers a cell of that material, and the full 3 mm from that step on:
    the cut top rises at once, with no window to wait for. That step comes within a cell of travel of the cutter's
    contact at x = 40 mm (the test points alone gave 3 mm from x = 39.4 mm, where the cutter cuts only the layer)."""
    y = 30.1 * MM
    first, _ = levels([(-10 * MM, y), (40 * MM, y)], [1.5 * MM])
    second = polyline([(-10 * MM, y, TOP - 3 * MM), (80 * MM, y, TOP - 3 * MM)], 0.1 * MM)
    points = chain(first, polyline([(40 * MM, y, TOP + 5 * MM), (-10 * MM, y, TOP + 5 * MM)], 1.0 * MM), second)
    rows = run_both(fmu, {}, points)
    zmap = ZMap({}, points[0])
    contact = None  # the first step of the second level that lowers a cell of the full height
    start = len(points) - len(second)
    for k, point in enumerate(points):
        full = np.count_nonzero(zmap.heights == TOP)
        zmap.step(point, H, SPINDLE)
        if contact is None and k >= start and np.count_nonzero(zmap.heights == TOP) < full:
            contact = k
    assert contact is not None and 40 * MM < points[contact][0] <= 40 * MM + zmap.dx + 0.1 * MM
    axial = rows[:, OUTPUTS.index("axial_depth")]
    before = axial[start + 100:contact]  # from x = 0 on (the block's face)
    assert np.all(before == pytest.approx(1.5 * MM, rel=1e-12)), np.unique(before)
    assert np.all(axial[contact:] == pytest.approx(3.0 * MM, rel=1e-12)), np.unique(axial[contact:])


@pytest.mark.parametrize("mode", ["down", "up"])
def test_a_side_cut_along_the_wall_an_earlier_level_left_reports_the_layer(fmu: Path, mode: str) -> None:
    """A 3 mm wide side cut along a face of the block at 1.5 mm, then at 4 mm on the same path: on the
    second level the first level's wall stands 4 mm high at the radius on the material side, the
    cut is the 2.5 mm layer with the angles of the first (Altintas: down milling entry pi - acos((R -
    a_e)/R), exit pi; up milling entry 0, exit acos((R - a_e)/R)) and the radial depth a_e."""
    radius, ae = 5 * MM, 3 * MM
    y = 60 * MM - ae + radius if mode == "down" else ae - radius
    points, slices = levels([(-10 * MM, y), (60 * MM, y)], [1.5 * MM, 4.0 * MM], 0.1 * MM)
    rows = run_both(fmu, {}, points)
    zmap = ZMap({}, points[0])
    if mode == "down":
        entry, exit_ = math.pi - math.acos((radius - ae) / radius), math.pi
    else:
        entry, exit_ = 0.0, math.acos((radius - ae) / radius)
    for level, layer in enumerate((1.5, 2.5)):
        out = on_level(rows, points, slices[level], lambda x, _: 10 < x < 50)
        assert np.all(out["axial_depth"] == pytest.approx(layer * MM, rel=1e-12)), np.unique(out["axial_depth"])
        assert np.all(np.abs(out["entry_angle"] - entry) <= angle_tolerance(zmap, entry, False))
        assert np.all(np.abs(out["exit_angle"] - exit_) <= angle_tolerance(zmap, exit_, False))
        assert np.all(np.abs(out["radial_depth"] - ae) <= 1e-3 * MM)


def test_a_pass_beside_a_deeper_slot_reports_its_own_depth(fmu: Path) -> None:
    """A 4 mm deep slot, then a pass 1.5 mm deep offset 2.5 mm to its +y side (feed +x): the deeper slot's
    wall is the edge of the new cut and lies below its tip on the slot's side; the pass cuts the stock
    top over 2.5 mm (up milling: entry 0, exit acos((R - 2.5)/R) within half a cell): 1.5 mm, neither the
    slot's depth nor more."""
    y = 30.1 * MM
    first, _ = levels([(-10 * MM, y), (110 * MM, y)], [4.0 * MM])
    second = polyline([(-10 * MM, y + 2.5 * MM, TOP - 1.5 * MM), (60 * MM, y + 2.5 * MM, TOP - 1.5 * MM)], 0.1 * MM)
    points = chain(first, polyline([(110 * MM, y, TOP + 5 * MM), (-10 * MM, y + 2.5 * MM, TOP + 5 * MM)], 1.0 * MM),
                   second)
    rows = run_both(fmu, {}, points)
    zmap = ZMap({}, points[0])
    out = {name: rows[-100:, k] for k, name in enumerate(OUTPUTS)}
    exit_ = math.acos(0.5)
    assert np.all(out["axial_depth"] == pytest.approx(1.5 * MM, rel=1e-12))
    assert np.all(out["entry_angle"] == 0.0)
    assert np.all(np.abs(out["exit_angle"] - exit_) <= angle_tolerance(zmap, exit_, True))
    assert np.all(np.abs(out["radial_depth"] - 2.5 * MM) <= 0.5 * zmap.dy + 1e-3 * MM)


# ---- what is not an error, and what is ----


def test_tool_above_the_stock_gives_zero_engagement(fmu: Path) -> None:
    """A 'negative depth of cut' (tool tip above the block, or beside it) is no error: nothing is cut."""
    points = chain(slot_points((-10 * MM, 30 * MM, TOP + 0.5 * MM), (110 * MM, 30 * MM, TOP + 0.5 * MM), 0.5 * MM),
                   slot_points((110 * MM, 30 * MM, 20 * MM), (110 * MM, -20 * MM, 20 * MM), 0.5 * MM))  # beside
    rows, slave = run_fmu(fmu, {}, points)
    assert not slave.messages
    slave.unload()
    assert not np.any(rows[:, STEP_OUTPUTS]) and not np.any(rows[:, OUTPUTS.index("removed_volume")])
    clearance = rows[:, OUTPUTS.index("clearance")]  # 0.5 mm above the top (towards its edge: more), beside it
    x = np.array([p[0] for p in points])
    assert np.all((clearance >= 0.5 * MM - 1e-12) & (clearance <= 5 * MM))
    over = (x > 5 * MM) & (x < 95 * MM) & (np.array([p[2] for p in points]) > TOP)
    assert np.count_nonzero(over) > 150 and clearance[over] == pytest.approx(0.5 * MM, abs=1e-12)


def initialize_with(path: Path, parameters: dict) -> Slave:
    slave = Slave(path)
    slave.instantiate()
    slave.enter_initialization()
    slave.set(parameters)
    return slave


BAD_CONFIGURATIONS = {
    "tool larger than the stock": ({"tool_diameter": 0.08}, "the tool is larger than the stock: tool_diameter = "
                                   "0.08 m, stock_length = 0.1 m, stock_width = 0.06 m"),
    "resolution too fine": ({"resolution": 1e-5}, "resolution = 1e-05 m is too fine for the stock: 10000 x 6000 "
                            "cells, more than the limit of 20000000 cells (160 MB); use resolution >= 1.73285e-05 m"),
    "resolution too coarse": ({"resolution": 0.004}, "resolution = 0.004 m is too coarse for tool_diameter = 0.01 m: "
                              "the Z-map needs at least 4 cells across the tool (resolution <= 0.0025 m)"),
    "corner radius beyond the radius": ({"corner_radius": 0.006}, "corner_radius = 0.006 m is larger than "
                                        "tool_diameter/2 = 0.005 m (0: flat end mill, tool_diameter/2: ball end mill)"),
}


@pytest.mark.parametrize("case", BAD_CONFIGURATIONS)
def test_bad_configurations_are_rejected_at_initialization(fmu: Path, case: str) -> None:
    parameters, message = BAD_CONFIGURATIONS[case]
    with pytest.raises(WorkpieceError) as raised:
        validate({**DEFAULTS, **parameters})
    assert str(raised.value) == message  # the reference rejects it with the same words
    slave = initialize_with(fmu, parameters)
    assert status_of(slave.exit_initialization) == ERROR
    assert slave.last_error() == f"exitInitializationMode: {message}"
    assert slave.messages[-1].category == "logStatusError"
    assert slave.step(H) == ERROR  # the instance is in the error state
    slave.fmu.reset()  # and usable again after reset
    slave.initialize()
    assert slave.step(H) == OK
    slave.unload()


def test_nan_position_is_rejected(fmu: Path) -> None:
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize()
        assert status_of(lambda: slave.set({"tool_z": math.nan})) == ERROR
        setter = "fmi3SetFloat64" if slave.fmi_version == 3 else "fmi2SetReal"
        assert slave.last_error() == f"{setter}: variable 'tool_z' set to nan: must be a finite number"


def test_a_jump_of_the_tool_is_an_error(fmu: Path) -> None:
    """A move faster than max_tool_speed (2 m/s = 120 m/min) in one step: positions in mm fed as m,
    or a glitch. The step is rejected before anything is cut."""
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({"tool_x": 0.05, "tool_y": 0.03, "tool_z": 0.028, "spindle_speed": SPINDLE})
        assert slave.step(H) == OK
        before = slave.get(FMU_OUTPUTS)
        slave.set({"tool_x": 0.0503})  # 0.3 mm in 1 ms: 0.3 m/s, fine
        assert slave.step(H) == OK
        slave.set({"tool_x": 0.0553})  # 5 mm in 1 ms: 5 m/s
        assert slave.step(H) == ERROR
        assert slave.last_error() == ("doStep: t = 0.002 s: the tool tip moved 0.005 m in 0.001 s (5 m/s), faster "
                                      "than max_tool_speed = 2 m/s: a jump in tool_x, tool_y, tool_z (a glitch, or "
                                      "not in m?)")
        assert not np.array_equal(slave.get(FMU_OUTPUTS), before)  # the outputs of the last good step stay
    zmap = ZMap({}, (0.05, 0.03, 0.028))
    zmap.step((0.0503, 0.03, 0.028), H)
    with pytest.raises(WorkpieceError, match="moved 0.005 m in 0.001 s"):
        zmap.step((0.0553, 0.03, 0.028), H)


def test_cutting_with_the_spindle_stopped_warns_once(fmu: Path) -> None:
    points = slot_points((-10 * MM, 30 * MM, 28 * MM), (20 * MM, 30 * MM, 28 * MM), 0.2 * MM)
    rows, slave = run_fmu(fmu, {}, points, spindle=0.0)
    assert len(slave.messages) == 1 and slave.messages[0].status == WARNING
    assert slave.warnings()[0].startswith("doStep: t = ")
    assert slave.warnings()[0].endswith("material removed while spindle_speed = 0 rad/s: the spindle stands still "
                                        "(a crash, or spindle_speed not connected? reported once)")
    slave.unload()
    assert np.array_equal(rows, run_reference({}, points, spindle=0.0)[0])  # and cuts as usual


def test_engagement_deeper_than_the_flutes_warns_once(fmu: Path) -> None:
    points = slot_points((-10 * MM, 30 * MM, 20 * MM), (20 * MM, 30 * MM, 20 * MM), 0.2 * MM)
    rows, slave = run_fmu(fmu, {"flute_length": 8 * MM}, points)
    assert [m.status for m in slave.messages] == [WARNING]
    assert "axial depth of cut 0.01 m is more than flute_length = 0.008 m: the shank is in the material " \
           "(reported once)" in slave.warnings()[0]
    slave.unload()
    assert np.max(rows[:, OUTPUTS.index("axial_depth")]) == pytest.approx(10 * MM, rel=1e-12)


# ---- tool changes ----

TOOL = ("tool_diameter", "corner_radius", "tool_length")


def tool_path(pieces: Sequence[tuple[dict, list]], parameters: dict | None = None) -> list[dict]:
    """Points (dicts of inputs and tunable tool parameters) of pieces of path, each cut with its tool (the values of
    TOOL; corner_radius and tool_length 0 when not given) from its first point on: the pieces' points are tips,
    the inputs the controlled point tool_length above. At a change of length the controlled point stays where it
    was: the new tool's tip starts that much lower (or higher), and a link of 1 mm per step takes it to the
    piece's first tip. points[0] also holds the fixed ``parameters``."""
    points: list[dict] = []
    length = 0.0
    for tool, tips in pieces:
        tool = {"corner_radius": 0.0, "tool_length": 0.0, **tool}
        if points and tool["tool_length"] != length:
            last = points[-1]
            start = (last["tool_x"], last["tool_y"], last["tool_z"] - tool["tool_length"])
            if math.dist(start, tips[0]) > 1e-12:
                tips = polyline([start, tips[0]], 1.0 * MM)[1:] + list(tips[1:])
        length = tool["tool_length"]
        points += [{**tool, "tool_x": x, "tool_y": y, "tool_z": z + length} for x, y, z in tips]
    points[0] = {**DEFAULTS, "spindle_speed": SPINDLE, **(parameters or {}), **points[0]}
    return points


def run_fmu_points(path: Path, points: Sequence[dict]) -> tuple[np.ndarray, Slave]:
    """Initialize with points[0], then set each point (fixed parameters left out) and step H: outputs after each."""
    slave = Slave(path)
    slave.instantiate()
    slave.initialize({n: v for n, v in points[0].items() if n in slave.vr})
    rows = []
    for point in points:
        slave.set(point, include_fixed=False)
        assert slave.step(H) in (OK, WARNING), slave.messages[-3:]
        rows.append(slave.get(FMU_OUTPUTS))
    return np.array(rows), slave


def assert_bits_equal(actual: np.ndarray, expected: np.ndarray) -> None:
    assert actual.shape == expected.shape
    differ = np.argwhere(actual != expected)
    if differ.size:
        first = tuple(differ[0])
        pytest.fail(f"{len(differ)} values differ, first at step {first[0]} output {OUTPUTS[first[1]]}: "
                    f"{actual[first]!r} != {expected[first]!r}")


FLAT = {"tool_diameter": 10 * MM, "corner_radius": 0.0}
BULL = {"tool_diameter": 6 * MM, "corner_radius": 1.5 * MM, "tool_length": 20 * MM}
BALL = {"tool_diameter": 8 * MM, "corner_radius": 4 * MM, "tool_length": 25 * MM}


def two_changes() -> tuple[list[dict], int, int]:
    """A 10 mm flat end mill ramps in, slots and rises to 60 mm; in air a 6 mm bull nose 20 mm longer comes in (its
    tip at 40 mm), goes down across the slot and along an arc; while that cuts, an 8 mm ball 5 mm longer still, its
    tip 5 mm lower (in material) from the step of the change on. Returns the points and the indices of the
    two changes."""
    first = polyline([(-8 * MM, 20 * MM, 31 * MM), (10 * MM, 20 * MM, 27.5 * MM), (45 * MM, 20 * MM, 27.5 * MM),
                      (45 * MM, 20 * MM, 60 * MM)], 0.3 * MM)
    second = chain(polyline([(45 * MM, 20 * MM, 40 * MM), (30 * MM, 10 * MM, 33 * MM), (30 * MM, 10 * MM, 28 * MM),
                             (30 * MM, 35 * MM, 28 * MM)], 0.3 * MM),
                   arc((40 * MM, 35 * MM), 10 * MM, math.pi, 1.5 * math.pi, 28 * MM, 0.2 * MM))
    third = [(x, y, z - 5 * MM) for x, y, z in
             chain(arc((40 * MM, 35 * MM), 10 * MM, 1.5 * math.pi, 2 * math.pi, 28 * MM, 0.2 * MM),
                   polyline([(50 * MM, 35 * MM, 28 * MM), (50 * MM, 50 * MM, 28 * MM)], 0.2 * MM))[1:]]
    points = tool_path([(FLAT, first), (BULL, second), (BALL, third)])
    assert len(points) == len(first) + len(second) + len(third)  # no links: the tips continue at the changes
    return points, len(first), len(first) + len(second)


def without_changes() -> list[dict]:
    """two_changes()'s tips with the flat end mill throughout (a link of 1 mm per step from 60 down to 40 mm)."""
    points, in_air, cutting = two_changes()
    tips = [(p["tool_x"], p["tool_y"], p["tool_z"] - p["tool_length"]) for p in points]
    return tool_path([(FLAT, tips[:in_air] + polyline([tips[in_air - 1], tips[in_air]], 1.0 * MM)[1:-1]
                       + tips[in_air:])])


def test_two_tool_changes_equal_the_reference_bit_for_bit(fmu: Path) -> None:
    """A change of diameter, corner and length in air, then another while cutting: the FMU equals the reference
    (which finds the changes in the tunable values of the points, as the FMU does) to the last bit, and each
    tool cuts as itself (the reference without changes, started with the new tool on the Z-map the old one
    left, gives the same outputs from the change on)."""
    points, in_air, cutting = two_changes()
    actual, slave = run_fmu_points(fmu, points)
    assert [m.status for m in slave.messages] == []
    slave.unload()
    expected = reference_trajectory(points, H)
    assert_bits_equal(actual, expected)
    mrr = expected[:, OUTPUTS.index("mrr")]
    clearance = expected[:, OUTPUTS.index("clearance")]
    assert clearance[in_air - 1] > 0 and clearance[cutting - 1] == 0  # the first change in air, the second cutting
    for lo, hi in ((0, in_air), (in_air, cutting), (cutting, len(points))):
        assert np.count_nonzero(mrr[lo:hi]) > (hi - lo) // 4
    # the ball's first step cuts under its tip, 5 mm below the bull nose's: it removes its whole lower part
    zmap = ZMap({}, (points[0]["tool_x"], points[0]["tool_y"], points[0]["tool_z"]))
    for point in points[:cutting]:
        zmap.change_tool(point["tool_diameter"], point["corner_radius"], point["tool_length"], zmap.p["flute_length"])
        zmap.step((point["tool_x"], point["tool_y"], point["tool_z"]), H, SPINDLE)
    assert zmap.radius == 3 * MM and zmap.n_corner > 0
    fresh = ZMap({**BALL, "tool_length": 0.0}, (zmap.position[0], zmap.position[1], zmap.point_z - BALL["tool_length"]))
    fresh.heights = zmap.heights.copy()
    fresh.feed = zmap.feed
    fresh.removed_height = zmap.removed_height
    rows = []
    for point in points[cutting:]:
        out = fresh.step((point["tool_x"], point["tool_y"], point["tool_z"] - BALL["tool_length"]), H, SPINDLE)
        rows.append([out[n] for n in OUTPUTS])
    assert_bits_equal(np.array(rows), expected[cutting:])


def test_after_a_tool_change_the_new_tool_cuts_its_own_slot(fmu: Path) -> None:
    """A 10 mm flat end mill slots through the block 3 mm deep, its walls on cell boundaries; in air a 6 mm one,
    40 mm longer, comes in and slots through it 2 mm deep elsewhere: each removes exactly its slot's volume
    (100 mm x D x depth: the walls on cell boundaries, so no cell is partly under the tool), with the depths and
    widths of slotting."""
    first = polyline([(-10 * MM, 30 * MM, 27 * MM), (110 * MM, 30 * MM, 27 * MM), (110 * MM, 30 * MM, 80 * MM)],
                     0.4 * MM)
    second = slot_points((110 * MM, 50 * MM, 28 * MM), (-10 * MM, 50 * MM, 28 * MM), 0.4 * MM)
    points = tool_path([(FLAT, first), ({"tool_diameter": 6 * MM, "tool_length": 40 * MM}, second)])
    change = len(first)
    assert points[change - 1]["tool_z"] == 80 * MM and points[change]["tool_z"] == pytest.approx(79.5 * MM)  # in air
    actual, slave = run_fmu_points(fmu, points)
    slave.unload()
    expected = reference_trajectory(points, H)
    assert_bits_equal(actual, expected)
    removed = expected[:, OUTPUTS.index("removed_volume")]
    assert removed[change - 1] == pytest.approx(100 * MM * 10 * MM * 3 * MM, rel=1e-12)
    assert removed[-1] - removed[change - 1] == pytest.approx(100 * MM * 6 * MM * 2 * MM, rel=1e-12)
    steady = expected[-200:-50]
    assert steady[:, OUTPUTS.index("axial_depth")] == pytest.approx(2 * MM, rel=1e-12)
    assert np.all(steady[:, OUTPUTS.index("radial_depth")] == 6 * MM)


def test_a_change_of_length_alone_moves_no_tip(fmu: Path) -> None:
    """A longer tool at the same controlled point puts the tip 4 mm lower (4 m/s in a step of 1 ms: the speed
    guard of 2 m/s would stop a move): no error, nothing removed, the clearance from the new tip. A shorter tool
    at rest in a slot lifts the tip out of it: nothing removed, no engagement."""
    def inputs(x: float, y: float, z: float, length: float) -> dict:
        return {"tool_x": x, "tool_y": y, "tool_z": z, "tool_length": length}

    above = [inputs(50 * MM, 30 * MM, 35 * MM, 0.0)] * 3 + [inputs(50 * MM, 30 * MM, 35 * MM, 4 * MM)] * 3
    path = polyline([(50 * MM, 30 * MM, 35 * MM), (-10 * MM, 30 * MM, 35 * MM), (-10 * MM, 30 * MM, 31 * MM),
                     (30 * MM, 30 * MM, 31 * MM)], 0.4 * MM)[1:]  # the tip 4 mm lower: a slot 3 mm deep
    cut = [inputs(x, y, z, 4 * MM) for x, y, z in path]
    shorter = [inputs(30 * MM, 30 * MM, 31 * MM, 1 * MM)] * 3  # the tip at 30 mm: the top
    points = above + cut + shorter
    points[0] = {**DEFAULTS, "spindle_speed": SPINDLE, **points[0]}
    assert points[0]["max_tool_speed"] == 2.0
    actual, slave = run_fmu_points(fmu, points)
    assert not slave.messages
    slave.unload()
    expected = reference_trajectory(points, H)
    assert_bits_equal(actual, expected)
    clearance, mrr = expected[:, OUTPUTS.index("clearance")], expected[:, OUTPUTS.index("mrr")]
    assert clearance[2] == pytest.approx(5 * MM) and clearance[3] == pytest.approx(1 * MM)  # the tip 4 mm lower
    assert not np.any(mrr[:6])
    lifted = len(points) - len(shorter)
    assert mrr[lifted - 1] > 0 and expected[lifted - 1, OUTPUTS.index("axial_depth")] == pytest.approx(3 * MM)
    assert not np.any(mrr[lifted:])
    volume = expected[:, OUTPUTS.index("removed_volume")]
    assert np.all(volume[lifted:] == volume[lifted - 1])
    assert not np.any(expected[lifted:, STEP_OUTPUTS])


def test_a_tool_change_at_rest_in_the_cut_forgets_what_the_old_tool_found(fmu: Path) -> None:
    """A 6 mm flat end mill slots and stops in the cut; at rest an 8 mm bull nose comes in (it cuts the ring the
    smaller tool left, though the disc the old tool cleared lies at its tip's height), then, still at rest, a
    5 mm one (inside the cut: it removes nothing, and sees the stock where the first tool's probes were). The
    FMU reuses between steps what the old tool found (the cleared disc, its probes of the stock) only for that
    tool: equal to the reference to the last bit."""
    slot = slot_points((-10 * MM, 30 * MM, 28 * MM), (30 * MM, 30 * MM, 28 * MM), 0.4 * MM)
    rest = [slot[-1]] * 4
    points = tool_path([({"tool_diameter": 6 * MM}, slot + rest),
                        ({"tool_diameter": 8 * MM, "corner_radius": 1 * MM}, rest),
                        ({"tool_diameter": 5 * MM}, rest + slot_points(slot[-1], (40 * MM, 30 * MM, 28 * MM)))])
    actual, slave = run_fmu_points(fmu, points)
    slave.unload()
    expected = reference_trajectory(points, H)
    assert_bits_equal(actual, expected)
    mrr, radial = expected[:, OUTPUTS.index("mrr")], expected[:, OUTPUTS.index("radial_depth")]
    bull, small = len(slot) + len(rest), len(slot) + 2 * len(rest)
    assert mrr[bull - 1] == 0 and mrr[bull] > 0 and not np.any(mrr[bull + 1:small + 4])
    assert radial[bull - 1] > 0 and radial[small - 1] != radial[bull - 1] and radial[small] != radial[small - 1]


BAD_TOOLS = {
    "corner radius beyond the radius": ({"corner_radius": 0.006}, "corner_radius = 0.006 m is larger than "
                                        "tool_diameter/2 = 0.005 m (0: flat end mill, tool_diameter/2: ball end mill)"),
    "tool larger than the stock": ({"tool_diameter": 0.08}, "the tool is larger than the stock: tool_diameter = "
                                   "0.08 m, stock_length = 0.1 m, stock_width = 0.06 m"),
    "resolution too coarse": ({"tool_diameter": 0.0009}, "resolution = 0.00025 m is too coarse for tool_diameter = "
                              "0.0009 m: the Z-map needs at least 4 cells across the tool (resolution <= 0.000225 m)"),
}


@pytest.mark.parametrize("case", BAD_TOOLS)
def test_a_new_tool_the_checks_reject_fails_the_step(fmu: Path, case: str) -> None:
    tool, message = BAD_TOOLS[case]
    new = {"tool_diameter": 0.01, "corner_radius": 0.0, "tool_length": 0.0, "flute_length": 0.022, **tool}
    zmap = ZMap({}, (0.05, 0.03, 0.028))
    zmap.step((0.0502, 0.03, 0.028), H, SPINDLE)
    with pytest.raises(WorkpieceError) as raised:
        zmap.change_tool(*(new[n] for n in (*TOOL, "flute_length")))
    assert str(raised.value) == f"tool change: {message}"
    assert zmap.radius == 5 * MM  # nothing changed
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({"tool_x": 0.05, "tool_y": 0.03, "tool_z": 0.028, "spindle_speed": SPINDLE})
        assert slave.step(H) == OK
        slave.set(tool)
        assert slave.step(H) == ERROR
        assert slave.last_error() == f"doStep: t = 0.001 s: tool change: {message}"
        assert slave.messages[-1].category == "logStatusError"


def test_a_state_saved_before_a_tool_change_gives_the_old_tool_back(fmu: Path) -> None:
    """FMU states hold the tool (its parameters, its tables in the heap, whose size changes with it): a state saved
    before a change and restored after it continues with the old tool, as if there had been no change; a state saved
    after the change, restored after that, with the new one (both equal to the reference to the last bit)."""
    points, in_air, _ = two_changes()
    old_tool = without_changes()
    later = in_air + 140  # the bull nose cutting
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({n: v for n, v in points[0].items() if n in slave.vr})
        rows = []
        for k, point in enumerate(points[:later + 30]):
            if k == in_air:
                before = slave.fmu.getFMUState()
            if k == later:
                after = slave.fmu.serializeFMUState(state := slave.fmu.getFMUState())
                slave.fmu.freeFMUState(state)
            slave.set(point, include_fixed=False)
            assert slave.step(H) == OK, slave.messages[-3:]
            rows.append(slave.get(FMU_OUTPUTS))
        slave.set_state(before)
        slave.fmu.freeFMUState(before)
        assert slave.get(list(TOOL)).tolist() == [FLAT["tool_diameter"], 0.0, 0.0]
        restored_old = []
        for point in old_tool[in_air:in_air + 200]:
            slave.set({n: point[n] for n in ("tool_x", "tool_y", "tool_z")})
            assert slave.step(H) == OK, slave.messages[-3:]
            restored_old.append(slave.get(FMU_OUTPUTS))
        slave.set_state(slave.fmu.deserializeFMUState(after))
        restored_new = []
        for point in points[later:later + 30]:
            slave.set({n: point[n] for n in ("tool_x", "tool_y", "tool_z")})
            assert slave.step(H) == OK, slave.messages[-3:]
            restored_new.append(slave.get(FMU_OUTPUTS))
    expected = reference_trajectory(points[:later + 30], H)
    assert_bits_equal(np.array(rows), expected)
    assert_bits_equal(np.array(restored_new), expected[later:])
    assert np.count_nonzero(expected[later:, OUTPUTS.index("mrr")]) > 10
    without = reference_trajectory(old_tool[:in_air + 200], H)
    assert_bits_equal(np.array(restored_old), without[in_air:])
    mrr = OUTPUTS.index("mrr")
    assert np.count_nonzero(without[in_air:, mrr]) > 10
    assert np.sum(without[in_air:, mrr]) > 1.5 * np.sum(expected[in_air:in_air + 180, mrr])  # 10 mm against 6 mm


def test_the_shank_warning_is_re_armed_by_a_new_flute_length_and_a_tool_change(fmu: Path) -> None:
    slot = slot_points((-10 * MM, 30 * MM, 20 * MM), (20 * MM, 30 * MM, 20 * MM), 0.4 * MM)
    points = tool_path([(FLAT, slot[:40]), (FLAT, slot[40:50]), (FLAT, slot[50:60]),
                        ({**FLAT, "tool_diameter": 9 * MM}, slot[60:])], {"flute_length": 8 * MM})
    for k, point in enumerate(points):
        point["flute_length"] = 9 * MM if 40 <= k < 50 else 8 * MM
    actual, slave = run_fmu_points(fmu, points)
    warnings = slave.warnings()
    slave.unload()
    zmap = ZMap({"flute_length": 8 * MM}, (points[0]["tool_x"], points[0]["tool_y"], points[0]["tool_z"]))
    for point in points:
        zmap.change_tool(point["tool_diameter"], point["corner_radius"], point["tool_length"], point["flute_length"])
        zmap.step((point["tool_x"], point["tool_y"], point["tool_z"]), H, SPINDLE)
    assert zmap.warnings == ["shank"] * 4  # the first tool, the flutes of 9 mm, of 8 mm again, the 9 mm tool
    assert len(warnings) == 4 and all("is more than flute_length" in w for w in warnings)
    assert "flute_length = 0.009 m" in warnings[1] and "flute_length = 0.008 m" in warnings[2]


# ---- cost per step ----


def test_cost_per_step_does_not_grow_with_the_stock() -> None:
    """The same slot in a 100 x 100 mm block and in an 800 x 800 mm one (64 times the cells, 82 MB):
    the time per step is the same within a factor 2, because only the cells under the swept tool are
    visited. Runs of the two alternate and the best of 5 counts (the machine may be shared)."""
    points = slot_points((10 * MM, 50 * MM, 27 * MM), (90 * MM, 50 * MM, 27 * MM), 0.2 * MM)
    sizes = (0.1, 0.8)
    slaves = {size: Slave(require_fmu(FMUS[0]), f"stock {size} m") for size in sizes}
    per_step = dict.fromkeys(sizes, math.inf)
    try:
        for _ in range(5):
            for size, slave in slaves.items():
                slave.instantiate()
                x, y, z = points[0]
                slave.initialize({"stock_length": size, "stock_width": size, "tool_x": x, "tool_y": y, "tool_z": z,
                                  "spindle_speed": SPINDLE})
                vrs = [slave.vr["tool_x"]]
                start = time.perf_counter()
                for x, _, _ in points:
                    slave.set_real(vrs, [x])
                    assert slave.step(H) == OK
                per_step[size] = min(per_step[size], (time.perf_counter() - start) / len(points))
                assert slave.get(["mrr"])[0] > 0
                slave.free_instance()
    finally:
        for slave in slaves.values():
            slave.unload()
    assert per_step[0.8] < 2 * per_step[0.1], per_step

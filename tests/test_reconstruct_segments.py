"""Per-segment reconstruction of spliced recordings, per-segment alignment and the refusal of failed alignments
(orchestrator/gcode/reconstruct.py, orchestrator/align/segments.py, orchestrator/calibrate/pairing.py)."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fmu_helpers import repo_root
from milling_twin.models import interpolator as ip
from milling_twin.orchestrator.align import TimeMap
from milling_twin.orchestrator.align.segments import agreement, align_segments
from milling_twin.orchestrator.align.trajectory import Trajectory
from milling_twin.orchestrator.calibrate.errors import CalibrationError
from milling_twin.orchestrator.calibrate.pairing import refuse_failed_alignment
from milling_twin.orchestrator.calibrate.spec import AlignmentSpec
from milling_twin.orchestrator.gcode import reconstruct as rc

RUN_01 = repo_root() / "scenarios" / "data" / "umich_experiment_01.csv"


@pytest.fixture(scope="module")
def spliced(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Cutting blocks of run 01 with blocks of rows at the home position (spindle stopped) between them, as the
    UMich runs 02-12 are spliced."""
    data = pd.read_csv(RUN_01)
    home = data.iloc[:10].copy()
    for a, value in zip("XYZ", (198.0, 158.0, 119.0)):
        home[f"{a}1_CommandPosition"] = home[f"{a}1_ActualPosition"] = value
        home[f"{a}1_CommandVelocity"] = home[f"{a}1_ActualVelocity"] = 0.0
    home["S1_ActualVelocity"] = 0.0
    blocks = [data.iloc[150:162], home, data.iloc[300:330], home, data.iloc[600:611], data.iloc[800:812]]
    path = tmp_path_factory.mktemp("spliced") / "spliced.csv"
    pd.concat(blocks, ignore_index=True).to_csv(path, index=False)
    return path


@pytest.fixture(scope="module")
def segmented(spliced: Path) -> rc.SegmentedReconstruction:
    return rc.reconstruct_segments(spliced)


def test_every_segment_program_is_accepted_and_takes_the_recorded_time(segmented: rc.SegmentedReconstruction) -> None:
    assert len(segmented.segments) >= 5 and len(segmented.moving) >= 4
    assert all(s.recon is not None for s in segmented.segments)  # every segment has at least 2 rows
    assert len(segmented.programs) - len(segmented.moving) == 2  # the home blocks: the tool stands
    for s in segmented.programs:
        text = s.recon.program()
        parameters = {**ip.default_parameters(), **rc.INTERPOLATOR_PARAMETERS, **rc._start(s.recon.start)}
        program = ip.parse_program(text, parameters)
        ip.build_path(program, parameters)  # the Interpolator's path builder accepts it
        first = [float(w[1:]) for w in text.splitlines()[5].split()[1:]]
        assert first == pytest.approx([float(rc._mm(c)) for c in s.recon.start])  # starts at the first position
        assert s.simulated_time == pytest.approx(rc.simulated_duration(text, s.recon.start), abs=1e-6)
        if s.standing:
            assert not re.search(r"\bG[0-3]\b", "\n".join(text.splitlines()[6:])) and s.simulated_time == 0.0
            continue
        assert s.recorded_time > 0 and abs(s.ratio - 1.0) <= 0.05, (s.index, s.ratio)


def test_no_arc_has_an_absurd_radius(segmented: rc.SegmentedReconstruction) -> None:
    for s in segmented.programs:
        for line in s.recon.program().splitlines():
            words = dict((w[0], float(w[1:])) for w in line.split() if re.fullmatch(r"[IJ]-?[\d.]+", w))
            if words:
                assert np.hypot(words.get("I", 0.0), words.get("J", 0.0)) <= rc.MAX_ARC_RADIUS
    # nearly collinear samples fit a circle of ~1e6 mm: never an arc
    x = np.linspace(0.0, 50.0, 12)
    points = np.column_stack([x, 1e-4 * x * (50.0 - x) / 625.0, np.zeros(12)])
    assert rc._arc_through(points[0], points[-1], points[1:-1]) is None
    assert [kind for kind, _, _ in rc._fit_piece(points, allow_arcs=True)] == ["G1"]


def test_the_command_writes_one_program_per_segment(spliced: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "programs"
    assert rc.command(argparse.Namespace(recording=spliced, output=out)) == 0
    index = pd.read_csv(out / "segments.csv")
    written = index[index["program"].notna()]
    assert sorted(p.name for p in out.glob("seg_*.nc")) == sorted(written["program"])
    assert (written["ratio"] - 1.0).abs().max() <= 0.05
    assert index["skipped"].isna().all()  # every segment has a program
    assert "standing); no program for" in capsys.readouterr().out


def test_per_segment_alignment_is_one_piecewise_map(segmented: rc.SegmentedReconstruction) -> None:
    """Each segment against the positions its program passes (the Interpolator's schedule stands in for the run):
    the map has a segment column and restarts at each segment."""
    data = pd.read_csv(segmented.source)
    positions = data[[f"{a}1_CommandPosition" for a in "XYZ"]].to_numpy() * 1e-3
    recorded = Trajectory(np.arange(len(data)) * rc.SAMPLE_PERIOD, positions, "spliced")
    pieces = []
    for s in segmented.segments:
        sim = None
        if s.recon is not None:
            fused = s.recon.positions * 1e-3
            t = (np.arange(len(fused)) - s.recon.blocks[0].first_sample) * rc.SAMPLE_PERIOD
            keep = t >= 0
            sim = Trajectory(t[keep], fused[keep], s.name)
        pieces.append((s.index, s.start, s.stop, sim, s.motion_start))
    piecewise = align_segments(recorded, pieces)
    frame = piecewise.frame()
    assert list(frame.columns) == ["row", "segment", "recorded_time", "simulated_time", "confidence"]
    firsts = frame.groupby("segment")["simulated_time"].first()
    assert (firsts <= 0.2).all()
    assert {s.index for s in piecewise.below(0.3)} >= {s.index for s in segmented.segments if s.recon is None}


def test_calibration_refuses_an_alignment_below_the_threshold() -> None:
    class Recording:
        path = Path("runs/experiment_07.csv")

    t = np.arange(20) * 0.1
    spec = AlignmentSpec("multiscale", (), (), 0.0, 0.0, 0.3)
    refuse_failed_alignment(Recording(), TimeMap(t, t, np.full(20, 0.8), "multiscale"), spec)  # passes
    with pytest.raises(CalibrationError, match=r"experiment_07\.csv: segment 4 \(rows 40-59\): alignment "
                                               r"confidence 0\.05 is below \[alignment\]\.refuse_below = 0\.3"):
        refuse_failed_alignment(Recording(), TimeMap(t, t, np.full(20, 0.05), "multiscale"), spec, 4, (40, 59))


# -- segment programs that keep the recorded timing, and the per-segment fit ----------------------------------


def test_segment_programs_split_moves_where_the_speed_changes() -> None:
    """Samples on one straight line, the tool at 20 mm/s, then 50 mm/s: one line for the path, but a constant
    feed over it would misplace the samples in time, so a segment program writes two moves."""
    along = np.concatenate([np.arange(6) * 2.0, 10.0 + np.arange(1, 6) * 5.0])
    points = np.column_stack([along, np.zeros_like(along), np.zeros_like(along)])
    assert [j for _, j, _ in rc._fit_piece(points, allow_arcs=False)] == [10]
    assert [j for _, j, _ in rc._fit_piece(points, allow_arcs=False, timing=rc.TIMING_DEVIATION)] == [5, 10]


def test_robust_fusion_trusts_the_positions_where_the_velocity_samples_miss_a_stop() -> None:
    """The machine stops for an instant between two blocks (the positions advance 1.4 mm instead of 2 in that
    0.1 s) while both velocity samples read 20 mm/s: the robust fusion follows the positions there."""
    true = np.array([0.0, 2.0, 4.0, 5.4, 7.4, 9.4]) + 80.0
    velocity = np.full(true.size, 20.0)
    stored = np.round(true, 1)
    plain = rc.fuse_positions(stored, velocity)
    robust = rc.fuse_positions(stored, velocity, robust=True)
    assert np.max(np.abs(robust - true)) <= 0.05
    assert np.max(np.abs(plain - true)) > 0.1


@pytest.fixture(scope="module")
def short_segments(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 2-row and a 3-row block of run 01's cutting, each between blocks of the home position."""
    data = pd.read_csv(RUN_01)
    home = data.iloc[:10].copy()
    for a, value in zip("XYZ", (198.0, 158.0, 119.0)):
        home[f"{a}1_CommandPosition"] = home[f"{a}1_ActualPosition"] = value
        home[f"{a}1_CommandVelocity"] = home[f"{a}1_ActualVelocity"] = 0.0
    path = tmp_path_factory.mktemp("short") / "short.csv"
    pd.concat([home, data.iloc[400:402], home, data.iloc[500:503], home], ignore_index=True).to_csv(path, index=False)
    return path


def test_two_row_segments_get_a_program_with_a_preroll(short_segments: Path) -> None:
    segmented = rc.reconstruct_segments(short_segments)
    moving = segmented.moving
    assert [s.rows for s in moving] == [2, 3]
    for s in moving:
        assert s.recon.blocks[0].kind == "preroll" and s.recon.preroll == rc.PREROLL
        assert s.motion_start == pytest.approx(s.start * rc.SAMPLE_PERIOD - rc.PREROLL)
        assert abs(s.ratio - 1.0) <= 0.05
        # the pre-roll ends at the first sample's position
        assert np.allclose(s.recon.blocks[0].moves[0][1], s.recon.positions[0])


def _program_run(segment: rc.SegmentProgram) -> Trajectory:
    """The positions a segment program passes at its samples (pre-roll start, then one per sample), linear between:
    what the Interpolator does with feeds that keep the recorded timing."""
    positions = np.vstack([np.asarray(segment.recon.start), segment.recon.positions]) * 1e-3
    t = np.concatenate([[0.0], segment.recon.preroll + np.arange(len(segment.recon.positions)) * rc.SAMPLE_PERIOD])
    dense = np.arange(0.0, t[-1] + 1e-9, 0.005)
    return Trajectory(dense, np.column_stack([np.interp(dense, t, positions[:, a]) for a in range(3)]), segment.name)


def _stored(position_m: np.ndarray) -> np.ndarray:
    """Positions (m) as the logger stores them: mm with 3 significant digits."""
    mm = position_m * 1e3
    q = rc.quantum_of(mm)
    return np.round(mm / q) * q * 1e-3


def test_segment_fit_recovers_the_servo_lag_to_the_millisecond(segmented: rc.SegmentedReconstruction) -> None:
    """Each segment's actual positions lag its program by 12 ms and are stored to 3 significant digits; the
    recorded velocities are the program's. The segment fit finds the lag within 2 ms, every sample lies within
    1.5 storage steps and the confidence is high; a standing segment maps flat with confidence 1."""
    data = pd.read_csv(segmented.source)
    n = len(data)
    time = np.arange(n) * rc.SAMPLE_PERIOD
    actual = np.zeros((n, 3))
    velocity = np.zeros((n, 3))
    runs = {}
    for s in segmented.programs:
        if s.standing:
            run = Trajectory(np.array([0.0, 0.5]), np.repeat(np.asarray(s.recon.start)[None] * 1e-3, 2, axis=0))
        else:
            run = _program_run(s)
        runs[s.index] = run
        tau = np.clip(time[s.start:s.stop] - s.motion_start - 0.012, 0.0, run.time[-1])
        actual[s.start:s.stop] = _stored(run.at(tau))
        velocity[s.start:s.stop] = np.stack([np.interp(tau, run.time, v) for v in run.velocity().T], axis=1)
    recorded = Trajectory(time, actual, "spliced")
    step = rc.quantum_of(actual * 1e3) * 1e-3
    pieces = [(s.index, s.start, s.stop, runs[s.index], s.motion_start) for s in segmented.programs]
    piecewise = align_segments(recorded, pieces, velocity=velocity, step=step)
    assert not piecewise.below()
    for seg, s in zip(piecewise.segments, segmented.programs):
        tm = seg.time_map
        if s.standing:
            assert tm.method == "standing" and np.all(tm.confidence == 1.0)
            continue
        if tm.method == "segment fit":
            assert tm.info["shift"] == pytest.approx(-0.012, abs=0.002) and tm.info["rate"] == pytest.approx(1, abs=0.02)
        mapped = tm.resample_simulated(runs[s.index].time, runs[s.index].position)
        residual = np.abs(actual[s.start:s.stop] - mapped)
        assert np.all(residual <= 1.5 * step[s.start:s.stop] + 1e-12), s.index
        assert seg.confidence >= 0.9


def test_a_segment_aligned_with_the_wrong_run_fails(segmented: rc.SegmentedReconstruction) -> None:
    """The agreement says when a map is bad: a segment against another segment's program scores below the
    threshold, and every sample far off the simulated path scores below 0.3."""
    moving = segmented.moving
    a, b = moving[0], moving[1]
    data = pd.read_csv(segmented.source)
    actual = data[[f"{x}1_ActualPosition" for x in "XYZ"]].to_numpy() * 1e-3
    recorded = Trajectory(np.arange(len(data)) * rc.SAMPLE_PERIOD, actual, "spliced")
    step = rc.quantum_of(actual * 1e3) * 1e-3
    piecewise = align_segments(recorded, [(a.index, a.start, a.stop, _program_run(b), a.motion_start)], step=step)
    assert [s.index for s in piecewise.below()] == [a.index]
    tol = np.full((4, 3), 1e-4)
    c = agreement(np.array([[0.0, 0.0, 1e-4], [0.0, 2e-4, 0.0], [5e-4, 0.0, 0.0], [np.nan, 0.0, 0.0]]), tol)
    assert c[0] == 1.0 and c[1] == pytest.approx(0.25) and c[2] < 0.05 and c[3] == 0.0
    v = np.array([[0.02, 0.0, 0.0]] * 4)
    assert agreement(np.zeros((4, 3)), tol, v, v)[0] == 1.0
    assert agreement(np.zeros((4, 3)), tol, v, -v, floor=1e-3)[0] == pytest.approx(0.5, abs=0.01)

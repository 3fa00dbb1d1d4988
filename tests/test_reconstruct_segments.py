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
from milling_twin.orchestrator.align.segments import align_segments
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
    assert len(segmented.segments) >= 5 and len(segmented.programs) >= 4
    assert {s.reason.split(" (")[0] for s in segmented.segments if s.recon is None} == {"no motion"}
    for s in segmented.programs:
        text = s.recon.program()
        parameters = {**ip.default_parameters(), **rc.INTERPOLATOR_PARAMETERS, **rc._start(s.recon.start)}
        program = ip.parse_program(text, parameters)
        ip.build_path(program, parameters)  # the Interpolator's path builder accepts it
        first = [float(w[1:]) for w in text.splitlines()[5].split()[1:]]
        assert first == pytest.approx([float(rc._mm(c)) for c in s.recon.start])  # starts at the first position
        assert s.recorded_time > 0 and abs(s.ratio - 1.0) <= 0.05, (s.index, s.ratio)
        assert s.simulated_time == pytest.approx(rc.simulated_duration(text, s.recon.start))


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
    assert index["skipped"].notna().any()
    assert "programs; no program for" in capsys.readouterr().out


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

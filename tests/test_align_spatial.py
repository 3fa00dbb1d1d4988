"""Spatial alignment (wall-thickness compensation by work-offset shift) on generated parts with
known shifts, rotations and thickness errors; bad input; the CLI."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from milling_twin.orchestrator.align import AlignmentError, ProbeData, compensate_wall, work_offset_gcode
from milling_twin.cli import main


def align_cli(args: list[str]) -> int:
    return main(["align", *args])
from milling_twin.orchestrator.align.icp import icp
from cases.align_parts import make_ring, make_wall
from milling_twin.orchestrator.align.shepard import shepard
from milling_twin.orchestrator.align.spatial import load_probe_csv
from milling_twin.orchestrator.align.surface import fit_circle


@pytest.mark.parametrize("inner_shift, seed", [((0.5, 0.0), 0), ((0.5, 0.0), 1),
                                               ((0.0, 0.5), 2), ((0.35, -0.35), 3)])
def test_ring_shift_recovered_within_10_um(inner_shift, seed):
    """0.5 mm shift of the inner wall, probe noise 2 um, gauge noise 5 um, cast outer surface
    off-centre with a 3-lobe form error: the work-offset shift is -inner_shift to 0.01 mm."""
    part = make_ring(inner_shift=inner_shift, seed=seed)
    comp = compensate_wall(part.probes, part.design, part.design_thickness, threshold=0.02)
    assert np.abs(comp.shift - part.shift).max() < 0.01
    assert comp.accepted and comp.registration.mean_distance < 0.02
    np.testing.assert_allclose(comp.registration.translation[:2], inner_shift, atol=0.01)
    assert comp.info["stock_mean"] == pytest.approx(0.4, abs=0.05)  # cast 0.4 mm oversize
    reg = compensate_wall(part.probes, part.design, part.design_thickness, 0.02,
                          centre="registration")
    assert np.abs(reg.shift - part.shift).max() < 0.01


def test_gcode_sets_g55_to_g54_minus_shift():
    part = make_ring(inner_shift=(0.5, 0.2))
    comp = compensate_wall(part.probes, part.design, part.design_thickness, threshold=0.02)
    lines = work_offset_gcode(comp.shift, (100.0, 50.0, -20.0))
    x, y = 100.0 + 0.5, 50.0 + 0.2
    assert lines[1] == "G55"
    head, xs, ys, zs = lines[0].split()[:3], *lines[0].split()[3:]
    assert head == ["G10", "L2", "P2"] and zs == "Z-20.0000"
    assert abs(float(xs[1:]) - x) < 0.01 and abs(float(ys[1:]) - y) < 0.01
    assert work_offset_gcode(np.array([-0.5, 0.25]), (1, 2, 3), register=6) == [
        "G10 L2 P6 X1.5000 Y1.7500 Z3.0000", "G59"]
    with pytest.raises(AlignmentError, match=r"register must be 2..6"):
        work_offset_gcode(np.zeros(2), (0, 0, 0), register=1)


def test_thickness_error_shows_in_f_and_fails_threshold():
    """Inner wall 0.1 mm too large: S2 is 0.1 mm outside the design everywhere: F ~ 0.1."""
    part = make_ring(inner_shift=(0.3, -0.4), thickness_error=0.1)
    comp = compensate_wall(part.probes, part.design, part.design_thickness, threshold=0.05)
    assert comp.registration.mean_distance == pytest.approx(0.1, abs=0.01)
    assert not comp.accepted
    assert np.abs(comp.shift - part.shift).max() < 0.01  # the centre is still right


@pytest.mark.parametrize("angle", [0.2, -0.5])
def test_flat_wall_rotation_and_shift(angle):
    part = make_wall(inner_shift=0.5, angle_deg=angle)
    comp = compensate_wall(part.probes, part.design, part.design_thickness, threshold=0.02,
                           geometry="plane", outward="x", centre="registration",
                           resolution=(81, 16))
    rotvec = Rotation.from_matrix(comp.registration.rotation).as_rotvec(degrees=True)
    assert rotvec[2] == pytest.approx(-angle, abs=0.02)  # design turned onto the tilted wall
    assert abs(comp.shift[0] - part.shift[0]) < 0.01
    assert abs(comp.shift[1]) < 0.01  # sliding along the wall is not determined: not moved
    assert comp.registration.rank == 3  # x, rotations about y and z


def test_shepard_and_circle_fit():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    vals = np.array([1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(shepard(pts, vals, pts), vals)
    mid = shepard(pts, vals, np.array([[0.5, 0.5]]))
    assert mid[0] == pytest.approx(2.5)
    np.testing.assert_allclose(shepard(pts, np.full(4, 7.0), np.random.rand(10, 2)), 7.0)
    ang = np.linspace(0, 2 * np.pi, 17)
    centre, r = fit_circle(np.c_[3 + 2 * np.cos(ang), -1 + 2 * np.sin(ang)])
    np.testing.assert_allclose(centre, [3, -1], atol=1e-12)
    assert r == pytest.approx(2.0)


def test_icp_recovers_a_rigid_motion_of_a_curved_patch():
    u, v = np.meshgrid(np.linspace(-20, 20, 81), np.linspace(-20, 20, 81), indexing="ij")
    z = 0.05 * u ** 2 - 0.03 * v ** 2 + 0.02 * u * v + 0.001 * u ** 3
    target = np.c_[u.ravel(), v.ravel(), z.ravel()]
    grad = np.c_[-(0.1 * u + 0.02 * v + 0.003 * u ** 2).ravel(),
                 -(-0.06 * v + 0.02 * u).ravel(), np.ones(u.size)]
    normals = grad / np.linalg.norm(grad, axis=1, keepdims=True)
    rot = Rotation.from_rotvec([0.01, -0.02, 0.015]).as_matrix()
    trans = np.array([0.3, -0.2, 0.1])
    inner = np.abs(target[:, :2]).max(axis=1) < 15
    source = (target[inner] - trans) @ rot  # so that rot @ source + trans = target
    res = icp(source, target, normals, max_distance=5.0, tolerance=1e-10, max_iterations=100)
    assert res.converged and res.rank == 6
    np.testing.assert_allclose(res.rotation, rot, atol=2e-4)
    np.testing.assert_allclose(res.translation, trans, atol=5e-3)
    assert res.mean_distance < 1e-3


def test_bad_input_gives_clear_errors(tmp_path):
    part = make_ring()
    pts, th = part.probes.points, part.probes.thickness
    with pytest.raises(AlignmentError, match="5 probe points; at least 6"):
        ProbeData(pts[:5], th[:5])
    bad = pts.copy()
    bad[7, 1] = np.nan
    with pytest.raises(AlignmentError, match="row 7: y is not a finite number"):
        ProbeData(bad, th)
    thin = th.copy()
    thin[3] = 0.0
    with pytest.raises(AlignmentError, match=r"row 3: thickness must be a finite number > 0, "
                                             r"got 0.0"):
        ProbeData(pts, thin)
    with pytest.raises(AlignmentError, match="do not overlap"):
        compensate_wall(part.probes, part.design + [500.0, 0.0, 0.0], 2.0, 0.05)
    with pytest.raises(AlignmentError, match="design_thickness must be a finite number > 0"):
        compensate_wall(part.probes, part.design, -2.0, 0.05)
    with pytest.raises(AlignmentError, match="3 design points; at least 6"):
        compensate_wall(part.probes, part.design[:3], 2.0, 0.05)
    (tmp_path / "p.csv").write_text("x,y,z,thickness\n1,2,3,2.0\n1,2,3,abc\n")
    with pytest.raises(AlignmentError, match=r"p.csv: line 3, column 'thickness': 'abc'"):
        load_probe_csv(tmp_path / "p.csv")
    (tmp_path / "q.csv").write_text("x,y,thickness\n1,2,2.0\n")
    with pytest.raises(AlignmentError, match=r"q.csv: no column 'z'"):
        load_probe_csv(tmp_path / "q.csv")


def test_cli_spatial(tmp_path, capsys):
    part = make_ring(inner_shift=(0.5, 0.0))
    pd.DataFrame(np.c_[part.probes.points, part.probes.thickness],
                 columns=["x", "y", "z", "thickness"]).to_csv(tmp_path / "probes.csv",
                                                               index=False)
    pd.DataFrame(part.design, columns=["x", "y", "z"]).to_csv(tmp_path / "design.csv",
                                                              index=False)
    base = ["spatial", "--probes", str(tmp_path / "probes.csv"), "--design",
            str(tmp_path / "design.csv"), "--design-thickness", "2", "--g54", "100", "50",
            "-20", "--out", str(tmp_path / "r.json"), "--plot", str(tmp_path / "part.png")]
    assert align_cli(base + ["--threshold", "0.02"]) == 0
    out = capsys.readouterr().out
    assert "G55" in out and "G10 L2 P2 X100.49" in out
    assert 0 < (tmp_path / "part.png").stat().st_size < 200_000
    assert align_cli(base + ["--threshold", "0.001"]) == 3
    assert "registration rejected" in capsys.readouterr().err
    assert align_cli(base[:2] + [str(tmp_path / "none.csv")] + base[3:] +
                     ["--threshold", "0.02"]) == 2  # bad input: exit 2, as in every subcommand
    assert "none.csv: file not found" in capsys.readouterr().err

"""[study.refine]: rounds of cases where an output crosses a threshold (orchestrator/study/refine.py)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from milling_twin.orchestrator.study.refine import SAFEGUARD, Bracket, RefineSpec, first_crossing, refined_values
from milling_twin.orchestrator.study.run import sweep
from milling_twin.orchestrator.study.spec import StudyError, load_study
from milling_twin.orchestrator.study.stability_map import onset_of

REPO = Path(__file__).resolve().parents[1]
CHATTER = REPO / "scenarios" / "chatter.toml"


def test_the_first_crossing_going_up() -> None:
    assert first_crossing([1, 2, 3, 4], [0.5, 0.9, 1.5, 0.8], 1.0) == (1, 2)
    assert first_crossing([1, 2, 3], [0.5, 0.9, 1.0], 1.0) is None      # never above
    assert first_crossing([1, 2, 3], [1.5, 0.9, 2.0], 1.0) is None      # above from the first


def test_the_estimate_is_the_log_crossing_kept_inside_the_bracket() -> None:
    # growth = exp(3 (x - 2)) crosses 1 at x = 2: exact in log from any bracket
    g = (lambda x: math.exp(3 * (x - 2)))
    assert Bracket(1.5, 2.8, g(1.5), g(2.8), "a").estimate(1.0, "log") == pytest.approx(2.0, rel=1e-12)
    # linear: the straight line between the two outputs
    assert Bracket(0.0, 1.0, 0.0, 4.0, "a").estimate(1.0, "linear") == pytest.approx(0.25)
    # a crossing next to an end is moved a tenth of the bracket inside, so that the round shrinks it
    assert Bracket(0.0, 1.0, 0.999, 100.0, "a").estimate(1.0, "log") == pytest.approx(SAFEGUARD)
    # an infinite growth above: the middle
    assert Bracket(0.0, 1.0, 0.5, math.inf, "a").estimate(1.0, "log") == pytest.approx(0.5)


def _summary(rows: list[tuple[str, float, float, float, str]]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["case_id", "speed", "depth", "growth", "status"])


def test_one_new_case_per_bracketed_group_with_the_values_of_the_case_below() -> None:
    summary = _summary([
        ("a1", 100.0, 1.0, 0.5, "ok"), ("a2", 100.0, 2.0, math.e, "ok"), ("a3", 100.0, 3.0, 9.0, "ok"),
        ("b1", 200.0, 1.0, 0.2, "ok"), ("b2", 200.0, 2.0, 0.4, "ok"),                  # stable throughout
        ("c1", 300.0, 1.0, 0.5, "ok"), ("c2", 300.0, 2.0, 3.0, "failed"),              # failed: no bracket
        ("d1", 400.0, 1.0, 0.5, "ok"), ("d2", 400.0, 1.001, 2.0, "ok"),                # narrower than tolerance
    ])
    values = {cid: {"speed": {"value": float(s), "unit": "rpm"}, "depth": d} for cid, s, d, _, _ in
              summary.itertuples(index=False, name=None)}
    spec = RefineSpec("depth", "growth", tolerance=0.01)
    made = refined_values(summary, spec, ("speed", "depth"), values, stop_time=0.1)
    assert len(made) == 1
    cid, new = made[0]
    assert new["speed"] == {"value": 100.0, "unit": "rpm"}       # the group's other values as the case gave them
    expected = 1.0 + (0 - math.log(0.5)) / (1 - math.log(0.5))   # log(growth) linear between depths 1 and 2
    assert new["depth"] == pytest.approx(expected)
    assert len(cid) == 16 and cid not in values
    with pytest.raises(KeyError, match="'chip' is no output of the reductions"):
        refined_values(summary, RefineSpec("depth", "chip"), ("speed", "depth"), values, None)


def test_extend_adds_a_case_beyond_the_end_of_groups_on_one_side_of_the_threshold() -> None:
    """With extend, a group stable at its deepest case gets one deeper (times extend), a group unstable at its
    shallowest one shallower (divided by extend); a bracketed group is refined as without it; a group with a failed
    case is left alone; the next round then refines the bracket the new case makes."""
    summary = _summary([
        ("a1", 100.0, 1.0, 0.5, "ok"), ("a2", 100.0, 2.0, math.e, "ok"),              # bracketed
        ("b1", 200.0, 1.0, 0.2, "ok"), ("b2", 200.0, 2.0, 0.4, "ok"),                 # stable throughout
        ("c1", 300.0, 1.0, 0.5, "ok"), ("c2", 300.0, 2.0, 0.9, "failed"),             # failed: left alone
        ("e1", 500.0, 1.0, 1.5, "ok"), ("e2", 500.0, 2.0, 4.0, "ok"),                 # unstable throughout
    ])
    values = {cid: {"speed": s, "depth": d} for cid, s, d, _, _ in summary.itertuples(index=False, name=None)}
    assert len(refined_values(summary, RefineSpec("depth", "growth"), ("speed", "depth"), values, None)) == 1
    made = refined_values(summary, RefineSpec("depth", "growth", extend=1.5), ("speed", "depth"), values, None)
    by_speed = {new["speed"]: new["depth"] for _, new in made}
    assert set(by_speed) == {100.0, 200.0, 500.0}
    assert by_speed[200.0] == pytest.approx(3.0) and by_speed[500.0] == pytest.approx(1.0 / 1.5)
    (deeper,) = [cid for cid, new in made if new["speed"] == 200.0]
    summary = pd.concat([summary, _summary([(deeper, 200.0, 3.0, 2.0, "ok")])], ignore_index=True)
    values[deeper] = {"speed": 200.0, "depth": 3.0}
    again = {new["speed"]: new["depth"] for _, new in
             refined_values(summary, RefineSpec("depth", "growth", extend=1.5), ("speed", "depth"), values, None)}
    assert 2.0 < again[200.0] < 3.0  # refined inside the bracket the extension made


BASE = f"""\
[study]
name = "refined"
base = "{CHATTER.as_posix()}"
[study.grid]
force.spindle_speed = {{ values = [11000], unit = "rpm" }}
"force.axial_depth" = {{ values = [0.03, 0.0456], unit = "mm" }}
[[study.reduce]]
kind = "chatter_growth"
"""


@pytest.mark.parametrize(("body", "key", "message"), [
    ("[study.refine]\nvariable = \"force.Ktc\"\noutput = \"chip_growth\"\n", "[study.refine].variable",
     "one of the cases' variables"),
    ("[study.refine]\nvariable = \"force.axial_depth\"\n", "[study.refine].output", "name of an output"),
    ("[study.refine]\nvariable = \"force.axial_depth\"\noutput = \"g\"\nrounds = 0\n", "[study.refine].rounds",
     "from 1 to 20"),
    ("[study.refine]\nvariable = \"force.axial_depth\"\noutput = \"g\"\nscale = \"exp\"\n", "[study.refine].scale",
     "\"log\" or \"linear\""),
    ("[study.refine]\nvariable = \"force.axial_depth\"\noutput = \"g\"\nthreshold = 0\n",
     "[study.refine].threshold", "> 0 with scale"),
    ("[study.refine]\nvariable = \"force.axial_depth\"\noutput = \"g\"\nsteps = 2\n", "[study.refine].steps",
     "unknown key"),
    ("[study.refine]\nvariable = \"force.axial_depth\"\noutput = \"g\"\nextend = 1\n", "[study.refine].extend",
     "a factor above 1"),
])
def test_bad_refine_tables_name_the_key(tmp_path: Path, fmu_dir: Path, body: str, key: str, message: str) -> None:
    path = tmp_path / "study.toml"
    path.write_text(BASE + body)
    with pytest.raises(StudyError) as info:
        load_study(path, fmu_dir)
    assert (info.value.path, info.value.key) == (path, key), str(info.value)
    assert message in info.value.detail


def test_an_output_no_reduction_gives_fails_naming_the_key(tmp_path: Path, fmu_dir: Path) -> None:
    path = tmp_path / "study.toml"
    path.write_text(BASE.replace("0.0456", "0.05") + "[study.refine]\nvariable = \"force.axial_depth\"\n"
                    "output = \"chip\"\n")
    with pytest.raises(StudyError) as info:
        sweep(load_study(path, fmu_dir), tmp_path / "out", workers=0, progress=False)
    assert info.value.key == "[study.refine].output" and "stable, chip_growth" in info.value.detail


def test_refining_the_onset_of_chatter_and_resuming(tmp_path: Path, fmu_dir: Path) -> None:
    """11000 rpm, the 922 Hz tool of scenarios/chatter.toml: the grid brackets the onset between 0.030 and 0.0456 mm;
    three rounds narrow the bracket to a small part of that, around the onset the bracket's interpolation gives."""
    path = tmp_path / "study.toml"
    path.write_text(BASE + "[study.refine]\nvariable = \"force.axial_depth\"\noutput = \"chip_growth\"\n"
                           "rounds = 3\n")
    study = load_study(path, fmu_dir)
    result = sweep(study, tmp_path / "out", workers=0, progress=False)
    summary = result.summary
    assert result.failed == 0 and len(summary) == result.ran and 3 <= result.ran <= 5
    assert list(result.phases) == ["executor start", "cases", "refinement", "executor close"]
    first = onset_of(11000, [0.03e-3, 0.0456e-3], summary["chip_growth"].to_numpy()[:2])
    refined = onset_of(11000, summary["force.axial_depth"], summary["chip_growth"])
    assert refined.unstable_depth - refined.stable_depth < 0.25 * (0.0456e-3 - 0.03e-3)
    assert refined.stable_depth <= refined.depth <= refined.unstable_depth
    assert abs(refined.depth / first.depth - 1) < 0.1
    doc = (result.folder / "study.json").read_text()
    assert "[study.refine] round 1" in doc
    again = sweep(study, tmp_path / "out", workers=0, resume=True, progress=False)
    assert (again.ran, again.skipped) == (0, len(summary))
    columns = [c for c in summary.columns if c != "wall_time"]
    pd.testing.assert_frame_equal(again.summary[columns], summary[columns])
    assert np.isfinite(summary["chip_growth"]).all()

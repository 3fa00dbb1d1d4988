"""milling_twin.orchestrator.recording_checks: impossible transitions found, segments cut, policies applied."""
from __future__ import annotations

import numpy as np
import pytest

from milling_twin.orchestrator.recording_checks import CheckLimits, RepairError, check_recording

LIMITS = CheckLimits(max_axis_speed=(0.05, 0.05, 0.05), timing_jitter=0.0, resolution=(1e-4, 1e-4, 1e-4))


def _line(n: int, start: float, speed: float = 0.01, dt: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """A move along x at ``speed`` (m/s): positions and velocities of n rows."""
    x = start + speed * dt * np.arange(n)
    positions = np.column_stack([x, np.zeros(n), np.zeros(n)])
    velocities = np.column_stack([np.full(n, speed), np.zeros(n), np.zeros(n)])
    return positions, velocities


def test_a_clean_pass_is_one_segment():
    p, v = _line(50, 0.1)
    check = check_recording(p, np.arange(50) * 0.1, LIMITS, velocities=v)
    assert check.clean and [(s.start, s.stop) for s in check.segments] == [(0, 50)] and check.dropped_rows == 0


def test_a_spliced_block_is_cut_out_and_reported():
    p, v = _line(30, 0.1)
    home, home_v = np.tile([0.198, 0.158, 0.119], (10, 1)), np.zeros((10, 3))  # rows of another moment
    p = np.vstack([p[:15], home, p[15:]])
    v = np.vstack([v[:15], home_v, v[15:]])
    t = np.arange(len(p)) * 0.1
    check = check_recording(p, t, LIMITS, velocities=v)
    assert [pr.row for pr in check.problems] == [15, 25] and {pr.kind for pr in check.problems} == {"jump"}
    assert [(s.start, s.stop) for s in check.segments] == [(0, 15), (15, 25), (25, 40)]
    assert "limit 50 mm/s" in check.problems[0].detail
    # drop: one time-ordered pass; the home block is unreachable, the continuation is reachable
    dropped = check_recording(p, t, LIMITS, velocities=v, policy="drop")
    assert [(s.start, s.stop) for s in dropped.segments] == [(0, 15), (25, 40)]
    assert dropped.dropped_rows == 10 and "not reachable" in dropped.reasons[15]
    assert any("impossible transitions" in line for line in dropped.summary())


def test_a_splice_within_the_axis_limits_is_found_by_the_velocities():
    p, v = _line(20, 0.1)
    p[10:] += 0.003  # 3 mm further than the velocities carry it, within the 5 mm a 0.1 s rapid allows
    check = check_recording(p, np.arange(20) * 0.1, LIMITS, velocities=v)
    assert [(pr.row, pr.kind) for pr in check.problems] == [(10, "velocity")]
    assert check_recording(p, np.arange(20) * 0.1, LIMITS).clean  # without velocities it cannot be seen


def test_a_channel_changing_faster_than_its_rate_limit_cuts_too():
    from milling_twin.orchestrator.recording_checks import RateLimit

    p, v = np.zeros((20, 3)), np.zeros((20, 3))  # the axes stand still: only the spindle tells the moments apart
    speed = np.full(20, 335.0)  # rad/s
    speed[8:12] = 0.0  # stopped in rows of another moment
    speed[15:] = 335.0 - 60.0 * np.arange(5)  # braking at 600 rad/s2: possible
    spindle = RateLimit("spindle_speed", speed, max_rate=942.0, resolution=0.6)
    check = check_recording(p, np.arange(20) * 0.1, LIMITS, velocities=v, rates=[spindle])
    assert [(pr.row, pr.kind) for pr in check.problems] == [(8, "rate"), (12, "rate")]
    assert "spindle_speed changes from 335 to 0" in check.problems[0].detail
    assert check.counts()["rate"] == 2


def test_time_going_backwards_and_short_pieces():
    p, v = _line(12, 0.1)
    t = np.arange(12) * 0.1
    t[6] = t[5]
    check = check_recording(p, t, LIMITS, velocities=v)
    assert [(pr.row, pr.kind) for pr in check.problems][0] == (6, "time")
    one_row = check_recording(np.vstack([p[:6], [[0.3, 0.3, 0.3]], p[6:]]), np.arange(13) * 0.1, LIMITS)
    assert [(s.start, s.stop) for s in one_row.dropped_segments] == [(6, 7)]
    assert "shorter than min_segment" in one_row.reasons[6]


def test_storage_resolution_and_jitter_are_allowed():
    limits = CheckLimits(max_axis_speed=(0.05,) * 3, significant_digits=3)
    p, v = _line(40, 0.1, speed=0.05)
    stored = np.round(p * 1e3, 0) / 1e3  # 3 significant digits from 100 mm on: 1 mm steps
    assert check_recording(stored, np.arange(40) * 0.1, limits, velocities=v).clean


def test_reorder_sorts_by_line_numbers_or_says_why_not():
    p, v = _line(30, 0.1)
    first, second = (p[:15], v[:15]), (p[15:], v[15:])
    shuffled_p, shuffled_v = np.vstack([second[0], first[0]]), np.vstack([second[1], first[1]])
    lines = np.concatenate([np.full(15, 20), np.full(15, 10)])
    check = check_recording(shuffled_p, np.arange(30) * 0.1, LIMITS, velocities=shuffled_v, policy="reorder",
                            lines=lines)
    assert [(s.start, s.stop) for s in check.segments] == [(15, 30), (0, 15)]
    with pytest.raises(RepairError, match="overlap"):
        check_recording(shuffled_p, np.arange(30) * 0.1, LIMITS, velocities=shuffled_v, policy="reorder",
                        lines=np.full(30, 10))


@pytest.mark.parametrize("kwargs, message", [({"max_axis_speed": ()}, "positive"),
                                              ({"max_axis_speed": (1.0,), "timing_jitter": -1}, "timing_jitter"),
                                              ({"max_axis_speed": (1.0,), "min_segment": 0}, "min_segment")])
def test_bad_limits_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CheckLimits(**kwargs)


# --------------------------------------------------------------------------- [recorded.checks] in a scenario

SCENARIO = """\
[scenario]
name = "spliced"
output_interval = 0.1
[fmus.power]
fmu = "SpindlePower"
step_size = 0.01
[fmus.power.parameters]
P_standby = 0.0
P_idle = 100.0
c1 = 0.0
[recorded]
file = "spliced.csv"
sample_period = 0.1
[recorded.channels]
x = { column = "x", unit = "mm" }
y = { column = "y", unit = "mm" }
z = { column = "z", unit = "mm" }
speed = { column = "speed", unit = "rev/s" }
on = { column = "speed", unit = "rev/s", above = 1.0 }
power = { column = "power", unit = "W" }
[recorded.checks]
positions = ["x", "y", "z"]
max_axis_speed = { value = 50.0, unit = "mm/s" }
resolution = { value = 0.1, unit = "mm" }
[[inputs]]
from = "speed"
to = "power.spindle_speed"
[[inputs]]
from = "on"
to = "power.spindle_on"
[[compare]]
simulated = "power.P_total"
recorded = "power"
"""


def _spliced_csv() -> str:
    """20 rows cutting at 53 rev/s (100 W) moving along x, with 6 rows of another moment (at home, spindle
    stopped, 0 W) spliced in after row 8."""
    rows = ["x,y,z,speed,power"]
    cutting = [(100 + 0.5 * k, 50.0, 20.0, 53.0, 100.0) for k in range(20)]
    home = [(198.0, 158.0, 119.0, 0.0, 0.0)] * 6
    for r in cutting[:8] + home + cutting[8:]:
        rows.append(",".join(f"{v:g}" for v in r))
    return "\n".join(rows) + "\n"


def test_a_scenario_checks_its_recording_and_compares_only_consistent_rows(tmp_path, fmu_dir):
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.report import write_report
    from milling_twin.orchestrator.scenario import load_scenario

    (tmp_path / "spliced.csv").write_text(_spliced_csv())
    (tmp_path / "s.toml").write_text(SCENARIO)
    scenario = load_scenario(tmp_path / "s.toml", fmu_dir)
    check = scenario.recorded.check
    assert [(p.row, p.kind) for p in check.problems] == [(8, "jump"), (14, "jump")]
    assert [(s.start, s.stop) for s in check.segments] == [(0, 8), (8, 14), (14, 26)]
    result = run(scenario, tmp_path / "runs", progress=False)
    report = write_report(scenario, result.run_dir)
    # the rows at which a segment starts (and t = 0) are left out: the step into them joins two moments
    assert report.comparisons[0].n_samples == 26 - 3
    # the spindle edges at the cuts fall between samples: no sample pays a full edge
    assert report.comparisons[0].max_error < 1e-9
    doc = __import__("json").loads(report.path.read_text())
    assert doc["recording_check"]["problems"]["jump"] == 2 and doc["recording_check"]["segments_used"] == 3


@pytest.mark.parametrize("edit, key", [
    ('positions = ["x", "y", "z"]', '[recorded.checks].positions'),
    ('max_axis_speed = { value = 50.0, unit = "mm/s" }', '[recorded.checks].max_axis_speed'),
])
def test_mistakes_in_the_checks_table_name_the_key(tmp_path, fmu_dir, edit, key):
    from milling_twin.orchestrator.scenario import ScenarioError, load_scenario

    (tmp_path / "spliced.csv").write_text(_spliced_csv())
    broken = {'positions = ["x", "y", "z"]': 'positions = ["x", "y", "speed"]',
              'max_axis_speed = { value = 50.0, unit = "mm/s" }': 'max_axis_speed = { value = 50.0, unit = "mm" }'}
    (tmp_path / "s.toml").write_text(SCENARIO.replace(edit, broken[edit]))
    with pytest.raises(ScenarioError) as info:
        load_scenario(tmp_path / "s.toml", fmu_dir)
    assert str(info.value).startswith(f"{tmp_path / 's.toml'}: {key}: "), str(info.value)
    assert str(info.value).count(key) == 1, str(info.value)


def test_the_run_command_reads_another_recording_and_says_what_its_check_found(tmp_path, fmu_dir, capsys):
    from milling_twin.cli import main

    (tmp_path / "spliced.csv").write_text(_spliced_csv())
    (tmp_path / "s.toml").write_text(SCENARIO.replace('file = "spliced.csv"', 'file = "absent.csv"'))
    code = main(["run", str(tmp_path / "s.toml"), "--recording", str(tmp_path / "spliced.csv"), "--fmu-dir",
                 str(fmu_dir), "--out", str(tmp_path / "runs"), "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "recording check: 26 rows; 2 impossible transitions (2 jumps beyond the axis limits" in out
    assert "3 segments used" in out and "(23 samples)" in out

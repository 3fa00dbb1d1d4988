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

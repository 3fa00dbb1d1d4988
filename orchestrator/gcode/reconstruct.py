"""Reconstruct a part program from a recorded CNC run that holds the commanded axis positions, the feed and
the G-code line being executed, but not the program text (the UMich "CNC Mill Tool Wear" runs,
scenarios/data/). The result runs on the Interpolator FMU (scenarios/umich_motion.toml).

    milling-twin reconstruct scenarios/data/umich_experiment_01.csv \\
        -o scenarios/programs/umich_01.nc

Method (each step documented in the program's header):

1. Line numbers: ``M1_sequence_number`` with its logging artefact removed: a sample that differs from both
   neighbours while those agree (the value 2 about once a second) takes the neighbours' value.
2. Positions: the commanded positions are quantised (X to 1 mm, Y and Z to 0.1 mm) but the commanded
   velocities are not. Per axis, the positions p_k at the samples minimise
   sum_k (p_k - q_k)^2 / s_q^2 + sum_k (p_k+1 - p_k - dt (v_k + v_k+1) / 2)^2 / s_v^2
   (q: recorded position, v: commanded velocity, s_q = quantum / sqrt(12), s_v = 0.05 mm): the quantised
   positions anchor the integrated velocities. A linear least-squares problem (tridiagonal), solved exactly.
3. Blocks: the interval between two samples belongs to the line executing at its end. The intervals of one
   line, in order, form a polyline, simplified (Douglas-Peucker, 0.05 mm) into G1 moves carrying the line as
   their N word (the Interpolator's block_number output then matches M1_sequence_number). Intervals without
   motion are dropped: the program has no dwell, so pauses of the recording are not in it.
4. Feed: ``M1_CURRENT_FEEDRATE`` (mm/s) of the line's samples (the most frequent value), as F in mm/min;
   lines at the positioning feed (50 mm/s: Prep, Repositioning, End) become rapid moves G0 (run them with
   rapid_feed = 50 mm/s).
5. Spindle: ``S1_ActualVelocity`` (controller units read as rev/s, scenarios/data/PROVENANCE.md) above 1 starts
   the spindle (S in rpm, M3) before the first move of the line where it runs, below stops it (M5).

Arcs are written only where the samples lie within ARC_TOLERANCE of the circle and its radius is at most
MAX_ARC_RADIUS (500 mm); straight moves otherwise, so no arc centre lies far off the machine.

The commanded positions are machine coordinates in mm; the program uses G21 G90 G54 with G54 = 0.

Recordings that are not one pass (rows of other moments spliced in: UMich runs 02-12) are cut by
:mod:`milling_twin.orchestrator.recording_checks` (commanded positions and velocities, axes at most 50 mm/s,
3 significant digits, policy ``segment``) into consistent segments, and :func:`reconstruct_segments` writes one
program per segment (``milling-twin reconstruct`` does so when the check finds any impossible transition;
a clean recording keeps the single program above). A segment program starts at the segment's first fused
position (``start_x/y/z``), writes every move as G1, and its feeds make the Interpolator take the recorded
time over each move: the feed is the move's length over its recorded time (pauses are added to the next move),
then corrected against the Interpolator's own schedule (models/interpolator, INTERPOLATOR_PARAMETERS) until every
move is within 1 %. The program is checked by the Interpolator's parser and path builder; one it refused would
be rebuilt with straight moves only. Segments of fewer than MIN_SEGMENT_ROWS rows or without motion get no
program (the index says which and why).

    milling-twin reconstruct ../shared/data/umich_cnc/experiment_11.csv -o runs/umich_11
    # runs/umich_11/seg_000.nc ..., runs/umich_11/segments.csv
"""
from __future__ import annotations

import argparse
import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.linalg import solve_banded
from scipy.optimize import minimize_scalar

from milling_twin.orchestrator.input_files import open_input
from milling_twin.orchestrator.recording_checks import CheckLimits, RecordingCheck, check_recording

SAMPLE_PERIOD = 0.1          # s, the recordings' row spacing
SIGNIFICANT_DIGITS = 3       # the recorded positions' resolution: 1 mm from 100 mm on, 0.1 mm below
VELOCITY_SIGMA = 0.005       # mm: error of integrating the commanded velocity over a sample period, plus
VELOCITY_CHANGE_SIGMA = 0.25  # times |velocity change| * period (the trapezoid rule where the velocity changes)
LINE_TOLERANCE = 0.1         # mm: a recorded line whose samples lie this close to a line is one G1/G0
ARC_TOLERANCE = 0.1          # mm: ... to a circle (through its end points, in a plane of constant Z): G2/G3
SIMPLIFY_TOLERANCE = 0.05    # mm: otherwise a polyline, simplified (Douglas-Peucker)
FLAT = 0.05                  # mm: Z range of an arc in the XY plane
RAPID_FEED = 50.0            # mm/s: the positioning feed of the recordings
ARTEFACT = 2                 # the line number the logger writes about once a second
SPINDLE_ON = 1.0             # S1_ActualVelocity above which the spindle runs
MIN_MOTION = 1e-3            # mm: shorter intervals are no motion
STOPPED = 0.05               # mm/s: commanded speed below which the tool stands
CORNER_ANGLE = 0.35          # rad: a turn of the commanded velocity between two samples that is a corner
CORNER_REACH = 1.0           # mm: how far a corner may lie from the sample taken for it
MAX_ARC_RADIUS = 500.0       # mm: no arc of a larger radius (the machine's travel is under 500 mm; a wider
                             # "arc" is a near-straight line whose centre the samples cannot fix)
MIN_SEGMENT_ROWS = 2         # rows: a shorter consistent segment (one row) gets no program
SEGMENT_MOTION = 0.1         # mm: a segment whose path is shorter has no motion: its program stands still
TIMING_DEVIATION = 0.05      # mm: segment programs merge samples into one move only where its constant feed
                             # puts every merged sample at most this far along the path from its recorded place
PREROLL = 0.5 * SAMPLE_PERIOD  # s: a segment program that starts in motion starts this long before its first
                             # sample, on the line of the commanded velocity there
TIMING_ITERATIONS = 6        # feed corrections against the Interpolator's schedule (segment programs)
TIMING_TOLERANCE = 0.01      # relative: stop correcting when every move is this close to its recorded time
MIN_FEED = 0.01              # mm/s: the slowest feed written (a move that absorbs a long pause)
#: the Interpolator as the segment programs are run (SI; scenarios/umich_motion.toml otherwise): the feeds
#: are corrected against its schedule with these limits. A segment is cut out of a moving machine but its
#: program starts and ends at rest: with the recording's 1 m/s2 a 50 mm/s move needs 0.06 s to start, 7 %
#: of a 0.9 s segment, and a 7 mm first sample cannot be reached in 0.1 s at all. So the segment programs
#: run with ten times the acceleration and jerk (ramps of ~6 ms) and feeds up to 100 mm/s, which make up
#: the ramps' time; the path and, between the ends, the timing are the recording's.
INTERPOLATOR_PARAMETERS = {"period": 1e-3, "rapid_feed": 0.05, "max_feed": 0.1, "acceleration": 10.0,
                           "jerk": 1000.0, "centripetal_acceleration": 10.0, "axis_acceleration_x": 20.0,
                           "axis_acceleration_y": 20.0, "axis_acceleration_z": 20.0, "axis_jerk_x": 3000.0,
                           "axis_jerk_y": 3000.0, "axis_jerk_z": 3000.0}


@dataclass
class Block:
    """One recorded line: its moves, feed (mm/s), rapid flag and spindle speed (rpm, 0 = stopped). Each move
    is ("G1", end) or ("G2"/"G3", end, centre) with points in mm."""

    sequence: int
    moves: list[tuple]
    feed: float
    rapid: bool
    spindle_rpm: float
    first_sample: int
    last_sample: int
    kind: str = "line"               # "line", "arc", "preroll" (before the first sample), "standing" (no move)


@dataclass
class Reconstruction:
    source: Path
    start: tuple[float, float, float]
    blocks: list[Block]
    positions: np.ndarray            # fused positions at the samples (n x 3, mm)
    sequence: np.ndarray             # cleaned line numbers at the samples
    stats: dict[str, float] = field(default_factory=dict)
    header: list[str] = field(default_factory=list)  # comment lines replacing the default note on N and F
    move_lines: list[int] = field(default_factory=list)  # program line (1-based) of each block's move, as written
    preroll: float = 0.0             # s before the first sample at which the program starts (segment programs)

    def program(self) -> str:
        return program_text(self)


def clean_sequence(sequence: np.ndarray) -> np.ndarray:
    """The recorded line numbers without the logger's artefact: a single sample reading ARTEFACT, or any value
    differing from both neighbours while those agree, takes the following sample's value."""
    s = np.asarray(sequence, dtype=float).copy()
    n = len(s)
    for k in range(1, n - 1):
        single = s[k] != s[k - 1] and s[k] != s[k + 1]
        if single and (s[k] == ARTEFACT or s[k - 1] == s[k + 1]):
            s[k] = s[k + 1]
    return s.astype(int)


def quantum_of(values: np.ndarray) -> np.ndarray:
    """Resolution of values stored with three significant digits."""
    magnitude = np.floor(np.log10(np.maximum(np.abs(values), 1e-3)))
    return 10.0 ** (magnitude - (SIGNIFICANT_DIGITS - 1))


def fuse_positions(quantised: np.ndarray, velocity: np.ndarray, dt: float = SAMPLE_PERIOD,
                   robust: bool = False) -> np.ndarray:
    """Least-squares positions of one axis from positions stored with three significant digits and the commanded
    velocities: minimise sum (p_k - q_k)^2 / s_q,k^2 + sum (p_k+1 - p_k - dt (v_k + v_k+1) / 2)^2 / s_v,k^2 with
    s_q = quantum / sqrt(12) and s_v = VELOCITY_SIGMA + VELOCITY_CHANGE_SIGMA |v_k+1 - v_k| dt. ``robust``: where
    the stored positions' difference and the integrated velocities disagree by more than the rounding of the two
    positions allows (half a step each, plus s_v), the two velocity samples do not describe the interval (the
    machine stopped between them, at the end of a block, while both samples read full speed): s_v is then that
    disagreement, and the positions decide."""
    q = np.asarray(quantised, dtype=float)
    v = np.asarray(velocity, dtype=float)
    n = len(q)
    quantum = quantum_of(q)
    wq = 12.0 / quantum ** 2
    s_v = VELOCITY_SIGMA + VELOCITY_CHANGE_SIGMA * np.abs(np.diff(v)) * dt
    d = dt * 0.5 * (v[1:] + v[:-1])
    if robust and n > 1:
        disagreement = np.abs(np.diff(q) - d)
        allowed = 0.5 * (quantum[1:] + quantum[:-1]) + s_v
        s_v = np.where(disagreement > allowed, np.maximum(disagreement, s_v), s_v)
    wv = 1.0 / s_v ** 2
    diagonal = wq.copy()
    diagonal[:-1] += wv
    diagonal[1:] += wv
    rhs = wq * q
    rhs[:-1] -= wv * d
    rhs[1:] += wv * d
    banded = np.zeros((3, n))
    banded[0, 1:] = -wv
    banded[1] = diagonal
    banded[2, :-1] = -wv
    return solve_banded((1, 1), banded, rhs)


def simplify(points: np.ndarray, tolerance: float) -> list[int]:
    """Indices kept by Douglas-Peucker (first and last always), iterative."""
    n = len(points)
    if n <= 2:
        return list(range(n))
    keep = np.zeros(n, dtype=bool)
    keep[0] = keep[-1] = True
    stack = [(0, n - 1)]
    while stack:
        a, b = stack.pop()
        if b <= a + 1:
            continue
        dist = _distances_to_segment(points[a + 1:b], points[a], points[b])
        k = int(np.argmax(dist))
        if dist[k] > tolerance:
            keep[a + 1 + k] = True
            stack += [(a, a + 1 + k), (a + 1 + k, b)]
    return [int(i) for i in np.nonzero(keep)[0]]


def _distances_to_segment(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    seg = b - a
    length2 = float(seg @ seg)
    rel = points - a
    t = np.clip(rel @ seg / length2, 0.0, 1.0) if length2 > 0 else np.zeros(len(points))
    return np.linalg.norm(rel - np.outer(t, seg), axis=1)


def _line_fit(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Centroid, unit direction and the largest distance of the points from that line."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre)
    direction = vt[0]
    rel = points - centre
    deviation = np.linalg.norm(rel - np.outer(rel @ direction, direction), axis=1)
    return centre, direction, float(deviation.max()) if len(points) else 0.0


def _arc_through(start: np.ndarray, end: np.ndarray, samples: np.ndarray) -> tuple[np.ndarray, bool, float] | None:
    """The circle in the XY plane through start and end that fits the samples best: (centre, counter-clockwise,
    largest radial deviation), or None when there is no arc (too few samples, not planar, a full turn)."""
    if len(samples) < 3:
        return None
    if np.ptp(np.concatenate([samples[:, 2], [start[2], end[2]]])) > FLAT:
        return None
    s, e = start[:2], end[:2]
    chord = e - s
    length = float(np.hypot(*chord))
    if length < 1e-6:
        return None
    mid = 0.5 * (s + e)
    normal = np.array([-chord[1], chord[0]]) / length
    pts = samples[:, :2]

    def cost(t: float) -> float:
        c = mid + t * normal
        return float(np.sum((np.linalg.norm(pts - c, axis=1) - np.linalg.norm(s - c)) ** 2))

    # the sagitta of the samples gives a starting point: t = (h^2 - (L/2)^2) / (2h) for a height h
    heights = (pts - mid) @ normal
    h = heights[np.argmax(np.abs(heights))]
    if abs(h) < 1e-9:
        return None
    t0 = (h * h - 0.25 * length * length) / (2.0 * h)
    result = minimize_scalar(cost, bracket=(t0 - abs(t0) - 1.0, t0 + abs(t0) + 1.0))
    c = mid + float(result.x) * normal
    radius = float(np.linalg.norm(s - c))
    if not np.isfinite(radius) or radius > MAX_ARC_RADIUS:
        return None
    deviation = float(np.max(np.abs(np.linalg.norm(pts - c, axis=1) - radius)))
    # direction from the samples' angles, which must progress monotonically from start to end
    angles = np.unwrap(np.arctan2(np.concatenate([[s[1]], pts[:, 1], [e[1]]]) - c[1],
                                  np.concatenate([[s[0]], pts[:, 0], [e[0]]]) - c[0]))
    steps = np.diff(angles)
    ccw = bool(steps.sum() > 0)
    if not (np.all(steps >= -1e-3) if ccw else np.all(steps <= 1e-3)) or abs(angles[-1] - angles[0]) > 2 * np.pi - 1e-3:
        return None
    centre = np.array([c[0], c[1], start[2]])
    return centre, ccw, deviation


def _pieces(fused: np.ndarray, velocity: np.ndarray, feed: np.ndarray) -> list[tuple[int, int]]:
    """Sample ranges [a, b] of continuous motion: split where the tool stops, where the feed changes and at
    corners (the commanded velocity turns by more than CORNER_ANGLE between two samples)."""
    speed = np.linalg.norm(velocity, axis=1)
    step = np.linalg.norm(np.diff(fused, axis=0), axis=1)
    pieces = []
    a = None
    for k in range(1, len(fused)):
        moving = step[k - 1] > MIN_MOTION
        if a is not None:
            corner = False
            if speed[k] > STOPPED and speed[k - 1] > STOPPED:
                cos = velocity[k] @ velocity[k - 1] / (speed[k] * speed[k - 1])
                corner = cos < math.cos(CORNER_ANGLE)
            if not moving or feed[k] != feed[k - 1] or corner:
                pieces.append((a, k - 1 if not moving else k))
                a = None if not moving else k
                continue
        if a is None and moving:
            a = k - 1
    if a is not None:
        pieces.append((a, len(fused) - 1))
    return [(a, b) for a, b in pieces if b > a]


def _evenly_timed(along: np.ndarray, i: int, j: int, tolerance: float | None) -> bool:
    """Whether one move at a constant feed from point i to point j (samples evenly spaced in time) passes every
    sample between them within ``tolerance`` (mm along the path, ``along``: cumulative path length at the
    points) of where it was recorded; always true without a tolerance."""
    if tolerance is None or j <= i + 1:
        return True
    uniform = along[i] + (along[j] - along[i]) * np.arange(1, j - i) / (j - i)
    return bool(np.max(np.abs(along[i + 1:j] - uniform)) <= tolerance)


def _fit_piece(points: np.ndarray, allow_arcs: bool,
               timing: float | None = None) -> list[tuple[str, int, np.ndarray | None]]:
    """Greedy: from each point, the line or arc (through its end points) reaching farthest within tolerance.
    ``timing`` (mm, segment programs): also at most that far along the path from a constant-feed move's place
    at every merged sample (:func:`_evenly_timed`), so that speed changes between samples split moves.
    Returns (kind, index of the end point, centre) per primitive."""
    out = []
    i, n = 0, len(points)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    while i < n - 1:
        j_line = i + 1
        for j in range(i + 2, n):
            if (np.max(_distances_to_segment(points[i + 1:j], points[i], points[j])) <= LINE_TOLERANCE
                    and _evenly_timed(along, i, j, timing)):
                j_line = j
            else:
                break
        j_arc, centre_arc, ccw_arc = -1, None, True
        if allow_arcs:
            for j in range(i + 3, n):
                arc = _arc_through(points[i], points[j], points[i + 1:j])
                if arc is not None and arc[2] <= ARC_TOLERANCE and _evenly_timed(along, i, j, timing):
                    j_arc, centre_arc, ccw_arc = j, arc[0], arc[1]
                elif j > j_line + 1:
                    break
        if j_arc > j_line:
            out.append(("G3" if ccw_arc else "G2", j_arc, centre_arc))
            i = j_arc
        else:
            out.append(("G1", j_line, None))
            i = j_line
    return out


def _read_recording(path: str | Path) -> pd.DataFrame:
    """A recording (CSV) as a frame, read from a regular file only (orchestrator/input_files.py)."""
    with open_input(path, "recording") as fh:
        return pd.read_csv(fh)


def reconstruct(path: Path) -> Reconstruction:
    """The program of a whole recording as one pass (run 01: scenarios/programs/umich_01.nc)."""
    return _reconstruct_rows(_read_recording(path), Path(path))


def _reconstruct_rows(data: pd.DataFrame, path: Path, allow_arcs: bool = True,
                      timed: bool = False) -> Reconstruction:
    """The blocks of ``data``'s rows. ``timed`` (segment programs): moves keep the recorded timing of every
    sample (TIMING_DEVIATION), corners stay at the samples, and a recording that is in motion at its first row
    gets a pre-roll move (PREROLL s along the commanded velocity there) before it."""
    data = data.reset_index(drop=True)
    n = len(data)
    sequence = clean_sequence(data["M1_sequence_number"].to_numpy())
    fused = np.column_stack([
        fuse_positions(data[f"{a}1_CommandPosition"].to_numpy(), data[f"{a}1_CommandVelocity"].to_numpy(),
                       robust=timed)
        for a in "XYZ"])
    velocity = np.column_stack([data[f"{a}1_CommandVelocity"].to_numpy(dtype=float) for a in "XYZ"])
    feed = data["M1_CURRENT_FEEDRATE"].to_numpy(dtype=float)
    spindle = data["S1_ActualVelocity"].to_numpy(dtype=float)
    running = spindle > SPINDLE_ON
    nominal_rpm = round(float(np.median(spindle[running])) * 60.0 / 10.0) * 10.0 if running.any() else 0.0
    blocks: list[Block] = []
    position = fused[0]
    previous_end = 0
    for a, b in _pieces(fused, velocity, feed):
        points = fused[a:b + 1].copy()
        points[0] = position if np.linalg.norm(points[0] - position) <= 2 * LINE_TOLERANCE else points[0]
        values, counts = np.unique(feed[a + 1:b + 1], return_counts=True)
        f = float(values[np.argmax(counts)])
        rapid = f >= RAPID_FEED
        if np.linalg.norm(points[0] - position) > MIN_MOTION:  # a jump: join it with a straight move
            mid = (previous_end + a) // 2
            blocks.append(Block(int(sequence[mid]), [("G1", tuple(points[0]))], f, rapid,
                                nominal_rpm if running[mid] else 0.0, previous_end, a, "line"))
        start = 0
        for kind, j, centre in _fit_piece(points, allow_arcs and not rapid, TIMING_DEVIATION if timed else None):
            mid = a + (start + j + 1) // 2
            move = (kind, tuple(points[j])) if centre is None else (kind, tuple(points[j]), tuple(centre))
            blocks.append(Block(int(sequence[min(mid, b)]), [move], f, rapid,
                                nominal_rpm if running[min(mid, b)] else 0.0, a + start, a + j,
                                "line" if centre is None else "arc"))
            start = j
        position = points[-1]
        previous_end = b
    start = tuple(map(float, fused[0]))
    preroll = 0.0
    if timed:
        # a segment cut out of a moving machine: the program starts PREROLL before the first sample, on the line
        # of the commanded velocity there, and reaches the first sample at the recorded speed (the actual
        # position lags the commanded one, so the first samples lie before the first commanded position)
        reach = PREROLL * velocity[0]
        if blocks and blocks[0].first_sample == 0 and np.linalg.norm(reach) > MIN_MOTION:
            start = tuple(map(float, fused[0] - reach))
            preroll = PREROLL
            blocks.insert(0, Block(int(sequence[0]), [("G1", tuple(map(float, fused[0])))],
                                   float(np.linalg.norm(velocity[0])), False, nominal_rpm if running[0] else 0.0,
                                   0, 0, "preroll"))
    else:
        _refine_corners(blocks)
    recon = Reconstruction(path, start, blocks, fused, sequence, preroll=preroll)
    kinds = [blk.kind for blk in blocks]
    recon.stats = {"samples": float(n), "duration": n * SAMPLE_PERIOD, "moves": float(len(blocks)),
                   "lines": float(kinds.count("line")), "arcs": float(kinds.count("arc")),
                   "artefacts_removed": float(np.sum(sequence != data["M1_sequence_number"].to_numpy()))}
    return recon


def _refine_corners(blocks: list[Block]) -> None:
    """Where two straight moves meet at a corner, the corner lies between two samples: move the shared point
    to where the two lines (through their other ends) meet, when that is close."""
    for k in range(1, len(blocks) - 1):
        m0, m1 = blocks[k].moves[0], blocks[k + 1].moves[0]
        if m0[0] != "G1" or m1[0] != "G1" or not blocks[k - 1].moves:
            continue
        p0 = np.array(blocks[k - 1].moves[-1][1])
        corner = np.array(m0[1])
        p1 = np.array(m1[1])
        d0, d1 = corner - p0, p1 - corner
        l0, l1 = np.linalg.norm(d0), np.linalg.norm(d1)
        if l0 < 1e-6 or l1 < 1e-6 or abs(d0 @ d1) / (l0 * l1) > math.cos(CORNER_ANGLE):
            continue
        # extend both lines: closest points of p0 + s d0 and p1 - t d1
        u0, u1 = d0 / l0, -d1 / l1
        w = p0 - p1
        b = u0 @ u1
        denom = 1.0 - b * b
        if denom < 1e-9:
            continue
        s = (b * (u1 @ w) - (u0 @ w)) / denom
        t = ((u1 @ w) - b * (u0 @ w)) / denom
        meet = 0.5 * ((p0 + s * u0) + (p1 + t * u1))
        if np.linalg.norm(meet - corner) <= CORNER_REACH and s > 0 and t > 0:
            blocks[k].moves[0] = ("G1", tuple(meet))


def _mm(x: float) -> str:
    text = f"{x:.3f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def _digest(path: Path) -> str:
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if key not in _DIGESTS:
        _DIGESTS[key] = hashlib.sha256(path.read_bytes()).hexdigest()
    return _DIGESTS[key]


_DIGESTS: dict[tuple[str, int, int], str] = {}


def program_text(recon: Reconstruction) -> str:
    digest = _digest(recon.source)
    st = recon.stats
    lines = [
        f"(Reconstructed by orchestrator.gcode.reconstruct from {recon.source.name}, sha256 {digest})",
        f"({int(st['samples'])} samples at {SAMPLE_PERIOD:g} s: {int(st['lines'])} straight moves and "
        f"{int(st['arcs'])} arcs fitted to {LINE_TOLERANCE:g} mm)",
        "(positions: least squares of the commanded positions, stored to 3 significant digits, and velocities)",
        *(recon.header or ["(N = the recorded M1_sequence_number; feed 50 mm/s = G0: run with rapid_feed = "
                           "50 mm/s; no dwells)"]),
        "G21 G90 G17 G54",
        "G0 X{} Y{} Z{}".format(*(_mm(c) for c in recon.start)),
    ]
    feed_now = None
    move_lines: list[int] = []
    recon.move_lines = move_lines
    spindle_now = 0.0
    motion_now = None
    position = np.array([float(_mm(c)) for c in recon.start])
    for block in recon.blocks:
        if block.spindle_rpm != spindle_now:
            lines.append(f"N{block.sequence} S{block.spindle_rpm:g} M3" if block.spindle_rpm > 0
                         else f"N{block.sequence} M5")
            spindle_now = block.spindle_rpm
        for move in block.moves:
            code = "G0" if block.rapid else move[0]
            words = [f"N{block.sequence}"]
            if code != motion_now:
                words.append(code)
                motion_now = code
            end = np.array([float(_mm(c)) for c in move[1]])
            words += [f"X{_mm(end[0])}", f"Y{_mm(end[1])}", f"Z{_mm(end[2])}"]
            if code in ("G2", "G3"):
                words += [f"I{_mm(move[2][0] - position[0])}", f"J{_mm(move[2][1] - position[1])}"]
            if code != "G0" and block.feed != feed_now:
                words.append(f"F{_mm(block.feed * 60.0)}")
                feed_now = block.feed
            lines.append(" ".join(words))
            move_lines.append(len(lines))
            position = end
    if spindle_now:
        lines.append("M5")
    lines.append("M30")
    return "\n".join(lines) + "\n"


# -- per-segment programs ---------------------------------------------------------------------------------

#: the recordings' physical limits for recording_checks (SI): every axis at most the positioning feed of
#: 50 mm/s, positions stored with 3 significant digits
CHECK_LIMITS = CheckLimits(max_axis_speed=(RAPID_FEED * 1e-3,) * 3, significant_digits=SIGNIFICANT_DIGITS,
                           min_segment=MIN_SEGMENT_ROWS)


@dataclass
class SegmentProgram:
    """One consistent segment of a recording (data rows ``start`` .. ``stop - 1``): its program, or why it
    has none. ``recorded_time``: s from the segment's first to its last sample with motion (what the
    program reproduces: it has no dwell, so stationary rows before the first and after the last motion
    are not in it; pauses between motions are spread over the next move); ``simulated_time``: the
    program's duration on the Interpolator (its schedule with :data:`INTERPOLATOR_PARAMETERS`)."""

    index: int
    start: int
    stop: int
    reason: str = ""                 # why there is no program ("" when there is one)
    recon: Reconstruction | None = None
    recorded_time: float = 0.0
    simulated_time: float = 0.0
    worst_move: float = 0.0          # largest |simulated / recorded - 1| of a single move

    @property
    def rows(self) -> int:
        return self.stop - self.start

    @property
    def name(self) -> str:
        return f"seg_{self.index:03d}"

    @property
    def motion_start(self) -> float | None:
        """Recorded time (s, rows at SAMPLE_PERIOD from row 0) at which the program starts: the segment's
        first motion (less the pre-roll of a segment that starts in motion); the first row of a standing
        segment."""
        if self.recon is None or not self.recon.blocks:
            return None
        return (self.start + self.recon.blocks[0].first_sample) * SAMPLE_PERIOD - self.recon.preroll

    @property
    def standing(self) -> bool:
        """Whether the segment's program has no move (the tool stands for the whole segment)."""
        return self.recon is not None and all(b.kind == "standing" for b in self.recon.blocks)

    @property
    def ratio(self) -> float:
        return self.simulated_time / self.recorded_time if self.recorded_time > 0 else math.nan


@dataclass
class SegmentedReconstruction:
    source: Path
    check: RecordingCheck
    segments: list[SegmentProgram]

    @property
    def programs(self) -> list[SegmentProgram]:
        return [s for s in self.segments if s.recon is not None]

    @property
    def moving(self) -> list[SegmentProgram]:
        """The programs with motion (their duration is the recorded time)."""
        return [s for s in self.programs if not s.standing]

    def index_frame(self) -> pd.DataFrame:
        rows = []
        for s in self.segments:
            start = tuple(float(_mm(c)) for c in s.recon.start) if s.recon is not None else (math.nan,) * 3
            rows.append({"segment": s.index, "first_row": s.start, "last_row": s.stop - 1, "rows": s.rows,
                         "t_first": s.start * SAMPLE_PERIOD, "t_last": (s.stop - 1) * SAMPLE_PERIOD,
                         "program": f"{s.name}.nc" if s.recon is not None else "",
                         "start_x_mm": start[0], "start_y_mm": start[1], "start_z_mm": start[2],
                         "recorded_time": s.recorded_time, "simulated_time": s.simulated_time,
                         "ratio": s.ratio, "skipped": s.reason})
        return pd.DataFrame(rows)

    def write(self, folder: Path) -> Path:
        """seg_NNN.nc per segment with a program and segments.csv (the index); returns the index path."""
        folder.mkdir(parents=True, exist_ok=True)
        for s in self.programs:
            (folder / f"{s.name}.nc").write_text(s.recon.program())
        index = folder / "segments.csv"
        self.index_frame().to_csv(index, index=False, float_format="%.10g")
        return index


def recording_check(data: pd.DataFrame, limits: CheckLimits = CHECK_LIMITS) -> RecordingCheck:
    """recording_checks on the commanded positions and velocities (mm, mm/s in the file; SI here)."""
    positions = data[[f"{a}1_CommandPosition" for a in "XYZ"]].to_numpy(dtype=float) * 1e-3
    velocities = data[[f"{a}1_CommandVelocity" for a in "XYZ"]].to_numpy(dtype=float) * 1e-3
    return check_recording(positions, np.arange(len(data)) * SAMPLE_PERIOD, limits, velocities=velocities,
                           policy="segment")


def _move_times(text: str, parameters: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(program line, end time in s) of every move of ``text`` on the Interpolator's schedule; raises
    ProgramError/PathError where the Interpolator refuses the program."""
    from milling_twin.models.interpolator.definition import default_parameters
    from milling_twin.models.interpolator.parser import parse_program
    from milling_twin.models.interpolator.path import build_path
    from milling_twin.models.interpolator.schedule import Schedule

    p = {**default_parameters(), **parameters}
    program = parse_program(text, p)
    path = build_path(program, p)
    schedule = Schedule(path, p["max_feed"], p["rapid_feed"])
    schedule.plan(0.0, 0.0, 0.0, 1.0)
    t = np.array([pc.t for pc in schedule.pieces])
    s_at = np.array([pc.s for pc in schedule.pieces])
    ends = np.asarray(path.move_s) + np.asarray(path.move_length)
    times = np.interp(ends, s_at, t) if len(t) > 1 else np.zeros(len(ends))
    return np.array([m.line for m in program.moves], dtype=int), times


def simulated_duration(text: str, start_mm: tuple[float, float, float],
                       parameters: dict[str, float] | None = None) -> float:
    """Duration (s) of a program on the Interpolator's schedule, the tool starting at ``start_mm``."""
    p = {**INTERPOLATOR_PARAMETERS, **(parameters or {}), **_start(start_mm)}
    times = _move_times(text, p)[1]
    return float(times[-1]) if len(times) else 0.0


def _start(start_mm: tuple[float, float, float]) -> dict[str, float]:
    return {f"start_{a}": float(_mm(c)) * 1e-3 for a, c in zip("xyz", start_mm)}


def _move_length(start: np.ndarray, move: tuple) -> float:
    end = np.asarray(move[1])
    if move[0] == "G1":
        return float(np.linalg.norm(end - start))
    centre = np.asarray(move[2])
    a0 = math.atan2(start[1] - centre[1], start[0] - centre[0])
    a1 = math.atan2(end[1] - centre[1], end[0] - centre[0])
    sweep = (a1 - a0) % (2 * math.pi) if move[0] == "G3" else (a0 - a1) % (2 * math.pi)
    return float(math.hypot(np.linalg.norm(start[:2] - centre[:2]) * sweep, end[2] - start[2]))


def _timed(recon: Reconstruction) -> tuple[float, float, float]:
    """Feeds of a segment program from the recorded time of each move, corrected against the Interpolator's
    schedule (its accelerations, corners): (recorded, simulated duration, worst move's |ratio - 1|)."""
    blocks = recon.blocks
    first = blocks[0].first_sample
    ends = np.array([b.last_sample for b in blocks])
    target = np.diff(np.concatenate([[first], ends])) * SAMPLE_PERIOD
    target[[b.kind == "preroll" for b in blocks]] = recon.preroll
    position = np.array([float(_mm(c)) for c in recon.start])
    lengths = []
    for b in blocks:
        lengths.append(_move_length(position, b.moves[0]))
        position = np.asarray(b.moves[0][1], dtype=float)
    lengths = np.maximum(np.array(lengths), 1e-6)
    max_feed = INTERPOLATOR_PARAMETERS["max_feed"] * 1e3
    target = np.maximum(target, lengths / max_feed)  # a move recorded in no time: at the highest feed
    feeds = np.clip(lengths / target, MIN_FEED, max_feed)
    parameters = {**INTERPOLATOR_PARAMETERS, **_start(recon.start)}
    simulated, worst = 0.0, math.inf
    for _ in range(TIMING_ITERATIONS + 1):
        for b, f in zip(blocks, feeds):
            b.feed, b.rapid = float(f), False
        move_line, times = _move_times(program_text(recon), parameters)
        # each block's move ends when the Interpolator's move of its line ends (a move the parser leaves out,
        # of no length, ends with the one before it)
        at = np.searchsorted(move_line, recon.move_lines, side="right") - 1
        block_end = np.where(at >= 0, times[np.clip(at, 0, None)], 0.0)
        per_move = np.diff(np.concatenate([[0.0], block_end]))
        simulated = float(times[-1]) if len(times) else 0.0
        ratio = per_move / target
        worst = float(np.max(np.abs(ratio - 1.0)))
        if worst <= TIMING_TOLERANCE:
            break
        feeds = np.clip(feeds * np.clip(ratio, 0.5, 2.0), MIN_FEED, max_feed)
    return float(target.sum()), simulated, worst


def reconstruct_segments(path: Path, limits: CheckLimits = CHECK_LIMITS) -> SegmentedReconstruction:
    """One program per consistent segment of the recording (recording_checks, policy ``segment``) of at
    least MIN_SEGMENT_ROWS rows: each starts at the segment's first (fused) position (PREROLL earlier when the
    segment starts in motion), writes every move as G1 with the feed that makes the Interpolator take the
    recorded time over it (moves split wherever a constant feed would misplace a sample by more than
    TIMING_DEVIATION along the path), and is checked by the Interpolator's own parser and schedule (a program
    it refuses is rebuilt with straight moves only). A segment without motion gets a program without a move:
    the tool stands at its position, with the spindle as recorded."""
    path = Path(path)
    data = _read_recording(path)
    check = recording_check(data, limits)
    used = {(s.start, s.stop) for s in check.segments}
    pieces = sorted([*check.segments, *check.dropped_segments], key=lambda s: s.start)
    out = []
    for index, seg in enumerate(pieces):
        item = SegmentProgram(index, seg.start, seg.stop)
        out.append(item)
        if (seg.start, seg.stop) not in used:
            item.reason = check.reasons.get(seg.start, "dropped by the recording check")
            continue
        if len(seg) < MIN_SEGMENT_ROWS:
            item.reason = f"shorter than {MIN_SEGMENT_ROWS} rows"
            continue
        rows = data.iloc[seg.start:seg.stop]
        for allow_arcs in (True, False):
            recon = _reconstruct_rows(rows, path, allow_arcs, timed=True)
            travel = float(np.sum(np.linalg.norm(np.diff(recon.positions, axis=0), axis=1)))
            if not recon.blocks or travel < SEGMENT_MOTION:
                item.recon = _standing(recon, rows, index, seg, travel)
                break
            first = ("start_x/y/z = the first position" if not recon.preroll else
                     f"start_x/y/z = {recon.preroll:g} s before the first position along the commanded velocity")
            recon.header = [f"(segment {index}: data rows {seg.start}-{seg.stop - 1}; N = the recorded "
                            "M1_sequence_number; every move G1 at the feed that takes the recorded time; "
                            f"{first})"]
            try:
                item.recorded_time, item.simulated_time, item.worst_move = _timed(recon)
            except ValueError:  # ProgramError, PathError: the Interpolator refuses it
                if allow_arcs:
                    continue
                raise
            item.recon = recon
            break
    return SegmentedReconstruction(path, check, out)


def _standing(recon: Reconstruction, rows: pd.DataFrame, index: int, seg, travel: float) -> Reconstruction:
    """The program of a segment without motion: the tool stands at the segment's first position, the spindle
    runs at the nominal speed if it runs in most rows (a block without a move)."""
    spindle = rows["S1_ActualVelocity"].to_numpy(dtype=float)
    running = spindle > SPINDLE_ON
    rpm = round(float(np.median(spindle[running])) * 60.0 / 10.0) * 10.0 if running.mean() > 0.5 else 0.0
    recon.start = tuple(map(float, recon.positions[0]))
    recon.preroll = 0.0
    recon.blocks = [Block(int(recon.sequence[0]), [], 0.0, False, rpm, 0, len(rows) - 1, "standing")]
    recon.header = [f"(segment {index}: data rows {seg.start}-{seg.stop - 1}; no motion, path {travel:.3g} mm: "
                    "the tool stands at start_x/y/z; N = the recorded M1_sequence_number)"]
    recon.stats["moves"] = 0.0
    _move_times(program_text(recon), {**INTERPOLATOR_PARAMETERS, **_start(recon.start)})  # the parser accepts it
    return recon


def command(args: argparse.Namespace) -> int:
    """``milling-twin reconstruct RECORDING -o OUT``: one program (OUT a file) for a recording that is one
    consistent pass; otherwise one program per consistent segment in the folder OUT (seg_NNN.nc and the
    index segments.csv)."""
    try:
        data = _read_recording(args.recording)
        data["M1_sequence_number"]  # the first column a UMich recording is recognised by
        check = recording_check(data)
        if check.clean:
            recon = reconstruct(args.recording)
    except KeyError as exc:
        raise ValueError(f"{args.recording}: no column {exc}: a UMich recording (CSV) is expected") from exc
    except pd.errors.ParserError as exc:
        raise ValueError(f"{args.recording}: not a readable CSV file: {exc}") from exc
    if check.clean:
        args.output.write_text(recon.program())
        for name, value in recon.stats.items():
            print(f"{name}: {value:g}")
        print(f"wrote {args.output}")
        return 0
    if args.output.exists() and not args.output.is_dir():
        raise ValueError(f"{args.output}: the recording has {len(check.problems)} impossible transitions, so "
                         "one program per consistent segment is written into a folder: give a folder name")
    segmented = reconstruct_segments(args.recording)
    for line in check.summary()[:2]:
        print(line)
    programs = segmented.moving
    skipped: dict[str, int] = {}
    for s in segmented.segments:
        if s.recon is None:
            key = s.reason.split(" (")[0]
            skipped[key] = skipped.get(key, 0) + 1
    print(f"{len(segmented.programs)} programs ({len(segmented.programs) - len(programs)} standing); no program "
          f"for {len(segmented.segments) - len(segmented.programs)} segments"
          + "".join(f"; {count} {reason}" for reason, count in sorted(skipped.items())))
    if programs:
        recorded = sum(s.recorded_time for s in programs)
        simulated = sum(s.simulated_time for s in programs)
        worst = max(programs, key=lambda s: abs(s.ratio - 1.0))
        print(f"duration simulated / recorded: total {simulated:.2f} / {recorded:.2f} s = {simulated / recorded:.4f}; "
              f"worst segment {worst.index} (rows {worst.start}-{worst.stop - 1}) {worst.ratio:.4f}")
    index = segmented.write(args.output)
    print(f"wrote {len(segmented.programs)} programs and {index}")
    return 0

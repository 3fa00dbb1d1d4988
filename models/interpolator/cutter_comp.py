"""Cutter radius compensation (G40/G41/G42): a stage after parsing that replaces the programmed XY contour of
compensated moves by the path of the tool centre. Mirrors ``fmus/interpolator/cutter_comp.c`` (and
``cutter_comp.h``) operation for operation, so both give bit-equal moves.

The parser marks every move programmed while G41 (tool left of the contour) or G42 (right) is active with
``comp`` and the tool radius ``comp_radius`` (m); moves after G40 carry ``COMP_OFF``. Compensation follows the
behaviour documented for LinuxCNC (the NIST RS274/NGC interpreter's Appendix B and LinuxCNC's
``convert_straight_comp1``/``comp2``), in the XY plane (G17) only:

- **Entry**: the first move with XY motion after G41/G42 must be straight (G0/G1). It goes from the current tool
  position C to the programmed point P offset by the radius perpendicular to the line C-P (to the left for G41,
  the right for G42). Refused when |C-P| is not greater than the radius (the tool would already cover P). Moves
  without XY motion before it (a plunge) keep the tool's XY position: the offset starts with the first move in
  the plane, as on Fanuc-style controls (LinuxCNC refuses such a first move).
- **Lines** are offset by the radius to the left (G41) / right (G42) of their XY direction; a Z change is kept.
  **Arcs** keep their centre, sweep and height (helices): the radius grows or shrinks by the tool radius
  (refused where the compensated radius would be <= 0: gouging).
- **Corners** between consecutive XY elements (moves without XY motion in between are skipped over and keep the
  tool's XY position):

  - tangent junctions (|sin| of the turn <= ``COMP_TANGENT``, same direction) join at the end of the first
    element; a reversal (|sin| as small, opposite directions) is an outside corner of half a turn;
  - **outside** (convex) corners: an arc of the tool radius around the programmed corner point, inserted before
    the second move and taking its line and machine state (feed, spindle, tool, ...); before a rapid (G0) a
    rapid straight across the corner to the rapid's offset start instead (there is no rapid arc; LinuxCNC does
    the same, so that the rapid itself stays parallel to the programmed one); where the turn's |sin| is
    below ``COMP_SMALL_TURN`` (LinuxCNC's 0.01 rad corner tolerance) the offset elements are extended to their
    intersection instead, when they meet within 2 radii of the corner (no arc: nearly straight chains of short
    lines and CAM's rounded "tangent" joins keep their speed, where a tiny arc of the tool's curvature would
    slow the feed; two lines meet r / cos(turn / 2) from the corner, < 0.002 % of r beyond the radius);
  - **inside** (concave) corners: the intersection of the two offset elements (line-line, line-circle or
    circle-circle; of two intersections the nearer the corner, else the other, that lies on both), which
    shortens both; refused when the offset elements do not meet, or meet outside either element (beyond
    ``COMP_SLACK``, or leaving one of no length: an inside step shorter than the tool radius): "the tool
    (radius .. mm) cannot follow this inside corner without gouging", naming the line of the move that ends at
    the corner.
- **Exit**: the first move with XY motion after G40 must be straight; it goes from the last compensated point to
  its programmed end (moves without XY motion before it keep the compensated XY position). A program that ends
  with compensation on leaves the tool at the last compensated point.

Also refused, naming the line: a NURBS block (G6.2 etc.) under compensation, an arc in the ZX/YZ plane
(G18/G19) under compensation, and a change of the side or radius while compensation is on (G40 first). A
negative radius compensates on the other side (LinuxCNC's nominal-path tool-table convention); radius 0 leaves
the moves as programmed. G40 and G41/G42 again with no move in between leave no trace in the moves: it is one
compensation then (a change of side or radius between them is refused as above).
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

# the parser module itself (not its names): it calls compensate() at the end of parsing and may import this module
# before its own names exist
from milling_twin.models.interpolator import parser as _parser

if TYPE_CHECKING:
    from milling_twin.models.interpolator.parser import Move, Program

COMP_TANGENT = 1e-9       # |sin| of a turn at or below which a junction is tangent
COMP_SMALL_TURN = 0.01    # |sin| of an outside turn below which the offset elements meet (no corner arc)
COMP_SLACK = 1e-9         # m: how far an inside-corner intersection may lie beyond an element's end (rounding)

_PLANES = {(2, 0, 1): "ZX plane (G18)", (1, 2, 0): "YZ plane (G19)"}


def _wrap(a: float) -> float:
    """a brought into (-pi, pi]."""
    while a > math.pi:
        a -= 2.0 * math.pi
    while a <= -math.pi:
        a += 2.0 * math.pi
    return a


def _side(move: Move) -> tuple[int, float]:
    """(+1 left / -1 right / 0 off, radius >= 0) of a move; a negative radius swaps the side."""
    if move.comp == _parser.COMP_LEFT:
        side = 1
    elif move.comp == _parser.COMP_RIGHT:
        side = -1
    else:
        return 0, 0.0
    r = move.comp_radius
    if r == 0.0:
        return 0, 0.0
    if r < 0.0:
        return -side, -r
    return side, r


def _xy_motion(move: Move) -> bool:
    if move.kind == _parser.MOVE_LINE or move.kind == _parser.MOVE_RAPID:
        return move.end[0] != move.start[0] or move.end[1] != move.start[1]
    return move.kind == _parser.MOVE_ARC or move.kind == _parser.MOVE_NURBS


class _Element:
    """One XY element of a compensated run: programmed start p0, tangents t0/t1 at its ends, actual (compensated)
    start s and end e; arcs: centre c, direction sigma, offset radii ra/rb at the ends, angles of s and e and the
    angle swept between them (span > 0)."""

    def __init__(self, index: int, move: Move, side: int, r: float):
        self.index = index
        self.arc = move.kind == _parser.MOVE_ARC
        self.rapid = move.kind == _parser.MOVE_RAPID
        self.p0 = (move.start[0], move.start[1])
        self.corner: Move | None = None      # the arc (before a rapid: the rapid) inserted before this move
        if self.arc:
            self.c = (move.center[0], move.center[1])
            self.sigma = 1.0 if move.sweep > 0.0 else -1.0
            rk = r * (-side * self.sigma)      # radial offset (+ outwards)
            self.ra = move.r0 + rk
            self.rb = move.r1 + rk
            theta1 = move.theta0 + move.sweep
            u0 = (math.cos(move.theta0), math.sin(move.theta0))
            u1 = (math.cos(theta1), math.sin(theta1))
            self.t0 = (-self.sigma * u0[1], self.sigma * u0[0])
            self.t1 = (-self.sigma * u1[1], self.sigma * u1[0])
            self.s = (move.start[0] + rk * u0[0], move.start[1] + rk * u0[1])
            self.e = (move.end[0] + rk * u1[0], move.end[1] + rk * u1[1])
            self.ang_s = move.theta0
            self.ang_e = theta1
            self.span = abs(move.sweep)
            self.set_start(self.s)
            self.set_end(self.e)
        else:
            dx, dy = move.end[0] - move.start[0], move.end[1] - move.start[1]
            length = math.sqrt(dx * dx + dy * dy)
            t = (dx / length, dy / length)
            self.t0 = self.t1 = t
            n = (-t[1] * side, t[0] * side)
            self.s = (move.start[0] + r * n[0], move.start[1] + r * n[1])
            self.e = (move.end[0] + r * n[0], move.end[1] + r * n[1])

    def angle_step(self, x: tuple[float, float], reference: float) -> tuple[float, float]:
        """(angle of x about the centre, its signed step from reference along the sweep)."""
        a = math.atan2(x[1] - self.c[1], x[0] - self.c[0])
        return a, self.sigma * _wrap(a - reference)

    def set_start(self, x: tuple[float, float]) -> None:
        if self.arc:
            a, d = self.angle_step(x, self.ang_s)
            self.span = self.span - d
            self.ang_s = a
        self.s = x

    def set_end(self, x: tuple[float, float]) -> None:
        if self.arc:
            a, d = self.angle_step(x, self.ang_e)
            self.span = self.span + d
            self.ang_e = a
        self.e = x


def _dot2(a: tuple[float, float], b: tuple[float, float]) -> float:
    return a[0] * b[0] + a[1] * b[1]


def _line_circle(q, t, c, radius) -> list[tuple[float, float]]:
    """The intersections of the line q + s t (t unit) with the circle (c, radius), the one nearer q first."""
    wx, wy = q[0] - c[0], q[1] - c[1]
    b = wx * t[0] + wy * t[1]
    cc = wx * wx + wy * wy - radius * radius
    disc = b * b - cc
    if disc < 0.0:
        return []
    sq = math.sqrt(disc)
    s1, s2 = -b - sq, -b + sq
    if not abs(s1) <= abs(s2):
        s1, s2 = s2, s1
    return [(q[0] + s1 * t[0], q[1] + s1 * t[1]), (q[0] + s2 * t[0], q[1] + s2 * t[1])]


def _circle_circle(c1, r1, c2, r2, near) -> list[tuple[float, float]]:
    """The intersections of the circles (c1, r1) and (c2, r2), the one nearer the point near first."""
    dx, dy = c2[0] - c1[0], c2[1] - c1[1]
    d2 = dx * dx + dy * dy
    if d2 <= 0.0:
        return []
    d = math.sqrt(d2)
    a = (r1 * r1 - r2 * r2 + d2) / (2.0 * d)
    h2 = r1 * r1 - a * a
    if h2 < 0.0:
        return []
    h = math.sqrt(h2)
    ux, uy = dx / d, dy / d
    bx, by = c1[0] + a * ux, c1[1] + a * uy
    x1 = (bx - h * uy, by + h * ux)
    x2 = (bx + h * uy, by - h * ux)
    e1x, e1y = x1[0] - near[0], x1[1] - near[1]
    e2x, e2y = x2[0] - near[0], x2[1] - near[1]
    return [x1, x2] if e1x * e1x + e1y * e1y <= e2x * e2x + e2y * e2y else [x2, x1]


def _meet(a: _Element, b: _Element, p, side: int, r: float) -> list[tuple[float, float]]:
    """Where the offset elements a (ending at the corner p) and b (starting there) intersect, the intersection
    nearer the junction first."""
    if not a.arc and not b.arc:
        den = 1.0 + _dot2(a.t1, b.t0)
        if den <= 0.0:
            return []
        q = r / den
        nx = -a.t1[1] * side + -b.t0[1] * side
        ny = a.t1[0] * side + b.t0[0] * side
        return [(p[0] + q * nx, p[1] + q * ny)]
    if not a.arc:
        return _line_circle(a.e, a.t1, b.c, b.ra)
    if not b.arc:
        return _line_circle(b.s, b.t0, a.c, a.rb)
    return _circle_circle(a.c, a.rb, b.c, b.ra, a.e)


def _fits(a: _Element, b: _Element, x, inside: bool) -> bool:
    """Whether x joins a to b: both keep a positive length, and x shortens a at its end and b at its start (inside
    corners) or lengthens them (outside corners), allowing COMP_SLACK the other way (rounding)."""
    sign = 1.0 if inside else -1.0
    if a.arc:
        _, d = a.angle_step(x, a.ang_e)
        if sign * d * a.rb > COMP_SLACK or not a.span + d > 0.0:
            return False
    else:
        if sign * ((x[0] - a.e[0]) * a.t1[0] + (x[1] - a.e[1]) * a.t1[1]) > COMP_SLACK:
            return False
        if not (x[0] - a.s[0]) * a.t1[0] + (x[1] - a.s[1]) * a.t1[1] > 0.0:
            return False
    if b.arc:
        _, d = b.angle_step(x, b.ang_s)
        if sign * d * b.ra < -COMP_SLACK or not b.span - d > 0.0:
            return False
    else:
        if sign * ((x[0] - b.s[0]) * b.t0[0] + (x[1] - b.s[1]) * b.t0[1]) < -COMP_SLACK:
            return False
        if not (b.e[0] - x[0]) * b.t0[0] + (b.e[1] - x[1]) * b.t0[1] > 0.0:
            return False
    return True


class _Compensator:
    def __init__(self, program: Program, text: str, file: str):
        self.program = program
        self.file = file
        self.lines = text.split("\n")

    def fail(self, line: int, expected: str):
        raw = self.lines[line - 1].rstrip("\r") if 1 <= line <= len(self.lines) else ""
        raise _parser.ProgramError(self.file, line, raw, expected)

    def corner(self, a: _Element, b: _Element, move_a: Move, move_b: Move, side: int, r: float) -> None:
        """Joins a (ending at the programmed corner) to b (starting there)."""
        ta, tb = a.t1, b.t0
        cross = ta[0] * tb[1] - ta[1] * tb[0]
        dot = ta[0] * tb[0] + ta[1] * tb[1]
        p = b.p0
        tangent = abs(cross) <= COMP_TANGENT
        if tangent and dot > 0.0:
            b.set_start(a.e)
            return
        if side * cross > 0.0 and not tangent:
            for x in _meet(a, b, p, side, r):
                if _fits(a, b, x, True):
                    a.set_end(x)
                    b.set_start(x)
                    return
            self.fail(move_a.line, f"the tool (radius {r * 1000.0:.6g} mm) cannot follow this inside corner without "
                                   f"gouging")
        if dot > 0.0 and abs(cross) < COMP_SMALL_TURN:
            for x in _meet(a, b, p, side, r):
                ex, ey = x[0] - p[0], x[1] - p[1]
                if ex * ex + ey * ey <= 4.0 * r * r and _fits(a, b, x, False):
                    a.set_end(x)
                    b.set_start(x)
                    return
        z = move_b.start[2]
        if b.rapid:
            b.corner = replace(move_b, start=(a.e[0], a.e[1], z), end=(b.s[0], b.s[1], z), exact_stop=False,
                               dwell=0.0)
            return
        sweep = math.atan2(cross, dot) if abs(cross) > COMP_TANGENT else -side * math.pi
        theta0 = math.atan2(a.e[1] - p[1], a.e[0] - p[0])
        b.corner = replace(move_b, kind=_parser.MOVE_ARC, start=(a.e[0], a.e[1], z), end=(b.s[0], b.s[1], z),
                           center=(p[0], p[1], z), axes=(0, 1, 2), theta0=theta0, sweep=sweep, r0=r, r1=r,
                           height=0.0, curve=-1, u0=0.0, u1=0.0, exact_stop=False, dwell=0.0)

    def plan(self, first: int, last: int, cur, side: int, r: float) -> dict[int, _Element]:
        """The elements of the compensated run moves[first:last], entered from the tool position cur."""
        moves = self.program.moves
        elements: dict[int, _Element] = {}
        previous: _Element | None = None
        for k in range(first, last):
            m = moves[k]
            if m.kind == _parser.MOVE_NURBS:
                self.fail(m.line, "cutter compensation of a NURBS block is not supported (G40 before the block)")
            if m.kind == _parser.MOVE_ARC and tuple(m.axes) != (0, 1, 2):
                self.fail(m.line, f"cutter compensation in the XY plane (G17) only (the tool radius offsets the path "
                                  f"within XY), this arc lies in the {_PLANES.get(tuple(m.axes), 'ZX plane (G18)')}")
            if not _xy_motion(m):
                continue
            if previous is None:
                if m.kind == _parser.MOVE_ARC:
                    self.fail(m.line, "a straight entry move (G0 or G1) as the first move in XY after G41/G42, got "
                                      "an arc")
                dx, dy = m.end[0] - cur[0], m.end[1] - cur[1]
                distance = math.sqrt(dx * dx + dy * dy)
                if not distance > r:
                    self.fail(m.line, f"an entry move after G41/G42 longer than the tool radius "
                                      f"({r * 1000.0:.6g} mm): the tool would cover the programmed point")
                el = _Element(k, replace(m, start=(cur[0], cur[1], m.start[2])), side, r)
                el.s = cur
            else:
                el = _Element(k, m, side, r)
                if el.arc and not (el.ra > 0.0 and el.rb > 0.0):
                    self.fail(m.line, f"an arc radius greater than the tool radius ({r * 1000.0:.6g} mm) on the "
                                      f"compensated side (the tool cannot follow a radius of "
                                      f"{min(m.r0, m.r1) * 1000.0:.6g} mm without gouging)")
                self.corner(previous, el, moves[previous.index], m, side, r)
            elements[k] = el
            previous = el
        return elements

    def run(self) -> None:
        moves = self.program.moves
        out: list[Move] = []
        cur = (self.program.start[0], self.program.start[1])
        closing = False
        n = len(moves)
        i = 0
        while i < n:
            m = moves[i]
            side, r = _side(m)
            if side != 0:
                j = i + 1
                while j < n and _side(moves[j])[0] != 0:
                    if moves[j].comp != m.comp or moves[j].comp_radius != m.comp_radius:
                        self.fail(moves[j].line, "G40 before changing the side or the radius of an active cutter "
                                                 "compensation (G41/G42 with another D)")
                    j += 1
                elements = self.plan(i, j, cur, side, r)
                for k in range(i, j):
                    mk = moves[k]
                    el = elements.get(k)
                    if el is None:
                        out.append(replace(mk, start=(cur[0], cur[1], mk.start[2]), end=(cur[0], cur[1], mk.end[2])))
                        continue
                    if el.corner is not None:
                        out.append(el.corner)
                    if el.arc:
                        sx, sy = el.s[0] - el.c[0], el.s[1] - el.c[1]
                        ex, ey = el.e[0] - el.c[0], el.e[1] - el.c[1]
                        out.append(replace(mk, start=(el.s[0], el.s[1], mk.start[2]), end=(el.e[0], el.e[1], mk.end[2]),
                                           theta0=el.ang_s, sweep=el.sigma * el.span, r0=math.sqrt(sx * sx + sy * sy),
                                           r1=math.sqrt(ex * ex + ey * ey)))
                    else:
                        out.append(replace(mk, start=(el.s[0], el.s[1], mk.start[2]),
                                           end=(el.e[0], el.e[1], mk.end[2])))
                    cur = el.e
                if elements:
                    closing = True
                i = j
                continue
            if not _xy_motion(m):
                out.append(replace(m, start=(cur[0], cur[1], m.start[2]), end=(cur[0], cur[1], m.end[2])))
            elif closing:
                if m.kind != _parser.MOVE_LINE and m.kind != _parser.MOVE_RAPID:
                    self.fail(m.line, "a straight exit move (G0 or G1) as the first move in XY after G40, got "
                                      + ("an arc" if m.kind == _parser.MOVE_ARC else "a NURBS block"))
                closing = False
                if cur[0] != m.end[0] or cur[1] != m.end[1] or m.start[2] != m.end[2]:
                    out.append(replace(m, start=(cur[0], cur[1], m.start[2])))
                cur = (m.end[0], m.end[1])
            else:
                out.append(m)
                cur = (m.end[0], m.end[1])
            i += 1
        self.program.moves = out


def compensate(program: Program, text: str, file: str) -> None:
    """Replaces program.moves by the tool-centre path of their cutter compensation (G41/G42), as the module
    docstring describes; raises ProgramError naming the line a refused move was programmed in. ``text`` is the
    program's text (for the quoted line), ``file`` its name."""
    _Compensator(program, text, file).run()


__all__ = ["COMP_SLACK", "COMP_SMALL_TURN", "COMP_TANGENT", "compensate"]

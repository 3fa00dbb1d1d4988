"""The interpolator engine, tick by tick: schedule evaluation, the position on lines, arcs and NURBS moves,
the NURBS parameter update with its corrector, the outputs. Mirrors ``fmus/interpolator/interpolator.c``
(and ``interpolator.h``; the corrector's Newton iterations are ``nurbs_state_advance`` of param_update.c)."""
from __future__ import annotations

import math
from typing import Mapping, Sequence

from milling_twin.models.interpolator.definition import default_parameters
from milling_twin.models.interpolator.nurbs import Nurbs, arc_length
from milling_twin.models.interpolator.nurbs import dot as _dot
from milling_twin.models.interpolator.param_update import (LANDING_SHARE, MAX_NEWTON, METHOD_CORRECTOR, NurbsState,
                                                           arc_of_chord, curvature_squared, predict, rbf_of)
from milling_twin.models.interpolator.parser import (DIALECT_FANUC, MOVE_ARC, MOVE_DWELL, MOVE_LINE, MOVE_RAPID, Move,
                                                    Tool, parse_program)
from milling_twin.models.interpolator.path import build_path
from milling_twin.models.interpolator.schedule import Schedule

TOOL_OUTPUTS = ("tool_number", "tool_diameter", "tool_corner_radius", "tool_length", "tool_stick_out",
                "tool_helix_angle", "tool_flutes")


def next_node_of_move(node_right: Sequence[int], move: int) -> int:
    """The node where the path enters `move` (the first node whose right move is `move` or later)."""
    lo, hi = 0, len(node_right) - 1
    while lo < hi:
        mid = (lo + hi) // 2
        if 0 <= node_right[mid] < move:
            lo = mid + 1
        else:
            hi = mid
    return lo


class Interpolator:
    """The FMU's behaviour, tick by tick (one tick = one interpolation period)."""

    def __init__(self, text: str, parameters: Mapping[str, float], file: str = "program.nc", *,
                 dialect: int = DIALECT_FANUC, tools: Sequence[Tool] = ()):
        p = {**default_parameters(), **parameters}
        self.p = p
        self.program = parse_program(text, p, file, dialect=dialect, tools=tools)
        self.tools = tuple(tools)
        self.path = build_path(self.program, p, text)
        self.schedule = Schedule(self.path, p["max_feed"], p["rapid_feed"])
        self.period = p["period"]
        self.method = int(p["method"])
        self.predictor = int(p["corrector_predictor"]) if self.method == METHOD_CORRECTOR else self.method
        self.tolerance = p["corrector_tolerance"]
        self.feedback = bool(p["arc_length_feedback"])
        self.net = rbf_of(p)
        self.tick_count = 0
        self.piece = 0
        self.move = 0
        self.s = 0.0
        self.v = 0.0
        self.a = 0.0
        self.nurbs = NurbsState()
        self.override = None
        # the look-ahead window (interpolator.c): 0 when the program is planned whole
        lookahead = int(p.get("lookahead_blocks", 0))
        self.lookahead = 0 if lookahead <= 0 or len(self.program.moves) <= lookahead else lookahead
        self.at_end = True
        self.replan_s = math.inf
        start = self.program.start
        self.out = self.initial_outputs(p)
        self.position = list(start)
        self.finished = False

    @staticmethod
    def initial_outputs(p: Mapping[str, float]) -> dict[str, float]:
        x, y, z = p["start_x"], p["start_y"], p["start_z"]
        return {"x": x, "y": y, "z": z, "x_program": x - p["g54_x"], "y_program": y - p["g54_y"],
                "z_program": z - p["g54_z"], "feed_velocity_x": 0.0, "feed_velocity_y": 0.0,
                "feed_velocity_z": 0.0, "feed": 0.0, "path_acceleration": 0.0, "u": 0.0, "line_number": 0.0,
                "block_number": 0.0, "spindle_speed": 0.0, "spindle_on": 0.0, "rapid": 0.0, "finished": 0.0,
                "coolant": 0.0, **{name: 0.0 for name in TOOL_OUTPUTS}}

    # -- schedule --
    def plan(self, s_start: float, v_start: float, t_start: float, override: float) -> None:
        """Plans the look-ahead window from s_start: the moves from the one holding s_start on, `lookahead` of
        them (to the program's end when it has no more), at rest at the window's end unless the program ends
        there; the next window is planned once the path passes the start of the window's middle move."""
        path = self.path
        window_end = None
        self.at_end, self.replan_s = True, math.inf
        if self.lookahead and path.int_move:
            first_move = path.int_move[self.schedule.interval_at(s_start)]
            if first_move + self.lookahead < len(self.program.moves):
                end_move = first_move + self.lookahead
                window_end = next_node_of_move(path.node_right, end_move)
                self.at_end = False
                self.replan_s = path.move_s[first_move + (self.lookahead + 1) // 2]
        self.schedule.plan(s_start, v_start, t_start, override, window_end)

    def replan(self, t_now: float) -> tuple[float, float]:
        """Plans anew from the next zero-acceleration moment at or after t_now, keeping the pieces up to it; that
        moment's s and v."""
        t_r, s_r, v_r, k = self.replan_point(t_now)
        kept = self.schedule.pieces[self.piece:k]
        self.plan(s_r, v_r, t_r, self.override)
        self.schedule.pieces = kept + self.schedule.pieces
        self.piece = 0
        return s_r, v_r

    def next_window(self) -> None:
        """The next look-ahead window, from the next zero-acceleration moment; where the start there is too fast
        for a hard cap of the new window, the old plan is kept and the next such moment after it tried
        (interpolator.c next_window)."""
        sch = self.schedule
        saved = (sch.pieces[self.piece:], sch.hold, sch.end_time, sch.n_int, sch.end, self.at_end)
        s_r, v_r = self.replan(self.tick_count * self.period)
        if sch.raised and v_r > 0.0:
            sch.pieces, sch.hold, sch.end_time, sch.n_int, sch.end, self.at_end = saved
            self.piece = 0
            self.replan_s = math.nextafter(s_r, math.inf)

    def replan_point(self, t_now: float) -> tuple[float, float, float, int]:
        """(t, s, v, piece index) of the first moment at or after t_now with zero acceleration."""
        pieces = self.schedule.pieces
        k = self.piece
        pc = pieces[k]
        if pc.a == 0.0 and pc.j == 0.0 and not self.dwell_piece(k):
            tau = t_now - pc.t
            return t_now, pc.s + pc.v * tau, pc.v, k
        k += 1
        while k < len(pieces) and not (pieces[k].a == 0.0 and not self.dwell_piece(k)):
            k += 1
        pc = pieces[k]
        return pc.t, pc.s, pc.v, k

    def dwell_piece(self, k: int) -> bool:
        """A piece at rest with more pieces after it: a dwell (a re-plan waits for its end)."""
        pieces = self.schedule.pieces
        pc = pieces[k]
        return pc.v == 0.0 and pc.a == 0.0 and pc.j == 0.0 and k + 1 < len(pieces)

    def set_override(self, override: float, t_now: float) -> None:
        if self.override is not None and override == self.override:
            return
        if self.override is None:
            self.override = override
            self.plan(0.0, 0.0, 0.0, override)
            self.piece = 0
            return
        self.override = override
        if self.finished:
            return
        self.replan(t_now)

    # -- one tick --
    def tick(self) -> None:
        if self.override is not None and not self.at_end and not self.finished and self.s >= self.replan_s:
            self.next_window()
        self.tick_count += 1
        t = self.tick_count * self.period
        sch = self.schedule
        pieces = sch.pieces
        while self.piece + 1 < len(pieces) and pieces[self.piece + 1].t <= t:
            self.piece += 1
        pc = pieces[self.piece]
        tau = t - pc.t
        s = pc.s + tau * (pc.v + tau * (0.5 * pc.a + tau * pc.j / 6.0))
        v = pc.v + tau * (pc.a + 0.5 * tau * pc.j)
        a = pc.a + tau * pc.j
        total = self.path.total
        done = (not sch.hold) and self.at_end and t >= sch.end_time
        if done or s >= total:
            s = total
        if done:
            v = a = 0.0
        if s < self.s:
            s = self.s
        if v < 0.0:
            v = 0.0
        self.s, self.v, self.a = s, v, a
        self.finished = done
        self.update_outputs()

    def update_outputs(self) -> None:
        prog = self.program
        out = self.out
        if not prog.moves:
            self.finished = True
            self.set_final(out)
            return
        moves = prog.moves
        s = self.s
        while self.move + 1 < len(moves):
            end = self.path.move_s[self.move] + self.path.move_length[self.move]
            # into a dwell once at rest on its position, out of any move once past its end
            if not (s > end or (moves[self.move + 1].kind == MOVE_DWELL and s >= end and self.v == 0.0)):
                break
            self.move += 1
        if self.finished:
            self.set_final(out)
            return
        m = moves[self.move]
        local = s - self.path.move_s[self.move]
        length = self.path.move_length[self.move]
        lam = local / length if m.kind != MOVE_DWELL else 0.0
        if lam > 1.0:
            lam = 1.0
        if lam < 0.0:
            lam = 0.0
        if m.kind == MOVE_DWELL:
            pos = list(m.start)
            tangent = [0.0, 0.0, 0.0]
            u = 0.0
        elif m.kind in (MOVE_RAPID, MOVE_LINE):
            if lam >= 1.0:
                pos = list(m.end)
            else:
                pos = [m.start[i] + lam * (m.end[i] - m.start[i]) for i in range(3)]
            d = [m.end[i] - m.start[i] for i in range(3)]
            norm = math.sqrt(_dot(d, d))
            tangent = [d[i] / norm for i in range(3)]
            u = lam
        elif m.kind == MOVE_ARC:
            arc = self.path.arcs[self.move]
            pos = arc.point(lam)
            tangent = arc.tangent(lam)
            u = lam
        else:
            pos, tangent, u = self.step_nurbs(local, length)
        self.position = pos
        for i, axis in enumerate("xyz"):
            out[axis] = pos[i]
            out[f"{axis}_program"] = pos[i] - m.offset[i]
            out[f"feed_velocity_{axis}"] = self.v * tangent[i]
        out["feed"] = self.v
        out["path_acceleration"] = self.a
        out["u"] = u
        out["line_number"] = float(m.line)
        out["block_number"] = float(m.block)
        out["spindle_speed"] = m.spindle
        out["spindle_on"] = 1.0 if m.spindle_on else 0.0
        out["rapid"] = 1.0 if m.kind == MOVE_RAPID else 0.0
        out["finished"] = 0.0
        self.set_tool(out, m.tool)
        out["coolant"] = float(m.coolant)

    def set_tool(self, out: dict, number: int) -> None:
        """The tool number and its geometry from the tool table (0 for tool 0 and for a tool it has not)."""
        if float(number) == out["tool_number"]:
            return
        tool = next((t for t in self.tools if t.number == number), None)
        out["tool_number"] = float(number)
        out["tool_diameter"] = tool.diameter if tool else 0.0
        out["tool_corner_radius"] = tool.corner_radius if tool else 0.0
        out["tool_length"] = tool.length if tool else 0.0
        out["tool_stick_out"] = tool.stick_out if tool else 0.0
        out["tool_helix_angle"] = tool.helix if tool else 0.0
        out["tool_flutes"] = float(tool.flutes) if tool else 0.0

    def set_final(self, out: dict) -> None:
        prog = self.program
        if prog.moves:
            last = prog.moves[-1]
            pos, offset = list(last.end), last.offset
        else:
            pos, offset = list(prog.start), prog.start_offset
        for i, axis in enumerate("xyz"):
            out[axis] = pos[i]
            out[f"{axis}_program"] = pos[i] - offset[i]
            out[f"feed_velocity_{axis}"] = 0.0
        out["feed"] = 0.0
        out["path_acceleration"] = 0.0
        out["u"] = 1.0 if prog.moves else 0.0
        out["line_number"] = float(prog.final_line)
        out["block_number"] = float(prog.final_block)
        out["spindle_speed"] = prog.final_spindle
        out["spindle_on"] = 1.0 if prog.final_spindle_on else 0.0
        out["rapid"] = 0.0
        out["finished"] = 1.0
        self.set_tool(out, prog.moves[-1].tool if prog.moves else 0)
        out["coolant"] = float(prog.moves[-1].coolant) if prog.moves else 0.0

    def step_nurbs(self, local: float, length: float) -> tuple[list[float], list[float], float]:
        m = self.program.moves[self.move]
        curve = self.path.curves[m.curve]
        lo, hi = self.path.move_span[self.move]
        st = self.nurbs
        if st.move != self.move:
            st.move = self.move
            st.u = st.u1 = st.u2 = m.u0
            st.count = 0
            st.s_done = 0.0
            st.s_actual = 0.0
            d = curve.evaluate(m.u0, 2, lo, hi)
            st.point, st.d1, st.d2 = d[0], d[1], d[2]
            st.upp_prev = 0.0
            st.chord_prev = 0.0
        if local >= length:
            if st.u < m.u1:
                self.nurbs_accept(st, curve, m.u1, lo, hi, 0.0, 0.0, 0.0)
            st.s_done = local
        else:
            step = local - (st.s_actual if self.feedback else st.s_done)
            if step > 0.0 and st.u < m.u1:
                remaining = length - st.s_done
                if not self.feedback and remaining <= LANDING_SHARE * length:
                    # open loop, landing: the steps scaled by the arc left (the block's length less the arc the
                    # steps travelled) over the schedule left, so the tool reaches the block end when the schedule
                    # does (the open loop's drift spread over the block's last tenth)
                    step = step * (length - st.s_actual) / remaining
                self.nurbs_advance(st, curve, m, step, lo, hi)
            st.s_done = local
        g = math.sqrt(_dot(st.d1, st.d1))
        tangent = [st.d1[i] / g for i in range(3)]
        kn = curve.knots
        u = (st.u - kn[0]) / (kn[-1] - kn[0])
        return list(st.point), tangent, (u if u < 1.0 else 1.0)

    def nurbs_accept(self, st: NurbsState, curve: Nurbs, u: float, lo: int, hi: int, upp_prev: float,
                     chord: float, arc: float, d=None) -> None:
        if d is None:
            d = curve.evaluate(u, 2, lo, hi)
        st.u2, st.u1, st.u = st.u1, st.u, u
        st.upp_prev = upp_prev
        st.chord_prev = chord
        st.point, st.d1, st.d2 = d[0], d[1], d[2]
        st.s_actual += arc
        st.count += 1

    def nurbs_advance(self, st: NurbsState, curve: Nurbs, m: Move, step: float, lo: int, hi: int) -> None:
        u_end = m.u1
        du = predict(st, step, self.predictor, self.net, m.u0, m.u1)
        upp_now = -_dot(st.d1, st.d2) / (_dot(st.d1, st.d1) * _dot(st.d1, st.d1))
        u = st.u + du
        if not (u > st.u):
            u = st.u + step / math.sqrt(_dot(st.d1, st.d1))
        if not (u < u_end):
            u = u_end
        p0 = st.point
        if self.method != METHOD_CORRECTOR:
            d = curve.evaluate(u, 2, lo, hi)
            c = d[0]
            e = [c[0] - p0[0], c[1] - p0[1], c[2] - p0[2]]
            chord = math.sqrt(_dot(e, e))
            arc = arc_of_chord(chord, curvature_squared(st.d1, st.d2), curvature_squared(d[1], d[2]))
            self.nurbs_accept(st, curve, u, lo, hi, upp_now, chord, arc, d)
            return
        # Newton on the arc length of the step (Gauss-Legendre per knot span), bracketed
        lo_u, hi_u = st.u, u_end
        d = None
        arc = 0.0
        u_eval = u
        for _ in range(MAX_NEWTON):
            arc = arc_length(curve, st.u, u, lo, hi)
            d = curve.evaluate(u, 2, lo, hi)
            u_eval = u
            f = arc - step
            if abs(f) <= self.tolerance * step:
                # converged: one more Newton step without a new arc length (its error is second order in f),
                # so the positions do not carry the tolerance's noise (1e-6 of a step would be 1e-10 m at
                # 0.1 m/s, up to 0.4 % of a 100 m/s^3 jerk in the third difference of the positions)
                g = math.sqrt(_dot(d[1], d[1]))
                nxt = u - f / g if g > 0.0 else u
                if nxt != u and nxt > st.u and nxt < u_end:
                    arc = arc + g * (nxt - u)
                    d = curve.evaluate(nxt, 2, lo, hi)
                    u_eval = nxt
                break
            if f < 0.0:
                if u >= u_end:
                    break
                lo_u = u
            else:
                hi_u = u
            g = math.sqrt(_dot(d[1], d[1]))
            nxt = u - f / g if g > 0.0 else -1.0
            if not (nxt > lo_u and nxt < hi_u):
                nxt = 0.5 * (lo_u + hi_u)
            if nxt == u:
                break
            u = nxt
        c = d[0]
        e = [c[0] - p0[0], c[1] - p0[1], c[2] - p0[2]]
        self.nurbs_accept(st, curve, u_eval, lo, hi, upp_now, math.sqrt(_dot(e, e)), arc, d)

/* The interpolator engine (see interpolator.h); the same operations in the same order as
 * models/interpolator/engine.py. */
#include "interpolator.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef LANDING_SHARE
#define LANDING_SHARE 0.1 /* models/interpolator/param_update.py (until model_constants.h generates it) */
#endif

/* The look-ahead covers the whole program (no window) when it holds no more than `lookahead` moves. */
static int whole_program(size_t lookahead, size_t n_moves) { return lookahead == 0 || n_moves <= lookahead; }

/* The most intervals a window of `lookahead` consecutive moves holds (what the schedule's pieces need room for). */
static int window_intervals(InterpPrepared *p, const char *file, char *error, size_t error_size) {
    const PathBuild *path = &p->path;
    size_t n = path->n_moves, W = p->lookahead, k, i, most = 0, *first;
    p->window_intervals = path->n_ints;
    if (whole_program(W, n)) return 0;
    first = malloc((n + 1) * sizeof *first); /* first[m]: the first interval of move m */
    if (!first) {
        snprintf(error, error_size, "%s: out of memory for the look-ahead window", file);
        return -1;
    }
    for (k = 0, i = 0; k < n; k++) {
        while (i < path->n_ints && (size_t)path->int_move[i] < k) i++;
        first[k] = i;
    }
    first[n] = path->n_ints;
    for (k = 0; k + W <= n; k++)
        if (first[k + W] - first[k] > most) most = first[k + W] - first[k];
    free(first);
    p->window_intervals = most;
    return 0;
}

int interp_prepare(const char *text, size_t length, const char *file, const InterpSettings *settings,
                   InterpPrepared *prepared, char *error, size_t error_size) {
    memset(prepared, 0, sizeof *prepared);
    if (gc_parse(text, length, file, &settings->gcode, &prepared->program, error, error_size) != 0) return -1;
    if (prepared->program.cap_moves > prepared->program.n_moves && prepared->program.n_moves) {
        /* the moves' array grew by doubling: give back what the program did not fill (up to half of it) */
        GcMove *fitted = realloc(prepared->program.moves, prepared->program.n_moves * sizeof *fitted);
        if (fitted) prepared->program.moves = fitted, prepared->program.cap_moves = prepared->program.n_moves;
    }
    if (path_build(&prepared->program, &settings->limits, text, length, file, &prepared->path, error, error_size) !=
        0) {
        gc_free(&prepared->program);
        return -1;
    }
    prepared->lookahead = settings->lookahead;
    if (window_intervals(prepared, file, error, error_size) != 0) {
        interp_release(prepared);
        return -1;
    }
    if (settings->gcode.n_tools) {
        prepared->tools = malloc(settings->gcode.n_tools * sizeof *prepared->tools);
        if (!prepared->tools) {
            snprintf(error, error_size, "%s: out of memory for the tool table", file);
            interp_release(prepared);
            return -1;
        }
        memcpy(prepared->tools, settings->gcode.tools, settings->gcode.n_tools * sizeof *prepared->tools);
        prepared->n_tools = settings->gcode.n_tools;
    }
    return 0;
}

void interp_release(InterpPrepared *prepared) {
    gc_free(&prepared->program);
    path_free(&prepared->path);
    free(prepared->tools);
    prepared->tools = NULL;
    prepared->n_tools = 0;
}

static void layout_of(const InterpPrepared *p, InterpLayout *L) {
    size_t k, points = 0, knots = 0, at = 0;
    memset(L, 0, sizeof *L);
    for (k = 0; k < p->program.n_curves; k++) {
        points += 4 * (size_t)p->program.curves[k].n_points;
        knots += (size_t)p->program.curves[k].n_points + (size_t)p->program.curves[k].degree + 1;
    }
    L->n_moves = p->program.n_moves;
    L->n_curves = p->program.n_curves;
    L->n_nodes = p->path.n_nodes;
    L->n_ints = p->path.n_ints;
    L->n_tools = p->n_tools;
    L->lookahead = whole_program(p->lookahead, L->n_moves) ? 0 : p->lookahead;
    /* a window's plan: at most PIECES_PER_INTERVAL per interval and the final piece, after the pieces kept up to the
     * next zero-acceleration moment (an S-curve's rest and a dwell: fewer than 8) */
    if (L->lookahead)
        L->piece_capacity = PIECES_PER_INTERVAL * p->window_intervals + 16;
    else
        L->piece_capacity = PIECES_PER_INTERVAL * L->n_ints + 8;
    at = 1; /* heap[0]: magic */
    L->moves = at, at += MOVE_DOUBLES * L->n_moves;
    L->curves = at, at += CURVE_DOUBLES * L->n_curves;
    L->points = at, at += points + knots;
    L->node_s = at, at += L->n_nodes;
    L->node_vh = at, at += L->n_nodes;
    L->node_left = at, at += L->n_nodes;
    L->node_right = at, at += L->n_nodes;
    L->station = at, at += L->n_nodes;
    L->int_move = at, at += L->n_ints;
    L->int_at = at, at += L->n_ints;
    L->int_jt = at, at += L->n_ints;
    L->int_cap = at, at += L->n_ints;
    L->tools = at, at += TOOL_DOUBLES * L->n_tools;
    L->pieces = at, at += PIECE_DOUBLES * L->piece_capacity;
    L->heap_size = at;
}

size_t interp_heap_size(const InterpPrepared *prepared) {
    InterpLayout L;
    layout_of(prepared, &L);
    return L.heap_size;
}

/* The parsed moves are given back from the end in steps of this many while the heap's records of them are written,
 * so the two copies of the program never coexist whole (with glibc a shrinking realloc of a large block returns
 * its tail to the system at once; another allocator may copy instead, which costs time, not correctness). */
#define INSTALL_STEP 65536

#define FREE_ARRAY(array) (free(array), (array) = NULL)
/* A path array copied into the heap from `offset` on (as doubles), then given back. */
#define INSTALL_ARRAY(offset, array, count)                                                                        \
    do {                                                                                                           \
        size_t i_;                                                                                                 \
        for (i_ = 0; i_ < (count); i_++) heap[(offset) + i_] = (double)(array)[i_];                                \
        FREE_ARRAY(array);                                                                                         \
    } while (0)

void interp_install(InterpPrepared *p, double *heap, InterpLayout *L) {
    GcProgram *g = &p->program;
    PathBuild *path = &p->path;
    size_t k, at, n_moves = g->n_moves;
    layout_of(p, L);
    L->total = path->total;
    L->final_line = g->final_line;
    L->final_block = g->final_block;
    L->final_spindle = g->final_spindle;
    L->final_spindle_on = g->final_spindle_on;
    memcpy(L->start, g->start, sizeof L->start);
    memcpy(L->start_offset, g->start_offset, sizeof L->start_offset);
    heap[0] = INTERP_MAGIC;
    at = L->points;
    for (k = 0; k < g->n_curves; k++) {
        const GcCurve *c = &g->curves[k];
        double *r = heap + L->curves + CURVE_DOUBLES * k;
        size_t n = (size_t)c->n_points, n_knots = n + (size_t)c->degree + 1;
        r[CR_DEGREE] = c->degree, r[CR_LAST_POINT] = c->n_points - 1, r[CR_PW] = (double)at,
        r[CR_KNOTS] = (double)(at + 4 * n);
        memcpy(heap + at, path->pw[k], 4 * n * sizeof *heap);
        memcpy(heap + at + 4 * n, c->knots, n_knots * sizeof *heap);
        at += 4 * n + n_knots;
    }
    for (k = n_moves; k-- > 0;) {
        const GcMove *m = &g->moves[k];
        double *r = heap + L->moves + MOVE_DOUBLES * k;
        int i;
        r[MR_KIND] = m->kind, r[MR_LINE] = m->line, r[MR_BLOCK] = m->block;
        r[MR_S] = path->move_s[k], r[MR_LENGTH] = path->move_length[k];
        for (i = 0; i < 3; i++) {
            r[MR_START + i] = m->start[i], r[MR_END + i] = m->end[i], r[MR_OFFSET + i] = m->offset[i];
            r[MR_CENTER + i] = m->center[i], r[MR_AXES + i] = m->axes[i];
        }
        r[MR_FEED] = m->feed, r[MR_SPINDLE] = m->spindle, r[MR_SPINDLE_ON] = m->spindle_on;
        r[MR_THETA0] = m->theta0, r[MR_SWEEP] = m->sweep, r[MR_R0] = m->r0, r[MR_R1] = m->r1, r[MR_HEIGHT] = m->height;
        r[MR_CURVE] = m->curve, r[MR_U0] = m->u0, r[MR_U1] = m->u1;
        r[MR_SPAN_LO] = path->span_lo[k], r[MR_SPAN_HI] = path->span_hi[k];
        r[MR_TOOL] = m->tool, r[MR_COOLANT] = m->coolant, r[MR_DWELL] = m->dwell, r[MR_EXACT_STOP] = m->exact_stop;
        if (k > 0 && k % INSTALL_STEP == 0) {
            GcMove *kept = realloc(g->moves, k * sizeof *kept);
            if (kept) g->moves = kept, g->cap_moves = k; /* else the block stays whole until released */
        }
    }
    FREE_ARRAY(g->moves);
    g->n_moves = g->cap_moves = 0;
    FREE_ARRAY(path->move_s), FREE_ARRAY(path->move_length), FREE_ARRAY(path->move_cap);
    FREE_ARRAY(path->span_lo), FREE_ARRAY(path->span_hi);
    INSTALL_ARRAY(L->node_s, path->node_s, path->n_nodes);
    INSTALL_ARRAY(L->node_vh, path->node_vh, path->n_nodes);
    INSTALL_ARRAY(L->node_left, path->node_left, path->n_nodes);
    INSTALL_ARRAY(L->node_right, path->node_right, path->n_nodes);
    INSTALL_ARRAY(L->station, path->station, path->n_nodes);
    INSTALL_ARRAY(L->int_move, path->int_move, path->n_ints);
    INSTALL_ARRAY(L->int_at, path->int_at, path->n_ints);
    INSTALL_ARRAY(L->int_jt, path->int_jt, path->n_ints);
    INSTALL_ARRAY(L->int_cap, path->int_cap, path->n_ints);
    for (k = 0; k < p->n_tools; k++) {
        const GcTool *t = &p->tools[k];
        double *r = heap + L->tools + TOOL_DOUBLES * k;
        r[TR_NUMBER] = t->number, r[TR_DIAMETER] = t->diameter, r[TR_CORNER_RADIUS] = t->corner_radius;
        r[TR_LENGTH] = t->length, r[TR_STICK_OUT] = t->stick_out, r[TR_HELIX] = t->helix, r[TR_FLUTES] = t->flutes;
    }
}

/* The tool `number` and its geometry from the heap's tool table, looked up only when the tool changes. */
static void set_tool(const double *heap, const InterpLayout *L, InterpOutputs *out, int number) {
    size_t k;
    if (number == out->tool) return;
    out->tool = number;
    out->tool_diameter = out->tool_corner_radius = out->tool_length = out->tool_stick_out = out->tool_helix = 0.0;
    out->tool_flutes = 0;
    for (k = 0; k < L->n_tools; k++) {
        const double *r = heap + L->tools + TOOL_DOUBLES * k;
        if (r[TR_NUMBER] != (double)number) continue;
        out->tool_diameter = r[TR_DIAMETER], out->tool_corner_radius = r[TR_CORNER_RADIUS];
        out->tool_length = r[TR_LENGTH], out->tool_stick_out = r[TR_STICK_OUT], out->tool_helix = r[TR_HELIX];
        out->tool_flutes = (int)r[TR_FLUTES];
        break;
    }
}

void interp_initial_outputs(const InterpSettings *settings, InterpOutputs *out) {
    int i;
    memset(out, 0, sizeof *out);
    for (i = 0; i < 3; i++) {
        out->x[i] = settings->gcode.start[i];
        out->program[i] = settings->gcode.start[i] - settings->gcode.offsets[0][i];
    }
}

void interp_start(InterpState *state, const InterpSettings *settings) {
    memset(state, 0, sizeof *state);
    state->nurbs.move = -1;
    interp_initial_outputs(settings, &state->out);
}

static const double *move_record(const double *heap, const InterpLayout *L, size_t k) {
    return heap + L->moves + MOVE_DOUBLES * k;
}

static void curve_view(const double *heap, const InterpLayout *L, int curve, NurbsView *v) {
    const double *r = heap + L->curves + CURVE_DOUBLES * (size_t)curve;
    v->degree = (int)r[CR_DEGREE];
    v->n = (int)r[CR_LAST_POINT];
    v->pw = heap + (size_t)r[CR_PW];
    v->knots = heap + (size_t)r[CR_KNOTS];
}

static void arc_of(const double *r, ArcParams *a) {
    int i;
    for (i = 0; i < 3; i++)
        a->center[i] = r[MR_CENTER + i], a->end[i] = r[MR_END + i], a->axes[i] = (int)r[MR_AXES + i];
    a->theta0 = r[MR_THETA0], a->sweep = r[MR_SWEEP], a->r0 = r[MR_R0], a->r1 = r[MR_R1], a->height = r[MR_HEIGHT];
}

/* The node where the path enters move `next` (the first node whose right move is `next` or later). */
static size_t node_of_move(const double *heap, const InterpLayout *L, size_t next) {
    size_t lo = 0, hi = L->n_nodes - 1;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        double right = heap[L->node_right + mid];
        if (right >= 0.0 && right < (double)next)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

/* The interval holding s (the last one whose start node is at or before s). */
static size_t interval_of(const double *heap, const InterpLayout *L, double s) {
    size_t lo = 0, hi = L->n_nodes - 2;
    while (lo < hi) {
        size_t mid = (lo + hi + 1) / 2;
        if (heap[L->node_s + mid] <= s)
            lo = mid;
        else
            hi = mid - 1;
    }
    return lo;
}

/* Plans the window from s_start; *raised: the start was too fast for a hard cap of the window (schedule_plan). */
static int plan(double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings, double s_start,
                double v_start, double t_start, size_t first_piece, int *raised) {
    ScheduleView view;
    double *soft, *dwell;
    size_t k, first_move = 0, base = 0, end_move = L->n_moves, n_window;
    int status;
    st->window_end = L->n_nodes ? L->n_nodes - 1 : 0;
    st->at_end = 1;
    st->replan_s = INFINITY;
    if (L->lookahead && L->n_ints) {
        first_move = (size_t)heap[L->int_move + interval_of(heap, L, s_start)];
        if (first_move + L->lookahead < L->n_moves) {
            end_move = first_move + L->lookahead; /* the first move after the window */
            st->window_end = node_of_move(heap, L, end_move);
            st->at_end = 0;
            st->replan_s = move_record(heap, L, first_move + (L->lookahead + 1) / 2)[MR_S];
        }
        base = first_move ? first_move - 1 : 0; /* the node before the window's first names the move before it */
        if (end_move < L->n_moves) end_move++;  /* and the window's last node the move after it */
    }
    n_window = end_move - base;
    soft = malloc(2 * (n_window ? n_window : 1) * sizeof *soft);
    if (!soft) return -1;
    dwell = soft + (n_window ? n_window : 1);
    for (k = 0; k < n_window; k++) {
        const double *r = move_record(heap, L, base + k);
        dwell[k] = (int)r[MR_KIND] == MOVE_DWELL ? r[MR_DWELL] : 0.0;
        if ((int)r[MR_KIND] == MOVE_RAPID) {
            soft[k] = settings->rapid_feed;
        } else {
            double f = r[MR_FEED] * st->override;
            soft[k] = settings->max_feed < f ? settings->max_feed : f;
        }
    }
    view.n_nodes = L->n_nodes, view.n_ints = st->at_end ? L->n_ints : st->window_end, view.n_moves = L->n_moves;
    view.node_s = heap + L->node_s, view.node_vh = heap + L->node_vh, view.node_left = heap + L->node_left;
    view.node_right = heap + L->node_right, view.station = heap + L->station;
    view.int_move = heap + L->int_move, view.int_at = heap + L->int_at, view.int_jt = heap + L->int_jt;
    view.int_cap = heap + L->int_cap, view.move_base = base, view.soft = soft, view.dwell = dwell;
    view.total = st->at_end ? L->total : heap[L->node_s + st->window_end];
    view.pieces = heap + L->pieces, view.piece_capacity = L->piece_capacity;
    if (L->n_ints) { /* room for what the plan may write (a state from outside may not fit its layout) */
        size_t first = interval_of(heap, L, s_start);
        if (first >= view.n_ints || first_piece + PIECES_PER_INTERVAL * (view.n_ints - first) + 1 > L->piece_capacity) {
            free(soft);
            return -1;
        }
    }
    status = schedule_plan(&view, s_start, v_start, t_start, first_piece, &st->n_pieces, &st->hold, &st->end_time);
    *raised = view.raised;
    free(soft);
    return status;
}

/* A piece at rest with more pieces after it: a dwell (a re-plan waits for its end). */
static int dwell_piece(const double *pieces, size_t n_pieces, size_t k) {
    const double *pc = pieces + PIECE_DOUBLES * k;
    return pc[PC_V] == 0.0 && pc[PC_A] == 0.0 && pc[PC_J] == 0.0 && k + 1 < n_pieces;
}

static int replan(double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings, double *s_r,
                  double *v_r, int *raised);

int interp_set_override(double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings,
                        double override) {
    double s_r, v_r;
    int raised;
    if (st->planned && override == st->override) return 0;
    if (!st->planned) {
        st->planned = 1;
        st->override = override;
        st->piece = 0;
        return plan(heap, L, st, settings, 0.0, 0.0, 0.0, 0, &raised);
    }
    st->override = override;
    if (st->finished) return 0;
    return replan(heap, L, st, settings, &s_r, &v_r, &raised);
}

/* Plans anew from the next zero-acceleration moment at or after the last tick, keeping the pieces up to it. */
static int replan(double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings, double *s_r,
                  double *v_r, int *raised) {
    const double *pieces = heap + L->pieces;
    const double *pc;
    double t_now, t_r;
    size_t k;
    t_now = (double)st->tick * settings->limits.period;
    k = st->piece;
    pc = pieces + PIECE_DOUBLES * k;
    if (pc[PC_A] == 0.0 && pc[PC_J] == 0.0 && !dwell_piece(pieces, st->n_pieces, k)) {
        double tau = t_now - pc[PC_T];
        t_r = t_now, *s_r = pc[PC_S] + pc[PC_V] * tau, *v_r = pc[PC_V];
    } else {
        k++;
        while (k < st->n_pieces &&
               !(pieces[PIECE_DOUBLES * k + PC_A] == 0.0 && !dwell_piece(pieces, st->n_pieces, k)))
            k++;
        pc = pieces + PIECE_DOUBLES * k;
        t_r = pc[PC_T], *s_r = pc[PC_S], *v_r = pc[PC_V];
    }
    memmove(heap + L->pieces, heap + L->pieces + PIECE_DOUBLES * st->piece,
            PIECE_DOUBLES * (k - st->piece) * sizeof *heap);
    k -= st->piece;
    st->piece = 0;
    return plan(heap, L, st, settings, *s_r, *v_r, t_r, k, raised);
}

/* The next look-ahead window, planned from the next zero-acceleration moment. Where the start there is too fast for
 * a hard cap of the new window (the old plan stops at its window's end, which the S-curves between stations of the
 * new one may not match for a cap just above rest there), the old plan is kept and the next zero-acceleration
 * moment after that one is tried, at the latest the old window's end, at rest. */
static int next_window(double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings) {
    size_t count = st->n_pieces - st->piece;
    double *saved = malloc(PIECE_DOUBLES * count * sizeof *saved), s_r, v_r;
    InterpState before;
    int raised = 0, status;
    if (!saved) return -1;
    memcpy(saved, heap + L->pieces + PIECE_DOUBLES * st->piece, PIECE_DOUBLES * count * sizeof *saved);
    memcpy(&before, st, sizeof before);
    status = replan(heap, L, st, settings, &s_r, &v_r, &raised);
    if (status == 0 && raised && v_r > 0.0) {
        memcpy(st, &before, sizeof *st);
        memcpy(heap + L->pieces, saved, PIECE_DOUBLES * count * sizeof *saved);
        st->piece = 0;
        st->n_pieces = count;
        st->replan_s = nextafter(s_r, INFINITY);
    }
    free(saved);
    return status;
}

static void set_final(const double *heap, const InterpLayout *L, InterpState *st) {
    InterpOutputs *out = &st->out;
    const double *pos, *offset;
    int i;
    if (L->n_moves) {
        const double *r = move_record(heap, L, L->n_moves - 1);
        pos = r + MR_END, offset = r + MR_OFFSET;
    } else {
        pos = L->start, offset = L->start_offset;
    }
    for (i = 0; i < 3; i++) {
        out->x[i] = pos[i];
        out->program[i] = pos[i] - offset[i];
        out->velocity[i] = 0.0;
    }
    out->feed = 0.0;
    out->acceleration = 0.0;
    out->u = L->n_moves ? 1.0 : 0.0;
    out->line = L->final_line;
    out->block = L->final_block;
    out->spindle = L->final_spindle;
    out->spindle_on = L->final_spindle_on;
    out->rapid = 0;
    out->finished = 1;
    set_tool(heap, L, out, L->n_moves ? (int)move_record(heap, L, L->n_moves - 1)[MR_TOOL] : 0);
    out->coolant = L->n_moves ? (int)move_record(heap, L, L->n_moves - 1)[MR_COOLANT] : 0;
}

static void step_nurbs(const double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings,
                       const double *r, double local, double length, double pos[3], double tangent[3], double *u) {
    NurbsState *ns = &st->nurbs;
    NurbsView curve;
    int lo = (int)r[MR_SPAN_LO], hi = (int)r[MR_SPAN_HI], i;
    double u0 = r[MR_U0], u1 = r[MR_U1], g;
    curve_view(heap, L, (int)r[MR_CURVE], &curve);
    if (ns->move != (int)st->move) nurbs_state_start(ns, (int)st->move, &curve, u0, lo, hi);
    if (local >= length) {
        if (ns->u < u1) {
            double d[3][3];
            nurbs_evaluate(&curve, u1, 2, lo, hi, d);
            nurbs_state_accept(ns, u1, (const double(*)[3])d, 0.0, 0.0, 0.0);
        }
        ns->s_done = local;
    } else {
        double step = local - (settings->update.feedback ? ns->s_actual : ns->s_done);
        if (step > 0.0 && ns->u < u1) {
            double remaining = length - ns->s_done;
            /* open loop, landing: the steps scaled by the arc left (the block's length less the arc the steps
             * travelled) over the schedule left, so the tool reaches the block end when the schedule does (the
             * open loop's drift spread over the block's last tenth) */
            if (!settings->update.feedback && remaining <= LANDING_SHARE * length)
                step = step * (length - ns->s_actual) / remaining;
            nurbs_state_advance(ns, &curve, u0, u1, lo, hi, step, &settings->update);
        }
        ns->s_done = local;
    }
    g = sqrt(vec_dot(ns->d1, ns->d1));
    for (i = 0; i < 3; i++) {
        tangent[i] = ns->d1[i] / g;
        pos[i] = ns->point[i];
    }
    /* normalised over the curve's knot range: 1 exactly at its end */
    g = (ns->u - curve.knots[0]) / (curve.knots[curve.n + curve.degree + 1] - curve.knots[0]);
    *u = g < 1.0 ? g : 1.0;
}

static void update_outputs(const double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings) {
    InterpOutputs *out = &st->out;
    const double *r;
    double s = st->s, local, length, lam, pos[3], tangent[3], u;
    int i, kind;
    if (L->n_moves == 0) {
        st->finished = 1;
        set_final(heap, L, st);
        return;
    }
    while (st->move + 1 < L->n_moves) {
        double end;
        r = move_record(heap, L, st->move);
        end = r[MR_S] + r[MR_LENGTH];
        /* into a dwell once at rest on its position, out of any move once past its end */
        if (!(s > end || ((int)move_record(heap, L, st->move + 1)[MR_KIND] == MOVE_DWELL && s >= end && st->v == 0.0)))
            break;
        st->move++;
    }
    if (st->finished) {
        set_final(heap, L, st);
        return;
    }
    r = move_record(heap, L, st->move);
    kind = (int)r[MR_KIND];
    local = s - r[MR_S];
    length = r[MR_LENGTH];
    lam = kind != MOVE_DWELL ? local / length : 0.0;
    if (lam > 1.0) lam = 1.0;
    if (lam < 0.0) lam = 0.0;
    if (kind == MOVE_DWELL) {
        for (i = 0; i < 3; i++) pos[i] = r[MR_START + i], tangent[i] = 0.0;
        u = 0.0;
    } else if (kind == MOVE_RAPID || kind == MOVE_LINE) {
        double d[3], norm;
        for (i = 0; i < 3; i++) {
            pos[i] = lam >= 1.0 ? r[MR_END + i] : r[MR_START + i] + lam * (r[MR_END + i] - r[MR_START + i]);
            d[i] = r[MR_END + i] - r[MR_START + i];
        }
        norm = sqrt(vec_dot(d, d));
        for (i = 0; i < 3; i++) tangent[i] = d[i] / norm;
        u = lam;
    } else if (kind == MOVE_ARC) {
        ArcParams a;
        arc_of(r, &a);
        arc_point(&a, lam, pos);
        arc_tangent(&a, lam, tangent);
        u = lam;
    } else {
        step_nurbs(heap, L, st, settings, r, local, length, pos, tangent, &u);
    }
    for (i = 0; i < 3; i++) {
        out->x[i] = pos[i];
        out->program[i] = pos[i] - r[MR_OFFSET + i];
        out->velocity[i] = st->v * tangent[i];
    }
    out->feed = st->v;
    out->acceleration = st->a;
    out->u = u;
    out->line = (int)r[MR_LINE];
    out->block = (int)r[MR_BLOCK];
    out->spindle = r[MR_SPINDLE];
    out->spindle_on = r[MR_SPINDLE_ON] != 0.0;
    out->rapid = kind == MOVE_RAPID;
    out->finished = 0;
    set_tool(heap, L, out, (int)r[MR_TOOL]);
    out->coolant = (int)r[MR_COOLANT];
}

int interp_tick(double *heap, const InterpLayout *L, InterpState *st, const InterpSettings *settings) {
    const double *pieces = heap + L->pieces, *pc;
    double t, tau, s, v, a;
    int done;
    if (st->planned && !st->at_end && !st->finished && st->s >= st->replan_s &&
        next_window(heap, L, st, settings) != 0)
        return -1;
    st->tick++;
    t = (double)st->tick * settings->limits.period;
    while (st->piece + 1 < st->n_pieces && pieces[PIECE_DOUBLES * (st->piece + 1) + PC_T] <= t) st->piece++;
    pc = pieces + PIECE_DOUBLES * st->piece;
    tau = t - pc[PC_T];
    s = pc[PC_S] + tau * (pc[PC_V] + tau * (0.5 * pc[PC_A] + tau * pc[PC_J] / 6.0));
    v = pc[PC_V] + tau * (pc[PC_A] + 0.5 * tau * pc[PC_J]);
    a = pc[PC_A] + tau * pc[PC_J];
    done = !st->hold && st->at_end && t >= st->end_time;
    if (done || s >= L->total) s = L->total;
    if (done) v = a = 0.0;
    if (s < st->s) s = st->s;
    if (v < 0.0) v = 0.0;
    st->s = s, st->v = v, st->a = a;
    st->finished = done;
    update_outputs(heap, L, st, settings);
    return 0;
}

int interp_holds_still(const double *heap, const InterpLayout *L, const InterpState *before,
                       const InterpState *after) {
    const double *pc;
    InterpState same;
    if (!after->hold || after->n_pieces == 0 || after->piece + 1 != after->n_pieces) return 0;
    pc = heap + L->pieces + PIECE_DOUBLES * after->piece;
    if (pc[PC_V] != 0.0 || pc[PC_A] != 0.0 || pc[PC_J] != 0.0) return 0; /* s, v, a no longer depend on t */
    /* bytewise, padding included: interp_start zeroes the state and the ticks write it field by field, so the
     * padding is zero; were it not, the comparison would only fail and nothing be skipped */
    memcpy(&same, before, sizeof same);
    same.tick = after->tick;
    return memcmp(&same, after, sizeof same) == 0;
}

int interp_check(const double *heap, size_t heap_size, const InterpLayout *L, const InterpState *st) {
    if (!heap || heap_size != L->heap_size || heap_size < 1 || heap[0] != INTERP_MAGIC) return -1;
    if (L->pieces + PIECE_DOUBLES * L->piece_capacity != L->heap_size) return -1;
    if (L->tools + TOOL_DOUBLES * L->n_tools != L->pieces) return -1;
    if (st->n_pieces > L->piece_capacity || st->piece >= (st->n_pieces ? st->n_pieces : 1)) return -1;
    if (L->n_moves && st->move >= L->n_moves) return -1;
    if (L->n_nodes ? st->window_end >= L->n_nodes : st->window_end != 0) return -1;
    return 0;
}

/* Feedrate schedule: look-ahead over the part of the path the view holds (the whole program, or the look-ahead
 * window of interpolator.c) from a given state (s, v, zero acceleration) to its end at rest. Stations (nodes where
 * the acceleration is zero) split the path into segments, each a jerk-limited S-curve to a cruise velocity and
 * another to the next station's velocity; station velocities come from a backward pass over every cap and a
 * forward pass from the start; nodes where a segment would exceed the velocity limit become stations until none
 * does. Mirrored by
 * models/interpolator/schedule.py. */
#ifndef FEED_SCHEDULE_H
#define FEED_SCHEDULE_H

#include <stddef.h>

/* A piece of the schedule in the heap: from time t at path length s, velocity v, acceleration a, jerk j. */
enum { PC_T = 0, PC_S = 1, PC_V = 2, PC_A = 3, PC_J = 4, PIECE_DOUBLES = 5 };
#define PIECES_PER_INTERVAL 7

typedef struct {
    size_t n_nodes, n_ints, n_moves;
    const double *node_s, *node_vh, *node_left, *node_right;
    double *station;
    const double *int_move, *int_at, *int_jt, *int_cap;
    /* n_ints: the intervals planned over (the look-ahead window ends at node n_ints, at rest, at s = total) */
    size_t move_base;   /* soft and dwell hold the moves from move_base on (those of the window) */
    const double *soft; /* per move: F * override capped by max_feed, or the rapid feed */
    const double *dwell; /* per move: seconds the tool stands in a dwell move, 0 for the others */
    double total;
    double *pieces;
    size_t piece_capacity;
    int raised; /* set by schedule_plan: a station's velocity was raised above its hard cap (the start too fast) */
} ScheduleView;

double s_curve_time(double dv, double a, double j);
double s_curve_distance(double v0, double v1, double a, double j);
double reach_up(double v0, double length, double a, double j);
double lowest_feasible(double v_high, double v_low, double length, double a, double j);
double segment_peak(double va, double vb, double length, double cap, double a, double j);
double s_curve_position(double v0, double v1, double a, double j, double w);

/* Plans from (s_start, v_start) at t_start; pieces are written from index first_piece on. Returns 0 and
 * *n_pieces (total, including the first_piece kept ones), *hold (the plan ends in a feed hold) and
 * *end_time (time at rest at the end; infinite when holding), or -1 when out of memory. */
int schedule_plan(ScheduleView *view, double s_start, double v_start, double t_start, size_t first_piece,
                  size_t *n_pieces, int *hold, double *end_time);

#endif

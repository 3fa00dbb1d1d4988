/* A recorded channel sampled at time t exactly as orchestrator.recorded.RecordedData.at does it with numpy,
 * so that the fast path (stepper.c) and the benchmark's plain C driver (tests/benchmarks/stepping_driver.c)
 * give the Python path's values bit for bit:
 *   t is first clipped to [time[0], time[n-1]] (np.clip);
 *   hold:   values[j], j the last sample with time[j] <= t (np.searchsorted(time, t, "right") - 1);
 *   linear: np.interp: values[j] at the last sample or on a sample's time, else
 *           slope * (t - time[j]) + values[j] with slope = (values[j+1] - values[j]) / (time[j+1] - time[j]),
 *           and numpy's fallback from the right-hand sample when that is NaN.
 * The sources compile as ISO C (no FMA contraction), as numpy's baseline code is compiled.
 * Samples are `stride` doubles apart (1: a channel of its own; the driver keeps one row-major table).
 * *hint carries the search position from one call to the next: times that only grow cost O(1).
 */
#ifndef MILLING_TWIN_RECORDED_SAMPLE_H
#define MILLING_TWIN_RECORDED_SAMPLE_H

#include <math.h>
#include <stdint.h>

/* The last j with time[j * stride] <= t (0 when t is before the first sample). */
static inline int64_t recorded_index(const double *time, int64_t stride, int64_t n, double t, int64_t *hint) {
    int64_t j = *hint;
    if (j < 0 || j >= n || time[j * stride] > t) { /* moved backwards (or first call): bisect */
        int64_t lo = 0, hi = n - 1;
        while (lo < hi) {
            const int64_t mid = lo + (hi - lo + 1) / 2;
            if (time[mid * stride] <= t) lo = mid; else hi = mid - 1;
        }
        j = lo;
    }
    while (j + 1 < n && time[(j + 1) * stride] <= t) ++j;
    *hint = j;
    return j;
}

static inline double recorded_sample(const double *time, const double *values, int64_t stride, int64_t n,
                                     int linear, double t, int64_t *hint) {
    int64_t j;
    double slope, value;
    if (t < time[0]) t = time[0];
    if (t > time[(n - 1) * stride]) t = time[(n - 1) * stride];
    j = recorded_index(time, stride, n, t, hint);
    if (!linear || j == n - 1 || time[j * stride] == t) return values[j * stride];
    slope = (values[(j + 1) * stride] - values[j * stride]) / (time[(j + 1) * stride] - time[j * stride]);
    value = slope * (t - time[j * stride]) + values[j * stride];
    if (isnan(value)) {
        value = slope * (t - time[(j + 1) * stride]) + values[(j + 1) * stride];
        if (isnan(value) && values[j * stride] == values[(j + 1) * stride]) value = values[j * stride];
    }
    return value;
}

#endif

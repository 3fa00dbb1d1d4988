/* The force net without FMI (forcenet.h): weights file, network, tool evaluation.
 * Every floating-point operation follows models/force_net.py (network, elements, tool_outputs) in the same
 * order, so the FMU equals that reference to rounding (the tests require 1e-12). */
#include "forcenet.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HEADER_BYTES 56          /* magic, version, 6 sizes, 3 scales */
#define CHUNK 8                  /* elements evaluated together (the activation buffers are CHUNK x width) */

static void say(char *message, size_t size, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

static void say(char *message, size_t size, const char *format, ...) {
    va_list args;
    if (!message || size == 0) return;
    va_start(args, format);
    vsnprintf(message, size, format, args);
    va_end(args);
}

/* ---- the weights file ---- */

static uint32_t u32(const unsigned char *p) {
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

static uint64_t u64(const unsigned char *p) { return (uint64_t)u32(p) | (uint64_t)u32(p + 4) << 32; }

static double f64(const unsigned char *p) {
    uint64_t bits = u64(p);
    double value;
    memcpy(&value, &bits, sizeof value); /* IEEE 754 binary64, as every platform of the FMU */
    return value;
}

static uint64_t fnv1a64(const unsigned char *data, size_t size) {
    uint64_t h = 0xcbf29ce484222325u;
    size_t i;
    for (i = 0; i < size; i++) h = (h ^ data[i]) * 0x100000001b3u;
    return h;
}

int forcenet_parse(const unsigned char *data, size_t size, ForceNetLayout *layout, double *params, char *message,
                   size_t message_size) {
    uint32_t n_in, n_out, l, i, o;
    size_t expected, offset, count = 0;
    double scales[3];
    ForceNetLayout lay;
    memset(&lay, 0, sizeof lay);
    if (size < HEADER_BYTES + 8) {
        say(message, message_size, "truncated: %zu bytes, shorter than the %d-byte header and checksum", size,
            HEADER_BYTES + 8);
        return -1;
    }
    if (memcmp(data, "FORCENET", 8) != 0) {
        say(message, message_size, "not a force-net weights file (its first 8 bytes are not 'FORCENET')");
        return -1;
    }
    if (u32(data + 8) != 1) {
        say(message, message_size, "format version %lu, this FMU reads version 1", (unsigned long)u32(data + 8));
        return -1;
    }
    n_in = u32(data + 12);
    lay.kernel = u32(data + 16);
    lay.width = u32(data + 20);
    lay.blocks = u32(data + 24);
    n_out = u32(data + 28);
    if (n_in != N_FEATURES || n_out != N_LOADS) {
        say(message, message_size,
            "shape mismatch: the network has %lu inputs and %lu outputs, the model needs %d and %d",
            (unsigned long)n_in, (unsigned long)n_out, N_FEATURES, N_LOADS);
        return -1;
    }
    if (lay.kernel < 1 || lay.kernel > MAX_WIDTH || lay.width < 1 || lay.width > MAX_WIDTH ||
        lay.blocks > MAX_BLOCKS) {
        say(message, message_size, "sizes K = %lu, W = %lu, B = %lu outside 1..%d, 1..%d, 0..%d",
            (unsigned long)lay.kernel, (unsigned long)lay.width, (unsigned long)lay.blocks, MAX_WIDTH,
            MAX_WIDTH, MAX_BLOCKS);
        return -1;
    }
    for (i = 0; i < 3; i++) {
        scales[i] = f64(data + 32 + 8 * i);
        if (!(isfinite(scales[i]) && scales[i] > 0.0)) {
            say(message, message_size, "scales h_ref, v_ref, load_ref must be positive and finite");
            return -1;
        }
    }
    lay.h_ref = scales[0];
    lay.v_ref = scales[1];
    lay.load_ref = scales[2];
    lay.layers = 3 + 2 * lay.blocks;
    for (l = 0; l < lay.layers; l++) {
        lay.n_in[l] = l == 0 ? N_FEATURES : l == 1 ? lay.kernel : lay.width;
        lay.n_out[l] = l == 0 ? lay.kernel : l == lay.layers - 1 ? N_LOADS : lay.width;
        lay.weight[l] = count;
        count += (size_t)lay.n_in[l] * lay.n_out[l];
        lay.bias[l] = count;
        count += lay.n_out[l];
    }
    lay.count = count;
    expected = HEADER_BYTES + 8 * lay.layers + 8 * count + 8;
    if (size != expected) {
        say(message, message_size, "%s: %zu bytes, the header (K = %lu, W = %lu, B = %lu) needs %zu",
            size < expected ? "truncated" : "trailing data", size, (unsigned long)lay.kernel,
            (unsigned long)lay.width, (unsigned long)lay.blocks, expected);
        return -1;
    }
    lay.checksum = u64(data + size - 8);
    if (lay.checksum != fnv1a64(data, size - 8)) {
        say(message, message_size, "checksum mismatch (corrupted file)");
        return -1;
    }
    offset = HEADER_BYTES;
    for (l = 0; l < lay.layers; l++) {
        uint32_t rows = u32(data + offset), cols = u32(data + offset + 4);
        if (rows != lay.n_out[l] || cols != lay.n_in[l]) {
            say(message, message_size, "shape mismatch: layer %lu is %lu x %lu, expected %lu x %lu",
                (unsigned long)l, (unsigned long)rows, (unsigned long)cols, (unsigned long)lay.n_out[l],
                (unsigned long)lay.n_in[l]);
            return -1;
        }
        offset += 8;
        for (o = 0; o < rows; o++) {
            for (i = 0; i < cols; i++) {
                double w = f64(data + offset + 8 * ((size_t)o * cols + i));
                if (!isfinite(w)) {
                    say(message, message_size, "layer %lu holds non-finite values", (unsigned long)l);
                    return -1;
                }
                if (params) params[lay.weight[l] + (size_t)i * rows + o] = w; /* transposed: in x out */
            }
        }
        offset += 8 * (size_t)rows * cols;
        for (o = 0; o < rows; o++) {
            double b = f64(data + offset + 8 * (size_t)o);
            if (!isfinite(b)) {
                say(message, message_size, "layer %lu holds non-finite values", (unsigned long)l);
                return -1;
            }
            if (params) params[lay.bias[l] + o] = b;
        }
        offset += 8 * (size_t)rows;
    }
    *layout = lay;
    return 0;
}

unsigned char *forcenet_read_file(const char *path, size_t *size, char *message, size_t message_size) {
    FILE *f = fopen(path, "rb");
    unsigned char *data;
    long length;
    if (!f) {
        say(message, message_size, "cannot open '%s': %s", path, strerror(errno));
        return NULL;
    }
    if (fseek(f, 0, SEEK_END) != 0 || (length = ftell(f)) < 0 || fseek(f, 0, SEEK_SET) != 0) {
        say(message, message_size, "cannot read '%s': %s", path, strerror(errno));
        fclose(f);
        return NULL;
    }
    if ((unsigned long)length > FORCENET_MAX_FILE_BYTES) {
        say(message, message_size, "'%s' has %ld bytes, more than a weights file may (%u MB)", path, length,
            FORCENET_MAX_FILE_BYTES >> 20);
        fclose(f);
        return NULL;
    }
    data = malloc(length > 0 ? (size_t)length : 1);
    if (!data) {
        say(message, message_size, "out of memory reading '%s'", path);
        fclose(f);
        return NULL;
    }
    if (fread(data, 1, (size_t)length, f) != (size_t)length) {
        say(message, message_size, "cannot read '%s': %s", path, ferror(f) ? strerror(errno) : "shorter than its size");
        free(data);
        fclose(f);
        return NULL;
    }
    fclose(f);
    *size = (size_t)length;
    return data;
}

/* ---- the network ---- */

/* The network's matrix products: y[r][o] = b[o] + sum_i x[r][i] * w[i][o], each sum accumulated over i in
 * order (models.force_net._dense). Two versions, picked per call by the CPU's features: an AVX2 kernel (GCC's
 * generic vectors, compiled for AVX2 by a target attribute) and the x86-64 baseline (SSE2, what the compiler
 * makes of plain C). No -march flag, so the FMU runs on any x86-64. Both do the same IEEE multiplications and
 * additions in the same order (no FMA: the AVX2 target does not include it), so they give bit-identical
 * results. (An AVX-512 kernel of the same form measured no faster: at about 1,300 cycles per element the
 * AVX2 kernel is at the limit of two vector multiplications or additions per cycle.) */

/* Outputs o_start.. of a block of rows (the 3 loads of the output layer): four rows at a time, so four
 * independent sums are in flight instead of one long chain of dependent additions. */
#if defined(__GNUC__)
__attribute__((always_inline)) /* compiled into each kernel, for its target */
#endif
static inline void dense_tail(const double *restrict w, const double *restrict b, size_t n_in, size_t n_out,
                              size_t o_start, const double *restrict x, size_t rows, double *restrict y) {
    size_t r = 0, i, o;
    for (; r + 4 <= rows; r += 4) {
        const double *x0 = x + r * n_in, *x1 = x0 + n_in, *x2 = x1 + n_in, *x3 = x2 + n_in;
        for (o = o_start; o < n_out; o++) {
            double s0 = b[o], s1 = b[o], s2 = b[o], s3 = b[o];
            for (i = 0; i < n_in; i++) {
                const double wi = w[i * n_out + o];
                s0 += x0[i] * wi;
                s1 += x1[i] * wi;
                s2 += x2[i] * wi;
                s3 += x3[i] * wi;
            }
            y[r * n_out + o] = s0;
            y[(r + 1) * n_out + o] = s1;
            y[(r + 2) * n_out + o] = s2;
            y[(r + 3) * n_out + o] = s3;
        }
    }
    for (; r < rows; r++)
        for (o = o_start; o < n_out; o++) {
            double sum = b[o];
            for (i = 0; i < n_in; i++) sum += x[r * n_in + i] * w[i * n_out + o];
            y[r * n_out + o] = sum;
        }
}

static inline size_t o_full(size_t n_out) { return n_out - n_out % 8; } /* outputs in groups of 8 */

/* Baseline: two rows by 8 outputs keep their sums in registers and share the loads of the weights; the
 * independent multiply-adds vectorize even at -O2. */
static void dense_baseline(const double *restrict w, const double *restrict b, size_t n_in, size_t n_out,
                  const double *restrict x, size_t rows, double *restrict y) {
    size_t r = 0, i, o;
    for (; r + 2 <= rows; r += 2) {
        const double *x0 = x + r * n_in, *x1 = x0 + n_in;
        double *y0 = y + r * n_out, *y1 = y0 + n_out;
        for (o = 0; o + 8 <= n_out; o += 8) {
            double a0 = b[o], a1 = b[o + 1], a2 = b[o + 2], a3 = b[o + 3];
            double a4 = b[o + 4], a5 = b[o + 5], a6 = b[o + 6], a7 = b[o + 7];
            double c0 = a0, c1 = a1, c2 = a2, c3 = a3, c4 = a4, c5 = a5, c6 = a6, c7 = a7;
            for (i = 0; i < n_in; i++) {
                const double u = x0[i], v = x1[i], *wi = w + i * n_out + o;
                a0 += u * wi[0], c0 += v * wi[0];
                a1 += u * wi[1], c1 += v * wi[1];
                a2 += u * wi[2], c2 += v * wi[2];
                a3 += u * wi[3], c3 += v * wi[3];
                a4 += u * wi[4], c4 += v * wi[4];
                a5 += u * wi[5], c5 += v * wi[5];
                a6 += u * wi[6], c6 += v * wi[6];
                a7 += u * wi[7], c7 += v * wi[7];
            }
            y0[o] = a0, y0[o + 1] = a1, y0[o + 2] = a2, y0[o + 3] = a3;
            y0[o + 4] = a4, y0[o + 5] = a5, y0[o + 6] = a6, y0[o + 7] = a7;
            y1[o] = c0, y1[o + 1] = c1, y1[o + 2] = c2, y1[o + 3] = c3;
            y1[o + 4] = c4, y1[o + 5] = c5, y1[o + 6] = c6, y1[o + 7] = c7;
        }
    }
    dense_tail(w, b, n_in, n_out, o_full(n_out), x, r, y); /* the outputs beyond a multiple of 8 */
    for (; r < rows; r++) { /* an odd last row */
        const double *xr = x + r * n_in;
        double *yr = y + r * n_out;
        for (o = 0; o < n_out; o++) {
            double sum = b[o];
            for (i = 0; i < n_in; i++) sum += xr[i] * w[i * n_out + o];
            yr[o] = sum;
        }
    }
}

#if defined(__x86_64__) && defined(__GNUC__) && defined(__has_attribute)
#if __has_attribute(target)
#define FORCENET_WIDE_KERNELS 1
#endif
#endif

#ifdef FORCENET_WIDE_KERNELS
#include <cpuid.h>

/* AVX2 in the CPU and its 256-bit registers saved by the operating system (OSXSAVE, XCR0 bits 1 and 2): what
 * __builtin_cpu_supports("avx2") tells, without libgcc's __cpu_model, which zig's cc does not link. */
unsigned forcenet_cpu_features(void) {
    unsigned a, b, c, d, xcr0, xcr0_high;
    if (!__get_cpuid(1, &a, &b, &c, &d) || !(c & bit_OSXSAVE) || !(c & bit_AVX)) return 0u;
    __asm__ __volatile__("xgetbv" : "=a"(xcr0), "=d"(xcr0_high) : "c"(0u));
    (void)xcr0_high;
    if ((xcr0 & 6u) != 6u) return 0u;
    if (!__get_cpuid_count(7, 0, &a, &b, &c, &d)) return 0u;
    return (b & bit_AVX2) ? FORCENET_CPU_AVX2 : 0u;
}
#else
unsigned forcenet_cpu_features(void) { return 0u; }
#endif

#ifdef FORCENET_WIDE_KERNELS
typedef double Vec4 __attribute__((vector_size(32))); /* one AVX2 register */
/* macros, not functions: a vector passed by value would depend on the target's ABI */
#define LOAD(vector, pointer) memcpy(&(vector), (pointer), sizeof(vector))
#define STORE(pointer, vector) memcpy((pointer), &(vector), sizeof(vector))

/* AVX2: blocks of 4 rows x 8 outputs (two vectors per row), 8 sums in registers. */
__attribute__((target("avx2"))) static void dense_avx2(const double *restrict w, const double *restrict b,
                                                        size_t n_in, size_t n_out, const double *restrict x,
                                                        size_t rows, double *restrict y) {
    size_t r, i, o, q;
    for (r = 0; r < rows; r += 4) {
        const size_t block = rows - r < 4 ? rows - r : 4;
        const double *x0 = x + r * n_in;
        double *y0 = y + r * n_out;
        for (o = 0; o + 8 <= n_out; o += 8) {
            Vec4 lo, hi;
            LOAD(lo, b + o);
            LOAD(hi, b + o + 4);
            if (block == 4) {
                const double *x1 = x0 + n_in, *x2 = x1 + n_in, *x3 = x2 + n_in;
                Vec4 a0 = lo, a1 = lo, a2 = lo, a3 = lo, c0 = hi, c1 = hi, c2 = hi, c3 = hi;
                for (i = 0; i < n_in; i++) {
                    Vec4 wl, wh;
                    LOAD(wl, w + i * n_out + o);
                    LOAD(wh, w + i * n_out + o + 4);
                    a0 += x0[i] * wl, c0 += x0[i] * wh;
                    a1 += x1[i] * wl, c1 += x1[i] * wh;
                    a2 += x2[i] * wl, c2 += x2[i] * wh;
                    a3 += x3[i] * wl, c3 += x3[i] * wh;
                }
                STORE(y0 + o, a0), STORE(y0 + o + 4, c0);
                STORE(y0 + n_out + o, a1), STORE(y0 + n_out + o + 4, c1);
                STORE(y0 + 2 * n_out + o, a2), STORE(y0 + 2 * n_out + o + 4, c2);
                STORE(y0 + 3 * n_out + o, a3), STORE(y0 + 3 * n_out + o + 4, c3);
            } else {
                for (q = 0; q < block; q++) {
                    const double *xq = x0 + q * n_in;
                    Vec4 a = lo, c = hi;
                    for (i = 0; i < n_in; i++) {
                        Vec4 wl, wh;
                        LOAD(wl, w + i * n_out + o);
                        LOAD(wh, w + i * n_out + o + 4);
                        a += xq[i] * wl, c += xq[i] * wh;
                    }
                    STORE(y0 + q * n_out + o, a), STORE(y0 + q * n_out + o + 4, c);
                }
            }
        }
    }
    dense_tail(w, b, n_in, n_out, o_full(n_out), x, rows, y); /* the outputs beyond a multiple of 8 */
}

#endif

/* FORCENET_KERNEL (a build option for the benchmark): 0 picks by the CPU, 1 the baseline, 2 AVX2 */
#ifndef FORCENET_KERNEL
#define FORCENET_KERNEL 0
#endif

#ifdef FORCENET_WIDE_KERNELS
#define DENSE(...) (wide ? dense_avx2(__VA_ARGS__) : dense_baseline(__VA_ARGS__))
#else
#define DENSE(...) dense_baseline(__VA_ARGS__)
#endif

static void relu(double *x, size_t n) {
    size_t i;
    for (i = 0; i < n; i++) x[i] = x[i] > 0.0 ? x[i] : 0.0;
}

/* The network on n elements with one kernel (wide: AVX2); inlined into one function per target, so that
 * the whole network, activations included, runs in that target's instructions. */
#if defined(__GNUC__)
__attribute__((always_inline))
#endif
static inline void network(const ForceNetLayout *layout, const double *params, const double *features, size_t n,
                           double *loads, int wide) {
    double a[CHUNK * MAX_WIDTH], t[CHUNK * MAX_WIDTH], u[CHUNK * MAX_WIDTH];
    const size_t K = layout->kernel, W = layout->width, last = layout->layers - 1;
    size_t start, i, block;
    (void)wide;
    for (start = 0; start < n; start += CHUNK) {
        size_t rows = n - start < CHUNK ? n - start : CHUNK;
        double *out = loads + start * N_LOADS;
        /* kernel-function block: cube */
        DENSE(params + layout->weight[0], params + layout->bias[0], N_FEATURES, K,
              features + start * N_FEATURES, rows, t);
        for (i = 0; i < rows * K; i++) t[i] = t[i] * t[i] * t[i];
        /* linear-transform block: ReLU */
        DENSE(params + layout->weight[1], params + layout->bias[1], K, W, t, rows, a);
        relu(a, rows * W);
        for (block = 0; block < layout->blocks; block++) {
            size_t l = 2 + 2 * block;
            DENSE(params + layout->weight[l], params + layout->bias[l], W, W, a, rows, t);
            relu(t, rows * W);
            DENSE(params + layout->weight[l + 1], params + layout->bias[l + 1], W, W, t, rows, u);
            for (i = 0; i < rows * W; i++) {
                double sum = a[i] + u[i];
                a[i] = sum > 0.0 ? sum : 0.0;
            }
        }
        DENSE(params + layout->weight[last], params + layout->bias[last], W, N_LOADS, a, rows, out);
        for (i = 0; i < rows * N_LOADS; i++) out[i] = out[i] * layout->load_ref;
    }
}

static void network_baseline(const ForceNetLayout *layout, const double *params, const double *features, size_t n,
                             double *loads) {
    network(layout, params, features, n, loads, 0);
}

#ifdef FORCENET_WIDE_KERNELS
__attribute__((target("avx2"))) static void network_avx2(const ForceNetLayout *layout, const double *params,
                                                          const double *features, size_t n, double *loads) {
    network(layout, params, features, n, loads, 1);
}
#endif

void forcenet_network(const ForceNetLayout *layout, const double *params, const double *features, size_t n,
                      double *loads, unsigned cpu_features) {
#ifdef FORCENET_WIDE_KERNELS
    if (FORCENET_KERNEL == 2 || (FORCENET_KERNEL == 0 && (cpu_features & FORCENET_CPU_AVX2))) {
        network_avx2(layout, params, features, n, loads);
        return;
    }
#else
    (void)cpu_features;
#endif
    network_baseline(layout, params, features, n, loads);
}

/* ---- the tool ---- */

static double wrap(double angle) { return angle - TWO_PI * floor(angle / TWO_PI); }

/* Whether edge element k (of every flute) at feed-frame angle theta is in material: the engagement map's
 * cell holding it (row k * 8 / 16: the map's rows halve the elements' heights; column floor(theta / 15 deg))
 * when that cell is given (>= 0: in material from 0.5 on), else the entry..exit window. */
static int in_material(const double *map, int k, double theta, int in_window) {
    if (map) {
        const size_t row = (size_t)k * MAP_ROWS / ELEMENTS_PER_FLUTE;
        size_t column = (size_t)(theta * (MAP_COLUMNS / TWO_PI));
        double value;
        if (column >= MAP_COLUMNS) column = MAP_COLUMNS - 1; /* theta rounded up to 2 pi */
        value = map[row * MAP_COLUMNS + column];
        if (value >= 0.0) return value >= 0.5;
    }
    return in_window;
}

size_t forcenet_elements(const ForceNetLayout *layout, const ForceNetCut *cut, double *features, double *sin_phi,
                         double *cos_phi, double *z_out, double *radius_out) {
    const int n = cut->n_flutes < MAX_FLUTES ? cut->n_flutes : MAX_FLUTES;
    const double omega = cut->spindle_speed, vx = cut->feed_velocity_x, vy = cut->feed_velocity_y;
    const double radius = cut->tool_diameter / 2.0, dz = cut->axial_depth / ELEMENTS_PER_FLUTE;
    const double dx = cut->displacement_x, dy = cut->displacement_y, offset = cut->runout_offset;
    double period, feed_angle, sin_feed, cos_feed, lag_per_height, entry, width, pitch, v_feature, theta0_feature;
    double z[ELEMENTS_PER_FLUTE], psi[ELEMENTS_PER_FLUTE];
    double sin_psi[ELEMENTS_PER_FLUTE], cos_psi[ELEMENTS_PER_FLUTE];
    size_t count = 0;
    int m, k;
    if (!(omega >= OMEGA_MIN && dz > 0.0) || n < 1) return 0;
    period = TWO_PI / ((double)n * omega);
    feed_angle = atan2(vy, vx);
    sin_feed = sin(feed_angle);
    cos_feed = cos(feed_angle);
    lag_per_height = tan(cut->helix_angle) / radius;
    entry = cut->entry_angle;
    width = wrap(cut->exit_angle - entry);
    pitch = TWO_PI / (double)n;
    v_feature = omega * radius / layout->v_ref;
    theta0_feature = cut->angle / PI - 1.0;
    /* the helix lag of each height, the same for every flute: 2 H + 2 N + 3 libm calls per evaluation,
     * the angles of the elements by the addition theorems */
    for (k = 0; k < ELEMENTS_PER_FLUTE; k++) {
        z[k] = ((double)k + 0.5) * dz;
        psi[k] = z[k] * lag_per_height;
        sin_psi[k] = sin(psi[k]);
        cos_psi[k] = cos(psi[k]);
    }
    for (m = 0; m < n; m++) {
        const double flute = cut->angle + (double)m * pitch, sin_flute = sin(flute), cos_flute = cos(flute);
        /* runout[back - 1] = r_m - r_(m-back), how much further out flute m reaches than the flute back teeth
         * before it: CuttingForce's runout chip (models/cutting_force.py, _runout_chip) */
        double runout[MAX_FLUTES] = {0.0}, flute_radius = radius;
        int back;
        if (offset != 0.0) {
            const double own = cos(cut->runout_angle - (double)m * pitch);
            for (back = 1; back <= n; back++)
                runout[back - 1] = offset * (own - cos(cut->runout_angle - (double)(m - back) * pitch));
            flute_radius = radius + offset * own;
        }
        for (k = 0; k < ELEMENTS_PER_FLUTE; k++) {
            const double phi = flute - psi[k];
            const double s = sin_flute * cos_psi[k] - cos_flute * sin_psi[k]; /* sin(phi) */
            const double c = cos_flute * cos_psi[k] + sin_flute * sin_psi[k]; /* cos(phi) */
            const double feed_chip = period * (vx * s + vy * c);
            double chip = feed_chip + runout[0], h, *f = features + count * N_FEATURES;
            for (back = 2; back <= n; back++) { /* the material every flute before this one left */
                const double earlier = (double)back * feed_chip + runout[back - 1];
                if (earlier < chip) chip = earlier;
            }
            h = chip + dx * s + dy * c;
            if (!(h > 0.0 && in_material(cut->engagement, k, wrap(phi + feed_angle),
                                         wrap(phi + feed_angle - entry) < width)))
                continue;
            f[0] = h / layout->h_ref;
            f[1] = v_feature;
            f[2] = theta0_feature;
            f[3] = s * cos_feed + c * sin_feed; /* sin(theta), theta = phi + feed angle */
            f[4] = c * cos_feed - s * sin_feed; /* cos(theta) */
            f[5] = sin_psi[k];
            f[6] = cos_psi[k];
            sin_phi[count] = s;
            cos_phi[count] = c;
            z_out[count] = z[k];
            radius_out[count] = flute_radius;
            count++;
        }
    }
    return count;
}

void forcenet_tool(const ForceNetLayout *layout, const double *params, const ForceNetCut *cut, ForceNetTool *out,
                   unsigned cpu_features) {
    double features[FORCENET_MAX_ELEMENTS * N_FEATURES], loads[FORCENET_MAX_ELEMENTS * N_LOADS];
    double s[FORCENET_MAX_ELEMENTS], c[FORCENET_MAX_ELEMENTS], z[FORCENET_MAX_ELEMENTS], r[FORCENET_MAX_ELEMENTS];
    const double dz = cut->axial_depth / ELEMENTS_PER_FLUTE;
    const double zp = cut->moment_height;
    double fx = 0.0, fy = 0.0, fz = 0.0, torque = 0.0, mx = 0.0, my = 0.0, mz = 0.0, max_chip = 0.0;
    size_t n = forcenet_elements(layout, cut, features, s, c, z, r), i;
    memset(out, 0, sizeof *out);
    if (n == 0) return;
    forcenet_network(layout, params, features, n, loads, cpu_features);
    for (i = 0; i < n; i++) {
        double ft = loads[3 * i] * dz, fr = loads[3 * i + 1] * dz, fa = loads[3 * i + 2] * dz;
        double dfx = -ft * c[i] - fr * s[i], dfy = ft * s[i] - fr * c[i];
        double px = r[i] * s[i], py = r[i] * c[i], pz = z[i] - zp;
        fx += dfx;
        fy += dfy;
        fz += fa;
        torque += ft * r[i];
        mx += py * fa - pz * dfy;
        my += pz * dfx - px * fa;
        mz += px * dfy - py * dfx;
        if (features[N_FEATURES * i] > max_chip) max_chip = features[N_FEATURES * i];
    }
    out->Fx = fx;
    out->Fy = fy;
    out->Fz = fz;
    out->torque = torque;
    out->power = torque * cut->spindle_speed;
    out->Mx = mx;
    out->My = my;
    out->Mz = mz;
    out->elements = n;
    out->max_chip = max_chip * layout->h_ref;
}

/* The force net without FMI: the weights file, the network and the tool evaluation
 * of models/force_net.py (same operations in the same order as its numpy reference). model.c wraps it into
 * the FMU; tools/forcenet_run.c drives it from the tests and the benchmark. No global state: the parameters
 * live in a caller's array (the FMU's instance heap) described by a ForceNetLayout (flat). */
#ifndef FORCENET_H
#define FORCENET_H

#include <stddef.h>
#include <stdint.h>

/* From models/force_net.py, in the generated model_constants.h: N_FEATURES (h/h_ref, v/v_ref, theta0/pi - 1,
 * sin/cos(theta), sin/cos(psi)), N_LOADS (tangential, radial, axial load per unit edge length), MAX_WIDTH and
 * MAX_BLOCKS (the largest K, W and number of residual blocks accepted), ELEMENTS_PER_FLUTE (H), MAX_FLUTES,
 * MAP_ROWS x MAP_COLUMNS (the Workpiece's engagement map: heights, and angles of 15 deg each). */
#include "model_constants.h"

#define FORCENET_MAX_LAYERS (3 + 2 * MAX_BLOCKS)
#define FORCENET_MAX_ELEMENTS (MAX_FLUTES * ELEMENTS_PER_FLUTE)
#define FORCENET_MAX_FILE_BYTES (16u << 20)
#define FORCENET_WEIGHTS_FILE "weights.bin"

/* Sizes and scales of a loaded network and where its layers are in the parameter array: layer l has its
 * weight transposed, in x out (row i holds the weights of input i to every output), at offset weight[l],
 * then its out biases at bias[l]. Flat: copied by value into FMU states. */
typedef struct {
    uint32_t kernel, width, blocks, layers;
    uint32_t n_in[FORCENET_MAX_LAYERS], n_out[FORCENET_MAX_LAYERS];
    size_t weight[FORCENET_MAX_LAYERS], bias[FORCENET_MAX_LAYERS];
    size_t count; /* doubles in the parameter array */
    double h_ref, v_ref, load_ref;
    uint64_t checksum;
} ForceNetLayout;

/* Checks a weights file image (format in models/force_net.py, encode_weights) and fills `layout`; with
 * `params` non-NULL (layout->count doubles, from a first call with NULL) also copies the parameters.
 * Returns 0, or -1 with the reason in `message` ("truncated: ...", "shape mismatch: ...", ...). */
int forcenet_parse(const unsigned char *data, size_t size, ForceNetLayout *layout, double *params, char *message,
                   size_t message_size);

/* Reads a whole file (at most FORCENET_MAX_FILE_BYTES); the caller frees it. NULL and a message on failure. */
unsigned char *forcenet_read_file(const char *path, size_t *size, char *message, size_t message_size);

/* What the CPU running this process offers the network's kernels (FORCENET_CPU_* bits): cpuid on x86-64
 * (AVX2 and the operating system's saving of its registers), 0 elsewhere. A cpuid is slow under a hypervisor
 * (tens of microseconds), so callers ask once (the FMU at instantiation) and pass the bits on. */
#define FORCENET_CPU_AVX2 1u
unsigned forcenet_cpu_features(void);

/* Loads per unit edge length [N/m] (n x 3) of n elements from their features (n x 7), with the AVX2 kernel
 * when `cpu_features` has FORCENET_CPU_AVX2 (the same sums in the same order: bit-identical loads). */
void forcenet_network(const ForceNetLayout *layout, const double *params, const double *features, size_t n,
                      double *loads, unsigned cpu_features);

/* The cutting state of one evaluation (SI units, the FMU's variables) */
typedef struct {
    int n_flutes;
    double tool_diameter, helix_angle, moment_height;
    double runout_offset, runout_angle; /* flute m's radius is R + offset * cos(angle - m * 2 pi / N) */
    double spindle_speed, feed_velocity_x, feed_velocity_y, axial_depth, entry_angle, exit_angle;
    double displacement_x, displacement_y; /* the tool's displacement now minus one tooth period ago: the
                                            * regenerative chip (0 and 0: the static chip) */
    double angle; /* spindle angle theta0 of flute 0 at the tip */
    const double *engagement; /* NULL, or the engagement map (MAP_ROWS x MAP_COLUMNS, row-major,
                               * feed frame): a cell >= 0 says whether its elements are in material (>= 0.5), a
                               * negative cell leaves it to the window entry_angle..exit_angle */
} ForceNetCut;

typedef struct {
    double Fx, Fy, Fz, torque, power, Mx, My, Mz; /* N, N.m, W */
    size_t elements;                              /* elements in contact */
    double max_chip;                              /* largest chip thickness in contact [m] */
} ForceNetTool;

/* The elements in contact (features n x 7, and for each sin/cos(phi), z and its flute's radius): returns n. */
size_t forcenet_elements(const ForceNetLayout *layout, const ForceNetCut *cut, double *features, double *sin_phi,
                         double *cos_phi, double *z, double *radius);

/* One full evaluation of the tool: elements, network, forces and moments. */
void forcenet_tool(const ForceNetLayout *layout, const double *params, const ForceNetCut *cut, ForceNetTool *out,
                  unsigned cpu_features);

#endif

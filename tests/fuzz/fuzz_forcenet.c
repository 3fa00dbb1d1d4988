/* Fuzz harness of the ForceNet FMU's resource handling (libFuzzer entry point; tests/fuzz/README.md), through
 * fmus/forcenet/forcenet.h:
 * - the weights file loader forcenet_parse on the input as it is, then on a copy whose trailing FNV-1a checksum
 *   is made to match (otherwise almost every mutation would stop at the checksum): a file the loader accepts
 *   must describe a layout that fits the file, load the same way twice, and evaluate the tool (elements,
 *   network, forces) without touching memory outside the parameter array;
 * - the resource location parser fmu_resource_file (fmus/common/resource_location.c) on the input as a string (FMI 2 file URIs, FMI 3
 *   paths), into output buffers of several sizes: an accepted location gives a terminated path that fits and
 *   ends in "/weights.bin" (a URI with %00 is rejected); a rejected one gives a message. */
#define _POSIX_C_SOURCE 200809L
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "forcenet.h"
#include "resource_location.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define REQUIRE(condition, what)                                                                             \
    do {                                                                                                     \
        if (!(condition)) {                                                                                  \
            fprintf(stderr, "fuzz_forcenet: %s (line %d)\n", what, __LINE__);                                 \
            abort();                                                                                         \
        }                                                                                                    \
    } while (0)

static uint64_t fnv1a64(const unsigned char *bytes, size_t size) {
    uint64_t h = 0xcbf29ce484222325u;
    size_t i;
    for (i = 0; i < size; i++) h = (h ^ bytes[i]) * 0x100000001b3u;
    return h;
}

/* A layout the loader accepted: sizes within the limits and every layer inside the parameter array. */
static void check_layout(const ForceNetLayout *layout, size_t size) {
    uint32_t l;
    size_t end = 0;
    REQUIRE(layout->kernel >= 1 && layout->kernel <= MAX_WIDTH, "kernel width out of range");
    REQUIRE(layout->width >= 1 && layout->width <= MAX_WIDTH, "width out of range");
    REQUIRE(layout->blocks <= MAX_BLOCKS && layout->layers == 3 + 2 * layout->blocks, "bad layer count");
    for (l = 0; l < layout->layers; l++) {
        REQUIRE(layout->weight[l] == end, "layers not contiguous");
        end += (size_t)layout->n_in[l] * layout->n_out[l];
        REQUIRE(layout->bias[l] == end, "bias not after its weights");
        end += layout->n_out[l];
    }
    REQUIRE(end == layout->count, "parameter count does not match the layers");
    REQUIRE(8 * layout->count < size, "more parameters than the file holds");
    REQUIRE(layout->h_ref > 0 && layout->v_ref > 0 && layout->load_ref > 0, "non-positive scales accepted");
}

static void evaluate(const ForceNetLayout *layout, const double *params, const uint8_t *data, size_t size) {
    ForceNetCut cut;
    ForceNetTool tool;
    double features[2 * N_FEATURES], loads[2 * N_LOADS];
    size_t i;
    for (i = 0; i < 2 * N_FEATURES; i++) features[i] = ((double)data[(i * 7) % size] - 128.0) / 32.0;
    forcenet_network(layout, params, features, 2, loads, forcenet_cpu_features());
    memset(&cut, 0, sizeof cut);
    cut.n_flutes = 1 + data[size / 2] % MAX_FLUTES;
    cut.tool_diameter = 0.01;
    cut.helix_angle = 0.5;
    cut.moment_height = 0.05;
    cut.spindle_speed = 500.0;
    cut.feed_velocity_x = 0.01;
    cut.feed_velocity_y = 0.002;
    cut.axial_depth = 0.001 * (1 + data[size - 9] % 30);
    cut.entry_angle = 0.0;
    cut.exit_angle = 3.141592653589793;
    cut.angle = (double)data[size / 3] / 40.0;
    forcenet_tool(layout, params, &cut, &tool, forcenet_cpu_features());
    REQUIRE(tool.elements <= FORCENET_MAX_ELEMENTS, "more elements in contact than the tool has");
}

static void weights_file(const uint8_t *data, size_t size) {
    ForceNetLayout layout, again;
    char message[256];
    unsigned char *file;
    double *params;
    int pass;
    message[0] = '\0';
    if (forcenet_parse(data, size, &layout, NULL, message, sizeof message) != 0)
        REQUIRE(message[0] != '\0' && strlen(message) < sizeof message, "rejected without a message");
    if (size < 64) return;
    /* exact-size heap copy (an overread is reported) with the checksum that makes it pass that check */
    file = malloc(size);
    REQUIRE(file != NULL, "out of memory");
    memcpy(file, data, size);
    {
        uint64_t h = fnv1a64(file, size - 8);
        for (pass = 0; pass < 8; pass++) file[size - 8 + (size_t)pass] = (unsigned char)(h >> (8 * pass));
    }
    message[0] = '\0';
    if (forcenet_parse(file, size, &layout, NULL, message, sizeof message) != 0) {
        REQUIRE(message[0] != '\0', "rejected without a message");
        free(file);
        return;
    }
    check_layout(&layout, size);
    params = malloc(layout.count * sizeof *params); /* exactly layout.count: the loader writes no further */
    REQUIRE(params != NULL, "out of memory");
    REQUIRE(forcenet_parse(file, size, &again, params, message, sizeof message) == 0, "second load failed");
    REQUIRE(memcmp(&layout, &again, sizeof layout) == 0, "the two loads give different layouts");
    for (pass = 0; (size_t)pass < layout.count; pass++) REQUIRE(isfinite(params[pass]), "non-finite parameter");
    evaluate(&layout, params, data, size);
    free(params);
    free(file);
}

static void resource_location(const uint8_t *data, size_t size) {
    static const size_t sizes[] = {1, 13, 64, 4096};
    char *location = malloc(size + 1), message[256];
    size_t k;
    REQUIRE(location != NULL, "out of memory");
    memcpy(location, data, size);
    location[size] = '\0';
    for (k = 0; k < sizeof sizes / sizeof sizes[0]; k++) {
        char *path = malloc(sizes[k]); /* exact size: a write past it is reported */
        REQUIRE(path != NULL, "out of memory");
        message[0] = '\0';
        if (fmu_resource_file(location, FORCENET_WEIGHTS_FILE, path, sizes[k], message, sizeof message) == 0) {
            size_t n = strnlen(path, sizes[k]);
            /* a decoded NUL would cut the path short: another file would be opened */
            REQUIRE(strncmp(location, "file:", 5) != 0 || strstr(location, "%00") == NULL, "%00 accepted in a URI");
            REQUIRE(n < sizes[k], "accepted path not terminated inside the buffer");
            REQUIRE(n >= strlen("/" FORCENET_WEIGHTS_FILE) &&
                        strcmp(path + n - strlen("/" FORCENET_WEIGHTS_FILE), "/" FORCENET_WEIGHTS_FILE) == 0,
                    "accepted path does not end in /weights.bin");
        } else {
            REQUIRE(message[0] != '\0', "location rejected without a message");
        }
        free(path);
    }
    free(location);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    weights_file(data, size);
    if (size <= 8192) resource_location(data, size);
    return 0;
}

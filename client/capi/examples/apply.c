/* Applies an operator bundle through the lightfarm C ABI, as a C engine would.
 *
 *   apply BUNDLE.lfb LIGHTS.txt
 *
 * LIGHTS.txt holds one point light per line, "x y z r g b" (position in metres, radiant
 * intensity in W/sr per channel); blank lines and lines starting with '#' are skipped.
 *
 * Loads the bundle, computes direct light from the lights, applies DRT if the bundle has it
 * (else MRT) and prints one line:
 *
 *   texels=N method=drt|mrt checksum=S max=M direct_checksum=D
 *
 * with S the sum of every output float, M the largest and D the sum of the direct light (sums
 * in double, in buffer order). Exit status 0 on success, 1 on any error (message on stderr).
 *
 * Build (from the repository root, after `cargo build --release -p lightfarm-client-capi`):
 *   cc -std=c99 -Wall -Wextra -I client/capi/include client/capi/examples/apply.c \
 *      -L target/release -llightfarm -Wl,-rpath,"$PWD/target/release" -o apply
 */
#include <stdio.h>
#include <stdlib.h>

#include "lightfarm.h"

/* Prints the library's last error (it names the failing call) and returns 1. */
static int fail(void) {
    char message[512];
    lf_last_error(message, sizeof message);
    fprintf(stderr, "error: %s\n", message);
    return 1;
}

/* Reads a whole file; NULL on error. */
static unsigned char *read_file(const char *path, size_t *len) {
    FILE *f = fopen(path, "rb");
    unsigned char *data = NULL;
    size_t cap = 0;
    *len = 0;
    if (!f) return NULL;
    for (;;) {
        if (*len == cap) {
            unsigned char *grown;
            cap = cap ? 2 * cap : 1 << 16;
            grown = realloc(data, cap);
            if (!grown) break;
            data = grown;
        }
        size_t got = fread(data + *len, 1, cap - *len, f);
        *len += got;
        if (got == 0) {
            if (ferror(f)) break;
            fclose(f);
            return data;
        }
    }
    free(data);
    fclose(f);
    return NULL;
}

/* Reads "x y z r g b" lines; returns the light count, or -1 on error (*lights malloc'd). */
static long read_lights(const char *path, LfPointLight **lights) {
    FILE *f = fopen(path, "r");
    char line[512];
    long n = 0, cap = 0, line_no = 0;
    *lights = NULL;
    if (!f) return -1;
    while (fgets(line, sizeof line, f)) {
        LfPointLight l;
        char first = ' ';
        line_no++;
        if (sscanf(line, " %c", &first) != 1 || first == '#') continue;
        if (sscanf(line, "%f %f %f %f %f %f", &l.position[0], &l.position[1], &l.position[2],
                   &l.intensity[0], &l.intensity[1], &l.intensity[2]) != 6) {
            fprintf(stderr, "%s:%ld: expected \"x y z r g b\"\n", path, line_no);
            n = -1;
            break;
        }
        if (n == cap) {
            LfPointLight *grown;
            cap = cap ? 2 * cap : 8;
            grown = realloc(*lights, (size_t)cap * sizeof **lights);
            if (!grown) { n = -1; break; }
            *lights = grown;
        }
        (*lights)[n++] = l;
    }
    fclose(f);
    return n;
}

int main(int argc, char **argv) {
    size_t len = 0, n_floats, i;
    unsigned char *bytes;
    LfPointLight *lights = NULL;
    long n_lights;
    LfRuntime *rt;
    float *direct, *indirect;
    int32_t method, status;
    double checksum = 0.0, direct_checksum = 0.0, max = 0.0;

    if (argc != 3) {
        fprintf(stderr, "usage: %s BUNDLE.lfb LIGHTS.txt\n", argv[0]);
        return 2;
    }
    bytes = read_file(argv[1], &len);
    if (!bytes) { perror(argv[1]); return 1; }
    n_lights = read_lights(argv[2], &lights);
    if (n_lights < 0) { perror(argv[2]); return 1; }

    rt = lf_runtime_new(bytes, len);
    free(bytes); /* the runtime keeps its own copy */
    if (!rt) return fail();

    n_floats = 3 * lf_runtime_texel_count(rt);
    direct = malloc(n_floats * sizeof *direct);
    indirect = malloc(n_floats * sizeof *indirect);
    if (!direct || !indirect) { fprintf(stderr, "out of memory\n"); return 1; }

    status = lf_runtime_direct_from_point_lights(rt, lights, (size_t)n_lights, direct, n_floats);
    if (status != LF_STATUS_OK) return fail();

    method = lf_runtime_has_drt(rt) ? LF_METHOD_DRT : LF_METHOD_MRT;
    status = lf_runtime_apply(rt, method, direct, n_floats, indirect, n_floats);
    if (status != LF_STATUS_OK) return fail();

    max = n_floats ? indirect[0] : 0.0;
    for (i = 0; i < n_floats; i++) {
        checksum += indirect[i];
        direct_checksum += direct[i];
        if (indirect[i] > max) max = indirect[i];
    }
    printf("texels=%zu method=%s applications=%u checksum=%.6e max=%.6e direct_checksum=%.6e\n",
           n_floats / 3, method == LF_METHOD_DRT ? "drt" : "mrt",
           (unsigned)lf_runtime_last_bounces(rt), checksum, max, direct_checksum);

    lf_runtime_free(rt);
    free(direct);
    free(indirect);
    free(lights);
    return 0;
}

/* Applies an operator bundle through the lightfarm C ABI, as a C engine would.
 *
 *   apply BUNDLE.lfb LIGHTS.txt [POSE]
 *
 * LIGHTS.txt holds one point light per line, "x y z r g b" (position in metres, radiant
 * intensity in W/sr per channel); blank lines and lines starting with '#' are skipped. POSE,
 * "id,x,y,z,qx,qy,qz,qw", places that dynamic object of the bundle (translation in metres,
 * rotation quaternion) before anything is lit.
 *
 * Loads the bundle, computes direct light from the lights, applies DRT if the bundle has it
 * (else MRT), then does it again the way an engine with its own direct light does: reads the
 * texel layout (centres, normals, albedo) and each texel's lightmap-atlas pixel, computes
 * unshadowed direct light from the same lights into an atlas image (an engine would render it
 * there on the GPU, with its own shadows), gathers it by texel, applies it and scatters the
 * indirect light back into the atlas. Prints one line:
 *
 *   texels=N method=drt|mrt applications=A checksum=S max=M direct_checksum=D surfaces=K
 *   first_surface=NAME atlas=WxH engine_direct_checksum=ED engine_checksum=E
 *   probes=P [probe_checksum=PC probe_irradiance=PE [object_spans=OS object_checksum=OC
 *   object_bounce_checksum=OB shadow_spans=SS shadow_checksum=SC]] moved_spans=MS moved_error=ME
 *   light_direct_same=B feedback_calls=FC feedback_error=FE feedback_lag=FL feedback_left=FR
 *
 * with S the sum of every output float, M the largest, D the sum of the direct light, ED the
 * sum of the engine's direct light and E the sum of the engine path's indirect-light atlas
 * (sums in double, in buffer or row order); P the probes of the bundle's probe volume (for
 * dynamic objects), fed the light leaving the texels (direct plus indirect), PC the sum of the
 * field's floats and PE the irradiance 0.25 m above texel 0 (sum of R, G and B); with POSE,
 * the placed object's own light on the texels around it (OS: its spans, OC: the sum of its
 * floats) and the sum OB of its bounces, and the change of direct light its shadow makes when
 * it moves 0.1 m along x (SS: its spans, SC: the sum of its floats); then moves
 * light 0 by 0.25 m and relights by the
 * change (MS: the spans it reaches, ME: relative L2 against relighting everything, B: 1 when
 * the one-call direct light of a light's reach is the two-call one), and moves it back in
 * LF_BOUNCES_FEEDBACK until nothing is due (FC: the calls after the change, FE: relative L2
 * against the first answer, FL and FR: the runtime's estimate of the light still to arrive
 * after the change and once settled). Exit status 0 on success, 1 on any error (message on
 * stderr).
 *
 * Build (from the repository root, after `cargo build --release -p lightfarm-client-capi`):
 *   cc -std=c99 -Wall -Wextra -I client/capi/include client/capi/examples/apply.c \
 *      -L target/release -llightfarm -lm -Wl,-rpath,"$PWD/target/release" -o apply
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "lightfarm.h"

/* Prints the library's last error (it names the failing call) and returns 1. */
static int fail(void) {
    char message[512];
    lf_last_error(message, sizeof message);
    fprintf(stderr, "error: %s\n", message);
    return 1;
}

/* Checks the layout's surfaces: contiguous, in order, covering every texel; prints
 * "surfaces=K first_surface=NAME ". Returns 0, or 1 on error. */
static int check_surfaces(const LfRuntime *rt) {
    size_t k, count = lf_runtime_surface_count(rt);
    uint32_t next = 0;
    for (k = 0; k < count; k++) {
        uint32_t offset, texels;
        /* First ask for the name's size, then copy it. */
        int64_t needed = lf_runtime_surface(rt, k, NULL, 0, NULL, NULL);
        char *name;
        if (needed < 0) return fail();
        name = malloc((size_t)needed);
        if (!name) { fprintf(stderr, "out of memory\n"); return 1; }
        if (lf_runtime_surface(rt, k, name, (size_t)needed, &offset, &texels) != needed) {
            free(name);
            return fail();
        }
        if (offset != next) {
            fprintf(stderr, "surface %s starts at texel %u, not %u\n", name, (unsigned)offset,
                    (unsigned)next);
            free(name);
            return 1;
        }
        if (k == 0) printf("surfaces=%zu first_surface=%s ", count, name);
        next += texels;
        free(name);
    }
    if (next != lf_runtime_texel_count(rt)) {
        fprintf(stderr, "surfaces cover %u texels, not %zu\n", (unsigned)next,
                lf_runtime_texel_count(rt));
        return 1;
    }
    return 0;
}

/* The engine path: direct light at each texel centre, rho/pi * sum I * max(cos, 0) / r^2 (no
 * shadows here; an engine applies its own), written into the lightmap atlas, gathered by
 * texel, applied, and the indirect light scattered back into the atlas. Prints
 * "atlas=WxH engine_direct_checksum=ED engine_checksum=E". Returns 0, or 1 on error. */
static int engine_path(LfRuntime *rt, int32_t method, const LfPointLight *lights,
                       long n_lights) {
    const double inv_pi = 0.31830988618379067154;
    size_t n = lf_runtime_texel_count(rt), t, c, i;
    uint32_t width, height;
    float *pos = malloc(3 * n * sizeof *pos), *nrm = malloc(3 * n * sizeof *nrm);
    float *rho = malloc(3 * n * sizeof *rho), *direct = malloc(3 * n * sizeof *direct);
    float *indirect = malloc(3 * n * sizeof *indirect), *image = NULL;
    uint32_t *xy = malloc(2 * n * sizeof *xy);
    double direct_sum = 0.0, atlas_sum = 0.0;
    int result = 1;

    if (!pos || !nrm || !rho || !direct || !indirect || !xy) {
        fprintf(stderr, "out of memory\n");
        goto out;
    }
    if (lf_runtime_texel_positions(rt, pos, 3 * n) != LF_STATUS_OK ||
        lf_runtime_texel_normals(rt, nrm, 3 * n) != LF_STATUS_OK ||
        lf_runtime_texel_albedo(rt, rho, 3 * n) != LF_STATUS_OK ||
        lf_runtime_atlas_size(rt, &width, &height) != LF_STATUS_OK ||
        lf_runtime_atlas_texels(rt, xy, 2 * n) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    image = calloc(3 * (size_t)width * height, sizeof *image);
    if (!image) {
        fprintf(stderr, "out of memory\n");
        goto out;
    }

    /* "Render" direct light into the atlas: texel t owns pixel (xy[2t], xy[2t+1]). */
    for (t = 0; t < n; t++) {
        double e[3] = {0.0, 0.0, 0.0};
        float *pixel = image + 3 * ((size_t)xy[2 * t + 1] * width + xy[2 * t]);
        for (i = 0; i < (size_t)n_lights; i++) {
            double d[3], r2 = 0.0, cosine = 0.0;
            for (c = 0; c < 3; c++) {
                d[c] = (double)lights[i].position[c] - pos[3 * t + c];
                r2 += d[c] * d[c];
                cosine += nrm[3 * t + c] * d[c];
            }
            if (r2 <= 0.0 || cosine <= 0.0) continue;
            cosine /= sqrt(r2);
            for (c = 0; c < 3; c++) e[c] += lights[i].intensity[c] * cosine / r2;
        }
        for (c = 0; c < 3; c++) pixel[c] = (float)(rho[3 * t + c] * inv_pi * e[c]);
    }
    /* Gather it into the vector lf_runtime_apply takes, apply, scatter the result back. */
    for (t = 0; t < n; t++)
        for (c = 0; c < 3; c++) {
            direct[3 * t + c] = image[3 * ((size_t)xy[2 * t + 1] * width + xy[2 * t]) + c];
            direct_sum += direct[3 * t + c];
        }
    if (lf_runtime_apply(rt, method, direct, 3 * n, indirect, 3 * n) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    for (i = 0; i < 3 * (size_t)width * height; i++) image[i] = 0.0f;
    for (t = 0; t < n; t++)
        for (c = 0; c < 3; c++)
            image[3 * ((size_t)xy[2 * t + 1] * width + xy[2 * t]) + c] = indirect[3 * t + c];
    for (i = 0; i < 3 * (size_t)width * height; i++) atlas_sum += image[i];
    printf("atlas=%ux%u engine_direct_checksum=%.6e engine_checksum=%.6e", (unsigned)width,
           (unsigned)height, direct_sum, atlas_sum);
    result = 0;
out:
    free(pos); free(nrm); free(rho); free(direct); free(indirect); free(xy); free(image);
    return result;
}

/* The probe volume dynamic objects are lit from, when the bundle has one: fed the light leaving
 * the texels (direct plus the indirect light of the first application, all bounces), read back
 * whole and as irradiance 0.25 m above texel 0 along its normal. Prints " probes=P" and, with
 * P > 0, " probe_checksum=PC probe_irradiance=PE" (PC the sum of the field's floats, PE the
 * sum of the three channels). Returns 0, or 1 on error. */
/* The placed objects' own light around them and its bounces (see the top comment); prints
 * " object_spans=OS object_checksum=OC object_bounce_checksum=OB". Returns 0, or 1 on error. */
static int object_part(LfRuntime *rt, int32_t method, const LfPointLight *lights,
                       long n_lights, const LfPose *pose, size_t n_floats) {
    size_t capacity = 0, count = 0, i, k;
    LfTexelSpan *spans = NULL;
    float *light = calloc(n_floats, sizeof *light), *bounced = malloc(n_floats * sizeof *bounced);
    double light_sum = 0.0, bounce_sum = 0.0, shadow_sum = 0.0;
    LfPose moved = *pose;
    int32_t status;
    int result = 1;

    if (!light || !bounced) {
        fprintf(stderr, "out of memory\n");
        goto out;
    }
    /* First ask how many spans, then make room for them. */
    status = lf_runtime_object_light(rt, lights, (size_t)n_lights, NULL, 0, &count, light,
                                     n_floats);
    if (status == LF_STATUS_BAD_LENGTH && count > 0) {
        capacity = count;
        spans = malloc(capacity * sizeof *spans);
        if (!spans) { fprintf(stderr, "out of memory\n"); goto out; }
        status = lf_runtime_object_light(rt, lights, (size_t)n_lights, spans, capacity, &count,
                                         light, n_floats);
    }
    if (status != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    for (k = 0; k < count; k++)
        for (i = 3 * (size_t)spans[k].start; i < 3 * (size_t)spans[k].end; i++)
            light_sum += light[i];
    /* Its bounces alone: added to zeros (an engine adds them to its indirect light). */
    memset(bounced, 0, n_floats * sizeof *bounced);
    if (lf_runtime_bounce_object_light(rt, method, bounced, n_floats) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    for (i = 0; i < n_floats; i++) bounce_sum += bounced[i];
    printf(" object_spans=%zu object_checksum=%.6e object_bounce_checksum=%.6e", count,
           light_sum, bounce_sum);
    /* The object moved 0.1 m along x: the change of direct light its shadow makes, on the
       spans it lies in (asked for first, as above), then the object put back. */
    moved.translation[0] += 0.1f;
    if (lf_runtime_set_poses(rt, &moved, 1) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    status = lf_runtime_shadow_change(rt, lights, (size_t)n_lights, spans, capacity, &count,
                                      light, n_floats);
    if (status == LF_STATUS_BAD_LENGTH && count > capacity) {
        LfTexelSpan *more = realloc(spans, count * sizeof *spans);
        if (!more) { fprintf(stderr, "out of memory\n"); goto out; }
        spans = more;
        capacity = count;
        status = lf_runtime_shadow_change(rt, lights, (size_t)n_lights, spans, capacity, &count,
                                          light, n_floats);
    }
    if (status != LF_STATUS_OK || lf_runtime_set_poses(rt, pose, 1) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    for (k = 0; k < count; k++)
        for (i = 3 * (size_t)spans[k].start; i < 3 * (size_t)spans[k].end; i++)
            shadow_sum += light[i];
    printf(" shadow_spans=%zu shadow_checksum=%.6e", count, shadow_sum);
    result = 0;
out:
    free(spans); free(light); free(bounced);
    return result;
}

static int probe_part(LfRuntime *rt, int32_t method, const LfPointLight *lights,
                      long n_lights, const LfPose *pose, const float *direct,
                      const float *indirect, size_t n_floats) {
    size_t probes = lf_runtime_probe_count(rt), i;
    float *leaving, *field, pos[3], nrm[3], at[3], e[3];
    double field_sum = 0.0;
    int result = 1;

    printf(" probes=%zu", probes);
    if (probes == 0) return 0;
    leaving = malloc(n_floats * sizeof *leaving);
    field = malloc(probes * LF_PROBE_FLOATS * sizeof *field);
    if (!leaving || !field) {
        fprintf(stderr, "out of memory\n");
        goto out;
    }
    for (i = 0; i < n_floats; i++) leaving[i] = direct[i] + indirect[i];
    if (lf_runtime_apply_probes(rt, leaving, n_floats) != LF_STATUS_OK ||
        lf_runtime_probe_field(rt, field, probes * LF_PROBE_FLOATS) != LF_STATUS_OK ||
        /* texel 0's centre and normal: the first 3 floats of each layout query */
        lf_runtime_texel_positions(rt, leaving, n_floats) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    memcpy(pos, leaving, sizeof pos);
    if (lf_runtime_texel_normals(rt, leaving, n_floats) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    memcpy(nrm, leaving, sizeof nrm);
    for (i = 0; i < 3; i++) at[i] = pos[i] + 0.25f * nrm[i];
    if (lf_runtime_probe_irradiance(rt, at, nrm, e) != LF_STATUS_OK) {
        result = fail();
        goto out;
    }
    for (i = 0; i < probes * LF_PROBE_FLOATS; i++) field_sum += field[i];
    printf(" probe_checksum=%.6e probe_irradiance=%.6e", field_sum,
           (double)e[0] + (double)e[1] + (double)e[2]);
    result = pose ? object_part(rt, method, lights, n_lights, pose, n_floats) : 0;
out:
    free(leaving); free(field);
    return result;
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

/* The spans `light` reaches (malloc'd, `*n` of them), with its direct light on them written
 * to `out` (`n_floats` floats; other texels keep their values), or NULL on error. Asks for the
 * count first (LF_STATUS_BAD_LENGTH when there are any), then takes both. Checks that the
 * one-call path gives what lf_runtime_direct_in_spans gives on the same spans, bit for bit
 * (`*same` becomes 0 otherwise). */
static LfTexelSpan *light_direct_of(LfRuntime *rt, const LfPointLight *light, size_t *n,
                                    float *out, size_t n_floats, int *same) {
    LfTexelSpan *spans;
    float *check;
    int32_t status = lf_runtime_light_direct(rt, light, NULL, 0, n, out, n_floats);
    if (status != LF_STATUS_OK && status != LF_STATUS_BAD_LENGTH) return NULL;
    spans = malloc((*n + 1) * sizeof *spans);
    check = malloc(n_floats * sizeof *check);
    if (!spans || !check) {
        fprintf(stderr, "out of memory\n");
        free(spans);
        free(check);
        return NULL;
    }
    memcpy(check, out, n_floats * sizeof *check);
    if (lf_runtime_light_direct(rt, light, spans, *n, n, out, n_floats) != LF_STATUS_OK ||
        lf_runtime_direct_in_spans(rt, light, 1, spans, *n, check, n_floats) != LF_STATUS_OK) {
        free(spans);
        free(check);
        return NULL;
    }
    if (memcmp(check, out, n_floats * sizeof *check) != 0) *same = 0;
    free(check);
    return spans;
}

/* Moves light 0 by `dx` m along x: its direct light where it reaches before and after
 * (lf_runtime_light_direct) and the change into `change` (`n_floats` floats, zero elsewhere).
 * Returns the spans the change lies in (malloc'd, `*n_spans` of them; those where the light
 * reaches now are the last `*n_new`), or NULL on error. */
static LfTexelSpan *light_change(LfRuntime *rt, LfPointLight *lights, float dx, float *change,
                                 size_t n_floats, size_t *n_spans, size_t *n_new, int *same) {
    size_t i, k, n_old = 0;
    LfTexelSpan *old_spans = NULL, *new_spans = NULL, *both = NULL;
    float *light0 = calloc(n_floats, sizeof *light0);
    if (!light0) { fprintf(stderr, "out of memory\n"); return NULL; }
    /* Light 0's direct light alone, on its reach (zero elsewhere, as it is). */
    old_spans = light_direct_of(rt, lights, &n_old, light0, n_floats, same);
    if (!old_spans) goto out;
    for (i = 0; i < n_floats; i++) change[i] = -light0[i];
    lights[0].position[0] += dx;
    for (k = 0; k < n_old; k++)
        for (i = 3 * (size_t)old_spans[k].start; i < 3 * (size_t)old_spans[k].end; i++)
            light0[i] = 0.0f;
    new_spans = light_direct_of(rt, lights, n_new, light0, n_floats, same);
    if (!new_spans) goto out;
    for (i = 0; i < n_floats; i++) change[i] += light0[i];
    /* The change lies where the light reached before and after. */
    both = malloc((n_old + *n_new + 1) * sizeof *both);
    if (!both) { fprintf(stderr, "out of memory\n"); goto out; }
    memcpy(both, old_spans, n_old * sizeof *both);
    memcpy(both + n_old, new_spans, *n_new * sizeof *both);
    *n_spans = n_old + *n_new;
out: /* Every path frees what it made; `both` is NULL on error. */
    free(old_spans);
    free(new_spans);
    free(light0);
    return both;
}

/* Relative L2 between `a` and `b` (`n` floats). */
static double relative_l2(const float *a, const float *b, size_t n) {
    double diff = 0.0, norm = 0.0;
    size_t i;
    for (i = 0; i < n; i++) {
        diff += ((double)a[i] - b[i]) * ((double)a[i] - b[i]);
        norm += (double)b[i] * b[i];
    }
    return norm > 0.0 ? sqrt(diff / norm) : 0.0;
}

/* Moves light 0 by 0.25 m along x the way a game relights one moving light: where it reaches
 * before and after and its direct light there only (lf_runtime_light_direct), the change, and
 * lf_runtime_apply_delta_in_spans on `indirect` (which holds the indirect light of `direct`),
 * told the change lies in those spans. Then relights everything for the moved lights and
 * prints "moved_spans=S moved_error=R light_direct_same=B": the spans the moved light reaches,
 * the relative L2 between the two answers, and 1 when lf_runtime_light_direct gave what
 * lf_runtime_direct_in_spans gives on its spans.
 *
 * Then moves it back in LF_BOUNCES_FEEDBACK, as a game letting the later bounces arrive over
 * the next frames does: one lf_runtime_apply_delta_in_spans with the change, then calls with no
 * span until lf_runtime_feedback_due says nothing is due, and prints "feedback_calls=N
 * feedback_error=R feedback_lag=L feedback_left=F": the calls after the change, the relative
 * L2 against `at_load` (all bounces of the lights back where they were), and the runtime's
 * estimate of the light still to arrive (lf_runtime_last_remaining) after the change and once
 * settled. Returns 0, or 1 on error. */
static int move_light(LfRuntime *rt, int32_t method, LfPointLight *lights, long n_lights,
                      const float *direct, float *indirect, const float *at_load,
                      size_t n_floats) {
    size_t i, n_spans = 0, n_new = 0;
    LfTexelSpan *spans = NULL;
    float *change, *moved, *want;
    int same = 1, calls = 0, status = 1;
    float lag;
    if (n_lights < 1) {
        printf(" moved_spans=0 moved_error=0 light_direct_same=1 feedback_calls=0"
               " feedback_error=0 feedback_lag=0 feedback_left=0");
        return 0;
    }
    change = malloc(n_floats * sizeof *change);
    moved = malloc(n_floats * sizeof *moved);
    want = malloc(n_floats * sizeof *want);
    if (!change || !moved || !want) { fprintf(stderr, "out of memory\n"); goto out; }
    spans = light_change(rt, lights, 0.25f, change, n_floats, &n_spans, &n_new, &same);
    if (!spans) { fail(); goto out; }
    if (lf_runtime_apply_delta_in_spans(rt, method, change, n_floats, spans, n_spans, indirect,
                                        n_floats) != LF_STATUS_OK) { fail(); goto out; }
    free(spans);
    spans = NULL;
    /* Everything again, for the moved lights. */
    for (i = 0; i < n_floats; i++) moved[i] = direct[i] + change[i];
    if (lf_runtime_apply(rt, method, moved, n_floats, want, n_floats) != LF_STATUS_OK) {
        fail();
        goto out;
    }
    printf(" moved_spans=%zu moved_error=%.3e light_direct_same=%d", n_new,
           relative_l2(indirect, want, n_floats), same);
    /* Back, by feedback: the answer of the moved lights is where it starts. */
    if (lf_runtime_set_bounces(rt, LF_BOUNCES_FEEDBACK, 0.0f) != LF_STATUS_OK) {
        fail();
        goto out;
    }
    spans = light_change(rt, lights, -0.25f, change, n_floats, &n_spans, &n_new, &same);
    if (!spans) { fail(); goto out; }
    if (lf_runtime_apply_delta_in_spans(rt, method, change, n_floats, spans, n_spans, want,
                                        n_floats) != LF_STATUS_OK) { fail(); goto out; }
    lag = lf_runtime_last_remaining(rt);
    for (i = 0; i < n_floats; i++) change[i] = 0.0f;
    while (lf_runtime_feedback_due(rt) > 0 && calls < 1000) {
        if (lf_runtime_apply_delta_in_spans(rt, method, change, n_floats, NULL, 0, want,
                                            n_floats) != LF_STATUS_OK) { fail(); goto out; }
        calls++;
    }
    printf(" feedback_calls=%d feedback_error=%.3e feedback_lag=%.3e feedback_left=%.3e", calls,
           relative_l2(want, at_load, n_floats), lag, lf_runtime_last_remaining(rt));
    if (lf_runtime_set_bounces(rt, LF_BOUNCES_CONVERGED, 0.0f) != LF_STATUS_OK) {
        fail();
        goto out;
    }
    status = 0;
out: /* Every path frees what it made. */
    free(spans);
    free(change);
    free(moved);
    free(want);
    return status;
}

int main(int argc, char **argv) {
    size_t len = 0, n_floats, i;
    unsigned char *bytes;
    LfPointLight *lights = NULL;
    long n_lights;
    LfRuntime *rt;
    float *direct, *indirect, *at_load;
    int32_t method, status;
    double checksum = 0.0, direct_checksum = 0.0, max = 0.0;
    char id[128];
    LfPose pose;

    if (argc != 3 && argc != 4) {
        fprintf(stderr, "usage: %s BUNDLE.lfb LIGHTS.txt [id,x,y,z,qx,qy,qz,qw]\n", argv[0]);
        return 2;
    }
    bytes = read_file(argv[1], &len);
    if (!bytes) { perror(argv[1]); return 1; }
    n_lights = read_lights(argv[2], &lights);
    if (n_lights < 0) { perror(argv[2]); return 1; }

    rt = lf_runtime_new(bytes, len);
    free(bytes); /* the runtime keeps its own copy */
    if (!rt) return fail();
    /* At load: what relighting by the change needs, so the first moved light is not slow. */
    if (lf_runtime_prepare_delta(rt) != LF_STATUS_OK) return fail();
    if (argc == 4) {
        /* The dynamic object, placed before direct light so that it carries its shadow. */
        if (sscanf(argv[3], "%127[^,],%f,%f,%f,%f,%f,%f,%f", id, &pose.translation[0],
                   &pose.translation[1], &pose.translation[2], &pose.rotation[0],
                   &pose.rotation[1], &pose.rotation[2], &pose.rotation[3]) != 8) {
            fprintf(stderr, "%s: not id,x,y,z,qx,qy,qz,qw\n", argv[3]);
            return 2;
        }
        pose.id = id;
        if (lf_runtime_set_poses(rt, &pose, 1) != LF_STATUS_OK) return fail();
    }

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
    printf("texels=%zu method=%s applications=%u checksum=%.6e max=%.6e direct_checksum=%.6e ",
           n_floats / 3, method == LF_METHOD_DRT ? "drt" : "mrt",
           (unsigned)lf_runtime_last_bounces(rt), checksum, max, direct_checksum);
    if (check_surfaces(rt) || engine_path(rt, method, lights, n_lights) ||
        probe_part(rt, method, lights, n_lights, argc == 4 ? &pose : NULL, direct, indirect,
                   n_floats))
        return 1;
    at_load = malloc(n_floats * sizeof *at_load);
    if (!at_load) { fprintf(stderr, "out of memory\n"); return 1; }
    memcpy(at_load, indirect, n_floats * sizeof *at_load);
    if (move_light(rt, method, lights, n_lights, direct, indirect, at_load, n_floats)) return 1;
    printf("\n");

    lf_runtime_free(rt);
    free(direct);
    free(indirect);
    free(at_load);
    free(lights);
    return 0;
}

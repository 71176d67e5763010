/*
 * Synthetic IMU of the Linux reference node (see sensor.h).
 */
#include "sensor.h"

#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "imu_cal.h"

#define DEG (3.14159265358979323846 / 180.0)
#define ALREADY_THERE_SIGMAS 5.0
#define DEFAULT_SECONDS 30.0
#define DEFAULT_TOLERANCE_DEG 0.1
#define MAX_PLAN_BYTES 65536

void sensor_defaults(sensor_t* s) {
    memset(s, 0, sizeof *s);
    s->g = 9.80665;
    s->accel_lsb = (float)(9.80665 / 2048.0);
    s->gyro_lsb = (float)(3.14159265358979323846 / (180.0 * 16.4));
    s->rng = 0x9E3779B97F4A7C15ull;
    s->transient_s = 1.0;
}

/* --- a JSON reader for {"positions": [{"alpha_deg": ..., ...}, ...]} ----------------------- */

typedef struct {
    const char* p;
    char* err;
    size_t err_len;
} reader_t;

static int fail(reader_t* r, const char* what) {
    snprintf(r->err, r->err_len, "%s near byte '%.12s'", what, r->p);
    return -1;
}

static void skip_space(reader_t* r) {
    while (isspace((unsigned char)*r->p)) {
        r->p++;
    }
}

static int expect(reader_t* r, char c) {
    skip_space(r);
    if (*r->p != c) {
        char what[32];
        snprintf(what, sizeof what, "expected '%c'", c);
        return fail(r, what);
    }
    r->p++;
    return 0;
}

static int read_key(reader_t* r, char* key, size_t len) {
    size_t n = 0;
    if (expect(r, '"') < 0) {
        return -1;
    }
    while (*r->p && *r->p != '"') {
        if (*r->p == '\\' || n + 1 >= len) {
            return fail(r, "unsupported key");
        }
        key[n++] = *r->p++;
    }
    key[n] = 0;
    return expect(r, '"') < 0 ? -1 : expect(r, ':');
}

static int read_number(reader_t* r, double* out) {
    char* end;
    skip_space(r);
    errno = 0;
    *out = strtod(r->p, &end);
    if (end == r->p || errno != 0 || !isfinite(*out)) {
        return fail(r, "expected a finite number");
    }
    r->p = end;
    return 0;
}

static int read_position(reader_t* r, sensor_pose_t* pose) {
    double deg[3] = {0, 0, 0}, seconds = DEFAULT_SECONDS, tol = DEFAULT_TOLERANCE_DEG, psi_tol = -1.0;
    int have_alpha = 0, have_beta = 0, i;
    if (expect(r, '{') < 0) {
        return -1;
    }
    skip_space(r);
    while (*r->p != '}') {
        char key[32];
        double value;
        if (read_key(r, key, sizeof key) < 0 || read_number(r, &value) < 0) {
            return -1;
        }
        if (strcmp(key, "alpha_deg") == 0) {
            deg[0] = value;
            have_alpha = 1;
        } else if (strcmp(key, "beta_deg") == 0) {
            deg[1] = value;
            have_beta = 1;
        } else if (strcmp(key, "psi_deg") == 0) {
            deg[2] = value;
        } else if (strcmp(key, "seconds") == 0) {
            seconds = value;
        } else if (strcmp(key, "tolerance_deg") == 0) {
            tol = value;
        } else if (strcmp(key, "psi_tolerance_deg") == 0) {
            psi_tol = value;
        } else {
            return fail(r, "unknown key");
        }
        skip_space(r);
        if (*r->p == ',') {
            r->p++;
            skip_space(r);
        }
    }
    r->p++;
    if (!have_alpha || !have_beta || !(seconds > 0.0)) {
        return fail(r, "a position needs alpha_deg, beta_deg and positive seconds");
    }
    for (i = 0; i < 3; i++) {
        pose->angles[i] = deg[i] * DEG;
    }
    pose->seconds = seconds;
    pose->tolerance[0] = pose->tolerance[1] = tol * DEG;
    pose->tolerance[2] = (psi_tol >= 0.0 ? psi_tol : tol) * DEG;
    return 0;
}

static int read_positions(reader_t* r, sensor_t* s) {
    char key[32];
    if (expect(r, '{') < 0 || read_key(r, key, sizeof key) < 0) {
        return -1;
    }
    if (strcmp(key, "positions") != 0) {
        return fail(r, "the only key is \"positions\"");
    }
    if (expect(r, '[') < 0) {
        return -1;
    }
    s->n_poses = 0;
    skip_space(r);
    while (*r->p != ']') {
        if (s->n_poses == SENSOR_MAX_POSES) {
            return fail(r, "too many positions");
        }
        if (read_position(r, &s->poses[s->n_poses++]) < 0) {
            return -1;
        }
        skip_space(r);
        if (*r->p == ',') {
            r->p++;
            skip_space(r);
        }
    }
    r->p++;
    if (expect(r, '}') < 0) {
        return -1;
    }
    return s->n_poses > 0 ? 0 : fail(r, "no positions");
}

int sensor_read_plan(sensor_t* s, const char* path, char* err, size_t err_len) {
    static char text[MAX_PLAN_BYTES + 1];
    reader_t r = {text, err, err_len};
    size_t n;
    FILE* f = fopen(path, "r");
    if (f == NULL) {
        snprintf(err, err_len, "cannot open %s: %s", path, strerror(errno));
        return -1;
    }
    n = fread(text, 1, MAX_PLAN_BYTES, f);
    fclose(f);
    text[n] = 0;
    if (read_positions(&r, s) < 0) {
        return -1;
    }
    sensor_schedule(s);
    return 0;
}

/* --- the schedule ---------------------------------------------------------------------- */

static void add_segment(sensor_t* s, double start, double duration, const double from[3], const double to[3],
                        int index) {
    sensor_segment_t* seg = &s->segments[s->n_segments++];
    seg->start_s = start;
    seg->duration_s = duration;
    memcpy(seg->from, from, sizeof seg->from);
    memcpy(seg->to, to, sizeof seg->to);
    seg->index = index;
}

void sensor_schedule(sensor_t* s) {
    double current[3] = {0, 0, 0}, t = 0.0;
    int i, k;
    s->n_segments = 0;
    for (i = 0; i < s->n_poses; i++) {
        const sensor_pose_t* pose = &s->poses[i];
        int there = i == 0, same = 1;
        for (k = 0; k < 3; k++) {
            there = there && fabs(pose->angles[k] - current[k]) <= ALREADY_THERE_SIGMAS * pose->tolerance[k];
            same = same && pose->angles[k] == current[k];
        }
        if (!there && s->transient_s > 0.0 && !same) {
            add_segment(s, t, s->transient_s, current, pose->angles, -1);
            t += s->transient_s;
        }
        add_segment(s, t, pose->seconds, pose->angles, pose->angles, i);
        t += pose->seconds;
        memcpy(current, pose->angles, sizeof current);
    }
    add_segment(s, t, -1.0, current, current, -1);
}

void sensor_pose_at(const sensor_t* s, double t, double angles[3], int* index, int* moving) {
    const sensor_segment_t* seg = NULL;
    int i, k;
    *index = -1;
    *moving = 0;
    if (s->n_segments == 0 || t + 1e-9 < s->segments[0].start_s) {
        for (k = 0; k < 3; k++) {
            angles[k] = s->n_segments ? s->segments[0].from[k] : 0.0;
        }
        return;
    }
    for (i = 0; i < s->n_segments; i++) {
        if (s->segments[i].start_s <= t + 1e-9) {
            seg = &s->segments[i]; /* a sample within 1 ns of a boundary belongs to the later one */
        }
    }
    *index = seg->index;
    if (seg->index < 0 && seg->duration_s > 0.0) {
        double tau = (t - seg->start_s) / seg->duration_s, sj;
        tau = tau < 0.0 ? 0.0 : (tau > 1.0 ? 1.0 : tau);
        sj = tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau); /* minimum jerk */
        for (k = 0; k < 3; k++) {
            angles[k] = seg->from[k] + (seg->to[k] - seg->from[k]) * sj;
        }
        *moving = 1;
        return;
    }
    memcpy(angles, seg->to, 3 * sizeof(double));
}

/* --- physics --------------------------------------------------------------------------- */

/* v <- A1(a) v (rotation of the frame about z), A2 about x, Ay about y (docs/design.md §2). */
static void rot_z(double a, double v[3]) {
    double c = cos(a), s = sin(a), x = v[0], y = v[1];
    v[0] = c * x + s * y;
    v[1] = -s * x + c * y;
}

static void rot_x(double a, double v[3]) {
    double c = cos(a), s = sin(a), y = v[1], z = v[2];
    v[1] = c * y + s * z;
    v[2] = -s * y + c * z;
}

static void rot_y(double a, double v[3]) {
    double c = cos(a), s = sin(a), x = v[0], z = v[2];
    v[0] = c * x - s * z;
    v[2] = s * x + c * z;
}

void sensor_force(const sensor_t* s, const double angles[3], double f[3]) {
    f[0] = 0.0;
    f[1] = -s->g;
    f[2] = 0.0;
    rot_z(s->base_tilt[0], f);
    rot_x(s->base_tilt[1], f);
    rot_z(angles[0], f);
    rot_x(angles[1], f);
    rot_y(angles[2], f);
}

static double uniform(sensor_t* s) {
    s->rng ^= s->rng >> 12;
    s->rng ^= s->rng << 25;
    s->rng ^= s->rng >> 27;
    return ((double)((s->rng * 0x2545F4914F6CDD1Dull) >> 11) + 0.5) / 9007199254740992.0;
}

static double gaussian(sensor_t* s) {
    return sqrt(-2.0 * log(uniform(s))) * cos(2.0 * 3.14159265358979323846 * uniform(s));
}

static int16_t saturate(double counts, uint8_t* flags) {
    double r = floor(counts + 0.5);
    if (r > 32767.0 || r < -32768.0) {
        *flags |= IMU_CAL_STATUS_SATURATED;
        return r > 0 ? INT16_MAX : INT16_MIN;
    }
    return (int16_t)r;
}

void sensor_sample(sensor_t* s, double t, int16_t accel[3], int16_t gyro[3], uint8_t* flags) {
    double angles[3], f[3];
    int index, moving, i;
    sensor_pose_at(s, t, angles, &index, &moving);
    sensor_force(s, angles, f);
    *flags = moving ? IMU_CAL_STATUS_MOVING : 0u;
    for (i = 0; i < 3; i++) {
        double u = s->accel_bias[i] + (1.0 + s->accel_scale[i]) / (double)s->accel_lsb * f[i];
        double v = s->gyro_bias[i];
        if (s->noise_counts > 0.0) {
            u += s->noise_counts * gaussian(s);
            v += s->noise_counts * gaussian(s);
        }
        accel[i] = saturate(u, flags);
        gyro[i] = saturate(v, flags);
    }
}

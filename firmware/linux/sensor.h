/*
 * A synthetic IMU for the Linux reference node: gravity at the pose of a pose schedule
 * (docs/design.md §5, the format `canimucal sim --poses` follows) seen through a sensor with
 * bias, scale error and white noise. Accelerometer U = b + K f + noise with
 * f = C(alpha, beta, psi) [0, -g, 0] (docs/design.md §2: C = Ay(psi) A2(beta) A1(alpha)
 * A2(beta0) A1(alpha0)) and K = diag(1 + s) / LSB; gyro V = B + noise (no rotation rates:
 * the HIL tests solve the accelerometer). Schedule time is sample counts over the output
 * data rate from the first NMT start, as the simulated node and `record --follow-schedule`
 * count it; moves between positions follow the same minimum-jerk profile.
 */
#ifndef IMU_NODE_SENSOR_H
#define IMU_NODE_SENSOR_H

#include <stddef.h>
#include <stdint.h>

#define SENSOR_MAX_POSES 64
#define SENSOR_MAX_SEGMENTS (2 * SENSOR_MAX_POSES + 2)

typedef struct {
    double angles[3];  /* alpha, beta, psi (rad) */
    double seconds;
    double tolerance[3]; /* 1 sigma per angle (rad) */
} sensor_pose_t;

typedef struct {
    double start_s;
    double duration_s; /* <= 0: holds for ever */
    double from[3];
    double to[3];
    int index; /* plan position, -1 for a move or the end */
} sensor_segment_t;

typedef struct {
    /* the unit */
    double g;
    float accel_lsb, gyro_lsb;
    double accel_bias[3];  /* counts */
    double accel_scale[3]; /* relative scale error s (K = diag(1 + s) / LSB) */
    double gyro_bias[3];   /* counts */
    double noise_counts;   /* white noise 1 sigma, accel and gyro */
    double base_tilt[2];   /* alpha0, beta0 (rad) */
    uint64_t rng;          /* xorshift64* state */
    /* the schedule */
    sensor_pose_t poses[SENSOR_MAX_POSES];
    int n_poses;
    double transient_s;
    sensor_segment_t segments[SENSOR_MAX_SEGMENTS];
    int n_segments;
} sensor_t;

/* Defaults: default LSBs, g = 9.80665, no errors, no noise, level and still. */
void sensor_defaults(sensor_t* s);

/* Read a pose schedule (JSON plan, docs/design.md §3/§5) into s->poses. 0, or -1 with a
 * one-line reason in err. */
int sensor_read_plan(sensor_t* s, const char* path, char* err, size_t err_len);

/* Lay out the schedule from time 0 (as PoseTrajectory.follow(0, plan, transient_s)). */
void sensor_schedule(sensor_t* s);

/* Pose at schedule time t (s): angles (rad), plan index (-1 none), moving flag. */
void sensor_pose_at(const sensor_t* s, double t, double angles[3], int* index, int* moving);

/* Specific force in body axes (m/s^2) at a pose, base tilt included. */
void sensor_force(const sensor_t* s, const double angles[3], double f[3]);

/* One sample at schedule time t: raw counts (INT16, saturating) and status flags. */
void sensor_sample(sensor_t* s, double t, int16_t accel[3], int16_t gyro[3], uint8_t* flags);

#endif /* IMU_NODE_SENSOR_H */

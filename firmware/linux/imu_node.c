/*
 * The reference IMU node on Linux: CANopenLinux's CO_main_basic.c with this application
 * (CO_USE_APPLICATION), the imu_cal module and a synthetic sensor (sensor.h).
 *
 *   imu_node vcan0 -i 0x10 -s /path/to/storage/
 *
 * Options are CANopenLinux's (-i node-id, -s storage file prefix). The synthetic unit and the
 * test knobs come from the environment (the HIL tests set them):
 *   IMU_NODE_SERIAL        0x1018:04 (default 0)
 *   IMU_NODE_POSES         pose schedule JSON (docs/design.md §5), followed from the first
 *                          NMT start; without it the unit lies level
 *   IMU_NODE_TRANSIENT_S   move time between poses (default 1 s, as `canimucal sim`)
 *   IMU_NODE_ACCEL_BIAS    "bx,by,bz" counts;  IMU_NODE_ACCEL_SCALE "sx,sy,sz" relative
 *   IMU_NODE_GYRO_BIAS     "Bx,By,Bz" counts;  IMU_NODE_NOISE counts (1 sigma)
 *   IMU_NODE_BASE_TILT_DEG "alpha0,beta0";     IMU_NODE_G m/s^2;  IMU_NODE_SEED
 *   IMU_NODE_NMT_CONTROL   "stock": CANopenLinux's default NMT control (docs/firmware.md)
 *   IMU_NODE_CAL_STORE_SUB 0x1010 sub-index of the calibration (default 4; 0x2011 says it)
 *   IMU_NODE_EVENT_TIMER_MS  TPDO1/2 event timers at start (default 0: data-ready only)
 * It prints one line "imu_node: ready ..." on stdout after every communication reset.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "CO_application.h"
#include "OD.h"
#include "imu_cal_co.h"
#include "sensor.h"

#define MAX_CATCH_UP_NS 100000000LL /* a stall longer than 0.1 s is not caught up */

static imu_cal_co_t imu;
static sensor_t sensor;
static volatile uint16_t odr_hz = 200;
static int64_t next_due_ns;
static uint64_t samples;           /* produced since start */
static int64_t schedule_start = -1; /* sample number of the first NMT start */

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static const char* env(const char* name) {
    const char* value = getenv(name);
    return (value != NULL && *value) ? value : NULL;
}

static int env_vector(const char* name, double* out, int n) {
    const char* text = env(name);
    int i;
    for (i = 0; text != NULL && i < n; i++) {
        char* end;
        out[i] = strtod(text, &end);
        if (end == text || (i < n - 1 && *end != ',')) {
            fprintf(stderr, "imu_node: %s must be %d numbers separated by commas\n", name, n);
            return -1;
        }
        text = end + 1;
    }
    return 0;
}

uint16_t imu_node_nmt_control(void) {
    const char* mode = env("IMU_NODE_NMT_CONTROL");
    if (mode != NULL && strcmp(mode, "stock") == 0) {
        return CO_NMT_STARTUP_TO_OPERATIONAL | CO_NMT_ERR_ON_ERR_REG | CO_ERR_REG_GENERIC_ERR
               | CO_ERR_REG_COMMUNICATION;
    }
    return CO_NMT_ERR_ON_ERR_REG | CO_ERR_REG_COMMUNICATION;
}

uint8_t imu_node_cal_store_sub(void) {
    const char* sub = env("IMU_NODE_CAL_STORE_SUB");
    long value = (sub != NULL) ? strtol(sub, NULL, 0) : 4;
    return (value >= 2 && value <= OD_CNT_ARR_1010) ? (uint8_t)value : 4;
}

static void odr_changed(void* arg, uint16_t hz) {
    (void)arg;
    odr_hz = hz; /* the synthetic sensor's data-ready rate follows 0x2010:03 */
}

static int configure_sensor(void) {
    double tilt[2] = {0, 0};
    char err[160];
    sensor_defaults(&sensor);
    if (env_vector("IMU_NODE_ACCEL_BIAS", sensor.accel_bias, 3) < 0
        || env_vector("IMU_NODE_ACCEL_SCALE", sensor.accel_scale, 3) < 0
        || env_vector("IMU_NODE_GYRO_BIAS", sensor.gyro_bias, 3) < 0
        || env_vector("IMU_NODE_NOISE", &sensor.noise_counts, 1) < 0
        || env_vector("IMU_NODE_G", &sensor.g, 1) < 0 || env_vector("IMU_NODE_TRANSIENT_S", &sensor.transient_s, 1) < 0
        || env_vector("IMU_NODE_BASE_TILT_DEG", tilt, 2) < 0) {
        return -1;
    }
    sensor.base_tilt[0] = tilt[0] * 3.14159265358979323846 / 180.0;
    sensor.base_tilt[1] = tilt[1] * 3.14159265358979323846 / 180.0;
    if (env("IMU_NODE_SEED") != NULL) {
        sensor.rng ^= strtoull(env("IMU_NODE_SEED"), NULL, 0) * 0x9E3779B97F4A7C15ull;
    }
    if (env("IMU_NODE_POSES") != NULL && sensor_read_plan(&sensor, env("IMU_NODE_POSES"), err, sizeof err) < 0) {
        fprintf(stderr, "imu_node: %s: %s\n", env("IMU_NODE_POSES"), err);
        return -1;
    }
    return 0;
}

static int set_u16(uint16_t index, uint8_t sub, uint16_t value) {
    uint16_t* p = OD_getPtr(OD_find(OD, index), sub, sizeof(uint16_t), NULL);
    if (p == NULL) {
        return -1;
    }
    *p = value;
    return 0;
}

CO_ReturnError_t app_programStart(uint16_t* bitRate, uint8_t* nodeId, uint32_t* errInfo) {
    uint32_t* serial = OD_getPtr(OD_ENTRY_H1018, 4, sizeof(uint32_t), NULL);
    uint8_t* store_sub = OD_getPtr(OD_ENTRY_H2011, 0, sizeof(uint8_t), NULL);
    const char* timer = env("IMU_NODE_EVENT_TIMER_MS");
    (void)bitRate;
    (void)nodeId;
    if (configure_sensor() < 0 || serial == NULL || store_sub == NULL) {
        *errInfo = 0x1018;
        return CO_ERROR_ILLEGAL_ARGUMENT;
    }
    if (env("IMU_NODE_SERIAL") != NULL) {
        *serial = (uint32_t)strtoul(env("IMU_NODE_SERIAL"), NULL, 0);
    }
    *store_sub = imu_node_cal_store_sub(); /* the device says where its calibration is stored */
    if (timer != NULL) { /* a misconfiguration the HIL tests reproduce: a second send trigger */
        uint16_t ms = (uint16_t)strtoul(timer, NULL, 0);
        if (set_u16(0x1800, 5, ms) < 0 || set_u16(0x1801, 5, ms) < 0) {
            *errInfo = 0x1800;
            return CO_ERROR_OD_PARAMETERS;
        }
    }
    return CO_ERROR_NO;
}

void app_communicationReset(CO_t* co) {
    uint32_t errInfo = 0;
    CO_ReturnError_t err = imu_cal_co_init(&imu, co, OD, &errInfo);
    if (err != CO_ERROR_NO) {
        fprintf(stderr, "imu_node: imu_cal_co_init failed (%d) at 0x%06X\n", (int)err, (unsigned)errInfo);
        exit(EXIT_FAILURE);
    }
    imu.odr_changed = odr_changed;
    odr_hz = *imu.odr_hz;
    next_due_ns = now_ns();
    printf("imu_node: ready: serial %lu, calibration valid %u active %u, stored on 0x1010:%02X\n",
           (unsigned long)OD_PERSIST_COMM.x1018_identity.serialNumber, (unsigned)imu_cal_valid(&imu.cal),
           (unsigned)imu.cal.active, (unsigned)imu_node_cal_store_sub());
    fflush(stdout);
}

void app_programEnd(void) {}

void app_programAsync(CO_t* co, uint32_t timer1usDiff) {
    (void)co;
    (void)timer1usDiff;
}

/* Realtime thread, every millisecond: at most one sample per call (its TPDOs go out in the
 * next call's PDO processing, before the following sample can overwrite them). */
void app_programRt(CO_t* co, uint32_t timer1usDiff) {
    int16_t accel[3], gyro[3];
    uint8_t flags;
    int64_t now = now_ns(), period = 1000000000LL / (odr_hz ? odr_hz : 200);
    double t = 0.0;
    (void)timer1usDiff;
    /* Nothing while a communication reset runs (as CO_epoll_processRT): the main thread is
     * then initialising imu and the PDOs, first after this thread has started. Sampling into
     * a half-initialised imu crashed the node once in CI's VM, right at its ready line. */
    if (!co->CANmodule->CANnormal) {
        return;
    }
    if (now < next_due_ns) {
        return;
    }
    next_due_ns = (now - next_due_ns > MAX_CATCH_UP_NS) ? now + period : next_due_ns + period;
    if (schedule_start < 0 && co->NMT->operatingState == CO_NMT_OPERATIONAL) {
        schedule_start = (int64_t)samples; /* the schedule starts at the first NMT start */
    }
    if (schedule_start >= 0) {
        t = (double)((int64_t)samples - schedule_start) / (double)(odr_hz ? odr_hz : 200);
    }
    sensor_sample(&sensor, t, accel, gyro, &flags);
    samples++;
    imu_cal_co_sample(&imu, accel, gyro, 2500, flags, NULL, NULL);
}

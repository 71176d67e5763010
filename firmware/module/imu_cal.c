/*
 * imu_cal: calibration block, ranges, CRC, gate, correction and counter (see imu_cal.h).
 *
 * Ranges are compared in double, as the client computes them (canimucal/device/od.py):
 * the same value is accepted or refused on both sides, bit for bit (the differential test
 * tests/firmware/test_core_differential.py feeds both the same inputs). The correction
 * runs in float, as an MCU with a single-precision FPU does.
 */
#include "imu_cal.h"

#include <math.h>
#include <string.h>

#define BIAS_LIMIT_COUNTS  65536.0
#define DIAGONAL_TOLERANCE 0.5 /* |diagonal| within +-50 % of the nominal |LSB| */
#define OFF_DIAGONAL_RATIO 0.2 /* |off-diagonal| <= 0.2 |row diagonal| */
#define G_LIMIT            1000.0
#define TILT_LIMIT_RAD     0.2
#define CRC32_POLY_REFLECTED 0xEDB88320u

#define REAL(index, sub, range) {(index), (sub), IMU_CAL_REAL32, (range)}
#define VEC3(index, range)      REAL(index, 1u, range), REAL(index, 2u, range), REAL(index, 3u, range)
#define MAT9(index, range)                                                                       \
    VEC3(index, range), REAL(index, 4u, range), REAL(index, 5u, range), REAL(index, 6u, range), \
        REAL(index, 7u, range), REAL(index, 8u, range), REAL(index, 9u, range)

const imu_cal_object_t imu_cal_objects[IMU_CAL_N_OBJECTS] = {
    VEC3(IMU_CAL_ACCEL_BIAS, IMU_CAL_RANGE_BIAS),
    MAT9(IMU_CAL_ACCEL_CORRECTION, IMU_CAL_RANGE_ACCEL_M),
    VEC3(IMU_CAL_GYRO_BIAS, IMU_CAL_RANGE_BIAS),
    MAT9(IMU_CAL_GYRO_CORRECTION, IMU_CAL_RANGE_GYRO_N),
    MAT9(IMU_CAL_GYRO_G, IMU_CAL_RANGE_G),
    REAL(IMU_CAL_BASE_TILT, 1u, IMU_CAL_RANGE_TILT),
    REAL(IMU_CAL_BASE_TILT, 2u, IMU_CAL_RANGE_TILT),
    {IMU_CAL_INFO, 1u, IMU_CAL_U32, IMU_CAL_RANGE_ANY},
    {IMU_CAL_INFO, 2u, IMU_CAL_U8, IMU_CAL_RANGE_PLAN},
    REAL(IMU_CAL_INFO, 3u, IMU_CAL_RANGE_ANY),
    REAL(IMU_CAL_INFO, 4u, IMU_CAL_RANGE_NONNEG),
    VEC3(IMU_CAL_MOUNTING_TRIM, IMU_CAL_RANGE_TILT),
    {IMU_CAL_INFO, IMU_CAL_VALID_SUB, IMU_CAL_U8, IMU_CAL_RANGE_FLAG},
    {IMU_CAL_INFO, IMU_CAL_CRC_SUB, IMU_CAL_U32, IMU_CAL_RANGE_ANY},
};

/* Object numbers used by the correction and the gate (positions in imu_cal_objects). */
enum {
    OBJ_ACCEL_BIAS = 0,
    OBJ_ACCEL_M = 3,
    OBJ_GYRO_BIAS = 12,
    OBJ_GYRO_N = 15,
    OBJ_GYRO_G = 24,
    OBJ_TRIM = 39,
    OBJ_VALID = 42,
    OBJ_CRC = 43
};

static size_t type_size(uint8_t type) {
    return (type == IMU_CAL_U8) ? 1u : 4u;
}

static uint32_t get_le32(const uint8_t* data) {
    return (uint32_t)data[0] | ((uint32_t)data[1] << 8) | ((uint32_t)data[2] << 16) | ((uint32_t)data[3] << 24);
}

static void put_le32(uint8_t* out, uint32_t v) {
    out[0] = (uint8_t)v;
    out[1] = (uint8_t)(v >> 8);
    out[2] = (uint8_t)(v >> 16);
    out[3] = (uint8_t)(v >> 24);
}

static float bits_to_float(uint32_t bits) {
    float f;
    memcpy(&f, &bits, sizeof f);
    return f;
}

static uint32_t float_to_bits(float f) {
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    return bits;
}

static float real_at(const imu_cal_t* cal, int obj) {
    float f;
    memcpy(&f, cal->value[obj], sizeof f);
    return f;
}

void imu_cal_bind_block(imu_cal_t* cal, imu_cal_block_t* block) {
    unsigned i;
    for (i = 0; i < 3u; i++) {
        cal->value[OBJ_ACCEL_BIAS + (int)i] = &block->accel_bias[i];
        cal->value[OBJ_GYRO_BIAS + (int)i] = &block->gyro_bias[i];
    }
    for (i = 0; i < 9u; i++) {
        cal->value[OBJ_ACCEL_M + (int)i] = &block->accel_m[i];
        cal->value[OBJ_GYRO_N + (int)i] = &block->gyro_n[i];
        cal->value[OBJ_GYRO_G + (int)i] = &block->gyro_g[i];
    }
    cal->value[33] = &block->base_tilt[0];
    cal->value[34] = &block->base_tilt[1];
    cal->value[35] = &block->time_unix_s;
    cal->value[36] = &block->plan_code;
    cal->value[37] = &block->temp_c;
    cal->value[38] = &block->rms_ms2;
    for (i = 0; i < 3u; i++) {
        cal->value[OBJ_TRIM + (int)i] = &block->mounting_trim[i];
    }
    cal->value[OBJ_VALID] = &block->valid;
    cal->value[OBJ_CRC] = &block->crc;
}

int imu_cal_find(uint16_t index, uint8_t sub) {
    int i;
    for (i = 0; i < (int)IMU_CAL_N_OBJECTS; i++) {
        if (imu_cal_objects[i].index == index && imu_cal_objects[i].sub == sub) {
            return i;
        }
    }
    return -1;
}

/* A matrix entry: the diagonal against the nominal LSB, an off-diagonal against its row's
 * diagonal as the device holds it now (docs/design.md §4). */
static int matrix_ok(const imu_cal_t* cal, int obj, double value) {
    const imu_cal_object_t* o = &imu_cal_objects[obj];
    if (o->sub == 1u || o->sub == 5u || o->sub == 9u) {
        double lsb = fabs((double)((o->range == IMU_CAL_RANGE_ACCEL_M) ? cal->accel_lsb : cal->gyro_lsb));
        double low = (1.0 - DIAGONAL_TOLERANCE) * lsb;
        double high = (1.0 + DIAGONAL_TOLERANCE) * lsb;
        return low <= fabs(value) && fabs(value) <= high;
    }
    {
        int row_diagonal = obj - (int)o->sub + 1 + 4 * (((int)o->sub - 1) / 3);
        double limit = OFF_DIAGONAL_RATIO * fabs((double)real_at(cal, row_diagonal));
        return !(fabs(value) > limit);
    }
}

static int real_ok(const imu_cal_t* cal, int obj, float f) {
    double v = (double)f;
    if (!isfinite(f)) {
        return 0;
    }
    switch ((imu_cal_range_t)imu_cal_objects[obj].range) {
        case IMU_CAL_RANGE_BIAS: return !(fabs(v) > BIAS_LIMIT_COUNTS);
        case IMU_CAL_RANGE_ACCEL_M:
        case IMU_CAL_RANGE_GYRO_N: return matrix_ok(cal, obj, v);
        case IMU_CAL_RANGE_G: return !(fabs(v) > G_LIMIT);
        case IMU_CAL_RANGE_TILT: return !(fabs(v) > TILT_LIMIT_RAD);
        case IMU_CAL_RANGE_NONNEG: return !(v < 0.0);
        case IMU_CAL_RANGE_ANY:
        case IMU_CAL_RANGE_PLAN:
        case IMU_CAL_RANGE_FLAG:
        default: return 1;
    }
}

static int integer_ok(int obj, uint32_t v) {
    switch ((imu_cal_range_t)imu_cal_objects[obj].range) {
        case IMU_CAL_RANGE_PLAN: return v <= IMU_CAL_PLAN_MAX;
        case IMU_CAL_RANGE_FLAG: return v <= 1u;
        default: return 1;
    }
}

static imu_cal_result_t check_obj(const imu_cal_t* cal, int obj, const uint8_t* data, size_t len) {
    uint8_t type = imu_cal_objects[obj].type;
    if (len != type_size(type)) {
        return IMU_CAL_E_LENGTH;
    }
    if (type == IMU_CAL_REAL32) {
        return real_ok(cal, obj, bits_to_float(get_le32(data))) ? IMU_CAL_OK : IMU_CAL_E_RANGE;
    }
    return integer_ok(obj, (type == IMU_CAL_U8) ? data[0] : get_le32(data)) ? IMU_CAL_OK : IMU_CAL_E_RANGE;
}

imu_cal_result_t imu_cal_check(const imu_cal_t* cal, uint16_t index, uint8_t sub, const uint8_t* data,
                               size_t len) {
    int obj = imu_cal_find(index, sub);
    if (obj < 0) {
        return IMU_CAL_E_NO_OBJECT;
    }
    return check_obj(cal, obj, data, len);
}

static void store(imu_cal_t* cal, int obj, const uint8_t* data) {
    uint8_t type = imu_cal_objects[obj].type;
    if (type == IMU_CAL_U8) {
        *(uint8_t*)cal->value[obj] = data[0];
    } else if (type == IMU_CAL_U32) {
        uint32_t v = get_le32(data);
        memcpy(cal->value[obj], &v, sizeof v);
    } else {
        float f = bits_to_float(get_le32(data));
        memcpy(cal->value[obj], &f, sizeof f);
    }
}

imu_cal_result_t imu_cal_write(imu_cal_t* cal, uint16_t index, uint8_t sub, const uint8_t* data, size_t len) {
    int obj = imu_cal_find(index, sub);
    imu_cal_result_t result;
    if (obj < 0) {
        return IMU_CAL_E_NO_OBJECT;
    }
    result = check_obj(cal, obj, data, len);
    if (result == IMU_CAL_OK) {
        store(cal, obj, data);
        (void)imu_cal_refresh(cal);
    }
    return result;
}

static size_t encode(const imu_cal_t* cal, int obj, uint8_t* out) {
    uint8_t type = imu_cal_objects[obj].type;
    if (type == IMU_CAL_U8) {
        out[0] = *(const uint8_t*)cal->value[obj];
        return 1u;
    }
    if (type == IMU_CAL_U32) {
        uint32_t v;
        memcpy(&v, cal->value[obj], sizeof v);
        put_le32(out, v);
    } else {
        put_le32(out, float_to_bits(real_at(cal, obj)));
    }
    return 4u;
}

size_t imu_cal_read(const imu_cal_t* cal, uint16_t index, uint8_t sub, uint8_t* out) {
    int obj = imu_cal_find(index, sub);
    return (obj < 0) ? 0u : encode(cal, obj, out);
}

uint32_t imu_cal_crc32(uint32_t crc, const uint8_t* data, size_t len) {
    size_t i;
    crc = ~crc;
    for (i = 0; i < len; i++) {
        unsigned bit;
        crc ^= data[i];
        for (bit = 0; bit < 8u; bit++) {
            crc = (crc >> 1) ^ (CRC32_POLY_REFLECTED & (0u - (crc & 1u)));
        }
    }
    return ~crc;
}

uint32_t imu_cal_block_crc(const imu_cal_t* cal) {
    uint32_t crc = 0;
    int obj;
    for (obj = 0; obj < (int)IMU_CAL_N_CRC; obj++) {
        uint8_t bytes[4];
        size_t n = encode(cal, obj, bytes);
        crc = imu_cal_crc32(crc, bytes, n);
    }
    return crc;
}

uint8_t imu_cal_valid(const imu_cal_t* cal) {
    return *(const uint8_t*)cal->value[OBJ_VALID];
}

/* R = Ay(psi) A2(beta) A1(alpha) of the mounting trim, row-major (unit <- vehicle; the
 * frame rotations of docs/design.md §2). */
static void build_align(imu_cal_t* cal) {
    float ca = cosf(real_at(cal, OBJ_TRIM)), sa = sinf(real_at(cal, OBJ_TRIM));
    float cb = cosf(real_at(cal, OBJ_TRIM + 1)), sb = sinf(real_at(cal, OBJ_TRIM + 1));
    float cp = cosf(real_at(cal, OBJ_TRIM + 2)), sp = sinf(real_at(cal, OBJ_TRIM + 2));
    /* A2(beta) A1(alpha) */
    float r[9] = {ca, sa, 0.0f, -cb * sa, cb * ca, sb, sb * sa, -sb * ca, cb};
    int c;
    for (c = 0; c < 3; c++) { /* Ay(psi) rows: [cp, 0, -sp], [0, 1, 0], [sp, 0, cp] */
        cal->align[c] = cp * r[c] - sp * r[6 + c];
        cal->align[3 + c] = r[3 + c];
        cal->align[6 + c] = sp * r[c] + cp * r[6 + c];
    }
}

uint8_t imu_cal_refresh(imu_cal_t* cal) {
    uint32_t stored;
    build_align(cal);
    memcpy(&stored, cal->value[OBJ_CRC], sizeof stored);
    cal->active = (uint8_t)(*(const uint8_t*)cal->value[OBJ_VALID] == 1u && stored == imu_cal_block_crc(cal));
    return cal->active;
}

void imu_cal_factory(imu_cal_t* cal) {
    static const uint8_t zero[4] = {0, 0, 0, 0};
    uint32_t crc;
    int obj;
    for (obj = 0; obj < (int)IMU_CAL_N_OBJECTS; obj++) {
        store(cal, obj, zero);
    }
    for (obj = 0; obj < 3; obj++) {
        memcpy(cal->value[OBJ_ACCEL_M + 4 * obj], &cal->accel_lsb, sizeof(float));
        memcpy(cal->value[OBJ_GYRO_N + 4 * obj], &cal->gyro_lsb, sizeof(float));
    }
    crc = imu_cal_block_crc(cal);
    memcpy(cal->value[OBJ_CRC], &crc, sizeof crc);
    build_align(cal);
    cal->active = 0;
}

static void mat_vec(const imu_cal_t* cal, int first, const float in[3], float out[3]) {
    int r;
    for (r = 0; r < 3; r++) {
        out[r] = real_at(cal, first + 3 * r) * in[0] + real_at(cal, first + 3 * r + 1) * in[1]
                 + real_at(cal, first + 3 * r + 2) * in[2];
    }
}

/* out = R' in: the unit-frame vector in the vehicle frame (R' = transpose of align). */
static void align_out(const imu_cal_t* cal, const float in[3], float out[3]) {
    int c;
    for (c = 0; c < 3; c++) {
        out[c] = cal->align[c] * in[0] + cal->align[3 + c] * in[1] + cal->align[6 + c] * in[2];
    }
}

void imu_cal_correct(const imu_cal_t* cal, const int16_t accel_counts[3], const int16_t gyro_counts[3],
                     float accel_out[3], float gyro_out[3]) {
    float du[3], dv[3], ga[3], a[3], w[3];
    int i;
    if (!cal->active) {
        for (i = 0; i < 3; i++) {
            accel_out[i] = cal->accel_lsb * (float)accel_counts[i];
            gyro_out[i] = cal->gyro_lsb * (float)gyro_counts[i];
        }
        return;
    }
    for (i = 0; i < 3; i++) {
        du[i] = (float)accel_counts[i] - real_at(cal, OBJ_ACCEL_BIAS + i);
    }
    mat_vec(cal, OBJ_ACCEL_M, du, a); /* a = M (U - b) */
    mat_vec(cal, OBJ_GYRO_G, a, ga);
    for (i = 0; i < 3; i++) {
        dv[i] = (float)gyro_counts[i] - real_at(cal, OBJ_GYRO_BIAS + i) - ga[i];
    }
    mat_vec(cal, OBJ_GYRO_N, dv, w); /* w = N (V - B - G a) */
    align_out(cal, a, accel_out);     /* in the vehicle frame: R' a, R' w */
    align_out(cal, w, gyro_out);
}

uint16_t imu_cal_next_sample(imu_cal_t* cal) {
    cal->counter = (uint16_t)(cal->counter + 1u);
    return cal->counter;
}

uint8_t imu_cal_status(const imu_cal_t* cal, uint8_t sensor_flags) {
    uint8_t status = (uint8_t)(sensor_flags & (IMU_CAL_STATUS_SATURATED | IMU_CAL_STATUS_MOVING));
    return (uint8_t)(status | (cal->active ? IMU_CAL_STATUS_ACTIVE : 0u));
}

int imu_cal_odr_ok(uint32_t hz) {
    return hz == 50u || hz == 100u || hz == 200u || hz == 250u || hz == 500u || hz == 1000u;
}

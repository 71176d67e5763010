/*
 * Unit tests of the imu_cal core (firmware/module/imu_cal.c), host-built with gcc.
 * Run by tests/firmware/test_core_c.py (make test) and by `make -C firmware test`.
 * Prints one line per failed check and "imu_cal: N checks, M failed"; exit status 1 on a failure.
 */
#include "imu_cal.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

static int checks, failures;

#define CHECK(cond)                                                     \
    do {                                                                \
        checks++;                                                       \
        if (!(cond)) {                                                  \
            failures++;                                                 \
            printf("FAIL %s:%d: %s\n", __FILE__, __LINE__, #cond);      \
        }                                                               \
    } while (0)

static const float ACCEL_LSB = (float)(9.80665 / 2048.0);
static const float GYRO_LSB = (float)(3.14159265358979323846 / (180.0 * 16.4));

static void le_float(uint8_t out[4], float f) {
    uint32_t bits;
    memcpy(&bits, &f, sizeof bits);
    out[0] = (uint8_t)bits;
    out[1] = (uint8_t)(bits >> 8);
    out[2] = (uint8_t)(bits >> 16);
    out[3] = (uint8_t)(bits >> 24);
}

static imu_cal_result_t write_f(imu_cal_t* cal, uint16_t index, uint8_t sub, float f) {
    uint8_t b[4];
    le_float(b, f);
    return imu_cal_write(cal, index, sub, b, 4);
}

static imu_cal_result_t write_u32(imu_cal_t* cal, uint16_t index, uint8_t sub, uint32_t v) {
    uint8_t b[4] = {(uint8_t)v, (uint8_t)(v >> 8), (uint8_t)(v >> 16), (uint8_t)(v >> 24)};
    return imu_cal_write(cal, index, sub, b, 4);
}

static imu_cal_result_t write_u8(imu_cal_t* cal, uint16_t index, uint8_t sub, uint8_t v) {
    return imu_cal_write(cal, index, sub, &v, 1);
}

static void fresh(imu_cal_t* cal, imu_cal_block_t* block) {
    memset(cal, 0, sizeof *cal);
    memset(block, 0, sizeof *block);
    imu_cal_bind_block(cal, block);
    cal->accel_lsb = ACCEL_LSB;
    cal->gyro_lsb = GYRO_LSB;
    imu_cal_factory(cal);
}

static void test_crc(void) {
    const uint8_t check[] = "123456789";
    imu_cal_t cal;
    imu_cal_block_t block;
    CHECK(imu_cal_crc32(0, check, 9) == 0xCBF43926u); /* CRC-32/ISO-HDLC check value */
    CHECK(imu_cal_crc32(imu_cal_crc32(0, check, 4), check + 4, 5) == 0xCBF43926u);
    CHECK(imu_cal_crc32(0, check, 0) == 0u);
    fresh(&cal, &block);
    CHECK(block.crc == 0x36701FFBu); /* docs/design.md §4 test vector: 42 objects, 165 bytes */
    CHECK(imu_cal_block_crc(&cal) == 0x36701FFBu);
    {
        /* the 42-object CRC continues the 39-object one (0x88E40123) over the trim's bytes */
        const uint8_t zeros[12] = {0};
        CHECK(imu_cal_crc32(0x88E40123u, zeros, 12) == 0x36701FFBu);
    }
    block.mounting_trim[1] = 0.01f; /* the trim is covered */
    CHECK(imu_cal_block_crc(&cal) != 0x36701FFBu);
}

static void test_objects(void) {
    uint8_t out[4];
    imu_cal_t cal;
    imu_cal_block_t block;
    fresh(&cal, &block);
    CHECK(imu_cal_find(0x2100, 1) == 0);
    CHECK(imu_cal_find(0x2121, 6) == (int)IMU_CAL_N_OBJECTS - 1);
    CHECK(imu_cal_find(0x2100, 4) < 0);
    CHECK(imu_cal_find(0x2010, 1) < 0);
    CHECK(imu_cal_read(&cal, 0x2121, 6, out) == 4 && out[0] == 0xFB && out[3] == 0x36);
    CHECK(imu_cal_read(&cal, 0x2121, 2, out) == 1);
    CHECK(imu_cal_read(&cal, 0x2122, 1, out) == 4);
    CHECK(imu_cal_find(0x2122, 3) == (int)IMU_CAL_N_CRC - 1);
    CHECK(imu_cal_read(&cal, 0x2122, 4, out) == 0);
    CHECK(write_u8(&cal, 0x2100, 1, 0) == IMU_CAL_E_LENGTH); /* REAL32 needs 4 bytes */
    CHECK(write_u32(&cal, 0x2121, 2, 1) == IMU_CAL_E_LENGTH);
    CHECK(write_f(&cal, 0x2130, 1, 0.0f) == IMU_CAL_E_NO_OBJECT);
}

static void test_ranges(void) {
    imu_cal_t cal;
    imu_cal_block_t block;
    fresh(&cal, &block);
    CHECK(write_f(&cal, 0x2100, 1, 65536.0f) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2100, 2, -65536.0f) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2100, 3, 65536.01f) == IMU_CAL_E_RANGE);
    CHECK(block.accel_bias[2] == 0.0f); /* refused: unchanged */
    CHECK(write_f(&cal, 0x2110, 1, NAN) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2110, 1, INFINITY) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2121, 3, -INFINITY) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2121, 3, -40.0f) == IMU_CAL_OK);
    /* diagonal: within +-50 % of |LSB|, either sign */
    CHECK(write_f(&cal, 0x2101, 1, 1.5f * ACCEL_LSB) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2101, 5, -0.5f * ACCEL_LSB) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2101, 9, 0.49f * ACCEL_LSB) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2111, 9, 1.51f * GYRO_LSB) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2111, 9, -GYRO_LSB) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2111, 1, ACCEL_LSB) == IMU_CAL_E_RANGE); /* gyro row, accel LSB */
    /* off-diagonal: against the row's diagonal as held now */
    CHECK(write_f(&cal, 0x2101, 2, 0.19f * 1.5f * ACCEL_LSB) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2101, 4, 0.19f * 1.5f * ACCEL_LSB) == IMU_CAL_E_RANGE); /* row 2: 0.5 LSB */
    CHECK(write_f(&cal, 0x2101, 4, -0.09f * ACCEL_LSB) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2111, 8, 0.21f * GYRO_LSB) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2111, 8, -0.2f * 0.999f * GYRO_LSB) == IMU_CAL_OK);
    /* G, tilt */
    CHECK(write_f(&cal, 0x2112, 5, 1000.0f) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2112, 5, -1000.1f) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2120, 2, -0.2f) == IMU_CAL_E_RANGE); /* float 0.2 > double 0.2 */
    CHECK(write_f(&cal, 0x2120, 2, -0.19999999f) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2122, 3, 0.2f) == IMU_CAL_E_RANGE); /* trim: the tilt's bound */
    CHECK(write_f(&cal, 0x2122, 3, 0.19999999f) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2122, 1, NAN) == IMU_CAL_E_RANGE);
    /* info: plan code, rms, valid */
    CHECK(write_u8(&cal, 0x2121, 2, 6) == IMU_CAL_OK);
    CHECK(write_u8(&cal, 0x2121, 2, 7) == IMU_CAL_E_RANGE);
    CHECK(write_f(&cal, 0x2121, 4, -0.0f) == IMU_CAL_OK);
    CHECK(write_f(&cal, 0x2121, 4, -1e-30f) == IMU_CAL_E_RANGE);
    CHECK(write_u8(&cal, 0x2121, 5, 2) == IMU_CAL_E_RANGE);
    CHECK(write_u32(&cal, 0x2121, 1, 0xFFFFFFFFu) == IMU_CAL_OK);
    CHECK(write_u32(&cal, 0x2121, 6, 0x12345678u) == IMU_CAL_OK);
}

static void test_gate(void) {
    imu_cal_t cal;
    imu_cal_block_t block;
    uint32_t crc;
    fresh(&cal, &block);
    CHECK(!cal.active);
    CHECK(write_u8(&cal, 0x2121, 5, 1) == IMU_CAL_OK);
    CHECK(cal.active); /* factory set with its CRC, now valid */
    CHECK(imu_cal_status(&cal, IMU_CAL_STATUS_MOVING) == (IMU_CAL_STATUS_MOVING | IMU_CAL_STATUS_ACTIVE));
    CHECK(write_f(&cal, 0x2100, 1, 12.5f) == IMU_CAL_OK);
    CHECK(!cal.active); /* values no longer match the CRC */
    crc = imu_cal_block_crc(&cal);
    CHECK(write_u32(&cal, 0x2121, 6, crc) == IMU_CAL_OK);
    CHECK(cal.active);
    CHECK(write_u8(&cal, 0x2121, 5, 0) == IMU_CAL_OK);
    CHECK(!cal.active);
    /* at boot: a stored block whose CRC does not match stays closed */
    block.valid = 1;
    block.gyro_g[4] = 3.0f;
    CHECK(imu_cal_refresh(&cal) == 0);
    block.crc = imu_cal_block_crc(&cal);
    CHECK(imu_cal_refresh(&cal) == 1);
    CHECK(imu_cal_status(&cal, 0xF8) == IMU_CAL_STATUS_ACTIVE);
}

static int near(float got, double want) {
    return fabs((double)got - want) <= 1e-6 * fabs(want) + 1e-12;
}

static void test_correction(void) {
    imu_cal_t cal;
    imu_cal_block_t block;
    const int16_t u[3] = {100, -2048, 7};
    const int16_t v[3] = {-3, 16, 1000};
    float a[3], w[3];
    double ga1;
    fresh(&cal, &block);
    imu_cal_correct(&cal, u, v, a, w); /* gate closed: nominal */
    CHECK(a[1] == ACCEL_LSB * -2048.0f && w[2] == GYRO_LSB * 1000.0f);
    block.accel_bias[0] = 4.0f;
    block.accel_bias[1] = -8.0f;
    block.accel_m[1] = 0.1f * ACCEL_LSB;
    block.gyro_bias[2] = 10.0f;
    block.gyro_g[5] = 2.0f; /* row 2, column 3 */
    block.gyro_n[4] = 1.1f * GYRO_LSB;
    block.valid = 1;
    block.crc = imu_cal_block_crc(&cal);
    CHECK(imu_cal_refresh(&cal));
    imu_cal_correct(&cal, u, v, a, w);
    CHECK(near(a[0], (double)ACCEL_LSB * 96.0 + 0.1 * ACCEL_LSB * -2040.0));
    CHECK(near(a[1], (double)ACCEL_LSB * -2040.0));
    CHECK(near(a[2], (double)ACCEL_LSB * 7.0));
    ga1 = 2.0 * (double)a[2];
    CHECK(near(w[0], (double)GYRO_LSB * -3.0));
    CHECK(near(w[1], 1.1 * GYRO_LSB * (16.0 - ga1)));
    CHECK(near(w[2], (double)GYRO_LSB * (1000.0 - 10.0)));
    {
        /* a trim of 0.1 rad about z (alpha): the outputs in the vehicle frame, R' a */
        float a0[3], w0[3];
        double c = cos(0.1), s = sin(0.1);
        imu_cal_correct(&cal, u, v, a0, w0);
        block.mounting_trim[0] = 0.1f;
        block.crc = imu_cal_block_crc(&cal);
        CHECK(imu_cal_refresh(&cal));
        imu_cal_correct(&cal, u, v, a, w);
        /* A1(t) = [[c, s, 0], [-s, c, 0], [0, 0, 1]]: R' a = [c a0 - s a1, s a0 + c a1, a2] */
        CHECK(fabs(a[0] - (c * a0[0] - s * a0[1])) < 1e-5);
        CHECK(fabs(a[1] - (s * a0[0] + c * a0[1])) < 1e-5);
        CHECK(a[2] == a0[2]);
        CHECK(fabs(w[0] - (c * w0[0] - s * w0[1])) < 1e-7 && w[2] == w0[2]);
    }
}

static void test_counter_and_odr(void) {
    imu_cal_t cal;
    imu_cal_block_t block;
    fresh(&cal, &block);
    CHECK(imu_cal_next_sample(&cal) == 1);
    cal.counter = 65535;
    CHECK(imu_cal_next_sample(&cal) == 0);
    CHECK(imu_cal_odr_ok(200) && imu_cal_odr_ok(1000) && imu_cal_odr_ok(50));
    CHECK(!imu_cal_odr_ok(0) && !imu_cal_odr_ok(400) && !imu_cal_odr_ok(2000));
}

int main(void) {
    test_crc();
    test_objects();
    test_ranges();
    test_gate();
    test_correction();
    test_counter_and_odr();
    printf("imu_cal: %d checks, %d failed\n", checks, failures);
    return failures ? 1 : 0;
}

/*
 * imu_cal: the calibration core of the canimucal reference IMU node (docs/design.md §4).
 *
 * Plain C99, no operating system, no CANopen stack types: the calibration block
 * 0x2100-0x2122, its value ranges, its CRC, the valid/CRC gate, the correction and the
 * alignment (mounting trim) the device applies and the sample counter. The CANopenNode v4 glue (imu_cal_co.h) is a thin layer on
 * top; an MCU project with another stack can use this file alone.
 *
 * Where the values live is up to the caller: imu_cal_t holds one pointer per object (into
 * the stack's object dictionary, or into an imu_cal_block_t with imu_cal_bind_block()).
 * Every write goes through imu_cal_write(), which refuses a value out of range and leaves
 * the object unchanged, and re-checks the gate after every change; imu_cal_refresh() does
 * the same at boot.
 */
#ifndef IMU_CAL_H
#define IMU_CAL_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/* Object dictionary indices (docs/design.md §4). */
#define IMU_CAL_ACCEL_BIAS       0x2100u /* REAL32 x3, counts */
#define IMU_CAL_ACCEL_CORRECTION 0x2101u /* REAL32 x9, M = K^-1, m/s^2 per count, row-major */
#define IMU_CAL_GYRO_BIAS        0x2110u /* REAL32 x3, counts */
#define IMU_CAL_GYRO_CORRECTION  0x2111u /* REAL32 x9, N = S^-1, rad/s per count, row-major */
#define IMU_CAL_GYRO_G           0x2112u /* REAL32 x9, counts per m/s^2, row-major */
#define IMU_CAL_BASE_TILT        0x2120u /* REAL32 x2, rad */
#define IMU_CAL_INFO             0x2121u /* 1 time U32, 2 plan U8, 3 temp REAL32, 4 rms REAL32,
                                            5 valid U8, 6 CRC U32 */
#define IMU_CAL_MOUNTING_TRIM    0x2122u /* REAL32 x3, rad: alpha, beta, psi of
                                            R = Ay(psi) A2(beta) A1(alpha), unit <- vehicle */
#define IMU_CAL_VALID_SUB 5u
#define IMU_CAL_CRC_SUB   6u

#define IMU_CAL_N_CRC     42u /* objects the CRC covers: 165 bytes (0x2100:01 .. 0x2121:04, then
                                 0x2122:01 .. 03); factory vector 0x36701FFB */
#define IMU_CAL_N_OBJECTS 44u /* those plus valid and the CRC */

#define IMU_CAL_STATUS_SATURATED 0x01u /* 0x2002:03 bit 0 */
#define IMU_CAL_STATUS_MOVING    0x02u /* 0x2002:03 bit 1 */
#define IMU_CAL_STATUS_ACTIVE    0x04u /* 0x2002:03 bit 2: valid = 1 and the CRC matches */

#define IMU_CAL_PLAN_MAX 6u /* plan codes 0 (none) .. 6 (vehicle) */

typedef enum {
    IMU_CAL_REAL32 = 0,
    IMU_CAL_U32 = 1,
    IMU_CAL_U8 = 2
} imu_cal_type_t;

/* Which value range an object has (docs/design.md §4 "Value ranges"). */
typedef enum {
    IMU_CAL_RANGE_BIAS = 0,    /* finite, |value| <= 65536 counts */
    IMU_CAL_RANGE_ACCEL_M = 1, /* diagonal within +-50 % of |nominal accel LSB|, off-diagonal
                                  |value| <= 0.2 |its row's diagonal| */
    IMU_CAL_RANGE_GYRO_N = 2,  /* the same against the nominal gyro LSB */
    IMU_CAL_RANGE_G = 3,       /* finite, |value| <= 1000 */
    IMU_CAL_RANGE_TILT = 4,    /* finite, |value| <= 0.2 rad (base tilt and mounting trim) */
    IMU_CAL_RANGE_ANY = 5,     /* finite (REAL32) or any (integers) */
    IMU_CAL_RANGE_PLAN = 6,    /* 0 .. IMU_CAL_PLAN_MAX */
    IMU_CAL_RANGE_NONNEG = 7,  /* finite, not negative */
    IMU_CAL_RANGE_FLAG = 8     /* 0 or 1 */
} imu_cal_range_t;

/* One object of the calibration block: where, what type, which range. */
typedef struct {
    uint16_t index;
    uint8_t sub;
    uint8_t type;  /* imu_cal_type_t */
    uint8_t range; /* imu_cal_range_t */
} imu_cal_object_t;

/* The table of every calibration object: the first IMU_CAL_N_CRC in CRC order, then valid
 * and the CRC. A new object is one more row here, in the block struct and, if the device
 * applies it, in imu_cal_correct(). */
extern const imu_cal_object_t imu_cal_objects[IMU_CAL_N_OBJECTS];

typedef enum {
    IMU_CAL_OK = 0,
    IMU_CAL_E_RANGE = 1,     /* value out of range: SDO abort 0x06090030 */
    IMU_CAL_E_LENGTH = 2,    /* wrong number of bytes: SDO abort 0x06070010 */
    IMU_CAL_E_NO_OBJECT = 3  /* not a calibration object */
} imu_cal_result_t;

/* The whole block as plain values (row-major matrices), for callers that keep it themselves. */
typedef struct {
    float accel_bias[3];
    float accel_m[9];
    float gyro_bias[3];
    float gyro_n[9];
    float gyro_g[9];
    float base_tilt[2];
    uint32_t time_unix_s;
    uint8_t plan_code;
    float temp_c;
    float rms_ms2;
    float mounting_trim[3]; /* 0x2122:01-03, rad */
    uint8_t valid;
    uint32_t crc;
} imu_cal_block_t;

typedef struct {
    void* value[IMU_CAL_N_OBJECTS]; /* float*, uint32_t* or uint8_t*, as imu_cal_objects says */
    float accel_lsb;                /* nominal LSBs (0x2010:01/02, signed) */
    float gyro_lsb;
    uint8_t active;                 /* valid = 1 and the stored CRC matches the values */
    uint16_t counter;               /* 0x2002:02 of the latest sample */
    float align[9];                 /* R of the mounting trim, row-major (imu_cal_refresh()) */
} imu_cal_t;

/* Point every object of cal at the fields of block. */
void imu_cal_bind_block(imu_cal_t* cal, imu_cal_block_t* block);

/* Position of (index, sub) in imu_cal_objects, or -1. */
int imu_cal_find(uint16_t index, uint8_t sub);

/* Check a write of the little-endian bytes data[0..len) to (index, sub) without doing it. */
imu_cal_result_t imu_cal_check(const imu_cal_t* cal, uint16_t index, uint8_t sub, const uint8_t* data,
                               size_t len);

/* Check, then store the value and re-check the gate; on an error nothing changes. */
imu_cal_result_t imu_cal_write(imu_cal_t* cal, uint16_t index, uint8_t sub, const uint8_t* data, size_t len);

/* The object's current value as its little-endian bytes; returns the length (0: none). */
size_t imu_cal_read(const imu_cal_t* cal, uint16_t index, uint8_t sub, uint8_t* out);

/* CRC-32/ISO-HDLC as zlib.crc32(data, crc): crc is the CRC so far (0 to start). */
uint32_t imu_cal_crc32(uint32_t crc, const uint8_t* data, size_t len);

/* The CRC of the block's current values (docs/design.md §4 order). */
uint32_t imu_cal_block_crc(const imu_cal_t* cal);

/* The valid flag (0x2121:05) as held now. */
uint8_t imu_cal_valid(const imu_cal_t* cal);

/* Re-check the gate: active = (valid == 1 and the stored CRC equals the values' CRC), and
 * rebuild the alignment rotation from the mounting trim. Call at boot, after the stored block
 * was loaded; imu_cal_write() calls it after every change. */
uint8_t imu_cal_refresh(imu_cal_t* cal);

/* Factory defaults for the nominal LSBs: zero biases, M and N = diag(LSB), G = 0, tilt 0,
 * info 0, trim 0, valid 0 and the CRC of that set. */
void imu_cal_factory(imu_cal_t* cal);

/* The correction (docs/design.md §4): with the gate open a = M (U - b) and
 * w = N (V - B - G a), both turned into the vehicle frame by the mounting trim (a_v = R' a,
 * w_v = R' w; docs/firmware.md section 3), else a = LSB U and w = LSB V. Outputs in m/s^2 and
 * rad/s. */
void imu_cal_correct(const imu_cal_t* cal, const int16_t accel_counts[3], const int16_t gyro_counts[3],
                     float accel_out[3], float gyro_out[3]);

/* Start a new sample: the counter advances (wrapping at 65536) and is returned. */
uint16_t imu_cal_next_sample(imu_cal_t* cal);

/* 0x2002:03 for a sample: the sensor's flags plus IMU_CAL_STATUS_ACTIVE when the gate is open. */
uint8_t imu_cal_status(const imu_cal_t* cal, uint8_t sensor_flags);

/* Output data rates the node offers (0x2010:03): 1 if hz is one of them. */
int imu_cal_odr_ok(uint32_t hz);

#ifdef __cplusplus
}
#endif

#endif /* IMU_CAL_H */

/*
 * imu_cal_co: the CANopenNode v4 glue of the imu_cal core (docs/firmware.md).
 *
 * Two calls in the firmware:
 *   imu_cal_co_init(&imu, CO, OD, &errInfo);   after CO_CANopenInit(), before CO_CANopenInitPDO()
 *                                              (CANopenLinux: app_communicationReset())
 *   imu_cal_co_sample(&imu, accel, gyro, temp_centi_c, flags, a, w);
 *                                              from the sensor's data-ready interrupt or the task
 *                                              it wakes, once per sample
 *
 * imu_cal_co_init() finds the objects by index (any generated OD works), binds the core to
 * the calibration block's memory, installs the write checks on 0x2100-0x2122 (a value out of
 * range is refused with SDO abort 0x06090030 and left unchanged; the valid/CRC gate is
 * re-checked after every write) and on 0x2010:03 (output data rate), restarts the sample
 * counter and checks the gate once (boot). A stored block with valid = 1 and a CRC that does
 * not match is reported once with EMCY 0x6300 (data set) and not applied.
 *
 * imu_cal_co_sample() advances the counter, writes the raw sample, the counter and the status
 * to 0x2000-0x2002, requests TPDO1 and TPDO2 (sent on data-ready: keep their event timers 0)
 * and returns the corrected values a = R' M (U - b), w = R' N (V - B - G M (U - b)) for the
 * application, in the vehicle frame of the mounting trim R (0x2122), or the nominal ones while
 * no valid calibration is active. Calibrated data never goes on
 * the bus: the calibration tool needs the raw counts.
 */
#ifndef IMU_CAL_CO_H
#define IMU_CAL_CO_H

#include "CANopen.h"
#include "imu_cal.h"

#ifdef __cplusplus
extern "C" {
#endif

#define IMU_CAL_CO_NOMINAL    0x2010u /* 1 accel LSB, 2 gyro LSB (REAL32), 3 output data rate U16 */
#define IMU_CAL_CO_STORE_SUB  0x2011u /* 0x1010/0x1011 sub-index that stores the calibration */
#define IMU_CAL_CO_EM_CAL_CRC CO_EM_MANUFACTURER_START /* error status bit of a bad stored block */
#define IMU_CAL_CO_N_BLOCKS   8u /* 0x2100, 0x2101, 0x2110, 0x2111, 0x2112, 0x2120, 0x2121, 0x2122 */

typedef struct {
    imu_cal_t cal;
    CO_t* co;
    OD_extension_t block_ext[IMU_CAL_CO_N_BLOCKS];
    OD_extension_t nominal_ext;
    int16_t* accel_raw[3]; /* 0x2000:01-03 */
    int16_t* gyro_raw[3];  /* 0x2001:01-03 */
    int16_t* temperature;  /* 0x2002:01, 0.01 degC */
    uint16_t* counter;     /* 0x2002:02 */
    uint8_t* status;       /* 0x2002:03 */
    uint16_t* odr_hz;      /* 0x2010:03 */
    /* Called (from the SDO server) after a new output data rate was accepted: reprogram the
     * sensor's data-ready rate there. NULL: nothing to do. */
    void (*odr_changed)(void* arg, uint16_t odr_hz);
    void* odr_arg;
} imu_cal_co_t;

/* Bind the module to the object dictionary (see above). Returns CO_ERROR_OD_PARAMETERS with
 * the missing index in *errInfo when the OD lacks an object the module needs. */
CO_ReturnError_t imu_cal_co_init(imu_cal_co_t* imu, CO_t* co, OD_t* od, uint32_t* errInfo);

/* One sample from the sensor (see above). flags: IMU_CAL_STATUS_SATURATED / _MOVING.
 * accel_out / gyro_out may be NULL. Takes the OD lock around its object accesses. */
void imu_cal_co_sample(imu_cal_co_t* imu, const int16_t accel[3], const int16_t gyro[3], int16_t temp_centi_c,
                       uint8_t flags, float accel_out[3], float gyro_out[3]);

#ifdef __cplusplus
}
#endif

#endif /* IMU_CAL_CO_H */

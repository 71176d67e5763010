/*
 * imu_cal_co: CANopenNode v4 glue of the imu_cal core (see imu_cal_co.h).
 */
#include "imu_cal_co.h"

#include <string.h>

static const uint16_t block_indices[IMU_CAL_CO_N_BLOCKS] = {
    IMU_CAL_ACCEL_BIAS, IMU_CAL_ACCEL_CORRECTION, IMU_CAL_GYRO_BIAS, IMU_CAL_GYRO_CORRECTION,
    IMU_CAL_GYRO_G,     IMU_CAL_BASE_TILT,        IMU_CAL_INFO,      IMU_CAL_MOUNTING_TRIM};

/* Write check of every calibration object: the core checks, stores and re-checks the gate. */
static ODR_t write_calibration(OD_stream_t* stream, const void* buf, OD_size_t count, OD_size_t* countWritten) {
    imu_cal_co_t* imu = stream->object;
    if (stream->dataOffset != 0U || count != stream->dataLength) {
        return ODR_TYPE_MISMATCH; /* every calibration object fits one expedited transfer */
    }
    switch (imu_cal_write(&imu->cal, stream->index, stream->subIndex, buf, count)) {
        case IMU_CAL_OK: *countWritten = count; return ODR_OK;
        case IMU_CAL_E_RANGE: return ODR_INVALID_VALUE; /* SDO abort 0x06090030, value unchanged */
        case IMU_CAL_E_LENGTH: return ODR_TYPE_MISMATCH;
        case IMU_CAL_E_NO_OBJECT:
        default: return OD_writeOriginal(stream, buf, count, countWritten);
    }
}

/* 0x2010: only the output data rate is writable; one of the offered rates or abort 0x06090030. */
static ODR_t write_nominal(OD_stream_t* stream, const void* buf, OD_size_t count, OD_size_t* countWritten) {
    imu_cal_co_t* imu = stream->object;
    ODR_t ret;
    if (stream->subIndex != 3U || count != sizeof(uint16_t)) {
        return OD_writeOriginal(stream, buf, count, countWritten);
    }
    if (!imu_cal_odr_ok(CO_getUint16(buf))) {
        return ODR_INVALID_VALUE;
    }
    ret = OD_writeOriginal(stream, buf, count, countWritten);
    if (ret == ODR_OK && imu->odr_changed != NULL) {
        imu->odr_changed(imu->odr_arg, CO_getUint16(buf));
    }
    return ret;
}

static void* od_ptr(OD_t* od, uint16_t index, uint8_t sub, OD_size_t size, uint32_t* errInfo) {
    OD_entry_t* entry = OD_find(od, index);
    ODR_t err = ODR_OK;
    void* ptr = (entry != NULL) ? OD_getPtr(entry, sub, size, &err) : NULL;
    if (ptr == NULL && errInfo != NULL) {
        *errInfo = ((uint32_t)index << 8) | sub;
    }
    return ptr;
}

static CO_ReturnError_t bind_objects(imu_cal_co_t* imu, OD_t* od, uint32_t* errInfo) {
    unsigned i;
    float32_t* lsb;
    for (i = 0; i < IMU_CAL_N_OBJECTS; i++) {
        const imu_cal_object_t* o = &imu_cal_objects[i];
        OD_size_t size = (o->type == IMU_CAL_U8) ? 1U : 4U;
        imu->cal.value[i] = od_ptr(od, o->index, o->sub, size, errInfo);
        if (imu->cal.value[i] == NULL) {
            return CO_ERROR_OD_PARAMETERS;
        }
    }
    for (i = 0; i < 3U; i++) {
        imu->accel_raw[i] = od_ptr(od, 0x2000, (uint8_t)(i + 1U), sizeof(int16_t), errInfo);
        imu->gyro_raw[i] = od_ptr(od, 0x2001, (uint8_t)(i + 1U), sizeof(int16_t), errInfo);
        if (imu->accel_raw[i] == NULL || imu->gyro_raw[i] == NULL) {
            return CO_ERROR_OD_PARAMETERS;
        }
    }
    imu->temperature = od_ptr(od, 0x2002, 1, sizeof(int16_t), errInfo);
    imu->counter = od_ptr(od, 0x2002, 2, sizeof(uint16_t), errInfo);
    imu->status = od_ptr(od, 0x2002, 3, sizeof(uint8_t), errInfo);
    imu->odr_hz = od_ptr(od, IMU_CAL_CO_NOMINAL, 3, sizeof(uint16_t), errInfo);
    if (imu->temperature == NULL || imu->counter == NULL || imu->status == NULL || imu->odr_hz == NULL) {
        return CO_ERROR_OD_PARAMETERS;
    }
    lsb = od_ptr(od, IMU_CAL_CO_NOMINAL, 1, sizeof(float32_t), errInfo);
    if (lsb == NULL) {
        return CO_ERROR_OD_PARAMETERS;
    }
    imu->cal.accel_lsb = *lsb;
    lsb = od_ptr(od, IMU_CAL_CO_NOMINAL, 2, sizeof(float32_t), errInfo);
    if (lsb == NULL) {
        return CO_ERROR_OD_PARAMETERS;
    }
    imu->cal.gyro_lsb = *lsb;
    return CO_ERROR_NO;
}

CO_ReturnError_t imu_cal_co_init(imu_cal_co_t* imu, CO_t* co, OD_t* od, uint32_t* errInfo) {
    CO_ReturnError_t err;
    unsigned i;
    if (imu == NULL || co == NULL || od == NULL) {
        return CO_ERROR_ILLEGAL_ARGUMENT;
    }
    imu->co = co;
    err = bind_objects(imu, od, errInfo);
    if (err != CO_ERROR_NO) {
        return err;
    }
    for (i = 0; i < IMU_CAL_CO_N_BLOCKS; i++) {
        imu->block_ext[i].object = imu;
        imu->block_ext[i].read = OD_readOriginal;
        imu->block_ext[i].write = write_calibration;
        if (OD_extension_init(OD_find(od, block_indices[i]), &imu->block_ext[i]) != ODR_OK) {
            if (errInfo != NULL) {
                *errInfo = (uint32_t)block_indices[i] << 8;
            }
            return CO_ERROR_OD_PARAMETERS;
        }
    }
    imu->nominal_ext.object = imu;
    imu->nominal_ext.read = OD_readOriginal;
    imu->nominal_ext.write = write_nominal;
    (void)OD_extension_init(OD_find(od, IMU_CAL_CO_NOMINAL), &imu->nominal_ext);

    imu->cal.counter = 0; /* a reset starts the counter again (the client re-pairs at boot-up) */
    *imu->counter = 0;
    if (!imu_cal_refresh(&imu->cal) && imu_cal_valid(&imu->cal) == 1U) {
        /* valid = 1 over values whose CRC does not match: not applied, and said once */
        CO_errorReport(co->em, IMU_CAL_CO_EM_CAL_CRC, CO_EMC_DATA_SET, imu_cal_block_crc(&imu->cal));
    } else {
        CO_errorReset(co->em, IMU_CAL_CO_EM_CAL_CRC, 0);
    }
    return CO_ERROR_NO;
}

void imu_cal_co_sample(imu_cal_co_t* imu, const int16_t accel[3], const int16_t gyro[3], int16_t temp_centi_c,
                       uint8_t flags, float accel_out[3], float gyro_out[3]) {
    float a[3], w[3];
    unsigned i;
    CO_LOCK_OD(imu->co->CANmodule);
    *imu->counter = imu_cal_next_sample(&imu->cal);
    for (i = 0; i < 3U; i++) {
        *imu->accel_raw[i] = accel[i];
        *imu->gyro_raw[i] = gyro[i];
    }
    *imu->temperature = temp_centi_c;
    *imu->status = imu_cal_status(&imu->cal, flags);
    imu_cal_correct(&imu->cal, accel, gyro, a, w);
    CO_UNLOCK_OD(imu->co->CANmodule);
    CO_TPDOsendRequest(&imu->co->TPDO[0]); /* data-ready: one TPDO1/TPDO2 pair per sample */
    CO_TPDOsendRequest(&imu->co->TPDO[1]);
    if (accel_out != NULL) {
        memcpy(accel_out, a, sizeof a);
    }
    if (gyro_out != NULL) {
        memcpy(gyro_out, w, sizeof w);
    }
}

/*
 * CANopenLinux build settings of the reference node (included by CANopenLinux's
 * CO_driver_target.h with -DCO_DRIVER_CUSTOM, before its defaults and before
 * CO_main_basic.c's own).
 */
#ifndef CO_DRIVER_CUSTOM_H
#define CO_DRIVER_CUSTOM_H

#include <stdint.h>

#include "imu_cal_co_config.h" /* the stack configuration the generated OD needs */

uint16_t imu_node_nmt_control(void);
uint8_t imu_node_cal_store_sub(void);

/* NMT start-up and error behaviour (docs/firmware.md "First boot"). CANopenLinux's default,
 * CO_NMT_STARTUP_TO_OPERATIONAL | CO_NMT_ERR_ON_ERR_REG | CO_ERR_REG_GENERIC_ERR |
 * CO_ERR_REG_COMMUNICATION, sends the node back to PRE-OPERATIONAL after every NMT start
 * while the generic error bit is set, and a blank storage sets it at every boot until
 * something is stored. The reference node starts PRE-OPERATIONAL and leaves OPERATIONAL
 * only on a communication error; IMU_NODE_NMT_CONTROL=stock brings the default back. */
#define NMT_CONTROL imu_node_nmt_control()

/* Storage (0x1010/0x1011): CO_main_basic.c registers the communication parameters on sub 2
 * and its node-id/bit-rate record on sub 4; the node adds the application parameters (output
 * data rate, sub 3) and the calibration block on the sub-index 0x2011 names (sub 4: one
 * 'save' there stores both records). */
#define CO_STORAGE_APPLICATION                                                                  \
    {.addr = &OD_PERSIST_APP,                                                                   \
     .len = sizeof(OD_PERSIST_APP),                                                             \
     .subIndexOD = 3,                                                                           \
     .attr = CO_storage_cmd | CO_storage_restore,                                               \
     .filename = "od_app.persist"},                                                             \
        {.addr = &OD_PERSIST_CAL,                                                               \
         .len = sizeof(OD_PERSIST_CAL),                                                         \
         .subIndexOD = imu_node_cal_store_sub(),                                                \
         .attr = CO_storage_cmd | CO_storage_restore,                                           \
         .filename = "imu_cal.persist"},

#endif /* CO_DRIVER_CUSTOM_H */

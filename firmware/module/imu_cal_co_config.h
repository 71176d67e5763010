/*
 * CANopenNode v4 stack configuration for an object dictionary generated from
 * eds/canimucal_imu.eds (docs/firmware.md "Configuration overrides").
 *
 * The EDS has what a calibrated IMU node needs and no more: no error history (0x1003), no EMCY
 * inhibit time (0x1015), no heartbeat consumer (0x1016), no SDO client (0x1280), no TIME
 * object (0x1012), no safety objects (0x1300-0x13FF). CANopenNode's (and CANopenLinux's) default
 * configuration expects those, so these overrides switch the matching services off. Include
 * this file from the port's CO_driver_target.h (CANopenLinux: CO_driver_custom.h with
 * -DCO_DRIVER_CUSTOM) before the defaults are set.
 */
#ifndef IMU_CAL_CO_CONFIG_H
#define IMU_CAL_CO_CONFIG_H

/* EMCY producer (0x1014) and consumer; no history 0x1003, no inhibit time 0x1015 */
#define CO_CONFIG_EM                                                                                   \
    (CO_CONFIG_EM_PRODUCER | CO_CONFIG_EM_CONSUMER | CO_CONFIG_GLOBAL_FLAG_CALLBACK_PRE                \
     | CO_CONFIG_GLOBAL_FLAG_TIMERNEXT)
#define CO_CONFIG_HB_CONS 0 /* no heartbeat consumer (0x1016) */
#define CO_CONFIG_SDO_CLI 0 /* no SDO client (0x1280) */
#define CO_CONFIG_GTW     0 /* the ASCII gateway needs the SDO client */
/* TIME stays as the port has it: without 0x1012 in the OD, CANopen.c leaves it unused (and
 * CANopenLinux's CO_main_basic.c calls CO_TIME_set() unconditionally) */
#define CO_CONFIG_GFC     0 /* no safety objects (0x1300, 0x1301-0x13FF) */
#define CO_CONFIG_SRDO    0
#define CO_CONFIG_LSS     (CO_CONFIG_LSS_SLAVE | CO_CONFIG_GLOBAL_FLAG_CALLBACK_PRE) /* slave only */

#endif /* IMU_CAL_CO_CONFIG_H */

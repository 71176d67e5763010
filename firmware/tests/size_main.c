/*
 * Link-size probe (make -C firmware size): built once with -DWITH_CORE, which calls every
 * public function of the core, and once without; the difference is what the core costs a
 * firmware image, library routines it pulls in (soft double for the range checks) included.
 */
#include "imu_cal.h"

#ifdef WITH_CORE
static imu_cal_t cal;
static imu_cal_block_t block;

int main(void) {
    uint8_t bytes[4] = {0, 0, 0, 0};
    int16_t counts[3] = {1, 2, 3};
    float a[3], w[3];
    imu_cal_bind_block(&cal, &block);
    imu_cal_factory(&cal);
    (void)imu_cal_write(&cal, 0x2100, 1, bytes, sizeof bytes);
    (void)imu_cal_read(&cal, 0x2101, 2, bytes);
    imu_cal_correct(&cal, counts, counts, a, w);
    (void)imu_cal_next_sample(&cal);
    return (int)(a[0] + w[0]) + imu_cal_status(&cal, 0) + imu_cal_odr_ok(200);
}
#else
int main(void) {
    return 0;
}
#endif

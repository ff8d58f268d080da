/* The hardware abstraction the firmware core calls (a board implements these four). See docs/firmware.md. */
#ifndef NFAL_HAL_H
#define NFAL_HAL_H

#include <stddef.h>
#include <stdint.h>

#include "nfal_fw.h"

/* Apply this drive voltage amplitude [V] from now on (DAC -> amplifier -> transducer). */
void hal_drive_write(float volts);
/* Read the height sensor and the tracker, after hal_drive_write of the same tick. */
void hal_sensor_read(nfal_fw_reading *reading);
/* Queue bytes for the host; never blocks (a byte that does not fit is dropped: a rig does not wait for its host). */
void hal_serial_write(const uint8_t *data, size_t n);

/* The other direction: the board's serial RX calls nfal_fw_rx(); its sample timer calls nfal_fw_tick(). */

#endif

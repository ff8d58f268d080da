/* The rig's side of the nfal rig protocol, version 1 (docs/protocol.md): portable C99.
 *
 * All state is in one struct (nfal_fw), no dynamic allocation, fixed-size buffers, no floating-point
 * printf. The firmware talks to the hardware through the few functions of nfal_hal.h. Time is rig time:
 * the tick count k (one tick per sample period); timestamps are k * sample_period_us.
 *
 * Use:
 *   nfal_fw_init(&fw, &config);            once, at power-up
 *   nfal_fw_rx(&fw, bytes, n);             whenever bytes from the host arrive (UART RX interrupt, USB-CDC
 *                                          callback, polling loop); they are only queued here
 *   nfal_fw_tick(&fw);                     once per sample period (the tick interrupt): takes the queued
 *                                          bytes, decides the voltage (hal_drive_write), reads the sensor
 *                                          (hal_sensor_read), and sends MEASUREMENT / RIG_HEARTBEAT / FAULT
 *                                          (hal_serial_write)
 * nfal_fw_rx and nfal_fw_tick may run in different contexts (an RX interrupt and the tick interrupt):
 * the queue is single-producer single-consumer; everything else is touched by nfal_fw_tick only.
 */
#ifndef NFAL_FW_H
#define NFAL_FW_H

#include <stddef.h>
#include <stdint.h>

#include "nfal_frame.h"

#define NFAL_PROTOCOL_VERSION 1u
#define NFAL_MAX_FRAME_BYTES 64u
#define NFAL_MAX_ENCODED_BYTES 65u
/* Bytes from the host queued between two ticks (a power of two). At 2 Mbaud a 0.5 ms tick brings 100 at
 * most, so 256 hold 2.5 ticks' worth and bound the tick's work; the host build, whose emulator may stall on a
 * busy machine, takes 4096. Bytes that do not fit are counted in rx_overflow (and the damaged frames they
 * leave are dropped as the protocol says). */
#ifndef NFAL_FW_RX_BYTES
#define NFAL_FW_RX_BYTES 256u
#endif

enum nfal_type {
    NFAL_HELLO = 0x01, NFAL_DRIVE = 0x02, NFAL_STOP = 0x03, NFAL_HOST_HEARTBEAT = 0x04,
    NFAL_HELLO_ACK = 0x81, NFAL_MEASUREMENT = 0x82, NFAL_RIG_HEARTBEAT = 0x83, NFAL_FAULT = 0x84
};

enum nfal_status {
    NFAL_PLL_LOCKED = 0x0001, NFAL_SESSION_ACTIVE = 0x0002, NFAL_WATCHDOG_TRIPPED = 0x0004,
    NFAL_DRIVE_LIMITED = 0x0008, NFAL_RESTING = 0x0010, NFAL_SENSOR_OUT_OF_RANGE = 0x0020
};

enum nfal_fault {
    NFAL_FAULT_WATCHDOG = 1, NFAL_FAULT_BAD_FRAME = 2, NFAL_FAULT_VERSION_MISMATCH = 3,
    NFAL_FAULT_DRIVE_LIMITED = 4, NFAL_FAULT_SENSOR_RANGE = 5
};

/* The rig's timing and limits, announced in HELLO_ACK. */
typedef struct {
    uint32_t sample_period_us;     /* MEASUREMENT period (the tick) */
    uint32_t watchdog_timeout_us;  /* >= 2 sample periods */
    uint32_t ramp_down_us;
    uint32_t heartbeat_period_us;  /* 100 000 by the protocol */
    float max_drive_voltage;
} nfal_fw_config;

/* What the rig's hardware reports at a tick. */
typedef struct {
    float height;            /* [m] */
    float drive_frequency;   /* [Hz] */
    uint8_t locked;          /* the resonance tracker is locked */
    uint8_t resting;         /* the object rests on the driving surface */
    uint8_t out_of_range;    /* the height sensor is saturated */
} nfal_fw_reading;

/* The receiver's counters, as docs/protocol.md section 5 names them. */
typedef struct {
    uint32_t frames_ok, cobs_errors, crc_errors, truncated, oversized, unknown_type, invalid_value,
        out_of_order, lost;
} nfal_fw_counters;

typedef struct {
    nfal_fw_config config;
    uint32_t watchdog_ticks, ramp_ticks, heartbeat_ticks;
    uint64_t k;                          /* the tick now running, or the next one */
    /* host -> rig: queue (nfal_fw_rx) and the frame being gathered */
    uint8_t rx[NFAL_FW_RX_BYTES];
    volatile uint32_t rx_head, rx_tail;  /* written by nfal_fw_rx / nfal_fw_tick only */
    uint32_t rx_overflow;                /* bytes lost because the queue was full */
    uint8_t chunk[NFAL_MAX_ENCODED_BYTES];
    uint8_t chunk_len, overflowing;
    uint8_t has_last;
    uint32_t last_seq;
    nfal_fw_counters counters;
    /* rig -> host */
    uint32_t tx_seq;
    uint32_t dropped_reported;           /* dropped count at the last BAD_FRAME fault check */
    /* session, drive, watchdog */
    uint8_t session, armed, tripped, limited, ramping;
    float commanded, applied, ramp_from;
    uint32_t command_seq;
    uint64_t last_drive_tick, ramp_start;
    uint16_t last_status;                /* the status word of the last tick (with the reading's flags) */
} nfal_fw;

/* 0 on success, -1 if the config is out of range (zero periods, watchdog < 2 sample periods, ...). */
int nfal_fw_init(nfal_fw *fw, const nfal_fw_config *config);
void nfal_fw_rx(nfal_fw *fw, const uint8_t *data, size_t n);
void nfal_fw_tick(nfal_fw *fw);
uint32_t nfal_fw_dropped(const nfal_fw *fw);


#endif

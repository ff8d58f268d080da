/* The rig's side of the nfal rig protocol (docs/protocol.md); see nfal_fw.h. Mirrors hil/firmware.py. */
#include "nfal_fw.h"

#include <string.h>

#include "nfal_hal.h"

/* Body lengths per host -> rig type (docs/protocol.md section 4). */
#define HELLO_BODY 2u
#define DRIVE_BODY 4u
#define EMPTY_BODY 0u
#define HEADER_BYTES 5u
#define CRC_BYTES 4u

/* ---- little-endian fields ------------------------------------------------------------------------------ */
static void put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static void put_u64(uint8_t *p, uint64_t v) { put_u32(p, (uint32_t)v); put_u32(p + 4, (uint32_t)(v >> 32)); }
static void put_f32(uint8_t *p, float v) { uint32_t u; memcpy(&u, &v, 4); put_u32(p, u); }
static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static float get_f32(const uint8_t *p) { uint32_t u = get_u32(p); float v; memcpy(&v, &u, 4); return v; }
/* finite without math.h (isfinite needs libm on some toolchains): the exponent is not all ones */
static int f32_finite(const uint8_t *p) { return ((get_u32(p) >> 23) & 0xFFu) != 0xFFu; }

/* ---- sending ------------------------------------------------------------------------------------------- */
static void send(nfal_fw *fw, uint8_t type, const uint8_t *body, size_t n) {
    uint8_t frame[NFAL_MAX_FRAME_BYTES], wire[NFAL_MAX_ENCODED_BYTES + 1];
    size_t len = HEADER_BYTES + n, w;
    frame[0] = type;
    put_u32(frame + 1, fw->tx_seq++);
    if (n) memcpy(frame + HEADER_BYTES, body, n);
    put_u32(frame + len, nfal_crc32(frame, len));
    w = nfal_cobs_encode(frame, len + CRC_BYTES, wire);
    wire[w++] = 0;
    hal_serial_write(wire, w);
}

static uint64_t now_us(const nfal_fw *fw) { return fw->k * (uint64_t)fw->config.sample_period_us; }

static void send_fault(nfal_fw *fw, uint16_t code, float detail) {
    uint8_t body[14];
    put_u64(body, now_us(fw));
    put_u16(body + 8, code);
    put_f32(body + 10, detail);
    send(fw, NFAL_FAULT, body, sizeof body);
}

/* ---- setup --------------------------------------------------------------------------------------------- */
static uint32_t ticks_rounded(uint32_t us, uint32_t period) {
    uint32_t t = (uint32_t)(((uint64_t)us + period / 2u) / period);
    return t ? t : 1u;
}

int nfal_fw_init(nfal_fw *fw, const nfal_fw_config *config) {
    const nfal_fw_config *c = config;
    if (!c->sample_period_us || !c->watchdog_timeout_us || !c->ramp_down_us || !c->heartbeat_period_us ||
        !(c->max_drive_voltage > 0.0f) || c->max_drive_voltage > 3.4e38f ||
        c->watchdog_timeout_us / 2u < c->sample_period_us)
        return -1;
    memset(fw, 0, sizeof *fw);
    fw->config = *c;
    fw->watchdog_ticks = (uint32_t)(((uint64_t)c->watchdog_timeout_us + c->sample_period_us - 1u) / c->sample_period_us);
    fw->ramp_ticks = ticks_rounded(c->ramp_down_us, c->sample_period_us);
    fw->heartbeat_ticks = ticks_rounded(c->heartbeat_period_us, c->sample_period_us);
    return 0;
}

uint32_t nfal_fw_dropped(const nfal_fw *fw) {
    const nfal_fw_counters *c = &fw->counters;
    return c->cobs_errors + c->crc_errors + c->truncated + c->oversized + c->unknown_type + c->invalid_value +
           c->out_of_order;
}

void nfal_fw_rx(nfal_fw *fw, const uint8_t *data, size_t n) {
    uint32_t head = fw->rx_head;
    while (n--) {
        if (head - fw->rx_tail >= NFAL_FW_RX_BYTES) {
            fw->rx_overflow += (uint32_t)(n + 1);
            break;
        }
        fw->rx[head % NFAL_FW_RX_BYTES] = *data++;
        head++;
    }
    fw->rx_head = head;
}

/* ---- messages (section 7) -------------------------------------------------------------------------------- */
static void start_ramp(nfal_fw *fw) {
    fw->ramping = 1;
    fw->ramp_start = fw->k;
    fw->ramp_from = fw->applied;
    fw->commanded = 0.0f;
}

static void on_hello(nfal_fw *fw, uint16_t version) {
    uint8_t body[18];
    if (version != NFAL_PROTOCOL_VERSION) {
        send_fault(fw, NFAL_FAULT_VERSION_MISMATCH, (float)version);
        return;
    }
    fw->tx_seq = 0;
    if (fw->tripped) fw->armed = 0; /* cleared: 0 V (after the ramp) until the next DRIVE */
    fw->session = 1;
    fw->tripped = 0;
    fw->limited = 0;
    put_u16(body, NFAL_PROTOCOL_VERSION);
    put_u32(body + 2, fw->config.sample_period_us);
    put_u32(body + 6, fw->config.watchdog_timeout_us);
    put_u32(body + 10, fw->config.ramp_down_us);
    put_f32(body + 14, fw->config.max_drive_voltage);
    send(fw, NFAL_HELLO_ACK, body, sizeof body);
}

static void on_drive(nfal_fw *fw, float volts, uint32_t seq) {
    int limited;
    if (!fw->session || fw->tripped) return;
    limited = volts > fw->config.max_drive_voltage;
    if (limited && !fw->limited) send_fault(fw, NFAL_FAULT_DRIVE_LIMITED, volts);
    fw->limited = (uint8_t)limited;
    fw->commanded = limited ? fw->config.max_drive_voltage : volts;
    fw->command_seq = seq;
    fw->last_drive_tick = fw->k;
    fw->armed = 1;
    fw->ramping = 0;
}

static void on_stop(nfal_fw *fw) {
    if (fw->session && !fw->ramping) start_ramp(fw); /* a running ramp (a trip's) runs on as it is */
    fw->session = 0;
    fw->armed = 0;
}

/* ---- receiving (section 5): one chunk between two delimiters ------------------------------------------ */
static void take_chunk(nfal_fw *fw, const uint8_t *chunk, size_t n) {
    nfal_fw_counters *c = &fw->counters;
    uint8_t frame[NFAL_MAX_ENCODED_BYTES];
    int len;
    uint8_t type;
    uint32_t seq;
    size_t body, want;
    if (n > NFAL_MAX_ENCODED_BYTES) { c->oversized++; return; }
    len = nfal_cobs_decode(chunk, n, frame);
    if (len < 0) { c->cobs_errors++; return; }
    if (len < (int)(HEADER_BYTES + CRC_BYTES)) { c->truncated++; return; }
    if (len > (int)NFAL_MAX_FRAME_BYTES) { c->oversized++; return; }
    body = (size_t)len - HEADER_BYTES - CRC_BYTES;
    if (nfal_crc32(frame, (size_t)len - CRC_BYTES) != get_u32(frame + len - CRC_BYTES)) { c->crc_errors++; return; }
    type = frame[0];
    seq = get_u32(frame + 1);
    switch (type) {
    case NFAL_HELLO: want = HELLO_BODY; break;
    case NFAL_DRIVE: want = DRIVE_BODY; break;
    case NFAL_STOP: case NFAL_HOST_HEARTBEAT: want = EMPTY_BODY; break;
    default: c->unknown_type++; return;
    }
    if (body != want) {
        if (body < want) c->truncated++; else c->oversized++;
        return;
    }
    if (type == NFAL_DRIVE) {
        const uint8_t *v = frame + HEADER_BYTES;
        if (!f32_finite(v) || get_f32(v) < 0.0f) { c->invalid_value++; return; } /* -0.0 >= 0: valid */
    }
    if (type == NFAL_HELLO) {
        fw->has_last = 0;
    } else if (fw->has_last && !nfal_seq_newer(seq, fw->last_seq)) {
        c->out_of_order++;
        return;
    }
    if (fw->has_last) c->lost += seq - fw->last_seq - 1u;
    fw->has_last = 1;
    fw->last_seq = seq;
    c->frames_ok++;
    switch (type) {
    case NFAL_HELLO: on_hello(fw, get_u16(frame + HEADER_BYTES)); break;
    case NFAL_DRIVE: on_drive(fw, get_f32(frame + HEADER_BYTES), seq); break;
    case NFAL_STOP: on_stop(fw); break;
    default: break; /* HOST_HEARTBEAT: nothing */
    }
}

static void take_byte(nfal_fw *fw, uint8_t b) {
    if (b == 0) {
        if (fw->overflowing) fw->overflowing = 0; /* the tail of an oversized frame (already counted) */
        else if (fw->chunk_len) take_chunk(fw, fw->chunk, fw->chunk_len);
        fw->chunk_len = 0;
    } else if (!fw->overflowing) {
        if (fw->chunk_len == NFAL_MAX_ENCODED_BYTES) { /* the 66th byte: count once, discard to the next 0x00 */
            fw->counters.oversized++;
            fw->overflowing = 1;
            fw->chunk_len = 0;
        } else {
            fw->chunk[fw->chunk_len++] = b;
        }
    }
}

/* ---- the tick ------------------------------------------------------------------------------------------ */
static void decide_voltage(nfal_fw *fw) {
    if (fw->armed && !fw->tripped && fw->k - fw->last_drive_tick >= fw->watchdog_ticks) {
        uint64_t silent = fw->k - fw->last_drive_tick;
        fw->tripped = 1;
        send_fault(fw, NFAL_FAULT_WATCHDOG, (float)(silent * fw->config.sample_period_us) / 1e6f);
        start_ramp(fw);
    }
    if (fw->ramping) {
        uint64_t j = fw->k - fw->ramp_start;
        if (j >= fw->ramp_ticks) {
            fw->applied = 0.0f;
            fw->ramping = 0;
            fw->commanded = 0.0f;
        } else {
            fw->applied = fw->ramp_from * (1.0f - (float)j / (float)fw->ramp_ticks);
        }
    } else if (fw->armed && !fw->tripped) {
        fw->applied = fw->commanded;
    } else {
        fw->applied = 0.0f;
    }
}

static uint16_t status_word(const nfal_fw *fw, const nfal_fw_reading *r) {
    uint16_t s = 0;
    if (fw->session) s |= NFAL_SESSION_ACTIVE;
    if (fw->tripped) s |= NFAL_WATCHDOG_TRIPPED;
    if (fw->limited) s |= NFAL_DRIVE_LIMITED;
    if (r->locked) s |= NFAL_PLL_LOCKED;
    if (r->resting) s |= NFAL_RESTING;
    if (r->out_of_range) s |= NFAL_SENSOR_OUT_OF_RANGE;
    return s;
}

void nfal_fw_tick(nfal_fw *fw) {
    nfal_fw_reading r;
    uint32_t dropped;
    uint32_t head = fw->rx_head, tail = fw->rx_tail;
    uint8_t body[26];
    while (tail != head) take_byte(fw, fw->rx[tail++ % NFAL_FW_RX_BYTES]);
    fw->rx_tail = tail;
    dropped = nfal_fw_dropped(fw);
    if (dropped != fw->dropped_reported) {
        fw->dropped_reported = dropped;
        send_fault(fw, NFAL_FAULT_BAD_FRAME, (float)dropped);
    }
    decide_voltage(fw);
    hal_drive_write(fw->applied);
    memset(&r, 0, sizeof r);
    hal_sensor_read(&r);
    fw->last_status = status_word(fw, &r);
    if (fw->session) {
        put_u64(body, now_us(fw));
        put_f32(body + 8, r.height);
        put_f32(body + 12, r.drive_frequency);
        put_f32(body + 16, fw->applied);
        put_u16(body + 20, fw->last_status);
        put_u32(body + 22, fw->command_seq);
        send(fw, NFAL_MEASUREMENT, body, 26);
    }
    if (fw->k % fw->heartbeat_ticks == 0) {
        put_u64(body, now_us(fw));
        put_u16(body + 8, fw->last_status);
        put_u32(body + 10, fw->counters.frames_ok);
        put_u32(body + 14, dropped);
        send(fw, NFAL_RIG_HEARTBEAT, body, 18);
    }
    fw->k++;
}

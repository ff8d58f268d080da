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

/* ---- CRC-32/ISO-HDLC, table-driven (1 KB of flash; one lookup a byte) ----------------------------------- */
static const uint32_t crc_table[256] = {
    0x00000000u, 0x77073096u, 0xEE0E612Cu, 0x990951BAu, 0x076DC419u, 0x706AF48Fu, 0xE963A535u, 0x9E6495A3u,
    0x0EDB8832u, 0x79DCB8A4u, 0xE0D5E91Eu, 0x97D2D988u, 0x09B64C2Bu, 0x7EB17CBDu, 0xE7B82D07u, 0x90BF1D91u,
    0x1DB71064u, 0x6AB020F2u, 0xF3B97148u, 0x84BE41DEu, 0x1ADAD47Du, 0x6DDDE4EBu, 0xF4D4B551u, 0x83D385C7u,
    0x136C9856u, 0x646BA8C0u, 0xFD62F97Au, 0x8A65C9ECu, 0x14015C4Fu, 0x63066CD9u, 0xFA0F3D63u, 0x8D080DF5u,
    0x3B6E20C8u, 0x4C69105Eu, 0xD56041E4u, 0xA2677172u, 0x3C03E4D1u, 0x4B04D447u, 0xD20D85FDu, 0xA50AB56Bu,
    0x35B5A8FAu, 0x42B2986Cu, 0xDBBBC9D6u, 0xACBCF940u, 0x32D86CE3u, 0x45DF5C75u, 0xDCD60DCFu, 0xABD13D59u,
    0x26D930ACu, 0x51DE003Au, 0xC8D75180u, 0xBFD06116u, 0x21B4F4B5u, 0x56B3C423u, 0xCFBA9599u, 0xB8BDA50Fu,
    0x2802B89Eu, 0x5F058808u, 0xC60CD9B2u, 0xB10BE924u, 0x2F6F7C87u, 0x58684C11u, 0xC1611DABu, 0xB6662D3Du,
    0x76DC4190u, 0x01DB7106u, 0x98D220BCu, 0xEFD5102Au, 0x71B18589u, 0x06B6B51Fu, 0x9FBFE4A5u, 0xE8B8D433u,
    0x7807C9A2u, 0x0F00F934u, 0x9609A88Eu, 0xE10E9818u, 0x7F6A0DBBu, 0x086D3D2Du, 0x91646C97u, 0xE6635C01u,
    0x6B6B51F4u, 0x1C6C6162u, 0x856530D8u, 0xF262004Eu, 0x6C0695EDu, 0x1B01A57Bu, 0x8208F4C1u, 0xF50FC457u,
    0x65B0D9C6u, 0x12B7E950u, 0x8BBEB8EAu, 0xFCB9887Cu, 0x62DD1DDFu, 0x15DA2D49u, 0x8CD37CF3u, 0xFBD44C65u,
    0x4DB26158u, 0x3AB551CEu, 0xA3BC0074u, 0xD4BB30E2u, 0x4ADFA541u, 0x3DD895D7u, 0xA4D1C46Du, 0xD3D6F4FBu,
    0x4369E96Au, 0x346ED9FCu, 0xAD678846u, 0xDA60B8D0u, 0x44042D73u, 0x33031DE5u, 0xAA0A4C5Fu, 0xDD0D7CC9u,
    0x5005713Cu, 0x270241AAu, 0xBE0B1010u, 0xC90C2086u, 0x5768B525u, 0x206F85B3u, 0xB966D409u, 0xCE61E49Fu,
    0x5EDEF90Eu, 0x29D9C998u, 0xB0D09822u, 0xC7D7A8B4u, 0x59B33D17u, 0x2EB40D81u, 0xB7BD5C3Bu, 0xC0BA6CADu,
    0xEDB88320u, 0x9ABFB3B6u, 0x03B6E20Cu, 0x74B1D29Au, 0xEAD54739u, 0x9DD277AFu, 0x04DB2615u, 0x73DC1683u,
    0xE3630B12u, 0x94643B84u, 0x0D6D6A3Eu, 0x7A6A5AA8u, 0xE40ECF0Bu, 0x9309FF9Du, 0x0A00AE27u, 0x7D079EB1u,
    0xF00F9344u, 0x8708A3D2u, 0x1E01F268u, 0x6906C2FEu, 0xF762575Du, 0x806567CBu, 0x196C3671u, 0x6E6B06E7u,
    0xFED41B76u, 0x89D32BE0u, 0x10DA7A5Au, 0x67DD4ACCu, 0xF9B9DF6Fu, 0x8EBEEFF9u, 0x17B7BE43u, 0x60B08ED5u,
    0xD6D6A3E8u, 0xA1D1937Eu, 0x38D8C2C4u, 0x4FDFF252u, 0xD1BB67F1u, 0xA6BC5767u, 0x3FB506DDu, 0x48B2364Bu,
    0xD80D2BDAu, 0xAF0A1B4Cu, 0x36034AF6u, 0x41047A60u, 0xDF60EFC3u, 0xA867DF55u, 0x316E8EEFu, 0x4669BE79u,
    0xCB61B38Cu, 0xBC66831Au, 0x256FD2A0u, 0x5268E236u, 0xCC0C7795u, 0xBB0B4703u, 0x220216B9u, 0x5505262Fu,
    0xC5BA3BBEu, 0xB2BD0B28u, 0x2BB45A92u, 0x5CB36A04u, 0xC2D7FFA7u, 0xB5D0CF31u, 0x2CD99E8Bu, 0x5BDEAE1Du,
    0x9B64C2B0u, 0xEC63F226u, 0x756AA39Cu, 0x026D930Au, 0x9C0906A9u, 0xEB0E363Fu, 0x72076785u, 0x05005713u,
    0x95BF4A82u, 0xE2B87A14u, 0x7BB12BAEu, 0x0CB61B38u, 0x92D28E9Bu, 0xE5D5BE0Du, 0x7CDCEFB7u, 0x0BDBDF21u,
    0x86D3D2D4u, 0xF1D4E242u, 0x68DDB3F8u, 0x1FDA836Eu, 0x81BE16CDu, 0xF6B9265Bu, 0x6FB077E1u, 0x18B74777u,
    0x88085AE6u, 0xFF0F6A70u, 0x66063BCAu, 0x11010B5Cu, 0x8F659EFFu, 0xF862AE69u, 0x616BFFD3u, 0x166CCF45u,
    0xA00AE278u, 0xD70DD2EEu, 0x4E048354u, 0x3903B3C2u, 0xA7672661u, 0xD06016F7u, 0x4969474Du, 0x3E6E77DBu,
    0xAED16A4Au, 0xD9D65ADCu, 0x40DF0B66u, 0x37D83BF0u, 0xA9BCAE53u, 0xDEBB9EC5u, 0x47B2CF7Fu, 0x30B5FFE9u,
    0xBDBDF21Cu, 0xCABAC28Au, 0x53B39330u, 0x24B4A3A6u, 0xBAD03605u, 0xCDD70693u, 0x54DE5729u, 0x23D967BFu,
    0xB3667A2Eu, 0xC4614AB8u, 0x5D681B02u, 0x2A6F2B94u, 0xB40BBE37u, 0xC30C8EA1u, 0x5A05DF1Bu, 0x2D02EF8Du};

uint32_t nfal_crc32(const uint8_t *p, size_t n) {
    uint32_t crc = 0xFFFFFFFFu;
    while (n--) crc = (crc >> 8) ^ crc_table[(crc ^ *p++) & 0xFFu];
    return crc ^ 0xFFFFFFFFu;
}

/* ---- COBS (section 2.3) ------------------------------------------------------------------------------ */
size_t nfal_cobs_encode(const uint8_t *in, size_t n, uint8_t *out) {
    size_t code_at = 0, o = 1, i;
    for (i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_at] = (uint8_t)(o - code_at);
            code_at = o++;
        } else {
            out[o++] = in[i];
        }
    }
    out[code_at] = (uint8_t)(o - code_at);
    return o;
}

int nfal_cobs_decode(const uint8_t *in, size_t n, uint8_t *out) {
    size_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = in[i++], k;
        if (code == 0 || i + code - 1 > n) return -1;
        for (k = 1; k < code; k++) out[o++] = in[i++];
        if (code != 0xFF && i < n) out[o++] = 0;
    }
    return (int)o;
}

int nfal_seq_newer(uint32_t seq, uint32_t last) {
    uint32_t d = seq - last;
    return d != 0u && d < 0x80000000u;
}

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

/* The plant channel server: nfal_hal.h implemented over the emulator's byte stream (see nfal_plant.h). */
#include "nfal_plant.h"

#include <string.h>

#include "nfal_hal.h"

#define TUNNEL_BYTES 2048u

static nfal_fw fw;
static struct {
    uint8_t tunnel, configured;
    uint8_t out[TUNNEL_BYTES];
    uint16_t out_len;
    uint32_t tx_dropped, tx_frames, cost_max, paused_at, waited;
} plant;

static void put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}
static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static float get_f32(const uint8_t *p) { uint32_t u = get_u32(p); float v; memcpy(&v, &u, 4); return v; }

void hal_drive_write(float volts) {
    uint8_t rec[5];
    rec[0] = 'D';
    memcpy(rec + 1, &volts, 4); /* both ends are little-endian IEEE-754 (x86-64, Cortex-M) */
    plant.paused_at = plat_cycles();
    plat_plant_write(rec, sizeof rec);
}

void hal_sensor_read(nfal_fw_reading *r) {
    uint8_t rec[10];
    plat_plant_read(rec, sizeof rec);
    if (rec[0] == 'S') {
        r->height = get_f32(rec + 1);
        r->drive_frequency = get_f32(rec + 5);
        r->locked = (uint8_t)(rec[9] & 1u);
        r->resting = (uint8_t)((rec[9] >> 1) & 1u);
        r->out_of_range = (uint8_t)((rec[9] >> 2) & 1u);
    }
    plant.waited += plat_cycles() - plant.paused_at;
}

void hal_serial_write(const uint8_t *data, size_t n) {
    plant.tx_frames++; /* the core writes one frame a call */
    if (plant.tunnel) {
        size_t room = TUNNEL_BYTES - plant.out_len, take = n < room ? n : room;
        memcpy(plant.out + plant.out_len, data, take);
        plant.out_len = (uint16_t)(plant.out_len + take);
        plant.tx_dropped += (uint32_t)(n - take);
    } else {
        plant.tx_dropped += (uint32_t)(n - plat_serial_send(data, n));
    }
}

static void configure(void) {
    uint8_t rec[21], ok;
    nfal_fw_config c;
    plat_plant_read(rec, sizeof rec);
    c.sample_period_us = get_u32(rec);
    c.watchdog_timeout_us = get_u32(rec + 4);
    c.ramp_down_us = get_u32(rec + 8);
    c.heartbeat_period_us = get_u32(rec + 12);
    c.max_drive_voltage = get_f32(rec + 16);
    ok = (uint8_t)(nfal_fw_init(&fw, &c) == 0);
    plant.configured = ok;
    plant.tunnel = rec[20] ? 1u : 0u;
    plant.tx_dropped = plant.tx_frames = plant.cost_max = 0;
    {
        uint8_t reply[2] = {'R', 0};
        reply[1] = ok;
        plat_plant_write(reply, 2);
    }
}

static void tick(void) {
    static uint8_t in[TUNNEL_BYTES];
    uint8_t head[2], end[18];
    uint16_t n;
    uint32_t start, cost;
    plat_plant_read(head, 2);
    n = (uint16_t)(head[0] | (head[1] << 8));
    if (n > TUNNEL_BYTES) n = TUNNEL_BYTES; /* the emulator never sends more */
    plat_plant_read(in, n);
    if (!plant.configured) return; /* the emulator configures first ('R' said whether it took) */
    start = plat_cycles();
    plant.waited = 0;
    plant.out_len = 0;
    if (plant.tunnel) nfal_fw_rx(&fw, in, n);
    else plat_serial_poll(&fw);
    nfal_fw_tick(&fw);
    cost = plat_cycles() - start - plant.waited;
    if (cost > plant.cost_max) plant.cost_max = cost;
    end[0] = 'E';
    put_u32(end + 1, cost);
    end[5] = (uint8_t)fw.last_status;
    end[6] = (uint8_t)(fw.last_status >> 8);
    memcpy(end + 7, &fw.applied, 4);
    put_u32(end + 11, fw.command_seq);
    end[15] = (uint8_t)(fw.armed | (fw.ramping << 1));
    end[16] = (uint8_t)plant.out_len;
    end[17] = (uint8_t)(plant.out_len >> 8);
    plat_plant_write(end, sizeof end);
    if (plant.out_len) plat_plant_write(plant.out, plant.out_len);
}

static void counters(void) {
    uint8_t rec[1 + 13 * 4];
    const nfal_fw_counters *c = &fw.counters;
    uint32_t v[13];
    int i;
    v[0] = c->frames_ok; v[1] = c->cobs_errors; v[2] = c->crc_errors; v[3] = c->truncated; v[4] = c->oversized;
    v[5] = c->unknown_type; v[6] = c->invalid_value; v[7] = c->out_of_order; v[8] = c->lost;
    v[9] = fw.rx_overflow; v[10] = plant.tx_dropped; v[11] = plant.cost_max; v[12] = plant.tx_frames;
    rec[0] = 'k';
    for (i = 0; i < 13; i++) put_u32(rec + 1 + 4 * i, v[i]);
    plat_plant_write(rec, sizeof rec);
}

void nfal_plant_serve(void) {
    uint8_t cmd;
    for (;;) {
        plat_plant_read(&cmd, 1);
        switch (cmd) {
        case 'C': configure(); break;
        case 'T': tick(); break;
        case 'K': counters(); break;
        default: break; /* idle fill or garbage: the emulator resynchronises with 'C' */
        }
    }
}

/* See nfal_loop.h. The receiver mirrors hil/protocol.py's FrameDecoder (host side), the sender its encode(). */
#define _GNU_SOURCE
#include "nfal_loop.h"

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <string.h>
#include <sys/ioctl.h>
#include <time.h>
#include <unistd.h>

#include "../core/nfal_fw.h"

#define HEADER_BYTES 5u
#define CRC_BYTES 4u
#define READ_CHUNK 4096u
/* With no bytes for this long [s], a step reads the port even if it says it holds none (see take_in). */
#define PROBE_AFTER_S 2e-3

double nfal_loop_clock(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static uint64_t get_u64(const uint8_t *p) { return (uint64_t)get_u32(p) | ((uint64_t)get_u32(p + 4) << 32); }
static float get_f32(const uint8_t *p) { uint32_t u = get_u32(p); float v; memcpy(&v, &u, 4); return v; }
static int f32_finite(const uint8_t *p) { return ((get_u32(p) >> 23) & 0xFFu) != 0xFFu; }
static void put_u32(uint8_t *p, uint32_t v) {
    p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); p[2] = (uint8_t)(v >> 16); p[3] = (uint8_t)(v >> 24);
}

/* ---- receiving: FrameDecoder._decode for the rig's four types ---------------------------------------------- */
typedef struct {
    nfal_loop_link *link;
    uint8_t chunk[NFAL_MAX_ENCODED_BYTES];
    uint32_t chunk_len, overflowing, hello_ack;
    double last_bytes;  /* when bytes last came in */
} receiver;

static uint32_t body_bytes(uint8_t type) {
    switch (type) {
    case NFAL_HELLO_ACK: return 18u;
    case NFAL_MEASUREMENT: return 26u;
    case NFAL_RIG_HEARTBEAT: return 18u;
    case NFAL_FAULT: return 14u;
    default: return 0u;
    }
}

static void take_frame(receiver *r, double now) {
    nfal_loop_link *l = r->link;
    uint8_t frame[NFAL_MAX_ENCODED_BYTES];
    const uint8_t *body = frame + HEADER_BYTES;
    int len = nfal_cobs_decode(r->chunk, r->chunk_len, frame);
    uint32_t want, seq, n;
    uint8_t type;
    if (len < 0 || len < (int)(HEADER_BYTES + CRC_BYTES) || len > (int)NFAL_MAX_FRAME_BYTES
        || nfal_crc32(frame, (size_t)len - CRC_BYTES) != get_u32(frame + len - CRC_BYTES)) {
        l->frames_dropped++;  /* COBS, length or CRC: damaged bytes */
        return;
    }
    type = frame[0], seq = get_u32(frame + 1), want = body_bytes(type), n = (uint32_t)len - HEADER_BYTES - CRC_BYTES;
    if (!want || n != want) { l->frames_dropped++; return; }
    if ((type == NFAL_MEASUREMENT && !(f32_finite(body + 8) && f32_finite(body + 12) && f32_finite(body + 16)))
        || (type == NFAL_HELLO_ACK && !f32_finite(body + 14)) || (type == NFAL_FAULT && !f32_finite(body + 10))) {
        l->frames_dropped++;  /* an intact frame with a value that is not finite */
        return;
    }
    if (type == NFAL_HELLO_ACK) {
        l->has_last_seq = 0;
        r->hello_ack = 1;     /* a new session the loop did not open: the rig restarted */
    } else if (l->has_last_seq && !nfal_seq_newer(seq, l->last_seq)) {
        l->frames_dropped++;  /* out of order */
        return;
    }
    if (l->has_last_seq) l->frames_lost += seq - l->last_seq - 1u;
    l->has_last_seq = 1, l->last_seq = seq;
    if (type == NFAL_MEASUREMENT) {
        l->rig_time_s = (double)get_u64(body) * 1e-6;
        l->height_m = (double)get_f32(body + 8);
        l->drive_frequency_hz = (double)get_f32(body + 12);
        l->applied_voltage_v = (double)get_f32(body + 16);
        l->status = (uint32_t)(body[20] | (body[21] << 8));
        l->command_seq = get_u32(body + 22);
        l->arrival_s = now;
        l->measurements++;
    } else if (type == NFAL_FAULT) {
        l->rig_faults++;
    }
}

static void take_bytes(receiver *r, const uint8_t *data, size_t n, double now) {
    size_t i;
    for (i = 0; i < n; i++) {
        uint8_t b = data[i];
        if (r->link->skip_to_delimiter) {
            r->link->skip_to_delimiter = b != 0;
        } else if (b == 0) {
            if (r->overflowing) r->overflowing = 0;
            else if (r->chunk_len) take_frame(r, now);
            r->chunk_len = 0;
        } else if (!r->overflowing) {
            if (r->chunk_len == NFAL_MAX_ENCODED_BYTES) {
                r->link->frames_dropped++;  /* oversized: counted once, discarded to the next 0x00 */
                r->overflowing = 1;
                r->chunk_len = 0;
            } else {
                r->chunk[r->chunk_len++] = b;
            }
        }
    }
}

/* What the port holds, without waiting; -1 on a failed read (errno kept), 0 otherwise. A tty in raw mode (VMIN 0)
 * reads 0 bytes when it has none; anything else that reads 0 has been closed at the other end.
 * A tty's read that finds no bytes first waits for the kernel worker that moves bytes already received into it
 * (n_tty_read's flush_work): a thread of normal priority, so a real-time loop reading would wait behind whatever
 * runs beside it. Unless `probe`, a tty that says it holds nothing (FIONREAD) is not read: bytes still on their way
 * are taken at the next step. The loop probes when none came for PROBE_AFTER_S, and so still sees a port that failed
 * (the read's error) whatever FIONREAD says. */
static int take_in(receiver *r, int fd, int tty, int probe) {
    uint8_t data[READ_CHUNK];
    for (;;) {
        ssize_t got;
        int waiting = 0;
        if (tty && !probe && ioctl(fd, FIONREAD, &waiting) == 0 && waiting == 0) return 0;
        got = read(fd, data, sizeof data);
        if (got > 0) {
            r->last_bytes = nfal_loop_clock();
            take_bytes(r, data, (size_t)got, r->last_bytes);
            if ((size_t)got < sizeof data) return 0;
        } else if (got == 0) {
            if (tty) return 0;
            errno = EPIPE;
            return -1;
        } else {
            return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR ? 0 : -1;
        }
    }
}

/* Lockstep: take in until the newest measurement reports DRIVE `seq` applied; 0, -1 (a failed read), or 1 (none within
 * timeout_s). */
static int await_answer(receiver *r, int fd, int tty, uint32_t seq, double timeout_s) {
    double deadline = nfal_loop_clock() + timeout_s;
    for (;;) {
        struct pollfd p;
        double left;
        if (take_in(r, fd, tty, 1) != 0) return -1;  /* lockstep waits for the answer anyway */
        if (r->link->measurements && r->link->command_seq == seq) return 0;
        left = deadline - nfal_loop_clock();
        if (left <= 0.0 || r->hello_ack) return 1;
        p.fd = fd, p.events = POLLIN, p.revents = 0;
        poll(&p, 1, (int)(left * 1e3) + 1);
    }
}

/* ---- sending: DRIVE as hil/protocol.py's encode(Drive(v), seq) ---------------------------------------------- */
static int send_drive(int fd, uint32_t seq, double voltage) {
    uint8_t frame[HEADER_BYTES + 4u + CRC_BYTES], wire[NFAL_MAX_ENCODED_BYTES + 1];
    float v = (float)voltage;
    uint32_t u;
    size_t n;
    ssize_t written;
    frame[0] = NFAL_DRIVE;
    put_u32(frame + 1, seq);
    memcpy(&u, &v, 4);
    put_u32(frame + HEADER_BYTES, u);
    put_u32(frame + HEADER_BYTES + 4u, nfal_crc32(frame, HEADER_BYTES + 4u));
    n = nfal_cobs_encode(frame, sizeof frame, wire);
    wire[n++] = 0;
    written = write(fd, wire, n);
    if (written < 0) return errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR ? 0 : -1;
    return (size_t)written == n;  /* a port that took part of it: not sent whole (the rig drops the damaged frame) */
}

/* ---- the loop ------------------------------------------------------------------------------------------------- */
static void wait_until(double deadline, double spin_s) {
    double sleep_to = deadline - spin_s;
    struct timespec t;
    if (sleep_to > nfal_loop_clock()) {
        t.tv_sec = (time_t)sleep_to;
        t.tv_nsec = (long)((sleep_to - (double)t.tv_sec) * 1e9);
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &t, NULL) == EINTR) {}
    }
    while (nfal_loop_clock() < deadline) {}
}

/* Row k + 1: the law on the newest measurement, and the proxy's outputs. 0, or the reason to end. */
static int next_row(const nfal_loop_config *c, const nfal_law_params *law, nfal_law_state *state,
                    const nfal_loop_link *l, uint64_t row, uint64_t seen, nfal_loop_row *out) {
    double now = nfal_loop_clock();
    out->reference_m = c->reference_m[row];
    out->height_m = l->height_m, out->drive_frequency_hz = l->drive_frequency_hz;
    out->applied_voltage_v = l->applied_voltage_v, out->rig_time_s = l->rig_time_s, out->status = l->status;
    out->measurement_age_s = now - l->arrival_s;
    out->samples_missed = (uint32_t)(out->measurement_age_s * c->sample_rate_hz);
    out->fresh = l->measurements != seen;
    out->frames_dropped = l->frames_dropped, out->frames_lost = l->frames_lost, out->rig_faults = l->rig_faults;
    if (nfal_law_step(law, state, out->reference_m, out->height_m, &out->command_m) != 0) return NFAL_LOOP_LAW_INPUT;
    out->voltage_v = out->command_m / c->metres_per_volt;
    return 0;
}

int nfal_loop_run(const nfal_loop_config *c, const nfal_law_params *law, nfal_law_state *state,
                  nfal_loop_link *link, nfal_loop_shared *shared) {
    receiver r;
    nfal_loop_row row;
    uint64_t k;
    double last_drive = 0.0, gap = 0.0;
    int flags = fcntl(c->fd, F_GETFL), end = NFAL_LOOP_DONE, tty = isatty(c->fd);
    sigset_t all, before;
    struct sched_param was;
    int policy = -1;
    sigfillset(&all);
    pthread_sigmask(SIG_BLOCK, &all, &before);  /* signals go to Python's main thread, which sets `stop` */
    memset(&r, 0, sizeof r);
    memset(&row, 0, sizeof row);
    r.link = link;
    if (c->ring_size == 0 || (c->ring_size & (c->ring_size - 1)) != 0 || flags < 0
        || fcntl(c->fd, F_SETFL, flags | O_NONBLOCK) != 0) {
        end = NFAL_LOOP_SETUP;
        goto done;
    }
    if (c->rt_priority > 0) {
        struct sched_param p;
        memset(&p, 0, sizeof p);
        p.sched_priority = c->rt_priority;
        if (pthread_getschedparam(pthread_self(), &policy, &was) != 0) policy = -1;
        if (pthread_setschedparam(pthread_self(), SCHED_FIFO, &p) != 0) {
            policy = -1;
            end = NFAL_LOOP_SETUP;
            goto done;
        }
    }
    if (next_row(c, law, state, link, 0, link->measurements - 1u, &row) != 0) {
        end = NFAL_LOOP_LAW_INPUT;
        goto done;
    }
    row.samples_missed = 0;  /* as the HardwareProxy's set-up publishes its first sample */
    c->ring[0] = row;
    __atomic_store_n(&shared->rows_written, 1u, __ATOMIC_RELEASE);
    shared->start_s = nfal_loop_clock();
    for (k = 0; k < c->steps; k++) {
        double release = c->lockstep ? nfal_loop_clock() : shared->start_s + (double)k * c->period_s, started, now;
        uint64_t seen = link->measurements;
        int sent;
        if (shared->stop) { end = NFAL_LOOP_STOPPED; break; }
        if (!c->lockstep) wait_until(release, c->spin_s);
        started = nfal_loop_clock();
        sent = send_drive(c->fd, link->next_drive_seq, row.voltage_v);
        if (sent < 0) { shared->error_number = errno; end = NFAL_LOOP_PORT; break; }
        if (sent) {
            link->next_drive_seq++;
            now = nfal_loop_clock();
            gap = last_drive > 0.0 ? now - last_drive : 0.0;
            last_drive = now;
        }
        if (c->lockstep && sent) {
            int answer = await_answer(&r, c->fd, tty, link->next_drive_seq - 1u, c->answer_timeout_s);
            if (answer < 0) { shared->error_number = errno; end = NFAL_LOOP_PORT; break; }
            if (answer > 0 && !r.hello_ack) { end = NFAL_LOOP_NO_ANSWER; break; }
        } else if (take_in(&r, c->fd, tty, nfal_loop_clock() - r.last_bytes > PROBE_AFTER_S) != 0) {
            shared->error_number = errno;
            end = NFAL_LOOP_PORT;
            break;
        }
        if (r.hello_ack) { end = NFAL_LOOP_RESTARTED; break; }
        {
            nfal_loop_row next;
            uint64_t written = shared->rows_written;
            int refused;
            memset(&next, 0, sizeof next);
            next.drive_sent = (uint32_t)sent, next.drive_gap_s = sent ? gap : 0.0;
            next.lateness_s = started - release;
            refused = next_row(c, law, state, link, k + 1u, seen, &next);
            if (c->lockstep) {  /* in rig time: the ticks between two answers, less one */
                double ticks = k == 0 ? 1.0 : (next.rig_time_s - row.rig_time_s) * c->sample_rate_hz;
                long whole = (long)(ticks + (ticks >= 0 ? 0.5 : -0.5));
                next.samples_missed = whole > 1 ? (uint32_t)(whole - 1) : 0u;
            }
            now = nfal_loop_clock();
            next.duration_s = now - started;
            /* a step that fails writes no row, as the master's run of the FMUs: the proxy's step raises on a trip or
               a silence, the Controller's outputs on a measurement its law refuses */
            if (refused) { end = refused; break; }
            if (next.status & NFAL_WATCHDOG_TRIPPED) { end = NFAL_LOOP_WATCHDOG; break; }
            if (next.samples_missed > c->max_missed_samples) { end = NFAL_LOOP_SILENT; break; }
            if (written - __atomic_load_n(&shared->rows_read, __ATOMIC_ACQUIRE) >= c->ring_size) {
                end = NFAL_LOOP_RING_FULL;
                break;
            }
            c->ring[written & (c->ring_size - 1u)] = next;
            __atomic_store_n(&shared->rows_written, written + 1u, __ATOMIC_RELEASE);
            shared->steps_done = k + 1u;
            row = next;
        }
    }
    if (end == NFAL_LOOP_DONE && !c->lockstep) wait_until(shared->start_s + (double)c->steps * c->period_s, c->spin_s);
done:
    if (flags >= 0) fcntl(c->fd, F_SETFL, flags);
    if (policy >= 0) pthread_setschedparam(pthread_self(), policy, &was);
    pthread_sigmask(SIG_SETMASK, &before, NULL);
    shared->reason = end;
    return end;
}

/* The host's 2 kHz loop in C: the link and the control law of ssp/fig7_hil.ssd's Controller -> proxy pair, paced on
 * CLOCK_MONOTONIC, with nothing in it that waits for Python (docs/hil.md, "The compiled loop").
 *
 * Python (nfal/apps/compiled_loop.py) opens the session (HELLO, HELLO_ACK, the first MEASUREMENT: hil/link.py), hands
 * over the port's descriptor, the law (nfal_law.h) and the reference of every step, and calls nfal_loop_run from a
 * thread of its own: ctypes releases the GIL for the call. Step k, released at t0 + k T:
 *   write DRIVE(the command of row k), take in what the port holds (MEASUREMENT, FAULT, ...: docs/protocol.md), the
 *   law on the newest measurement and the reference of step k + 1 (row k + 1's command), record row k + 1.
 * That is the order the master gives the Controller and HardwareProxy FMUs (a row: the outputs at a communication
 * point; the proxy's DRIVE leaves at the start of its step). The rows go into a ring that Python drains to the results
 * file; the loop never waits for it (a ring that fills ends the loop, as a missed deadline of the recorder).
 *
 * It ends after `steps` steps (and one more period, so that the last DRIVE holds as long as the others), or at the
 * first of: the rig's watchdog tripped, more than max_missed_samples samples without a measurement (by the clock, as
 * the HardwareProxy counts them), a measurement the law refuses, a port that fails, a HELLO_ACK the loop did not ask
 * for (the rig restarted), the ring full, `stop` set by Python (a signal), and in lockstep no answer in time.
 * In lockstep missed samples are counted in rig time, as the HardwareProxy does (the ticks between answers less one).
 * The port is left open: Python sends STOP and closes it. No reconnection (the FMU loop's HardwareProxy has it).
 */
#ifndef NFAL_LOOP_H
#define NFAL_LOOP_H

#include <stdint.h>

#include "nfal_law.h"

/* Why the loop ended (nfal_loop_shared.reason). */
enum nfal_loop_end {
    NFAL_LOOP_RUNNING = 0, NFAL_LOOP_DONE = 1, NFAL_LOOP_STOPPED = 2, NFAL_LOOP_WATCHDOG = 3, NFAL_LOOP_SILENT = 4,
    NFAL_LOOP_LAW_INPUT = 5, NFAL_LOOP_PORT = 6, NFAL_LOOP_RESTARTED = 7, NFAL_LOOP_RING_FULL = 8, NFAL_LOOP_SETUP = 9,
    NFAL_LOOP_NO_ANSWER = 10
};

/* One row: what the Controller and the HardwareProxy FMUs output at a communication point, and the loop's timing. */
typedef struct {
    double reference_m, command_m, voltage_v;                  /* Controller */
    double height_m, drive_frequency_hz, applied_voltage_v;    /* proxy: the newest measurement */
    double rig_time_s, measurement_age_s;
    double lateness_s, duration_s;                             /* the step that ended at this row (0 in row 0) */
    double drive_gap_s;                                        /* since the DRIVE before (0: the first, or none) */
    uint32_t status, fresh, samples_missed;
    uint32_t frames_dropped, frames_lost, rig_faults;
    uint32_t drive_sent;                                       /* the step's DRIVE left whole */
} nfal_loop_row;

/* The newest measurement, and the decoder's memory: given by Python from the session it opened, kept by the loop. */
typedef struct {
    double height_m, drive_frequency_hz, applied_voltage_v, rig_time_s;
    double arrival_s;                       /* CLOCK_MONOTONIC [s] (Python's time.perf_counter) */
    uint32_t status, command_seq;           /* the measurement's status word, the seq of the DRIVE it applied */
    uint32_t last_seq, has_last_seq;
    uint32_t next_drive_seq;                /* the seq the next DRIVE takes */
    uint32_t skip_to_delimiter;             /* bytes of a frame were pending in Python's decoder */
    uint64_t measurements;                  /* measurements received, the first included */
    uint32_t frames_dropped, frames_lost, rig_faults;
} nfal_loop_link;

typedef struct {
    int32_t fd;
    int32_t rt_priority;                    /* > 0: SCHED_FIFO at this priority for the loop's thread */
    uint64_t steps;
    double period_s, spin_s;                /* release every period_s; sleep until spin_s before, then spin */
    double metres_per_volt, sample_rate_hz;
    uint32_t max_missed_samples;
    int32_t lockstep;                       /* each step waits for the measurement that reports its DRIVE applied
                                               (up to answer_timeout_s), and is released at once: the HardwareProxy's
                                               lockstep, against nfal rig-emulator --lockstep */
    double answer_timeout_s;
    const double *reference_m;              /* [steps + 1]: the reference at each row */
    nfal_loop_row *ring;                    /* [ring_size], a power of two */
    uint64_t ring_size;
} nfal_loop_config;

/* Written by the loop (rows_written, reason, the link) and by Python (rows_read, stop). */
typedef struct {
    volatile uint64_t rows_written, rows_read;
    volatile int32_t stop, reason;
    int32_t error_number;                   /* errno of a failed read or write */
    uint64_t steps_done;
    double start_s;                         /* step 0's release (CLOCK_MONOTONIC) */
} nfal_loop_shared;

/* Row 0 (the law on the session's first measurement), then the steps; returns the reason it ended. */
int nfal_loop_run(const nfal_loop_config *config, const nfal_law_params *law, nfal_law_state *state,
                  nfal_loop_link *link, nfal_loop_shared *shared);

/* CLOCK_MONOTONIC [s]. */
double nfal_loop_clock(void);

#endif

/* This machine's floor for a 2 kHz loop: a loop that does nothing but `work_us` of busy work a step, released as
   nfal's RealTimePacer releases its steps (absolute release times t0 + k T; a late step is not skipped, the schedule
   is not shifted), waiting for each release in nanosleep (``sleep``) or spinning on the clock (``spin``: the vCPU
   never idles). Whatever a host of the rig does, it cannot overrun less than this, or stall for less.
   usage: machine_floor SECONDS WORK_US sleep|spin     prints one JSON object (bench/machine_floor.py runs it). */
#define _POSIX_C_SOURCE 200809L
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define PERIOD_S 5e-4

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

int main(int argc, char **argv) {
    if (argc != 4 || (strcmp(argv[3], "sleep") != 0 && strcmp(argv[3], "spin") != 0)) {
        fprintf(stderr, "usage: %s SECONDS WORK_US sleep|spin\n", argv[0]);
        return 2;
    }
    const double seconds = atof(argv[1]), work_s = atof(argv[2]) * 1e-6;
    const int spin = strcmp(argv[3], "spin") == 0;
    const long steps = (long)(seconds / PERIOD_S);
    long overruns = 0, gaps_over_5ms = 0, gaps_over_10ms = 0;
    double gap_max = 0.0, lateness_max = 0.0;
    const double t0 = now() + 0.01;
    double last_start = t0;
    for (long k = 0; k < steps; k++) {
        const double release = t0 + (double)k * PERIOD_S, remaining = spin ? 0.0 : release - now();
        while (spin && now() < release) {
        }
        if (remaining > 0.0) {
            struct timespec sleep_for = {(time_t)remaining, 0};
            sleep_for.tv_nsec = (long)((remaining - (double)sleep_for.tv_sec) * 1e9);
            nanosleep(&sleep_for, NULL);
        }
        const double start = now(), gap = start - last_start;
        if (start - release > lateness_max) lateness_max = start - release;
        if (k > 0) {
            if (gap > gap_max) gap_max = gap;
            gaps_over_5ms += gap > 5e-3;
            gaps_over_10ms += gap > 10e-3;
        }
        last_start = start;
        while (now() - start < work_s) {
        }
        overruns += now() > release + PERIOD_S; /* finished after the next step's release: RealTimePacer.done */
    }
    printf("{\"steps\": %ld, \"overruns\": %ld, \"overrun_share_percent\": %.4f, \"gap_max_ms\": %.2f, "
           "\"gaps_over_5ms\": %ld, \"gaps_over_10ms\": %ld, \"lateness_max_ms\": %.2f}\n",
           steps, overruns, 100.0 * (double)overruns / (double)steps, gap_max * 1e3, gaps_over_5ms, gaps_over_10ms,
           lateness_max * 1e3);
    return 0;
}

/* The master's communication step in C (orchestration/compiled_exchange.py builds and loads it): the doSteps and
 * the exchange's get and set calls of a step, made straight to the FMUs' functions, as Master.step makes them
 * through ctypes. It decides nothing: the plan, the row's columns and every error are the Python master's.
 *
 * The row is the master's row as doubles; a value of any other type crosses as the Python master copies it
 * (compiled_exchange.py admits only the types a double holds exactly, and no Integer external input: a Python int
 * may not fit a double). An integer target takes a value wrapped modulo 2^bits, as a ctypes integer does. Built with -ffp-contract=off: a
 * connection's factor * value + offset is rounded as Python rounds it.
 */
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <time.h>

enum { GET = 0, LOAD_AND_SET = 1, SET = 2, LOAD = 3 };  /* what a transfer does (kind) */
enum { F64 = 0, F32, I8, U8, I16, U16, I32, U32, BOOL };  /* the C type of its values (type) */

typedef int (*fmi2_values)(void *, const uint32_t *, size_t, void *);
typedef int (*fmi3_values)(void *, const uint32_t *, size_t, void *, size_t);
typedef int (*fmi2_do_step)(void *, double, double, int);
typedef int (*fmi3_do_step)(void *, double, double, bool, bool *, bool *, bool *, double *);

typedef struct {
    void *function;          /* fmi<2|3><Get|Set><Type>, or NULL (LOAD) */
    void *component;
    const uint32_t *vr;
    size_t n;
    int32_t fmi, kind, type;
    void *buffer;            /* n values of the type */
    const int32_t *columns;  /* the row's column of each value */
    const uint8_t *scaled;   /* NULL, or per value: 1 where a LinearTransformation applies */
    const double *factor, *offset;
} nfal_transfer;

typedef struct {
    void *do_step;
    void *component;
    int32_t fmi;
    double seconds;          /* wall time in its doSteps */
    double last;             /* FMI 3.0: lastSuccessfulTime of a doStep that asked to terminate */
} nfal_slave;

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* value modulo 2^bits, in [0, 2^bits): an integer target takes it as ctypes takes a Python int, wrapped */
static double wrapped(double value, double modulus) {
    double rest = fmod(value, modulus);
    return rest < 0.0 ? rest + modulus : rest;
}

static double value_at(const void *buffer, int32_t type, size_t j) {
    switch (type) {
    case F64: return ((const double *)buffer)[j];
    case F32: return ((const float *)buffer)[j];
    case I8: return ((const int8_t *)buffer)[j];
    case U8: return ((const uint8_t *)buffer)[j];
    case I16: return ((const int16_t *)buffer)[j];
    case U16: return ((const uint16_t *)buffer)[j];
    case I32: return ((const int32_t *)buffer)[j];
    case U32: return ((const uint32_t *)buffer)[j];
    default: return ((const uint8_t *)buffer)[j] != 0;  /* as ctypes reads a c_bool, whatever byte the FMU wrote */
    }
}

static void put(void *buffer, int32_t type, size_t j, double value) {
    switch (type) {
    case F64: ((double *)buffer)[j] = value; break;
    case F32: ((float *)buffer)[j] = (float)value; break;
    case I8: ((int8_t *)buffer)[j] = (int8_t)(uint8_t)wrapped(value, 256.0); break;
    case U8: ((uint8_t *)buffer)[j] = (uint8_t)wrapped(value, 256.0); break;
    case I16: ((int16_t *)buffer)[j] = (int16_t)(uint16_t)wrapped(value, 65536.0); break;
    case U16: ((uint16_t *)buffer)[j] = (uint16_t)wrapped(value, 65536.0); break;
    case I32: ((int32_t *)buffer)[j] = (int32_t)(uint32_t)wrapped(value, 4294967296.0); break;
    case U32: ((uint32_t *)buffer)[j] = (uint32_t)wrapped(value, 4294967296.0); break;
    default: ((bool *)buffer)[j] = value != 0.0; break;
    }
}

static int call(const nfal_transfer *t) {
    if (t->fmi == 3)
        return ((fmi3_values)t->function)(t->component, t->vr, t->n, t->buffer, t->n);
    return ((fmi2_values)t->function)(t->component, t->vr, t->n, t->buffer);
}

/* Carry out transfers[0..count) on row: the index of the first whose call failed (status above fmi2Warning, in
 * *status), or -1. */
int nfal_transfers(const nfal_transfer *transfers, int32_t count, double *row, int32_t *status) {
    for (int32_t i = 0; i < count; i++) {
        const nfal_transfer *t = &transfers[i];
        if (t->kind == LOAD_AND_SET || t->kind == LOAD)
            for (size_t j = 0; j < t->n; j++) {
                double value = row[t->columns[j]];
                put(t->buffer, t->type, j, t->scaled && t->scaled[j] ? t->factor[j] * value + t->offset[j] : value);
            }
        if (t->kind != LOAD && (*status = call(t)) > 1)
            return i;
        if (t->kind == GET)
            for (size_t j = 0; j < t->n; j++)
                row[t->columns[j]] = value_at(t->buffer, t->type, j);
    }
    return -1;
}

/* doStep(t, dt) slaves[first..count): the index of the first that did not step cleanly (a status above
 * fmi2Warning in *status, or FMI 3.0's terminateSimulation with *status 0), or -1. */
int nfal_do_steps(nfal_slave *slaves, int32_t first, int32_t count, double t, double dt, int32_t *status) {
    for (int32_t i = first; i < count; i++) {
        nfal_slave *s = &slaves[i];
        double started = now();
        if (s->fmi == 3) {
            bool event = false, terminate = false, early = false;
            *status = ((fmi3_do_step)s->do_step)(s->component, t, dt, true, &event, &terminate, &early, &s->last);
            s->seconds += now() - started;
            if (*status > 1 || terminate)
                return i;
        } else {
            *status = ((fmi2_do_step)s->do_step)(s->component, t, dt, 1);
            s->seconds += now() - started;
            if (*status > 1)
                return i;
        }
    }
    return -1;
}

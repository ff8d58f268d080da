/* A minimal FMI 2.0 co-simulation host, as the FMI Compliance Checker (fmuCheck) drives an FMU:
 * dlopen the binary, instantiate, set up, initialise, step to the stop time, read the outputs,
 * terminate, free, dlclose, exit. A crash anywhere (also in the library's teardown at exit) shows
 * in the exit code. nfal.fmus.host_check compiles and runs it (tests/test_host_compatibility.py, bench/host_compat.py).
 *
 * usage: fmi2_host BINARY GUID RESOURCES_URI STOP_TIME STEP_SIZE [VR | VR=TEXT ...]
 * VR=TEXT sets the String variable VR to TEXT before initialisation (e.g. the HardwareProxy's port);
 * prints "t=<stop>" and then "vr=<value>" (%.17g) for each Real value reference VR;
 * every FMI log message goes to stdout as "log <status> <category>: <message>".
 * With NFAL_HOST_THREAD_PER_STEP=1 in its environment (not on Windows), each fmi2DoStep runs on a thread of its own,
 * as a host that makes a thread per call does.
 * Exit codes: 0 ok; 1 library or symbol not found; 2 fmi2Instantiate failed; 3 an FMI call did not
 * return fmi2OK (the call is named on stdout).
 */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "host_common.h"
#ifndef _WIN32
#include <pthread.h>
#endif

typedef void *Component;
typedef int Status; /* fmi2OK = 0, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending */
typedef void (*Logger)(void *, const char *, Status, const char *, const char *, ...);
typedef struct {
    Logger logger;
    void *(*allocate)(size_t, size_t);
    void (*free)(void *);
    void *step_finished;
    void *environment;
} Callbacks;

typedef Component (*Instantiate)(const char *, int, const char *, const char *, const Callbacks *, int, int);
typedef Status (*SetupExperiment)(Component, int, double, double, int, double);
typedef Status (*Call)(Component);
typedef Status (*DoStep)(Component, double, double, int);
typedef Status (*GetReal)(Component, const unsigned int *, size_t, double *);
typedef Status (*SetString)(Component, const unsigned int *, size_t, const char *const *);
typedef void (*FreeInstance)(Component);

static void log_message(void *env, const char *instance, Status status, const char *category, const char *message, ...) {
    va_list args;
    (void)env;
    printf("log %d %s: ", status, category);
    va_start(args, message);
    vprintf(message, args);
    va_end(args);
    printf(" [%s]\n", instance);
}

typedef struct {
    DoStep do_step;
    Component c;
    double t, step;
    Status status;
} StepCall;

static void *step_call(void *call) {
    StepCall *s = call;
    s->status = s->do_step(s->c, s->t, s->step, 1);
    return NULL;
}

/* fmi2DoStep, on a thread of its own if ``own_thread`` */
static Status do_one_step(DoStep do_step, Component c, double t, double step, int own_thread) {
    StepCall call = {do_step, c, t, step, 0};
#ifndef _WIN32
    pthread_t thread;
    if (own_thread) {
        if (pthread_create(&thread, NULL, step_call, &call) != 0 || pthread_join(thread, NULL) != 0) {
            printf("fmi2DoStep's thread could not be started or joined\n");
            exit(3);
        }
        return call.status;
    }
#endif
    step_call(&call);
    return call.status;
}

int main(int argc, char **argv) {
    if (argc < 6) {
        printf("usage: %s BINARY GUID RESOURCES_URI STOP_TIME STEP_SIZE [VR ...]\n", argv[0]);
        return 1;
    }
    double stop = atof(argv[4]), step = atof(argv[5]), t = 0.0;
    void *library = open_library(argv[1]);
    Instantiate instantiate = (Instantiate)symbol(library, "fmi2Instantiate");
    SetupExperiment setup = (SetupExperiment)symbol(library, "fmi2SetupExperiment");
    Call enter = (Call)symbol(library, "fmi2EnterInitializationMode");
    Call exit_init = (Call)symbol(library, "fmi2ExitInitializationMode");
    DoStep do_step = (DoStep)symbol(library, "fmi2DoStep");
    GetReal get_real = (GetReal)symbol(library, "fmi2GetReal");
    SetString set_string = (SetString)symbol(library, "fmi2SetString");
    Call terminate = (Call)symbol(library, "fmi2Terminate");
    FreeInstance free_instance = (FreeInstance)symbol(library, "fmi2FreeInstance");

    Callbacks callbacks = {log_message, calloc, free, NULL, NULL};
    Component c = instantiate("instance", 1 /* fmi2CoSimulation */, argv[2], argv[3], &callbacks, 0, 1);
    if (!c) {
        printf("fmi2Instantiate failed\n");
        return 2;
    }
    for (int i = 6; i < argc; ++i) {
        const char *text = strchr(argv[i], '=');
        if (text) {
            unsigned int vr = (unsigned int)atoi(argv[i]);
            ++text;
            check(set_string(c, &vr, 1, &text), "fmi2SetString");
        }
    }
    check(setup(c, 0, 0.0, 0, 1, stop), "fmi2SetupExperiment");
    check(enter(c), "fmi2EnterInitializationMode");
    check(exit_init(c), "fmi2ExitInitializationMode");
    long n = (long)(stop / step + 0.5);
    const char *per_step = getenv("NFAL_HOST_THREAD_PER_STEP");
    int own_thread = per_step && strcmp(per_step, "1") == 0;
    for (long k = 0; k < n; ++k, t = k * step) {
        check(do_one_step(do_step, c, t, step, own_thread), "fmi2DoStep");
    }
    printf("t=%.17g\n", n * step);
    for (int i = 6; i < argc; ++i) {
        if (strchr(argv[i], '=')) continue;
        unsigned int vr = (unsigned int)atoi(argv[i]);
        double value = 0.0;
        check(get_real(c, &vr, 1, &value), "fmi2GetReal");
        printf("%u=%.17g\n", vr, value);
    }
    check(terminate(c), "fmi2Terminate");
    free_instance(c);
    dlclose(library);
    return 0;
}

/* A minimal FMI 3.0 co-simulation host, fmi2_host.c's counterpart: dlopen the binary, instantiate,
 * initialise, step to the stop time, read the outputs, terminate, free, dlclose, exit. A crash anywhere
 * (also in the library's teardown at exit) shows in the exit code. nfal.fmus.host_check compiles and
 * runs it (tests/test_fmi3.py, bench/host_compat.py).
 *
 * usage: fmi3_host BINARY INSTANTIATION_TOKEN RESOURCE_PATH STOP_TIME STEP_SIZE [VR ...]
 * prints "t=<stop>" and then "vr=<value>" (%.17g) for each Float64 value reference VR;
 * every FMI log message goes to stdout as "log <status> <category>: <message> [instance]".
 * Exit codes: 0 ok; 1 library or symbol not found; 2 fmi3InstantiateCoSimulation failed; 3 an FMI call
 * did not return fmi3OK (the call is named on stdout).
 */
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>

#include "host_common.h"

typedef void *Instance;
typedef int Status; /* fmi3OK = 0, fmi3Warning, fmi3Discard, fmi3Error, fmi3Fatal */
typedef bool Boolean; /* fmi3Boolean */
typedef void (*LogMessage)(void *, Status, const char *, const char *);

typedef Instance (*Instantiate)(const char *, const char *, const char *, Boolean, Boolean, Boolean, Boolean,
                                const unsigned int *, size_t, void *, LogMessage, void *);
typedef Status (*EnterInitialization)(Instance, Boolean, double, double, Boolean, double);
typedef Status (*Call)(Instance);
typedef Status (*DoStep)(Instance, double, double, Boolean, Boolean *, Boolean *, Boolean *, double *);
typedef Status (*GetFloat64)(Instance, const unsigned int *, size_t, double *, size_t);
typedef void (*FreeInstance)(Instance);

static void log_message(void *instance, Status status, const char *category, const char *message) {
    printf("log %d %s: %s [%s]\n", status, category ? category : "(null)", message, (const char *)instance);
}

int main(int argc, char **argv) {
    if (argc < 6) {
        printf("usage: %s BINARY INSTANTIATION_TOKEN RESOURCE_PATH STOP_TIME STEP_SIZE [VR ...]\n", argv[0]);
        return 1;
    }
    double stop = atof(argv[4]), step = atof(argv[5]), t = 0.0;
    void *library = open_library(argv[1]);
    const char *(*get_version)(void) = (const char *(*)(void))symbol(library, "fmi3GetVersion");
    Instantiate instantiate = (Instantiate)symbol(library, "fmi3InstantiateCoSimulation");
    EnterInitialization enter = (EnterInitialization)symbol(library, "fmi3EnterInitializationMode");
    Call exit_init = (Call)symbol(library, "fmi3ExitInitializationMode");
    DoStep do_step = (DoStep)symbol(library, "fmi3DoStep");
    GetFloat64 get_float64 = (GetFloat64)symbol(library, "fmi3GetFloat64");
    Call terminate = (Call)symbol(library, "fmi3Terminate");
    FreeInstance free_instance = (FreeInstance)symbol(library, "fmi3FreeInstance");

    printf("version=%s\n", get_version());
    /* visible = false, loggingOn = false, eventModeUsed = false, earlyReturnAllowed = false */
    Instance c = instantiate("instance", argv[2], argv[3], false, false, false, false, NULL, 0, "instance", log_message, NULL);
    if (!c) {
        printf("fmi3InstantiateCoSimulation failed\n");
        return 2;
    }
    check(enter(c, false, 0.0, 0.0, true, stop), "fmi3EnterInitializationMode");
    check(exit_init(c), "fmi3ExitInitializationMode");
    long n = (long)(stop / step + 0.5);
    for (long k = 0; k < n; ++k, t = k * step) {
        Boolean event = false, terminate_simulation = false, early_return = false;
        double last = 0.0;
        check(do_step(c, t, step, true, &event, &terminate_simulation, &early_return, &last), "fmi3DoStep");
    }
    printf("t=%.17g\n", n * step);
    for (int i = 6; i < argc; ++i) {
        unsigned int vr = (unsigned int)atoi(argv[i]);
        double value = 0.0;
        check(get_float64(c, &vr, 1, &value, 1), "fmi3GetFloat64");
        printf("%u=%.17g\n", vr, value);
    }
    check(terminate(c), "fmi3Terminate");
    free_instance(c);
    dlclose(library);
    return 0;
}

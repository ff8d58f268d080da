/* The binary a host loads from an nfal FMU: a small loader with no Python symbols (docs/cosimulation.md,
 * "The loader: FMUs that need nothing from the environment").
 *
 * binaries/<platform>/<Model>.so is this file, compiled once per FMI version (NFAL_FMI_VERSION 2 or 3)
 * by fmus/export_runtime.py together with the generated forwarders (nfal_forwarders.h: one exported
 * function per FMI function the runtime exports). At the first fmi2Instantiate / fmi3Instantiate* it
 *
 *   1. reads resources/python.cfg, written by the build: the Python the FMU was built with (executable,
 *      version, prefix, libpython, site-packages);
 *   2. takes another Python if the environment variable NFAL_FMU_PYTHON or the file's "override=" names
 *      one (its settings are asked from that Python itself);
 *   3. uses the libpython already in the process (FMPy, libcosimpy: Py_IsInitialized is found globally),
 *      or dlopen()s the recorded one with RTLD_GLOBAL (extension modules such as numpy's need its symbols
 *      globally) and initialises it as the recorded executable would start (program name = that
 *      executable, so a venv's pyvenv.cfg is found and its site-packages used), without signal handlers,
 *      then adds the recorded site-packages to sys.path;
 *   4. dlopen()s the real runtime, binaries/<platform>/<Model>_runtime.so (the patched pythonfmu or
 *      pythonfmu3 runtime), and forwards every call to it.
 *
 * Anything missing makes the instantiate call return NULL with one line through the host's logger that
 * names what is missing and the override (also written to stderr: ecos shows FMU messages only at its
 * debug level); nothing here crashes a host. The interpreter is never
 * finalised (see PyState.hpp in the runtimes), and neither library is ever closed.
 *
 * The loader also keeps the set of live instances: a call with an instance that is not live (freed
 * already, never created, NULL) returns an error, and a second FreeInstance does nothing.
 */
#ifdef _WIN32
#include "loader_windows.h" /* the Windows stand-ins for what follows (dlopen, dladdr, posix_spawn, access) */
#else
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <spawn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>
#include <wchar.h>
#define NFAL_CONFIG_FILE "python.cfg"
#define NFAL_LIBRARY_SUFFIX ".so"
#define NFAL_SEPARATOR "/"
#define NFAL_LIBPYTHON_WORDS "a shared libpython"
extern char **environ;
#endif

#if NFAL_FMI_VERSION == 2
#include "fmi2Functions.h"
#else
#include "fmi3Functions.h"
#endif
#include "nfal_python_info.h" /* generated: NFAL_PYTHON_INFO, the script that prints a Python's settings */

#define NFAL_MESSAGE_SIZE 2048
#define NFAL_VALUE_SIZE 4096
#define NFAL_OVERRIDE_ENV "NFAL_FMU_PYTHON"

/* What resources/python.cfg (or the override's Python) says. */
typedef struct {
    char override[NFAL_VALUE_SIZE];
    char executable[NFAL_VALUE_SIZE];
    char version[64];
    char libpython[NFAL_VALUE_SIZE];
    char base_prefix[NFAL_VALUE_SIZE]; /* Python's home (set explicitly on Windows) */
    char site[4 * NFAL_VALUE_SIZE];
} nfal_python;

static char nfal_self[PATH_MAX];     /* this library's own path */
static char nfal_model[256];         /* its model identifier (the file name without .so) */
static void *nfal_runtime_handle;    /* the real runtime, once loaded */
static pthread_mutex_t nfal_lock = PTHREAD_MUTEX_INITIALIZER;

static void *nfal_runtime_symbol(const char *name);
static void nfal_fill_table(void); /* generated: nfal_forwarders.h */

#ifndef _WIN32
static void *nfal_global_symbol(const char *name) { return dlsym(RTLD_DEFAULT, name); }

static int nfal_can_run(const char *path) { return access(path, X_OK) == 0; }

/* The path of the library holding ``address`` (this loader), into out. */
static void nfal_library_path(const void *address, char *out, size_t size)
{
    Dl_info info;
    if (dladdr(address, &info) && info.dli_fname) {
        if (!realpath(info.dli_fname, out)) snprintf(out, size, "%s", info.dli_fname);
    }
}

static char *nfal_last_separator(char *path) { return strrchr(path, '/'); }
#endif

__attribute__((constructor)) static void nfal_find_self(void)
{
    nfal_library_path((const void *)&nfal_find_self, nfal_self, sizeof nfal_self);
    const char *separator = nfal_last_separator(nfal_self);
    snprintf(nfal_model, sizeof nfal_model, "%s", separator ? separator + 1 : nfal_self);
    char *dot = strstr(nfal_model, NFAL_LIBRARY_SUFFIX);
    if (dot) *dot = '\0';
}

/* dirname of nfal_self, up ``levels`` folders, into out. */
static void nfal_folder(char *out, size_t size, int levels)
{
    snprintf(out, size, "%s", nfal_self);
    for (int k = 0; k <= levels; ++k) {
        char *separator = nfal_last_separator(out);
        if (separator) *separator = '\0';
    }
}

static void nfal_trim(char *text)
{
    size_t n = strlen(text);
    while (n > 0 && (text[n - 1] == '\n' || text[n - 1] == '\r' || text[n - 1] == ' ' || text[n - 1] == '\t')) {
        text[--n] = '\0';
    }
    size_t start = strspn(text, " \t");
    if (start) memmove(text, text + start, n - start + 1);
}

/* One "key=value" line into the settings (unknown keys and comments are ignored). */
static void nfal_setting(nfal_python *python, char *line)
{
    if (line[0] == '#') return;
    char *equals = strchr(line, '=');
    if (!equals) return;
    *equals = '\0';
    char *key = line, *value = equals + 1;
    nfal_trim(key);
    nfal_trim(value);
    struct { const char *key; char *target; size_t size; } fields[] = {
        {"override", python->override, sizeof python->override},
        {"executable", python->executable, sizeof python->executable},
        {"version", python->version, sizeof python->version},
        {"libpython", python->libpython, sizeof python->libpython},
        {"base_prefix", python->base_prefix, sizeof python->base_prefix},
        {"site", python->site, sizeof python->site},
    };
    for (size_t k = 0; k < sizeof fields / sizeof fields[0]; ++k) {
        if (strcmp(key, fields[k].key) == 0) snprintf(fields[k].target, fields[k].size, "%s", value);
    }
}

static void nfal_settings(nfal_python *python, FILE *source)
{
    char line[4 * NFAL_VALUE_SIZE + 64];
    while (fgets(line, sizeof line, source)) nfal_setting(python, line);
}

#ifdef _WIN32
/* Run ``executable`` on the build's script (NFAL_PYTHON_INFO_HEX: hex, so no quoting can break the command line)
   and read its settings; its exit status, or -1 with a message. */
static int nfal_run_python_info(nfal_python *python, const char *executable, char *message, size_t size)
{
    SECURITY_ATTRIBUTES inherit = {sizeof inherit, NULL, TRUE};
    HANDLE read_end, write_end;
    if (!CreatePipe(&read_end, &write_end, &inherit, 0)) {
        snprintf(message, size, "cannot ask the Python %s for its settings: CreatePipe failed (%lu)", executable,
                 (unsigned long)GetLastError());
        return -1;
    }
    SetHandleInformation(read_end, HANDLE_FLAG_INHERIT, 0);
    HANDLE nothing = CreateFileA("NUL", GENERIC_READ, FILE_SHARE_READ | FILE_SHARE_WRITE, &inherit, OPEN_EXISTING, 0,
                                 NULL);
    STARTUPINFOA startup;
    memset(&startup, 0, sizeof startup);
    startup.cb = sizeof startup;
    startup.dwFlags = STARTF_USESTDHANDLES;
    startup.hStdInput = nothing;
    startup.hStdOutput = write_end;
    startup.hStdError = nothing;
    static char command[2 * NFAL_VALUE_SIZE + sizeof NFAL_PYTHON_INFO_HEX];
    snprintf(command, sizeof command, "\"%s\" -c \"exec(bytes.fromhex('%s').decode())\"", executable,
             NFAL_PYTHON_INFO_HEX);
    PROCESS_INFORMATION child;
    BOOL started = CreateProcessA(executable, command, NULL, NULL, TRUE, CREATE_NO_WINDOW, NULL, NULL, &startup,
                                  &child);
    DWORD error = GetLastError();
    CloseHandle(write_end);
    if (nothing != INVALID_HANDLE_VALUE) CloseHandle(nothing);
    if (!started) {
        CloseHandle(read_end);
        snprintf(message, size, "cannot run the Python %s: Windows error %lu", executable, (unsigned long)error);
        return -1;
    }
    FILE *output = _fdopen(_open_osfhandle((intptr_t)read_end, _O_RDONLY), "r");
    if (output) {
        nfal_settings(python, output);
        fclose(output);
    } else {
        CloseHandle(read_end);
    }
    DWORD status = 1;
    if (WaitForSingleObject(child.hProcess, 60000) != WAIT_OBJECT_0) {
        TerminateProcess(child.hProcess, 1);  /* a Python that hangs is one that did not tell */
    } else {
        GetExitCodeProcess(child.hProcess, &status);
    }
    CloseHandle(child.hProcess);
    CloseHandle(child.hThread);
    return status == 0 ? 0 : 1;  /* an NTSTATUS (0xC...) is not a negative "no message" */
}
#else
/* Run ``executable -c NFAL_PYTHON_INFO`` and read its settings; its exit status, or -1 with a message. */
static int nfal_run_python_info(nfal_python *python, const char *executable, char *message, size_t size)
{
    int pipe_fds[2];
    if (pipe(pipe_fds) != 0) {
        snprintf(message, size, "cannot ask the Python %s for its settings: pipe: %s", executable, strerror(errno));
        return -1;
    }
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], STDOUT_FILENO);
    posix_spawn_file_actions_addclose(&actions, pipe_fds[0]);
    char *argv[] = {(char *)executable, "-c", (char *)NFAL_PYTHON_INFO, NULL};
    pid_t child;
    int spawned = posix_spawn(&child, executable, &actions, NULL, argv, environ);
    posix_spawn_file_actions_destroy(&actions);
    close(pipe_fds[1]);
    if (spawned != 0) {
        close(pipe_fds[0]);
        snprintf(message, size, "cannot run the Python %s: %s", executable, strerror(spawned));
        return -1;
    }
    FILE *output = fdopen(pipe_fds[0], "r");
    if (output) {
        nfal_settings(python, output);
        fclose(output);
    } else {
        close(pipe_fds[0]);
    }
    int status = 0;
    while (waitpid(child, &status, 0) < 0 && errno == EINTR) {}
    return WIFEXITED(status) ? WEXITSTATUS(status) : 128;
}
#endif

/* Ask ``executable`` for its settings (the build's script, NFAL_PYTHON_INFO); 0 with a message on failure. */
static int nfal_ask_python(nfal_python *python, const char *executable, char *message, size_t size)
{
    int status = nfal_run_python_info(python, executable, message, size);
    if (status < 0) return 0;
    if (status != 0 || !python->executable[0]) {
        snprintf(message, size, "the Python %s did not tell its settings (is it Python 3.8 or newer?)", executable);
        return 0;
    }
    return 1;
}

typedef int (*nfal_int_void)(void);

/* The Python of the process if one is initialised there already (a Python host). */
static int nfal_python_in_process(void)
{
    nfal_int_void is_initialized = (nfal_int_void)nfal_global_symbol("Py_IsInitialized");
    return is_initialized && is_initialized();
}

/* Python source text for a string literal holding ``text`` (backslashes and quotes escaped). */
static void nfal_python_literal(char *out, size_t size, const char *text)
{
    size_t n = 0;
    if (n < size) out[n++] = '\'';
    for (const char *c = text; *c && n + 3 < size; ++c) {
        if (*c == '\\' || *c == '\'') out[n++] = '\\';
        out[n++] = *c;
    }
    if (n < size) out[n++] = '\'';
    out[n < size ? n : size - 1] = '\0';
}

#ifdef _WIN32
/* The runtime imports python3.dll (the stable ABI): load the one beside ``libpython`` now, so that it is the one the
   runtime gets (Windows resolves a module name to the module already loaded), never one found on PATH. */
static int nfal_load_stable_abi(const char *libpython, char *message, size_t size)
{
    char stable[NFAL_VALUE_SIZE + 16];
    snprintf(stable, sizeof stable, "%s", libpython);
    char *separator = nfal_last_separator(stable);
    size_t used = separator ? (size_t)(separator + 1 - stable) : 0;
    snprintf(stable + used, sizeof stable - used, "python3.dll");
    if (!dlopen(stable, RTLD_NOW)) {
        snprintf(message, size, "cannot load %s beside %s (%s)", stable, libpython, dlerror());
        return 0;
    }
    return 1;
}

/* The file of the process's own libpython (a Python host's), into out; "" when none. */
static void nfal_process_libpython(char *out, size_t size)
{
    out[0] = '\0';
    void *is_initialized = nfal_global_symbol("Py_IsInitialized");
    if (is_initialized) nfal_library_path(is_initialized, out, size);
}
#endif

/* dlopen libpython globally and start it as ``python->executable`` would start; 0 with a message on failure. */
static int nfal_start_python(const nfal_python *python, const char *fix, char *message, size_t size)
{
    void *library = dlopen(python->libpython, RTLD_NOW | RTLD_GLOBAL);
    if (!library) {
        snprintf(message, size, "cannot load libpython %s of the Python %s (%s): %s", python->libpython,
                 python->executable, dlerror(), fix);
        return 0;
    }
    nfal_int_void is_initialized = (nfal_int_void)dlsym(library, "Py_IsInitialized");
    void (*initialize)(int) = (void (*)(int))dlsym(library, "Py_InitializeEx");
    int (*run)(const char *) = (int (*)(const char *))dlsym(library, "PyRun_SimpleString");
    void *(*save_thread)(void) = (void *(*)(void))dlsym(library, "PyEval_SaveThread");
    wchar_t *(*decode)(const char *, size_t *) = (wchar_t * (*)(const char *, size_t *))dlsym(library, "Py_DecodeLocale");
    void (*set_program_name)(const wchar_t *) = (void (*)(const wchar_t *))dlsym(library, "Py_SetProgramName");
    if (!is_initialized || !initialize || !run || !save_thread || !decode) {
        snprintf(message, size, "%s is not a libpython this FMU can use (Python 3.8 or newer): %s",
                 python->libpython, fix);
        return 0;
    }
#ifdef _WIN32
    if (!nfal_load_stable_abi(python->libpython, message, size)) return 0;
#endif
    if (is_initialized()) return 1;  /* loaded and started by someone else meanwhile */
#ifdef _WIN32
    void (*set_home)(const wchar_t *) = (void (*)(const wchar_t *))dlsym(library, "Py_SetPythonHome");
    if (set_home && python->base_prefix[0]) {
        wchar_t *home = decode(python->base_prefix, NULL);  /* kept for the interpreter's lifetime */
        if (home) set_home(home);
    }
#endif
    if (set_program_name) {
        /* the program name decides sys.prefix, a venv's pyvenv.cfg and sys.executable; kept for the
           interpreter's lifetime, which is the process's (never freed) */
        wchar_t *name = decode(python->executable, NULL);
        if (name) set_program_name(name);
    }
    initialize(0);  /* no signal handlers: the host owns SIGINT */
    char literal[4 * NFAL_VALUE_SIZE + 16], executable[NFAL_VALUE_SIZE + 16];
    nfal_python_literal(literal, sizeof literal, python->site);
    nfal_python_literal(executable, sizeof executable, python->executable);
    char code[sizeof literal + sizeof executable + 512];
    /* one OpenBLAS thread, unless the host's environment names a number: the FMUs' linear algebra is small, and each
       of numpy's and scipy's pools starts a thread per core that spins idle at its start (a Controller's 10 ms run in
       the C host: 0.80x the CPU of one with a thread per core, `python bench/bench_startup.py`) */
    snprintf(code, sizeof code,
             "import os, site, sys\n"
             "os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')\n"
             "sys.executable = %s\n"
             "for _p in %s.split(os.pathsep):\n"
             "    if _p and _p not in sys.path and os.path.isdir(_p):\n"
             "        site.addsitedir(_p)\n"
             "del _p\n",
             executable, literal);
    run(code);
    save_thread();  /* the runtime takes the GIL per call (PyGILState_Ensure) */
    return 1;
}

/* Make the runtime callable: 1, or 0 with one line in ``message`` naming what is missing and the fix. */
static int nfal_load(char *message, size_t size)
{
    pthread_mutex_lock(&nfal_lock);
    if (nfal_runtime_handle) {
        pthread_mutex_unlock(&nfal_lock);
        return 1;
    }
    char resources[PATH_MAX], binaries[PATH_MAX], config[PATH_MAX + 32], runtime[PATH_MAX + 300];
    nfal_folder(resources, sizeof resources, 2);
    strncat(resources, NFAL_SEPARATOR "resources", sizeof resources - strlen(resources) - 1);
    nfal_folder(binaries, sizeof binaries, 0);
    snprintf(config, sizeof config, "%s" NFAL_SEPARATOR "%s", resources, NFAL_CONFIG_FILE);
    snprintf(runtime, sizeof runtime, "%s" NFAL_SEPARATOR "%s_runtime" NFAL_LIBRARY_SUFFIX, binaries, nfal_model);

    int ok = 1;
    nfal_python python;
    memset(&python, 0, sizeof python);
    if (nfal_python_in_process()) {
#ifdef _WIN32
        char libpython[NFAL_VALUE_SIZE];
        nfal_process_libpython(libpython, sizeof libpython);
        ok = nfal_load_stable_abi(libpython, message, size);
#endif
    } else {
        FILE *file = fopen(config, "r");
        if (file) {
            nfal_settings(&python, file);
            fclose(file);
        }
        const char *from_env = getenv(NFAL_OVERRIDE_ENV);
        char fix[1024];
        snprintf(fix, sizeof fix, "set the environment variable " NFAL_OVERRIDE_ENV
                 " (or override= in the FMU's resources/" NFAL_CONFIG_FILE ") to a Python executable with "
                 NFAL_LIBPYTHON_WORDS " and this FMU's packages");
        if (from_env && from_env[0]) {
            char chosen[NFAL_VALUE_SIZE];
            snprintf(chosen, sizeof chosen, "%s", from_env);
            memset(&python, 0, sizeof python);
            if (!nfal_can_run(chosen)) {
                snprintf(message, size, "the Python %s named by " NFAL_OVERRIDE_ENV " does not exist or cannot run "
                         "(%s): %s, or unset it to use the Python the FMU was built with",
                         chosen, strerror(errno), fix);
                ok = 0;
            } else {
                ok = nfal_ask_python(&python, chosen, message, size);
            }
        } else if (python.override[0]) {
            char chosen[NFAL_VALUE_SIZE];
            snprintf(chosen, sizeof chosen, "%s", python.override);
            memset(&python, 0, sizeof python);
            if (!nfal_can_run(chosen)) {
                snprintf(message, size, "the Python %s named by override= in %s does not exist or cannot run (%s): "
                         "%s, or empty override= to use the Python the FMU was built with", chosen, config,
                         strerror(errno), fix);
                ok = 0;
            } else {
                ok = nfal_ask_python(&python, chosen, message, size);
            }
        } else if (!python.executable[0]) {
            snprintf(message, size, "the FMU does not say which Python runs it (%s is missing or has no "
                     "executable=): %s", config, fix);
            ok = 0;
        } else if (!nfal_can_run(python.executable)) {
            snprintf(message, size, "the Python %s this FMU was built with does not exist or cannot run (%s): "
                     "install it there, or %s", python.executable, strerror(errno), fix);
            ok = 0;
        }
        if (ok && !python.libpython[0]) {
#ifdef _WIN32
            snprintf(message, size, "the Python %s has no pythonXY.dll beside it or in its base_prefix: %s",
                     python.executable, fix);
#else
            snprintf(message, size, "the Python %s has no shared libpython (built without --enable-shared; check "
                     "with: %s -c \"import sysconfig; print(sysconfig.get_config_var('Py_ENABLE_SHARED'))\"): %s",
                     python.executable, python.executable, fix);
#endif
            ok = 0;
        }
        if (ok) ok = nfal_start_python(&python, fix, message, size);
    }
    if (ok) {
        nfal_runtime_handle = dlopen(runtime, RTLD_NOW | RTLD_LOCAL);
        if (!nfal_runtime_handle) {
            snprintf(message, size, "cannot load the FMU's runtime %s: %s", runtime, dlerror());
            ok = 0;
        } else {
            nfal_fill_table();
        }
    }
    pthread_mutex_unlock(&nfal_lock);
    return ok;
}

static void *nfal_runtime_symbol(const char *name)
{
    return dlsym(nfal_runtime_handle, name);
}

/* When the host unloads this loader (FMPy's freeLibrary: dlclose), unload the runtime with it, so that its static
 * destructors run then, while the host's Python still lives, as they did when the host loaded the runtime itself;
 * left to the end of the process they ran after FMPy's interpreter had finalised and corrupted the heap (SIGABRT
 * at exit in 1 of 10 FMI 3.0 runs, measured). A host that never unloads gets the same order as before: at exit. */
#ifndef _WIN32 /* on Windows a DLL must not unload another from its detach (the loader lock): the runtime stays */
__attribute__((destructor)) static void nfal_unload(void)
{
    if (nfal_runtime_handle) {
        dlclose(nfal_runtime_handle);
        nfal_runtime_handle = NULL;
    }
}
#endif

/* The live instances (a handful at most: a linear list). */
static void **nfal_live;
static size_t nfal_live_count, nfal_live_capacity;
static pthread_mutex_t nfal_live_lock = PTHREAD_MUTEX_INITIALIZER;

static void nfal_live_add(void *instance)
{
    pthread_mutex_lock(&nfal_live_lock);
    if (nfal_live_count == nfal_live_capacity) {
        size_t capacity = nfal_live_capacity ? 2 * nfal_live_capacity : 16;
        void **grown = realloc(nfal_live, capacity * sizeof *grown);
        if (grown) {
            nfal_live = grown;
            nfal_live_capacity = capacity;
        }
    }
    if (nfal_live_count < nfal_live_capacity) nfal_live[nfal_live_count++] = instance;
    pthread_mutex_unlock(&nfal_live_lock);
}

static int nfal_live_has(void *instance)
{
    int found = 0;
    pthread_mutex_lock(&nfal_live_lock);
    for (size_t k = 0; k < nfal_live_count && !found; ++k) found = nfal_live[k] == instance;
    pthread_mutex_unlock(&nfal_live_lock);
    return instance && found;
}

/* 1 if ``instance`` was live (and is no longer), 0 otherwise. */
static int nfal_live_remove(void *instance)
{
    int found = 0;
    pthread_mutex_lock(&nfal_live_lock);
    for (size_t k = 0; k < nfal_live_count; ++k) {
        if (nfal_live[k] == instance) {
            nfal_live[k] = nfal_live[--nfal_live_count];
            found = 1;
            break;
        }
    }
    pthread_mutex_unlock(&nfal_live_lock);
    return instance && found;
}

/* The one line a failed instantiate logs, through the host's logger, and the same line on stderr: some hosts
   show FMU messages only at a debug level (ecos 0.7.2) and go on with the instance they did not get. */
#if NFAL_FMI_VERSION == 2
static void nfal_log_failure(fmi2String instance, const fmi2CallbackFunctions *functions, const char *message)
{
    if (functions && functions->logger) {
        functions->logger(functions->componentEnvironment, instance ? instance : nfal_model, fmi2Error,
                          "logStatusError", "%s", message);
    }
    fprintf(stderr, "%s (%s FMU): %s\n", instance ? instance : nfal_model, nfal_model, message);
}
#else
static void nfal_log_failure(fmi3String instance, fmi3InstanceEnvironment environment, fmi3LogMessageCallback logger,
                             const char *message)
{
    if (logger) logger(environment, fmi3Error, "logStatusError", message);
    fprintf(stderr, "%s (%s FMU): %s\n", instance ? instance : nfal_model, nfal_model, message);
}
#endif

#include "nfal_forwarders.h" /* generated: the function table and one exported forwarder per FMI function */

/* loader.c on Windows (built with mingw-w64 by fmus/export_runtime.py): the few POSIX calls the loader makes,
 * over the Win32 API. Libraries are loaded by full path with LOAD_WITH_ALTERED_SEARCH_PATH, so a DLL's own
 * dependencies are found beside it (python311.dll's vcruntime140.dll), never on PATH.
 */
#ifndef NFAL_LOADER_WINDOWS_H
#define NFAL_LOADER_WINDOWS_H

#define WIN32_LEAN_AND_MEAN
#include <windows.h>
#include <psapi.h>
#include <errno.h>
#include <fcntl.h>
#include <io.h>
#include <limits.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <wchar.h>

#define NFAL_CONFIG_FILE "python-win64.cfg"
#define NFAL_LIBRARY_SUFFIX ".dll"
#define NFAL_SEPARATOR "\\"
#define NFAL_LIBPYTHON_WORDS "its pythonXY.dll beside it"
#define RTLD_NOW 0
#define RTLD_GLOBAL 0
#define RTLD_LOCAL 0
#ifndef PATH_MAX
#define PATH_MAX MAX_PATH
#endif

static char nfal_dl_message[512];

static const char *dlerror(void)
{
    return nfal_dl_message;
}

static void *dlopen(const char *path, int flags)
{
    (void)flags;
    HMODULE library = LoadLibraryExA(path, NULL, LOAD_WITH_ALTERED_SEARCH_PATH);
    if (!library) {
        DWORD code = GetLastError();
        int n = snprintf(nfal_dl_message, sizeof nfal_dl_message, "Windows error %lu: ", (unsigned long)code);
        FormatMessageA(FORMAT_MESSAGE_FROM_SYSTEM | FORMAT_MESSAGE_IGNORE_INSERTS, NULL, code, 0,
                       nfal_dl_message + n, (DWORD)(sizeof nfal_dl_message - n), NULL);
        size_t end = strlen(nfal_dl_message); /* the message's own line end: the loader reports one line */
        while (end > 0 && (nfal_dl_message[end - 1] == '\n' || nfal_dl_message[end - 1] == '\r')) {
            nfal_dl_message[--end] = '\0';
        }
    }
    return (void *)library;
}

static void *dlsym(void *library, const char *name)
{
    return (void *)GetProcAddress((HMODULE)library, name);
}

/* A symbol of any module of the process (POSIX: dlsym(RTLD_DEFAULT, name)): a Python host's pythonXY.dll. */
static void *nfal_global_symbol(const char *name)
{
    HMODULE modules[1024];
    DWORD needed = 0;
    if (!EnumProcessModules(GetCurrentProcess(), modules, sizeof modules, &needed)) return NULL;
    for (DWORD k = 0; k < needed / sizeof modules[0] && k < 1024; ++k) {
        void *found = (void *)GetProcAddress(modules[k], name);
        if (found) return found;
    }
    return NULL;
}

/* The path of the library holding ``address`` (this loader), into out. */
static void nfal_library_path(const void *address, char *out, size_t size)
{
    HMODULE self = NULL;
    if (GetModuleHandleExA(GET_MODULE_HANDLE_EX_FLAG_FROM_ADDRESS | GET_MODULE_HANDLE_EX_FLAG_UNCHANGED_REFCOUNT,
                           (LPCSTR)address, &self)) {
        GetModuleFileNameA(self, out, (DWORD)size);
    }
}

static char *nfal_last_separator(char *path)
{
    char *slash = strrchr(path, '/'), *backslash = strrchr(path, '\\');
    return slash > backslash ? slash : backslash;
}

/* Whether ``path`` is a file a host could run (POSIX: access(path, X_OK)); errno set when not. */
static int nfal_can_run(const char *path)
{
    DWORD attributes = GetFileAttributesA(path);
    if (attributes == INVALID_FILE_ATTRIBUTES || (attributes & FILE_ATTRIBUTE_DIRECTORY)) {
        errno = ENOENT;
        return 0;
    }
    return 1;
}

#endif

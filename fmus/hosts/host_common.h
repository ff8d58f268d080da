/* What the minimal C hosts (fmi2_host.c, fmi3_host.c) share: symbol lookup and status checks that end
 * the process with the exit codes their usage lines document (1: symbol missing, 3: a call failed). */
#ifndef NFAL_HOST_COMMON_H
#define NFAL_HOST_COMMON_H

#include <stdio.h>
#include <stdlib.h>
#ifdef _WIN32 /* built with mingw-w64 for the Windows bench (nfal.apps.host_check.compile_c_host) */
#include <windows.h>
#define RTLD_NOW 0
#define RTLD_LOCAL 0
static void *dlopen(const char *path, int flags) { (void)flags; return (void *)LoadLibraryA(path); }
static void *dlsym(void *library, const char *name) { return (void *)GetProcAddress((HMODULE)library, name); }
static int dlclose(void *library) { return !FreeLibrary((HMODULE)library); }
static const char *dlerror(void) {
    static char text[64];
    snprintf(text, sizeof text, "Windows error %lu", (unsigned long)GetLastError());
    return text;
}
#else
#include <dlfcn.h>
#endif

static void *symbol(void *library, const char *name) {
    void *found = dlsym(library, name);
    if (!found) {
        printf("missing symbol %s\n", name);
        exit(1);
    }
    return found;
}

static void check(int status, const char *call) {
    if (status != 0) {
        printf("%s returned %d\n", call, status);
        fflush(stdout);
        exit(3);
    }
}

/* dlopen BINARY (RTLD_NOW | RTLD_LOCAL, as fmuCheck does), or exit with 1. */
static void *open_library(const char *binary) {
    void *library = dlopen(binary, RTLD_NOW | RTLD_LOCAL);
    if (!library) {
        printf("dlopen failed: %s\n", dlerror());
        exit(1);
    }
    return library;
}

#endif

/* tar.exe for the Windows test bench under wine 8.0 (nfal/apps/wine.py): never part of an FMU.
 *
 * Windows 10 and later ship tar.exe (bsdtar) in System32, and ecos unpacks every FMU and SSP with
 * "tar -xf ARCHIVE -C DIR"; wine has no tar. This one does that much with the Windows Python's zipfile module
 * (NFAL_PYTHON, the python.exe nfal/apps/wine.py compiles in), and exits with its status.
 */
#include <stdio.h>
#include <string.h>
#include <windows.h>

int main(int argc, char **argv)
{
    const char *archive = NULL, *folder = ".";
    for (int k = 1; k < argc; ++k) {
        if (strcmp(argv[k], "-xf") == 0 && k + 1 < argc) archive = argv[++k];
        else if (strcmp(argv[k], "-C") == 0 && k + 1 < argc) folder = argv[++k];
    }
    if (!archive) {
        fprintf(stderr, "usage: tar -xf ARCHIVE [-C DIR] (nfal's stand-in: extraction only)\n");
        return 2;
    }
    char target[2 * MAX_PATH], command[6 * MAX_PATH];
    int n = snprintf(target, sizeof target, "%s", folder);
    while (n > 1 && (target[n - 1] == '\\' || target[n - 1] == '/')) target[--n] = '\0'; /* no \" at the end */
    n = snprintf(command, sizeof command, "\"%s\" -m zipfile -e \"%s\" \"%s\"", NFAL_PYTHON, archive, target);
    if (n < 0 || (size_t)n >= sizeof command) {
        fprintf(stderr, "tar: paths too long\n");
        return 2;
    }
    SECURITY_ATTRIBUTES inherit = {sizeof inherit, NULL, TRUE};
    HANDLE nothing = CreateFileA("NUL", GENERIC_READ | GENERIC_WRITE, FILE_SHARE_READ | FILE_SHARE_WRITE, &inherit,
                                 OPEN_EXISTING, 0, NULL);
    STARTUPINFOA startup;
    memset(&startup, 0, sizeof startup);
    startup.cb = sizeof startup;
    startup.dwFlags = STARTF_USESTDHANDLES; /* a Python with a file or console handle dies under wine 8.0 */
    startup.hStdInput = startup.hStdOutput = startup.hStdError = nothing;
    PROCESS_INFORMATION child;
    if (!CreateProcessA(NFAL_PYTHON, command, NULL, NULL, TRUE, CREATE_NO_WINDOW, NULL, NULL, &startup, &child)) {
        fprintf(stderr, "tar: cannot run %s (Windows error %lu)\n", NFAL_PYTHON, (unsigned long)GetLastError());
        return 2;
    }
    DWORD status = 2;
    WaitForSingleObject(child.hProcess, INFINITE);
    GetExitCodeProcess(child.hProcess, &status);
    return (int)status;
}

/* The host build: the firmware as a Linux process. The plant channel is stdin/stdout (the emulator's pipes);
 * with --pty the protocol goes on a new pseudo-terminal, whose path is the first line on stderr
 * ("pty /dev/pts/N"); without it, only tunnel mode carries the protocol. */
#define _XOPEN_SOURCE 600
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "nfal_plant.h"

static int pty_master = -1, pty_slave = -1;

void plat_plant_read(uint8_t *p, size_t n) {
    while (n) {
        ssize_t got = read(STDIN_FILENO, p, n);
        if (got > 0) { p += got; n -= (size_t)got; continue; }
        if (got < 0 && errno == EINTR) continue;
        exit(0); /* the emulator closed the channel: the rig is switched off */
    }
}

void plat_plant_write(const uint8_t *p, size_t n) {
    while (n) {
        ssize_t put = write(STDOUT_FILENO, p, n);
        if (put > 0) { p += put; n -= (size_t)put; continue; }
        if (put < 0 && errno == EINTR) continue;
        exit(0);
    }
}

void plat_serial_poll(nfal_fw *fw) {
    uint8_t buf[512];
    ssize_t got;
    if (pty_master < 0) return;
    while ((got = read(pty_master, buf, sizeof buf)) > 0) nfal_fw_rx(fw, buf, (size_t)got);
}

size_t plat_serial_send(const uint8_t *p, size_t n) {
    ssize_t put;
    if (pty_master < 0) return n; /* no line: as a UART with nothing plugged in */
    put = write(pty_master, p, n);
    return put > 0 ? (size_t)put : 0u;
}

uint32_t plat_cycles(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint32_t)((uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec);
}

static int open_pty(void) {
    struct termios raw;
    const char *name;
    pty_master = posix_openpt(O_RDWR | O_NOCTTY);
    if (pty_master < 0 || grantpt(pty_master) || unlockpt(pty_master) || !(name = ptsname(pty_master))) return -1;
    /* keep the slave open here too: writes never fail for want of a reader, and the host may come and go */
    pty_slave = open(name, O_RDWR | O_NOCTTY);
    if (pty_slave < 0 || tcgetattr(pty_slave, &raw)) return -1;
    cfmakeraw(&raw);
    if (tcsetattr(pty_slave, TCSANOW, &raw)) return -1;
    if (fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK)) return -1;
    fprintf(stderr, "pty %s\n", name);
    fflush(stderr);
    return 0;
}

int main(int argc, char **argv) {
    if (argc > 1 && strcmp(argv[1], "--pty") == 0) {
        if (open_pty()) {
            fprintf(stderr, "nfal-fw-host: cannot open a pty: %s\n", strerror(errno));
            return 1;
        }
    } else if (argc > 1) {
        fprintf(stderr, "usage: nfal-fw-host [--pty]   (plant channel on stdin/stdout; see firmware/plant/nfal_plant.h)\n");
        return 2;
    }
    nfal_plant_serve();
    return 0;
}

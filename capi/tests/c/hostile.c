/* Hostile use of the C ABI, from C: each case prints one line "ok CASE" or "FAIL CASE: why"
 * and the program exits 1 if any failed. An alarm ends it (exit 2) if a call blocks, so a
 * FIFO that hung pinrt_open fails the test instead of hanging it.
 *
 * usage: hostile PIN_FILE WORK_DIR */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "pinrt.h"

static int failures = 0;

static void check(int ok, const char *name, const char *why) {
    if (ok) {
        printf("ok %s\n", name);
    } else {
        printf("FAIL %s: %s (last error: %s)\n", name, why, pinrt_last_error());
        failures++;
    }
}

static void on_alarm(int sig) {
    (void)sig;
    static const char msg[] = "FAIL a call blocked for 20 s\n";
    (void)!write(1, msg, sizeof msg - 1);
    _exit(2);
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: hostile PIN_FILE WORK_DIR\n");
        return 2;
    }
    signal(SIGALRM, on_alarm);
    alarm(20);
    const char *pin = argv[1];
    const char *dir = argv[2];
    char path[4096];
    PinrtGrid *grid = NULL;
    PinrtStatus st;

    /* A FIFO: refused at once, never opened for a blocking read. */
    snprintf(path, sizeof path, "%s/fifo.pin", dir);
    if (mkfifo(path, 0600) != 0) {
        perror("mkfifo");
        return 2;
    }
    st = pinrt_open(path, &grid);
    check(st == PINRT_STATUS_IO && grid == NULL && strstr(pinrt_last_error(), "not a regular file"),
          "fifo", "expected PINRT_STATUS_IO, 'not a regular file'");

    /* A directory says so (it said "No such device"). */
    st = pinrt_open(dir, &grid);
    check(st == PINRT_STATUS_IO && strstr(pinrt_last_error(), "is a directory") != NULL,
          "directory", "expected 'is a directory'");

    /* A path with a newline: the message stays one line and names the whole path. */
    snprintf(path, sizeof path, "%s/two\nlines.pin", dir);
    st = pinrt_open(path, &grid);
    {
        const char *m = pinrt_last_error();
        check(st == PINRT_STATUS_IO && strchr(m, '\n') == NULL && strstr(m, "two\\nlines.pin"),
              "newline in path", "expected one line with the escaped name");
    }

    /* A copy that cannot be made: 1 TiB of reserved, unreadable address space. The copy is
     * allocated before a byte is read, so the host gets a status, not an abort. */
    size_t huge = (size_t)1 << 40;
    void *reserved = mmap(NULL, huge, PROT_NONE, MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (reserved != MAP_FAILED) {
        st = pinrt_open_memory(reserved, huge, &grid);
        check(st == PINRT_STATUS_OUT_OF_MEMORY && grid == NULL,
              "uncopyable buffer", "expected PINRT_STATUS_OUT_OF_MEMORY");
        munmap(reserved, huge);
    } else {
        printf("ok uncopyable buffer (skipped: no address space to reserve)\n");
    }

    /* Misaligned pointers, where the header says pointers are alignment-checked. */
    st = pinrt_open(pin, &grid);
    check(st == PINRT_STATUS_OK && grid != NULL, "open", "the test file does not open");
    if (grid != NULL) {
        PinrtRay ray = {{0.5f, 0.5f, -1.0f}, INFINITY, {0.0f, 0.0f, 1.0f}, 0};
        float t = -1.0f;
        _Alignas(8) unsigned char opts_bytes[sizeof(PinrtQueryOptions) + 8];
        memset(opts_bytes, 0, sizeof opts_bytes);
        const PinrtQueryOptions *misaligned = (const PinrtQueryOptions *)(opts_bytes + 1);
        st = pinrt_transmittance(grid, misaligned, &ray, 1, 0, 0, &t);
        check(st == PINRT_STATUS_INVALID_ARGUMENT && strstr(pinrt_last_error(), "opts"),
              "misaligned opts", "expected PINRT_STATUS_INVALID_ARGUMENT naming opts");
        st = pinrt_transmittance((const PinrtGrid *)((const char *)grid + 1), NULL, &ray, 1, 0, 0, &t);
        check(st == PINRT_STATUS_INVALID_ARGUMENT, "misaligned grid",
              "expected PINRT_STATUS_INVALID_ARGUMENT");
        st = pinrt_transmittance(grid, NULL, &ray, 1, 0, 0, &t);
        check(st == PINRT_STATUS_OK && t >= 0.0f && t <= 1.0f, "aligned query", "a good query failed");
        pinrt_close(grid);
    }
    return failures == 0 ? 0 : 1;
}

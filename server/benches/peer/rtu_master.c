/* A libmodbus RTU master for the `suite` benchmark: reads COUNT holding registers from
 * slave 1 on the serial port PATH as fast as libmodbus goes, for SECONDS, and prints
 * "transactions elapsed_seconds". Built by the benchmark with the system's C compiler and
 * Debian's libmodbus-dev (see install.sh).
 * Usage: rtu_master PATH BAUD COUNT SECONDS */
#include <errno.h>
#include <modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec + (double)t.tv_nsec / 1e9;
}

int main(int argc, char **argv) {
    if (argc < 5) {
        fprintf(stderr, "usage: %s PATH BAUD COUNT SECONDS\n", argv[0]);
        return 2;
    }
    int count = atoi(argv[3]);
    double seconds = atof(argv[4]);
    modbus_t *ctx = modbus_new_rtu(argv[1], atoi(argv[2]), 'N', 8, 1);
    if (ctx == NULL || modbus_set_slave(ctx, 1) == -1 || modbus_connect(ctx) == -1) {
        fprintf(stderr, "connect: %s\n", modbus_strerror(errno));
        return 1;
    }
    uint16_t registers[125];
    /* One read first, so that opening the port is not timed. */
    if (modbus_read_registers(ctx, 0, count, registers) != count) {
        fprintf(stderr, "read: %s\n", modbus_strerror(errno));
        return 1;
    }
    long done = 0;
    double start = now(), elapsed = 0;
    while (elapsed < seconds) {
        if (modbus_read_registers(ctx, 0, count, registers) != count) {
            fprintf(stderr, "read: %s\n", modbus_strerror(errno));
            return 1;
        }
        done++;
        elapsed = now() - start;
    }
    printf("%ld %.6f\n", done, elapsed);
    modbus_close(ctx);
    modbus_free(ctx);
    return 0;
}

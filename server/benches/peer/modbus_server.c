/* A libmodbus Modbus TCP server for the `modbus_server` benchmark: the classic select()
 * loop of libmodbus's examples, 8192 holding registers, one process. Built by the benchmark
 * with the system's C compiler and Debian's libmodbus-dev when they are there.
 * Usage: modbus_server PORT */
#include <errno.h>
#include <modbus.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>

int main(int argc, char **argv) {
    if (argc < 2) {
        fprintf(stderr, "usage: %s PORT\n", argv[0]);
        return 2;
    }
    modbus_t *ctx = modbus_new_tcp("127.0.0.1", atoi(argv[1]));
    modbus_mapping_t *map = modbus_mapping_new(0, 0, 8192, 0);
    if (ctx == NULL || map == NULL) {
        return 1;
    }
    for (int i = 0; i < 8192; i++) {
        map->tab_registers[i] = (uint16_t)i;
    }
    int server = modbus_tcp_listen(ctx, 64);
    if (server == -1) {
        fprintf(stderr, "listen: %s\n", modbus_strerror(errno));
        return 1;
    }
    fd_set all;
    FD_ZERO(&all);
    FD_SET(server, &all);
    int max = server;
    printf("ready\n");
    fflush(stdout);
    for (;;) {
        fd_set ready = all;
        if (select(max + 1, &ready, NULL, NULL, NULL) == -1) {
            return 1;
        }
        for (int fd = 0; fd <= max; fd++) {
            if (!FD_ISSET(fd, &ready)) {
                continue;
            }
            if (fd == server) {
                struct sockaddr_in addr;
                socklen_t len = sizeof(addr);
                int conn = accept(server, (struct sockaddr *)&addr, &len);
                if (conn != -1) {
                    FD_SET(conn, &all);
                    if (conn > max) {
                        max = conn;
                    }
                }
            } else {
                uint8_t query[MODBUS_TCP_MAX_ADU_LENGTH];
                modbus_set_socket(ctx, fd);
                int rc = modbus_receive(ctx, query);
                if (rc > 0) {
                    modbus_reply(ctx, query, rc, map);
                } else if (rc == -1) {
                    close(fd);
                    FD_CLR(fd, &all);
                }
            }
        }
    }
}

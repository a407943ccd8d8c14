#!/usr/bin/env python3
"""A controlled station (an RTU) on c104, lib60870's Python binding: common address 1 with
a point of each monitored type, a command point of each kind, prints its port, then one
line per command it executes (`cmd IOA VALUE`, `select IOA` for a select; point 205
confirms its commands 2.5 s late) and per clock
synchronisation (`clock SECONDS`, the time it was set to, as seconds since 1970). Reads lines on
stdin: `set IOA VALUE` changes a point and sends it spontaneously; `invalid IOA` marks it
invalid and sends it.

    rtu.py [PORT]
"""

import datetime
import socket
import sys
import threading
import time

import c104


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    port = int(sys.argv[1]) if len(sys.argv) > 1 else free_port()
    server = c104.Server(ip="127.0.0.1", port=port, select_timeout_ms=5000)
    station = server.add_station(common_address=1)
    points = {}

    def add(ioa, kind, value, **kw):
        p = station.add_point(io_address=ioa, type=kind, **kw)
        if value is not None:
            p.value = value
        points[ioa] = p
        return p

    add(100, c104.Type.M_SP_TB_1, True)
    add(101, c104.Type.M_DP_NA_1, c104.Double.ON)
    add(102, c104.Type.M_ME_NC_1, 12.5)
    add(103, c104.Type.M_ME_TE_1, c104.Int16(-7))
    add(104, c104.Type.M_ME_NA_1, c104.NormalizedFloat(0.5))
    add(105, c104.Type.M_IT_TB_1, 42)
    add(106, c104.Type.M_ST_NA_1, c104.Int7(3))
    add(107, c104.Type.M_BO_NA_1, c104.Byte32(bytes([0xA5])))
    add(108, c104.Type.M_ME_TF_1, 1.25)
    add(109, c104.Type.M_ME_NB_1, c104.Int16(123))

    def on_command(point: c104.Point, previous_info: c104.Information, message: c104.IncomingMessage) -> c104.ResponseState:
        if message.is_select_command:
            print("select", point.io_address, flush=True)
        else:
            print("cmd", point.io_address, message.info.value, flush=True)
        if point.io_address == 205:
            # A slow station: its confirmation 2.5 s after the command.
            time.sleep(2.5)
        return c104.ResponseState.SUCCESS

    for ioa, kind, mode in [
        (200, c104.Type.C_SE_NC_1, c104.CommandMode.SELECT_AND_EXECUTE),
        (201, c104.Type.C_SC_NA_1, c104.CommandMode.DIRECT),
        (202, c104.Type.C_SE_NB_1, c104.CommandMode.DIRECT),
        (203, c104.Type.C_SC_NA_1, c104.CommandMode.DIRECT),
        (204, c104.Type.C_SE_NB_1, c104.CommandMode.DIRECT),
        (205, c104.Type.C_SC_NA_1, c104.CommandMode.DIRECT),
    ]:
        add(ioa, kind, None, command_mode=mode).on_receive(callable=on_command)

    def on_clock_sync(server: c104.Server, ip: str, date_time: datetime.datetime) -> c104.ResponseState:
        print("clock", date_time.timestamp(), flush=True)
        return c104.ResponseState.SUCCESS

    server.on_clock_sync(callable=on_clock_sync)
    server.start()
    print(port, flush=True)
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        p = points[int(words[1])]
        if words[0] == "set":
            v = float(words[2])
            p.value = c104.Int16(int(v)) if p.type == c104.Type.M_ME_TE_1 else v
        elif words[0] == "invalid":
            p.quality = c104.Quality.Invalid
        p.transmit(cause=c104.Cot.SPONTANEOUS)
        print("sent", words[1], flush=True)
    server.stop()


if __name__ == "__main__":
    main()

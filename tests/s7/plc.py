"""A PLC for the S7 driver's tests: Snap7's server (python-snap7) with data blocks, merkers,
inputs, outputs, timers and counters holding one value of every S7 type.

Prints its port, then takes commands on stdin, one a line, answering each with a line:
  stop | run                      the CPU's state as SZL tells it
  dump AREA NUMBER START LENGTH   the bytes it holds (AREA: DB MK PE PA TM CT), in hex
  set AREA NUMBER START HEX       bytes written there, as another client would
Ends when stdin closes.
"""

import argparse
import ctypes
import socket
import struct
import sys

from snap7.server import Server
from snap7.type import SrvArea

# Snap7's server: S7CpuStatusRun / S7CpuStatusStop.
RUN, STOP = 8, 4


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def put(buf, at, data):
    for i, b in enumerate(data):
        buf[at + i] = b


def db1():
    b = (ctypes.c_uint8 * 256)()
    put(b, 0, struct.pack(">Bbhiq", 0b10101010, -5, -300, 100000, -(2**40)))
    put(b, 16, struct.pack(">fdB", 1.5, 2.25, 200))
    put(b, 29, b"Z")
    put(b, 30, struct.pack(">HIQ", 60000, 4000000000, 2**63 + 5))
    put(b, 44, struct.pack(">HIQi", 0xBEEF, 0xDEADBEEF, 0x0123456789ABCDEF, -1500))
    put(b, 62, "Ω".encode("utf-16-be"))
    put(b, 64, bytes([20, 5]) + b"press")
    put(b, 88, struct.pack(">h", 250))
    put(b, 100, bytes([100, 4]) + b"tail")
    put(b, 254, struct.pack(">h", 258))
    return b


def db2():
    b = (ctypes.c_uint8 * 64)()
    # DATE_AND_TIME 2026-11-26 16:50:45.123, a Thursday (5).
    put(b, 0, bytes([0x26, 0x11, 0x26, 0x16, 0x50, 0x45, 0x12, 0x35]))
    # DTL 2026-11-26 16:50:45.123456789.
    dtl = struct.pack(">HBBBBBBI", 2026, 11, 26, 5, 16, 50, 45, 123456789)
    put(b, 8, dtl)
    word = "Grüße".encode("utf-16-be")
    put(b, 20, struct.pack(">HH", 10, 5) + word)
    put(b, 44, dtl)
    return b


def db3():
    b = (ctypes.c_uint8 * 300)()
    text = bytes(ord("a") + i % 26 for i in range(200))
    put(b, 0, bytes([254, len(text)]) + text)
    return b


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, default=0)
    args = ap.parse_args()
    port = args.port or free_port()
    areas = {
        ("DB", 1): db1(),
        ("DB", 2): db2(),
        ("DB", 3): db3(),
        ("MK", 0): (ctypes.c_uint8 * 32)(),
        ("PE", 0): (ctypes.c_uint8 * 16)(),
        ("PA", 0): (ctypes.c_uint8 * 16)(),
        ("TM", 0): (ctypes.c_uint8 * 16)(),
        ("CT", 0): (ctypes.c_uint8 * 16)(),
    }
    put(areas[("MK", 0)], 0, bytes([0b00001000]))
    put(areas[("MK", 0)], 10, struct.pack(">h", 1234))
    put(areas[("PE", 0)], 0, bytes([0x80, 0, 0x12, 0x34]))
    put(areas[("PA", 0)], 4, bytes([0x5A]))
    # Snap7's server keeps timer or counter n at byte n / 2: timer 4 is 2.5 s (S5TIME, base
    # 100 ms), counter 6 is 123.
    put(areas[("TM", 0)], 2, bytes([0x10, 0x25]))
    put(areas[("CT", 0)], 3, bytes([0x01, 0x23]))
    srv = Server(log=False)
    for (kind, number), buf in areas.items():
        srv.register_area(getattr(SrvArea, kind), number, buf)
    srv.start(tcp_port=port)
    print(port, flush=True)
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        if words[0] in ("stop", "run"):
            srv.set_cpu_status(STOP if words[0] == "stop" else RUN)
            print("ok", flush=True)
        elif words[0] == "dump":
            kind, number, start, length = words[1], int(words[2]), int(words[3]), int(words[4])
            buf = areas[(kind, number)]
            print(bytes(buf[start:start + length]).hex(), flush=True)
        elif words[0] == "set":
            # What another client (an HMI, the PLC's program) writes: bytes in an area.
            kind, number, start, data = words[1], int(words[2]), int(words[3]), bytes.fromhex(words[4])
            put(areas[(kind, number)], start, data)
            print("ok", flush=True)
        else:
            print("unknown command", flush=True)
    srv.stop()


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""A controlling station reduced to its wire, for the IEC 104 outstation's benchmark: starts
data transfer on HOST:PORT, acknowledges every w (8) I-frames at once from its own thread (and
what came once the line is quiet for 100 ms),
answers TESTFR, and reads the time tag (CP56Time2a, UTC) of every time-tagged object of
every spontaneous ASDU as it arrives, so what it measures is the outstation and the
socket, not a master's processing of each object (c104's Python callbacks). Says `ready`
once data transfer is confirmed; then reads lines on stdin:

    stats -> `stats N P50 P99 MAX`: the spontaneous objects since the last `stats`, and the
             milliseconds from their time tags to their arrival

    wire_master.py HOST PORT
"""

import calendar
import socket
import struct
import sys
import threading
import time

# Time-tagged monitor types: (type id, octets of the element before the time tag).
TAGGED = {30: 1, 31: 1, 32: 2, 33: 5, 34: 3, 35: 3, 36: 5, 37: 5}
W = 8
SPONTANEOUS = 3

lock = threading.Lock()
delays = []


def stamp_ms(t):
    millis, minute, hour, day, month, year = struct.unpack_from("<HBBBBB", t)
    seconds = calendar.timegm((2000 + (year & 0x7F), month & 0x0F, day & 0x1F,
                               hour & 0x1F, minute & 0x3F, 0, 0, 0, 0))
    return seconds * 1000 + millis


def objects(asdu, now_ms):
    ty, vsq, cot = asdu[0], asdu[1], asdu[2] & 0x3F
    size = TAGGED.get(ty)
    if size is None or cot != SPONTANEOUS or vsq & 0x80:
        return
    step = 3 + size + 7
    found = []
    for k in range(vsq & 0x7F):
        at = 6 + k * step + 3 + size
        if at + 7 <= len(asdu):
            found.append(now_ms - stamp_ms(asdu[at:at + 7]))
    with lock:
        delays.extend(found)


def receive(sock, started):
    buf = b""
    received = 0
    unacked = 0
    sock.settimeout(0.1)
    while True:
        try:
            data = sock.recv(65536)
        except socket.timeout:
            # t2 of 100 ms: what came is acknowledged once the line is quiet.
            if unacked:
                sock.sendall(struct.pack("<BBHH", 0x68, 4, 1, received << 1))
                unacked = 0
            continue
        if not data:
            return
        now_ms = time.time() * 1000
        buf += data
        while len(buf) >= 2 and len(buf) >= buf[1] + 2:
            frame, buf = buf[:buf[1] + 2], buf[buf[1] + 2:]
            control = frame[2]
            if control & 1 == 0:
                received = (received + 1) % 32768
                unacked += 1
                objects(frame[6:], now_ms)
                if unacked >= W:
                    sock.sendall(struct.pack("<BBHH", 0x68, 4, 1, received << 1))
                    unacked = 0
            elif control == 0x0B:
                started.set()
            elif control == 0x43:
                sock.sendall(bytes([0x68, 4, 0x83, 0, 0, 0]))


def main():
    host, port = sys.argv[1], int(sys.argv[2])
    sock = socket.create_connection((host, port))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    started = threading.Event()
    threading.Thread(target=receive, args=(sock, started), daemon=True).start()
    sock.sendall(bytes([0x68, 4, 0x07, 0, 0, 0]))
    started.wait(30)
    print("ready", flush=True)
    for line in sys.stdin:
        if line.split()[:1] == ["stats"]:
            with lock:
                taken = sorted(delays)
                delays.clear()
            at = lambda q: round(taken[min(len(taken) - 1, int(len(taken) * q))], 1) if taken else 0
            print("stats", len(taken), at(0.5), at(0.99), at(1.0), flush=True)


if __name__ == "__main__":
    main()

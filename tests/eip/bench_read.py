#!/usr/bin/env python3
"""The EtherNet/IP benchmark's reference client: pylogix (not the gateway's code).

    bench_read.py PORT TAGS SECONDS LAYOUT

LAYOUT `tags`: reads tags T0 .. T{TAGS-1} in one call (pylogix packs them in Multiple
Service Packets); `array`: reads TAGS elements of Counts from Counts[0] in one call (its
array read). Again and again for SECONDS; prints {"cycles": N, "seconds": S, "good": G}
(G: the values of the last cycle read without error).
"""
import json
import sys
import time

from pylogix import PLC

port, count, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
array = sys.argv[4] == "array"
tags = [f"T{i}" for i in range(count)]


def cycle(plc):
    if array:
        r = plc.Read("Counts[0]", count)
        return len(r.Value) if r.Status == "Success" else 0
    return sum(1 for r in plc.Read(tags) if r.Status == "Success")


with PLC() as plc:
    plc.IPAddress = "127.0.0.1"
    plc.Port = port
    cycle(plc)  # connection and tag types learned before the clock starts
    cycles, start, good = 0, time.monotonic(), 0
    while time.monotonic() - start < seconds:
        good = cycle(plc)
        cycles += 1
    took = time.monotonic() - start
print(json.dumps({"cycles": cycles, "seconds": took, "good": good}))

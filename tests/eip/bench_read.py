#!/usr/bin/env python3
"""The EtherNet/IP benchmark's reference client: pylogix (not the gateway's code).

    bench_read.py PORT TAGS SECONDS

Reads tags Counts[0] .. Counts[TAGS-1] in one call (pylogix packs them in Multiple Service
Packets) again and again for SECONDS, and prints {"cycles": N, "seconds": S, "good": G}
(G: the tags of the last cycle read without error).
"""
import json
import sys
import time

from pylogix import PLC

port, count, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
tags = [f"Counts[{i}]" for i in range(count)]
with PLC() as plc:
    plc.IPAddress = "127.0.0.1"
    plc.Port = port
    plc.Read(tags)  # connection and tag types learned before the clock starts
    cycles, start, last = 0, time.monotonic(), []
    while time.monotonic() - start < seconds:
        last = plc.Read(tags)
        cycles += 1
    took = time.monotonic() - start
print(json.dumps({"cycles": cycles, "seconds": took,
                  "good": sum(1 for r in last if r.Status == "Success")}))

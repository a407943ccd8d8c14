#!/usr/bin/env python3
"""Reads tags of a Logix controller with pylogix (not the gateway's code).

    read.py PORT TAG ...

Prints one JSON object: each tag's value, or {"error": STATUS} when the read failed.
"""
import json
import sys

from pylogix import PLC

port, tags = int(sys.argv[1]), sys.argv[2:]
with PLC() as plc:
    plc.IPAddress = "127.0.0.1"
    plc.Port = port
    out = {}
    for r in plc.Read(tags):
        out[r.TagName] = r.Value if r.Status == "Success" else {"error": r.Status}
print(json.dumps(out))

#!/usr/bin/env python3
"""Writes tags of a Logix controller with pylogix (not the gateway's code).

    write.py PORT TAG=VALUE ...

VALUE is an integer, a float (with a dot) or true/false. Prints one JSON object: each
tag's status ("Success" when written).
"""
import json
import sys

from pylogix import PLC


def value(text):
    if text in ("true", "false"):
        return text == "true"
    return float(text) if "." in text else int(text, 0)


port, pairs = int(sys.argv[1]), [a.split("=", 1) for a in sys.argv[2:]]
with PLC() as plc:
    plc.IPAddress = "127.0.0.1"
    plc.Port = port
    out = {tag: plc.Write(tag, value(v)).Status for tag, v in pairs}
print(json.dumps(out))

#!/usr/bin/env python3
"""A pymodbus RTU slave described by JSON, for the scan tests: one unit with its four tables
and, optionally, its device identification (FC 43 / MEI 14); it keeps quiet for every other
unit id, as a slave on a shared line does; serves until killed.

    scan_slave.py PORT BAUD SPEC

SPEC: {"unit": 3, "coils": {"0": [1, 0]}, "discrete": {...}, "holding": {"0": [1, 2]},
       "input": {...}, "identity": {"VendorName": "...", "ProductCode": "...",
       "MajorMinorRevision": "..."}}
Tables map a start address to its values; every other address answers exception 02, but
with "everywhere": true every address of every table answers (zeros where not given), as
many simple devices and gateways do.
"""

import json
import sys

from pymodbus import FramerType, ModbusDeviceIdentification
from pymodbus.datastore import ModbusDeviceContext, ModbusServerContext, ModbusSparseDataBlock
from pymodbus.server import StartSerialServer


EVERYWHERE = False


def block(table, bits):
    values = {a: (False if bits else 0) for a in range(65536)} if EVERYWHERE else {}
    for start, items in table.items():
        for i, v in enumerate(items):
            values[int(start) + i] = bool(v) if bits else int(v)
    # An empty table still needs a block: one value far from anything a scan reads.
    return ModbusSparseDataBlock(values or {65000: 0})


def main():
    global EVERYWHERE
    port, baud, spec = sys.argv[1], int(sys.argv[2]), json.loads(sys.argv[3])
    EVERYWHERE = bool(spec.get("everywhere"))
    identity = None
    if "identity" in spec:
        identity = ModbusDeviceIdentification(info_name=spec["identity"])
    unit = ModbusDeviceContext(
        co=block(spec.get("coils", {}), True),
        di=block(spec.get("discrete", {}), True),
        hr=block(spec.get("holding", {}), False),
        ir=block(spec.get("input", {}), False),
    )
    context = ModbusServerContext(devices={spec["unit"]: unit}, single=False)
    print("serving", flush=True)
    StartSerialServer(
        context=context,
        framer=FramerType.RTU,
        identity=identity,
        ignore_missing_devices=True,
        port=port,
        baudrate=baud,
        parity="N",
        bytesize=8,
        stopbits=1,
    )


if __name__ == "__main__":
    main()

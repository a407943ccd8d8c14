#!/usr/bin/env python3
"""A pymodbus serial master (RTU or ASCII) that reads and writes the gateway's Modbus map
through its serial server, with every function code, a broadcast and a wrong unit id, and
prints what it got as one JSON object.

    master.py PORT rtu|ascii UNIT BAUD PARITY DATA_BITS
"""

import json
import sys
import time

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusException


def main():
    port, framing, unit = sys.argv[1], sys.argv[2], int(sys.argv[3])
    baud, parity, data_bits = int(sys.argv[4]), sys.argv[5], int(sys.argv[6])
    framer = FramerType.RTU if framing == "rtu" else FramerType.ASCII
    client = ModbusSerialClient(
        port=port,
        framer=framer,
        baudrate=baud,
        parity=parity,
        bytesize=data_bits,
        stopbits=1,
        timeout=0.5,
        retries=0,
    )
    if not client.connect():
        print(json.dumps({"error": "cannot open " + port}))
        return 1
    out = {}

    def call(name, fn, pick):
        try:
            r = fn()
        except ModbusException as e:
            out[name] = {"no_answer": str(e)}
            return
        if r.isError():
            out[name] = {"exception": getattr(r, "exception_code", None)}
        else:
            out[name] = pick(r)

    regs = lambda r: list(r.registers)
    bits = lambda r: [bool(b) for b in r.bits]
    ok = lambda r: "ok"

    call("fc16", lambda: client.write_registers(1024, [11, 22, 33], device_id=unit), ok)
    call("fc03", lambda: client.read_holding_registers(1024, count=3, device_id=unit), regs)
    call("fc06", lambda: client.write_register(1027, 44, device_id=unit), ok)
    call("fc03_single", lambda: client.read_holding_registers(1027, count=1, device_id=unit), regs)
    call("fc15", lambda: client.write_coils(800, [True, False, True], device_id=unit), ok)
    call("fc01", lambda: client.read_coils(800, count=3, device_id=unit), lambda r: bits(r)[:3])
    call("fc05", lambda: client.write_coil(0, True, device_id=unit), ok)
    call("fc02", lambda: client.read_discrete_inputs(800, count=1, device_id=unit), lambda r: bits(r)[:1])
    call("fc04", lambda: client.read_input_registers(0, count=1, device_id=unit), regs)
    call("illegal_address", lambda: client.read_holding_registers(9000, count=2, device_id=unit), regs)
    call("illegal_function", lambda: client.read_exception_status(device_id=unit), ok)
    # A broadcast: applied by every slave, answered by none.
    try:
        client.write_register(1030, 555, device_id=0, no_response_expected=True)
        out["broadcast"] = "sent"
    except ModbusException as e:
        out["broadcast"] = {"error": str(e)}
    time.sleep(0.2)
    call("other_unit", lambda: client.read_holding_registers(1024, count=1, device_id=unit + 1), regs)
    call("after_broadcast", lambda: client.read_holding_registers(1030, count=1, device_id=unit), regs)
    client.close()
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())

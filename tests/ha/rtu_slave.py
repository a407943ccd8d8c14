#!/usr/bin/env python3
"""A pymodbus slave speaking Modbus RTU frames over TCP, as a serial device server passes
them on: unit 1 holds holding registers 0-19 (0). Prints its port, then one line for every
write request it is sent, as it receives it: `write ADDRESS VALUE...`. Serves until killed.

    rtu_slave.py
"""

import asyncio
import logging

from pymodbus import FramerType
from pymodbus.logging import Log
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice


def logged(sending, pdu):
    """Prints each write request received (function 6 or 16), before it is executed."""
    if not sending and pdu.function_code in (6, 16):
        values = pdu.registers if pdu.function_code == 16 else [pdu.registers[0]]
        print("write", pdu.address, *values, flush=True)
    return pdu


async def main():
    # A master that closes before its answer is sent is how a takeover looks: not news.
    Log.setLevel(logging.CRITICAL)
    device = SimDevice(
        id=1,
        simdata=[SimData(0, count=20, values=[0] * 20, datatype=DataType.REGISTERS)],
    )
    server = ModbusTcpServer(
        context=device,
        framer=FramerType.RTU,
        address=("127.0.0.1", 0),
        trace_pdu=logged,
    )
    await server.serve_forever(background=True)
    print(server.transport.sockets[0].getsockname()[1], flush=True)
    await server.serving


if __name__ == "__main__":
    asyncio.run(main())

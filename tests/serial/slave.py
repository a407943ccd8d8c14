#!/usr/bin/env python3
"""A pymodbus serial slave (RTU or ASCII) for the gateway's links to poll: unit UNIT holds
holding registers 0-19 = 1000, 1001, ... 1019; serves until killed.

    slave.py PORT rtu|ascii UNIT BAUD PARITY DATA_BITS
"""

import sys

from pymodbus import FramerType
from pymodbus.server import StartSerialServer
from pymodbus.simulator import DataType, SimData, SimDevice


def main():
    port, framing, unit = sys.argv[1], sys.argv[2], int(sys.argv[3])
    baud, parity, data_bits = int(sys.argv[4]), sys.argv[5], int(sys.argv[6])
    device = SimDevice(
        id=unit,
        simdata=[SimData(0, count=20, values=[1000 + i for i in range(20)], datatype=DataType.REGISTERS)],
    )
    print("serving", flush=True)
    StartSerialServer(
        context=device,
        framer=FramerType.RTU if framing == "rtu" else FramerType.ASCII,
        port=port,
        baudrate=baud,
        parity=parity,
        bytesize=data_bits,
        stopbits=1,
    )


if __name__ == "__main__":
    main()

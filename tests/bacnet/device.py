"""An independent BACnet/IP device for the BACnet driver's tests: bacpypes3 serving one
object of each kind the driver reads (analog, binary and multi-state inputs, outputs and
values), on 127.0.0.1 at a free port (printed first), driven one command per line:

    get OBJECT PROPERTY        the property's value as the device holds it
    priority OBJECT N          what the object's priority array holds at N (1-16): null or a value
    set OBJECT VALUE           the present value changed on the device (as its program would)
    flags OBJECT FAULT|OOS|OK  its status flags (fault, out of service) or back to normal
                               (through its reliability and out-of-service)
    subscriptions              how many change-of-value subscriptions the device holds
    quit
"""

import argparse
import asyncio
import socket
import sys

from bacpypes3.app import Application
from bacpypes3.argparse import SimpleArgumentParser
from bacpypes3.local.analog import AnalogInputObject, AnalogOutputObject, AnalogValueObjectCmd
from bacpypes3.local.binary import BinaryInputObject, BinaryOutputObject, BinaryValueObjectCmd
from bacpypes3.local.multistate import (
    MultiStateInputObject,
    MultiStateOutputObject,
    MultiStateValueObject,
)
from bacpypes3.local.cov import GenericCriteria
from bacpypes3.primitivedata import ObjectIdentifier


# bacpypes3 0.0.110 gives multi-state objects the COV increment criteria of analog ones, so a
# subscribed multi-state object fails every write of its present value (it has no COV
# increment); the standard's criteria for them are the generic ones (Table 13-1).
class MultiStateInputObject(MultiStateInputObject):
    _cov_criteria = GenericCriteria


class MultiStateOutputObject(MultiStateOutputObject):
    _cov_criteria = GenericCriteria


class MultiStateValueObject(MultiStateValueObject):
    _cov_criteria = GenericCriteria


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def objects():
    return [
        AnalogInputObject(
            objectIdentifier=("analog-input", 1),
            objectName="Temperature",
            presentValue=21.5,
            units="degreesCelsius",
            statusFlags=[0, 0, 0, 0],
            reliability="noFaultDetected",
            covIncrement=0.1,
        ),
        AnalogOutputObject(
            objectIdentifier=("analog-output", 1),
            objectName="Valve",
            presentValue=0.0,
            units="percent",
            covIncrement=0.1,
            statusFlags=[0, 0, 0, 0],
            relinquishDefault=0.0,
        ),
        AnalogValueObjectCmd(
            objectIdentifier=("analog-value", 1),
            objectName="Setpoint",
            presentValue=20.0,
            units="degreesCelsius",
            covIncrement=0.1,
            statusFlags=[0, 0, 0, 0],
            relinquishDefault=18.0,
        ),
        BinaryInputObject(
            objectIdentifier=("binary-input", 1),
            objectName="Alarm",
            presentValue="inactive",
            statusFlags=[0, 0, 0, 0],
        ),
        BinaryOutputObject(
            objectIdentifier=("binary-output", 1),
            objectName="Fan",
            presentValue="inactive",
            statusFlags=[0, 0, 0, 0],
            relinquishDefault="inactive",
        ),
        BinaryValueObjectCmd(
            objectIdentifier=("binary-value", 1),
            objectName="Enable",
            presentValue="active",
            statusFlags=[0, 0, 0, 0],
            relinquishDefault="inactive",
        ),
        MultiStateInputObject(
            objectIdentifier=("multi-state-input", 1),
            objectName="Mode",
            presentValue=2,
            numberOfStates=3,
            statusFlags=[0, 0, 0, 0],
        ),
        MultiStateOutputObject(
            objectIdentifier=("multi-state-output", 1),
            objectName="Speed",
            presentValue=1,
            numberOfStates=4,
            statusFlags=[0, 0, 0, 0],
            relinquishDefault=1,
        ),
        MultiStateValueObject(
            objectIdentifier=("multi-state-value", 1),
            objectName="Season",
            presentValue=1,
            numberOfStates=4,
            statusFlags=[0, 0, 0, 0],
        ),
    ]


async def commands(app: Application) -> None:
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while True:
        line = (await reader.readline()).decode().split()
        if not line or line[0] == "quit":
            return
        if line[0] == "subscriptions":
            held = sum(len(d.cov_subscriptions) for d in app._cov_detections.values())
            print(held, flush=True)
            continue
        try:
            obj = app.get_object_id(ObjectIdentifier(line[1]))
            if line[0] == "get":
                value = getattr(obj, line[2])
                print(str(value) if not hasattr(value, "asn1") else value, flush=True)
            elif line[0] == "priority":
                slot = obj.priorityArray[int(line[2]) - 1]
                held = [
                    getattr(slot, k)
                    for k in ("real", "enumerated", "unsigned", "integer", "boolean", "double")
                    if getattr(slot, k, None) is not None
                ]
                print(held[0] if held else "null", flush=True)
            elif line[0] == "set":
                kind = line[1].split(",")[0]
                text = line[2]
                if kind.startswith("analog"):
                    obj.presentValue = float(text)
                elif kind.startswith("binary"):
                    obj.presentValue = text
                else:
                    obj.presentValue = int(text)
                print("ok", flush=True)
            elif line[0] == "flags":
                # bacpypes3 makes the status flags of a local object from these.
                obj.reliability = "unreliableOther" if line[2] == "FAULT" else "noFaultDetected"
                obj.outOfService = line[2] == "OOS"
                print("ok", flush=True)
            else:
                print(f"error: unknown command {line[0]}", flush=True)
        except Exception as e:  # a bad command is said, the device goes on
            print(f"error: {e}", flush=True)


async def main() -> None:
    parser = SimpleArgumentParser()
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--host", default="127.0.0.1")
    args = parser.parse_args()
    port = args.port or free_port()
    args.address = f"{args.host}/32:{port}"
    app = Application.from_args(args)
    for obj in objects():
        app.add_object(obj)
    print(port, flush=True)
    await commands(app)
    app.close()


if __name__ == "__main__":
    asyncio.run(main())

"""A second, independent BACnet/IP device for the BACnet driver's tests: the original bacpypes
(0.19, its own stack, not bacpypes3), serving commandable objects of the kinds bacpypes3's
device does not have (integer, positive integer, large analog and character string values)
beside an analog input and commandable analog, binary and multi-state values, with
change-of-value services, on a host of its own (127.0.0.2 by default) at a free port (printed
first; `--no-rpm`: without ReadPropertyMultiple), driven one command per line:

    get OBJECT PROPERTY        the property's value as the device holds it
    priority OBJECT N          what the object's priority array holds at N (1-16): null or a value
    set OBJECT VALUE           the present value changed on the device (as its program would)
    quit
"""

import argparse
import socket
import sys
import threading

from bacpypes.app import BIPSimpleApplication
from bacpypes.core import deferred, run, stop
from bacpypes.local.device import LocalDeviceObject
from bacpypes.local.object import (
    AnalogValueCmdObject,
    BinaryValueCmdObject,
    CharacterStringValueCmdObject,
    IntegerValueCmdObject,
    LargeAnalogValueCmdObject,
    MultiStateValueCmdObject,
    PositiveIntegerValueCmdObject,
)
from bacpypes.object import AnalogInputObject, register_object_type
from bacpypes.service.cov import ChangeOfValueServices
from bacpypes.service.object import ReadWritePropertyMultipleServices


class Device(BIPSimpleApplication, ReadWritePropertyMultipleServices, ChangeOfValueServices):
    pass


class SmallDevice(BIPSimpleApplication, ChangeOfValueServices):
    """A device without ReadPropertyMultiple (as many small controllers are): it rejects the
    service as unrecognized."""


# bacpypes builds an object class's property table when the class is registered; its
# commandable classes are not (they would replace the standard ones for decoding), so their
# writable present value is registered here under a vendor of its own.
for commandable in (
    AnalogValueCmdObject,
    BinaryValueCmdObject,
    CharacterStringValueCmdObject,
    IntegerValueCmdObject,
    LargeAnalogValueCmdObject,
    MultiStateValueCmdObject,
    PositiveIntegerValueCmdObject,
):
    register_object_type(commandable, vendor_id=999)


def free_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def objects():
    return [
        AnalogInputObject(
            objectIdentifier=("analogInput", 1),
            objectName="Outside",
            presentValue=4.5,
            units="degreesCelsius",
            statusFlags=[0, 0, 0, 0],
            eventState="normal",
            outOfService=False,
            reliability="noFaultDetected",
            covIncrement=0.1,
        ),
        AnalogValueCmdObject(
            objectIdentifier=("analogValue", 1),
            objectName="Setpoint",
            presentValue=20.0,
            units="degreesCelsius",
            statusFlags=[0, 0, 0, 0],
            eventState="normal",
            outOfService=False,
            covIncrement=0.1,
            relinquishDefault=18.0,
        ),
        BinaryValueCmdObject(
            objectIdentifier=("binaryValue", 1),
            objectName="Occupied",
            presentValue="inactive",
            statusFlags=[0, 0, 0, 0],
            eventState="normal",
            outOfService=False,
            relinquishDefault="inactive",
        ),
        MultiStateValueCmdObject(
            objectIdentifier=("multiStateValue", 1),
            objectName="Mode",
            presentValue=1,
            numberOfStates=4,
            statusFlags=[0, 0, 0, 0],
            eventState="normal",
            outOfService=False,
            relinquishDefault=1,
        ),
        IntegerValueCmdObject(
            objectIdentifier=("integerValue", 1),
            objectName="Offset",
            presentValue=-3,
            covIncrement=1,
            statusFlags=[0, 0, 0, 0],
            relinquishDefault=0,
        ),
        PositiveIntegerValueCmdObject(
            objectIdentifier=("positiveIntegerValue", 1),
            objectName="Count",
            presentValue=7,
            covIncrement=1,
            statusFlags=[0, 0, 0, 0],
            relinquishDefault=0,
        ),
        LargeAnalogValueCmdObject(
            objectIdentifier=("largeAnalogValue", 1),
            objectName="Energy",
            presentValue=1234567.25,
            covIncrement=0.1,
            statusFlags=[0, 0, 0, 0],
            relinquishDefault=0.0,
        ),
        CharacterStringValueCmdObject(
            objectIdentifier=("characterstringValue", 1),
            objectName="Label",
            presentValue="north wing",
            statusFlags=[0, 0, 0, 0],
            relinquishDefault="",
        ),
    ]


def held(value) -> str:
    """A priority array slot or a property as text."""
    if value is None:
        return "null"
    if hasattr(value, "null") and value.null is not None:
        return "null"
    for k in ("real", "enumerated", "unsigned", "integer", "boolean", "double", "characterString"):
        v = getattr(value, k, None)
        if v is not None:
            return str(v)
    return str(value)


def answer(app: Device, line: list) -> str:
    obj = app.get_object_id(tuple_of(line[1]))
    if obj is None:
        return f"error: no object {line[1]}"
    if line[0] == "get":
        return held(obj.ReadProperty(line[2]))
    if line[0] == "priority":
        return held(obj.priorityArray[int(line[2])])
    if line[0] == "set":
        kind = line[1].split(",")[0]
        text = " ".join(line[2:])
        if kind in ("analogInput", "analogValue", "largeAnalogValue"):
            value = float(text)
        elif kind in ("integerValue", "positiveIntegerValue", "multiStateValue"):
            value = int(text)
        else:
            value = text
        # As the device's own program would: its present value, and what COV tells.
        obj.WriteProperty("presentValue", value, direct=True)
        return "ok"
    return f"error: unknown command {line[0]}"


def tuple_of(text: str):
    kind, instance = text.split(",")
    return (kind, int(instance))


def commands(app: Device) -> None:
    for raw in sys.stdin:
        line = raw.split()
        if not line or line[0] == "quit":
            break
        done = threading.Event()
        said = []

        def step(line=line):
            try:
                said.append(answer(app, line))
            except Exception as e:  # a bad command is said, the device goes on
                said.append(f"error: {e}")
            done.set()

        deferred(step)
        done.wait()
        print(said[0], flush=True)
    deferred(stop)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--host", default="127.0.0.2")
    parser.add_argument("--instance", type=int, default=2002)
    parser.add_argument("--no-rpm", action="store_true", help="no ReadPropertyMultiple")
    args = parser.parse_args()
    port = free_port(args.host)
    device = LocalDeviceObject(
        objectName="legacy",
        objectIdentifier=("device", args.instance),
        maxApduLengthAccepted=1024,
        segmentationSupported="segmentedBoth",
        vendorIdentifier=15,
    )
    kind = SmallDevice if args.no_rpm else Device
    app = kind(device, f"{args.host}/32:{port}")
    for obj in objects():
        app.add_object(obj)
    print(port, flush=True)
    threading.Thread(target=commands, args=(app,), daemon=True).start()
    run()


if __name__ == "__main__":
    main()

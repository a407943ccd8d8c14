"""Many BACnet devices behind one IP address, as a BACnet router with an MS/TP trunk or a
multi-device controller has them: bacpypes3 routing between BACnet/IP (network 1, on HOST
at PORT, a BBMD that takes foreign devices) and a virtual network (network 2) of COUNT
devices, device instances BASE+1 to
BASE+COUNT, each with analog-input:1 to analog-input:OBJECTS holding its own number (k for
device BASE+k) and analog-value:1, commandable. The router's own device is BASE. Prints "ready", then takes
commands one per line:

    get INSTANCE OBJECT PROPERTY   a property of a device behind the router
    set INSTANCE OBJECT VALUE      a present value changed on that device
    quit
"""

import argparse
import asyncio
import sys

from bacpypes3.app import Application
from bacpypes3.local.analog import AnalogInputObject, AnalogValueObjectCmd
from bacpypes3.local.device import DeviceObject
from bacpypes3.local.networkport import NetworkPortObject
from bacpypes3.primitivedata import ObjectIdentifier
from bacpypes3.vlan import VirtualNetwork


def device(instance: int, name: str) -> DeviceObject:
    return DeviceObject(
        objectIdentifier=("device", instance),
        objectName=name,
        vendorIdentifier=999,
    )


def virtual_port(mac: int, network: int) -> NetworkPortObject:
    return NetworkPortObject(
        None,
        objectIdentifier=("network-port", 2),
        objectName="VirtualPort",
        networkType="virtual",
        protocolLevel="bacnet-application",
        macAddress=bytes([mac]),
        networkInterfaceName="vlan",
        networkNumber=network,
        networkNumberQuality="configured",
        statusFlags=[0, 0, 0, 0],
        reliability="no-fault-detected",
        outOfService=False,
        changesPending=False,
        linkSpeed=0.0,
    )


async def commands(apps) -> None:
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    while True:
        line = (await reader.readline()).decode().split()
        if not line or line[0] == "quit":
            return
        try:
            obj = apps[int(line[1])].get_object_id(ObjectIdentifier(line[2]))
            if line[0] == "get":
                print(getattr(obj, line[3]), flush=True)
            elif line[0] == "set":
                obj.presentValue = float(line[3])
                print("ok", flush=True)
            else:
                print(f"error: unknown command {line[0]}", flush=True)
        except Exception as e:  # a bad command is said, the router goes on
            print(f"error: {e}", flush=True)


async def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--host", default="127.0.0.2")
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--base", type=int, default=3000)
    parser.add_argument("--count", type=int, default=3)
    parser.add_argument("--objects", type=int, default=1, help="analog inputs a device")
    args = parser.parse_args()
    VirtualNetwork("vlan")
    router = Application.from_object_list(
        [
            device(args.base, "Router"),
            NetworkPortObject(
                f"{args.host}/32:{args.port}",
                objectIdentifier=("network-port", 1),
                objectName="IPPort",
                networkNumber=1,
                networkNumberQuality="configured",
                bacnetIPMode="bbmd",
                bbmdAcceptFDRegistrations=True,
                bbmdBroadcastDistributionTable=[],
                bbmdForeignDeviceTable=[],
            ),
            virtual_port(1, 2),
        ]
    )
    apps = {}
    for k in range(1, args.count + 1):
        instance = args.base + k
        apps[instance] = Application.from_object_list(
            [
                device(instance, f"Vav{k}"),
                virtual_port(k + 1, 2),
                *[
                    AnalogInputObject(
                        objectIdentifier=("analog-input", i),
                        objectName="Flow" if i == 1 else f"Input{i}",
                        presentValue=float(k),
                        units="litersPerSecond",
                        statusFlags=[0, 0, 0, 0],
                        covIncrement=0.1,
                    )
                    for i in range(1, args.objects + 1)
                ],
                AnalogValueObjectCmd(
                    objectIdentifier=("analog-value", 1),
                    objectName="Setpoint",
                    presentValue=20.0,
                    statusFlags=[0, 0, 0, 0],
                    relinquishDefault=20.0,
                    covIncrement=0.1,
                ),
            ]
        )
    print("ready", flush=True)
    await commands(apps)
    router.close()
    for app in apps.values():
        app.close()


if __name__ == "__main__":
    asyncio.run(main())

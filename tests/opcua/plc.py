#!/usr/bin/env python3
"""An independent OPC UA server for the OPC UA client driver's tests (asyncua, not the
gateway's code): a PLC with a variable of every IEC type.

    plc.py [--port P] [--reorder] [--no-subscriptions] [--security CERT KEY TRUSTED_DIR]
           [--user USER PASSWORD]
    plc.py --client-cert CERT KEY

Serves opc.tcp://127.0.0.1:P/plc (P a free port when not given) with the namespace
urn:iogate:test:plc (behind two other namespaces with --reorder, so its index changes);
with --security only Basic256Sha256 SignAndEncrypt, its certificate CERT (DER, made when
missing) and key KEY (PEM), trusting the client certificates in TRUSTED_DIR (--client-cert
makes one, for the application urn:iogate:client, and ends); with --user only that user
with that password gets a session. Prints
{"url": URL, "ns": N} when it listens. Then each JSON line on standard input is a command,
answered by one JSON line:

    {"cmd": "set", "name": NAME, "value": V}        -> {"ok": true}
    {"cmd": "status", "name": NAME, "status": S}    -> {"ok": true} (the value kept, status
                                                       S, a name in ua.StatusCodes)
    {"cmd": "get", "name": NAME}                    -> {"value": V}
    {"cmd": "subscriptions"}                        -> {"count": K} (subscriptions open)
    {"cmd": "drop_subscriptions"}                   -> {"dropped": K} (every subscription
                                                       deleted without telling its client)

Variables (string ids `Line1.NAME`): Bool, SInt, Int, DInt, LInt, USInt, UInt, UDInt,
ULInt, Real, LReal, Str (each of the matching OPC UA type, writable), Big (Int32 40000),
Locked (Int16, read-only), Speed (Double, EngineeringUnits rpm); Started (a DateTime) and
Counts (an array) have no IEC field. `--many N` adds Line1.Many.0 .. Line1.Many.N-1 (Int32,
each holding its number).
"""
import argparse
import asyncio
import json
import socket
import sys
from datetime import datetime, timezone

from asyncua import Server, ua

VARIABLES = [
    ("Bool", False, ua.VariantType.Boolean),
    ("SInt", -5, ua.VariantType.SByte),
    ("Int", -300, ua.VariantType.Int16),
    ("DInt", 100000, ua.VariantType.Int32),
    ("LInt", -(2**40), ua.VariantType.Int64),
    ("USInt", 200, ua.VariantType.Byte),
    ("UInt", 60000, ua.VariantType.UInt16),
    ("UDInt", 4000000000, ua.VariantType.UInt32),
    ("ULInt", 2**63, ua.VariantType.UInt64),
    ("Real", 1.5, ua.VariantType.Float),
    ("LReal", 2.25, ua.VariantType.Double),
    ("Str", "hello", ua.VariantType.String),
    ("Big", 40000, ua.VariantType.Int32),
    ("Locked", 7, ua.VariantType.Int16),
    ("Speed", 0.0, ua.VariantType.Double),
]


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def make_cert(cert, key, uri="urn:iogate:test:plc-server", use="server"):
    from asyncua.crypto.cert_gen import setup_self_signed_certificate
    from cryptography.x509.oid import ExtendedKeyUsageOID

    usage = ExtendedKeyUsageOID.SERVER_AUTH if use == "server" else ExtendedKeyUsageOID.CLIENT_AUTH
    await setup_self_signed_certificate(key, cert, uri, "127.0.0.1", [usage], {"commonName": use})


class Users:
    """Only USER with PASSWORD gets in (`--user USER PASSWORD`)."""

    def __init__(self, user, password):
        self.user, self.password = user, password

    def get_user(self, iserver, username=None, password=None, certificate=None):
        from asyncua.server.user_managers import User, UserRole
        if username == self.user and password == self.password:
            return User(role=UserRole.User)
        return None


async def start(args):
    server = Server(user_manager=Users(*args.user) if args.user else None)
    await server.init()
    port = args.port or free_port()
    url = f"opc.tcp://127.0.0.1:{port}/plc"
    server.set_endpoint(url)
    server.set_server_name("iogate test PLC")
    await server.set_application_uri("urn:iogate:test:plc-server")
    if args.security:
        from pathlib import Path
        from asyncua.crypto.truststore import TrustStore
        from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
        cert, key, trusted = (Path(p) for p in args.security)
        if not cert.exists():
            await make_cert(cert, key)
        server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))
        store = TrustStore([trusted], [])
        await store.load()
        server.set_certificate_validator(
            CertificateValidator(CertificateValidatorOptions.TRUSTED_VALIDATION | CertificateValidatorOptions.PEER_CLIENT, store)
        )
    else:
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    if args.user:
        server.set_security_IDs(["Username"])
    if args.reorder:
        await server.register_namespace("urn:iogate:test:other-a")
        await server.register_namespace("urn:iogate:test:other-b")
    ns = await server.register_namespace("urn:iogate:test:plc")
    line = await server.nodes.objects.add_object(ua.NodeId("Line1", ns), ua.QualifiedName("Line1", ns))
    nodes = {}
    for name, value, vt in VARIABLES:
        node = await line.add_variable(ua.NodeId(f"Line1.{name}", ns), ua.QualifiedName(name, ns), ua.Variant(value, vt))
        if name != "Locked":
            await node.set_writable()
        nodes[name] = (node, vt)
    unit = ua.EUInformation(NamespaceUri="http://www.opcfoundation.org/UA/units/un/cefact", UnitId=4740434, DisplayName=ua.LocalizedText("rpm"), Description=ua.LocalizedText("revolutions per minute"))
    await nodes["Speed"][0].add_property(ua.NodeId("Line1.Speed.EU", ns), ua.QualifiedName("EngineeringUnits", 0), ua.Variant(unit, ua.VariantType.ExtensionObject))
    when = await line.add_variable(ua.NodeId("Line1.Started", ns), ua.QualifiedName("Started", ns), ua.Variant(datetime.now(timezone.utc), ua.VariantType.DateTime))
    await line.add_variable(ua.NodeId("Line1.Counts", ns), ua.QualifiedName("Counts", ns), ua.Variant([1, 2, 3], ua.VariantType.Int32))
    del when
    for k in range(args.many):
        await line.add_variable(ua.NodeId(f"Line1.Many.{k}", ns), ua.QualifiedName(f"Many{k}", ns), ua.Variant(k, ua.VariantType.Int32))
    if args.no_subscriptions:
        async def refuse(*_a, **_k):
            raise ua.UaStatusCodeError(ua.StatusCodes.BadServiceUnsupported)
        server.iserver.subscription_service.create_subscription = refuse
    await server.start()
    print(json.dumps({"url": url, "ns": ns}), flush=True)
    return server, nodes


async def answer(server, nodes, cmd):
    if cmd["cmd"] == "set":
        node, vt = nodes[cmd["name"]]
        now = datetime.now(timezone.utc)
        await node.write_value(ua.DataValue(ua.Variant(cmd["value"], vt), SourceTimestamp=now, ServerTimestamp=now))
        return {"ok": True}
    if cmd["cmd"] == "status":
        node, vt = nodes[cmd["name"]]
        value = (await node.read_data_value(raise_on_bad_status=False)).Value.Value
        code = ua.StatusCode(getattr(ua.StatusCodes, cmd["status"]))
        now = datetime.now(timezone.utc)
        await node.write_value(ua.DataValue(ua.Variant(value, vt), StatusCode_=code, SourceTimestamp=now, ServerTimestamp=now))
        return {"ok": True}
    if cmd["cmd"] == "get":
        node, _ = nodes[cmd["name"]]
        return {"value": await node.read_value()}
    service = server.iserver.subscription_service
    if cmd["cmd"] == "subscriptions":
        return {"count": len(service.subscriptions)}
    if cmd["cmd"] == "drop_subscriptions":
        ids = list(service.subscriptions.keys())
        for i in ids:
            sub = service.subscriptions.pop(i)
            await sub.stop()
        return {"dropped": len(ids)}
    return {"error": f"unknown command {cmd['cmd']}"}


async def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--reorder", action="store_true")
    parser.add_argument("--no-subscriptions", action="store_true")
    parser.add_argument("--security", nargs=3, metavar=("CERT", "KEY", "TRUSTED"))
    parser.add_argument("--client-cert", nargs=2, metavar=("CERT", "KEY"))
    parser.add_argument("--user", nargs=2, metavar=("USER", "PASSWORD"))
    parser.add_argument("--many", type=int, default=0, help="variables Line1.Many.0 .. N-1 (Int32 k)")
    args = parser.parse_args()
    if args.client_cert:
        from pathlib import Path
        cert, key = (Path(p) for p in args.client_cert)
        await make_cert(cert, key, "urn:iogate:client", "client")
        print(json.dumps({"made": str(cert)}), flush=True)
        return
    server, nodes = await start(args)
    loop = asyncio.get_running_loop()
    try:
        while True:
            # A thread reads standard input: a pipe, a file or a terminal alike.
            line = await loop.run_in_executor(None, sys.stdin.readline)
            if not line:
                break
            try:
                reply = await answer(server, nodes, json.loads(line))
            except Exception as e:  # noqa: BLE001 - the test reads the error
                reply = {"error": f"{type(e).__name__}: {e}"}
            print(json.dumps(reply, default=str), flush=True)
    finally:
        await server.stop()


if __name__ == "__main__":
    asyncio.run(main())

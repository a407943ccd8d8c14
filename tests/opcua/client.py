#!/usr/bin/env python3
"""An independent OPC UA client for the tests (asyncua, not the gateway's code).

    client.py URL [SECURITY CERT KEY] [USER PASSWORD]

Connects to URL, anonymously or as USER with PASSWORD, and with SECURITY (an asyncua
security string such as `Basic256Sha256,SignAndEncrypt`) signing with the client
certificate CERT (DER) and key KEY (PEM), made (self-signed) when CERT does not exist; prints {"connected": true, "ns": N} (N: the
index of urn:iogate:devices) or {"error": "..."} and ends. Then each JSON line on standard
input is a command, answered by one JSON line:

    {"cmd": "browse", "node": ID}           -> {"children": [{"id", "name", "class"}]}
    {"cmd": "read", "node": ID}             -> {"value", "type", "status", "source", "server"}
      (with "absolute": true, ID is a whole node id such as "i=2267", not one of iogate's)
    {"cmd": "attrs", "node": ID}            -> {"data_type", "access", "user_access", "description"}
    {"cmd": "write", "node": ID, "value": V, "type": VARIANT_TYPE}
                                            -> {"status": "Good"} or {"status": NAME}
    {"cmd": "subscribe", "nodes": [ID], "interval": MS}
                                            -> {"subscribed": K}
    {"cmd": "deadband", "node": ID, "value": V, "type": 1 (absolute) or 2 (percent)}
                                            -> {"subscribed": 1}
    {"cmd": "subscribe_events", "type": T}  -> {"subscribed": 1} (the Server object's events of
                                               type T, a name in ua.ObjectIds, and its subtypes;
                                               every event without T)
    {"cmd": "monitor_many", "node": ID, "count": N}
                                            -> {"good": K, "refused": {STATUS: COUNT}} (N items
                                               on one node, 1,000 a call, on a subscription of
                                               its own)
    {"cmd": "subscription", "interval": MS, "lifetime": N, "keepalive": K, "node": ID, "count": C}
                                            -> {"interval", "lifetime", "keepalive", "good": K}
                                               (a subscription asked for these, as revised,
                                               with C items on the node)
    {"cmd": "message_sizes"}                -> {"sizes": [K]} (the notifications in each data
                                               change message of that subscription since
                                               the last ask)
    {"cmd": "path", "path": ["2:iogate", ...]}
                                            -> {"id": ID} (a browse path from Objects)
    {"cmd": "read_many", "node": ID, "count": N}
                                            -> {"status": "Good", "results": K} or {"status": NAME}
                                               (one Read of N times the node's value)
    {"cmd": "read0", "id": I}               -> {"value"} (the standard node ns=0;i=I)
    {"cmd": "changes", "wait": S}           -> {"changes": [{"node", "value", "status", "source"}
                                                            or {"event", "message", "source",
                                                            "changes": [{"affected", "verb"}]}]}

IDs are string node ids in the iogate namespace. Changes are collected from the moment of
subscribing; `changes` answers those seen so far (waiting up to S seconds for one).
"""
import asyncio
import json
import socket
import sys
from pathlib import Path

from asyncua import Client, ua
from asyncua.common.subscription import Subscription
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from cryptography.x509.oid import ExtendedKeyUsageOID

APP_URI = "urn:iogate:test-client"


def ts(t):
    return t.isoformat() if t is not None else None


def plain(v):
    if isinstance(v, (bool, int, float, str)) or v is None:
        return v
    return str(v)


class Handler:
    def __init__(self):
        self.seen = []
        self.event = asyncio.Event()

    def datachange_notification(self, node, val, data):
        dv = data.monitored_item.Value
        self.seen.append({
            "node": node.nodeid.Identifier,
            "value": plain(val),
            "status": dv.StatusCode_.name,
            "code": dv.StatusCode_.value,
            "source": ts(dv.SourceTimestamp),
        })
        self.event.set()

    def event_notification(self, event):
        self.seen.append({
            "event": event.EventType.Identifier,
            "message": event.Message.Text if event.Message else None,
            "source": event.SourceNode.Identifier if event.SourceNode else None,
            "changes": [
                {"affected": plain(c.Affected.Identifier), "verb": c.Verb}
                for c in (getattr(event, "Changes", None) or [])
            ],
        })
        self.event.set()


def counted(call, sizes):
    """`call` (a subscription's data change handling), noting each message's size."""
    async def wrapped(notification):
        sizes.append(len(notification.MonitoredItems))
        await call(notification)
    return wrapped


async def main():
    args = sys.argv[1:]
    url = args.pop(0)
    client = Client(url, timeout=10)
    if len(args) >= 3 and "," in args[0]:
        security, cert, key = args[0], args[1], args[2]
        args = args[3:]
        if not Path(cert).exists():
            # A client certificate of its own, made once (asyncua's generator).
            await setup_self_signed_certificate(
                Path(key), Path(cert), APP_URI, socket.gethostname(),
                [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "iogate test client"})
        client.application_uri = APP_URI
        await client.set_security_string(f"{security},{cert},{key}")
    if len(args) >= 2:
        client.set_user(args[0])
        client.set_password(args[1])
    loop = asyncio.get_running_loop()
    out = lambda o: (sys.stdout.write(json.dumps(o) + "\n"), sys.stdout.flush())
    try:
        await client.connect()
    except Exception as e:  # every failure is the answer
        out({"error": f"{type(e).__name__}: {e}"})
        return
    ns = await client.get_namespace_index("urn:iogate:devices")
    out({"connected": True, "ns": ns})
    handler = Handler()
    sub = None
    sizes = []
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
    try:
        while True:
            line = await reader.readline()
            if not line:
                break
            c = json.loads(line)
            node = lambda i: client.get_node(ua.NodeId(i, ns))
            try:
                if c["cmd"] == "browse":
                    kids = []
                    for k in await node(c["node"]).get_children():
                        kids.append({
                            "id": k.nodeid.Identifier,
                            "name": (await k.read_browse_name()).Name,
                            "class": (await k.read_node_class()).name,
                        })
                    out({"children": kids})
                elif c["cmd"] == "read":
                    rv = ua.ReadValueId()
                    if c.get("absolute"):
                        rv.NodeId = ua.NodeId.from_string(c["node"])
                    else:
                        rv.NodeId = ua.NodeId(c["node"], ns)
                    rv.AttributeId = ua.AttributeIds.Value
                    params = ua.ReadParameters()
                    params.NodesToRead = [rv]
                    params.TimestampsToReturn = ua.TimestampsToReturn.Both
                    dv = (await client.uaclient.read(params))[0]
                    out({
                        "value": plain(dv.Value.Value) if dv.Value else None,
                        "type": dv.Value.VariantType.name if dv.Value else None,
                        "status": dv.StatusCode_.name,
            "code": dv.StatusCode_.value,
                        "source": ts(dv.SourceTimestamp),
                        "server": ts(dv.ServerTimestamp),
                    })
                elif c["cmd"] == "attrs":
                    n = node(c["node"])
                    dt = await n.read_data_type()
                    desc = await n.read_description()
                    out({
                        "data_type": dt.Identifier,
                        "access": sorted(x.name for x in await n.get_access_level()),
                        "user_access": sorted(x.name for x in await n.get_user_access_level()),
                        "description": desc.Text,
                    })
                elif c["cmd"] == "write":
                    vt = getattr(ua.VariantType, c["type"])
                    try:
                        await node(c["node"]).write_value(ua.DataValue(ua.Variant(c["value"], vt)))
                        out({"status": "Good"})
                    except ua.UaStatusCodeError as e:
                        out({"status": ua.StatusCode(e.code).name})
                elif c["cmd"] == "subscribe":
                    if sub is None:
                        sub = await client.create_subscription(c.get("interval", 50), handler)
                    handles = await sub.subscribe_data_change([node(i) for i in c["nodes"]])
                    out({"subscribed": len(handles)})
                elif c["cmd"] == "deadband":
                    if sub is None:
                        sub = await client.create_subscription(c.get("interval", 50), handler)
                    await sub.deadband_monitor(node(c["node"]), c["value"], c["type"])
                    out({"subscribed": 1})
                elif c["cmd"] == "subscribe_events":
                    if sub is None:
                        sub = await client.create_subscription(c.get("interval", 50), handler)
                    if "type" in c:
                        evtype = getattr(ua.ObjectIds, c["type"])
                        await sub.subscribe_events(client.nodes.server, evtype)
                    else:
                        await sub.subscribe_events()  # BaseEventType on the Server object
                    out({"subscribed": 1})
                elif c["cmd"] == "monitor_many":
                    many = await client.create_subscription(1000, handler)
                    many._call_datachange = counted(many._call_datachange, sizes)
                    good, refused = 0, {}
                    left = c["count"]
                    while left > 0:
                        batch = min(left, 1000)
                        left -= batch
                        for r in await many.subscribe_data_change([node(c["node"])] * batch):
                            if isinstance(r, ua.StatusCode):
                                refused[r.name] = refused.get(r.name, 0) + 1
                            else:
                                good += 1
                    out({"good": good, "refused": refused})
                elif c["cmd"] == "subscription":
                    params = ua.CreateSubscriptionParameters()
                    params.RequestedPublishingInterval = c["interval"]
                    params.RequestedLifetimeCount = c["lifetime"]
                    params.RequestedMaxKeepAliveCount = c["keepalive"]
                    params.PublishingEnabled = True
                    own = Subscription(client.uaclient, params, handler)
                    made = await own.init()
                    items = await own.subscribe_data_change([node(c["node"])] * c["count"])
                    out({
                        "interval": made.RevisedPublishingInterval,
                        "lifetime": made.RevisedLifetimeCount,
                        "keepalive": made.RevisedMaxKeepAliveCount,
                        "good": sum(1 for r in items if not isinstance(r, ua.StatusCode)),
                    })
                elif c["cmd"] == "message_sizes":
                    out({"sizes": list(sizes)})
                    sizes.clear()
                elif c["cmd"] == "read_many":
                    params = ua.ReadParameters()
                    for _ in range(c["count"]):
                        rv = ua.ReadValueId()
                        rv.NodeId = ua.NodeId(c["node"], ns)
                        rv.AttributeId = ua.AttributeIds.Value
                        params.NodesToRead.append(rv)
                    try:
                        results = await client.uaclient.read(params)
                        out({"status": "Good", "results": len(results)})
                    except ua.UaStatusCodeError as e:
                        out({"status": ua.StatusCode(e.code).name})
                elif c["cmd"] == "read0":
                    value = await client.get_node(ua.NodeId(c["id"], 0)).read_value()
                    out({"value": plain(value)})
                elif c["cmd"] == "path":
                    found = await client.nodes.objects.get_child(c["path"])
                    out({"id": found.nodeid.Identifier, "ns": found.nodeid.NamespaceIndex})
                elif c["cmd"] == "changes":
                    if not handler.seen:
                        handler.event.clear()
                        try:
                            await asyncio.wait_for(handler.event.wait(), c.get("wait", 5))
                        except asyncio.TimeoutError:
                            pass
                    seen, handler.seen = handler.seen, []
                    out({"changes": seen})
                else:
                    out({"error": f"unknown command {c['cmd']}"})
            except Exception as e:
                out({"error": f"{type(e).__name__}: {e}"})
    finally:
        try:
            await client.disconnect()
        except Exception:
            pass


asyncio.run(main())

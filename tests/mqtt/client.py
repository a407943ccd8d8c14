#!/usr/bin/env python3
"""An independent MQTT client for the tests (paho-mqtt, not the gateway's code).

    client.py PORT FILTER [CLIENT_ID]

Subscribes to FILTER (QoS 1) on the broker at 127.0.0.1:PORT and prints every message as
one JSON line: {"topic", "payload" (text), "retain"}; a Sparkplug B message (spBv1.0/...,
not STATE) is decoded with pysparkplug, an implementation of its own, into "sparkplug":
{"type", "seq", "timestamp", "metrics": [{"name", "alias", "datatype", "value",
"is_historical", "is_null"}]}; data is decoded against the device's (or node's) last birth,
so aliases resolve as a host resolves them. With CLIENT_ID the session is kept by the broker
(not clean) and the client reconnects within half a second. After subscribing it prints {"subscribed": true}.
Each JSON line on standard input is published: {"topic", "payload", "qos"}, or {"topic",
"command": [{"name", "datatype", "value"}]} encoded as a Sparkplug NCMD/DCMD by pysparkplug.
A publish waits for the connection while the broker is away. Ends when standard input closes.
"""
import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
import pysparkplug as sp

port, filter_ = int(sys.argv[1]), sys.argv[2]
client_id = sys.argv[3] if len(sys.argv) > 3 else ""
lock = threading.Lock()


def emit(obj):
    with lock:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


connected = threading.Event()


def on_connect(client, userdata, flags, rc):
    client.subscribe(filter_, qos=1)
    connected.set()


def on_disconnect(client, userdata, rc):
    connected.clear()


subscribed = False


def on_subscribe(client, userdata, mid, granted_qos):
    global subscribed
    if not subscribed:
        subscribed = True
        emit({"subscribed": True})


births = {}
KINDS = {
    "NBIRTH": sp.NBirth, "NDEATH": sp.NDeath, "NDATA": sp.NData, "NCMD": sp.NCmd,
    "DBIRTH": sp.DBirth, "DDEATH": sp.DDeath, "DDATA": sp.DData, "DCMD": sp.DCmd,
}


def plain(v):
    if isinstance(v, (bytes, bytearray)):
        return v.hex()
    if isinstance(v, tuple):
        return list(v)
    if hasattr(v, "isoformat"):
        return v.isoformat()
    return v


def sparkplug(topic, raw):
    parts = topic.split("/")
    kind = parts[2]
    key = "/".join(parts[3:])
    cls = KINDS[kind]
    if kind in ("NDATA", "NCMD"):
        payload = cls.decode(raw, birth=births.get(parts[3]))
    elif kind in ("DDATA", "DCMD"):
        payload = cls.decode(raw, birth=births.get(key))
    else:
        payload = cls.decode(raw)
    if kind in ("NBIRTH", "DBIRTH"):
        births[key] = payload
    metrics = getattr(payload, "metrics", None)
    if metrics is None and hasattr(payload, "bd_seq_metric"):
        metrics = (payload.bd_seq_metric,)
    return {
        "type": kind,
        "seq": getattr(payload, "seq", None),
        "timestamp": payload.timestamp,
        "metrics": [
            {
                "name": m.name, "alias": m.alias, "datatype": m.datatype.name,
                "value": plain(m.value), "is_historical": m.is_historical, "is_null": m.is_null,
            }
            for m in (metrics or ())
        ],
    }


def on_message(client, userdata, m):
    out = {"topic": m.topic, "retain": bool(m.retain)}
    if m.topic.startswith("spBv1.0/") and not m.topic.startswith("spBv1.0/STATE/"):
        try:
            out["sparkplug"] = sparkplug(m.topic, m.payload)
        except Exception as e:  # a payload this implementation cannot decode is reported
            out["decode_error"] = repr(e)
        out["payload"] = m.payload.hex()
    else:
        out["payload"] = m.payload.decode("utf-8", "replace")
    emit(out)


client = mqtt.Client(client_id=client_id, clean_session=not client_id)
client.reconnect_delay_set(min_delay=0.1, max_delay=0.5)
client.on_connect = on_connect
client.on_disconnect = on_disconnect
client.on_subscribe = on_subscribe
client.on_message = on_message
client.connect("127.0.0.1", port, keepalive=30)
client.loop_start()
for line in sys.stdin:
    line = line.strip()
    if not line:
        continue
    msg = json.loads(line)
    payload = msg.get("payload")
    if "command" in msg:
        metrics = tuple(
            sp.Metric(timestamp=int(time.time() * 1000), name=c["name"],
                      datatype=sp.DataType[c["datatype"]], value=c["value"])
            for c in msg["command"]
        )
        cls = sp.NCmd if "/NCMD/" in msg["topic"] else sp.DCmd
        payload = cls(timestamp=int(time.time() * 1000), metrics=metrics).encode()
    retain = bool(msg.get("retain", False))
    # While the broker is away, wait for the reconnect; a publish that still fails is
    # reported as a line, not an end.
    connected.wait(5)
    try:
        client.publish(msg["topic"], payload, qos=msg.get("qos", 1), retain=retain).wait_for_publish(5)
    except (RuntimeError, ValueError) as e:
        emit({"publish_error": repr(e)})
client.loop_stop()
client.disconnect()

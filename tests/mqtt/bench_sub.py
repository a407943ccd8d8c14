#!/usr/bin/env python3
"""The MQTT benchmark's subscriber (paho-mqtt, not the gateway's code).

    bench_sub.py PORT FILTER

Subscribes to FILTER (QoS 0) and, for every message, takes the delivery latency: the time
of arrival minus the JSON payload's `timestamp` (when the gateway read the value). Prints
{"subscribed": true} once subscribed. Reads commands from standard input: `reset` forgets
what was measured, `report` prints {"count", "p50_ms", "p99_ms", "max_ms"} for what was
measured since.
"""
import json
import sys
import threading
import time
from datetime import datetime

import paho.mqtt.client as mqtt

port, filter_ = int(sys.argv[1]), sys.argv[2]
lock = threading.Lock()
latencies = []
subscribed = threading.Event()


def on_connect(client, userdata, flags, rc):
    client.subscribe(filter_, qos=0)


def on_subscribe(client, userdata, mid, granted_qos):
    subscribed.set()


def on_message(client, userdata, m):
    now = time.time()
    try:
        stamp = json.loads(m.payload)["timestamp"]
        at = datetime.fromisoformat(stamp.replace("Z", "+00:00")).timestamp()
    except (ValueError, KeyError, TypeError):
        return
    with lock:
        latencies.append((now - at) * 1000.0)


client = mqtt.Client()
client.on_connect = on_connect
client.on_subscribe = on_subscribe
client.on_message = on_message
client.connect("127.0.0.1", port, keepalive=30)
client.loop_start()
subscribed.wait(10)
print(json.dumps({"subscribed": subscribed.is_set()}), flush=True)
for line in sys.stdin:
    command = line.strip()
    with lock:
        taken = sorted(latencies)
        latencies.clear() if command in ("reset", "report") else None
    if command == "report":
        n = len(taken)
        pick = lambda q: round(taken[min(n - 1, int(q * n))], 2) if n else None
        print(json.dumps({"count": n, "p50_ms": pick(0.5), "p99_ms": pick(0.99),
                          "max_ms": round(taken[-1], 2) if n else None}), flush=True)
client.loop_stop()

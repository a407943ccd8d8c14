#!/usr/bin/env python3
"""An independent MQTT client for the tests (paho-mqtt, not the gateway's code).

    client.py PORT FILTER

Subscribes to FILTER (QoS 1) on the broker at 127.0.0.1:PORT and prints every message as
one JSON line: {"topic", "payload" (text), "retain"}; after subscribing it prints
{"subscribed": true}. Each JSON line on standard input, {"topic", "payload", "qos"}, is
published. Ends when standard input closes.
"""
import json
import sys
import threading

import paho.mqtt.client as mqtt

port, filter_ = int(sys.argv[1]), sys.argv[2]
lock = threading.Lock()


def emit(obj):
    with lock:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


def on_connect(client, userdata, flags, rc):
    client.subscribe(filter_, qos=1)


def on_subscribe(client, userdata, mid, granted_qos):
    emit({"subscribed": True})


def on_message(client, userdata, m):
    emit({"topic": m.topic, "payload": m.payload.decode("utf-8", "replace"), "retain": bool(m.retain)})


client = mqtt.Client(client_id="", clean_session=True)
client.on_connect = on_connect
client.on_subscribe = on_subscribe
client.on_message = on_message
client.connect("127.0.0.1", port, keepalive=30)
client.loop_start()
for line in sys.stdin:
    line = line.strip()
    if not line:
        continue
    msg = json.loads(line)
    client.publish(msg["topic"], msg["payload"], qos=msg.get("qos", 1)).wait_for_publish(5)
client.loop_stop()
client.disconnect()

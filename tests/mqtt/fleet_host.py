"""A Sparkplug B host application for the fleet bench: subscribes to every edge node of one
group, decodes every payload with pysparkplug (births whole, data with its protobuf binding),
and counts what a host would check.

Per edge node: the sequence number of each message after its NBIRTH (0..255, then 0 again);
a message whose number is not the one after the last is a gap. Per metric (a device's field,
by alias): the value, an integer the bench adds 1 to every change; a value further on than
the next is a lost change. Every second a JSON line: messages and metrics since the last
line, and the totals of gaps, lost changes, births and decode errors.

    python fleet_host.py PORT GROUP
"""

import json
import sys
import threading
import time

import paho.mqtt.client as mqtt
import pysparkplug as sp
from pysparkplug import _protobuf as protobuf

port, group = int(sys.argv[1]), sys.argv[2]
lock = threading.Lock()
births = {}  # "node/device" -> DBirth
seqs = {}  # node -> last sequence number
last = {}  # (node, device, alias) -> last value
count = {"messages": 0, "metrics": 0}
total = {"gaps": 0, "lost": 0, "births": 0, "errors": 0, "all_metrics": 0}


def next_seq(node, seq):
    before = seqs.get(node)
    seqs[node] = seq
    if before is not None and seq != (before + 1) % 256:
        total["gaps"] += 1


def on_connect(client, userdata, flags, rc):
    client.subscribe(f"spBv1.0/{group}/#", qos=0)
    print(json.dumps({"connected": rc}), flush=True)


def data(node, device, raw):
    # pysparkplug's binding of the Sparkplug B schema: its full decode (a dataclass a
    # metric) keeps up with some 130,000 metrics a second on one core, the fleet sends more.
    payload = protobuf.Payload.FromString(raw)
    next_seq(node, payload.seq)
    for m in payload.metrics:
        key = (node, device, m.alias or m.name)
        value = m.int_value
        before = last.get(key)
        if before is not None and value != before:
            step = (value - before) % 65536
            if step > 1:
                total["lost"] += step - 1
        last[key] = value
    count["metrics"] += len(payload.metrics)
    total["all_metrics"] += len(payload.metrics)


def on_message(client, userdata, m):
    parts = m.topic.split("/")
    if len(parts) < 4 or parts[1] != group:
        return
    kind, node = parts[2], parts[3]
    device = parts[4] if len(parts) > 4 else None
    with lock:
        count["messages"] += 1
        try:
            if kind == "DDATA":
                data(node, device, m.payload)
            elif kind == "NBIRTH":
                payload = sp.NBirth.decode(m.payload)
                seqs[node] = payload.seq
                total["births"] += 1
            elif kind == "DBIRTH":
                payload = sp.DBirth.decode(m.payload)
                births[f"{node}/{device}"] = payload
                next_seq(node, payload.seq)
            elif kind in ("NDATA", "DDEATH"):
                next_seq(node, sp.NData.decode(m.payload).seq)
        except Exception as e:  # a payload pysparkplug cannot decode is counted
            total["errors"] += 1
            print(json.dumps({"decode_error": repr(e), "topic": m.topic}), flush=True)


client = mqtt.Client(client_id=f"fleet-host-{port}", clean_session=True)
client.on_connect = on_connect
client.on_message = on_message
client.connect("127.0.0.1", port, keepalive=30)
client.loop_start()
while True:
    time.sleep(1)
    with lock:
        line = dict(count, **total, nodes=len(seqs))
        count["messages"] = count["metrics"] = 0
    print(json.dumps(line), flush=True)

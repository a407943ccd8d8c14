#!/usr/bin/env python3
"""The demo's REST and gRPC answers at two revisions, side by side.

    python3 tests/compare/answers.py [BEFORE [AFTER]]      (default: b2147a7 and the work tree)

Each revision is built in its own git worktree (its own target directory, under
target/compare/), runs `iogate serve` on the demo configuration with free loopback ports,
and is asked the same questions over REST (curl-like, urllib: every route the demo
answers, the OpenAPI document and the metrics' names), gRPC (that revision's own
`iogatectl --json`), Modbus TCP (pymodbus: every located address of the map) and OPC UA
(asyncua: every node of the address space, its class, name, type and status): lists,
devices, fields, located addresses, writes, simulated inputs, refusals, the first events of
the SSE stream. The demo has no MQTT section, so no MQTT topic is asked. Times and the demo's simulated process
values are masked; the answers are written to target/compare/<rev>/ and compared; every
difference is printed. Exit status 0 when the answers are the same, 1 when they differ.
"""

import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request

ROOT = subprocess.run(
    ["git", "rev-parse", "--show-toplevel"], capture_output=True, text=True, check=True
).stdout.strip()
WORK = os.path.join(ROOT, "target", "compare")

# Keys whose values are times or measurements that differ between any two runs.
MASKED = {"address", "listen", "hash", "loaded_at_unix_ms", "file", "config_hash", "timestamp", "timestamp_ms", "requested", "finished", "at", "since", "uptime_seconds", "last_response_ms", "response_time_ms",
          "age_seconds", "cycle_ms", "utilisation", "measured", "requested_at", "written_at",
          "sample_age_ms", "last_cycle_ms", "io_cycles", "requests", "ok", "timeouts"}


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def checkout(rev):
    """A directory holding `rev` (the work tree itself for `WORKTREE`)."""
    if rev == "WORKTREE":
        return ROOT
    path = os.path.join(WORK, "src-" + rev)
    if not os.path.isdir(path):
        subprocess.run(["git", "worktree", "add", "--detach", path, rev], cwd=ROOT, check=True,
                       capture_output=True)
    return path


def build(src, rev):
    target = os.path.join(WORK, "target-" + ("worktree" if rev == "WORKTREE" else "rev"))
    subprocess.run(["cargo", "build", "-q", "-p", "iogate", "-p", "iogate-client"], cwd=src,
                   check=True, env={**os.environ, "CARGO_TARGET_DIR": target})
    return os.path.join(target, "debug")


def masked(value, key=None):
    if isinstance(value, dict):
        return {k: masked(v, k) for k, v in sorted(value.items())}
    if isinstance(value, list):
        return [masked(v) for v in value]
    if key in MASKED:
        return "<masked>"
    return value


class Gateway:
    def __init__(self, src, bins):
        self.http, self.grpc, self.modbus = free_port(), free_port(), free_port()
        self.opcua = free_port()
        with open(os.path.join(src, "examples", "demo.yaml")) as f:
            config = f.read()
        config = (config.replace("127.0.0.1:8080", f"127.0.0.1:{self.http}")
                  .replace("127.0.0.1:50051", f"127.0.0.1:{self.grpc}")
                  .replace("127.0.0.1:5020", f"127.0.0.1:{self.modbus}")
                  .replace("127.0.0.1:4840", f"127.0.0.1:{self.opcua}"))
        self.config = os.path.join(WORK, f"demo-{self.http}.yaml")
        with open(self.config, "w") as f:
            f.write(config)
        self.bins = bins
        self.process = subprocess.Popen(
            [os.path.join(bins, "iogate"), "serve", "--config", self.config], cwd=src,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                if self.rest("GET", "/readyz")[0] == 200:
                    return
            except OSError:
                pass
            time.sleep(0.1)
        raise SystemExit("the gateway did not become ready")

    def stop(self):
        self.process.terminate()
        self.process.wait(10)

    def rest(self, method, path, body=None, timeout=5):
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(f"http://127.0.0.1:{self.http}{path}", data=data,
                                         method=method,
                                         headers={"Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(request, timeout=timeout) as r:
                return r.status, r.read().decode()
        except urllib.error.HTTPError as e:
            return e.code, e.read().decode()

    def sse(self, query, events):
        """The first `events` events of the stream."""
        request = urllib.request.Request(f"http://127.0.0.1:{self.http}/api/v1/events?{query}")
        out, event = [], {}
        with urllib.request.urlopen(request, timeout=5) as r:
            for line in r:
                line = line.decode().rstrip("\n")
                if not line:
                    if event:
                        out.append(event)
                        event = {}
                    if len(out) >= events:
                        break
                    continue
                k, _, v = line.partition(":")
                event[k] = v.strip()
        # The current values come first in no promised order: compare them sorted.
        events = [{"event": e.get("event"), "data": json.loads(e["data"]) if "data" in e else None}
                  for e in out]
        return sorted(events, key=lambda e: json.dumps(e, sort_keys=True))

    def ctl(self, *args):
        r = subprocess.run([os.path.join(self.bins, "iogatectl"), "-s",
                            f"http://127.0.0.1:{self.grpc}", "--json", *args],
                           capture_output=True, text=True, timeout=20)
        try:
            out = json.loads(r.stdout)
        except json.JSONDecodeError:
            out = r.stdout.strip()
        return {"exit": r.returncode, "out": out, "err": r.stderr.strip()}


def answers(gw):
    """The same questions, in the same order, at each revision."""
    a = {}

    def rest(name, method, path, body=None):
        status, text = gw.rest(method, path, body)
        try:
            text = json.loads(text)
        except json.JSONDecodeError:
            pass
        a["rest " + name] = {"status": status, "body": text}

    # A simulated input, a write and its outcome, so that every view has something to say.
    rest("simulate DI_0", "PUT", "/api/v1/devices/sim/fields/DI_0/simulate", {"value": True})
    rest("write DO_0", "PUT", "/api/v1/devices/sim/fields/DO_0", {"value": True})
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        status, text = gw.rest("GET", "/api/v1/writes/1")
        if status == 200 and json.loads(text).get("status") != "pending":
            break
        time.sleep(0.1)
    rest("the write", "GET", "/api/v1/writes/1")
    rest("devices", "GET", "/api/v1/devices")
    rest("device sim", "GET", "/api/v1/devices/sim")
    rest("field DO_0", "GET", "/api/v1/devices/sim/fields/DO_0")
    rest("field DI_0", "GET", "/api/v1/devices/sim/fields/DI_0")
    rest("links", "GET", "/api/v1/links")
    rest("profiles", "GET", "/api/v1/profiles")
    rest("profile SimIo", "GET", "/api/v1/profiles/SimIo")
    rest("map", "GET", "/api/v1/map")
    rest("map %QX0.0", "GET", "/api/v1/map/%25QX0.0")
    rest("unknown device", "GET", "/api/v1/devices/nosuch")
    rest("unknown field", "GET", "/api/v1/devices/sim/fields/nosuch")
    rest("write an input", "PUT", "/api/v1/devices/sim/fields/DI_0", {"value": True})
    rest("value of the wrong type", "PUT", "/api/v1/devices/sim/fields/DO_0", {"value": "on"})
    rest("out of range", "PUT", "/api/v1/devices/plant/fields/Recipe", {"value": 300})
    rest("simulate an output", "PUT", "/api/v1/devices/sim/fields/DO_0/simulate",
         {"value": True})
    rest("unknown write", "GET", "/api/v1/writes/999")
    rest("readyz", "GET", "/readyz")
    a["sse device=sim (first 3)"] = gw.sse("device=sim", 3)
    # Without values, the first events are every device's diagnostics, in no promised order.
    every = len(json.loads(gw.rest("GET", "/api/v1/devices")[1])["devices"])
    a["sse values=false (first of each device)"] = gw.sse("values=false", every)
    for e in a["sse device=sim (first 3)"] + a["sse values=false (first of each device)"]:
        e["data"].pop("io_cycles", None)
        e["data"].pop("last_response_ms", None)

    a["grpc devices"] = gw.ctl("devices")
    a["grpc links"] = gw.ctl("links")
    a["grpc profiles"] = gw.ctl("profiles")
    a["grpc get sim"] = gw.ctl("get", "sim")
    a["grpc get sim.DO_0"] = gw.ctl("get", "sim.DO_0")
    a["grpc get %QX0.0"] = gw.ctl("get", "%QX0.0")
    a["grpc describe device sim"] = gw.ctl("describe", "device", "sim")
    a["grpc get nosuch"] = gw.ctl("get", "nosuch")
    a["grpc set an input"] = gw.ctl("set", "sim.DI_0", "true")
    a["grpc set out of range"] = gw.ctl("set", "plant.Recipe", "300")
    more_rest(rest)
    a["openapi"] = json.loads(gw.rest("GET", "/api/v1/openapi.json")[1])
    a["metric names"] = metric_names(gw.rest("GET", "/metrics")[1])
    a["modbus reads"] = modbus_reads(gw)
    a["opcua nodes"] = opcua_nodes(gw)
    return a


def more_rest(rest):
    """The other routes the demo answers."""
    rest("config", "GET", "/api/v1/config")
    rest("livez", "GET", "/livez")
    rest("link field", "GET", "/api/v1/links/field")
    rest("link field plan", "GET", "/api/v1/links/field/plan")
    rest("profile SimIo st", "GET", "/api/v1/profiles/SimIo/st")
    rest("memory", "GET", "/api/v1/memory")
    rest("transactions", "GET", "/api/v1/transactions")
    rest("mqtt", "GET", "/api/v1/mqtt")
    rest("unknown route", "GET", "/api/v1/nosuch")
    rest("unknown query", "GET", "/api/v1/events?colour=red")
    rest("device meter", "GET", "/api/v1/devices/meter")
    rest("device io", "GET", "/api/v1/devices/io")


def metric_names(text):
    """The metrics' names and label names, values left out."""
    names = set()
    for line in text.splitlines():
        if line and not line.startswith("#"):
            series = line.rsplit(" ", 1)[0]
            name, _, labels = series.partition("{")
            keys = sorted(kv.split("=")[0] for kv in labels.rstrip("}").split(",") if kv)
            names.add(name + "{" + ",".join(keys) + "}")
    return sorted(names)


def modbus_reads(gw):
    """Every located address of the map read over Modbus TCP: its answer or exception;
    values only for the `sim` device (the plant and the field devices move)."""
    from pymodbus.client import ModbusTcpClient
    info = json.loads(gw.rest("GET", "/api/v1/map")[1])
    unit = info.get("unit_id", 1)
    client = ModbusTcpClient("127.0.0.1", port=gw.modbus)
    client.connect()
    out = {}
    try:
        for e in info.get("bindings", []):
            at, table, address = e["at"], e["table"], e["address"]
            size = at[2].upper() if len(at) > 2 else "X"
            count = {"X": 1, "B": 1, "W": 1, "D": 2, "L": 4}.get(size, 1)
            read = {"coil": client.read_coils, "discrete input": client.read_discrete_inputs,
                    "holding register": client.read_holding_registers,
                    "input register": client.read_input_registers}[table]
            r = read(address, count=count, device_id=unit)
            if r.isError():
                out[at] = {"exception": getattr(r, "exception_code", str(r))}
                continue
            value = r.bits[:count] if table in ("coil", "discrete input") else r.registers
            out[at] = {"answered": True, "value": value if e["device"] == "sim" else "<masked>"}
    finally:
        client.close()
    return out


def opcua_nodes(gw):
    """Every node under Objects: its id, class, browse name, data type and status."""
    import asyncio
    from asyncua import Client, ua

    async def walk():
        out = {}
        async with Client(f"opc.tcp://127.0.0.1:{gw.opcua}/") as client:
            todo = [client.nodes.objects]
            while todo and len(out) < 5000:
                node = todo.pop()
                for child in await node.get_children():
                    key = child.nodeid.to_string()
                    if key in out or child.nodeid.NamespaceIndex == 0:
                        continue
                    cls = await child.read_node_class()
                    entry = {"class": cls.name,
                             "name": (await child.read_browse_name()).to_string()}
                    if cls == ua.NodeClass.Variable:
                        dv = await child.read_data_value(raise_on_bad_status=False)
                        entry["type"] = (await child.read_data_type()).to_string()
                        entry["status"] = dv.StatusCode.name
                    out[key] = entry
                    todo.append(child)
        return out

    return asyncio.run(walk())


def run(rev):
    src = checkout(rev)
    print(f"building {rev} ...", file=sys.stderr)
    bins = build(src, rev)
    gw = Gateway(src, bins)
    try:
        got = masked(answers(gw))
    finally:
        gw.stop()
    out = os.path.join(WORK, rev)
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    for name, value in got.items():
        with open(os.path.join(out, name.replace(" ", "_").replace("/", "_") + ".json"), "w") as f:
            json.dump(value, f, indent=2, sort_keys=True)
            f.write("\n")
    return got


def differences(a, b, path=""):
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a:
                yield f"{path}.{k}: added {json.dumps(b[k])}"
            elif k not in b:
                yield f"{path}.{k}: removed (was {json.dumps(a[k])})"
            else:
                yield from differences(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            yield from differences(x, y, f"{path}[{i}]")
    elif a != b:
        yield f"{path}: {json.dumps(a)} -> {json.dumps(b)}"


def main():
    before = sys.argv[1] if len(sys.argv) > 1 else "b2147a7"
    after = sys.argv[2] if len(sys.argv) > 2 else "WORKTREE"
    os.makedirs(WORK, exist_ok=True)
    a, b = run(before), run(after)
    diffs = [d for name in a for d in differences(a[name], b.get(name), f"[{name}]")]
    for d in diffs:
        print(d)
    print(f"{len(a)} questions, {len(diffs)} differences ({before} -> {after}); "
          f"answers in {WORK}/", file=sys.stderr)
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())

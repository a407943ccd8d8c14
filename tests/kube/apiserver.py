"""A Kubernetes API server for Lease objects only, written from the API's conventions
(coordination.k8s.io/v1 Lease; optimistic concurrency by metadata.resourceVersion), for the
tests of `ha: {arbiter: kubernetes}`: GET, POST and PUT of leases in any namespace, 409
Conflict on a stale resourceVersion, 409 AlreadyExists on a second create, 404 NotFound,
401 without the bearer token when one is required. It prints its port, then serves until
killed.

    python3 apiserver.py [--token TOKEN]
"""

import argparse
import json
import re
import threading
from datetime import datetime, timezone
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

PATH = re.compile(r"^/apis/coordination\.k8s\.io/v1/namespaces/([a-z0-9-]+)/leases(?:/([a-z0-9.-]+))?$")
LOCK = threading.Lock()
LEASES = {}
VERSION = [1000]


def status(code, reason, message):
    return code, {"kind": "Status", "apiVersion": "v1", "status": "Failure",
                  "reason": reason, "message": message, "code": code}


def stored(ns, name, body, old=None):
    VERSION[0] += 1
    meta = dict(body.get("metadata") or {})
    meta.update({"name": name, "namespace": ns, "resourceVersion": str(VERSION[0])})
    if old is None:
        meta["uid"] = f"lease-{VERSION[0]}"
        meta["creationTimestamp"] = datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    else:
        meta["uid"] = old["metadata"]["uid"]
        meta["creationTimestamp"] = old["metadata"]["creationTimestamp"]
    lease = {"apiVersion": "coordination.k8s.io/v1", "kind": "Lease",
             "metadata": meta, "spec": body.get("spec") or {}}
    LEASES[(ns, name)] = lease
    return lease


def handle(method, ns, name, body):
    with LOCK:
        if method == "GET" and name:
            lease = LEASES.get((ns, name))
            return (200, lease) if lease else status(404, "NotFound", f'leases "{name}" not found')
        if method == "POST" and not name:
            name = (body.get("metadata") or {}).get("name", "")
            if not re.match(r"^[a-z0-9]([a-z0-9.-]*[a-z0-9])?$", name):
                return status(422, "Invalid", "metadata.name: Invalid value")
            if (ns, name) in LEASES:
                return status(409, "AlreadyExists", f'leases "{name}" already exists')
            return 201, stored(ns, name, body)
        if method == "PUT" and name:
            old = LEASES.get((ns, name))
            if old is None:
                return status(404, "NotFound", f'leases "{name}" not found')
            given = (body.get("metadata") or {}).get("resourceVersion")
            if given != old["metadata"]["resourceVersion"]:
                return status(409, "Conflict",
                              f'Operation cannot be fulfilled on leases.coordination.k8s.io "{name}": '
                              "the object has been modified; please apply your changes to the latest "
                              "version and try again")
            return 200, stored(ns, name, body, old)
        return status(405, "MethodNotAllowed", f"{method} is not allowed here")


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    token = None

    def log_message(self, *args):
        pass

    def serve(self, method):
        length = int(self.headers.get("Content-Length") or 0)
        raw = self.rfile.read(length) if length else b""
        if self.token and self.headers.get("Authorization") != f"Bearer {self.token}":
            code, answer = status(401, "Unauthorized", "Unauthorized")
        else:
            match = PATH.match(self.path.split("?")[0])
            if not match:
                code, answer = status(404, "NotFound", "the server could not find the requested resource")
            else:
                try:
                    body = json.loads(raw) if raw else {}
                except ValueError:
                    body = None
                if body is None or not isinstance(body, dict):
                    code, answer = status(400, "BadRequest", "the body is not a JSON object")
                else:
                    code, answer = handle(method, match.group(1), match.group(2), body)
        out = json.dumps(answer).encode()
        self.send_response(code)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(out)))
        self.end_headers()
        self.wfile.write(out)

    def do_GET(self):
        self.serve("GET")

    def do_POST(self):
        self.serve("POST")

    def do_PUT(self):
        self.serve("PUT")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--token")
    args = parser.parse_args()
    Handler.token = args.token
    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    print(server.server_address[1], flush=True)
    server.serve_forever()


if __name__ == "__main__":
    main()

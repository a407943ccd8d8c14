#!/usr/bin/env python3
"""A Logix controller for the EtherNet/IP tests: cpppo's simulator (not the gateway's code).

    plc.py [--port P] TAG=TYPE[N] ...

Listens on 127.0.0.1 (port P, else a free one), prints the port on a line of its own once
it listens, and serves the tags until killed (cpppo's `enip` server: Read Tag, Write Tag,
Multiple Service Packets, Read Tag Fragmented, routing to slot 0 of backplane 1).
"""
import socket
import sys
import threading
import time

from cpppo.server.enip import main as enip_main

args = sys.argv[1:]
port = 0
if args[:1] == ["--port"]:
    port = int(args[1])
    args = args[2:]
if port == 0:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]


def announce():
    # Told once the server accepts connections.
    for _ in range(200):
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                print(port, flush=True)
                return
        except OSError:
            time.sleep(0.05)


threading.Thread(target=announce, daemon=True).start()
sys.exit(enip_main.main(argv=["--address", f"127.0.0.1:{port}"] + args))

"""Snap7 (python-snap7: the Snap7 C library) for the S7 driver's benchmark.

`server DBS SIZE` serves data blocks DB1..DB<DBS> of SIZE bytes each and prints its port,
then runs until stdin closes. `client PORT SCENARIO SECONDS` reads as fast as Snap7's
client can, one job at a time, and prints `cycles pdus_per_cycle`:
  block      1,000 INTs of DB1 (bytes 0-1999): one db_read, split by Snap7 into PDUs;
  scattered  200 REALs, 20 in each of DB1..DB10, 100 bytes apart: read_multi_vars of 20
             items (Snap7's most) at a time.
  gapped     500 INTs of DB1, 8 bytes apart (bytes 0-3993): read_multi_vars of 20 items
             at a time, as a client reads fields it is given.
"""

import ctypes
import math
import socket
import sys
import time

import snap7
from snap7.server import Server
from snap7.type import Parameter, S7DataItem, SrvArea

AREA_DB, WORDLEN_BYTE = 0x84, 0x02


def serve(dbs, size):
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    srv = Server(log=False)
    blocks = [(ctypes.c_uint8 * size)() for _ in range(dbs)]
    for i, b in enumerate(blocks):
        for k in range(0, size, 2):
            b[k + 1] = (i + k) & 0xFF
        srv.register_area(SrvArea.DB, i + 1, b)
    srv.start(tcp_port=port)
    print(port, flush=True)
    while sys.stdin.read(1):
        pass
    srv.stop()


def scattered_items():
    items = []
    for db in range(1, 11):
        for k in range(20):
            items.append((db, k * 100))
    return multi_vars(items, 4)


def gapped_items():
    return multi_vars([(1, 8 * k) for k in range(500)], 2)


def multi_vars(items, amount):
    chunks = []
    for at in range(0, len(items), 20):
        chunk = items[at:at + 20]
        data = (S7DataItem * len(chunk))()
        buffers = []
        for i, (db, start) in enumerate(chunk):
            buf = ctypes.create_string_buffer(amount)
            buffers.append(buf)
            data[i].Area = AREA_DB
            data[i].WordLen = WORDLEN_BYTE
            data[i].DBNumber = db
            data[i].Start = start
            data[i].Amount = amount
            data[i].pData = ctypes.cast(ctypes.pointer(buf), ctypes.POINTER(ctypes.c_uint8))
        chunks.append((data, buffers))
    return chunks


def client(port, scenario, seconds):
    c = snap7.client.Client()
    # The PDU size the gateway asks for too (Snap7's client asks for 480 unless told).
    c.set_param(Parameter.PDURequest, 960)
    c.connect("127.0.0.1", 0, 1, port)
    pdu = c.get_pdu_length()
    if scenario == "block":
        pdus = math.ceil(2000 / (pdu - 18))
        step = lambda: c.db_read(1, 0, 2000)
    else:
        chunks = scattered_items() if scenario == "scattered" else gapped_items()
        pdus = len(chunks)

        def step():
            for data, _ in chunks:
                c.read_multi_vars(data)

    cycles = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        step()
        cycles += 1
    print(cycles, pdus, flush=True)
    c.disconnect()


if __name__ == "__main__":
    if sys.argv[1] == "server":
        serve(int(sys.argv[2]), int(sys.argv[3]))
    else:
        client(int(sys.argv[2]), sys.argv[3], float(sys.argv[4]))

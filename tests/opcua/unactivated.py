#!/usr/bin/env python3
"""Sessions that are created and never activated (asyncua's own steps of a connect, stopped
before ActivateSession), as a careless or hostile client leaves them.

    unactivated.py URL N

Opens N secure channels to URL, creates a session on each and activates none; prints
{"created": K} (K the sessions the server created; a refusal is {"refused": STATUS}) and
keeps the channels open until standard input closes.
"""
import asyncio
import json
import sys

from asyncua import Client


async def main():
    url, n = sys.argv[1], int(sys.argv[2])
    clients, created, refused = [], 0, None
    for _ in range(n):
        c = Client(url)
        try:
            await c.connect_socket()
            await c.send_hello()
            await c.open_secure_channel()
            await c.create_session()
            created += 1
        except Exception as e:  # every refusal is the answer
            refused = f"{type(e).__name__}: {e}"
        clients.append(c)
    out = {"created": created}
    if refused:
        out["refused"] = refused
    sys.stdout.write(json.dumps(out) + "\n")
    sys.stdout.flush()
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


asyncio.run(main())

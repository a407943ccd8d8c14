#!/usr/bin/env python3
"""Browse continuation points held and never released, as a careless or hostile client
leaves them (asyncua's browse service, one reference a node asked for).

    browse_points.py URL SESSIONS PER

Opens SESSIONS anonymous sessions to URL and in each browses the Objects folder PER times
in one Browse request asking one reference per node, so that every result that has more
needs a continuation point; never calls BrowseNext, but at the end asks the first session's
first point for its next reference. Prints {"held": K, "refused": R, "other": O, "first":
S} (K results with a continuation point, R answered Bad_NoContinuationPoints, O any other
status, S the status of BrowseNext with the first point kept) and keeps the sessions open
until standard input closes.
"""
import asyncio
import json
import sys

from asyncua import Client, ua


async def main():
    url, sessions, per = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    clients, held, refused, other, first = [], 0, 0, 0, None
    for _ in range(sessions):
        c = Client(url)
        await c.connect()
        clients.append(c)
        params = ua.BrowseParameters()
        params.View.Timestamp = ua.get_win_epoch()
        params.RequestedMaxReferencesPerNode = 1
        for _ in range(per):
            d = ua.BrowseDescription()
            d.NodeId = ua.NodeId(ua.ObjectIds.ObjectsFolder)
            d.BrowseDirection = ua.BrowseDirection.Both
            d.IncludeSubtypes = True
            d.ResultMask = ua.BrowseResultMask.All
            params.NodesToBrowse.append(d)
        for r in await c.uaclient.browse(params):
            if r.StatusCode.value == ua.StatusCodes.BadNoContinuationPoints:
                refused += 1
            elif r.StatusCode.is_good() and r.ContinuationPoint:
                held += 1
                first = first or (c, r.ContinuationPoint)
            else:
                other += 1
    status = None
    if first:
        params = ua.BrowseNextParameters()
        params.ReleaseContinuationPoints = False
        params.ContinuationPoints = [first[1]]
        try:
            results = await first[0].uaclient.browse_next(params)
            status = ua.StatusCode(results[0].StatusCode.value).name
        except ua.UaStatusCodeError as e:
            status = ua.StatusCode(e.code).name
    out = {"held": held, "refused": refused, "other": other, "first": status}
    sys.stdout.write(json.dumps(out) + "\n")
    sys.stdout.flush()
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.read)


asyncio.run(main())

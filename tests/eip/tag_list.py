#!/usr/bin/env python3
"""Lists a Logix controller's tags with pylogix (not the gateway's code).

    tag_list.py PORT

Prints one JSON object: "tags", each tag's name, type name, array size (0: not an array)
and whether it is a structure; "udts", each structure's name and its members' names and
type names as pylogix reads their templates.
"""
import json
import sys

from pylogix import PLC

with PLC() as plc:
    plc.IPAddress = "127.0.0.1"
    plc.Port = int(sys.argv[1])
    r = plc.GetTagList(True)
    if r.Status != "Success":
        sys.exit(f"pylogix: {r.Status}")
    tags = [{"name": t.TagName, "type": t.DataType, "size": t.Size, "struct": bool(t.Struct)}
            for t in r.Value]
    udts = {name: [[f.TagName, f.DataType] for f in udt.Fields]
            for name, udt in plc.UDTByName.items()}
print(json.dumps({"tags": tags, "udts": udts}))

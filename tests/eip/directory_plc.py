#!/usr/bin/env python3
"""A Logix controller's tag directory, for the import tests: the services a client lists a
controller's tags with, from the Logix 5000 Data Access manual (1756-PM020), on a real
EtherNet/IP session. cpppo's simulator has no tag directory; pylogix's GetTagList (another
implementation) is the check that this one answers as controllers do.

    directory_plc.py [--extra N] [--stuck] [--small | --unconnected]

Serves Register Session, List Identity, Forward Open (large and not), Forward Close,
SendRRData (with Unconnected Send unwrapped) and SendUnitData; and on them Get Instance
Attribute List (0x55) of the Symbol class (0x6B), controller and program scope, Get
Attribute List (0x03) and Read Template (0x4C) of the Template class (0x6C); and, for the
atomic controller tags, Read Tag (0x4C), Write Tag (0x4D) and Read-Modify-Write Tag (0x4E:
the tag becomes (value OR or-mask) AND and-mask), alone or in Multiple Service Packets
(0x0A), which cpppo's simulator does not have. Replies are
cut at about 480 bytes with status 0x06 (partial transfer), so clients page. `--extra N`
adds N DINT tags `Extra0`.. to the controller scope; each Forward Close and UnRegister
Session is printed on a line of its own (`forward-close vendor=0x4947 originator=...`); `--stuck` answers every page of the
list from the first symbol on, always partial (a controller a client must not follow
forever); `--small` refuses Large Forward Open, `--unconnected` both Forward Opens (a
controller that takes unconnected messages only). Listens on 127.0.0.1, prints the port once it listens.
"""
import socket
import struct
import sys
import threading

ATOMIC = {"BOOL": (0xC1, 1), "SINT": (0xC2, 1), "INT": (0xC3, 2), "DINT": (0xC4, 4),
          "LINT": (0xC5, 8), "USINT": (0xC6, 1), "UINT": (0xC7, 2), "UDINT": (0xC8, 4),
          "ULINT": (0xC9, 8), "REAL": (0xCA, 4), "LREAL": (0xCB, 8), "BOOL[]": (0xD3, 4)}
# Structures: name -> members (name, type, array length or 0).
UDTS = {
    "STRING": [("LEN", "DINT", 0), ("DATA", "SINT", 82)],
    "STATUS": [("Running", "BOOL", 0), ("Faulted", "BOOL", 0), ("Code", "INT", 0)],
    "MOTOR": [("Speed", "REAL", 0), ("Status", "STATUS", 0), ("Hist", "INT", 3),
              ("Label", "STRING", 0), ("Enabled", "BOOL", 0), ("__Hidden", "DINT", 0)],
}
TEMPLATE_ID = {"STRING": 0x0FCE, "STATUS": 0x0101, "MOTOR": 0x0102}
# Tags: (name, type, dimensions).
CONTROLLER = [("Speed", "REAL", []), ("Counts", "DINT", [5]), ("Grid", "INT", [2, 2]),
              ("Flag", "BOOL", []), ("Big", "LINT", []), ("Lr", "LREAL", []),
              ("Flags", "DINT", []), ("Word", "INT", []), ("Bad Name", "DINT", []),
              ("Name", "STRING", []), ("M1", "MOTOR", []), ("Bits", "BOOL[]", [2]),
              ("__Internal", "DINT", []), ("Map:Local", "MAP", []),
              ("Program:Main", "PROGRAM", [])]
PROGRAMS = {"Program:Main": [("Level", "UINT", []), ("Motors", "MOTOR", [2])]}
LIMIT = 480


def symbol_type(ty, dims):
    if ty == "PROGRAM":
        return 0x1068
    if ty == "MAP":
        return 0x1069
    code = ATOMIC[ty][0] if ty in ATOMIC else 0x8000 | TEMPLATE_ID[ty]
    return code | (len(dims) << 13)


def member_layout(udt):
    """Members as a controller lays them out: BOOLs in a hidden SINT host."""
    out, offset, host = [], 0, None
    for name, ty, n in UDTS[udt]:
        if ty == "BOOL" and n == 0:
            if host is None or host[1] == 8:
                host = [offset, 0]
                out.append((f"ZZZZZZZZZZ{udt}{offset}", 0xC2, 0, offset))
                offset += 1
            out.append((name, 0xC1, host[1], host[0]))
            host[1] += 1
            continue
        host = None
        size = ATOMIC[ty][1] if ty in ATOMIC else structure_size(ty)
        align = min(size, 4) if ty in ATOMIC else 4
        offset = (offset + align - 1) // align * align
        code = ATOMIC[ty][0] if ty in ATOMIC else 0x8000 | TEMPLATE_ID[ty]
        if n:
            code |= 0x2000
        out.append((name, code, n, offset))
        offset += size * max(n, 1)
    return out, (offset + 3) // 4 * 4


def structure_size(udt):
    return member_layout(udt)[1]


def template(udt):
    members, _ = member_layout(udt)
    data = b"".join(struct.pack("<HHI", info, code, off) for _, code, info, off in members)
    data += udt.encode() + b"\0" + b"".join(m[0].encode() + b"\0" for m in members)
    # Padded to whole words: the definition size (attribute 4) is the words of it plus
    # five, and clients read (size x 4 - 23) bytes rounded up to a word.
    return members, data + bytes(-len(data) % 4)


def symbols(scope):
    tags = CONTROLLER if scope is None else PROGRAMS.get(scope)
    if tags is None:
        return None
    out = [(i + 1, name, symbol_type(ty, dims), dims) for i, (name, ty, dims) in enumerate(tags)]
    if scope is None:
        out += [(100 + k, f"Extra{k}", 0xC4, []) for k in range(EXTRA)]
    return out


def parse_path(path):
    """Symbolic segments, class, instance, attribute of an EPATH."""
    out, at = {"symbol": None}, 0
    while at < len(path):
        seg = path[at]
        if seg == 0x91:
            n = path[at + 1]
            out["symbol"] = path[at + 2:at + 2 + n].decode()
            at += 2 + n + (n % 2)
        elif seg in (0x20, 0x24, 0x30):
            out[{0x20: "class", 0x24: "instance", 0x30: "attribute"}[seg]] = path[at + 1]
            at += 2
        elif seg in (0x21, 0x25, 0x31):
            key = {0x21: "class", 0x25: "instance", 0x31: "attribute"}[seg]
            out[key] = struct.unpack_from("<H", path, at + 2)[0]
            at += 4
        else:
            raise ValueError(f"segment {seg:#x}")
    return out


def reply(service, status, data=b""):
    return bytes([service | 0x80, 0, status, 0]) + data


def list_symbols(p, data):
    table = symbols(p["symbol"])
    if table is None or p.get("class") != 0x6B:
        return reply(0x55, 0x05)
    count = struct.unpack_from("<H", data, 0)[0]
    attrs = struct.unpack_from(f"<{count}H", data, 2)
    out, status = b"", 0
    for inst, name, ty, dims in table:
        if inst < p.get("instance", 0) and not STUCK:
            continue
        item = struct.pack("<I", inst)
        for a in attrs:
            if a == 1:
                item += struct.pack("<H", len(name)) + name.encode()
            elif a == 2:
                item += struct.pack("<H", ty)
            elif a == 7:
                item += struct.pack("<H", 4)
            elif a == 8:
                item += struct.pack("<3I", *(list(dims) + [0, 0, 0])[:3])
        if len(out) + len(item) > LIMIT:
            status = 0x06
            break
        out += item
    return reply(0x55, 0x06 if STUCK else status, out)


def template_service(service, p, data):
    udt = next((u for u, i in TEMPLATE_ID.items() if i == p.get("instance")), None)
    if udt is None:
        return reply(service, 0x05)
    members, body = template(udt)
    if service == 0x03:
        count = struct.unpack_from("<H", data, 0)[0]
        out = struct.pack("<H", count)
        for a in struct.unpack_from(f"<{count}H", data, 2):
            value = {1: struct.pack("<H", TEMPLATE_ID[udt]), 2: struct.pack("<H", len(members)),
                     3: struct.pack("<H", 0), 4: struct.pack("<I", (len(body) + 20) // 4),
                     5: struct.pack("<I", structure_size(udt))}.get(a)
            out += struct.pack("<HH", a, 0 if value else 0x14) + (value or b"")
        return reply(0x03, 0, out)
    offset, size = struct.unpack_from("<IH", data, 0)
    chunk = body[offset:offset + min(size, LIMIT)]
    more = offset + len(chunk) < min(len(body), offset + size) if chunk else False
    return reply(0x4C, 0x06 if more else 0, chunk)


VALUES = {}  # an atomic controller tag's bytes, by name (zeros at first)


def tag_service(service, p, data):
    entry = next(((ty, dims) for name, ty, dims in CONTROLLER if name == p["symbol"]), None)
    if entry is None or entry[1] or entry[0] not in ATOMIC or entry[0] == "BOOL[]":
        return reply(service, 0x05)
    code, size = ATOMIC[entry[0]]
    value = VALUES.setdefault(p["symbol"], bytes(size))
    if service == 0x4C:
        return reply(service, 0, struct.pack("<H", code) + value)
    if service == 0x4D:
        got, count = struct.unpack_from("<HH", data, 0)
        if got != code or count != 1 or len(data) != 4 + size:
            return reply(service, 0xFF, b"")[:3] + b"\x01" + struct.pack("<H", 0x2107)
        VALUES[p["symbol"]] = data[4:]
        return reply(service, 0)
    n = struct.unpack_from("<H", data, 0)[0]
    if n != size or len(data) != 2 + 2 * n:
        return reply(service, 0x13)
    ors, ands = data[2:2 + n], data[2 + n:2 + 2 * n]
    VALUES[p["symbol"]] = bytes((v | o) & a for v, o, a in zip(value, ors, ands))
    return reply(service, 0)


def multiple(data):
    count = struct.unpack_from("<H", data, 0)[0]
    offsets = list(struct.unpack_from(f"<{count}H", data, 2)) + [len(data)]
    replies = [message(data[offsets[k]:offsets[k + 1]]) for k in range(count)]
    out, at = b"", 2 + 2 * count
    for r in replies:
        out += struct.pack("<H", at)
        at += len(r)
    status = 0x1E if any(r[2] for r in replies) else 0
    return reply(0x0A, status, struct.pack("<H", count) + out + b"".join(replies))


def message(msg):
    service, words = msg[0], msg[1]
    path, data = msg[2:2 + 2 * words], msg[2 + 2 * words:]
    try:
        p = parse_path(path)
    except (ValueError, IndexError, struct.error):
        return reply(service, 0x04)
    if service == 0x52 and p.get("class") == 0x06:
        n = struct.unpack_from("<H", data, 2)[0]
        return message(data[4:4 + n])
    if service in REFUSED and p.get("class") == 0x06:
        return reply(service, 0x08)
    if service in (0x54, 0x5B) and p.get("class") == 0x06:
        t_o, serial, vendor, orig = struct.unpack_from("<IHHI", data, 6)
        return reply(service, 0, struct.pack("<IIHHIIIBB", 0x7000 + serial, t_o, serial,
                                             vendor, orig, 2_000_000, 2_000_000, 0, 0))
    if service == 0x4E and p.get("class") == 0x06:
        serial, vendor, orig = struct.unpack_from("<HHI", data, 2)
        print(f"forward-close vendor={vendor:#06x} originator={orig:#010x}", flush=True)
        return reply(0x4E, 0, data[2:10] + b"\0\0")
    if service == 0x55:
        return list_symbols(p, data)
    if service == 0x0A and p.get("class") == 0x02:
        return multiple(data)
    if service in (0x4C, 0x4D, 0x4E) and p["symbol"] and "class" not in p:
        return tag_service(service, p, data)
    if service in (0x03, 0x4C) and p.get("class") == 0x6C:
        return template_service(service, p, data)
    return reply(service, 0x08)


def cpf(items):
    return struct.pack("<IHH", 0, 0, len(items)) + b"".join(
        struct.pack("<HH", t, len(d)) + d for t, d in items)


def items_of(data):
    count, at, out = struct.unpack_from("<H", data, 6)[0], 8, {}
    for _ in range(count):
        t, n = struct.unpack_from("<HH", data, at)
        out[t] = data[at + 4:at + 4 + n]
        at += 4 + n
    return out


def answer(command, session, data):
    if command == 0x65:
        return 0x1234, data
    if command == 0x63:
        name = b"Directory"
        ident = struct.pack("<H", 1) + bytes(16) + struct.pack(
            "<HHHBBHI", 1, 14, 0x60, 32, 11, 0, 0x12345678) + bytes([len(name)]) + name + b"\x03"
        return session, struct.pack("<HHH", 1, 0x0C, len(ident)) + ident
    if command == 0x6F:
        got = items_of(data)
        return session, cpf([(0, b""), (0xB2, message(got.get(0xB2, b"\0\0")))])
    if command == 0x70:
        got = items_of(data)
        seq, msg = got[0xB1][:2], got[0xB1][2:]
        conn = struct.unpack("<I", got[0xA1])[0]
        return session, cpf([(0xA1, struct.pack("<I", conn)), (0xB1, seq + message(msg))])
    return session, None


def serve(sock):
    with sock:
        buf = b""
        while True:
            while len(buf) < 24 or len(buf) < 24 + struct.unpack_from("<H", buf, 2)[0]:
                more = sock.recv(65536)
                if not more:
                    return
                buf += more
            n = struct.unpack_from("<H", buf, 2)[0]
            head, data, buf = buf[:24], buf[24:24 + n], buf[24 + n:]
            command, _, session, _, context, _ = struct.unpack("<HHII8sI", head)
            if command == 0x66:
                print("unregister-session", flush=True)
                return
            session, out = answer(command, session, data)
            if out is not None:
                sock.sendall(struct.pack("<HHII8sI", command, len(out), session, 0, context, 0) + out)


EXTRA = int(sys.argv[sys.argv.index("--extra") + 1]) if "--extra" in sys.argv else 0
STUCK = "--stuck" in sys.argv
# `--small`: no Large Forward Open; `--unconnected`: no Forward Open at all.
REFUSED = {0x5B} if "--small" in sys.argv else {0x5B, 0x54} if "--unconnected" in sys.argv else set()
listener = socket.socket()
listener.bind(("127.0.0.1", 0))
listener.listen(16)
print(listener.getsockname()[1], flush=True)
while True:
    conn, _ = listener.accept()
    threading.Thread(target=serve, args=(conn,), daemon=True).start()

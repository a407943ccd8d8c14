"""Writes the seed corpora of the fuzz targets (fuzz/corpus/<target>/): valid inputs of each
parser, from which the fuzzer mutates. Run from anywhere: python3 fuzz/seeds.py."""

import pathlib
import shutil
import struct

HERE = pathlib.Path(__file__).resolve().parent
REPO = HERE.parent
CORPUS = HERE / "corpus"


def crc16(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return struct.pack("<H", crc)


def lrc(data):
    return (-sum(data)) & 0xFF


PDUS = [
    bytes.fromhex("0300000002"),
    bytes.fromhex("0100000008"),
    bytes.fromhex("0200100010"),
    bytes.fromhex("0400000004"),
    bytes.fromhex("050000ff00"),
    bytes.fromhex("0600010003"),
    bytes.fromhex("0f0000000a02ff03"),
    bytes.fromhex("100000000204000100020"[:-1]),
    bytes.fromhex("2b0e0100"),
    bytes.fromhex("17000000020000000204000a000b"),
]

ANSWERS = [
    (bytes.fromhex("0300000002"), bytes.fromhex("030400010002")),
    (bytes.fromhex("0100000008"), bytes.fromhex("0101a5")),
    (bytes.fromhex("0600010003"), bytes.fromhex("0600010003")),
    (bytes.fromhex("1000000002"), bytes.fromhex("1000000002")),
    (bytes.fromhex("0300000002"), bytes.fromhex("8302")),
]

MQTT = [
    bytes.fromhex("20020000"),
    bytes.fromhex("2003000000"),
    bytes.fromhex("d000"),
    bytes.fromhex("40020001"),
    bytes.fromhex("9003000100"),
    b"\x30\x0e\x00\x07iogate/hi" + b"x",
    b"\x32\x10\x00\x07iogate/\x00\x01{\"v\":1}",
]


def metric(name, datatype, field, value):
    body = b"\x0a" + bytes([len(name)]) + name + b"\x20" + bytes([datatype])
    return body + bytes([field << 3]) + value


def sparkplug():
    m1 = metric(b"Speed", 3, 10, b"\x05")
    m2 = metric(b"Node Control/Rebirth", 11, 14, b"\x01")
    m3 = b"\x10\x07\x20\x0c\x7a\x03abc"  # alias 7, a String
    return [b"\x12" + bytes([len(m)]) + m for m in (m1, m2, m3)] + [
        b"\x08\x01" + b"\x12" + bytes([len(m1)]) + m1 + b"\x18\x00"
    ]


S7 = [
    # A Read Var answer of one item of two bytes.
    bytes.fromhex("02f0803203000000010002000600000401ff0400101234"),
    # Setup of communication: a PDU of 480.
    bytes.fromhex("02f080320300000001000800000000f0000001000101e0"),
    # A Write Var answer of two items.
    bytes.fromhex("02f0803203000000010002000200000502ff0a"),
    # A refusal (8104).
    bytes.fromhex("02f0803203000000010000000081 04".replace(" ", "")),
    # A user-data SZL answer of one record.
    bytes.fromhex("02f080320700000001000c00160001120812840100000000" "ff09001204240000000400010008000000"),
    # A COTP connection confirm.
    bytes.fromhex("06d00001000100"),
]


def ld(field, payload):
    """A length-delimited protobuf field."""
    return bytes([field << 3 | 2, len(payload)]) + payload


def grpc():
    values = [b"\x18\x0a", b"\x10\x01", b"\x2d\x00\x00\xc0\x3f", b"\x3a\x03abc", b"\x40\xd0\x0f", b"\x20\xff\xff\xff\xff\x0f"]
    writes = [ld(1, ld(1, b"d1") + ld(2, b"Speed") + ld(3, v)) for v in values]
    return [b"\x00" + b"".join(writes), b"\x00" + writes[0], b"\x01" + ld(1, b"d1") + ld(2, ld(1, b"d1") + ld(2, b"f")), b"\x02" + ld(1, b"d1"), b"\x03", b"\x04" + ld(1, b"plc"), b"\x05" + ld(1, b"dev")]


def opcua():
    """OPC UA binary of the messages the targets decode, by asyncua (when installed)."""
    try:
        from asyncua import ua
        from asyncua.ua.ua_binary import struct_to_binary, variant_to_binary
    except ImportError:
        return []
    out = []
    for v in [ua.Variant(5, ua.VariantType.Int32), ua.Variant(2.5, ua.VariantType.Double), ua.Variant("abc"), ua.Variant(True), ua.Variant([1, 2], ua.VariantType.Int16)]:
        out.append(b"\x00" + struct_to_binary(ua.DataValue(v)))
    read = ua.ReadRequest()
    read.Parameters.NodesToRead = [ua.ReadValueId()]
    out.append(b"\x01" + struct_to_binary(read))
    write = ua.WriteRequest()
    wv = ua.WriteValue()
    wv.Value = ua.DataValue(ua.Variant(5, ua.VariantType.Int32))
    write.Parameters.NodesToWrite = [wv]
    out.append(b"\x02" + struct_to_binary(write))
    out.append(b"\x03" + struct_to_binary(ua.CreateMonitoredItemsRequest()))
    out.append(b"\x04" + struct_to_binary(ua.CreateSessionRequest()))
    out.append(b"\x05" + struct_to_binary(ua.ActivateSessionRequest()))
    out.append(b"\x06" + struct_to_binary(ua.BrowseRequest()))
    return out


# The method's index (GET, PUT, POST, DELETE, PATCH, HEAD), the target, a newline, the body.
HTTP = [
    b"\x00/api/v1/devices",
    b"\x00/api/v1/devices/sim/fields/DO_0",
    b"\x00/api/v1/devices/sim?fields=DO_0,AI_0",
    b"\x00/api/v1/values?devices=sim,plant&fields=plant.Level",
    b"\x01/api/v1/devices/sim/fields/DO_0\n{\"value\": true}",
    b"\x01/api/v1/devices/plant/fields/Recipe\n{\"value\": 300}",
    b"\x02/api/v1/devices/sim/write\n{\"DO_0\": true, \"DO_1\": false}",
    b"\x01/api/v1/devices/plant/fields/Level/simulate\n{\"value\": 42.5}",
    b"\x00/api/v1/events?device=sim&diagnostics=true",
    b"\x00/api/v1/writes/1",
    b"\x00/api/v1/links",
    b"\x01/api/v1/links/l1\n{\"tcp\": {\"host\": \"127.0.0.1\", \"port\": 502}}",
    b"\x01/api/v1/devices/d1\n{\"profile\": \"SimIo\", \"link\": \"l1\", \"slave_id\": 1}",
    b"\x03/api/v1/devices/d1",
    b"\x00/api/v1/profiles/SimPlant/st",
    b"\x00/api/v1/map/%25IW0",
    b"\x00/api/v1/map",
    b"\x01/api/v1/transactions/t1\n{\"link\": \"l1\", \"function\": 3, \"slave\": 1, \"address\": 0, \"refresh_interval_ms\": 1000}",
    b"\x02/api/v1/links/l1/transactions\n{\"function\": 6, \"slave\": 1, \"address\": 1, \"type\": \"uint16\", \"values\": [3]}",
    b"\x02/api/v1/links/l1/scan\n{\"ids\": \"1-247\", \"timeout\": \"50ms\"}",
    b"\x00/api/v1/config",
    b"\x00/readyz",
    b"\x00/metrics",
    b"\x00/api/v1/openapi.json",
    b"\x00/api/v1/devices/%ZZ/fields/%C3%A9",
]


# EtherNet/IP answers: the first byte also says how many replies are asked (mod 40).
def _eip_rr(mr):
    return b"\x02\x00\x00\x00\x00\x00\x02\x00\x00\x00\x00\x00\xb2\x00" + len(mr).to_bytes(2, "little") + mr


_DINT7 = b"\xcc\x00\x00\x00\xc4\x00\x07\x00\x00\x00"
_MISSING = b"\xcc\x00\x05\x01\x00\x00"
# A c104 (lib60870) station's answer to a general interrogation, as it sent it: STARTDT con,
# ACTCON, a double point, a short float, a single point and a scaled value with
# CP56Time2a, a step position, a bitstring, a normalized value, ACTTERM.
IEC104 = [bytes.fromhex(h) for h in [
    "68040b000000",
    "680e0000020064010700010000000014",
    "680e0200020003811400010065000002",
    "6812040002000d81140001006600000000484100",
    "68150c0002001e8114000100640000016d0e0f07030c1a",
    "68170e000200238114000100670000f9ff006d0e0f07030c1a",
    "680f040002000581140001006a00000300",
    "6812060002000781140001006b00000000000000",
    "681008000200098114000100680000004000",
    "6819100002002481140001006c00000000a03f006e0e0f07030c1a",
    "680e1200020064010a00010000000014",
]]

EIP = [
    _eip_rr(b"\x8a\x00\x00\x00\x02\x00\x06\x00" + bytes([6 + len(_DINT7)]) + b"\x00" + _DINT7 + _MISSING),
    _eip_rr(_DINT7),
    b"\x6f\x00\x10\x00" + bytes(20),
    b"\x01\x00\x0c\x00\x34\x00\x01\x00" + bytes(16) + b"\x01\x00\x0e\x00\x36\x00\x14\x0b\x60\x31\x1a\x06\x6c\x00\x05LOGIX\xff",
]


def write(target, name, data):
    d = CORPUS / target
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_bytes(data)


def main():
    if CORPUS.exists():
        shutil.rmtree(CORPUS)
    for i, pdu in enumerate(PDUS):
        write("modbus_request", f"pdu{i}", pdu)
        frame = bytes([1]) + pdu
        write("modbus_rtu_request", f"rtu{i}", frame + crc16(frame))
        write("modbus_ascii_request", f"ascii{i}", b":" + (frame + bytes([lrc(frame)])).hex().upper().encode() + b"\r\n")
        write("modbus_tcp_request", f"tcp{i}", struct.pack(">HHHB", i, 0, len(pdu) + 1, 1) + pdu)
    for i, (request, answer) in enumerate(ANSWERS):
        write("modbus_answer", f"answer{i}", bytes([len(request)]) + request + answer)
        rtu = bytes([1]) + answer
        write("modbus_answer", f"rtu{i}", bytes([len(request)]) + request + rtu + crc16(rtu))
    for i, packet in enumerate(MQTT):
        write("mqtt_packets", f"packet{i}", packet)
    write("mqtt_packets", "several", b"".join(MQTT))
    for i, payload in enumerate(sparkplug()):
        write("sparkplug_command", f"cmd{i}", payload)
    for i, body in enumerate([b'{"value": 5}', b"5", b'"T#2s"', b"true", b'{"value": "abc"}', b"[1,2]", b"1e400", b'{"value": -1.5}']):
        write("json_write", f"body{i}", body)
    for path in sorted((REPO / "examples").glob("*.yaml")) + sorted((REPO / "tests/fixtures/bad_configs").glob("*.yaml")):
        write("config_yaml", path.name, path.read_bytes())
    profiles = sorted((REPO / "profiles").glob("*.yaml"))[:12] + sorted((REPO / "tests/fixtures/bad_profiles").glob("*.yaml"))
    for path in profiles:
        write("profile_yaml", path.name, path.read_bytes())
    write("profile_yaml", "s7.yaml", b"name: P\nprotocol: s7\nfields:\n  - { name: a, type: REAL, direction: inout, address: DB1.DBW0, raw_type: INT, scale: 0.1 }\n  - { name: s, type: STRING, direction: input, address: DB1.STRING2, length: 20 }\n")
    write("profile_yaml", "opcua.yaml", b'name: P\nprotocol: opcua\nfields:\n  - { name: a, type: LREAL, direction: input, node: "ns=2;s=Line1.Speed" }\n')
    write("tokens", "tokens", b"# tokens\nread r3adr3adr3adr3ad\nwrite wr1tewr1tewr1te\nadmin 4dm1n4dm1n4dm1n\n")
    for path in sorted((REPO / "tests/fixtures/import/wb").glob("*.json"))[:6]:
        write("import", "wb-" + path.name, b"\x00" + path.read_bytes())
    for path in sorted((REPO / "tests/fixtures/import/edgex").glob("*.yml")):
        write("import", "edgex-" + path.name, b"\x01" + path.read_bytes())
    for i, answer in enumerate(S7):
        write("s7_answer", f"answer{i}", answer)
    write("iec104_frames", "interrogation", b"".join(IEC104))
    for i, frame in enumerate(IEC104):
        write("iec104_frames", f"frame{i}", frame)
    for i, answer in enumerate(EIP):
        write("eip_answer", f"answer{i}", answer)
    for i, message in enumerate(grpc()):
        write("grpc_request", f"message{i}", message)
    for i, message in enumerate(opcua()):
        write("opcua_binary", f"message{i}", message)
    for i, request in enumerate(HTTP):
        write("http_request", f"request{i}", request)


if __name__ == "__main__":
    main()

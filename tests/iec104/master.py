#!/usr/bin/env python3
"""A controlling station (a SCADA master) on c104, lib60870's Python binding, for the IEC 104
outstation's tests: connects to HOST:PORT, common address 1, with STARTDT, a general
interrogation and a clock synchronisation (c104's `Init.ALL`), takes every point the
outstation sends, known or not, and prints one line per information object it receives:

    m IOA TYPE VALUE QUALITY COT STAMP

(VALUE a number, or `true`/`false`; QUALITY c104's flags, `-` when good; STAMP the time tag
in milliseconds since the epoch, `-` without one), `unexpected IOA TYPE COT WHY` for what
c104 refuses, and `ready` once connected. Reads lines on
stdin, each answered with one line:

    gi                          -> `gi True|False`   (a general interrogation, awaited)
    ci                          -> `ci True|False`   (a counter interrogation)
    cmd IOA TYPE VALUE [select] -> `cmd IOA True|False` (a command, awaited: its ACTCON)
    mute | unmute               -> `mute True|False`  (STOPDT, STARTDT)

With `--count` (for the benchmarks) objects are counted, not printed:

    gi N    -> `gi MS` once N objects of the interrogation came, MS after it was asked
    stats   -> `stats N P50 P99 MAX`: the spontaneous objects since the last `stats`, and
               the milliseconds from their time tags to their arrival

With `--tagged` a point first seen in its plain form is kept in its time-tagged one (c104
keeps one type per point and hands the other form to `on_unexpected_message`, which drops
what it cannot take at once): for counting spontaneous objects, not interrogated ones.

    master.py HOST PORT [--count] [--tagged]
"""

import os
import sys
import threading
import time

import c104

lock = threading.Lock()


def say(*words):
    with lock:
        print(*words, flush=True)


def number(value):
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, c104.Double):
        return value.name
    if isinstance(value, c104.Byte32):
        return str(int(str(value), 0))
    try:
        return repr(float(value))
    except (TypeError, ValueError):
        return str(value)


def flags(quality):
    return "-" if quality is None or quality.is_good() else str(quality).replace(" ", "")


counting = "--count" in sys.argv
delays = []
interrogated = [0]
enough = threading.Event()
wanted = [0]


def count(message):
    if message.cot == c104.Cot.SPONTANEOUS:
        stamp = message.info.recorded_at
        if stamp is not None:
            delays.append(time.time() * 1000 - stamp.timestamp() * 1000)
    elif message.cot == c104.Cot.INTERROGATED_BY_STATION:
        interrogated[0] += 1
        if interrogated[0] >= wanted[0] > 0:
            enough.set()


def report(message):
    if counting:
        count(message)
        return
    info = message.info
    stamp = "-" if info.recorded_at is None else str(int(info.recorded_at.timestamp() * 1000))
    say("m", message.io_address, message.type.name, number(info.value), flags(info.quality),
        message.cot.name, stamp)


def on_point(point: c104.Point, previous_info: c104.Information, message: c104.IncomingMessage) -> c104.ResponseState:
    report(message)
    return c104.ResponseState.SUCCESS


TAGGED = {
    c104.Type.M_SP_NA_1: c104.Type.M_SP_TB_1,
    c104.Type.M_DP_NA_1: c104.Type.M_DP_TB_1,
    c104.Type.M_BO_NA_1: c104.Type.M_BO_TB_1,
    c104.Type.M_ME_NA_1: c104.Type.M_ME_TD_1,
    c104.Type.M_ME_NB_1: c104.Type.M_ME_TE_1,
    c104.Type.M_ME_NC_1: c104.Type.M_ME_TF_1,
    c104.Type.M_IT_NA_1: c104.Type.M_IT_TB_1,
}
tagged = "--tagged" in sys.argv


def on_new_point(client: c104.Client, station: c104.Station, io_address: int, point_type: c104.Type) -> None:
    if tagged:
        point_type = TAGGED.get(point_type, point_type)
    station.add_point(io_address=io_address, type=point_type).on_receive(callable=on_point)


def command_value(kind, text):
    if kind in (c104.Type.C_SC_NA_1, c104.Type.C_SC_TA_1):
        return text.lower() in ("1", "true", "on")
    if kind in (c104.Type.C_SE_NB_1, c104.Type.C_SE_TB_1):
        return c104.Int16(int(text))
    if kind in (c104.Type.C_SE_NA_1, c104.Type.C_SE_TA_1):
        return c104.NormalizedFloat(float(text))
    if kind in (c104.Type.C_BO_NA_1, c104.Type.C_BO_TA_1):
        return c104.Byte32(int(text).to_bytes(4, "little"))
    if kind in (c104.Type.C_DC_NA_1, c104.Type.C_DC_TA_1):
        return c104.Double.ON if text.lower() in ("1", "true", "on") else c104.Double.OFF
    return float(text)


def connect(host, port):
    """A client connected to HOST:PORT with data transfer started, or None when c104 did
    not open the connection within 10 s."""
    client = c104.Client(tick_rate_ms=50, command_timeout_ms=5000)
    client.on_new_point(callable=on_new_point)
    connection = client.add_connection(ip=host, port=port, init=c104.Init.ALL)
    connection.add_station(common_address=1)
    if os.environ.get("IEC104_RAW"):
        def rx(connection: c104.Connection, data: bytes) -> None:
            say("rx", data.hex())

        def tx(connection: c104.Connection, data: bytes) -> None:
            say("tx", data.hex())

        connection.on_receive_raw(callable=rx)
        connection.on_send_raw(callable=tx)
    # Told by c104's own thread: asking for the state from this one while that thread waits
    # for the interpreter inside a callback would deadlock.
    opened = threading.Event()

    def on_state(connection: c104.Connection, state: c104.ConnectionState) -> None:
        if state == c104.ConnectionState.OPEN:
            opened.set()

    connection.on_state_change(callable=on_state)

    def on_unexpected(connection: c104.Connection, message: c104.IncomingMessage, cause: c104.Umc) -> None:
        # c104 keeps one type per point; a SCADA master takes a point's time-tagged form
        # (spontaneous) as well as its plain one (interrogated).
        if cause == c104.Umc.MISMATCHED_TYPE_ID:
            report(message)
        else:
            say("unexpected", message.io_address, message.type.name, message.cot.name, cause.name)

    connection.on_unexpected_message(callable=on_unexpected)
    client.start()
    if opened.wait(10):
        return client, connection
    client.stop()
    return None


def main():
    host, port = sys.argv[1], int(sys.argv[2])
    # c104 at times connects and then sends nothing (not even STARTDT): a new client then.
    for _ in range(3):
        opened = connect(host, port)
        if opened is not None:
            break
    else:
        say("unopened")
        return
    client, connection = opened
    station = connection.get_station(common_address=1)
    say("ready")
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        if words[0] == "gi" and counting:
            interrogated[0], wanted[0] = 0, int(words[1])
            enough.clear()
            asked = time.time()
            connection.interrogation(common_address=1, wait_for_response=False)
            enough.wait(120)
            say("gi", round((time.time() - asked) * 1000, 1))
        elif words[0] == "stats":
            taken = sorted(delays)
            delays.clear()
            at = lambda q: round(taken[min(len(taken) - 1, int(len(taken) * q))], 1) if taken else 0
            say("stats", len(taken), at(0.5), at(0.99), at(1.0))
        elif words[0] == "gi":
            say("gi", connection.interrogation(common_address=1))
        elif words[0] == "ci":
            say("ci", connection.counter_interrogation(common_address=1))
        elif words[0] == "mute":
            say("mute", connection.mute())
        elif words[0] == "unmute":
            say("unmute", connection.unmute())
        elif words[0] == "cmd":
            ioa, kind = int(words[1]), getattr(c104.Type, words[2])
            mode = c104.CommandMode.SELECT_AND_EXECUTE if "select" in words[4:] else c104.CommandMode.DIRECT
            point = station.get_point(io_address=ioa)
            if point is None or point.type != kind:
                if point is not None:
                    station.remove_point(io_address=ioa)
                point = station.add_point(io_address=ioa, type=kind, command_mode=mode)
            point.value = command_value(kind, words[3])
            say("cmd", ioa, point.transmit(cause=c104.Cot.ACTIVATION))
    client.stop()


if __name__ == "__main__":
    main()

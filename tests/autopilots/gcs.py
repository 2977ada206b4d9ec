"""A ground station for the real-autopilot tests: pymavlink connected to the autopilot.

Usage: gcs.py ADDRESS            (e.g. tcp:127.0.0.1:5760, udpin:127.0.0.1:14550)

It sends a GCS HEARTBEAT once a second and prints, one JSON object a line on stdout, every
message it hears from a component other than the autopilot's (the bridge's, through the
autopilot), and the autopilot's COMMAND_ACK, HEARTBEAT, PARAM_VALUE and STATUSTEXT:
    {"msg": "HEARTBEAT", "src": [1, 140], "t": 12.5, ...the message's fields...}
It takes one JSON command a line on stdin:
    {"send": "COMMAND_LONG", "fields": {...}}     any message, by pymavlink's field names
    {"sign": "<64 hex digits>"}                   sign what it sends from now on
    {"unsign": true}                              stop signing
Text fields are sent as bytes; bytes fields (a signing key) are given as hex strings and named
in "hex". A command it cannot send ends it, with the reason on stderr.
"""

import json
import os
import sys
import threading
import time

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

address = sys.argv[1]
m = mavutil.mavlink_connection(address, source_system=255, source_component=190, dialect="common")
out = threading.Lock()


def emit(obj):
    with out:
        sys.stdout.write(json.dumps(obj) + "\n")
        sys.stdout.flush()


def commands():
    try:
        take_commands()
    except Exception as e:  # a command the script cannot send ends it, loudly
        sys.stderr.write(f"gcs.py: {e!r}\n")
        os._exit(1)
    os._exit(0)


def take_commands():
    for line in sys.stdin:
        line = line.strip()
        if not line:
            continue
        cmd = json.loads(line)
        with out:
            if "sign" in cmd:
                m.setup_signing(bytes.fromhex(cmd["sign"]), sign_outgoing=True)
            elif "unsign" in cmd:
                m.disable_signing()
            else:
                fields = {k: v.encode() if isinstance(v, str) else v for k, v in cmd.get("fields", {}).items()}
                for name in cmd.get("hex", []):
                    fields[name] = bytes.fromhex(fields[name].decode())
                msg = getattr(mavutil.mavlink, "MAVLink_" + cmd["send"].lower() + "_message")(**fields)
                m.mav.send(msg)


threading.Thread(target=commands, daemon=True).start()
emit({"msg": "READY", "src": [0, 0]})
next_heartbeat = 0.0
KEEP_FROM_AUTOPILOT = {"COMMAND_ACK", "HEARTBEAT", "PARAM_VALUE", "STATUSTEXT"}
while True:
    now = time.monotonic()
    if now >= next_heartbeat:
        with out:
            m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        next_heartbeat = now + 1.0
    msg = m.recv_match(blocking=True, timeout=0.1)
    if msg is None or msg.get_type() == "BAD_DATA" or msg.get_type().startswith("UNKNOWN"):
        continue
    src = [msg.get_srcSystem(), msg.get_srcComponent()]
    if src[1] == 1 and msg.get_type() not in KEEP_FROM_AUTOPILOT:
        continue
    fields = msg.to_dict()
    for k, v in list(fields.items()):
        if isinstance(v, (bytes, bytearray)):
            fields[k] = v.hex()
    fields["src"] = src
    fields["msg"] = msg.get_type()
    fields["t"] = time.monotonic()
    emit(fields)

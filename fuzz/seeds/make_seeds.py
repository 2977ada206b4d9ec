"""The receive-path fuzz targets' seeds (fuzz/regressions/{link_datagram,signed_stream,
stream_framing}/) from traffic captured by capture.py: real datagrams and a TCP stream of
ArduPlane SITL and PX4 SIH, some frames signed here (pymavlink's signing) with the targets' key.

    python3 make_seeds.py CAPTURE_DIR   # writes into ../regressions/
"""
import os, random, struct, sys, time
from pymavlink.dialects.v20 import ardupilotmega as mav2

CAPTURE = sys.argv[1]
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "regressions")
KEY = bytes([0x5E] * 32)  # lj9da_bridge::fuzz_targets::FUZZ_KEY
OTHER_KEY = bytes([0x11] * 32)
FAR_FUTURE = 75 * 365 * 86_400 * 100_000  # fuzz_targets::FAR_FUTURE: stays fresh on replay
NOW = int((time.time() - 1_420_070_400) * 100_000)  # stale a minute after the capture
random.seed(7)


def datagrams(name):
    path = os.path.join(CAPTURE, name)
    return [bytes.fromhex(l.strip()) for l in open(path) if l.strip()]


def parse(d):
    p = mav2.MAVLink(None)
    p.robust_parsing = True
    return p.parse_buffer(d) or []


def first_of(dgrams, kind, n=1, pred=lambda m: True):
    """The first `n` datagrams whose (single) message is `kind`, with distinct contents."""
    found, seen = [], set()
    for d in dgrams:
        ms = parse(d)
        if (kind == "BAD_DATA" and not ms) or any(m.get_type() == kind and pred(m) for m in ms):
            key = d[10:] if kind not in ("BAD_DATA",) else d
            if key in seen:
                continue
            seen.add(key)
            found.append(d)
            if len(found) == n:
                break
    return found


def signer(key, timestamp, link_id=0):
    mav = mav2.MAVLink(None)
    mav.signing.secret_key = key
    mav.signing.link_id = link_id
    mav.signing.timestamp = timestamp
    mav.signing.sign_outgoing = True
    return mav


def sign(d, mav):
    """Datagram `d`'s messages signed by `mav` (ids and sequence number kept)."""
    out = b""
    for m in parse(d):
        if m.get_type() == "BAD_DATA":
            continue
        mav.srcSystem, mav.srcComponent, mav.seq = m.get_srcSystem(), m.get_srcComponent(), m.get_seq()
        out += m.pack(mav)
        mav.signing.timestamp += 1
    return out


def write(target, name, data):
    d = os.path.join(OUT, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


ap = datagrams("ap_udp.hex")
px4 = datagrams("px4_udp.hex")
px4_onboard = datagrams("px4_onboard.hex")
ap_tcp = open(os.path.join(CAPTURE, "ap_tcp.bin"), "rb").read()

# --- link_datagram: [options, datagram] --------------------------------------------------------
unsigned = {}
for kind, n in [("HEARTBEAT", 1), ("SERVO_OUTPUT_RAW", 2), ("PARAM_VALUE", 2), ("STATUSTEXT", 2),
                ("COMMAND_ACK", 3), ("AUTOPILOT_VERSION", 1), ("SYS_STATUS", 1), ("RC_CHANNELS", 1),
                ("AHRS", 1), ("SIMSTATE", 1), ("ESC_TELEMETRY_1_TO_4", 1), ("TIMESYNC", 1),
                ("HOME_POSITION", 1), ("BAD_DATA", 1), ("BATTERY_STATUS", 1)]:
    for i, d in enumerate(first_of(ap, kind, n)):
        unsigned[f"ap_{kind.lower()}_{i}"] = d
for kind, n in [("HEARTBEAT", 1), ("SERVO_OUTPUT_RAW", 1), ("ACTUATOR_OUTPUT_STATUS", 2),
                ("PARAM_VALUE", 2), ("COMMAND_ACK", 3), ("AUTOPILOT_VERSION", 1),
                ("UNKNOWN_410", 1), ("UNKNOWN_8", 1), ("UNKNOWN_380", 1), ("OPEN_DRONE_ID_SYSTEM", 1),
                ("EXTENDED_SYS_STATE", 1), ("PING", 1), ("ESTIMATOR_STATUS", 1)]:
    for i, d in enumerate(first_of(px4, kind, n)):
        unsigned[f"px4_{kind.lower()}_{i}"] = d
for kind in ["ODOMETRY", "HIGHRES_IMU"]:
    for i, d in enumerate(first_of(px4_onboard, kind)):
        unsigned[f"px4_onboard_{kind.lower()}_{i}"] = d
for i, (name, d) in enumerate(sorted(unsigned.items())):
    # Mostly as a reader sees it (link 0 or 1); every fourth re-signed by the target, with the
    # key or (every eighth) another.
    options = [0x00, 0x01, 0x00, 0x02 | 0x10, 0x00, 0x01, 0x00, 0x02 | 0x08][i % 8]
    write("link_datagram", name, bytes([options]) + d)

hb_ap = first_of(ap, "HEARTBEAT")[0]
out_ap = first_of(ap, "SERVO_OUTPUT_RAW")[0]
hb_px4 = first_of(px4, "HEARTBEAT")[0]
act_px4 = first_of(px4, "ACTUATOR_OUTPUT_STATUS")[0]
out_px4 = first_of(px4, "SERVO_OUTPUT_RAW")[0]
param_px4 = first_of(px4, "PARAM_VALUE")[0]
ack_ap = first_of(ap, "COMMAND_ACK")[0]
text_ap = first_of(ap, "STATUSTEXT")[0]
# Several frames in one datagram (as a router or a busy autopilot sends them).
write("link_datagram", "ap_heartbeat_and_outputs", b"\x00" + hb_ap + out_ap)
write("link_datagram", "px4_heartbeat_outputs_actuators", b"\x01" + hb_px4 + out_px4 + act_px4)
write("link_datagram", "ap_outputs_with_junk_between", b"\x00" + hb_ap + b"0 " + out_ap + b"\xfd\x03" + ack_ap)
# Signed with the key at a far-future timestamp (accepted whenever replayed), pymavlink's signing.
signed = {
    "signed_ap_heartbeat": sign(hb_ap, signer(KEY, FAR_FUTURE)),
    "signed_ap_servo_output_raw": sign(out_ap, signer(KEY, FAR_FUTURE + 10)),
    "signed_ap_command_ack": sign(ack_ap, signer(KEY, FAR_FUTURE + 20, 1)),
    "signed_ap_statustext": sign(text_ap, signer(KEY, FAR_FUTURE + 30)),
    "signed_px4_heartbeat": sign(hb_px4, signer(KEY, FAR_FUTURE + 40)),
    "signed_px4_actuator_output_status": sign(act_px4, signer(KEY, FAR_FUTURE + 50)),
    "signed_px4_servo_output_raw": sign(out_px4, signer(KEY, FAR_FUTURE + 60, 2)),
    "signed_px4_param_value": sign(param_px4, signer(KEY, FAR_FUTURE + 70)),
}
for i, (name, d) in enumerate(signed.items()):
    write("link_datagram", name, bytes([i % 2]) + d)
mav = signer(KEY, FAR_FUTURE + 100)
write("link_datagram", "signed_ap_heartbeat_and_outputs", b"\x00" + sign(hb_ap, mav) + sign(out_ap, mav))
# A frame replayed within its datagram, and a stream going back in time: the second is dropped.
s = sign(out_ap, signer(KEY, FAR_FUTURE + 200))
write("link_datagram", "signed_replayed_in_one_datagram", b"\x00" + s + s)
write("link_datagram", "signed_older_after_newer",
      b"\x00" + sign(out_ap, signer(KEY, FAR_FUTURE + 300)) + sign(out_ap, signer(KEY, FAR_FUTURE + 299)))
# Signed at the capture: more than a minute old whenever replayed (dropped as old).
write("link_datagram", "signed_at_capture_ap_servo_output_raw", b"\x00" + sign(out_ap, signer(KEY, NOW)))
write("link_datagram", "signed_at_capture_px4_actuator_output_status", b"\x01" + sign(act_px4, signer(KEY, NOW)))
# Another key: a bad signature.
write("link_datagram", "signed_other_key_ap_servo_output_raw", b"\x00" + sign(out_ap, signer(OTHER_KEY, FAR_FUTURE)))
write("link_datagram", "signed_other_key_px4_heartbeat", b"\x01" + sign(hb_px4, signer(OTHER_KEY, FAR_FUTURE)))
# A radio's RADIO_STATUS, unsigned (taken by neither) and signed.
radio = mav2.MAVLink(None, srcSystem=51, srcComponent=68).radio_status_encode(200, 190, 80, 20, 30, 0, 0)
write("link_datagram", "radio_status_unsigned", b"\x00" + radio.pack(mav2.MAVLink(None, 51, 68)))
m = signer(KEY, FAR_FUTURE + 400); m.srcSystem, m.srcComponent = 51, 68
write("link_datagram", "radio_status_signed", b"\x00" + radio.pack(m))
# Real frames re-signed by the target from now (options & 4).
write("link_datagram", "resigned_now_px4_outputs", b"\x06" + hb_px4 + out_px4 + act_px4)

# --- signed_stream: records [op, ...] (see fuzz_targets::signed_stream) -------------------------
def frames(d):
    return [d]  # one message per captured datagram


def rec_bytes(d, link=0):
    assert len(d) <= 255
    return bytes([0x05 | (link << 4), len(d)]) + d


def rec_replay(i, link=0):
    return bytes([0x03 | (link << 4), i])


def rec_mutate(i, pos, flip, link=0):
    return bytes([0x04 | (link << 4), i, pos, flip])


def rec_clock(dt_10ms, at_100ms):
    return bytes([0x06]) + struct.pack("<hB", dt_10ms, at_100ms)


def rec_peer_signed(link_id, sysid, comp, seq, idsel, dt_10ms, payload, other_key=False, link=0):
    op = (0x08 if other_key else 0x00) | (link << 4)
    return bytes([op, link_id, sysid, comp, seq, idsel]) + struct.pack("<h", dt_10ms) + bytes([len(payload)]) + payload


def rec_unsigned(sysid, comp, seq, sel, payload, link=0):
    return bytes([0x07 | (link << 4), sysid, comp, seq, sel, len(payload)]) + payload


mav = signer(KEY, FAR_FUTURE)
ap_run = [sign(d, mav) for d in [hb_ap, out_ap, out_ap, ack_ap, text_ap]]
seq = b"".join(rec_bytes(d) for d in ap_run)
seq += rec_replay(1) + rec_replay(4, link=1) + rec_clock(500, 20) + rec_mutate(2, 3, 0x40) + rec_bytes(sign(out_ap, mav))
write("signed_stream", "ap_signed_run_then_replays", seq)
mav = signer(KEY, FAR_FUTURE + 5_000, link_id=1)
px4_run = [sign(d, mav) for d in [hb_px4, act_px4, out_px4, act_px4, param_px4]]
seq = b"".join(rec_bytes(d, link=1) for d in px4_run) + rec_replay(0, link=1) + rec_replay(3) + rec_mutate(1, 10, 0x01)
write("signed_stream", "px4_signed_run_then_replays", seq)
# Unsigned real traffic (dropped and counted; warnings at the first and every 10 s) and a radio.
seq = b"".join(rec_bytes(d, link=i % 3) for i, d in enumerate([hb_ap, out_ap, hb_px4, act_px4]))
seq += rec_clock(0, 60) + rec_bytes(out_px4) + rec_clock(0, 120) + rec_bytes(out_ap)
seq += rec_bytes(radio.pack(mav2.MAVLink(None, 51, 68)))
write("signed_stream", "unsigned_real_traffic_and_radio", seq)
# Signed at the capture (old on replay) and with another key, then peers signing now.
seq = rec_bytes(sign(out_ap, signer(KEY, NOW))) + rec_bytes(sign(act_px4, signer(OTHER_KEY, FAR_FUTURE)))
payload = parse(out_ap)[0].get_msgbuf()[10:-2]
seq += rec_peer_signed(0, 1, 1, 7, 1, 0, payload) + rec_peer_signed(0, 1, 1, 8, 1, -1, payload)
seq += rec_peer_signed(0, 1, 1, 9, 1, -6001, payload) + rec_peer_signed(3, 1, 1, 9, 1, -5999, payload)
seq += rec_peer_signed(0, 1, 1, 10, 1, 100, payload, other_key=True) + rec_replay(2) + rec_replay(3, link=1)
write("signed_stream", "peers_signing_now_around_the_minute", seq)
# The wall clock set back and forward between signed frames of one stream.
seq = rec_peer_signed(0, 1, 1, 0, 0, 0, b"") + rec_clock(-30000, 1) + rec_peer_signed(0, 1, 1, 1, 0, 0, b"")
seq += rec_clock(30000, 1) + rec_clock(30000, 1) + rec_peer_signed(0, 1, 1, 2, 0, 0, b"") + rec_peer_signed(0, 2, 1, 2, 0, -32000, b"")
write("signed_stream", "clock_back_and_forth", seq)
# Raw payloads signed with the key: one that is no message of the dialect (bad enum).
seq = bytes([0x02, 0, 1, 1, 0, 0]) + struct.pack("<h", 0) + bytes([9]) + bytes([0xFF] * 9)
seq += bytes([0x02, 0, 1, 1, 1, 1]) + struct.pack("<h", 1) + bytes([21]) + bytes(range(21))
seq += rec_unsigned(1, 1, 0, 8, b"\xc8\xbe\x50\x14\x1e\x00\x00\x00\x00") + rec_unsigned(1, 1, 1, 0x81, b"")
write("signed_stream", "raw_payloads_signed_and_unsigned", seq)

# --- stream_framing: [seed (2 bytes), stream] --------------------------------------------------
for i, (off, seed) in enumerate([(0, 0x0000), (4096, 0x0001), (9000, 0x0002), (20000, 0x0003),
                                 (30000, 0x0005), (40000, 0x000A)]):
    write("stream_framing", f"ap_tcp_stream_{i}", struct.pack("<H", seed) + ap_tcp[off:off + 4000])
px4_stream = b"".join(px4_onboard[:40])
write("stream_framing", "px4_onboard_datagrams_as_a_stream", struct.pack("<H", 0x0006) + px4_stream[:4000])
px4_gcs = b"".join(px4[:40])
write("stream_framing", "px4_gcs_datagrams_as_a_stream", struct.pack("<H", 0x0009) + px4_gcs[:4000])
mav = signer(KEY, FAR_FUTURE)
signed_stream = b"".join(sign(d, mav) for d in ap[:30])
write("stream_framing", "ap_signed_stream", struct.pack("<H", 0x000B) + signed_stream[:4000])
# Noise in a stream: a cut frame, a stray marker, line noise between real frames.
noisy = ap_tcp[:300] + ap_tcp[300:330] + b"\xfd\x20\x00" + ap_tcp[400:900] + bytes(random.randrange(256) for _ in range(200)) + ap_tcp[900:2000]
write("stream_framing", "ap_tcp_stream_with_noise", struct.pack("<H", 0x0007) + noisy)
write("stream_framing", "stray_marker_before_a_frame", struct.pack("<H", 0x0000) + b"\xfd" + hb_ap)

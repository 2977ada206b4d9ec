#!/usr/bin/env python3
"""The host's side of the board in a box, once the computer is booting.

`run` starts the simulated servo buses and the computer (`machine boot`: the emulated arm64
board, or a container under systemd-nspawn), then this program: it asks the computer's agent
(guest.sh, over "control" and "results": the board's virtio ports, or the container's FIFO
and file) to install and set up the package as an integrator would, plays an autopilot and a
ground station (pymavlink, over UDP), reads what the simulated servos saw (their logs), and
judges it all: one PASS/FAIL/SKIP line per check, the exit status 1 if any check failed. The
checks of the kernel's side (the PL011, the FTDI adapter, udev) are the board's: the
container skips them and says so.

Clocks: the times here are the host's (time.time()); the simulators' log lines carry the same
clock (UTC). The computer's clock is read only to place its flight record's last sample on
the host's clock (the container's is the host's own).
"""

import argparse
import datetime
import json
import os
import re
import socket
import stat
import statistics
import subprocess
import sys
import threading
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

# The autopilot's outputs: a staircase, a new value on every channel every STEP_S seconds, and at
# once when a fault is triggered (so that the outputs after a recovery differ from the servos'
# goals before it). Channel c drives the servo with ID c (mapping written by guest.sh).
STEP_S = 2.0
OUTPUT_HZ = 50.0
CHANNELS = 4
# A goal write counts as the autopilot's current output if it carries a value the autopilot sent
# at most this long before (the path autopilot → slirp → bridge → bus under TCG, with margin).
GRACE_S = 1.0
# Goal positions: the servo's own PWM range, 920 / 1520 / 2120 µs ↔ −25 / 0 / +25 mm, in
# 0.01 mm. The staircase uses PWM steps of 12 µs (0.5 mm): values on the servo's 0.02 mm grid.
PWM_CENTRE_US = 1520
PWM_HALF_RANGE_US = 600
STROKE_HALF_CENTI = 2500
TOLERANCE_CENTI = 2
GOAL_REGISTER = 30
# A bus without a packet for this long has lost its bridge (it polls its servos all the time,
# a packet every few milliseconds). On the board, TCG's pauses are longer than the container's
# recoveries are: each place has its own.
SILENCE_S = {"board": 0.5, "container": 0.1}
# After a power cut, the flight record of the cut run must hold the samples up to this long
# before the cut.
RECORD_LOSS_S = 0.5

BUSES = {"uart": (1, 2), "usb": (3, 4)}


def pwm_to_centi(pwm):
    return round((pwm - PWM_CENTRE_US) * STROKE_HALF_CENTI / PWM_HALF_RANGE_US)


def staircase(step, channel):
    """PWM of `channel` (1-based) on step `step`: ±480 µs, different from step to step."""
    return PWM_CENTRE_US + 12 * (((step * 23 + channel * 31) % 81) - 40)


# ── report ──────────────────────────────────────────────────────────────────────────────────────


class Report:
    def __init__(self, out_dir, strict=False):
        self.out_dir = out_dir
        # --strict (CI): a SKIP is a FAIL, but for a check of the kernel's side in a container.
        self.strict = strict
        self.checks = []
        self.phases = []
        self.host_phases = ""
        self.log = open(os.path.join(out_dir, "host.log"), "a", buffering=1)

    def note(self, text):
        line = f"[{time.strftime('%H:%M:%S')}] {text}"
        print(line, flush=True)
        self.log.write(line + "\n")

    def check(self, name, ok, detail, kernel=False):
        """ok: True (PASS), False (FAIL) or None (SKIP: could not be run here, says why; a FAIL
        under --strict unless `kernel`, a check of the kernel's side that a container cannot
        run)."""
        if ok is None and self.strict and not kernel:
            ok, detail = False, f"{detail} (not run: a failure under --strict)"
        verdict = {True: "PASS", False: "FAIL", None: "SKIP"}[ok]
        self.checks.append((verdict, name, detail))
        self.note(f"{verdict} {name}: {detail}")
        return ok

    def phase(self, name):
        return Phase(self, name)

    def write(self, name, text):
        path = os.path.join(self.out_dir, name)
        with open(path, "w") as f:
            f.write(text)
        return path

    def summary(self):
        lines = ["", "== phases (wall time)"] + [l for l in self.host_phases.splitlines() if l.strip()]
        lines += [f"  {name:<28} {secs:8.1f} s" for name, secs in self.phases]
        lines += ["", "== checks"]
        width = max((len(n) for _, n, _ in self.checks), default=10)
        lines += [f"  {v}  {n:<{width}}  {d}" for v, n, d in self.checks]
        failed = sum(v == "FAIL" for v, _, _ in self.checks)
        skipped = sum(v == "SKIP" for v, _, _ in self.checks)
        passed = sum(v == "PASS" for v, _, _ in self.checks)
        lines.append(f"\n{passed} passed, {failed} failed, {skipped} skipped")
        text = "\n".join(lines) + "\n"
        print(text, flush=True)
        self.write("summary.txt", text)
        return failed == 0


class Phase:
    def __init__(self, report, name):
        self.report, self.name = report, name

    def __enter__(self):
        self.start = time.monotonic()
        self.report.note(f"== {self.name}")
        return self

    def __exit__(self, *exc):
        secs = time.monotonic() - self.start
        self.report.phases.append((self.name, secs))
        self.report.note(f"== {self.name}: {secs:.1f} s")
        return False


# ── the board's agent ──────────────────────────────────────────────────────────────────────────


class GuestError(Exception):
    pass


class BootError(GuestError):
    """The computer did not come up: this host cannot run it (exit 2, as a set-up failure)."""


class Guest:
    """Requests to guest.sh: one line on the control port, the answer between markers in the
    results file."""

    def __init__(self, control_path, results_path, report, alive=lambda: True):
        self.report = report
        self.control_path = control_path
        self.results_path = results_path
        self.offset = 0
        self.pending = ""
        self.blocks = {}
        self.current = None  # the request whose output is being read
        self.next_id = 1
        self.control = None
        self.connect(30, alive)

    def connect(self, timeout, alive=lambda: True):
        """Open "control": QEMU's socket of the board's virtio port, or the container's FIFO
        (which opens once the agent reads it). Again after the computer was cut and booted."""
        if self.control is not None:
            self.control.close()
            self.control = None
        self.ready_at = None
        self.current = None
        deadline = time.monotonic() + timeout
        while True:
            try:
                if stat.S_ISFIFO(os.stat(self.control_path).st_mode):
                    fd = os.open(self.control_path, os.O_WRONLY | os.O_NONBLOCK)
                    os.set_blocking(fd, True)
                    self.control = os.fdopen(fd, "wb", buffering=0)
                else:
                    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                    sock.connect(self.control_path)
                    self.control = sock.makefile("wb", buffering=0)
                return
            except OSError:
                if time.monotonic() > deadline:
                    raise GuestError(f"cannot open the agent's control port {self.control_path}")
                if not alive():
                    raise GuestError("the computer stopped before its agent listened")
                time.sleep(0.05)

    def _read(self):
        try:
            with open(self.results_path, "rb") as f:
                f.seek(self.offset)
                data = f.read()
        except FileNotFoundError:
            return
        self.offset += len(data)
        self.pending += data.decode("utf-8", "replace")
        *lines, self.pending = self.pending.split("\n")
        for line in lines:
            self._line(line.rstrip("\r"))

    def _line(self, line):
        if line.startswith("@@READY"):
            self.ready_at = time.time()
        elif line.startswith("@@BEGIN "):
            self.current = int(line.split()[1])
            self.blocks[self.current] = {"lines": [], "status": None}
        elif line.startswith("@@END "):
            _, rid, status = line.split()
            self.blocks[int(rid)]["status"] = int(status)
            self.current = None
        elif self.current is not None:
            self.blocks[self.current]["lines"].append(line)

    def wait_ready(self, timeout, alive=lambda: True):
        """Until the agent says it is ready; `alive` tells whether the computer still runs."""
        deadline = time.monotonic() + timeout
        while self.ready_at is None:
            if time.monotonic() > deadline:
                raise GuestError(f"the computer's agent did not report within {timeout} s")
            if not alive():
                raise GuestError("the computer stopped before its agent was ready")
            self._read()
            time.sleep(0.1)
        return self.ready_at

    def send(self, *words):
        """Send a request; returns its id and the host time it was sent."""
        rid = self.next_id
        self.next_id += 1
        self.control.write((" ".join([str(rid), *map(str, words)]) + "\n").encode())
        return rid, time.time()

    def wait(self, rid, timeout):
        deadline = time.monotonic() + timeout
        while True:
            self._read()
            block = self.blocks.get(rid)
            if block and block["status"] is not None:
                return block["status"], block["lines"]
            if time.monotonic() > deadline:
                raise GuestError(f"request {rid} got no answer within {timeout} s")
            time.sleep(0.05)

    def run(self, *words, timeout=320):
        rid, _ = self.send(*words)
        status, lines = self.wait(rid, timeout)
        self.report.log.write(f"--- guest {' '.join(map(str, words))} (exit {status})\n")
        self.report.log.write("\n".join(lines) + "\n")
        return status, lines


def number(text):
    """A figure the computer printed, or infinity where it printed none ("unknown")."""
    try:
        return float(text)
    except (TypeError, ValueError):
        return float("inf")


def parse_usec(text):
    """systemd's time span as `systemctl show` prints it ("2s", "500ms", "1min 30s") in seconds."""
    units = {"us": 1e-6, "ms": 1e-3, "s": 1.0, "min": 60.0, "h": 3600.0}
    total = 0.0
    for number, unit in re.findall(r"([0-9.]+)\s*(us|ms|min|s|h)", text):
        total += float(number) * units[unit]
    return total or None


def values(lines):
    """KEY=value lines of a guest answer (the first of each key)."""
    found = {}
    for line in lines:
        m = re.match(r"^([A-Za-z][A-Za-z0-9_]*)=(.*)$", line)
        if m and m.group(1) not in found:
            found[m.group(1)] = m.group(2)
    return found


def section(lines, name):
    """The lines after `--- name` up to the next `--- ` line."""
    out, inside = [], False
    for line in lines:
        if line.startswith("--- "):
            inside = line == f"--- {name}"
            continue
        if inside:
            out.append(line)
    return out


# ── the simulated servos, as their logs tell ────────────────────────────────────────────────────

TS = re.compile(r"^(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d+)Z ")
PACKET = re.compile(r"event=Packet\(.*?bytes: \[([0-9, ]*)\].*?acted: \[([0-9, ]*)\], collided: (true|false)")
STATS_ROW = re.compile(r"^\s+packets \d+ replies \d+ bad-sums \d+ garbage \d+ collisions \d+ .*$")
STATUS_ROW = re.compile(r"^\s+(\d+)\s+(yes|no)\s+(\S+)\s+(-?\d+\.\d+)\s+(-?\d+\.\d+)\s")


def parse_ts(text):
    return datetime.datetime.fromisoformat(text + "+00:00").timestamp()


def goals_of(frame):
    """{servo id: goal position, 0.01 mm} that a host packet writes (short, broadcast or long)."""
    if len(frame) < 8 or frame[0] != 0xFA or frame[1] != 0xAF:
        return {}
    sid, flag, address, length, count = frame[2:7]
    data = frame[7:-1]
    goals = {}

    def pick(block, first):
        offset = GOAL_REGISTER - first
        if 0 <= offset and offset + 2 <= len(block):
            return int.from_bytes(bytes(block[offset : offset + 2]), "little", signed=True)
        return None

    if sid == 0 and flag == 0:  # long packet: count blocks of VID + (length − 1) bytes
        for i in range(count):
            block = data[i * length : (i + 1) * length]
            if len(block) == length:
                goal = pick(block[1:], address)
                if goal is not None:
                    goals[block[0]] = goal
    elif count == 1 and length > 0 and address != 0xFF:
        goal = pick(data, address)
        if goal is not None:
            goals[sid] = goal
    return goals


class SimLog:
    """One lj9da-sim's stderr (-vv and --status-every), read as it grows."""

    def __init__(self, bus, path, ids):
        self.bus, self.path, self.ids = bus, path, ids
        self.offset = 0
        self.pending = ""
        self.last_ts = None
        self.packets = []  # (t, {id: goal}) of every understood host packet
        self.status = []  # (t, id, online, force, goal_mm, pos_mm)
        self.stats = {}  # the latest counters: packets, replies, bad-sums, garbage (bytes), …

    def poll(self):
        with open(self.path, "rb") as f:
            f.seek(self.offset)
            data = f.read()
        self.offset += len(data)
        self.pending += data.decode("utf-8", "replace")
        *lines, self.pending = self.pending.split("\n")
        for line in lines:
            line = re.sub(r"\x1b\[[0-9;]*m", "", line)
            m = TS.match(line)
            if m:
                self.last_ts = parse_ts(m.group(1))
                p = PACKET.search(line)
                if p and p.group(3) == "false":
                    frame = [int(x) for x in p.group(1).split(",") if x.strip()]
                    acted = {int(x) for x in p.group(2).split(",") if x.strip()}
                    goals = {i: g for i, g in goals_of(frame).items() if i in acted or i == 255}
                    self.packets.append((self.last_ts, goals))
                continue
            c = STATS_ROW.match(line)
            if c:
                self.stats = dict(zip(c.group(0).split()[0::2], map(int, c.group(0).split()[1::2])))
                continue
            s = STATUS_ROW.match(line)
            if s and self.last_ts is not None:
                self.status.append(
                    (self.last_ts, int(s.group(1)), s.group(2) == "yes", s.group(3),
                     float(s.group(4)), float(s.group(5)))
                )

    def goal_writes(self, since=0.0, until=float("inf")):
        return [(t, i, g) for t, goals in self.packets if since <= t <= until for i, g in goals.items()]


# ── the autopilot and the ground station ───────────────────────────────────────────────────────


class Autopilot(threading.Thread):
    """An ArduPilot-like autopilot on the bridge's `connection`: HEARTBEAT at 1 Hz,
    SERVO_OUTPUT_RAW at 50 Hz (the staircase), COMMAND_ACK ACCEPTED to its stream request."""

    def __init__(self, port):
        super().__init__(daemon=True, name="autopilot")
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, dialect="ardupilotmega"
        )
        self.lock = threading.Lock()
        self.steps = []  # (host time the step began, [pwm per channel])
        self.step = 0
        self.advance = threading.Event()
        self.stop = threading.Event()
        self.sent = 0
        self.acks = 0

    def new_step(self):
        """Start the next step now (a fault was triggered); returns its start time."""
        self.advance.set()
        while self.advance.is_set():
            time.sleep(0.002)
        with self.lock:
            return self.steps[-1][0]

    def allowed(self, channel, t):
        """Goals (0.01 mm) the autopilot sent for `channel` within GRACE_S before `t`."""
        with self.lock:
            steps = list(self.steps)
        out = set()
        for k, (start, pwms) in enumerate(steps):
            end = steps[k + 1][0] if k + 1 < len(steps) else float("inf")
            if start <= t and end >= t - GRACE_S:
                out.add(pwm_to_centi(pwms[channel - 1]))
        return out

    def current_since(self, channel, t0):
        """Goals the autopilot sent for `channel` from `t0` on."""
        with self.lock:
            steps = list(self.steps)
        out = set()
        for k, (start, pwms) in enumerate(steps):
            end = steps[k + 1][0] if k + 1 < len(steps) else float("inf")
            if end > t0:
                out.add(pwm_to_centi(pwms[channel - 1]))
        return out

    def run(self):
        mav = self.conn.mav
        period = 1.0 / OUTPUT_HZ
        boot = time.monotonic()
        next_send = boot
        next_beat = boot
        step_due = boot
        while not self.stop.is_set():
            now = time.monotonic()
            if now >= step_due or self.advance.is_set():
                pwms = [staircase(self.step, c) for c in range(1, CHANNELS + 1)]
                with self.lock:
                    self.steps.append((time.time(), pwms))
                self.step += 1
                step_due = now + STEP_S
                self.advance.clear()
            if now >= next_beat:
                mav.heartbeat_send(
                    mavutil.mavlink.MAV_TYPE_FIXED_WING, mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                    mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0, mavutil.mavlink.MAV_STATE_ACTIVE,
                )
                next_beat += 1.0
            if now >= next_send:
                with self.lock:
                    pwms = self.steps[-1][1]
                raw = pwms + [0] * (8 - len(pwms))
                mav.servo_output_raw_send(int((now - boot) * 1e6) & 0xFFFFFFFF, 0, *raw)
                self.sent += 1
                next_send += period
                if next_send < now:
                    next_send = now + period
            while True:
                msg = self.conn.recv_match(blocking=False)
                if msg is None:
                    break
                if msg.get_type() == "COMMAND_LONG" and msg.target_system in (0, 1):
                    mav.command_ack_send(msg.command, mavutil.mavlink.MAV_RESULT_ACCEPTED, 0, 0,
                                         msg.get_srcSystem(), msg.get_srcComponent())
                    self.acks += 1
            time.sleep(max(0.0, min(next_send, step_due, next_beat) - time.monotonic()))


class GroundStation(threading.Thread):
    """A ground station on the bridge's `gcs` link: HEARTBEAT at 1 Hz, counts what it hears."""

    def __init__(self, port):
        super().__init__(daemon=True, name="gcs")
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=255, source_component=190, dialect="ardupilotmega"
        )
        self.stop = threading.Event()
        self.lock = threading.Lock()
        self.counts = {}  # (system, component, type) → count
        self.names = {}  # NAMED_VALUE_FLOAT name → last value
        self.texts = []  # (t, severity, text)

    def snapshot(self):
        with self.lock:
            return dict(self.counts), dict(self.names), list(self.texts)

    def run(self):
        next_beat = time.monotonic()
        while not self.stop.is_set():
            if time.monotonic() >= next_beat:
                self.conn.mav.heartbeat_send(
                    mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
                )
                next_beat += 1.0
            msg = self.conn.recv_match(blocking=True, timeout=0.2)
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            key = (msg.get_srcSystem(), msg.get_srcComponent(), msg.get_type())
            with self.lock:
                self.counts[key] = self.counts.get(key, 0) + 1
                if msg.get_type() == "NAMED_VALUE_FLOAT":
                    self.names[msg.name] = msg.value
                elif msg.get_type() == "STATUSTEXT":
                    self.texts.append((time.time(), msg.severity, msg.text))


# ── checks ─────────────────────────────────────────────────────────────────────────────────────


class Board:
    def __init__(self, args):
        self.args = args
        self.report = Report(args.out, strict=args.strict)
        self.report.host_phases = args.host_phases
        self.sims = {
            "uart": SimLog("uart", args.sim_uart, BUSES["uart"]),
            "usb": SimLog("usb", args.sim_usb, BUSES["usb"]),
        }
        self.autopilot = Autopilot(args.autopilot_port)
        self.gcs = GroundStation(args.gcs_port)
        self.guest = None
        self.place = args.place
        self.silence_s = SILENCE_S[args.place]
        # The buses' devices as the computer has them.
        self.devices_of = ({"uart": "/dev/ttyAMA0", "usb": "/dev/ttyUSB0"} if self.place == "board"
                           else {"uart": "/dev/lj9da-uart", "usb": "/dev/lj9da-usb"})

    def alive(self):
        """Whether the computer's process (QEMU, or systemd-nspawn's `timeout`) still runs."""
        try:
            with open(os.path.join(self.args.run_dir, "machine.pid")) as f:
                os.kill(int(f.read().strip()), 0)
            return True
        except (OSError, ValueError):
            return False

    def console_tail(self):
        """The console's last line that says something, for an error."""
        try:
            with open(os.path.join(self.args.run_dir, "console.log"), errors="replace") as f:
                lines = [l.strip() for l in f.read().splitlines() if l.strip()]
            return lines[-1] if lines else "(the console is empty)"
        except OSError:
            return "(no console log)"

    def kernel_side(self, name):
        """In the container, a check of the kernel's drivers is skipped: the board has them."""
        if self.place == "board":
            return False
        self.report.check(name, None, "the kernel's side: the arm64 board's (packaging/board/run), "
                          "not a container's, whose buses are pseudo-terminals", kernel=True)
        return True

    def poll_sims(self):
        for sim in self.sims.values():
            sim.poll()

    # The agent and the devices.
    def boot(self):
        r = self.report
        with r.phase(f"boot ({self.place} start → agent ready)"):
            try:
                self.guest = Guest(self.args.control, self.args.results, r, self.alive)
                ready = self.guest.wait_ready(self.args.boot_timeout, self.alive)
            except GuestError as e:
                raise BootError(f"the {self.place} did not come up: {e}; the console's last line: "
                                f"{self.console_tail()}") from None
            r.check("boot", True, f"agent ready {ready - self.args.machine_started:.1f} s after the {self.place} started")
            rid, sent = self.guest.send("ping")
            self.guest.wait(rid, 30)
            r.note(f"control round trip (ping): {(time.time() - sent) * 1000:.0f} ms")

    def devices(self):
        r = self.report
        status, lines = self.guest.run("facts")
        v = values(lines)
        r.note(f"board: {v.get('KERNEL')}, {v.get('SYSTEMD')}; {v.get('BOOT')}; {v.get('IPV4')}")
        failed = [l.split()[1] for l in lines if l.startswith("FAILED_UNIT ")]
        r.check("board up", v.get("SYSTEM_STATE") == "running",
                f"system {v.get('SYSTEM_STATE') or 'unknown'}"
                + (f", failed units: {' '.join(failed)}" if failed else "") + f"; {v.get('BOOT')}")
        if not self.kernel_side("PL011 /dev/ttyAMA0"):
            r.check("PL011 /dev/ttyAMA0", v.get("UART_DRIVER") == "uart-pl011",
                    f"driver {v.get('UART_DRIVER')}, RS485 before any set: {v.get('RS485_BEFORE')}")
        if not self.kernel_side("FTDI /dev/ttyUSB0"):
            r.check("FTDI /dev/ttyUSB0", v.get("USB_DRIVER") == "ftdi_sio" and bool(v.get("USB_BY_ID")),
                    f"driver {v.get('USB_DRIVER')}, {v.get('USB_BY_ID') or 'no by-id name'}, "
                    f"latency_timer before the package: {v.get('LATENCY_BEFORE')}")
        self.facts = v
        # One packet each way through both wires, before any package: stty and printf on the board.
        for bus, sid in (("uart", 1), ("usb", 3)):
            device = self.devices_of[bus]
            status, lines = self.guest.run("probe", device, sid)
            reply = values(lines).get("REPLY", "")
            self.poll_sims()
            seen = sum(1 for _ in self.sims[bus].packets)
            r.check(f"servo {sid} answers through {device}", reply.startswith(f"fd df {sid:02x}"),
                    f"reply {reply[:47] or 'none'}{'…' if len(reply) > 47 else ''} "
                    f"({len(reply.split())} bytes); the simulator on bus {bus} saw {seen} packet(s)")

    # Install and set up, as the integrator.
    def install(self):
        r = self.report
        with r.phase("install, configure, enable"):
            status, lines = self.guest.run("install", self.args.deb1)
            v = values(lines)
            if not r.check("apt install ./" + self.args.deb1, status == 0,
                           f"exit {status}, installed {v.get('INSTALLED', '?')}"):
                r.note("\n".join(lines[-20:]))
                return False
            self.binary_sha = v.get("BINARY_SHA256")
            self.installed = v.get("INSTALLED", "")
            status, lines = self.guest.run("configure")
            r.check("mapping file written", status == 0, values(lines).get("USB_BY_ID", "no by-id name"))
            status, lines = self.guest.run("check")
            r.check("lj9da-bridge check", status == 0,
                    f"exit {status}" + ("" if status == 0 else ": " + " | ".join(lines[-5:])))
            status, lines = self.guest.run("enable")
            ok = r.check("systemctl enable --now", status == 0,
                         f"exit {status}, main PID {values(lines).get('MAIN_PID', '?')}")
            return ok

    def drive(self, seconds):
        """Let the autopilot drive for `seconds`; judge motion on both buses and the telemetry."""
        r = self.report
        with r.phase(f"drive ({seconds:.0f} s)"):
            t0 = time.time()
            time.sleep(seconds)
            self.poll_sims()
            t1 = time.time()
        for bus, sim in self.sims.items():
            writes = sim.goal_writes(t0, t1)
            ids = BUSES[bus]
            per_id = {i: [g for _, j, g in writes if j == i] for i in ids}
            current = {i: sum(1 for t, j, g in writes if j == i and self.is_current(i, t, g)) for i in ids}
            rows = [s for s in sim.status if t0 <= s[0] <= t1 and s[1] in ids]
            spread = {i: (max((s[5] for s in rows if s[1] == i), default=0)
                          - min((s[5] for s in rows if s[1] == i), default=0)) for i in ids}
            arrived = {i: sum(1 for s in rows if s[1] == i and abs(s[4] - s[5]) < 0.05 and s[3] == "on")
                       for i in ids}
            ok = all(current[i] >= 3 and spread[i] >= 5.0 and arrived[i] >= 1 for i in ids)
            detail = "; ".join(
                f"servo {i}: {len(per_id[i])} goal writes ({current[i]} the autopilot's current), "
                f"position spread {spread[i]:.2f} mm, {arrived[i]} status rows at the goal"
                for i in ids)
            st = sim.stats
            detail += (f"; the simulator: {st.get('packets')} packets, {st.get('replies')} replies, "
                       f"{st.get('garbage')} bytes of garbage, {st.get('collisions')} collisions")
            r.check(f"servos move on bus {bus}", ok, detail)
        self.telemetry(t1 - t0)

    def telemetry(self, seconds):
        counts, names, texts = self.gcs.snapshot()
        bridge = {(s, c) for (s, c, t) in counts if t == "HEARTBEAT" and (s, c) != (1, 1) and s != 255}
        nvf = sum(n for (s, c, t), n in counts.items() if t == "NAMED_VALUE_FLOAT")
        # ESC_INFO (290) and ESC_STATUS (291) are work in progress in common.xml: pymavlink's
        # dialects leave them out and hand them over undecoded.
        esc = sum(n for (s, c, t), n in counts.items()
                  if t in ("ESC_INFO", "ESC_STATUS", "UNKNOWN_290", "UNKNOWN_291"))
        relayed = counts.get((1, 1, "HEARTBEAT"), 0)
        pos = {k: round(v, 2) for k, v in names.items() if k.endswith("_pos")}
        self.report.check(
            "ground station hears the bridge",
            bool(bridge) and nvf > 0 and esc > 0,
            f"bridge HEARTBEAT from {sorted(bridge)}, {nvf} NAMED_VALUE_FLOAT, {esc} ESC_INFO/ESC_STATUS (ids 290/291), "
            f"{relayed} relayed autopilot HEARTBEATs; positions {pos}",
        )

    def is_current(self, servo, t, goal):
        return any(abs(goal - a) <= TOLERANCE_CENTI for a in self.autopilot.allowed(servo, t))

    def readings(self):
        r = self.report
        status, lines = self.guest.run("journal")
        self.report.write("journal-start.txt", "\n".join(lines) + "\n")
        started = [l for l in lines if "Started lj9da-bridge" in l]
        ready = [l for l in lines if "lj9da_bridge::runtime: ready" in l]
        r.check("journalctl -u lj9da-bridge shows the start", bool(started) and bool(ready) and status == 0,
                (started[0].split(": ", 1)[-1] if started else f"no 'Started' line in {len(lines)} lines")
                + " | " + (ready[0].split("runtime: ", 1)[-1] if ready else "no 'ready' line from the bridge"))
        lost = sum("lost: no reply" in l for l in lines)
        degraded = sum(" degraded: " in l and "lj9da_bridge::runtime" in l for l in lines)

        status, lines = self.guest.run("status")
        v = values(lines)
        r.check("service steady while driving", v.get("ActiveState") == "active" and v.get("NRestarts") == "0",
                f"{v.get('ActiveState')}/{v.get('SubState')}, main PID {v.get('MainPID')}, "
                f"{v.get('NRestarts')} restarts since enabled; the log says {lost}× servo lost, {degraded}× degraded")

        if self.place != "board":
            for name in ("lj9da-bridge ports names both ports", "udev rule: latency_timer 1", "PL011 in RS485 mode"):
                self.kernel_side(name)
            return
        status, lines = self.guest.run("ports")
        self.report.write("ports.txt", "\n".join(lines) + "\n")
        try:
            ports = json.loads("\n".join(section(lines, "json")))
        except ValueError:
            ports = []
        by_dev = {p.get("device"): p for p in ports}
        uart, usb = by_dev.get("/dev/ttyAMA0"), by_dev.get("/dev/ttyUSB0")
        usb_ok = bool(usb) and usb.get("driver") == "ftdi_sio" and self.facts.get("USB_BY_ID") in usb.get("by_id", [])
        uart_ok = bool(uart) and uart.get("driver") == "uart-pl011"
        r.check("lj9da-bridge ports names both ports", usb_ok and uart_ok,
                f"ttyAMA0: {uart and uart.get('driver')}; ttyUSB0: {usb and usb.get('driver')}, "
                f"{usb and usb.get('usb')}, by-id {usb and usb.get('by_id')}, latency {usb and usb.get('latency_timer_ms')} ms, "
                f"open by {usb and usb.get('open_by')}")

        status, lines = self.guest.run("latency")
        v = values(lines)
        r.check("udev rule: latency_timer 1", v.get("LATENCY") == "1",
                f"/sys/bus/usb-serial/devices/ttyUSB0/latency_timer = {v.get('LATENCY')} "
                f"(before the package: {self.facts.get('LATENCY_BEFORE')})")

        status, lines = self.guest.run("rs485")
        v = values(lines)
        said = [l for l in section(lines, "journal") if "RS485 mode" in l]
        granted = "flags=0x3" in v.get("RS485_NOW", "")
        logged = any("RS485 mode on" in l or "granted" in l for l in said)
        r.check("PL011 in RS485 mode", granted and logged,
                f"TIOCGRS485 now: {v.get('RS485_NOW')}; the bridge's log: {said[0].strip() if said else 'nothing'}")

    def rs485_refusal(self):
        r = self.report
        if self.kernel_side("ftdi_sio refuses RS485 with the bridge's error"):
            return
        with r.phase("RS485 asked of ttyUSB0"):
            status, lines = self.guest.run("rs485-usb")
        self.report.write("rs485-usb.txt", "\n".join(lines) + "\n")
        v = values(lines)
        refusal = [l for l in lines if "refuses RS485 mode" in l]
        r.check("ftdi_sio refuses RS485 with the bridge's error",
                bool(refusal) and "usb" in (refusal[0] if refusal else ""),
                (f"TIOCGRS485 on ttyUSB0: {v.get('USB_RS485_TTY')}; "
                 + (refusal[0].strip()[:400] if refusal else "no refusal in the output")))
        r.check("service back after the refusal test", status == 0, f"main PID {v.get('MAIN_PID')}")

    def security(self):
        status, lines = self.guest.run("security")
        path = self.report.write("systemd-analyze-security.txt", "\n".join(lines) + "\n")
        score = [l for l in lines if "Overall exposure level" in l]
        self.report.check("systemd-analyze security", status == 0 and bool(score),
                          f"{score[0].strip() if score else 'no score line'} (table: {path})")

    # The upgrade while it runs.
    def upgrade(self):
        r = self.report
        if not self.args.deb2:
            if self.args.deb2_error:
                r.check("upgrade to revision 2", False, self.args.deb2_error)
            else:
                r.check("upgrade to revision 2", None, self.args.deb2_missing or "no revision-2 package")
            return
        with r.phase("upgrade while running"):
            status, lines = self.guest.run("pre-upgrade")
            before = values(lines)
            records_before = [l for l in lines if not re.match(r"^[A-Z_]+=", l)]
            status, lines = self.guest.run("upgrade", self.args.deb2)
        self.report.write("upgrade.txt", "\n".join(lines) + "\n")
        after = values(lines)
        records_after = [l for l in lines if re.match(r"^\S+ \d+$", l)]
        r.check("apt install ./" + self.args.deb2, status == 0, f"exit {status}, installed {after.get('INSTALLED')}")
        r.check("upgrade keeps the edited mapping file",
                after.get("CONFFILE_EDIT") == "1" and after.get("CONFFILE_SHA256") == before.get("CONFFILE_SHA256"),
                f"edit lines {after.get('CONFFILE_EDIT')}, same hash "
                f"{after.get('CONFFILE_SHA256') == before.get('CONFFILE_SHA256')}, dpkg files: {after.get('CONFFILE_DIST') or 'none'}")
        exe = after.get("EXE", "")
        r.check("service runs the new program",
                bool(exe) and "(deleted)" not in exe and after.get("EXE_SHA256") == after.get("BINARY_SHA256")
                and after.get("MAIN_PID") != before.get("MAIN_PID"),
                f"PID {before.get('MAIN_PID')} → {after.get('MAIN_PID')}, exe {exe}, "
                f"sha256 {after.get('EXE_SHA256', '?')[:16]}… = installed {after.get('BINARY_SHA256', '?')[:16]}…")
        lost = sorted(set(l.split()[0] for l in records_before if re.match(r"^\S+ \d+$", l))
                      - set(l.split()[0] for l in records_after))
        r.check("records folder kept", before.get("RECORDS_BEFORE") not in (None, "0") and not lost,
                f"{before.get('RECORDS_BEFORE')} files before, {after.get('RECORDS_AFTER')} after, lost: {lost or 'none'}")

    # Faults and how long until the autopilot's outputs are on the wire again.
    def features(self):
        status, lines = self.guest.run("features")
        v = values(lines)
        watchdog = v.get("WatchdogUSec", "0") not in ("0", "infinity", "")
        self.report.note(f"service: Type={v.get('Type')} WatchdogUSec={v.get('WatchdogUSec')} "
                         f"Restart={v.get('Restart')} RestartUSec={v.get('RestartUSec')} "
                         f"hang switch in binary: {v.get('HANG_SWITCH')}")
        return v, watchdog, v.get("HANG_SWITCH", "0") not in ("0", "")

    def wait_steady(self, timeout=90):
        """Until both buses have written the autopilot's current outputs after now."""
        t0 = time.time()
        deadline = time.monotonic() + timeout
        self.autopilot.new_step()
        while time.monotonic() < deadline:
            time.sleep(0.5)
            self.poll_sims()
            if all(self.first_current(bus, t0) for bus in BUSES):
                return True
        return False

    def first_current(self, bus, since):
        """Host time when every servo of `bus` had been written an output that the autopilot
        sent from `since` on; None if not yet."""
        return self.first_written(bus, since, since)

    def first_current_after(self, bus, since):
        """Host time when every servo of `bus` had been written, after `since`, a value that was
        the autopilot's current output when it was written; None if not yet."""
        times = []
        for i in BUSES[bus]:
            hit = next((t for t, j, g in self.sims[bus].goal_writes(since) if j == i and t > since
                        and self.is_current(i, t, g)), None)
            if hit is None:
                return None
            times.append(hit)
        return max(times)

    def first_written(self, bus, step_at, after):
        """Host time when every servo of `bus` had been written, from `after` on, an output the
        autopilot sent from `step_at` on; None if not yet."""
        times = []
        for i in BUSES[bus]:
            wanted = self.autopilot.current_since(i, step_at)
            hit = next((t for t, j, g in self.sims[bus].goal_writes(after) if j == i
                        and any(abs(g - a) <= TOLERANCE_CENTI for a in wanted)), None)
            if hit is None:
                return None
            times.append(hit)
        return max(times)

    def silence(self, bus, since, until=float("inf"), polls_only=False):
        """The first silence on `bus` longer than SILENCE_S that begins between `since` and
        `until`: (last packet before it, first packet after it or None while it lasts). With
        `polls_only`, goal writes do not break a silence."""
        times = [t for t, goals in self.sims[bus].packets
                 if t >= since - self.silence_s and not (polls_only and goals)]
        for a, b in zip(times, times[1:]):
            if b - a > self.silence_s and since <= a <= until:
                return a, b
        if times and since <= times[-1] <= until and time.time() - times[-1] > self.silence_s:
            return times[-1], None
        return None

    def judge(self, name, results, runs, bound, what):
        """The check of a recovery measured `runs` times: every run recovered and, in the
        container (a computer's speed; the board's TCG is 5–10× slower), its worst case within
        `bound` seconds."""
        good = [s for s in results if s is not None]
        figures = ", ".join("—" if s is None else f"{s:.2f}" for s in results)
        if not good:
            self.report.check(name, False, f"no recovery ({figures})")
            return
        worst = max(good)
        held = self.place == "board" or bound is None or worst <= bound
        goal = "" if bound is None else (f"; goal ≤ {bound:.2f} s worst case"
                                         + (" (reported only under TCG)" if self.place == "board" else ""))
        self.report.check(name, len(good) == runs and held,
                          f"{figures} s (median {statistics.median(good):.2f} s, worst {worst:.2f} s), {what}{goal}")

    def measure(self, name, trigger, runs, bound=None, timeout=120):
        """Trigger a fault `runs` times. Each time: seconds from the fault to both buses carrying
        the autopilot's current outputs again. The fault's instant is when the bus on the USB
        adapter, which the bridge talks on every ~10 ms, fell silent; the autopilot moves to new
        outputs once the board has carried the request out, so only a bridge started after the
        fault can write them."""
        r = self.report
        results = []
        with r.phase(f"fault: {name} ×{runs}"):
            for run in range(runs):
                if not self.wait_steady():
                    r.note(f"{name} run {run + 1}: the bridge did not settle first")
                    results.append(None)
                    continue
                status, t_request, t_done = trigger()
                t_step = self.autopilot.new_step()
                if status != 0:
                    r.note(f"{name} run {run + 1}: the board could not signal the bridge (exit {status})")
                    results.append(None)
                    continue
                deadline = time.monotonic() + timeout
                quiet, recovered = None, {}
                while time.monotonic() < deadline and len(recovered) < len(BUSES):
                    time.sleep(0.5)
                    self.poll_sims()
                    quiet = quiet or self.silence("usb", t_request - 0.1, t_done + 0.1)
                    for bus in BUSES:
                        hit = self.first_current(bus, t_step)
                        if hit and bus not in recovered:
                            recovered[bus] = hit
                quiet = self.silence("usb", t_request - 0.1, t_done + 0.1) or quiet
                if not quiet or len(recovered) < len(BUSES):
                    r.note(f"{name} run {run + 1}: " + ("the bus never fell silent" if not quiet else
                           f"no recovery within {timeout} s (back: {sorted(recovered)})"))
                    results.append(None)
                    continue
                back = max(recovered.values())
                results.append(back - quiet[0])
                bad = self.audit(t_request, back)
                r.note(f"{name} run {run + 1}: {back - quiet[0]:.2f} s from the silence to the current outputs "
                       f"on both buses (uart {recovered['uart'] - quiet[0]:.2f} s, usb {recovered['usb'] - quiet[0]:.2f} s; "
                       f"usb silent for {(quiet[1] or back) - quiet[0]:.2f} s; {back - t_request:.2f} s from the host's request); "
                       f"other moves: {len(bad)}")
        self.judge(f"recovery after {name}", results, runs, bound, "fault → current outputs on both buses")
        return results

    def measure_hang(self, bus, after_s, cycles, bound=None, timeout=180):
        """With the fault switch set, the bus thread hangs `after_s` after every start and the
        watchdog restarts the service: each hang is a run. The hang is when the bus's polls
        stop (goal writes may go on: they are not the bus thread's alone); the restart when
        they start again. Once the hang is seen, the autopilot moves to new outputs, so that the
        restarted bridge has a goal to write (a servo already at its goal gets none). A run's
        figure: seconds from the hang to the restarted bridge's first goal writes of the
        autopilot's current outputs on every servo of the bus."""
        r = self.report
        results, restarts, during = [], [], []
        with r.phase(f"fault: hung bus thread ×{cycles}"):
            rid, t0 = self.guest.send("hang", f"{bus}:{after_s}")
            status, lines = self.guest.wait(rid, 320)
            if status != 0:
                r.check("recovery after a hung bus thread", False, "the drop-in could not be applied")
                return
            deadline = time.monotonic() + timeout
            # The restart that applies the drop-in: the first silence after the request. Each
            # hang is looked for from half its delay after the bridge (re)started talking.
            started, since, stepped = None, None, None
            while len(results) < cycles and time.monotonic() < deadline:
                time.sleep(0.5)
                self.poll_sims()
                if started is None:
                    quiet = self.silence(bus, t0 - 0.1, polls_only=True)
                    if quiet and quiet[1] is not None:
                        started, since = quiet[1], quiet[1] + after_s / 2
                    continue
                quiet = self.silence(bus, since, polls_only=True)
                if quiet and quiet[1] is None and (stepped is None or stepped[0] != quiet[0]):
                    stepped = (quiet[0], self.autopilot.new_step())
                if not quiet or quiet[1] is None:
                    continue
                if stepped and stepped[0] == quiet[0]:
                    hit = self.first_written(bus, stepped[1], quiet[1] - 1e-6)
                else:
                    # The restart came before the hang was seen: the first current goals.
                    hit = self.first_current_after(bus, quiet[1] - 1e-6)
                if not hit:
                    continue
                hung = [(t, i, g) for t, i, g in self.sims[bus].goal_writes(quiet[0] + 1e-6, quiet[1] - 1e-6)]
                kept = sum(self.is_current(i, t, g) for t, i, g in hung)
                results.append(hit - quiet[0])
                restarts.append(quiet[1] - quiet[0])
                during.append((len(hung), kept))
                r.note(f"hung {bus} thread, run {len(results)}: polls stopped {quiet[0] - started:.1f} s after the "
                       f"bridge started polling, again {quiet[1] - quiet[0]:.2f} s later (the restarted bridge), its "
                       f"current outputs {hit - quiet[0]:.2f} s after the hang; meanwhile {len(hung)} goal writes, "
                       f"{kept} of them current")
                started, since = quiet[1], quiet[1] + after_s / 2
            t_end = time.time()
            self.guest.run("hang", "off")
        bad = self.audit(t0, t_end)
        results += [None] * (cycles - len(results))
        self.judge("recovery after a hung bus thread", results, cycles, bound,
                   f"hang → the restarted bridge's current outputs on bus {bus}; polls back after "
                   f"{', '.join(f'{x:.2f}' for x in restarts)} s; goal writes while hung (current/all): "
                   f"{', '.join(f'{k}/{n}' for n, k in during)}; {len(bad)} other moves in between")

    def faults(self):
        r = self.report
        v, watchdog, hang_switch = self.features()
        runs = self.args.fault_runs
        # The service's promise: back on the autopilot's current outputs within a second of a
        # crash; of a hang, within a second of the watchdog's timeout.
        watchdog_s = parse_usec(v.get("WatchdogUSec", "")) if watchdog else None
        hang_bound = None if watchdog_s is None else watchdog_s + 1.0
        if v.get("Restart") in ("on-failure", "always", "on-abnormal", "on-abort"):
            self.measure("kill -9", lambda: self.kill("KILL"), runs, bound=1.0)
        else:
            r.check("recovery after kill -9", None, f"the unit does not restart (Restart={v.get('Restart')})")
        if watchdog:
            self.measure("SIGSTOP (watchdog)", lambda: self.kill("STOP"), runs, bound=hang_bound)
        else:
            r.check("recovery after SIGSTOP (watchdog)", None,
                    f"NOT RUN: the installed unit has no watchdog (Type={v.get('Type')}, "
                    f"WatchdogUSec={v.get('WatchdogUSec')}); it needs Type=notify and WatchdogSec")
        if hang_switch:
            installed = getattr(self, "installed", "")
            r.check("a test build says so", installed.endswith("~test"),
                    f"the binary has the hung-thread switch; the package's version is {installed or '?'}")
        if watchdog and hang_switch:
            self.measure_hang("usb", self.args.hang_after, runs, bound=hang_bound)
        else:
            r.check("recovery after a hung bus thread", None,
                    "NOT RUN: " + ("the binary has no LJ9DA_TEST_HANG_BUS switch (a package built with LJ9DA_PACKAGE_FEATURES=fault-switch has)" if not hang_switch
                                   else "the unit has no watchdog"))

    def guest_clock_offset(self):
        """The computer's clock minus the host's, in seconds, and its uncertainty (half the
        request's round trip). A container's clock is the host's own."""
        if self.place == "container":
            return 0.0, 0.0
        best = None
        for _ in range(3):
            rid, sent = self.guest.send("clock")
            status, lines = self.guest.wait(rid, 30)
            back = time.time()
            clock = float(values(lines).get("CLOCK", "nan"))
            estimate = (clock - (sent + back) / 2, (back - sent) / 2)
            if best is None or estimate[1] < best[1]:
                best = estimate
        return best

    def power_cut(self, runs, timeout=120):
        """Cut the computer off while it drives and records (`machine kill`: QEMU killed, or the
        container's PID 1), boot it again. Each run: the service runs again, the seconds from
        the boot to the autopilot's current outputs on both buses, and the flight record of the
        cut run read back: its last sample at most RECORD_LOSS_S before the cut."""
        r = self.report
        machine = [self.args.machine]
        boot_times, losses, ok = [], [], True
        with r.phase(f"power cut ×{runs}"):
            for run in range(runs):
                if not self.wait_steady():
                    r.note(f"power cut run {run + 1}: the bridge did not settle first")
                    ok = False
                    continue
                offset, uncertainty = self.guest_clock_offset()
                # Drive and record a little past the settling.
                time.sleep(2.0)
                asked = time.time()
                said = subprocess.run([*machine, "kill", self.args.run_dir], check=True,
                                      capture_output=True, text=True).stdout.split()
                cut_done = time.time()
                # The signal went out between these two.
                cut, cut_after = (float(said[0]), float(said[1])) if len(said) == 2 else (asked, cut_done)
                t_step = self.autopilot.new_step()
                booted = time.time()
                subprocess.run([*machine, "boot", self.args.run_dir], check=True)
                self.guest.connect(60)
                ready = self.guest.wait_ready(self.args.boot_timeout, self.alive)
                deadline = time.monotonic() + timeout
                recovered = {}
                while time.monotonic() < deadline and len(recovered) < len(BUSES):
                    time.sleep(0.2)
                    self.poll_sims()
                    for bus in BUSES:
                        hit = self.first_current(bus, t_step)
                        if hit and bus not in recovered:
                            recovered[bus] = hit
                status, lines = self.guest.run("status")
                active = values(lines).get("ActiveState") == "active"
                status, lines = self.guest.run("records")
                self.report.write(f"records-after-cut-{run + 1}.txt", "\n".join(lines) + "\n")
                cut_on_guest = cut + offset
                after_on_guest = cut_after + offset
                files = [values(l.split()[2:]) | {"name": l.split()[1]}
                         for l in lines if l.startswith("RECORD ")]
                before = [f for f in files if number(f.get("START")) < cut_on_guest]
                last = max(before, key=lambda f: float(f["START"])) if before else None
                if last and last.get("LAST") not in (None, ""):
                    end = float(last["START"]) + float(last["LAST"])
                    loss, after = cut_on_guest - end, end - after_on_guest
                else:
                    loss, after = None, None
                back = max(recovered.values()) if len(recovered) == len(BUSES) else None
                if back is not None:
                    boot_times.append(back - booted)
                losses.append(loss)
                # Nothing recorded after the signal, nothing lost before it but the last
                # RECORD_LOSS_S (the record's start is given to the millisecond).
                run_ok = (active and back is not None and loss is not None
                          and after <= uncertainty + 0.001 and loss <= RECORD_LOSS_S + uncertainty)
                ok = ok and run_ok
                r.note(f"power cut run {run + 1}: signalled {cut - asked:.3f}–{cut_after - asked:.3f} s after the "
                       f"request, gone {cut_done - cut_after:.2f} s later; agent ready "
                       f"{ready - booted:.2f} s after the boot began; "
                       + (f"current outputs on both buses {back - booted:.2f} s after it" if back else
                          f"no current outputs within {timeout} s (back: {sorted(recovered)})")
                       + f"; service {'active' if active else 'NOT active'}; "
                       + (f"record {last['name']} ({last.get('STATE', '?')}): its last sample {loss:.3f} s before the cut"
                          f" (clocks ±{uncertainty * 1000:.0f} ms)" if loss is not None else
                          f"no record of the cut run among {len(files)} files"))
        good = boot_times
        r.check("power cut: the service runs again", ok and len(good) == runs,
                (f"boot → current outputs on both buses {', '.join(f'{b:.2f}' for b in good)} s "
                 f"(median {statistics.median(good):.2f} s, worst {max(good):.2f} s)" if good else "no recovery")
                + "; the cut run's record ends "
                + ", ".join("—" if x is None else f"{x:.3f}" for x in losses)
                + f" s before the cut (at most {RECORD_LOSS_S} s lost)")

    def kill(self, signal):
        rid, sent = self.guest.send("kill", signal)
        status, lines = self.guest.wait(rid, 60)
        return status, sent, time.time()

    def audit(self, since=0.0, until=float("inf")):
        """Goal writes that moved a servo to something the autopilot was not sending."""
        self.poll_sims()
        bad = []
        for bus, sim in self.sims.items():
            last = {}
            for t, i, g in sim.goal_writes():
                moved = last.get(i) is not None and abs(last[i] - g) > TOLERANCE_CENTI
                if since <= t <= until and not self.is_current(i, t, g) and (moved or i not in last):
                    bad.append((bus, t, i, g))
                last[i] = g
        return bad

    def final_audit(self):
        bad = self.audit()
        writes = sum(len(s.goal_writes()) for s in self.sims.values())
        detail = f"{writes} goal writes on both buses"
        if bad:
            shown = "; ".join(f"{bus} servo {i} → {g / 100:.2f} mm at {time.strftime('%H:%M:%S', time.localtime(t))}"
                              for bus, t, i, g in bad[:5])
            detail += f", {len(bad)} not the autopilot's current outputs: {shown}"
        else:
            detail += ", every one the autopilot's current output"
        self.report.check("nothing but the autopilot's outputs moved a servo", not bad, detail)

    def poweroff(self):
        rid, _ = self.guest.send("poweroff")
        try:
            self.guest.wait(rid, 30)
        except GuestError:
            pass


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--place", choices=("board", "container"), default="board")
    p.add_argument("--machine", required=True, help="the `machine` script: boot and cut the computer")
    p.add_argument("--run-dir", required=True, help="the run's folder, with machine.env")
    p.add_argument("--control", required=True, help="QEMU's socket of the virtio port 'control', or the container's FIFO")
    p.add_argument("--results", required=True, help="the file the agent's answers go to")
    p.add_argument("--sim-uart", required=True, help="stderr log of the simulator on the PL011")
    p.add_argument("--sim-usb", required=True, help="stderr log of the simulator on the USB adapter")
    p.add_argument("--autopilot-port", type=int, required=True)
    p.add_argument("--gcs-port", type=int, required=True)
    p.add_argument("--deb1", default="", help="file name of the package on the payload disk")
    p.add_argument("--deb2", default="", help="file name of the revision-2 package, if any")
    p.add_argument("--deb2-missing", default="", help="why there is no revision-2 package (a SKIP)")
    p.add_argument("--deb2-error", default="", help="why the revision-2 package could not be had (a FAIL)")
    p.add_argument("--devices-only", action="store_true", help="no package: the board's devices only")
    p.add_argument("--strict", action="store_true",
                   help="a check that cannot be run fails (CI), but the kernel's side in a container")
    p.add_argument("--host-phases", default="", help="phase lines of `run`, for the summary")
    p.add_argument("--machine-started", type=float, required=True, help="host time the computer was started")
    p.add_argument("--boot-timeout", type=float, default=240)
    p.add_argument("--drive-seconds", type=float, default=20)
    p.add_argument("--fault-runs", type=int, default=3)
    p.add_argument("--cut-runs", type=int, help="power cuts, each with a boot (default: --fault-runs)")
    p.add_argument("--hogs", type=int, default=0, help="busy loops `run` keeps beside it all (for the report)")
    p.add_argument("--hang-after", type=float, default=8)
    p.add_argument("--out", required=True, help="folder for the results")
    args = p.parse_args()

    board = Board(args)
    r = board.report
    board.autopilot.start()
    board.gcs.start()
    try:
        board.boot()
        board.devices()
        if args.devices_only:
            board.report.check("bridge", None, "--devices-only: no package installed")
        elif board.install():
            board.drive(args.drive_seconds)
            board.readings()
            board.security()
            board.rs485_refusal()
            board.upgrade()
            board.faults()
            board.power_cut(args.cut_runs or args.fault_runs)
            board.final_audit()
            # The service's whole journal (every start, ready and first goal), for the times.
            status, lines = board.guest.run("journal")
            board.report.write("journal-end.txt", "\n".join(lines) + "\n")
    except BootError as e:
        # This host cannot run the computer (systemd-nspawn or QEMU could not boot it): a
        # set-up failure, said in one line.
        print(f"board: {e}", file=sys.stderr, flush=True)
        r.summary()
        sys.exit(2)
    except GuestError as e:
        r.check("the board answered", False, str(e))
    finally:
        if board.guest:
            with r.phase("poweroff"):
                board.poweroff()
        board.autopilot.stop.set()
        board.gcs.stop.set()
    ok = r.summary()
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()

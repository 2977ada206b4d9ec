"""Capture real MAVLink traffic from ArduPlane SITL and PX4 SIH for fuzz seeds.

Starts one autopilot (as a child of this process), listens on a UDP port it sends to, asks it
for parameters, a command and output streams, and writes every datagram (hex, one a line) and,
for ArduPlane, the raw bytes of its TCP serial0 stream. Stops the autopilot at the end.
"""
import os, shutil, socket, subprocess, sys, tempfile, time
from pymavlink.dialects.v20 import ardupilotmega as mav2

SITL = "/work/shared/sitl"
OUT = "/tmp/fuzz-capture"
which = sys.argv[1]
seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 15

def requests(sock, peer, mav, target_sys, target_comp, t):
    """What a ground station asks, spread over the capture."""
    out = []
    if t == 0:
        out.append(mav.request_data_stream_encode(target_sys, target_comp, 0, 10, 1))
        out.append(mav.command_long_encode(target_sys, target_comp, 511, 0, 36, 100000, 0, 0, 0, 0, 0))  # SET_MESSAGE_INTERVAL SERVO_OUTPUT_RAW 10 Hz
        out.append(mav.command_long_encode(target_sys, target_comp, 511, 0, 375, 100000, 0, 0, 0, 0, 0))  # ACTUATOR_OUTPUT_STATUS
    if t == 1:
        out.append(mav.param_request_read_encode(target_sys, target_comp, b"SERVO1_FUNCTION" if which == "ap" else b"PWM_MAIN_FUNC1", -1))
        out.append(mav.command_long_encode(target_sys, target_comp, 512, 0, 148, 0, 0, 0, 0, 0, 0))  # REQUEST_MESSAGE AUTOPILOT_VERSION
        out.append(mav.command_long_encode(target_sys, target_comp, 31000, 0, 0, 0, 0, 0, 0, 0, 0))  # unsupported: a denied/unsupported ACK
    if t == 2:
        out.append(mav.param_request_list_encode(target_sys, target_comp))
        out.append(mav.command_long_encode(target_sys, target_comp, 400, 0, 1, 0, 0, 0, 0, 0, 0))  # arm (refused: a STATUSTEXT)
    if t == 3:
        out.append(mav.param_set_encode(target_sys, target_comp, b"SERVO2_TRIM" if which == "ap" else b"PWM_MAIN_DIS1", 1500, 4))
    for m in out:
        sock.sendto(m.pack(mav), peer)

def run():
    work = tempfile.mkdtemp(prefix=f"fuzz-capture-{which}-")
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    if which == "ap":
        port = 24777
        udp.bind(("127.0.0.1", port))
        cmd = [f"{SITL}/ardupilot/arduplane", "--model", "plane", "--speedup", "1", "-I7",
               "--home", "-35.363261,149.165230,584,353", "--defaults", f"{SITL}/ardupilot/plane.parm",
               "--serial0=tcp:0", f"--serial1=udpclient:127.0.0.1:{port}"]
        env = os.environ.copy()
    else:
        port = 24877
        udp.bind(("127.0.0.1", port))
        etc = os.path.join(work, "etc")
        shutil.copytree(f"{SITL}/px4/etc", etc, symlinks=True)
        with open(os.path.join(etc, "init.d-posix/px4-rc.mavlink"), "w") as f:
            f.write(f"""#!/bin/sh
mavlink start -x -u 24871 -r 4000000 -f -o {port}
mavlink stream -r 10 -s SERVO_OUTPUT_RAW_0 -u 24871
mavlink stream -r 10 -s ACTUATOR_OUTPUT_STATUS -u 24871
mavlink start -x -u 24872 -r 4000000 -f -m onboard -o 24878
""")
        # A writable copy of bin with its px4-* links made again (the shared copy has them as
        # plain files, see the SITL README).
        bindir = os.path.join(work, "bin")
        os.makedirs(bindir)
        shutil.copy2(f"{SITL}/px4/bin/px4", bindir)
        shutil.copy2(f"{SITL}/px4/bin/px4-alias.sh", bindir)
        for name in os.listdir(f"{SITL}/px4/bin"):
            if name.startswith("px4-") and name != "px4-alias.sh":
                os.symlink("px4", os.path.join(bindir, name))
        cmd = [os.path.join(bindir, "px4"), "-d", "-w", work, "-i", "7", etc]
        env = dict(os.environ, PX4_SIM_MODEL="sihsim_quadx", PX4_SIMULATOR="sihsim")
    onboard = None
    if which == "px4":
        onboard = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        onboard.bind(("127.0.0.1", 24878))
        onboard.setblocking(False)
    log = open(os.path.join(OUT, f"{which}.console.log"), "w")
    proc = subprocess.Popen(cmd, cwd=work, env=env, stdout=log, stderr=subprocess.STDOUT)
    print("started", which, proc.pid, flush=True)
    udp.settimeout(0.2)
    mav = mav2.MAVLink(None, srcSystem=255, srcComponent=190)
    parser = mav2.MAVLink(None)
    parser.robust_parsing = True
    datagrams = open(os.path.join(OUT, f"{which}_udp.hex"), "w")
    onboard_out = open(os.path.join(OUT, f"{which}_onboard.hex"), "w") if onboard else None
    tcp = None
    tcp_bytes = bytearray()
    peer = None
    start = time.time()
    step = 0
    next_step = None
    target = (1, 1)
    try:
        while time.time() - start < seconds + 40:
            if which == "ap" and tcp is None and time.time() - start > 3:
                try:
                    tcp = socket.create_connection(("127.0.0.1", 5830), timeout=1)
                    tcp.setblocking(False)
                    tcp.sendall(mav.request_data_stream_encode(1, 1, 0, 4, 1).pack(mav))
                except OSError:
                    tcp = None
            if tcp is not None:
                try:
                    tcp_bytes += tcp.recv(65536)
                except BlockingIOError:
                    pass
            if onboard is not None:
                try:
                    while True:
                        d, _ = onboard.recvfrom(65536)
                        onboard_out.write(d.hex() + "\n")
                except BlockingIOError:
                    pass
            try:
                d, addr = udp.recvfrom(65536)
            except socket.timeout:
                continue
            datagrams.write(d.hex() + "\n")
            if peer is None:
                for m in parser.parse_buffer(d) or []:
                    if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
                        peer = addr
                        target = (m.get_srcSystem(), 1)
                        start = time.time()
                        next_step = time.time()
                        print("heard", which, addr, flush=True)
            if peer is not None and next_step is not None and time.time() >= next_step and step < 4:
                requests(udp, peer, mav, target[0], target[1], step)
                step += 1
                next_step = time.time() + 2
            if peer is not None and time.time() - start > seconds:
                break
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        print("stopped", which, proc.returncode, flush=True)
        if tcp_bytes:
            open(os.path.join(OUT, f"{which}_tcp.bin"), "wb").write(tcp_bytes)
        shutil.rmtree(work, ignore_errors=True)

run()

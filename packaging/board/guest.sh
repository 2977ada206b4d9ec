#!/bin/bash
# The computer's side of the board in a box: what an integrator types on the companion
# computer, one request at a time.
#
# board-agent (in the image) mounts the payload disk (this script, the packages) read-only on
# /run/lj9da-board (a container has it bound there) and runs `guest.sh agent`: it reads requests
# `ID COMMAND ARGS…` from "control" and writes each one's output between `@@BEGIN ID COMMAND`
# and `@@END ID EXIT-STATUS` to "results", which the host keeps as a file: the board's virtio
# ports, or in a container a FIFO and a file bound in (place.env says). Every request is bounded
# by a timeout. The host (host.py) judges what is printed here: the commands print what they
# read, with `KEY=value` lines where a figure is wanted.
set -euo pipefail

payload=/run/lj9da-board
conffile=/etc/lj9da-bridge/bridge.toml
records=/var/lib/lj9da-bridge/records
dropin_dir=/etc/systemd/system/lj9da-bridge.service.d
unit=lj9da-bridge.service
# The board's wiring; a container's place.env (written by `run`) replaces it.
place=board
usb_tty=ttyUSB0
uart=/dev/ttyAMA0
usb=""
autopilot_port=14560
gcs_port=14561
control=/dev/virtio-ports/control
results=/dev/virtio-ports/results
# shellcheck source=/dev/null
[ ! -f "$payload/place.env" ] || . "$payload/place.env"
# The reply allowance of both buses in the mapping file (see `mapping`): under TCG a reply
# reaches the bridge tens of milliseconds after the servo sent it; in the container the servos
# are lj9da-sim on pseudo-terminals, which `sitl` gives 20 ms.
turnaround_ms=50
[ "$place" = board ] || turnaround_ms=20

say() { printf '%s\n' "$*"; }
main_pid() { systemctl show -p MainPID --value "$unit"; }

# `/dev/serial/by-id/…` of the USB adapter, read from udev's links.
usb_by_id() {
    local link
    for link in /dev/serial/by-id/*; do
        [ -e "$link" ] || continue
        if [ "$(readlink -f "$link")" = "/dev/$usb_tty" ]; then
            say "$link"
            return 0
        fi
    done
    return 1
}

# Wait until the unit is active with a main process, up to $1 seconds.
wait_active() {
    local deadline=$((SECONDS + $1))
    while [ $SECONDS -lt $deadline ]; do
        if [ "$(systemctl is-active "$unit" 2>/dev/null)" = active ] && [ "$(main_pid)" != 0 ]; then
            return 0
        fi
        sleep 0.2
    done
    return 1
}

cmd_ping() { say pong; }

# probe DEVICE ID: one request-only packet to servo ID (reply: registers 30–59) at 115200 bit/s,
# made with stty and printf as on any board; prints the reply's bytes in hex.
cmd_probe() {
    local device=$1 id=$2 sum
    stty -F "$device" 115200 raw -echo -crtscts clocal cs8 -cstopb -parenb
    sum=$((id ^ 3 ^ 0 ^ 0 ^ 1))
    exec 5<>"$device"
    # shellcheck disable=SC2059  # the format is the packet
    printf "\\xfa\\xaf\\x$(printf %02x "$id")\\x03\\x00\\x00\\x01\\x$(printf %02x "$sum")" >&5
    say "REPLY=$(timeout 1 cat <&5 | od -An -tx1 -v | tr -s ' \n' ' ' | sed 's/^ //; s/ $//')"
    exec 5<&-
}

# The devices as the kernel and udev made them, before any package is installed.
cmd_facts() {
    say "KERNEL=$(uname -r)"
    say "SYSTEMD=$(systemctl --version | head -n 1)"
    say "SYSTEM_STATE=$(timeout 120 systemctl is-system-running --wait 2>/dev/null || true)"
    say "BOOT=$(systemd-analyze time 2>/dev/null | head -n 1 || true)"
    systemctl --failed --no-legend --plain 2>/dev/null | sed 's/^/FAILED_UNIT /' || true
    say "UART_DRIVER=$(basename "$(readlink -f /sys/class/tty/ttyAMA0/device/driver)")"
    say "USB_DRIVER=$(basename "$(readlink -f /sys/class/tty/$usb_tty/device/driver 2>/dev/null)" 2>/dev/null || true)"
    say "USB_BY_ID=$(usb_by_id || true)"
    say "LATENCY_BEFORE=$(cat /sys/bus/usb-serial/devices/$usb_tty/latency_timer 2>/dev/null || say none)"
    say "IPV4=$(ip -4 -o addr show scope global | awk '{print $2, $4}' | tr '\n' ' ')"
    say "RS485_BEFORE=$(rs485_get "$uart")"
    say "--- /dev/serial/by-id"
    ls -l /dev/serial/by-id/ 2>&1 || true
    say "--- systemd-analyze blame"
    systemd-analyze blame --no-pager 2>&1 | head -n 12 || true
}

# TIOCGRS485 on a port: `flags=0x… before=… after=…` or the error. Opening a port does not change
# it; root may open one that the bridge holds exclusively.
rs485_get() {
    python3 - "$1" <<'PY'
import fcntl, os, struct, sys
TIOCGRS485 = 0x542E
try:
    fd = os.open(sys.argv[1], os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        flags, before, after = struct.unpack("3I", fcntl.ioctl(fd, TIOCGRS485, bytes(32))[:12])
        print(f"flags=0x{flags:x} before={before} after={after}")
    finally:
        os.close(fd)
except OSError as e:
    print(f"error errno={e.errno} {e.strerror}")
PY
}

cmd_install() {
    local deb=$payload/$1
    [ -f "$deb" ] || { say "no package $deb"; return 1; }
    cp "$deb" /root/
    cd /root
    # As an integrator types it; the dependencies are in the image already (no network here).
    DEBIAN_FRONTEND=noninteractive apt install -y "./$1" </dev/null 2>&1
    say "INSTALLED=$(dpkg-query -W -f='${Version}' lj9da-bridge)"
    say "BINARY_SHA256=$(sha256sum /usr/bin/lj9da-bridge | cut -d' ' -f1)"
}

# The mapping file: bus "uart" on the PL011 in RS485 mode, bus "usb" on the USB adapter by its
# by-id name, the autopilot and a ground station on UDP ports that the host forwards. In a
# container both buses are pseudo-terminals (no RS485 mode, no by-id name), which the unit's
# device list does not name: a drop-in adds them, as README.md's Troubleshooting says for a
# port of another driver.
cmd_configure() {
    local by_id uart_rs485="rs485 = { rts_on_send = true }"
    if [ "$place" = board ]; then
        by_id=$(usb_by_id) || { say "no /dev/serial/by-id/ link to /dev/$usb_tty"; return 1; }
        say "USB_BY_ID=$by_id"
    else
        by_id=$usb uart_rs485=""
        mkdir -p "$dropin_dir"
        printf '[Service]\n# The buses are pseudo-terminals (lj9da-sim).\nDeviceAllow=char-pts rw\n' \
            >"$dropin_dir/pseudo-terminals.conf"
        systemctl daemon-reload
        say "USB_BY_ID=$by_id (a pseudo-terminal; drop-in $dropin_dir/pseudo-terminals.conf)"
    fi
    mapping "$by_id" "$uart_rs485" "" >"$conffile.new"
    chown --reference="$conffile" "$conffile.new"
    chmod --reference="$conffile" "$conffile.new"
    mv "$conffile.new" "$conffile"
    cat "$conffile"
}

# mapping BY_ID UART_RS485 USB_RS485 [CONNECTION]: the board's mapping file on stdout, with the
# given `rs485 = …` lines (or none) on the buses.
mapping() {
    local by_id=$1 uart_rs485=$2 usb_rs485=$3 connection=${4:-udpin:0.0.0.0:$autopilot_port}
    cat <<EOF
# The board in a box ($place): a PL011 UART board with its transceiver's DE on RTS (bus "uart")
# and a USB–RS485 adapter (bus "usb"), two servos each; the autopilot and a ground station on
# UDP. The emulated board (QEMU, TCG) hands a reply to the bridge tens of milliseconds after
# the servo sent it, the simulated servos on a container's pseudo-terminals a few: each bus
# allows $turnaround_ms ms for that (a real adapter needs the default).
[mavlink]
connection = "$connection"
gcs = "udpin:0.0.0.0:$gcs_port"
output_rate_hz = 50.0
# The autopilot's id, known before its first HEARTBEAT: a restarted bridge obeys its outputs at
# once instead of up to a second later.
system_id = 1

[telemetry]
esc_index_base = 0

[[bus]]
name = "uart"
port = "$uart"
baud = 115200
turnaround_ms = $turnaround_ms
$uart_rs485

[[bus]]
name = "usb"
port = "$by_id"
baud = 115200
turnaround_ms = $turnaround_ms
$usb_rs485

[[servo]]
name = "aileron_left"
label = "ail_l"
bus = "uart"
id = 1
channel = 1

[[servo]]
name = "aileron_right"
label = "ail_r"
bus = "uart"
id = 2
channel = 2

[[servo]]
name = "elevator"
label = "elev"
bus = "usb"
id = 3
channel = 3

[[servo]]
name = "rudder"
bus = "usb"
id = 4
channel = 4

[record]
dir = "$records"
EOF
}

cmd_check() { lj9da-bridge check --config "$conffile" 2>&1; }

cmd_enable() {
    systemctl enable --now "$unit" 2>&1
    wait_active 60 || { systemctl status --no-pager "$unit" 2>&1 || true; return 1; }
    say "MAIN_PID=$(main_pid)"
}

cmd_status() {
    systemctl show -p ActiveState,SubState,MainPID,NRestarts,ExecMainStartTimestampMonotonic "$unit"
}

cmd_journal() { journalctl -u "$unit" --no-pager -o short-iso-precise 2>&1; }

cmd_ports() {
    say "--- text"
    lj9da-bridge ports 2>&1
    say "--- json"
    lj9da-bridge ports --json 2>&1
}

cmd_latency() {
    say "LATENCY=$(cat /sys/bus/usb-serial/devices/$usb_tty/latency_timer)"
    say "RULE=$(ls /lib/udev/rules.d/99-lj9da-bridge.rules 2>&1)"
}

# The PL011's RS485 mode as the kernel holds it now (the bridge has set it), and what the
# bridge's log says it asked and was granted.
cmd_rs485() {
    say "RS485_NOW=$(rs485_get "$uart")"
    say "--- journal"
    journalctl -u "$unit" --no-pager -o cat 2>&1 | grep "RS485 mode" || say "(no RS485 line in the journal)"
}

# A mapping that asks RS485 mode of the USB adapter: the service is stopped for it (one program
# per port), `check` and `run` are run on it as the service's user, then the service is started
# again.
cmd_rs485_usb() {
    local by_id file=/run/lj9da-board-usb-rs485.toml status=0
    by_id=$(usb_by_id) || { say "no /dev/serial/by-id/ link to /dev/$usb_tty"; return 1; }
    mapping "$by_id" "" "rs485 = { rts_on_send = true }" "udpin:0.0.0.0:14570" >"$file"
    chmod 0644 "$file"
    say "USB_RS485_TTY=$(rs485_get /dev/$usb_tty)"
    systemctl stop "$unit"
    say "--- check"
    runuser -u lj9da -- lj9da-bridge check --config "$file" 2>&1 || say "CHECK_EXIT=$?"
    say "--- run (8 s)"
    runuser -u lj9da -- env RUST_LOG=warn,lj9da_bridge=info NO_COLOR=1 \
        timeout -s INT 8 lj9da-bridge run --config "$file" 2>&1 || say "RUN_EXIT=$?"
    systemctl start "$unit" || status=$?
    wait_active 60 || status=1
    say "MAIN_PID=$(main_pid)"
    return $status
}

cmd_security() { systemd-analyze security --no-pager "$unit" 2>&1; }

# The service's kind, watchdog and restart policy as systemd holds them, and whether the binary
# knows the test fault switch.
cmd_features() {
    systemctl show -p Type,WatchdogUSec,Restart,RestartUSec,NotifyAccess "$unit"
    say "HANG_SWITCH=$(grep -c -a LJ9DA_TEST_HANG_BUS /usr/bin/lj9da-bridge || true)"
}

# Before an upgrade: a harmless comment in the mapping file, and what the records folder holds.
cmd_pre_upgrade() {
    printf '\n# edited on the board before the upgrade (%s)\n' "$(date -u +%FT%TZ)" >>"$conffile"
    say "CONFFILE_SHA256=$(sha256sum "$conffile" | cut -d' ' -f1)"
    say "RECORDS_BEFORE=$(find "$records" -type f 2>/dev/null | wc -l)"
    find "$records" -type f -printf '%P %s\n' 2>/dev/null | sort || true
    say "MAIN_PID=$(main_pid)"
    say "EXE=$(readlink "/proc/$(main_pid)/exe")"
}

cmd_upgrade() {
    cmd_install "$1"
    wait_active 60 || { systemctl status --no-pager "$unit" 2>&1 || true; return 1; }
    sleep 2
    local pid
    pid=$(main_pid)
    say "MAIN_PID=$pid"
    say "EXE=$(readlink "/proc/$pid/exe")"
    say "EXE_SHA256=$(sha256sum "/proc/$pid/exe" | cut -d' ' -f1)"
    say "CONFFILE_SHA256=$(sha256sum "$conffile" | cut -d' ' -f1)"
    say "CONFFILE_EDIT=$(grep -c 'edited on the board before the upgrade' "$conffile" || true)"
    say "CONFFILE_DIST=$(ls "$conffile".dpkg-* 2>/dev/null | tr '\n' ' ')"
    say "RECORDS_AFTER=$(find "$records" -type f 2>/dev/null | wc -l)"
    find "$records" -type f -printf '%P %s\n' 2>/dev/null | sort || true
    cmd_status
}

cmd_kill() {
    local pid
    pid=$(main_pid)
    kill "-$1" "$pid"
    say "SIGNALLED=$pid"
}

# The test fault switch through a drop-in: LJ9DA_TEST_HANG_BUS=BUS:SECONDS, or off.
cmd_hang() {
    if [ "$1" = off ]; then
        rm -f "$dropin_dir/test-hang.conf"
    else
        mkdir -p "$dropin_dir"
        printf '[Service]\nEnvironment=LJ9DA_TEST_HANG_BUS=%s\n' "$1" >"$dropin_dir/test-hang.conf"
    fi
    systemctl daemon-reload
    systemctl restart "$unit"
    wait_active 60
    cmd_status
}

# The computer's clock, to place its flight records on the host's.
cmd_clock() { say "CLOCK=$(date +%s.%N)"; }

# Every flight record: its name, the run's start (seconds since 1970, UTC), its last sample's
# time from that start, and how it ended (the summary's words, joined by _), then the summary's
# first line and its notes.
cmd_records() {
    local f head start state last
    for f in "$records"/*.lj9rec; do
        [ -e "$f" ] || continue
        # The whole summary is read: a reader that stops early would cut the writer's pipe.
        head=$(lj9da-bridge record summary "$f" 2>/dev/null | sed -n '/^run started /p')
        start=$(sed -n 's/^run started \([0-9-]* [0-9:.]*\) UTC.*/\1/p' <<<"$head")
        state=${head##*records, }
        last=$(lj9da-bridge record csv "$f" 2>/dev/null | awk -F, 'NR > 1 && $1 + 0 > m { m = $1 + 0 } END { printf "%.6f", m }')
        say "RECORD $(basename "$f") START=$(date -u -d "$start UTC" +%s.%N 2>/dev/null || echo unknown) LAST=$last STATE=${state// /_}"
        say "  $head"
        lj9da-bridge record summary "$f" 2>&1 >/dev/null | sed 's/^/  /'
    done
}

cmd_poweroff() {
    sync
    systemctl poweroff --no-block 2>&1 || true
}

agent() {
    local i=0
    until [ -e "$control" ] && [ -e "$results" ]; do
        i=$((i + 1))
        [ $i -le 120 ] || { echo "guest.sh: no ports $control, $results" >&2; exit 1; }
        sleep 0.5
    done
    # Appended: after a power cut and a boot the host reads on where it stopped.
    exec 3<"$control" 4>>"$results"
    say "@@READY $(date -u +%FT%T.%NZ)" >&4
    local line id
    while IFS= read -r line <&3; do
        read -r -a words <<<"$line"
        [ ${#words[@]} -ge 2 ] || continue
        id=${words[0]}
        say "@@BEGIN $id ${words[*]:1}" >&4
        set +e
        timeout 300 bash "$0" "${words[@]:1}" >&4 2>&1 </dev/null
        local status=$?
        set -e
        say "@@END $id $status" >&4
    done
}

case ${1:-} in
agent) agent ;;
ping | probe | facts | install | configure | check | enable | status | journal | ports | latency | rs485 | \
    security | features | upgrade | kill | hang | clock | records | poweroff)
    command=$1
    shift
    "cmd_$command" "$@"
    ;;
rs485-usb) cmd_rs485_usb ;;
pre-upgrade) cmd_pre_upgrade ;;
*)
    echo "guest.sh: unknown request ${1:-(none)}" >&2
    exit 2
    ;;
esac

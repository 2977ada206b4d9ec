//! Deployment on a companion computer: a systemd unit, a udev rule, and the start-up check of
//! USB RS485 adapters whose latency timer is too high.
//!
//! # Installing the bridge as a service
//!
//! ```text
//! cargo build --release
//! sudo install -m 755 target/release/lj9da-bridge /usr/local/bin/
//! sudo install -d /etc/lj9da-bridge
//! sudo cp mappings/ardupilot-plane.toml /etc/lj9da-bridge/bridge.toml   # then edit it
//! sudo useradd --system --user-group --groups dialout --no-create-home \
//!      --shell /usr/sbin/nologin lj9da
//! lj9da-bridge deploy udev | sudo tee /etc/udev/rules.d/99-lj9da-bridge.rules
//! sudo udevadm control --reload-rules && sudo udevadm trigger --action=add --subsystem-match=usb-serial
//! lj9da-bridge deploy systemd | sudo tee /etc/systemd/system/lj9da-bridge.service
//! sudo systemctl daemon-reload && sudo systemctl enable --now lj9da-bridge
//! journalctl -u lj9da-bridge -f        # the bridge's log
//! ```
//!
//! The service runs as the unprivileged user `lj9da` (group `dialout` opens the serial
//! ports), logs to stderr, which journald keeps (`RUST_LOG` sets the detail), and stops cleanly
//! on SIGTERM. It tells systemd when it is ready and feeds its watchdog while its main loop and
//! every bus thread run ([`crate::runtime::service`]); whether it exits, is killed or hangs, it
//! is started again within 200 ms of systemd noticing (a hang: after the 1 s watchdog). systemd
//! creates `/var/lib/lj9da-bridge` for it (`StateDirectory`); point the flight record folder
//! there in the mapping file, since `/etc` is read-only for the service.
//!
//! # The latency timer
//!
//! FTDI USB-serial chips hold received bytes until 62 have arrived or their latency timer
//! runs out: 16 ms by default. On a half-duplex RS485 bus every reply then reaches the bridge
//! up to 16 ms late, so the bus waits for nothing most of the time, or times out. [`udev_rule`]
//! sets the timer to 1 ms whenever such an adapter appears; at start-up, [`check_latency`]
//! reads it for each bus's port and, if it is above 1 ms, lowers it itself — through sysfs
//! (as root) or through the port's low-latency flag (`TIOCSSERIAL` with `ASYNC_LOW_LATENCY`,
//! which `ftdi_sio` turns into a 1 ms timer and which the port's owner may set) — or else
//! warns with the exact command that fixes it.

use crate::config::Config;
pub use crate::serial::latency::{
    LatencyCheck, LatencyFixer, LoweredBy, ReportOnly, SystemFixer, UDEV_RULE_PATH,
    WANTED_LATENCY_MS, check_latency, check_latency_in, check_latency_with, latency_fix,
};
use clap::Subcommand;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

/// Where `lj9da-bridge deploy systemd` assumes the program is installed.
pub const DEFAULT_BINARY: &str = "/usr/local/bin/lj9da-bridge";
/// The mapping file the service reads.
pub const DEFAULT_CONFIG: &str = "/etc/lj9da-bridge/bridge.toml";
/// The service's state folder (systemd `StateDirectory`), for flight records.
pub const STATE_DIR: &str = "/var/lib/lj9da-bridge";
/// Where the unit is installed.
pub const SYSTEMD_UNIT_PATH: &str = "/etc/systemd/system/lj9da-bridge.service";
/// The service's user.
pub const SERVICE_USER: &str = "lj9da";

/// A path as one argument of a systemd command line: quoted if it holds white space or
/// quotes, with `%` and `$` escaped (systemd expands them).
fn systemd_arg(path: &Path) -> String {
    let s = path.to_string_lossy().replace('%', "%%").replace('$', "$$");
    if s.chars()
        .any(|c| c.is_whitespace() || c == '"' || c == '\'' || c == '\\' || c == ';')
    {
        format!("\"{}\"", s.replace('\\', "\\\\").replace('"', "\\\""))
    } else {
        s
    }
}

/// The systemd unit that runs `binary run --config config` as a service.
pub fn systemd_unit(binary: &Path, config: &Path) -> String {
    let config_dir = match config.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    };
    format!(
        "\
# {SYSTEMD_UNIT_PATH}, written by `lj9da-bridge deploy systemd`.
# Install: sudo systemctl daemon-reload && sudo systemctl enable --now lj9da-bridge
# Log:     journalctl -u lj9da-bridge -f
[Unit]
Description=lj9da-bridge: MAVLink autopilot outputs to Futaba LJ9DA41 RS485 servos
Documentation=man:lj9da-bridge(1)
# The MAVLink link may be a network address: start once the network is up.
Wants=network-online.target
After=network-online.target
# A bridge that fails again and again at once (100 starts within 30 s: it never gets going)
# is left failed, for `systemctl status` to show why; one that fails in flight is started
# again every time.
StartLimitIntervalSec=30
StartLimitBurst=100

[Service]
# Ready once the MAVLink links are bound and every bus has tried its port.
Type=notify
NotifyAccess=main
ExecStart={binary} run --config {config}
# The bridge pings the watchdog every 250 ms, from its main loop and only while every bus
# thread turns: a bridge that hangs (a deadlock, a write that never returns, a stopped
# process) is killed within 1.25 s and started again 200 ms later. Meanwhile the servos hold
# the last goal they were sent; the new process sends the autopilot's current outputs. 1 s
# leaves a ping 750 ms to be late: 6.7 times the latest measured beside two busy loops (112 ms,
# benches/README.md).
WatchdogSec=1s
WatchdogSignal=SIGKILL
Restart=always
RestartSec=200ms
# A mapping file that does not load (exit status 2) is not tried again until it is fixed:
# `lj9da-bridge check --config {config}` says what is wrong.
RestartPreventExitStatus=2
# An unprivileged user; the dialout group opens the serial ports. Create it with:
#   sudo useradd --system --user-group --groups dialout --no-create-home --shell /usr/sbin/nologin {SERVICE_USER}
User={SERVICE_USER}
Group={SERVICE_USER}
SupplementaryGroups=dialout
# {STATE_DIR}, writable by the service: put the flight records there (the mapping file's
# record folder), since /etc is read-only for the service.
StateDirectory=lj9da-bridge
WorkingDirectory={STATE_DIR}
# SIGTERM stops the bridge cleanly: last packets to the servos, flight record closed.
TimeoutStopSec=10
# Logs go to stderr, which journald keeps; RUST_LOG sets the detail.
Environment=RUST_LOG=warn,lj9da_bridge=info
Environment=NO_COLOR=1
StandardOutput=journal
StandardError=journal
SyslogIdentifier=lj9da-bridge
# Less scheduling jitter on the serial bus.
Nice=-5
# Each bus thread asks for real-time scheduling (SCHED_FIFO, priority 10), the thread that takes
# the autopilot's messages too (priority 9), and the bridge locks its memory, so that a goal is
# not kept waiting by other programs or a page fault; without these grants it runs all the
# same, and says so once in the log. (On a kernel built with CONFIG_RT_GROUP_SCHED, the
# service's cgroup also needs real-time time: cpu.rt_runtime_us.)
AmbientCapabilities=CAP_SYS_NICE CAP_IPC_LOCK
CapabilityBoundingSet=CAP_SYS_NICE CAP_IPC_LOCK
LimitRTPRIO=10
LimitMEMLOCK=infinity
# What the bridge needs and nothing more (`systemd-analyze security lj9da-bridge`). The serial
# ports by their kernel driver names (/proc/devices): 8250 UARTs, the PL011 of a Raspberry Pi,
# USB adapters (FTDI, CP210x, CH340: ttyUSB; CDC-ACM: ttyACM), SC16IS7xx RS485 HATs (ttySC),
# Jetson (ttyTHS). A port of another driver is refused (Operation not permitted): add
# its name in a drop-in (`systemctl edit lj9da-bridge`, `DeviceAllow=char-NAME rw`).
DevicePolicy=closed
DeviceAllow=char-ttyS rw
DeviceAllow=char-ttyAMA rw
DeviceAllow=char-ttyUSB rw
DeviceAllow=char-ttyACM rw
DeviceAllow=char-ttySC rw
DeviceAllow=char-ttyTHS rw
NoNewPrivileges=yes
ProtectSystem=strict
ProtectHome=yes
PrivateTmp=yes
ProtectKernelTunables=yes
ProtectKernelModules=yes
ProtectKernelLogs=yes
ProtectControlGroups=yes
ProtectClock=yes
ProtectHostname=yes
ProtectProc=invisible
RestrictNamespaces=yes
RestrictSUIDSGID=yes
LockPersonality=yes
MemoryDenyWriteExecute=yes
RemoveIPC=yes
# AF_CAN: the DroneCAN node on a SocketCAN interface ([dronecan] interface = \"can0\").
RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_CAN
SystemCallArchitectures=native
SystemCallFilter=@system-service
SystemCallErrorNumber=EPERM
UMask=0027
# Parameter changes from the ground station are saved into the mapping file, by writing a new
# file beside it and renaming it over the old one: the service user needs its folder writable
# (sudo chown {SERVICE_USER}: {config_dir_plain}); without that a change is refused, and said so.
ReadWritePaths={config_dir}

[Install]
WantedBy=multi-user.target
",
        binary = systemd_arg(binary),
        config = systemd_arg(config),
        // `-`: a folder that does not exist does not stop the service from starting.
        config_dir = systemd_arg(Path::new(&format!("-{}", config_dir.display()))),
        config_dir_plain = config_dir.display(),
    )
}

/// The USB IDs of FTDI chips found in USB RS485 adapters: (product ID, chip).
pub const FTDI_PRODUCTS: [(&str, &str); 5] = [
    ("6001", "FT232R"),
    ("6010", "FT2232"),
    ("6011", "FT4232"),
    ("6014", "FT232H"),
    ("6015", "FT-X (FT230X, FT231X, FT234XD)"),
];

/// The udev rule that sets the latency timer of FTDI USB-serial adapters to 1 ms whenever one
/// appears.
pub fn udev_rule() -> String {
    let chips: Vec<String> = FTDI_PRODUCTS
        .iter()
        .map(|(pid, chip)| format!("#   0403:{pid}  {chip}"))
        .collect();
    let pids: Vec<&str> = FTDI_PRODUCTS.iter().map(|(pid, _)| *pid).collect();
    format!(
        "\
# {UDEV_RULE_PATH}, written by `lj9da-bridge deploy udev`.
#
# USB RS485 adapters with an FTDI chip hold received bytes for up to their latency timer
# before passing them on: 16 ms by default, which ruins half-duplex turnaround on the servo
# bus. These rules set it to 1 ms whenever such an adapter is plugged in. FTDI chips:
{chips}
# The first rule covers every adapter the ftdi_sio driver takes (also other vendor IDs);
# the second is the same for the tty of the listed chips. They also match \"change\", the
# event a plain `udevadm trigger` sends, so an adapter already plugged in is covered too.
#
# Install: lj9da-bridge deploy udev | sudo tee {UDEV_RULE_PATH}
#          sudo udevadm control --reload-rules && sudo udevadm trigger --action=add --subsystem-match=usb-serial
# Check:   cat /sys/bus/usb-serial/devices/ttyUSB0/latency_timer   (should print 1)
ACTION==\"add|change\", SUBSYSTEM==\"usb-serial\", DRIVER==\"ftdi_sio\", ATTR{{latency_timer}}=\"1\"
ACTION==\"add|change\", SUBSYSTEM==\"tty\", KERNEL==\"ttyUSB[0-9]*\", ATTRS{{idVendor}}==\"0403\", ATTRS{{idProduct}}==\"{pids}\", ATTR{{device/latency_timer}}=\"1\"
",
        chips = chips.join("\n"),
        pids = pids.join("|"),
    )
}

/// Check every bus port of a mapping file (before the buses are opened) and log each result.
pub fn check_buses(cfg: &Config) -> Vec<(String, LatencyCheck)> {
    cfg.buses
        .iter()
        .map(|bus| {
            let check = check_latency(&bus.port);
            check.log(&bus.name);
            (bus.name.clone(), check)
        })
        .collect()
}

/// `lj9da-bridge deploy …`: print the files of a service installation, check a port.
#[derive(Debug, Clone, PartialEq, Eq, Subcommand)]
pub enum DeployCommand {
    /// Print a systemd unit that runs the bridge as a service (install it as
    /// /etc/systemd/system/lj9da-bridge.service).
    Systemd {
        /// Where the program is installed.
        #[arg(long, default_value = DEFAULT_BINARY)]
        binary: PathBuf,
        /// The mapping file the service runs.
        #[arg(long, default_value = DEFAULT_CONFIG)]
        config: PathBuf,
    },
    /// Print a udev rule that sets the latency timer of FTDI USB RS485 adapters to 1 ms
    /// (install it as /etc/udev/rules.d/99-lj9da-bridge.rules).
    Udev,
    /// Check a serial port's latency timer, and lower it to 1 ms if this user may.
    Latency {
        /// The serial port (e.g. /dev/ttyUSB0 or /dev/serial/by-id/…).
        port: PathBuf,
        /// Only report, change nothing.
        #[arg(long)]
        check_only: bool,
    },
}

/// Run a `deploy` subcommand. `latency` exits with 1 when the port needs attention.
pub fn run(cmd: DeployCommand) -> ExitCode {
    match cmd {
        DeployCommand::Systemd { binary, config } => {
            print!("{}", systemd_unit(&binary, &config));
            ExitCode::SUCCESS
        }
        DeployCommand::Udev => {
            print!("{}", udev_rule());
            ExitCode::SUCCESS
        }
        DeployCommand::Latency { port, check_only } => {
            let check = if check_only {
                check_latency_with(Path::new("/sys"), &port, &ReportOnly)
            } else {
                check_latency(&port)
            };
            println!("{check}");
            if check.needs_attention() {
                ExitCode::FAILURE
            } else {
                ExitCode::SUCCESS
            }
        }
    }
}

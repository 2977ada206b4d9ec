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
//! is started again within 200 ms of systemd noticing (a hang: after the 2 s watchdog). systemd
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
use clap::Subcommand;
use std::fmt;
use std::io;
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
/// Where the udev rule is installed.
pub const UDEV_RULE_PATH: &str = "/etc/udev/rules.d/99-lj9da-bridge.rules";
/// The service's user.
pub const SERVICE_USER: &str = "lj9da";
/// The latency timer the bridge wants, in ms.
pub const WANTED_LATENCY_MS: u32 = 1;

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
Documentation=https://github.com/lj9da-bridge/lj9da-bridge
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
# The bridge pings the watchdog every second, from its main loop and only while every bus
# thread turns: a bridge that hangs (a deadlock, a write that never returns, a stopped
# process) is killed after 2 s and started again 200 ms later. Meanwhile the servos hold the
# last goal they were sent; the new process sends the autopilot's current outputs.
WatchdogSec=2s
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
# Each bus thread asks for real-time scheduling (SCHED_FIFO, priority 10) and the bridge locks
# its memory, so that a goal is not kept waiting by other programs or a page fault; without
# these grants it runs all the same, and says so once in the log. (On a kernel built with
# CONFIG_RT_GROUP_SCHED, the service's cgroup also needs real-time time: cpu.rt_runtime_us.)
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
RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6
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

/// How a high latency timer was lowered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoweredBy {
    /// Writing 1 to the sysfs `latency_timer` (root).
    Sysfs,
    /// Setting the port's low-latency flag (`TIOCSSERIAL`, `ASYNC_LOW_LATENCY`).
    LowLatencyFlag,
}

/// What the latency check found for one port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LatencyCheck {
    /// The latency timer is already low.
    Ok { tty: String, ms: u32 },
    /// It was high and the bridge lowered it to 1 ms (until the adapter is plugged in again).
    Lowered {
        tty: String,
        from: u32,
        by: LoweredBy,
    },
    /// It is high and could not be lowered; `fix` says how, with the exact commands.
    High {
        tty: String,
        ms: u32,
        fix: String,
        /// Why each way of lowering it failed.
        tried: Vec<String>,
    },
    /// A USB-serial adapter without an FTDI-style latency timer (CP210x, CH34x, PL2303, …).
    NoLatencyTimer { tty: String, driver: Option<String> },
    /// Not a USB-serial adapter (a built-in UART, a pseudo-terminal, a CDC-ACM device).
    NotUsbSerial { port: PathBuf },
    /// The latency timer exists but could not be read.
    Unreadable { tty: String, reason: String },
}

impl LatencyCheck {
    /// Whether the port needs the user's attention.
    pub fn needs_attention(&self) -> bool {
        matches!(
            self,
            LatencyCheck::High { .. } | LatencyCheck::Unreadable { .. }
        )
    }

    /// Log the result for bus `bus`: a warning when the user must act, else info or debug.
    pub fn log(&self, bus: &str) {
        match self {
            LatencyCheck::High { .. } | LatencyCheck::Unreadable { .. } => {
                tracing::warn!(bus = %bus, "{self}");
            }
            LatencyCheck::Lowered { .. } => tracing::info!(bus = %bus, "{self}"),
            _ => tracing::debug!(bus = %bus, "{self}"),
        }
    }
}

impl fmt::Display for LatencyCheck {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LatencyCheck::Ok { tty, ms } => write!(f, "{tty}: latency timer {ms} ms: good"),
            LatencyCheck::Lowered { tty, from, by } => write!(
                f,
                "{tty}: latency timer lowered from {from} ms to 1 ms ({}); it goes back to {from} \
                 ms when the adapter is plugged in again unless the udev rule is installed \
                 (lj9da-bridge deploy udev)",
                match by {
                    LoweredBy::Sysfs => "through sysfs",
                    LoweredBy::LowLatencyFlag => "through the port's low-latency flag",
                }
            ),
            LatencyCheck::High { tty, ms, fix, .. } => {
                write!(f, "{tty}: latency timer {ms} ms: {fix}")
            }
            LatencyCheck::NoLatencyTimer { tty, driver } => write!(
                f,
                "{tty}: a USB-serial adapter{} without an adjustable latency timer: nothing to set",
                driver
                    .as_ref()
                    .map(|d| format!(" (driver {d})"))
                    .unwrap_or_default()
            ),
            LatencyCheck::NotUsbSerial { port } => write!(
                f,
                "{}: not a USB-serial adapter: no latency timer to check",
                port.display()
            ),
            LatencyCheck::Unreadable { tty, reason } => {
                write!(f, "{tty}: cannot read the latency timer: {reason}")
            }
        }
    }
}

/// The fix for a high latency timer on `tty`, with the exact commands.
pub fn latency_fix(tty: &str, ms: u32) -> String {
    format!(
        "replies reach the bridge up to {ms} ms late, which ruins half-duplex turnaround. \
         Fix it now:\n  echo 1 | sudo tee /sys/bus/usb-serial/devices/{tty}/latency_timer\n\
         and for good, with the udev rule:\n  lj9da-bridge deploy udev | sudo tee {UDEV_RULE_PATH}\n  \
         sudo udevadm control --reload-rules && sudo udevadm trigger --action=add --subsystem-match=usb-serial\n\
         (or live with it: turnaround_ms = {} in this bus's [[bus]] table, at the cost of a slower bus)",
        ms + 4
    )
}

/// The ways a latency check may lower a high latency timer. [`SystemFixer`] is the real one.
pub trait LatencyFixer {
    /// Write `ms` to the sysfs `latency_timer` file.
    fn write_latency(&self, file: &Path, ms: u32) -> io::Result<()>;
    /// Set the low-latency flag of the port at `port`.
    fn set_low_latency(&self, port: &Path) -> io::Result<()>;
}

/// Lowers the latency timer as the running process may: sysfs, then the low-latency flag.
#[derive(Debug, Clone, Copy, Default)]
pub struct SystemFixer;

impl LatencyFixer for SystemFixer {
    fn write_latency(&self, file: &Path, ms: u32) -> io::Result<()> {
        use std::io::Write;
        let mut f = std::fs::OpenOptions::new().write(true).open(file)?;
        f.write_all(format!("{ms}\n").as_bytes())
    }

    fn set_low_latency(&self, port: &Path) -> io::Result<()> {
        low_latency::set(port)
    }
}

/// Changes nothing: the check only reports.
#[derive(Debug, Clone, Copy, Default)]
pub struct ReportOnly;

impl LatencyFixer for ReportOnly {
    fn write_latency(&self, _file: &Path, _ms: u32) -> io::Result<()> {
        Err(io::Error::new(
            io::ErrorKind::PermissionDenied,
            "report only: nothing is changed",
        ))
    }

    fn set_low_latency(&self, _port: &Path) -> io::Result<()> {
        Err(io::Error::new(
            io::ErrorKind::PermissionDenied,
            "report only: nothing is changed",
        ))
    }
}

/// Check the latency timer of the serial port at `port` and lower it if it is above 1 ms.
pub fn check_latency(port: &Path) -> LatencyCheck {
    check_latency_in(Path::new("/sys"), port)
}

/// [`check_latency`] with sysfs at `sysfs_root` (a fake tree in tests).
pub fn check_latency_in(sysfs_root: &Path, port: &Path) -> LatencyCheck {
    check_latency_with(sysfs_root, port, &SystemFixer)
}

/// The tty name of `port`: symlinks (`/dev/serial/by-id/…`) resolved.
fn tty_name(port: &Path) -> Option<String> {
    let resolved = std::fs::canonicalize(port).unwrap_or_else(|_| port.to_path_buf());
    resolved
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
}

fn read_ms(file: &Path) -> Result<u32, String> {
    let text = std::fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
    text.trim().parse().map_err(|_| {
        format!(
            "{}: {:?} is not a number of ms",
            file.display(),
            text.trim()
        )
    })
}

/// [`check_latency_in`] lowering the timer through `fixer`.
pub fn check_latency_with(
    sysfs_root: &Path,
    port: &Path,
    fixer: &dyn LatencyFixer,
) -> LatencyCheck {
    let not_usb = || LatencyCheck::NotUsbSerial {
        port: port.to_path_buf(),
    };
    let Some(tty) = tty_name(port) else {
        return not_usb();
    };
    let device = sysfs_root.join("bus/usb-serial/devices").join(&tty);
    let candidates = [
        device.join("latency_timer"),
        sysfs_root
            .join("class/tty")
            .join(&tty)
            .join("device/latency_timer"),
    ];
    let Some(file) = candidates.iter().find(|f| f.is_file()) else {
        if device.exists() {
            let driver = std::fs::read_link(device.join("driver"))
                .ok()
                .and_then(|d| d.file_name().map(|n| n.to_string_lossy().into_owned()));
            return LatencyCheck::NoLatencyTimer { tty, driver };
        }
        return not_usb();
    };
    let ms = match read_ms(file) {
        Ok(ms) => ms,
        Err(reason) => return LatencyCheck::Unreadable { tty, reason },
    };
    if ms <= WANTED_LATENCY_MS {
        return LatencyCheck::Ok { tty, ms };
    }
    let mut tried = Vec::new();
    let attempts: [(LoweredBy, &dyn Fn() -> io::Result<()>); 2] = [
        (LoweredBy::Sysfs, &|| {
            fixer.write_latency(file, WANTED_LATENCY_MS)
        }),
        (LoweredBy::LowLatencyFlag, &|| fixer.set_low_latency(port)),
    ];
    for (by, attempt) in attempts {
        let what = match by {
            LoweredBy::Sysfs => format!("writing {}", file.display()),
            LoweredBy::LowLatencyFlag => {
                format!("setting the low-latency flag of {}", port.display())
            }
        };
        match attempt() {
            Err(e) => tried.push(format!("{what}: {e}")),
            Ok(()) => match read_ms(file) {
                Ok(now) if now <= WANTED_LATENCY_MS => {
                    return LatencyCheck::Lowered { tty, from: ms, by };
                }
                Ok(now) => tried.push(format!("{what}: the timer still reads {now} ms")),
                Err(reason) => tried.push(format!("{what}: then {reason}")),
            },
        }
    }
    LatencyCheck::High {
        fix: latency_fix(&tty, ms),
        tty,
        ms,
        tried,
    }
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

/// The port's low-latency flag (`ASYNC_LOW_LATENCY`), set with `TIOCGSERIAL`/`TIOCSSERIAL`.
/// The owner of a port may change this flag without root; `ftdi_sio` then sets the chip's
/// latency timer to 1 ms.
#[cfg(target_os = "linux")]
mod low_latency {
    use std::io;
    use std::os::fd::AsRawFd;
    use std::os::unix::fs::OpenOptionsExt;
    use std::path::Path;

    /// `ASYNC_LOW_LATENCY` of `<linux/tty_flags.h>`: bit 13.
    const ASYNC_LOW_LATENCY: libc::c_int = 1 << 13;

    /// `struct serial_struct` of `<linux/serial.h>`, with spare room at the end.
    #[repr(C)]
    struct SerialStruct {
        kind: libc::c_int,
        line: libc::c_int,
        port: libc::c_uint,
        irq: libc::c_int,
        flags: libc::c_int,
        xmit_fifo_size: libc::c_int,
        custom_divisor: libc::c_int,
        baud_base: libc::c_int,
        close_delay: libc::c_ushort,
        io_type: libc::c_char,
        reserved_char: [libc::c_char; 1],
        hub6: libc::c_int,
        closing_wait: libc::c_ushort,
        closing_wait2: libc::c_ushort,
        iomem_base: *mut libc::c_uchar,
        iomem_reg_shift: libc::c_ushort,
        port_high: libc::c_uint,
        iomap_base: libc::c_ulong,
        spare: [u8; 64],
    }

    pub fn set(port: &Path) -> io::Result<()> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
            .open(port)?;
        let fd = file.as_raw_fd();
        let mut serial = SerialStruct {
            kind: 0,
            line: 0,
            port: 0,
            irq: 0,
            flags: 0,
            xmit_fifo_size: 0,
            custom_divisor: 0,
            baud_base: 0,
            close_delay: 0,
            io_type: 0,
            reserved_char: [0],
            hub6: 0,
            closing_wait: 0,
            closing_wait2: 0,
            iomem_base: std::ptr::null_mut(),
            iomem_reg_shift: 0,
            port_high: 0,
            iomap_base: 0,
            spare: [0; 64],
        };
        // SAFETY: TIOCGSERIAL writes one `struct serial_struct` through the pointer, which
        // points at a live, writable SerialStruct with that layout (and spare room after it).
        if unsafe { libc::ioctl(fd, libc::TIOCGSERIAL, &mut serial as *mut SerialStruct) } < 0 {
            return Err(io::Error::last_os_error());
        }
        if serial.flags & ASYNC_LOW_LATENCY != 0 {
            return Ok(());
        }
        serial.flags |= ASYNC_LOW_LATENCY;
        // SAFETY: TIOCSSERIAL reads one `struct serial_struct` through the pointer, which
        // points at a live SerialStruct with that layout, filled in by TIOCGSERIAL above.
        if unsafe { libc::ioctl(fd, libc::TIOCSSERIAL, &serial as *const SerialStruct) } < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }
}

#[cfg(not(target_os = "linux"))]
mod low_latency {
    pub fn set(_port: &std::path::Path) -> std::io::Result<()> {
        Err(std::io::Error::new(
            std::io::ErrorKind::Unsupported,
            "the low-latency flag is set on Linux only",
        ))
    }
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

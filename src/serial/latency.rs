//! The latency timer of USB-serial adapters: read from sysfs, lowered where the process may,
//! and the exact commands that fix it otherwise.
//!
//! FTDI USB-serial chips hold received bytes until 62 have arrived or their latency timer
//! runs out: 16 ms by default. On a half-duplex RS485 bus every reply then reaches the bridge
//! up to 16 ms late. [`check_latency`] reads the timer of a port and, if it is above 1 ms,
//! lowers it — through sysfs (as root) or through the port's low-latency flag (`TIOCSSERIAL`
//! with `ASYNC_LOW_LATENCY`, which `ftdi_sio` turns into a 1 ms timer and which the port's
//! owner may set) — or says how to. `lj9da-bridge deploy` and `lj9da-bridge ports` use it.

use std::fmt;
use std::io;
use std::path::{Path, PathBuf};

/// Where the udev rule that sets the timer for good is installed (`lj9da-bridge deploy udev`).
pub const UDEV_RULE_PATH: &str = "/etc/udev/rules.d/99-lj9da-bridge.rules";
/// The latency timer the bridge wants, in ms.
pub const WANTED_LATENCY_MS: u32 = 1;

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

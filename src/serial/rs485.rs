//! RS485 mode of a UART, as the Linux kernel drives it (`TIOCSRS485`): the transceiver's driver
//! enable follows the transmitter through the RTS line, switched by the kernel around every
//! write, so that the bus is driven only while the bridge talks and a servo's reply is heard.
//!
//! A bus asks for it with `rs485 = { … }` in its `[[bus]]` table (see `docs/rs485.md`); without
//! that key the port's RS485 setting is left as it is. The setting is applied each time the
//! bus's port is opened (by the bus driver, through its [`Rs485Request`]), read back, and a
//! driver that clamped a delay is reported with what was asked and what was granted. A driver
//! that refuses RS485 mode (a UART without it in its device tree, a USB adapter, a
//! pseudo-terminal) keeps the bus closed: it is reported once as an error naming the bus, the
//! port, the errno and what to check, and to the rest of the bridge as a port that cannot be
//! opened.

use std::fmt;
use std::os::fd::{AsRawFd, BorrowedFd};
use std::path::Path;

/// `SER_RS485_ENABLED` of `<linux/serial.h>`: RS485 mode on.
pub const SER_RS485_ENABLED: u32 = 1 << 0;
/// `SER_RS485_RTS_ON_SEND`: RTS is high (logical 1) while sending.
pub const SER_RS485_RTS_ON_SEND: u32 = 1 << 1;
/// `SER_RS485_RTS_AFTER_SEND`: RTS is high after sending.
pub const SER_RS485_RTS_AFTER_SEND: u32 = 1 << 2;
/// `SER_RS485_RX_DURING_TX`: the receiver stays on while sending (the bridge then reads its
/// own packets back, which its decoder skips).
pub const SER_RS485_RX_DURING_TX: u32 = 1 << 4;
/// `SER_RS485_TERMINATE_BUS`: switch on the board's bus termination, where it has a GPIO for it.
pub const SER_RS485_TERMINATE_BUS: u32 = 1 << 5;

/// The longest delay before or after sending that the kernel grants (`RS485_MAX_RTS_DELAY` of
/// `serial_core`: larger values are clamped to it).
pub const MAX_DELAY_MS: u32 = 100;

/// `struct serial_rs485` of `<linux/serial.h>` (32 bytes). The union at its end
/// (`addr_recv`, `addr_dest`, padding) is all zero here: the bridge uses no 9-bit addressing.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SerialRs485 {
    pub flags: u32,
    /// ms between raising the driver enable and the first bit.
    pub delay_rts_before_send: u32,
    /// ms between the last bit and releasing the driver enable.
    pub delay_rts_after_send: u32,
    pub padding: [u32; 5],
}

/// The RS485 mode a bus asks for (`rs485 = { … }` in its `[[bus]]` table).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rs485Mode {
    /// The driver enable is RTS high while sending (the usual wiring: RTS → DE and /RE).
    pub rts_on_send: bool,
    /// The driver enable is RTS high after sending (an inverted wiring). Exactly one of the
    /// two is true.
    pub rts_after_send: bool,
    /// ms the driver is enabled before the first bit, 0–100.
    pub delay_before_send_ms: u32,
    /// ms the driver stays enabled after the last bit, 0–100. The servo answers after its
    /// Return Delay Time (register 7): a longer hold talks over the start of its reply.
    pub delay_after_send_ms: u32,
    /// Keep the receiver on while sending.
    pub rx_during_tx: bool,
}

impl Default for Rs485Mode {
    /// RTS high while sending, no delays, receiver off while sending.
    fn default() -> Self {
        Rs485Mode {
            rts_on_send: true,
            rts_after_send: false,
            delay_before_send_ms: 0,
            delay_after_send_ms: 0,
            rx_during_tx: false,
        }
    }
}

impl Rs485Mode {
    /// The kernel's struct asking for this mode.
    pub fn to_kernel(self) -> SerialRs485 {
        let mut flags = SER_RS485_ENABLED;
        if self.rts_on_send {
            flags |= SER_RS485_RTS_ON_SEND;
        }
        if self.rts_after_send {
            flags |= SER_RS485_RTS_AFTER_SEND;
        }
        if self.rx_during_tx {
            flags |= SER_RS485_RX_DURING_TX;
        }
        SerialRs485 {
            flags,
            delay_rts_before_send: self.delay_before_send_ms,
            delay_rts_after_send: self.delay_after_send_ms,
            padding: [0; 5],
        }
    }

    /// The mode the kernel reports, `None` when RS485 mode is off.
    pub fn from_kernel(k: &SerialRs485) -> Option<Rs485Mode> {
        (k.flags & SER_RS485_ENABLED != 0).then_some(Rs485Mode {
            rts_on_send: k.flags & SER_RS485_RTS_ON_SEND != 0,
            rts_after_send: k.flags & SER_RS485_RTS_AFTER_SEND != 0,
            delay_before_send_ms: k.delay_rts_before_send,
            delay_after_send_ms: k.delay_rts_after_send,
            rx_during_tx: k.flags & SER_RS485_RX_DURING_TX != 0,
        })
    }
}

impl fmt::Display for Rs485Mode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let rts = match (self.rts_on_send, self.rts_after_send) {
            (true, false) => "RTS high while sending",
            (false, true) => "RTS high after sending",
            (true, true) => "RTS high while and after sending",
            (false, false) => "RTS low while and after sending",
        };
        write!(
            f,
            "{rts}, {} ms before, {} ms after",
            self.delay_before_send_ms, self.delay_after_send_ms
        )?;
        if self.rx_during_tx {
            f.write_str(", receiver on while sending")?;
        }
        Ok(())
    }
}

/// Why a port could not be put in RS485 mode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Rs485Error {
    /// `TIOCSRS485` failed: the driver has no RS485 mode (`ENOTTY`), or refuses this one.
    Refused(nix::errno::Errno),
    /// The mode was set but cannot be read back.
    Unreadable(nix::errno::Errno),
    /// This build has no RS485 ioctls (not Linux, or an architecture whose numbers `libc`
    /// does not give).
    Unsupported,
}

impl fmt::Display for Rs485Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Rs485Error::Refused(e) => write!(f, "its driver refuses RS485 mode (TIOCSRS485: {e})"),
            Rs485Error::Unreadable(e) => {
                write!(f, "RS485 mode cannot be read back (TIOCGRS485: {e})")
            }
            Rs485Error::Unsupported => f.write_str("this build cannot set RS485 mode"),
        }
    }
}

impl std::error::Error for Rs485Error {}

/// What the kernel made of the mode asked for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Granted {
    pub asked: Rs485Mode,
    /// Read back after setting; `None`: the driver switched RS485 mode off again.
    pub granted: Option<Rs485Mode>,
}

impl Granted {
    /// A sentence for the log when the driver changed what was asked (drivers clamp delays,
    /// and some support only one RTS polarity); `None` when it granted exactly that.
    pub fn difference(&self) -> Option<String> {
        match self.granted {
            Some(g) if g == self.asked => None,
            Some(g) => Some(format!("asked {}, granted {g}", self.asked)),
            None => Some(format!(
                "asked {}, but the driver reports RS485 mode off",
                self.asked
            )),
        }
    }
}

#[cfg(all(
    any(target_os = "linux", target_os = "android"),
    not(any(target_arch = "sparc", target_arch = "sparc64"))
))]
mod ioctl {
    use super::SerialRs485;
    use nix::errno::Errno;
    use std::os::fd::RawFd;

    pub fn set(fd: RawFd, value: &SerialRs485) -> Result<(), Errno> {
        let mut value = *value;
        // SAFETY: `value` is a `struct serial_rs485` laid out as the kernel's (checked by the
        // tests), which the kernel reads and may rewrite (the granted mode); it outlives the
        // call.
        let r = unsafe { libc::ioctl(fd, libc::TIOCSRS485, &mut value as *mut SerialRs485) };
        Errno::result(r).map(drop)
    }

    pub fn get(fd: RawFd) -> Result<SerialRs485, Errno> {
        let mut value = SerialRs485::default();
        // SAFETY: as in `set`; the kernel writes the 32 bytes of the struct.
        let r = unsafe { libc::ioctl(fd, libc::TIOCGRS485, &mut value as *mut SerialRs485) };
        Errno::result(r).map(|_| value)
    }

    pub const SUPPORTED: bool = true;
}

#[cfg(not(all(
    any(target_os = "linux", target_os = "android"),
    not(any(target_arch = "sparc", target_arch = "sparc64"))
)))]
mod ioctl {
    use super::SerialRs485;
    use nix::errno::Errno;
    use std::os::fd::RawFd;

    pub fn set(_fd: RawFd, _value: &SerialRs485) -> Result<(), Errno> {
        Err(Errno::ENOTSUP)
    }

    pub fn get(_fd: RawFd) -> Result<SerialRs485, Errno> {
        Err(Errno::ENOTSUP)
    }

    pub const SUPPORTED: bool = false;
}

/// The port's RS485 setting as the kernel reports it (`TIOCGRS485`).
pub fn get(fd: BorrowedFd<'_>) -> Result<SerialRs485, Rs485Error> {
    if !ioctl::SUPPORTED {
        return Err(Rs485Error::Unsupported);
    }
    ioctl::get(fd.as_raw_fd()).map_err(Rs485Error::Unreadable)
}

/// Put the open port `fd` in RS485 mode `mode` and read back what the driver granted.
pub fn set(fd: BorrowedFd<'_>, mode: Rs485Mode) -> Result<Granted, Rs485Error> {
    if !ioctl::SUPPORTED {
        return Err(Rs485Error::Unsupported);
    }
    ioctl::set(fd.as_raw_fd(), &mode.to_kernel()).map_err(Rs485Error::Refused)?;
    let back = ioctl::get(fd.as_raw_fd()).map_err(Rs485Error::Unreadable)?;
    Ok(Granted {
        asked: mode,
        granted: Rs485Mode::from_kernel(&back),
    })
}

/// What to check when `port` refuses RS485 mode, for the operator; `request` is where the
/// mode was asked for (see [`IN_MAPPING`]).
pub fn refusal_advice(port: &Path, request: &str) -> String {
    format!(
        "check that {} is a UART whose RS485 mode is enabled (on a Raspberry Pi: the board's \
         device-tree overlay, e.g. `linux,rs485-enabled-at-boot-time` and `rts-gpios` on the \
         UART node, and `dtoverlay=` in config.txt); a USB adapter or a transceiver with \
         automatic direction control switches by itself: then remove {request}",
        port.display()
    )
}

/// Where a bus asks for RS485 mode, for [`refusal_advice`].
pub const IN_MAPPING: &str = "`rs485` from this bus in the mapping file";

/// One bus's RS485 request, held by its bus driver and applied each time the port opens
/// ([`Rs485Request::apply`]). What was last said in the log is kept, so that a port tried
/// again and again is reported once, and again only when the outcome changes.
#[derive(Debug)]
pub struct Rs485Request {
    bus: String,
    mode: Rs485Mode,
    told: Option<String>,
}

impl Rs485Request {
    pub fn new(bus: impl Into<String>, mode: Rs485Mode) -> Self {
        Rs485Request {
            bus: bus.into(),
            mode,
            told: None,
        }
    }

    /// Set the mode on `fd`, the just-opened `port`. A refusal is logged as an error with what
    /// to check and returned as the reason the port cannot be used; a driver that changed the
    /// mode is reported with what was asked and what was granted.
    pub fn apply(&mut self, port: &Path, fd: BorrowedFd<'_>) -> Result<(), String> {
        let result = set(fd, self.mode);
        let said = match &result {
            Ok(g) => g.difference().unwrap_or_else(|| self.mode.to_string()),
            Err(e) => e.to_string(),
        };
        let first = self.told.as_deref() != Some(said.as_str());
        self.told = Some(said);
        match result {
            Ok(granted) => {
                if first {
                    match granted.difference() {
                        Some(d) => tracing::warn!(
                            bus = %self.bus,
                            port = %port.display(),
                            "RS485 mode: the driver changed it: {d}"
                        ),
                        None => tracing::info!(
                            bus = %self.bus,
                            port = %port.display(),
                            "RS485 mode on: {}",
                            self.mode
                        ),
                    }
                }
                Ok(())
            }
            Err(e) => {
                if first {
                    tracing::error!(
                        bus = %self.bus,
                        port = %port.display(),
                        "bus \"{}\" not started: {}: {e}; {}",
                        self.bus,
                        port.display(),
                        refusal_advice(port, IN_MAPPING)
                    );
                }
                Err(format!("RS485 mode not set: {e}"))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{offset_of, size_of};
    use std::os::fd::AsFd;

    #[test]
    fn the_struct_is_laid_out_as_the_kernels_serial_rs485() {
        // include/uapi/linux/serial.h: three __u32, then a 20-byte union.
        assert_eq!(size_of::<SerialRs485>(), 32);
        assert_eq!(offset_of!(SerialRs485, flags), 0);
        assert_eq!(offset_of!(SerialRs485, delay_rts_before_send), 4);
        assert_eq!(offset_of!(SerialRs485, delay_rts_after_send), 8);
        assert_eq!(offset_of!(SerialRs485, padding), 12);
        assert_eq!(std::mem::align_of::<SerialRs485>(), 4);
    }

    /// The value of `#define name (1 << n)` (or `_BITUL(n)`) in a C header.
    fn bit_defined(header: &str, name: &str) -> Option<u32> {
        header.lines().find_map(|line| {
            let rest = line.trim_start().strip_prefix("#define")?.trim_start();
            let value = rest.strip_prefix(name)?;
            if !value.starts_with(char::is_whitespace) {
                return None;
            }
            let value = value.split("/*").next()?.trim();
            let shift = value
                .strip_prefix("(1 <<")
                .and_then(|v| v.strip_suffix(')'))
                .or_else(|| value.strip_prefix("_BITUL(")?.strip_suffix(')'))?;
            Some(1 << shift.trim().parse::<u32>().ok()?)
        })
    }

    #[test]
    fn the_flags_are_the_kernels() {
        // The kernel's own definitions, from its user-space headers (Debian's linux-libc-dev,
        // which every C toolchain here brings).
        let path = "/usr/include/linux/serial.h";
        let header = std::fs::read_to_string(path)
            .unwrap_or_else(|e| panic!("{path}: {e} (install linux-libc-dev)"));
        for (name, ours) in [
            ("SER_RS485_ENABLED", SER_RS485_ENABLED),
            ("SER_RS485_RTS_ON_SEND", SER_RS485_RTS_ON_SEND),
            ("SER_RS485_RTS_AFTER_SEND", SER_RS485_RTS_AFTER_SEND),
            ("SER_RS485_RX_DURING_TX", SER_RS485_RX_DURING_TX),
            ("SER_RS485_TERMINATE_BUS", SER_RS485_TERMINATE_BUS),
        ] {
            assert_eq!(bit_defined(&header, name), Some(ours), "{name} in {path}");
        }
    }

    #[cfg(all(
        target_os = "linux",
        any(
            target_arch = "x86_64",
            target_arch = "x86",
            target_arch = "aarch64",
            target_arch = "arm"
        )
    ))]
    // `Ioctl` is `c_ulong` with glibc and `c_int` with musl: the cast is needed on one of them.
    #[allow(clippy::unnecessary_cast)]
    #[test]
    fn the_ioctl_numbers_are_the_generic_ones_on_the_usual_architectures() {
        assert_eq!(libc::TIOCGRS485 as u64, 0x542E);
        assert_eq!(libc::TIOCSRS485 as u64, 0x542F);
    }

    /// The struct's bytes as the kernel reads them (native byte order, as the ioctl does).
    fn bytes(k: &SerialRs485) -> Vec<u8> {
        let mut out = Vec::new();
        for word in [k.flags, k.delay_rts_before_send, k.delay_rts_after_send]
            .into_iter()
            .chain(k.padding)
        {
            out.extend_from_slice(&word.to_ne_bytes());
        }
        out
    }

    #[test]
    fn a_mode_is_encoded_as_flags_and_delays() {
        let k = Rs485Mode::default().to_kernel();
        assert_eq!(k.flags, SER_RS485_ENABLED | SER_RS485_RTS_ON_SEND);
        assert_eq!((k.delay_rts_before_send, k.delay_rts_after_send), (0, 0));

        let mode = Rs485Mode {
            rts_on_send: false,
            rts_after_send: true,
            delay_before_send_ms: 3,
            delay_after_send_ms: 1,
            rx_during_tx: true,
        };
        let k = mode.to_kernel();
        assert_eq!(
            k.flags,
            SER_RS485_ENABLED | SER_RS485_RTS_AFTER_SEND | SER_RS485_RX_DURING_TX
        );
        let mut expected = vec![0u8; 32];
        expected[0..4].copy_from_slice(&0x15u32.to_ne_bytes());
        expected[4..8].copy_from_slice(&3u32.to_ne_bytes());
        expected[8..12].copy_from_slice(&1u32.to_ne_bytes());
        assert_eq!(bytes(&k), expected);
        // And what the kernel reports decodes to the same mode.
        assert_eq!(Rs485Mode::from_kernel(&k), Some(mode));
        assert_eq!(Rs485Mode::from_kernel(&SerialRs485::default()), None);
    }

    #[test]
    fn a_clamped_delay_is_told_as_asked_and_granted() {
        let asked = Rs485Mode {
            delay_before_send_ms: 100,
            ..Rs485Mode::default()
        };
        let granted = Rs485Mode {
            delay_before_send_ms: 50,
            ..asked
        };
        let same = Granted {
            asked,
            granted: Some(asked),
        };
        assert_eq!(same.difference(), None);
        let clamped = Granted {
            asked,
            granted: Some(granted),
        };
        assert_eq!(
            clamped.difference().as_deref(),
            Some(
                "asked RTS high while sending, 100 ms before, 0 ms after, \
                 granted RTS high while sending, 50 ms before, 0 ms after"
            )
        );
        let off = Granted {
            asked,
            granted: None,
        };
        assert!(off.difference().unwrap().contains("RS485 mode off"));
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_pseudo_terminal_refuses_rs485_mode() {
        let pty = nix::pty::openpty(None, None).unwrap();
        let err = set(pty.slave.as_fd(), Rs485Mode::default()).unwrap_err();
        assert_eq!(err, Rs485Error::Refused(nix::errno::Errno::ENOTTY));
        assert!(err.to_string().contains("ENOTTY"), "{err}");
        assert!(get(pty.slave.as_fd()).is_err());
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_refusal_names_the_reason_every_time_it_is_tried() {
        let pty = nix::pty::openpty(None, None).unwrap();
        let path = nix::unistd::ttyname(&pty.slave).unwrap();
        let mut request = Rs485Request::new("wing", Rs485Mode::default());
        for _ in 0..2 {
            let reason = request.apply(&path, pty.slave.as_fd()).unwrap_err();
            assert!(reason.contains("refuses RS485 mode"), "{reason}");
            assert!(reason.contains("ENOTTY"), "{reason}");
        }
    }

    #[test]
    fn the_advice_names_the_port_the_overlay_and_the_way_out() {
        let advice = refusal_advice(Path::new("/dev/ttyAMA0"), IN_MAPPING);
        assert!(advice.contains("/dev/ttyAMA0"));
        assert!(advice.contains("linux,rs485-enabled-at-boot-time"));
        assert!(advice.contains("automatic direction"));
        assert!(advice.contains("remove `rs485`"));
    }
}

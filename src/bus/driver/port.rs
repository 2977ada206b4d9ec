//! The bus thread's serial port: opening it, the bytes it holds, and the wait for the last bytes
//! of a reply on the tty's read threshold.

use super::LATE_WAKEUP;
use crate::protocol::BaudRate;
use crate::serial::rs485::Rs485Request;
use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::poll::{PollFd, PollFlags, ppoll};
use nix::sys::termios::{SetArg, SpecialCharacterIndices, Termios, tcgetattr, tcsetattr};
use nix::sys::time::TimeSpec;
use std::fs::File;
use std::os::fd::{AsFd, AsRawFd, FromRawFd, IntoRawFd};
use std::path::Path;
use std::time::{Duration, Instant};
use tokio_serial::{DataBits, FlowControl, Parity, StopBits};

/// Open `path` at `baud`, 8N1, no flow control, without `TIOCEXCL` (a pseudo-terminal in
/// tests) but refused while another program holds it (see [`crate::serial::lock`]),
/// non-blocking: reads return what has arrived, writes never wait; in RS485 mode when the bus
/// asks for it (a refusal keeps the port closed). With it, the bus thread's [`ReplyWaiter`] on
/// the same port.
pub(super) fn open_port(
    path: &Path,
    baud: BaudRate,
    rs485: Option<&mut Rs485Request>,
) -> Result<(File, ReplyWaiter), String> {
    let mut native = tokio_serial::new(path.to_string_lossy(), baud.bits_per_second())
        .data_bits(DataBits::Eight)
        .parity(Parity::None)
        .stop_bits(StopBits::One)
        .flow_control(FlowControl::None)
        .open_native()
        .map_err(|e| match crate::serial::lock::refused_on_open(path, &e) {
            Some(in_use) => in_use.to_string(),
            None => e.to_string(),
        })?;
    let _ = native.set_exclusive(false);
    // SAFETY: `into_raw_fd` hands over a valid, open descriptor that nothing else owns or
    // closes any more; the `File` becomes its only owner.
    let port = unsafe { File::from_raw_fd(native.into_raw_fd()) };
    if let Some(request) = rs485 {
        request.apply(path, port.as_fd())?;
    }
    let flags = fcntl(port.as_raw_fd(), FcntlArg::F_GETFL).map_err(|e| e.to_string())?;
    let flags = OFlag::from_bits_retain(flags) | OFlag::O_NONBLOCK;
    fcntl(port.as_raw_fd(), FcntlArg::F_SETFL(flags)).map_err(|e| e.to_string())?;
    let waiter = ReplyWaiter::new(&port).map_err(|e| e.to_string())?;
    Ok((port, waiter))
}

/// The bytes the tty holds for reading (`TIOCINQ`; `None` where it cannot tell). Unlike a
/// read that finds nothing, it never waits for the kernel's worker to pass bytes on.
pub(super) fn bytes_in(port: &File) -> Option<usize> {
    use nix::libc;
    let mut held: libc::c_int = 0;
    // SAFETY: TIOCINQ writes one c_int, into `held`, which lives across the call.
    if unsafe { libc::ioctl(port.as_raw_fd(), libc::TIOCINQ, &mut held) } != 0 {
        return None;
    }
    usize::try_from(held).ok()
}

/// Waits on the port for the last bytes of a reply, without the core locked. It holds its own
/// descriptor of the port (a duplicate), so a writer closing the port meanwhile cannot pull
/// the descriptor from under the wait.
pub(super) struct ReplyWaiter {
    pub(super) port: File,
    /// The tty's settings, to change its read threshold (`None` when it cannot be changed:
    /// the wait then ends at the first byte, and the bus thread looks again).
    termios: Option<Termios>,
    /// The read threshold set last.
    vmin: u8,
}

/// Whether a [`ReplyWaiter::wait_for`] that timed out came back late (see [`LATE_WAKEUP`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Waited {
    InTime,
    /// Woken this long after the deadline.
    Late(Duration),
}

impl ReplyWaiter {
    fn new(port: &File) -> std::io::Result<Self> {
        let port = port.try_clone()?;
        let termios = tcgetattr(&port).ok().map(|mut termios| {
            // VMIN counts only when VTIME is 0.
            termios.control_chars[SpecialCharacterIndices::VTIME as usize] = 0;
            termios
        });
        Ok(ReplyWaiter {
            port,
            termios,
            vmin: 0,
        })
    }

    /// Block until `bytes` more bytes can be read (or the port failed), or until `until`.
    /// The tty's read threshold (termios `VMIN`) is set to `bytes` first, so the kernel makes
    /// the port readable only then; reads stay non-blocking and return whatever is there.
    pub(super) fn wait_for(&mut self, bytes: usize, until: Instant) -> Waited {
        self.set_threshold(u8::try_from(bytes.max(1)).unwrap_or(u8::MAX));
        let left = until.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Waited::InTime;
        }
        let mut fds = [PollFd::new(self.port.as_fd(), PollFlags::POLLIN)];
        // Readable, failed, hung up or timed out: the bus thread reads and looks again.
        let timed_out = ppoll(&mut fds, Some(TimeSpec::from_duration(left)), None) == Ok(0);
        let late = Instant::now().saturating_duration_since(until);
        if timed_out && late > LATE_WAKEUP {
            Waited::Late(late)
        } else {
            Waited::InTime
        }
    }

    /// Set the tty's read threshold to `vmin` bytes (no system call when it is already so).
    fn set_threshold(&mut self, vmin: u8) {
        let Some(termios) = self.termios.as_mut() else {
            return;
        };
        if vmin == self.vmin {
            return;
        }
        termios.control_chars[SpecialCharacterIndices::VMIN as usize] = vmin;
        match tcsetattr(&self.port, SetArg::TCSANOW, termios) {
            Ok(()) => self.vmin = vmin,
            Err(e) => {
                tracing::debug!("read threshold not settable, waking at every byte: {e}");
                self.termios = None;
            }
        }
    }
}

impl Drop for ReplyWaiter {
    /// Leave the tty reading byte by byte, as it was opened, for whoever opens it next.
    fn drop(&mut self) {
        if self.vmin > 1 {
            self.set_threshold(1);
        }
    }
}

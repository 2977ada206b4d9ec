//! The pseudo-terminal transport: the host opens the slave like any serial port; the simulator holds the
//! master.
//!
//! - The slave is put in raw mode (no echo, no line editing) at the bus's bit rate, so a host that does not
//!   configure the port still talks to the servos.
//! - The simulator keeps a slave descriptor open, so the master never reports EIO/hang-up when the host
//!   closes and reopens the port.
//! - A pty has no real bit rate, but it stores the one the host set (`tcsetattr`, or `TCSETS2` with `BOTHER`
//!   as `serialport`/`tokio-serial` do). The simulator reads it with `TCGETS2` whenever bytes arrive: that is
//!   "the host's current baud" of the bus model.
//! - Both descriptors are close-on-exec, so child processes (a bridge started by a test) never keep a pty
//!   alive after `disconnect_port`.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, FromRawFd, IntoRawFd, OwnedFd};
use std::path::{Path, PathBuf};

use nix::fcntl::{OFlag, open};
use nix::pty::{grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::stat::Mode;
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

/// One pseudo-terminal pair.
#[derive(Debug)]
pub struct Pty {
    master: File,
    slave: OwnedFd,
    path: PathBuf,
}

impl Pty {
    /// A new raw pty whose slave is set to `baud`. Both descriptors are opened close-on-exec
    /// (not marked so afterwards): a child that another thread starts meanwhile gets neither.
    pub fn open(baud: u32) -> io::Result<Pty> {
        let cloexec = OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC;
        let ptmx = posix_openpt(cloexec | OFlag::O_NONBLOCK).map_err(io::Error::from)?;
        grantpt(&ptmx).map_err(io::Error::from)?;
        unlockpt(&ptmx).map_err(io::Error::from)?;
        let slave_path = ptsname_r(&ptmx).map_err(io::Error::from)?;
        // SAFETY: `into_raw_fd` hands over the descriptor `ptmx` owned.
        let master = unsafe { OwnedFd::from_raw_fd(ptmx.into_raw_fd()) };
        let slave: OwnedFd = open(slave_path.as_str(), cloexec, Mode::empty())
            .map_err(io::Error::from)
            // SAFETY: `open` returned a new descriptor that nothing else owns.
            .map(|fd| unsafe { OwnedFd::from_raw_fd(fd) })?;
        let mut termios = tcgetattr(&slave).map_err(io::Error::from)?;
        cfmakeraw(&mut termios);
        tcsetattr(&slave, SetArg::TCSANOW, &termios).map_err(io::Error::from)?;
        set_speed(slave.as_fd(), baud)?;
        let path = nix::unistd::ttyname(&slave).map_err(io::Error::from)?;
        Ok(Pty {
            master: File::from(master),
            slave,
            path,
        })
    }

    /// The slave's path, e.g. `/dev/pts/7`.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Descriptor to poll for host bytes.
    pub fn master_fd(&self) -> BorrowedFd<'_> {
        self.master.as_fd()
    }

    /// Non-blocking read of what the host wrote.
    pub fn read(&mut self, buffer: &mut [u8]) -> io::Result<usize> {
        self.master.read(buffer)
    }

    /// Non-blocking write toward the host; returns how many bytes the pty took.
    pub fn write(&mut self, bytes: &[u8]) -> io::Result<usize> {
        self.master.write(bytes)
    }

    /// The bit rate the host set on the slave, if any.
    pub fn host_baud(&self) -> Option<u32> {
        get_speed(self.slave.as_fd()).ok().filter(|&baud| baud > 0)
    }
}

/// Output speed of a tty, from `TCGETS2` (works for standard rates and for `BOTHER`).
pub fn get_speed(fd: BorrowedFd<'_>) -> io::Result<u32> {
    let termios = get_termios2(fd)?;
    Ok(termios.c_ospeed)
}

/// Set a tty's input and output speed to any rate (`TCSETS2` with `BOTHER`).
pub fn set_speed(fd: BorrowedFd<'_>, baud: u32) -> io::Result<()> {
    let mut termios = get_termios2(fd)?;
    termios.c_cflag &= !(libc::CBAUD | libc::CIBAUD);
    termios.c_cflag |= libc::BOTHER;
    termios.c_ispeed = baud;
    termios.c_ospeed = baud;
    // SAFETY: TCSETS2 reads one `termios2` from the pointer, which points to a live, initialised value.
    let result = unsafe {
        libc::ioctl(
            fd.as_raw_fd(),
            libc::TCSETS2,
            &termios as *const libc::termios2,
        )
    };
    if result < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(())
    }
}

fn get_termios2(fd: BorrowedFd<'_>) -> io::Result<libc::termios2> {
    // SAFETY: `termios2` is a plain C struct for which all-zero bytes are a valid value.
    let mut termios: libc::termios2 = unsafe { std::mem::zeroed() };
    // SAFETY: TCGETS2 writes one `termios2` through the pointer, which points to a live value of that type.
    let result = unsafe {
        libc::ioctl(
            fd.as_raw_fd(),
            libc::TCGETS2,
            &mut termios as *mut libc::termios2,
        )
    };
    if result < 0 {
        Err(io::Error::last_os_error())
    } else {
        Ok(termios)
    }
}

/// Point a symlink at `target`, replacing whatever link is there (atomically, via a rename).
pub fn replace_symlink(link: &Path, target: &Path) -> io::Result<()> {
    let mut temporary = link.as_os_str().to_owned();
    temporary.push(format!(".{}.tmp", std::process::id()));
    let temporary = PathBuf::from(temporary);
    let _ = std::fs::remove_file(&temporary);
    std::os::unix::fs::symlink(target, &temporary)?;
    std::fs::rename(&temporary, link)
}

/// Remove the symlink at `link` if it still points at `target`.
pub fn remove_symlink_to(link: &Path, target: &Path) {
    if std::fs::read_link(link).is_ok_and(|points_to| points_to == target) {
        let _ = std::fs::remove_file(link);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs::OpenOptions;
    use std::os::unix::fs::OpenOptionsExt;

    /// Neither descriptor outlives an `exec`, and reading the master never blocks.
    #[test]
    fn both_descriptors_are_close_on_exec_and_the_master_never_blocks() {
        use nix::fcntl::{FcntlArg, FdFlag, fcntl};
        let pty = Pty::open(115_200).expect("pty");
        for fd in [pty.master.as_raw_fd(), pty.slave.as_raw_fd()] {
            let flags = FdFlag::from_bits_truncate(fcntl(fd, FcntlArg::F_GETFD).unwrap());
            assert!(flags.contains(FdFlag::FD_CLOEXEC), "{fd}: {flags:?}");
        }
        let status =
            OFlag::from_bits_truncate(fcntl(pty.master.as_raw_fd(), FcntlArg::F_GETFL).unwrap());
        assert!(status.contains(OFlag::O_NONBLOCK), "{status:?}");
    }

    #[test]
    fn the_slave_starts_at_the_bus_rate_and_follows_the_host() {
        let pty = Pty::open(57_600).expect("pty");
        assert_eq!(pty.host_baud(), Some(57_600));
        let host = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY)
            .open(pty.path())
            .expect("open slave");
        set_speed(host.as_fd(), 76_800).expect("set speed");
        assert_eq!(pty.host_baud(), Some(76_800));
    }

    #[test]
    fn bytes_cross_the_pty_unchanged_in_both_directions() {
        let mut pty = Pty::open(115_200).expect("pty");
        let mut host = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY)
            .open(pty.path())
            .expect("open slave");
        let all_bytes: Vec<u8> = (0..=255).collect();
        host.write_all(&all_bytes).expect("host write");
        let mut received = Vec::new();
        let mut buffer = [0u8; 512];
        for _ in 0..100 {
            match pty.read(&mut buffer) {
                Ok(n) => received.extend_from_slice(&buffer[..n]),
                Err(error) if error.kind() == io::ErrorKind::WouldBlock => {
                    if received.len() >= all_bytes.len() {
                        break;
                    }
                    std::thread::sleep(std::time::Duration::from_millis(2));
                }
                Err(error) => panic!("read: {error}"),
            }
        }
        assert_eq!(
            received, all_bytes,
            "raw mode must pass every byte (no echo, no CR/LF mapping)"
        );
        assert_eq!(pty.write(&all_bytes).expect("sim write"), 256);
        let mut back = vec![0u8; 256];
        host.read_exact(&mut back).expect("host read");
        assert_eq!(back, all_bytes);
    }
}

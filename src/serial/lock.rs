//! One program at a time on a serial port, and a refusal that says who has it.
//!
//! Two programs writing to one RS485 bus talk over each other, and each moves the servos to its
//! own goals: a second bridge started by hand beside the service, or a commissioning command run
//! while the service drives the bus. The serial port crate opens every port with an exclusive
//! advisory lock (`flock`, as picocom and minicom take; it holds for root too, where the
//! terminal's `TIOCEXCL` does not), and the bus keeps a shared one after it; either refuses a
//! second open. Its refusal says only "Unable to acquire exclusive lock": [`refused_on_open`]
//! turns it into [`PortInUse`], which names the port, the processes that hold it and what to do.

use std::fmt;
use std::path::{Path, PathBuf};

/// The port is held by another program.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PortInUse {
    pub path: PathBuf,
    /// The processes that have the port open, as `pid (name)`, when `/proc` tells.
    pub holders: Vec<String>,
}

impl fmt::Display for PortInUse {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} is in use by another program", self.path.display())?;
        if !self.holders.is_empty() {
            write!(f, " ({})", self.holders.join(", "))?;
        }
        write!(
            f,
            "; two programs on one bus would talk over each other. Stop the other one first \
             (the service: sudo systemctl stop lj9da-bridge)"
        )
    }
}

impl std::error::Error for PortInUse {}

/// The serial port crate's own refusal of `path` (it takes a `flock` on every open, shared or
/// exclusive), said as [`PortInUse`].
pub fn refused_on_open(path: &Path, e: &tokio_serial::Error) -> Option<PortInUse> {
    (e.kind() == tokio_serial::ErrorKind::NoDevice && e.description.contains("lock on serial port"))
        .then(|| PortInUse {
            path: path.to_path_buf(),
            holders: holders(path),
        })
}

/// The other processes with `path` open, from `/proc/*/fd`, as `pid (name)`.
fn holders(path: &Path) -> Vec<String> {
    let Ok(target) = path.canonicalize() else {
        return Vec::new();
    };
    let me = std::process::id();
    let Ok(procs) = std::fs::read_dir("/proc") else {
        return Vec::new();
    };
    let mut found = Vec::new();
    for entry in procs.flatten() {
        let Some(pid) = entry
            .file_name()
            .to_str()
            .and_then(|s| s.parse::<u32>().ok())
        else {
            continue;
        };
        if pid == me {
            continue;
        }
        let Ok(fds) = std::fs::read_dir(entry.path().join("fd")) else {
            continue;
        };
        if fds
            .flatten()
            .any(|fd| std::fs::read_link(fd.path()).is_ok_and(|l| l == target))
        {
            let name = std::fs::read_to_string(entry.path().join("comm")).unwrap_or_default();
            found.push(format!("pid {pid} ({})", name.trim()));
        }
    }
    found.sort();
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::fd::AsFd;

    fn open(path: &Path) -> Result<tokio_serial::SerialStream, tokio_serial::Error> {
        tokio_serial::SerialPortBuilderExt::open_native_async(tokio_serial::new(
            path.to_string_lossy(),
            115_200,
        ))
    }

    #[tokio::test]
    async fn a_second_open_of_a_port_is_refused_with_who_holds_it() {
        let pty = nix::pty::openpty(None, None).unwrap();
        let path = nix::unistd::ttyname(pty.slave.as_fd()).unwrap();
        let first = open(&path).expect("the first open");
        let e = open(&path).expect_err("a second open is refused");
        let refused = refused_on_open(&path, &e).expect("said as in use");
        assert_eq!(refused.path, path);
        let said = refused.to_string();
        assert!(said.contains("in use by another program"), "{said}");
        assert!(said.contains("systemctl stop lj9da-bridge"), "{said}");
        // Another error is not "in use".
        let missing = open(Path::new("/dev/lj9da-no-such-port")).expect_err("no such port");
        assert_eq!(
            refused_on_open(Path::new("/dev/lj9da-no-such-port"), &missing),
            None
        );
        drop(first);
        open(&path).expect("free once the holder closed it");
    }
}

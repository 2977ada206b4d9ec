//! The commissioning tools' `--rs485`: a port that refuses RS485 mode is refused before a byte
//! is written (exit 2), with what to check.

use nix::fcntl::{FcntlArg, OFlag, fcntl};
use nix::pty::openpty;
use std::io::Read;
use std::os::fd::AsRawFd;
use std::process::{Command, Stdio};

#[test]
fn a_port_without_rs485_mode_is_refused_and_left_untouched() {
    let pty = openpty(None, None).expect("a pseudo-terminal");
    let path = nix::unistd::ttyname(&pty.slave).expect("its name");
    let out = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["scan", "--ids", "1-3", "--rs485", "--port"])
        .arg(&path)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .output()
        .expect("the binary runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    for part in [
        &*path.to_string_lossy(),
        "refuses RS485 mode",
        "ENOTTY",
        "linux,rs485-enabled-at-boot-time",
        "remove --rs485 from the command",
    ] {
        assert!(stderr.contains(part), "{part:?} not in {stderr}");
    }
    let flags = fcntl(pty.master.as_raw_fd(), FcntlArg::F_GETFL).unwrap();
    fcntl(
        pty.master.as_raw_fd(),
        FcntlArg::F_SETFL(OFlag::from_bits_retain(flags) | OFlag::O_NONBLOCK),
    )
    .unwrap();
    let mut master = std::fs::File::from(pty.master);
    let mut buf = [0u8; 64];
    match master.read(&mut buf) {
        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
        other => panic!("a ping reached the port: {other:?}"),
    }
}

#[test]
fn a_misspelt_mode_is_a_usage_error() {
    let out = Command::new(env!("CARGO_BIN_EXE_lj9da-bridge"))
        .args(["scan", "--port", "/dev/null", "--rs485=on-sned"])
        .output()
        .expect("the binary runs");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("`on-sned` is not part of an RS485 mode"),
        "{stderr}"
    );
}

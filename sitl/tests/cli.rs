//! The `lj9da-sim` binary: prints the device path, serves it, applies fault options, stops on SIGTERM.

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use common::{HostPort, read, request};
use lj9da_sim::ReturnPacket;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;

const BINARY: &str = env!("CARGO_BIN_EXE_lj9da-sim");

fn start(args: &[&str]) -> (Child, String) {
    let mut child = Command::new(BINARY)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("start lj9da-sim");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("first line");
    (child, line.trim().to_string())
}

fn stop(mut child: Child) {
    let pid = Pid::from_raw(i32::try_from(child.id()).expect("pid"));
    kill(pid, Signal::SIGTERM).expect("SIGTERM");
    let status = child.wait().expect("wait");
    assert!(status.success(), "exit status {status}");
}

#[test]
fn it_prints_the_pty_path_serves_it_and_stops_on_sigterm() {
    let (child, path) = start(&["--ids", "1,2,3,4", "--baud", "115200", "--pty"]);
    assert!(path.starts_with("/dev/"), "{path}");
    let mut port = HostPort::open(&PathBuf::from(&path), 115_200);
    for id in 1..=4 {
        port.send(&request(id, 0x09));
        let reply = port.receive_bytes(26, Duration::from_secs(2));
        assert_eq!(
            ReturnPacket::parse(&reply).map(|(reply, _)| reply.id),
            Some(id)
        );
    }
    stop(child);
}

#[test]
fn fault_options_are_applied() {
    let (child, path) = start(&[
        "--ids",
        "1,2",
        "--wrong-model",
        "1:0x7511",
        "--unplug",
        "2",
        "--echo",
    ]);
    let mut port = HostPort::open(&PathBuf::from(&path), 115_200);
    let packet = read(1, 0x00, 2);
    port.send(&packet);
    let answer = port.receive_bytes(packet.len() + 10, Duration::from_secs(2));
    assert_eq!(&answer[..packet.len()], packet.as_slice(), "echo first");
    let (reply, _) = ReturnPacket::parse(&answer[packet.len()..]).expect("reply");
    assert_eq!(reply.data, [0x11, 0x75]);
    let unplugged = request(2, 0x01);
    port.send(&unplugged);
    assert_eq!(
        port.receive_bytes(unplugged.len() + 1, Duration::from_millis(300)),
        unplugged,
        "only the echo"
    );
    stop(child);
}

#[test]
fn it_serves_tcp_and_prints_the_bound_address() {
    let (child, address) = start(&["--tcp", "127.0.0.1:0", "--ids", "7"]);
    let mut client =
        TcpStream::connect(&address).unwrap_or_else(|error| panic!("connect {address}: {error}"));
    client
        .set_read_timeout(Some(Duration::from_secs(2)))
        .expect("timeout");
    client.write_all(&request(7, 0x01)).expect("send");
    let mut ack = [0u8; 1];
    client.read_exact(&mut ack).expect("ack");
    assert_eq!(ack, [0x07]);
    stop(child);
}

#[test]
fn help_explains_every_fault_with_examples() {
    let output = Command::new(BINARY)
        .arg("--help")
        .output()
        .expect("run --help");
    assert!(output.status.success());
    let help = String::from_utf8_lossy(&output.stdout);
    for option in [
        "--ids",
        "--baud",
        "--pty",
        "--tcp",
        "--link",
        "--voltage",
        "--ambient",
        "--latency-us",
        "--seed",
        "--corrupt",
        "--drop",
        "--echo",
        "--stall",
        "--load",
        "--overheat",
        "--wrong-model",
        "--unplug",
        "--status-every",
        "Examples:",
    ] {
        assert!(help.contains(option), "--help does not mention {option}");
    }
}

#[test]
fn an_unsupported_baud_is_refused_with_the_allowed_rates() {
    let output = Command::new(BINARY)
        .args(["--baud", "921600"])
        .output()
        .expect("run");
    assert_eq!(output.status.code(), Some(2));
    let error = String::from_utf8_lossy(&output.stderr);
    assert!(
        error.contains("921600") && error.contains("460800"),
        "{error}"
    );
}

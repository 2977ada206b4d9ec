//! Helpers shared by the integration tests: a virtual-time driver for the bus model and a host end of a
//! real pty.

#![allow(dead_code)]

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::os::unix::fs::OpenOptionsExt;
use std::path::Path;
use std::time::{Duration, Instant};

use lj9da_sim::bus::TxByte;
use lj9da_sim::{BusEvent, BusModel, ReturnPacket, SimConfig};
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};

/// The bus model driven with virtual time: nothing sleeps.
pub struct VirtualBus {
    pub model: BusModel,
    pub now: Instant,
    pub host_baud: u32,
}

impl VirtualBus {
    pub fn new(config: SimConfig) -> Self {
        let now = Instant::now();
        let host_baud = config.baud;
        VirtualBus {
            model: BusModel::new(&config, now),
            now,
            host_baud,
        }
    }

    pub fn with_ids(ids: &[u8]) -> Self {
        Self::new(SimConfig {
            ids: ids.to_vec(),
            ..SimConfig::default()
        })
    }

    /// Let `duration` of virtual time pass; returns what reached the host meanwhile.
    pub fn wait(&mut self, duration: Duration) -> Vec<TxByte> {
        let end = self.now + duration;
        let mut received = Vec::new();
        // Step through every deadline so bytes are delivered at their own times.
        while let Some(deadline) = self.model.next_deadline() {
            if deadline > end {
                break;
            }
            let deadline = deadline.max(self.now);
            self.model.advance(deadline);
            received.extend(self.model.poll_transmit(deadline));
            self.now = deadline;
        }
        self.model.advance(end);
        received.extend(self.model.poll_transmit(end));
        self.now = end;
        received
    }

    /// The host writes `bytes` now.
    pub fn write(&mut self, bytes: &[u8]) {
        let baud = self.host_baud;
        self.model.receive(self.now, bytes, Some(baud));
    }

    /// Write `bytes` and collect what comes back within 50 ms.
    pub fn transact(&mut self, bytes: &[u8]) -> Vec<u8> {
        self.write(bytes);
        self.wait(Duration::from_millis(50))
            .iter()
            .map(|tx| tx.byte)
            .collect()
    }

    /// Write `bytes` and parse the one return packet that must come back.
    pub fn reply(&mut self, bytes: &[u8]) -> ReturnPacket {
        let answer = self.transact(bytes);
        let (packet, used) =
            ReturnPacket::parse(&answer).unwrap_or_else(|| panic!("no valid reply: {answer:02X?}"));
        assert_eq!(
            used,
            answer.len(),
            "extra bytes after the reply: {answer:02X?}"
        );
        packet
    }

    /// Registers 42–59 of servo `id`.
    pub fn status(&mut self, id: u8) -> ReturnPacket {
        self.reply(&request(id, 0x09))
    }

    pub fn events(&mut self) -> Vec<BusEvent> {
        self.model.drain_events()
    }
}

/// Bytes of a short write.
pub fn write(id: u8, address: u8, data: &[u8]) -> Vec<u8> {
    lj9da_sim::ShortPacket::write(id, address, data, 0).encode()
}

/// Bytes of a short write with a reply request.
pub fn write_reply(id: u8, address: u8, data: &[u8], reply_code: u8) -> Vec<u8> {
    lj9da_sim::ShortPacket::write(id, address, data, reply_code).encode()
}

/// Bytes of a request-only packet.
pub fn request(id: u8, reply_code: u8) -> Vec<u8> {
    lj9da_sim::ShortPacket::request(id, reply_code).encode()
}

/// Bytes of a reply-code-1111 read.
pub fn read(id: u8, address: u8, length: u8) -> Vec<u8> {
    lj9da_sim::ShortPacket::read(id, address, length).encode()
}

/// Goal position write (0.01 mm).
pub fn goal(id: u8, mm_centi: i16) -> Vec<u8> {
    write(id, 0x1E, &mm_centi.to_le_bytes())
}

/// Force enable write.
pub fn force(id: u8, value: u8) -> Vec<u8> {
    write(id, 0x24, &[value])
}

/// The host end of a pty: opened like a serial port, raw, at a bit rate.
pub struct HostPort {
    pub file: File,
}

impl HostPort {
    pub fn open(path: &Path, baud: u32) -> HostPort {
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
            .open(path)
            .unwrap_or_else(|error| panic!("open {}: {error}", path.display()));
        let mut termios = nix::sys::termios::tcgetattr(&file).expect("tcgetattr");
        nix::sys::termios::cfmakeraw(&mut termios);
        nix::sys::termios::tcsetattr(&file, nix::sys::termios::SetArg::TCSANOW, &termios)
            .expect("tcsetattr");
        let port = HostPort { file };
        port.set_baud(baud);
        port
    }

    pub fn set_baud(&self, baud: u32) {
        lj9da_sim::runtime::pty::set_speed(self.file.as_fd(), baud).expect("set speed");
    }

    pub fn send(&mut self, bytes: &[u8]) -> Instant {
        self.file.write_all(bytes).expect("host write");
        Instant::now()
    }

    /// Read until `count` bytes arrived or `timeout` passed; every chunk with the instant it was read.
    pub fn receive(&mut self, count: usize, timeout: Duration) -> Vec<(Instant, Vec<u8>)> {
        let end = Instant::now() + timeout;
        let mut chunks = Vec::new();
        let mut total = 0;
        let mut buffer = [0u8; 512];
        while total < count {
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                break;
            }
            let mut fds = [PollFd::new(self.file.as_fd(), PollFlags::POLLIN)];
            let millis = u16::try_from(left.as_millis().max(1)).unwrap_or(u16::MAX);
            let _ = poll(&mut fds, PollTimeout::from(millis));
            match self.file.read(&mut buffer) {
                Ok(0) => break,
                Ok(n) => {
                    chunks.push((Instant::now(), buffer[..n].to_vec()));
                    total += n;
                }
                Err(error) if error.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(_) => break,
            }
        }
        chunks
    }

    pub fn receive_bytes(&mut self, count: usize, timeout: Duration) -> Vec<u8> {
        self.receive(count, timeout)
            .into_iter()
            .flat_map(|(_, bytes)| bytes)
            .collect()
    }

    /// Drop whatever is waiting.
    pub fn drain(&mut self) {
        let _ = self.receive(usize::MAX, Duration::from_millis(20));
    }
}

//! One serial port to one RS485 bus, used one transaction at a time: send a packet, wait for
//! the reply it asks for (or for nothing), with a timeout computed from the wire time.
//!
//! The timeout of a transaction is the wire time of the request and of its reply at the port's
//! baud rate, plus the servo's Return Delay Time (learned from every reply that carries
//! register 7), plus a margin for the adapter and the operating system. Replies are decoded by
//! the protocol core's [`Decoder`], which skips echoes of our own packets and garbage; a reply
//! from another ID or for other registers is ignored, not taken for the one awaited.
//!
//! This file carries bytes and time only: what to send and what a reply means is decided by
//! the subcommand modules. Reads are retried (they change nothing); writes are sent once unless
//! the caller asks for an acknowledged, retried write.

use crate::protocol::packet::ExpectedReply;
use crate::protocol::registers::addr;
use crate::protocol::{
    BaudRate, Decoded, Decoder, Expect, ReplyRequest, ReturnPacket, ServoId, ShortPacket,
};
use crate::serial::rs485::Rs485Mode;
use std::collections::HashMap;
use std::fmt::Write as _;
use std::os::fd::{AsRawFd, BorrowedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;
use thiserror::Error;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::Instant;
use tokio_serial::{
    ClearBuffer, DataBits, FlowControl, Parity, SerialPort, SerialPortBuilderExt, SerialStream,
    StopBits,
};

/// What can go wrong on the link itself. Refusals of values never get here: they are stopped
/// by the protocol core before a packet exists.
#[derive(Debug, Error)]
pub enum LinkError {
    #[error(
        "cannot open {path} at {baud}: {source} (is the adapter plugged in, the path right, and no other program using the port?)"
    )]
    Open {
        path: PathBuf,
        baud: BaudRate,
        source: tokio_serial::Error,
    },
    #[error(transparent)]
    InUse(#[from] crate::serial::lock::PortInUse),
    #[error(
        "{path} cannot be used: {source}; {advice}",
        path = path.display(),
        advice = crate::serial::rs485::refusal_advice(path, "--rs485 from the command")
    )]
    Rs485 {
        path: PathBuf,
        source: crate::serial::rs485::Rs485Error,
    },
    #[error("serial port {path} failed: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("serial port {path} was closed (adapter unplugged?)")]
    Closed { path: PathBuf },
    #[error(
        "servo {id} did not answer within {timeout_ms:.1} ms at {baud} ({attempts} attempt{s}): sent {sent}, expected {expected}",
        timeout_ms = timeout.as_secs_f64() * 1000.0,
        s = if *attempts == 1 { "" } else { "s" }
    )]
    Timeout {
        id: u8,
        sent: String,
        expected: String,
        timeout: Duration,
        baud: BaudRate,
        attempts: u32,
    },
}

/// What came back for a packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reply {
    /// The packet asked for no reply (it was sent and its wire time has passed).
    None,
    /// The single ACK byte `07h`.
    Ack,
    /// The return packet asked for, from the addressed servo, for the registers asked for.
    Packet(ReturnPacket),
}

/// A serial port to one bus; see the module docs.
#[derive(Debug)]
pub struct Link {
    /// `None` only between closing and reopening the port (or after a reopen failed).
    port: Option<SerialStream>,
    path: PathBuf,
    baud: BaudRate,
    decoder: Decoder,
    margin: Duration,
    retries: u32,
    return_delays: HashMap<u8, Duration>,
    /// The kernel's RS485 mode set each time the port is opened; `None`: left as it is.
    rs485: Option<Rs485Mode>,
}

/// Bytes as `FA AF 01 …` for messages.
pub fn hex(bytes: &[u8]) -> String {
    let mut out = String::with_capacity(bytes.len() * 3);
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            out.push(' ');
        }
        let _ = write!(out, "{b:02X}");
    }
    out
}

fn describe_expected(expected: ExpectedReply) -> String {
    match expected {
        ExpectedReply::Nothing => "no reply".into(),
        ExpectedReply::Ack => "an ACK (07h)".into(),
        ExpectedReply::Registers { address, length } => {
            let last = usize::from(address) + usize::from(length).max(1) - 1;
            format!("registers {address}–{last}")
        }
    }
}

/// How long the old rate stays in force after the last packet written at it (see
/// [`Link::reopen`]).
pub const REOPEN_SETTLE: Duration = Duration::from_millis(25);

impl Link {
    /// Margin added to the computed wire time of ordinary transactions.
    pub const DEFAULT_MARGIN: Duration = Duration::from_millis(50);
    /// Margin for the ACK pings of a scan: tight, so that 127 IDs take little more than 1.5 s.
    pub const SCAN_MARGIN: Duration = Duration::from_millis(12);
    /// Extra attempts of a read that timed out.
    pub const DEFAULT_RETRIES: u32 = 2;
    /// No transaction waits longer than this, whatever the margin.
    pub const MAX_TIMEOUT: Duration = Duration::from_secs(60);

    /// Open `path` at `baud`, 8N1, no flow control, for exclusive use. Call it inside a tokio
    /// runtime.
    pub async fn open(path: impl AsRef<Path>, baud: BaudRate) -> Result<Link, LinkError> {
        Self::open_rs485(path, baud, None).await
    }

    /// [`Link::open`], with the port put in the kernel's RS485 mode `rs485` (a UART whose
    /// transceiver's driver enable is on RTS) each time it is opened.
    pub async fn open_rs485(
        path: impl AsRef<Path>,
        baud: BaudRate,
        rs485: Option<Rs485Mode>,
    ) -> Result<Link, LinkError> {
        let path = path.as_ref().to_path_buf();
        let port = open_port(&path, baud, rs485)?;
        Ok(Link {
            port: Some(port),
            path,
            baud,
            decoder: Decoder::new(),
            margin: Self::DEFAULT_MARGIN,
            retries: Self::DEFAULT_RETRIES,
            return_delays: HashMap::new(),
            rs485,
        })
    }

    /// Close the port and open it again at `baud` (after the servo was told to change rate),
    /// [`REOPEN_SETTLE`] after the last write.
    pub async fn reopen(&mut self, baud: BaudRate) -> Result<(), LinkError> {
        if baud == self.baud && self.port.is_some() {
            return Ok(());
        }
        // The last packet must leave the adapter at the old rate before the rate changes: a
        // USB adapter may hold bytes for its latency timer (16 ms by default) after the kernel
        // let them go, and a pseudo-terminal's reader may take as long to see them. The port
        // is exclusive, so the old one is closed before the new one is opened.
        if let Some(mut old) = self.port.take() {
            let _ = old.flush().await;
            tokio::time::sleep(REOPEN_SETTLE).await;
            drop(old);
        }
        self.decoder.clear();
        self.port = Some(open_port(&self.path, baud, self.rs485)?);
        self.baud = baud;
        Ok(())
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn baud(&self) -> BaudRate {
        self.baud
    }

    pub fn margin(&self) -> Duration {
        self.margin
    }

    /// Set the margin added to every computed timeout.
    pub fn set_margin(&mut self, margin: Duration) {
        self.margin = margin;
    }

    pub fn retries(&self) -> u32 {
        self.retries
    }

    /// Set how many times a read that timed out is tried again.
    pub fn set_retries(&mut self, retries: u32) {
        self.retries = retries;
    }

    /// The Return Delay Time assumed for servo `id`: the one it last reported, or else the
    /// largest any servo reported, or else 0.
    pub fn return_delay(&self, id: u8) -> Duration {
        self.return_delays
            .get(&id)
            .copied()
            .or_else(|| self.return_delays.values().max().copied())
            .unwrap_or_default()
    }

    /// Tell the link what Return Delay Time servo `id` has (e.g. after writing register 7).
    pub fn learn_return_delay(&mut self, id: u8, delay: Duration) {
        self.return_delays.insert(id, delay);
    }

    /// Forget what was learned about servo `id` (e.g. after its ID changed).
    pub fn forget(&mut self, id: u8) {
        self.return_delays.remove(&id);
    }

    /// How long to wait for the reply to `packet`: wire time of request and reply, the
    /// servo's return delay, and the margin.
    pub fn timeout_for(&self, packet: &ShortPacket) -> Duration {
        let wire_ns = self.baud.wire_time_ns(packet.wire_len())
            + self.baud.wire_time_ns(packet.expected_reply().wire_len());
        (Duration::from_nanos(wire_ns) + self.return_delay(packet.id_byte()))
            .saturating_add(self.margin)
            .min(Self::MAX_TIMEOUT)
    }

    /// Send `packet` once and wait for the reply it asks for. A packet that asks for nothing
    /// returns [`Reply::None`] once its wire time has passed.
    pub async fn exchange(&mut self, packet: &ShortPacket) -> Result<Reply, LinkError> {
        self.exchange_attempts(packet, 1).await
    }

    /// Like [`Link::exchange`], tried up to `1 + retries` times while it times out. Only for
    /// packets that may safely arrive twice (reads, and writes of a fixed value).
    pub async fn transact(&mut self, packet: &ShortPacket) -> Result<Reply, LinkError> {
        self.exchange_attempts(packet, 1 + self.retries).await
    }

    async fn exchange_attempts(
        &mut self,
        packet: &ShortPacket,
        attempts: u32,
    ) -> Result<Reply, LinkError> {
        let attempts = attempts.max(1);
        let mut tried = 0;
        loop {
            tried += 1;
            match self.exchange_once(packet).await {
                Err(LinkError::Timeout {
                    id,
                    sent,
                    expected,
                    timeout,
                    baud,
                    ..
                }) => {
                    if tried >= attempts {
                        return Err(LinkError::Timeout {
                            id,
                            sent,
                            expected,
                            timeout,
                            baud,
                            attempts: tried,
                        });
                    }
                    tracing::debug!(id, tried, "no reply, trying again");
                }
                other => return other,
            }
        }
    }

    /// Send a packet that asks for no reply and wait for its wire time.
    pub async fn send(&mut self, packet: &ShortPacket) -> Result<(), LinkError> {
        self.exchange_once(packet).await.map(drop)
    }

    /// Whether servo `id` answers an ACK ping (one attempt).
    pub async fn ping(&mut self, id: ServoId) -> Result<bool, LinkError> {
        match self
            .exchange_once(&ShortPacket::request(id, ReplyRequest::Ack))
            .await
        {
            Ok(_) => Ok(true),
            Err(LinkError::Timeout { .. }) => Ok(false),
            Err(e) => Err(e),
        }
    }

    /// Ping servo `id` until it answers or `within` has passed (e.g. while it reboots).
    pub async fn wait_for(&mut self, id: ServoId, within: Duration) -> Result<bool, LinkError> {
        let deadline = Instant::now() + within;
        loop {
            if self.ping(id).await? {
                return Ok(true);
            }
            if Instant::now() >= deadline {
                return Ok(false);
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// Read one of the fixed register blocks of servo `id` (retried).
    pub async fn read(
        &mut self,
        id: ServoId,
        request: ReplyRequest,
    ) -> Result<ReturnPacket, LinkError> {
        self.read_packet(&ShortPacket::request(id, request)).await
    }

    /// Read registers 0–29 and 30–59 of servo `id`: the whole memory map, and the flags of the
    /// second reply.
    pub async fn read_all(
        &mut self,
        id: ServoId,
    ) -> Result<(crate::protocol::MemoryMap, crate::protocol::ReplyFlags), LinkError> {
        let mut map = crate::protocol::MemoryMap::default();
        let low = self.read(id, ReplyRequest::Registers0To29).await?;
        map.store(low.address, &low.data);
        let high = self.read(id, ReplyRequest::Registers30To59).await?;
        map.store(high.address, &high.data);
        Ok((map, high.flags))
    }

    async fn read_packet(&mut self, packet: &ShortPacket) -> Result<ReturnPacket, LinkError> {
        match self.transact(packet).await? {
            Reply::Packet(p) => Ok(p),
            // `exchange_once` only returns what the packet asked for; a read asks for a packet.
            Reply::Ack | Reply::None => Err(LinkError::Timeout {
                id: packet.id_byte(),
                sent: hex(&packet.to_bytes()),
                expected: describe_expected(packet.expected_reply()),
                timeout: self.timeout_for(packet),
                baud: self.baud,
                attempts: 1,
            }),
        }
    }

    async fn exchange_once(&mut self, packet: &ShortPacket) -> Result<Reply, LinkError> {
        let expected = packet.expected_reply();
        let bytes = packet.to_bytes();
        self.discard_input();
        self.decoder.clear();
        self.decoder.expect(if expected == ExpectedReply::Ack {
            Expect::Ack
        } else {
            Expect::Packet
        });
        tracing::trace!(sent = %hex(&bytes), "tx");
        self.write_all(&bytes).await?;
        if expected == ExpectedReply::Nothing {
            let wire = Duration::from_nanos(self.baud.wire_time_ns(bytes.len()));
            tokio::time::sleep(wire + Duration::from_millis(1)).await;
            return Ok(Reply::None);
        }
        let timeout = self.timeout_for(packet);
        let deadline = Instant::now() + timeout;
        let id = packet.id_byte();
        let mut buf = [0u8; 256];
        let mut timed_out = false;
        loop {
            while let Some(item) = self.decoder.poll() {
                match item {
                    Ok(Decoded::Ack) if expected == ExpectedReply::Ack => return Ok(Reply::Ack),
                    Ok(Decoded::Reply(reply)) => {
                        if let ExpectedReply::Registers { address, length } = expected
                            && reply.id == id
                            && reply.address == address
                            && reply.data.len() == usize::from(length)
                        {
                            self.learn_from(&reply);
                            return Ok(Reply::Packet(reply));
                        }
                        tracing::debug!(
                            from = reply.id,
                            address = reply.address,
                            len = reply.data.len(),
                            "reply that was not the one awaited, ignored"
                        );
                    }
                    Ok(Decoded::Ack) | Ok(Decoded::Echo { .. }) => {}
                    Err(e) => tracing::debug!(id, "rx: {e}"),
                }
            }
            if timed_out {
                return Err(LinkError::Timeout {
                    id,
                    sent: hex(&bytes),
                    expected: describe_expected(expected),
                    timeout,
                    baud: self.baud,
                    attempts: 1,
                });
            }
            let port = self.port.as_mut().ok_or_else(|| LinkError::Closed {
                path: self.path.clone(),
            })?;
            match tokio::time::timeout_at(deadline, port.read(&mut buf)).await {
                Err(_) => {
                    // A complete reply may still hide inside an abandoned partial one.
                    self.decoder.abandon_partial();
                    timed_out = true;
                }
                Ok(Ok(0)) => {
                    return Err(LinkError::Closed {
                        path: self.path.clone(),
                    });
                }
                Ok(Ok(n)) => {
                    tracing::trace!(received = %hex(&buf[..n]), "rx");
                    self.decoder.push(&buf[..n]);
                }
                Ok(Err(source)) => {
                    return Err(LinkError::Io {
                        path: self.path.clone(),
                        source,
                    });
                }
            }
        }
    }

    fn learn_from(&mut self, reply: &ReturnPacket) {
        let start = usize::from(reply.address);
        let delay_reg = usize::from(addr::RETURN_DELAY);
        if (start..start + reply.data.len()).contains(&delay_reg)
            && let Some(&ms) = reply.data.get(delay_reg - start)
        {
            self.return_delays
                .insert(reply.id, Duration::from_millis(u64::from(ms)));
        }
    }

    async fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        let path = &self.path;
        let port = self
            .port
            .as_mut()
            .ok_or_else(|| LinkError::Closed { path: path.clone() })?;
        let io = |source| LinkError::Io {
            path: path.clone(),
            source,
        };
        port.write_all(bytes).await.map_err(io)?;
        port.flush().await.map_err(io)
    }

    /// Drop whatever arrived before this transaction (late replies, noise).
    fn discard_input(&mut self) {
        let Some(port) = self.port.as_mut() else {
            return;
        };
        let _ = port.clear(ClearBuffer::Input);
        let mut buf = [0u8; 256];
        while let Ok(n) = port.try_read(&mut buf) {
            if n == 0 {
                break;
            }
        }
    }
}

fn open_port(
    path: &Path,
    baud: BaudRate,
    rs485: Option<Rs485Mode>,
) -> Result<SerialStream, LinkError> {
    let port = tokio_serial::new(path.to_string_lossy(), baud.bits_per_second())
        .data_bits(DataBits::Eight)
        .parity(Parity::None)
        .stop_bits(StopBits::One)
        .flow_control(FlowControl::None)
        .open_native_async()
        .map_err(
            |source| match crate::serial::lock::refused_on_open(path, &source) {
                Some(in_use) => LinkError::InUse(in_use),
                None => LinkError::Open {
                    path: path.to_path_buf(),
                    baud,
                    source,
                },
            },
        )?;
    if let Some(mode) = rs485 {
        // SAFETY: the descriptor belongs to `port`, which outlives the borrow.
        let fd = unsafe { BorrowedFd::borrow_raw(port.as_raw_fd()) };
        let granted = crate::serial::rs485::set(fd, mode).map_err(|source| LinkError::Rs485 {
            path: path.to_path_buf(),
            source,
        })?;
        if let Some(d) = granted.difference() {
            tracing::warn!(port = %path.display(), "RS485 mode: the driver changed it: {d}");
        }
    }
    Ok(port)
}

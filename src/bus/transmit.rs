//! The bytes the bus master wants written next, and why.

use crate::protocol::ServoId;
use std::time::Duration;

/// Why a packet is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TxKind {
    /// A long packet with the goals of every commanded servo (no reply).
    Command,
    /// A telemetry poll (reply code 09: registers 42–59).
    Poll(ServoId),
    /// A position-and-current read (registers 42–49), the poll between two full ones.
    MotionPoll(ServoId),
    /// A position-only read (registers 42–43), in bus time too short for any other poll.
    PositionPoll(ServoId),
    /// A start-up read: registers 0–29 (identity, limits) or 30–41 (force, goal, max force).
    Init(ServoId),
    /// A force-enable write, answered with registers 30–41 to confirm it.
    Force(ServoId),
    /// A periodic read-back of registers 30–41 (force state and goal register).
    Verify(ServoId),
    /// A probe of an offline servo (registers 0–29).
    Probe(ServoId),
    /// A packet sent at shutdown (no reply).
    Final(Option<ServoId>),
}

/// One packet to write to the port now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transmit {
    pub bytes: Vec<u8>,
    pub kind: TxKind,
    /// Whether the bus master now waits for a reply (and transmits nothing until it arrives or
    /// times out).
    pub expects_reply: bool,
    /// Time the bytes take on the wire at the bus speed.
    pub wire_time: Duration,
}

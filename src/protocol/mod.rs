//! The LJ9DA41 RS485 command protocol, as pure data: packets, the memory map and a
//! streaming reply decoder.
//!
//! This module is sans-IO. It never touches a port, never reads a clock and never panics on
//! any input: every function takes bytes or values and returns bytes, values or an error. The
//! bus master and the commissioning tools build on it; the tests in this folder check it
//! against the vectors of the protocol reference (`shared/spec/lj9da41-protocol.md`, section 5).
//!
//! Layout, one idea per file:
//! - [`units`]: physical quantities in the servo's own register units (`MmCenti`, `Ms10`, …).
//! - [`id`]: servo IDs (1–127) and the broadcast destination (255).
//! - [`baud`]: the baud-rate table of register 6.
//! - [`registers`]: the memory map, its access rules and the write validation.
//! - [`packet`]: encoding of every host → servo packet (short, special, long).
//! - [`reply`]: return packets, reply flags and the decoded telemetry block (registers 42–59).
//! - [`decoder`]: the streaming decoder for the bytes that come back from the bus.
//! - [`error`]: what can go wrong, each error saying what was expected and what arrived.

pub mod baud;
pub mod checksum;
pub mod decoder;
pub mod error;
pub mod id;
pub mod packet;
pub mod registers;
pub mod reply;
pub mod units;

#[cfg(test)]
mod vectors;

pub use baud::BaudRate;
pub use decoder::{Decoded, Decoder, Expect};
pub use error::{DecodeError, ProtocolError};
pub use id::{Destination, ServoId};
pub use packet::{GoalEntry, LongPacket, ReplyRequest, ShortPacket};
pub use registers::{Access, ForceMode, MemoryMap, Register};
pub use reply::{Motion, ReplyFlags, ReturnPacket, Telemetry};
pub use units::{Celsius, Ma10, MmCenti, Ms10, Mv10, Percent, PositionLimits, Punch};

/// First header byte of every host → servo packet.
pub const COMMAND_HEADER: [u8; 2] = [0xFA, 0xAF];
/// Header of every servo → host return packet.
pub const RETURN_HEADER: [u8; 2] = [0xFD, 0xDF];
/// The single byte a servo sends when asked for an ACK (flag bits 0001).
pub const ACK_BYTE: u8 = 0x07;
/// Model number of the LJ9DA41 (registers 0–1).
pub const LJ9DA41_MODEL_NUMBER: u16 = 0x7510;
/// Number of registers in the memory map (0x00–0x3B).
pub const MEMORY_MAP_LEN: usize = 60;

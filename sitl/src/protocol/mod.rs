//! The simulator's own reading of the LJ9DA41 wire format (protocol spec, section 4).
//!
//! This is an independent implementation of the maker's manual: it shares no code with the bridge's
//! protocol core, so that each cross-checks the other. Everything here is pure: bytes in, values out,
//! no I/O and no clock.

pub mod checksum;
pub mod frame_decoder;
pub mod host_packet;
pub mod return_packet;

/// First two bytes of every packet the host sends (short and long packets).
pub const HOST_HEADER: [u8; 2] = [0xFA, 0xAF];
/// First two bytes of every return packet a servo sends.
pub const RETURN_HEADER: [u8; 2] = [0xFD, 0xDF];
/// Short-packet ID addressing every servo on the bus; nobody ever replies to it.
pub const BROADCAST_ID: u8 = 255;
/// The whole ACK "packet": a single raw byte, no header, no sum (manual, "ACK パケット").
pub const ACK_BYTE: u8 = 0x07;

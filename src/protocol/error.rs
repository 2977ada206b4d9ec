//! Errors of the protocol core. Validation errors ([`ProtocolError`]) stop a dangerous or
//! malformed packet before it is built; decode errors ([`DecodeError`]) describe bytes from the
//! bus that are not a valid reply. Each says what was expected and what was found.

use thiserror::Error;

/// A value or packet refused before anything is written to the bus.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum ProtocolError {
    #[error("servo id {id} is outside 1–127 (255 is only for broadcast packets)")]
    InvalidId { id: u8 },
    #[error(
        "baud-rate code 0x{code:02X} is not in the servo's table (0x00–0x0A); writing it can make the servo unreachable"
    )]
    UnknownBaudCode { code: u8 },
    #[error(
        "{bps} bit/s is not a rate the LJ9DA41 supports (9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200, 153600, 230400, 460800)"
    )]
    UnsupportedBaud { bps: u32 },
    #[error("position {mm:.2} mm is beyond the stroke (−25.00 … +25.00 mm)")]
    PositionOutOfStroke { mm: f64 },
    #[error(
        "{which} position limit {mm:.2} mm is outside {allowed}; a limit beyond ±25.00 mm can break the servo"
    )]
    LimitOutOfRange {
        which: &'static str,
        mm: f64,
        allowed: &'static str,
    },
    #[error("max force {percent} % is above 100 %")]
    MaxForceOutOfRange { percent: u8 },
    #[error("punch 0x{raw:04X} is above 0x7FFF (68.2 % of the maximum current)")]
    PunchOutOfRange { raw: u16 },
    #[error("force-enable value 0x{value:02X} is not 00h (off), 01h (on) or 02h (brake)")]
    InvalidForceMode { value: u8 },
    #[error("reverse value 0x{value:02X} is not 00h (normal) or 01h (reversed)")]
    InvalidReverse { value: u8 },
    #[error("register {address} ({name}) is read only")]
    ReadOnlyRegister { address: u8, name: &'static str },
    #[error("register {address} is reserved; nothing may be written there")]
    ReservedRegister { address: u8 },
    #[error(
        "a write starting at register {start} with {len} bytes covers only one byte of the two-byte register {address} ({name})"
    )]
    SplitRegister {
        start: u8,
        len: usize,
        address: u8,
        name: &'static str,
    },
    #[error("registers {start}…{end} are outside the memory map (0–59)")]
    OutsideMap { start: usize, end: usize },
    #[error("a write needs at least one data byte")]
    EmptyWrite,
    #[error("{len} data bytes do not fit one packet (at most 255)")]
    WriteTooLong { len: usize },
    #[error("a long packet needs at least one servo")]
    EmptyLongPacket,
    #[error("a long packet carries {count} servos; at most 255 fit")]
    LongPacketTooManyServos { count: usize },
    #[error(
        "every servo of a long packet takes the same data length: servo {id} has {got} bytes, the first has {expected}"
    )]
    LongPacketUnequalData { id: u8, expected: usize, got: usize },
    #[error("servo {id} appears twice in one long packet")]
    LongPacketDuplicateId { id: u8 },
    #[error("a read of {len} bytes from register {address} is outside the memory map (0–59)")]
    ReadOutsideMap { address: u8, len: u8 },
}

/// Bytes from the bus that are not a valid reply. The decoder reports each and carries on.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum DecodeError {
    #[error("bad checksum: computed 0x{computed:02X}, packet says 0x{received:02X}")]
    BadChecksum { computed: u8, received: u8 },
    /// A whole return packet (its header and length read, all its bytes in) whose sum is
    /// wrong: a servo answered, garbled.
    #[error(
        "return packet from ID {id} (registers {address}, {length} bytes) has a bad checksum: computed 0x{computed:02X}, packet says 0x{received:02X}"
    )]
    ReplyBadChecksum {
        id: u8,
        address: u8,
        length: u8,
        computed: u8,
        received: u8,
    },
    #[error("skipped {skipped} bytes that start no packet (expected a header FD DF{ack})", ack = if *.expecting_ack { " or the ACK byte 07h" } else { "" })]
    Garbage { skipped: usize, expecting_ack: bool },
    #[error("return packet has Count {count}, expected 1")]
    BadCount { count: u8 },
    #[error("return packet claims registers {address}…{end}, beyond the memory map (0–59)", end = usize::from(*.address) + usize::from(*.length))]
    OutsideMap { address: u8, length: u8 },
    #[error("echoed command packet is malformed: {reason}")]
    BadEcho { reason: &'static str },
    #[error("expected {expected} data bytes from register {address}, got {got}")]
    WrongLength {
        address: u8,
        expected: usize,
        got: usize,
    },
    #[error("expected a reply from register {expected}, got one from register {got}")]
    WrongAddress { expected: u8, got: u8 },
}

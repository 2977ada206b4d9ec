//! What the simulated bus reports: events (one per host packet, bad sum, garbage run, reply, collision,
//! damage, ignored packet) and running counters.

use std::time::Instant;

use crate::protocol::host_packet::HostPacket;

/// Something that happened on the simulated bus.
#[derive(Debug, Clone, PartialEq)]
pub enum BusEvent {
    /// A host packet with a good sum.
    Packet(PacketEvent),
    /// A candidate frame whose sum was wrong (the servos ignored it).
    BadSum { at: Instant, bytes: Vec<u8> },
    /// Bytes that could not start a packet.
    Garbage { at: Instant, bytes: Vec<u8> },
    /// A servo put a reply on the wire (`first_byte_at` = when its first byte is complete).
    Reply(ReplyEvent),
    /// A reply the "drop replies" fault swallowed.
    ReplyDropped { at: Instant, id: u8 },
    /// Two talkers on the half-duplex line at once: the host and a replying servo, or two servos.
    Collision { at: Instant, id: u8 },
    /// A write the manual forbids; a real servo might have been damaged.
    Damage(DamageEvent),
    /// The simulator's thread handed bytes to the host later than their wire instants (it did not run
    /// in time): until `at` the host saw a slower line than the model's. `due` is when the last byte
    /// of the write was complete on the modelled wire.
    HandedLate {
        due: Instant,
        at: Instant,
        bytes: usize,
    },
    /// A servo that was addressed did not act on (part of) a packet.
    Ignored {
        at: Instant,
        id: u8,
        reason: IgnoreReason,
    },
}

/// One host packet as the line saw it.
#[derive(Debug, Clone, PartialEq)]
pub struct PacketEvent {
    /// When the simulator's `read()` returned the chunk holding the packet's first byte (taken before
    /// any processing: this is the "first byte on the serial device" instant).
    pub first_byte_at: Instant,
    /// When the packet's last byte had fully arrived at wire speed.
    pub completed_at: Instant,
    /// The host's bit rate while sending the packet (`None` if it changed within the packet).
    pub host_baud: Option<u32>,
    /// The packet's bytes, header and sum included.
    pub bytes: Vec<u8>,
    pub packet: HostPacket,
    /// IDs (as they were before the packet) of the servos that acted on it.
    pub acted: Vec<u8>,
    /// Whether a reply was on the wire while the packet was sent (then no servo understood it).
    pub collided: bool,
}

/// One reply put on the wire.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplyEvent {
    pub id: u8,
    /// When the first byte is complete on the wire.
    pub first_byte_at: Instant,
    /// When the last byte is complete on the wire.
    pub last_byte_at: Instant,
    /// The bytes as sent (after any injected corruption or baud garbling).
    pub bytes: Vec<u8>,
    /// The "corrupt replies" fault changed a byte.
    pub corrupted: bool,
    /// The servo's bit rate differs from the host's: the host receives noise.
    pub baud_mismatch: bool,
}

/// A forbidden write, observable so that a bridge's tests can assert it never causes one.
#[derive(Debug, Clone, PartialEq)]
pub struct DamageEvent {
    pub at: Instant,
    /// The servo's ID when the event happened.
    pub id: u8,
    pub kind: DamageKind,
}

/// What the manual forbids and the simulator records.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DamageKind {
    /// A position limit beyond the stroke: Plus outside 0…+2500 or Minus outside −2500…0 (0.01 mm).
    PositionLimitBeyondStroke { register: u8, value_mm_centi: i16 },
    /// A Baud Rate code outside the table (00h–0Ah): the servo can no longer talk.
    UnknownBaudCode(u8),
    /// A Servo ID outside 1–127.
    ForbiddenId(u8),
    /// Power removed while a flash write was under way (the flash keeps its old values and the flash-write
    /// error flag is set).
    PowerLostDuringFlashWrite,
}

/// Why an addressed servo did not act on a packet or on its reply request.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IgnoreReason {
    /// A flash write is under way.
    FlashWriteBusy,
    /// The servo is still starting up after a reboot or power-on.
    Booting,
    /// More than one of flag bits 6, 5, 4 (flash write, reboot, factory reset) set.
    CombinedSpecialFlags,
    /// A special flag with the wrong Address, Length or Count.
    MalformedSpecial,
    /// A short packet with Count above 1.
    CountAboveOne,
    /// Flag bits 3–0 hold a code the reply table does not define.
    UnknownReplyCode(u8),
    /// Reply code 1111 for registers outside 0–59 (or zero bytes).
    ReadOutOfMap { address: u8, length: u8 },
}

/// Running counters of one bus.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BusStats {
    /// Host packets with a good sum.
    pub packets_rx: u64,
    /// Bytes read from the host.
    pub bytes_rx: u64,
    /// Bytes written to the host (replies, echo, noise).
    pub bytes_tx: u64,
    /// Replies put on the wire.
    pub replies_tx: u64,
    /// Candidate frames with a bad sum.
    pub bad_sums: u64,
    /// Bytes that could not start a packet.
    pub garbage_bytes: u64,
    /// Collisions on the half-duplex line.
    pub collisions: u64,
    /// Replies swallowed by the "drop replies" fault.
    pub replies_dropped: u64,
    /// Replies changed by the "corrupt replies" fault.
    pub replies_corrupted: u64,
    /// Packets a powered servo could not understand because its bit rate differs from the host's.
    pub baud_mismatches: u64,
    /// Forbidden writes.
    pub damage_events: u64,
    /// Bytes echoed back by an echoing adapter.
    pub echo_bytes: u64,
    /// Packets (or reply requests) an addressed servo ignored.
    pub ignored: u64,
    /// Writes toward the host that left more than [`crate::runtime::LATE_REPORT`] after their last
    /// byte was due (the simulator's thread did not run in time).
    pub handed_late: u64,
}

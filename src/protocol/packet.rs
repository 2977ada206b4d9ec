//! Encoding of every host → servo packet the manual defines.
//!
//! ```text
//! short: FA AF | ID | Flag | Address | Length | Count | Data[Length] | Sum
//! long:  FA AF | 00 | 00   | Address | Length | Count | (VID, Data[Length−1]) × Count | Sum
//! ```
//! `Sum` is the XOR of every byte from `ID` through the last data byte. Every constructor
//! validates its input, so a packet that exists is a packet that is safe to send.

use super::checksum::xor_sum;
use super::error::ProtocolError;
use super::id::{Destination, ServoId};
use super::registers::{ForceMode, addr, validate_read, validate_write};
use super::units::{MmCenti, Ms10, Percent, PositionLimits, Punch};
use super::{BaudRate, COMMAND_HEADER};

/// Flag bit 6: write registers 4–29 to flash.
pub const FLAG_WRITE_FLASH: u8 = 0x40;
/// Flag bit 5: reboot.
pub const FLAG_REBOOT: u8 = 0x20;
/// Flag bit 4: restore registers 4–29 to the factory values.
pub const FLAG_FACTORY_RESET: u8 = 0x10;
/// Flag bits 3–0 = 1111: reply with `Length` bytes from `Address`.
pub const FLAG_READ_ARBITRARY: u8 = 0x0F;

/// The reply a short packet asks for (flag bits 3–0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ReplyRequest {
    None = 0x00,
    /// The single byte 07h.
    Ack = 0x01,
    /// Registers 0–29.
    Registers0To29 = 0x03,
    /// Registers 30–59.
    Registers30To59 = 0x05,
    /// Registers 20–29.
    Registers20To29 = 0x07,
    /// Registers 42–59: present position, time, load, temperature, voltage.
    Registers42To59 = 0x09,
    /// Registers 30–41.
    Registers30To41 = 0x0B,
}

impl ReplyRequest {
    pub const fn flag_bits(self) -> u8 {
        self as u8
    }

    /// First register and length of the reply this request produces (`None` for no reply or ACK).
    pub const fn register_span(self) -> Option<(u8, u8)> {
        match self {
            ReplyRequest::None | ReplyRequest::Ack => None,
            ReplyRequest::Registers0To29 => Some((0, 30)),
            ReplyRequest::Registers30To59 => Some((30, 30)),
            ReplyRequest::Registers20To29 => Some((20, 10)),
            ReplyRequest::Registers42To59 => Some((42, 18)),
            ReplyRequest::Registers30To41 => Some((30, 12)),
        }
    }
}

/// What the bus will carry back after a packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ExpectedReply {
    Nothing,
    Ack,
    /// A return packet with `length` bytes from register `address`.
    Registers {
        address: u8,
        length: u8,
    },
}

impl ExpectedReply {
    /// Bytes of the reply on the wire (8 + data for a return packet, 1 for an ACK).
    pub const fn wire_len(self) -> usize {
        match self {
            ExpectedReply::Nothing => 0,
            ExpectedReply::Ack => 1,
            ExpectedReply::Registers { length, .. } => 8 + length as usize,
        }
    }
}

/// A packet for one servo (or every servo, with [`Destination::Broadcast`]).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct ShortPacket {
    id: u8,
    flags: u8,
    address: u8,
    length: u8,
    count: u8,
    data: Vec<u8>,
    expected: ExpectedReply,
}

impl ShortPacket {
    /// Write `data` into the memory map from `address`, optionally asking for a reply.
    /// Refused for read-only and reserved registers, half registers and unsafe values.
    pub fn write(
        dest: Destination,
        address: u8,
        data: &[u8],
        reply: ReplyRequest,
    ) -> Result<Self, ProtocolError> {
        validate_write(address, data)?;
        let length = u8::try_from(data.len())
            .map_err(|_| ProtocolError::WriteTooLong { len: data.len() })?;
        Ok(Self::raw(
            dest,
            reply.flag_bits(),
            address,
            length,
            1,
            data.to_vec(),
        ))
    }

    /// Ask one servo for a reply without writing anything (`Address=00h, Length=00h, Count=01h`).
    pub fn request(id: ServoId, reply: ReplyRequest) -> Self {
        Self::raw(id.into(), reply.flag_bits(), 0, 0, 1, Vec::new())
    }

    /// Ask one servo for `length` bytes from `address` (flag 0Fh, `Count = 0`, no data).
    pub fn read(id: ServoId, address: u8, length: u8) -> Result<Self, ProtocolError> {
        validate_read(address, length)?;
        Ok(Self::raw(
            id.into(),
            FLAG_READ_ARBITRARY,
            address,
            length,
            0,
            Vec::new(),
        ))
    }

    /// Save registers 4–29 to flash. Wait at least 1 s before the next packet.
    pub fn write_flash(dest: Destination) -> Self {
        Self::raw(dest, FLAG_WRITE_FLASH, 0xFF, 0, 0, Vec::new())
    }

    /// Reboot. Never combined with a flash write: send it after the flash write has finished.
    pub fn reboot(dest: Destination) -> Self {
        Self::raw(dest, FLAG_REBOOT, 0xFF, 0, 0, Vec::new())
    }

    /// Restore registers 4–29 to the factory values (the ID becomes 1). Sent in the form of the
    /// manual's worked example: `Length = FFh`, `Count = 00h`, no data byte.
    pub fn factory_reset(dest: Destination) -> Self {
        Self::raw(dest, FLAG_FACTORY_RESET, 0xFF, 0xFF, 0, Vec::new())
    }

    pub fn goal_position(dest: Destination, goal: MmCenti) -> Result<Self, ProtocolError> {
        Self::write(
            dest,
            addr::GOAL_POSITION,
            &goal.within_stroke()?.to_le_bytes(),
            ReplyRequest::None,
        )
    }

    /// Goal position and the time to reach it (registers 30–33 in one write).
    pub fn goal_position_with_time(
        dest: Destination,
        goal: MmCenti,
        time: Ms10,
    ) -> Result<Self, ProtocolError> {
        let [p0, p1] = goal.within_stroke()?.to_le_bytes();
        let [t0, t1] = time.0.to_le_bytes();
        Self::write(
            dest,
            addr::GOAL_POSITION,
            &[p0, p1, t0, t1],
            ReplyRequest::None,
        )
    }

    pub fn force(dest: Destination, mode: ForceMode) -> Self {
        Self::raw(dest, 0, addr::FORCE_ENABLE, 1, 1, vec![mode as u8])
    }

    pub fn max_force(dest: Destination, force: Percent) -> Self {
        Self::raw(dest, 0, addr::MAX_FORCE, 1, 1, vec![force.get()])
    }

    /// Give servo `id` the new ID `new_id` (in RAM: flash and reboot separately to keep it).
    pub fn set_id(id: ServoId, new_id: ServoId) -> Self {
        Self::raw(id.into(), 0, addr::SERVO_ID, 1, 1, vec![new_id.get()])
    }

    pub fn baud_rate(dest: Destination, baud: BaudRate) -> Self {
        Self::raw(dest, 0, addr::BAUD_RATE, 1, 1, vec![baud.code()])
    }

    pub fn reverse(dest: Destination, reversed: bool) -> Self {
        Self::raw(dest, 0, addr::REVERSE, 1, 1, vec![u8::from(reversed)])
    }

    pub fn return_delay(dest: Destination, ms: u8) -> Self {
        Self::raw(dest, 0, addr::RETURN_DELAY, 1, 1, vec![ms])
    }

    pub fn plus_limit(dest: Destination, limit: MmCenti) -> Result<Self, ProtocolError> {
        let limit = PositionLimits::check_plus(limit)?;
        Ok(Self::raw(
            dest,
            0,
            addr::PLUS_LIMIT,
            2,
            1,
            limit.to_le_bytes().to_vec(),
        ))
    }

    pub fn minus_limit(dest: Destination, limit: MmCenti) -> Result<Self, ProtocolError> {
        let limit = PositionLimits::check_minus(limit)?;
        Ok(Self::raw(
            dest,
            0,
            addr::MINUS_LIMIT,
            2,
            1,
            limit.to_le_bytes().to_vec(),
        ))
    }

    pub fn punch(dest: Destination, punch: Punch) -> Self {
        Self::raw(
            dest,
            0,
            addr::PUNCH,
            2,
            1,
            punch.get().to_le_bytes().to_vec(),
        )
    }

    fn raw(
        dest: Destination,
        flags: u8,
        address: u8,
        length: u8,
        count: u8,
        data: Vec<u8>,
    ) -> Self {
        let reply_bits = flags & 0x0F;
        let expected = if dest == Destination::Broadcast || reply_bits == 0 {
            ExpectedReply::Nothing
        } else if reply_bits == FLAG_READ_ARBITRARY {
            ExpectedReply::Registers { address, length }
        } else if reply_bits == ReplyRequest::Ack as u8 {
            ExpectedReply::Ack
        } else {
            let span = [
                ReplyRequest::Registers0To29,
                ReplyRequest::Registers30To59,
                ReplyRequest::Registers20To29,
                ReplyRequest::Registers42To59,
                ReplyRequest::Registers30To41,
            ]
            .into_iter()
            .find(|r| r.flag_bits() == reply_bits)
            .and_then(ReplyRequest::register_span);
            match span {
                Some((address, length)) => ExpectedReply::Registers { address, length },
                None => ExpectedReply::Nothing,
            }
        };
        ShortPacket {
            id: dest.id_byte(),
            flags,
            address,
            length,
            count,
            data,
            expected,
        }
    }

    /// The reply the servo sends to this packet (none for broadcasts).
    pub fn expected_reply(&self) -> ExpectedReply {
        self.expected
    }

    /// The ID byte (255 for broadcast).
    pub fn id_byte(&self) -> u8 {
        self.id
    }

    /// Bytes on the wire.
    pub fn wire_len(&self) -> usize {
        8 + self.data.len()
    }

    /// Append the packet's bytes to `out`.
    pub fn encode_into(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&COMMAND_HEADER);
        let body_start = out.len();
        out.extend_from_slice(&[self.id, self.flags, self.address, self.length, self.count]);
        out.extend_from_slice(&self.data);
        let sum = xor_sum(&out[body_start..]);
        out.push(sum);
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.wire_len());
        self.encode_into(&mut out);
        out
    }
}

/// One servo's goal in a long packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct GoalEntry {
    pub id: ServoId,
    pub position: MmCenti,
    /// Travel time; when any entry of a packet has one, every entry carries one (0 = max speed).
    pub time: Option<Ms10>,
}

/// A packet that writes the same registers of several servos in one frame. No servo replies.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct LongPacket {
    address: u8,
    length: u8,
    count: u8,
    /// (VID, data) × count, already interleaved.
    body: Vec<u8>,
}

impl LongPacket {
    /// Write `data` at `address` of each listed servo. Every entry must have the same data
    /// length, no ID may appear twice, and each write must pass the same validation as a
    /// short write.
    pub fn new(address: u8, entries: &[(ServoId, &[u8])]) -> Result<Self, ProtocolError> {
        let first = entries.first().ok_or(ProtocolError::EmptyLongPacket)?;
        let count =
            u8::try_from(entries.len()).map_err(|_| ProtocolError::LongPacketTooManyServos {
                count: entries.len(),
            })?;
        let data_len = first.1.len();
        let length = u8::try_from(data_len + 1)
            .map_err(|_| ProtocolError::WriteTooLong { len: data_len })?;
        let mut body = Vec::with_capacity(entries.len() * (data_len + 1));
        for (i, (id, data)) in entries.iter().enumerate() {
            if data.len() != data_len {
                return Err(ProtocolError::LongPacketUnequalData {
                    id: id.get(),
                    expected: data_len,
                    got: data.len(),
                });
            }
            if entries[..i].iter().any(|(other, _)| other == id) {
                return Err(ProtocolError::LongPacketDuplicateId { id: id.get() });
            }
            validate_write(address, data)?;
            body.push(id.get());
            body.extend_from_slice(data);
        }
        Ok(LongPacket {
            address,
            length,
            count,
            body,
        })
    }

    /// Goal positions (and goal times when any entry has one) for several servos.
    pub fn goals(entries: &[GoalEntry]) -> Result<Self, ProtocolError> {
        let with_time = entries.iter().any(|e| e.time.is_some());
        let mut data: Vec<(ServoId, [u8; 4])> = Vec::with_capacity(entries.len());
        for e in entries {
            let [p0, p1] = e.position.within_stroke()?.to_le_bytes();
            let [t0, t1] = e.time.unwrap_or_default().0.to_le_bytes();
            data.push((e.id, [p0, p1, t0, t1]));
        }
        let n = if with_time { 4 } else { 2 };
        let slices: Vec<(ServoId, &[u8])> = data.iter().map(|(id, d)| (*id, &d[..n])).collect();
        Self::new(addr::GOAL_POSITION, &slices)
    }

    /// Bytes on the wire: `8 + Count × Length`.
    pub fn wire_len(&self) -> usize {
        8 + self.body.len()
    }

    pub fn encode_into(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&COMMAND_HEADER);
        let body_start = out.len();
        out.extend_from_slice(&[0x00, 0x00, self.address, self.length, self.count]);
        out.extend_from_slice(&self.body);
        let sum = xor_sum(&out[body_start..]);
        out.push(sum);
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.wire_len());
        self.encode_into(&mut out);
        out
    }
}

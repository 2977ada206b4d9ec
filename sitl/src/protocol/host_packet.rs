//! Packets from the host: short packets (one servo, or every servo with ID 255) and long packets
//! (several servos in one frame). Protocol spec sections 4.1 and 4.2.
//!
//! Frame layout, both kinds: `FA AF | ID | Flag | Address | Length | Count | Data | Sum`, where the data
//! field is `Length × Count` bytes long. That single rule frames every form in the manual:
//! a short write (`Count = 1`, `Length` data bytes), a request-only packet (`Length = 0`, `Count = 1`),
//! the special and arbitrary-read packets (`Count = 0`, no data) and long packets
//! (`ID = Flag = 0`, `Count` blocks of `VID + Length − 1` data bytes).

use super::HOST_HEADER;
use super::checksum::xor_sum;

/// Bytes before the data field: header, ID, Flag, Address, Length, Count.
pub const FRAME_HEAD_LEN: usize = 7;
/// The longest data field the simulated servos accept in one frame. A real servo has a small receive
/// buffer; 1024 bytes holds a long packet for 127 servos with 7 data bytes each. A header that claims
/// more is taken for garbage, so that the decoder resynchronises quickly.
pub const MAX_FRAME_DATA: usize = 1024;

/// Flag bit 6: save registers 4–29 to flash.
pub const FLAG_WRITE_FLASH: u8 = 0x40;
/// Flag bit 5: reboot.
pub const FLAG_REBOOT: u8 = 0x20;
/// Flag bit 4: restore registers 4–29 to their factory values.
pub const FLAG_FACTORY_RESET: u8 = 0x10;
/// Flag bits 3–0: which reply the host asks for.
pub const FLAG_REPLY_MASK: u8 = 0x0F;
/// `Address` of the three special packets.
pub const SPECIAL_ADDRESS: u8 = 0xFF;

/// One packet from the host whose sum was right.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum HostPacket {
    /// A packet to one servo (or to every servo, ID 255).
    Short(ShortPacket),
    /// A packet carrying data for several servos, never answered.
    Long(LongPacket),
}

/// A short packet, kept as it was on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShortPacket {
    pub id: u8,
    pub flag: u8,
    pub address: u8,
    pub length: u8,
    pub count: u8,
    pub data: Vec<u8>,
}

/// A long packet: the same `Address` and data length for every servo listed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LongPacket {
    pub address: u8,
    /// `1 + data bytes per servo` (the VID counts).
    pub length: u8,
    pub blocks: Vec<LongBlock>,
}

/// One servo's share of a long packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LongBlock {
    pub vid: u8,
    pub data: Vec<u8>,
}

/// The three special short packets (flag bits 6, 5, 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpecialCommand {
    WriteFlash,
    Reboot,
    FactoryReset,
}

/// What a short packet asks the servo to do, read the way the manual describes the forms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ShortForm<'a> {
    /// Write `data` at `address` (possibly zero bytes), then reply as `reply_code` asks.
    Write {
        address: u8,
        data: &'a [u8],
        reply_code: u8,
    },
    /// `Count = 0`: no data; reply as `reply_code` asks (1111: `length` bytes from `address`).
    Request {
        address: u8,
        length: u8,
        reply_code: u8,
    },
    /// A well-formed special packet.
    Special(SpecialCommand),
    /// More than one of flag bits 6, 5, 4 set: the manual says these cannot be combined.
    CombinedSpecial,
    /// A special flag with the wrong Address / Length / Count.
    MalformedSpecial,
    /// `Count` above 1 in a packet that is not a long packet.
    CountAboveOne,
}

impl ShortPacket {
    /// A write of `data` at `address`, with the reply request in `reply_code` (flag bits 3–0).
    pub fn write(id: u8, address: u8, data: &[u8], reply_code: u8) -> Self {
        ShortPacket {
            id,
            flag: reply_code & FLAG_REPLY_MASK,
            address,
            length: u8::try_from(data.len()).unwrap_or(u8::MAX),
            count: 1,
            data: data.iter().copied().take(usize::from(u8::MAX)).collect(),
        }
    }

    /// A request-only packet (`Address = 0, Length = 0, Count = 1`), e.g. code 1001 for registers 42–59.
    pub fn request(id: u8, reply_code: u8) -> Self {
        Self::write(id, 0, &[], reply_code)
    }

    /// Reply code 1111: ask for `length` bytes from `address` (`Count = 0`).
    pub fn read(id: u8, address: u8, length: u8) -> Self {
        ShortPacket {
            id,
            flag: 0x0F,
            address,
            length,
            count: 0,
            data: Vec::new(),
        }
    }

    /// One of the special packets in the form of the manual's examples.
    pub fn special(id: u8, command: SpecialCommand) -> Self {
        let (flag, length) = match command {
            SpecialCommand::WriteFlash => (FLAG_WRITE_FLASH, 0x00),
            SpecialCommand::Reboot => (FLAG_REBOOT, 0x00),
            SpecialCommand::FactoryReset => (FLAG_FACTORY_RESET, 0xFF),
        };
        ShortPacket {
            id,
            flag,
            address: SPECIAL_ADDRESS,
            length,
            count: 0,
            data: Vec::new(),
        }
    }

    /// Flag bits 3–0.
    pub fn reply_code(&self) -> u8 {
        self.flag & FLAG_REPLY_MASK
    }

    /// Classify the packet.
    pub fn form(&self) -> ShortForm<'_> {
        let special_bits = self.flag & (FLAG_WRITE_FLASH | FLAG_REBOOT | FLAG_FACTORY_RESET);
        if special_bits != 0 {
            if special_bits.count_ones() > 1 {
                return ShortForm::CombinedSpecial;
            }
            let (command, length) = match special_bits {
                FLAG_WRITE_FLASH => (SpecialCommand::WriteFlash, 0x00),
                FLAG_REBOOT => (SpecialCommand::Reboot, 0x00),
                _ => (SpecialCommand::FactoryReset, 0xFF),
            };
            if self.address == SPECIAL_ADDRESS && self.length == length && self.count == 0 {
                return ShortForm::Special(command);
            }
            return ShortForm::MalformedSpecial;
        }
        match self.count {
            0 => ShortForm::Request {
                address: self.address,
                length: self.length,
                reply_code: self.reply_code(),
            },
            1 => ShortForm::Write {
                address: self.address,
                data: &self.data,
                reply_code: self.reply_code(),
            },
            _ => ShortForm::CountAboveOne,
        }
    }

    /// The packet's bytes, header and sum included.
    pub fn encode(&self) -> Vec<u8> {
        let mut body = vec![self.id, self.flag, self.address, self.length, self.count];
        body.extend_from_slice(&self.data);
        frame(&body)
    }
}

impl LongPacket {
    /// A long packet writing each `(vid, data)` at `address`. Every block must have the same data length;
    /// the first block decides it (the others are cut or zero-padded to it).
    pub fn write(address: u8, blocks: &[(u8, &[u8])]) -> Self {
        let data_len = blocks
            .first()
            .map_or(0, |(_, data)| data.len())
            .min(usize::from(u8::MAX) - 1);
        let blocks = blocks
            .iter()
            .map(|(vid, data)| {
                let mut data: Vec<u8> = data.iter().copied().take(data_len).collect();
                data.resize(data_len, 0);
                LongBlock { vid: *vid, data }
            })
            .collect();
        LongPacket {
            address,
            length: u8::try_from(data_len + 1).unwrap_or(u8::MAX),
            blocks,
        }
    }

    /// The packet's bytes, header and sum included.
    pub fn encode(&self) -> Vec<u8> {
        let count = u8::try_from(self.blocks.len()).unwrap_or(u8::MAX);
        let mut body = vec![0x00, 0x00, self.address, self.length, count];
        for block in self.blocks.iter().take(usize::from(count)) {
            body.push(block.vid);
            body.extend_from_slice(&block.data);
        }
        frame(&body)
    }
}

impl HostPacket {
    /// Whether this is a long packet.
    pub fn is_long(&self) -> bool {
        matches!(self, HostPacket::Long(_))
    }

    /// The IDs the packet is addressed to: the short packet's ID (255 = every servo) or each VID.
    pub fn target_ids(&self) -> Vec<u8> {
        match self {
            HostPacket::Short(short) => vec![short.id],
            HostPacket::Long(long) => long.blocks.iter().map(|block| block.vid).collect(),
        }
    }

    /// The `Address` field.
    pub fn address(&self) -> u8 {
        match self {
            HostPacket::Short(short) => short.address,
            HostPacket::Long(long) => long.address,
        }
    }

    /// The data written per target ID: one entry for a short write, one per VID for a long packet,
    /// none for special, request-only and read packets.
    pub fn writes(&self) -> Vec<(u8, &[u8])> {
        match self {
            HostPacket::Short(short) => match short.form() {
                ShortForm::Write { data, .. } if !data.is_empty() => vec![(short.id, data)],
                _ => Vec::new(),
            },
            HostPacket::Long(long) => long
                .blocks
                .iter()
                .map(|block| (block.vid, block.data.as_slice()))
                .collect(),
        }
    }

    /// The Goal Position (registers 30–31, 0.01 mm) written per target ID, for writes that cover both bytes.
    pub fn goal_positions(&self) -> Vec<(u8, i16)> {
        const GOAL_POSITION: usize = 0x1E;
        let address = usize::from(self.address());
        self.writes()
            .into_iter()
            .filter_map(|(id, data)| {
                let offset = GOAL_POSITION.checked_sub(address)?;
                let low = *data.get(offset)?;
                let high = *data.get(offset + 1)?;
                Some((id, i16::from_le_bytes([low, high])))
            })
            .collect()
    }

    /// The packet's bytes, header and sum included.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            HostPacket::Short(short) => short.encode(),
            HostPacket::Long(long) => long.encode(),
        }
    }
}

/// Length of the data field announced by a frame head (`ID, Flag, Address, Length, Count`), or `None`
/// when the head cannot start a frame the servos accept.
pub fn announced_data_len(id: u8, flag: u8, length: u8, count: u8) -> Option<usize> {
    let is_long = id == 0 && flag == 0;
    if is_long && count > 0 && length == 0 {
        return None;
    }
    let data_len = usize::from(length) * usize::from(count);
    (data_len <= MAX_FRAME_DATA).then_some(data_len)
}

/// Build a packet from a complete frame body (`ID` through the last data byte, sum already checked).
pub fn from_body(body: &[u8]) -> Option<HostPacket> {
    let (&[id, flag, address, length, count], data) = body.split_first_chunk::<5>()?;
    if id == 0 && flag == 0 {
        let block_len = usize::from(length);
        if block_len == 0 {
            return (count == 0 && data.is_empty()).then(|| {
                HostPacket::Long(LongPacket {
                    address,
                    length,
                    blocks: Vec::new(),
                })
            });
        }
        if data.len() != block_len * usize::from(count) {
            return None;
        }
        let blocks = data
            .chunks_exact(block_len)
            .map(|chunk| LongBlock {
                vid: chunk[0],
                data: chunk[1..].to_vec(),
            })
            .collect();
        return Some(HostPacket::Long(LongPacket {
            address,
            length,
            blocks,
        }));
    }
    Some(HostPacket::Short(ShortPacket {
        id,
        flag,
        address,
        length,
        count,
        data: data.to_vec(),
    }))
}

/// Header + body + sum.
fn frame(body: &[u8]) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(body.len() + 3);
    bytes.extend_from_slice(&HOST_HEADER);
    bytes.extend_from_slice(body);
    bytes.push(xor_sum(body));
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn goal_position_write_encodes_as_the_spec_vector() {
        let packet = ShortPacket::write(1, 0x1E, &[0x84, 0x03], 0);
        assert_eq!(
            packet.encode(),
            [0xFA, 0xAF, 0x01, 0x00, 0x1E, 0x02, 0x01, 0x84, 0x03, 0x9B]
        );
    }

    #[test]
    fn special_packets_encode_as_the_spec_vectors() {
        let flash = ShortPacket::special(1, SpecialCommand::WriteFlash).encode();
        let reboot = ShortPacket::special(1, SpecialCommand::Reboot).encode();
        let reset = ShortPacket::special(1, SpecialCommand::FactoryReset).encode();
        assert_eq!(flash, [0xFA, 0xAF, 0x01, 0x40, 0xFF, 0x00, 0x00, 0xBE]);
        assert_eq!(reboot, [0xFA, 0xAF, 0x01, 0x20, 0xFF, 0x00, 0x00, 0xDE]);
        assert_eq!(reset, [0xFA, 0xAF, 0x01, 0x10, 0xFF, 0xFF, 0x00, 0x11]);
    }

    #[test]
    fn read_and_request_encode_as_the_spec_vectors() {
        assert_eq!(
            ShortPacket::read(1, 0x2A, 2).encode(),
            [0xFA, 0xAF, 0x01, 0x0F, 0x2A, 0x02, 0x00, 0x26]
        );
        assert_eq!(
            ShortPacket::request(1, 0x09).encode(),
            [0xFA, 0xAF, 0x01, 0x09, 0x00, 0x00, 0x01, 0x09]
        );
    }

    #[test]
    fn long_packet_encodes_as_the_spec_vector() {
        let packet = LongPacket::write(
            0x1E,
            &[(1, &[0x64, 0x00]), (2, &[0x64, 0x00]), (5, &[0xF4, 0x01])],
        );
        let expected = [
            0xFA, 0xAF, 0x00, 0x00, 0x1E, 0x03, 0x03, 0x01, 0x64, 0x00, 0x02, 0x64, 0x00, 0x05,
            0xF4, 0x01, 0xED,
        ];
        assert_eq!(packet.encode(), expected);
    }

    #[test]
    fn long_packet_goal_positions_are_listed_per_vid() {
        let packet = HostPacket::Long(LongPacket::write(
            0x1E,
            &[(1, &[0x64, 0x00]), (5, &[0xF4, 0x01])],
        ));
        assert_eq!(packet.goal_positions(), vec![(1, 100), (5, 500)]);
        assert_eq!(packet.target_ids(), vec![1, 5]);
    }

    #[test]
    fn short_write_starting_at_goal_time_has_no_goal_position() {
        let packet = HostPacket::Short(ShortPacket::write(1, 0x20, &[0xF4, 0x01], 0));
        assert!(packet.goal_positions().is_empty());
    }

    #[test]
    fn forms_follow_the_flag_and_count() {
        let reboot = ShortPacket::special(1, SpecialCommand::Reboot);
        assert_eq!(reboot.form(), ShortForm::Special(SpecialCommand::Reboot));
        let combined = ShortPacket {
            flag: 0x60,
            ..reboot.clone()
        };
        assert_eq!(combined.form(), ShortForm::CombinedSpecial);
        let malformed = ShortPacket {
            address: 0x00,
            ..reboot
        };
        assert_eq!(malformed.form(), ShortForm::MalformedSpecial);
        let read = ShortPacket::read(1, 0x2A, 2);
        assert_eq!(
            read.form(),
            ShortForm::Request {
                address: 0x2A,
                length: 2,
                reply_code: 0x0F
            }
        );
    }

    #[test]
    fn long_head_with_zero_length_and_blocks_is_refused() {
        assert_eq!(announced_data_len(0, 0, 0, 3), None);
        assert_eq!(announced_data_len(0, 0, 3, 3), Some(9));
        assert_eq!(announced_data_len(1, 0x0F, 0x2A, 0), Some(0));
        assert_eq!(announced_data_len(0, 0, 255, 255), None);
    }
}

//! A classic CAN frame with a 29-bit identifier, and the fields DroneCAN puts in that
//! identifier:
//!
//! | bits | message frame | anonymous message | service frame |
//! |---|---|---|---|
//! | 28–24 | priority (0 highest) | priority | priority |
//! | 23–8 | data type id (16 bits) | discriminator (14), type id's low 2 bits | type id (8), request (1), destination node (7) |
//! | 7 | 0 | 0 | 1 |
//! | 6–0 | source node (1–127) | 0 | source node |

use std::fmt;

/// The most data a classic CAN frame carries.
pub const MAX_DATA: usize = 8;

/// One CAN frame: an extended (29-bit) identifier and up to 8 bytes, the last of them
/// DroneCAN's tail byte.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct CanFrame {
    id: u32,
    len: u8,
    data: [u8; MAX_DATA],
}

impl CanFrame {
    /// A frame of identifier `id` (29 bits) with `data` (1–8 bytes); `None` otherwise.
    pub fn new(id: u32, data: &[u8]) -> Option<Self> {
        if id >> 29 != 0 || data.is_empty() || data.len() > MAX_DATA {
            return None;
        }
        let mut bytes = [0u8; MAX_DATA];
        bytes[..data.len()].copy_from_slice(data);
        Some(CanFrame {
            id,
            len: data.len() as u8,
            data: bytes,
        })
    }

    /// The 29-bit identifier.
    pub fn id(&self) -> u32 {
        self.id
    }

    pub fn data(&self) -> &[u8] {
        &self.data[..usize::from(self.len)]
    }
}

impl fmt::Debug for CanFrame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:08X}#", self.id)?;
        for b in self.data() {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

/// What a transfer is: a broadcast message, or a service request or response to one node.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    Message,
    Request { destination: u8 },
    Response { destination: u8 },
}

/// The fields of a DroneCAN frame's identifier.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanId {
    /// 0 (highest) … 31 (lowest).
    pub priority: u8,
    pub kind: Kind,
    /// 16 bits for a message, 8 for a service; the low 2 bits only, for an anonymous message.
    pub data_type_id: u16,
    /// 1–127, or 0 for an anonymous message (a node with no id yet).
    pub source: u8,
    /// An anonymous message's discriminator (14 bits); 0 for the others.
    pub discriminator: u16,
}

impl CanId {
    /// The identifier's fields; `None` for a service frame to or from node 0, or one to itself.
    pub fn parse(id: u32) -> Option<Self> {
        let priority = ((id >> 24) & 0x1F) as u8;
        let source = (id & 0x7F) as u8;
        if id & 0x80 == 0 {
            let (data_type_id, discriminator) = if source == 0 {
                (((id >> 8) & 0x3) as u16, ((id >> 10) & 0x3FFF) as u16)
            } else {
                (((id >> 8) & 0xFFFF) as u16, 0)
            };
            return Some(CanId {
                priority,
                kind: Kind::Message,
                data_type_id,
                source,
                discriminator,
            });
        }
        let destination = ((id >> 8) & 0x7F) as u8;
        if source == 0 || destination == 0 || source == destination {
            return None;
        }
        let kind = if id & 0x8000 != 0 {
            Kind::Request { destination }
        } else {
            Kind::Response { destination }
        };
        Some(CanId {
            priority,
            kind,
            data_type_id: ((id >> 16) & 0xFF) as u16,
            source,
            discriminator: 0,
        })
    }

    /// The 29-bit identifier of these fields.
    pub fn to_raw(self) -> u32 {
        let common = (u32::from(self.priority & 0x1F) << 24) | u32::from(self.source & 0x7F);
        match self.kind {
            Kind::Message if self.source == 0 => {
                common
                    | (u32::from(self.discriminator & 0x3FFF) << 10)
                    | (u32::from(self.data_type_id & 0x3) << 8)
            }
            Kind::Message => common | (u32::from(self.data_type_id) << 8),
            Kind::Request { destination } | Kind::Response { destination } => {
                let request = matches!(self.kind, Kind::Request { .. });
                common
                    | 0x80
                    | (u32::from(self.data_type_id & 0xFF) << 16)
                    | (u32::from(request) << 15)
                    | (u32::from(destination & 0x7F) << 8)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_read_back_as_written() {
        // ArduPlane's ArrayCommand from node 10 at priority 16 (medium): type 1010.
        let array = CanId::parse(0x1003F20A).unwrap();
        assert_eq!(
            (array.priority, array.kind, array.data_type_id, array.source),
            (16, Kind::Message, 1010, 10)
        );
        assert_eq!(array.to_raw(), 0x1003F20A);
        let request = CanId {
            priority: 30,
            kind: Kind::Request { destination: 42 },
            data_type_id: 1,
            source: 10,
            discriminator: 0,
        };
        assert_eq!(CanId::parse(request.to_raw()), Some(request));
        let response = CanId {
            kind: Kind::Response { destination: 10 },
            source: 42,
            ..request
        };
        assert_eq!(CanId::parse(response.to_raw()), Some(response));
        let anonymous = CanId {
            priority: 30,
            kind: Kind::Message,
            data_type_id: 1,
            source: 0,
            discriminator: 0x2ABC,
        };
        assert_eq!(CanId::parse(anonymous.to_raw()), Some(anonymous));
        // A service frame from node 0 is not DroneCAN.
        assert_eq!(CanId::parse(0x80 | (5 << 8)), None);
    }

    #[test]
    fn a_frame_holds_one_to_eight_bytes_and_29_bits() {
        assert!(CanFrame::new(0x1FFF_FFFF, &[0; 8]).is_some());
        assert!(CanFrame::new(0x2000_0000, &[0]).is_none());
        assert!(CanFrame::new(1, &[]).is_none());
        assert!(CanFrame::new(1, &[0; 9]).is_none());
    }
}

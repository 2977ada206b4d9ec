//! DroneCAN (UAVCAN v0) on classic CAN, as data: no socket, no clock of its own.
//!
//! - [`frame`]: a CAN frame with a 29-bit identifier, and what the identifier says: priority,
//!   message or service, data type, source and destination nodes.
//! - [`transfer`]: transfers split into frames and frames put back into transfers: the tail
//!   byte (start, end, toggle, transfer id), the transfer CRC of a multi-frame transfer seeded
//!   with the data type's signature, one reassembly per sender and type, dropped after
//!   [`transfer::TRANSFER_TIMEOUT`].
//! - [`bits`]: DSDL's bit packing of scalars, and [`float16`] its half-precision floats.
//! - [`messages`]: the data types the bridge speaks, each with its id and signature:
//!   `uavcan.equipment.actuator.ArrayCommand` in, `uavcan.equipment.actuator.Status`,
//!   `uavcan.equipment.device.Temperature`, `uavcan.protocol.NodeStatus` and
//!   `uavcan.protocol.GetNodeInfo` out.
//! - [`mcast`]: ArduPilot SITL's CAN bus over multicast UDP, a datagram per frame (the test
//!   transport; SocketCAN is the aircraft's).
//! - [`node`]: a node on those: ArrayCommand's commands out of the frames, GetNodeInfo
//!   answered, NodeStatus once a second, its transfers numbered; its id static or asked of an
//!   allocator ([`allocation`], dynamic node id allocation's client).
//!
//! Written from the DroneCAN specification and checked against the `dronecan` package's own
//! encoder and decoder (`tests/dronecan_peer.rs`). Uses nothing else of the crate.

pub mod allocation;
pub mod bits;
pub mod crc;
pub mod float16;
pub mod frame;
pub mod mcast;
pub mod messages;
pub mod node;
pub mod transfer;

pub use frame::{CanFrame, CanId, Kind};
pub use transfer::{Reassembler, Transfer, TransferError};

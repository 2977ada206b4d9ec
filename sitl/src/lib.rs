//! `lj9da-sim`: a simulated bus of Futaba LJ9DA41 RS485 linear servos, on a real pseudo-terminal or TCP.
//!
//! A host (the bridge, a test, a terminal program) opens the printed pty path like a serial port and talks
//! the LJ9DA41 protocol; the simulated servos answer with wire timing at their bit rate, move, draw current,
//! heat up, keep RAM and flash apart, and can be given faults.
//!
//! Layers, each in its own module:
//! - [`protocol`]: the simulator's own parser of host packets and encoder of return packets (independent of
//!   the bridge's protocol core, so that the two cross-check each other);
//! - [`servo`]: one servo — memory map, RAM/flash, force, motion, current, heat — pure, handed `now`;
//! - [`bus`]: [`BusModel`], the line and the servos on it — wire time, bit rates, half-duplex collisions,
//!   echo, reply faults — pure, handed `now` (tests drive it with virtual time);
//! - [`runtime`]: [`SimBus`], a thread serving a pty or TCP in real time (at real-time priority
//!   where granted, by `lj9da-realtime`, which the bridge's bus threads use too), and [`SimHandle`].
//!
//! API notes (relative to the shape first agreed with the bridge):
//! - Handle methods that address a servo take its *current* ID (register 4); if no servo has that ID now,
//!   the servo configured with it is used. They return `bool`: `false` when no such servo exists.
//! - [`ServoSnapshot::baud`] is `Option<u32>` (`None` after a forbidden baud code was written); the snapshot
//!   also has `slot`, `rod_mm`, `ambient_c`, `flash_error`, `busy`, `flash`, `model_number`, `stalled`,
//!   `load_n`, `overheating`.
//! - `disconnect_port` / `reconnect_port` return nothing (errors are logged); `try_reconnect_port` returns
//!   the new path or the error.
//! - Added: `SimBus::local_addr` (TCP), `SimHandle::{path, snapshots, set_voltage, set_ambient,
//!   set_temperature, move_rod, set_host_baud, try_reconnect_port, set_wear}` ([`Wear`]: friction
//!   current in proportion to speed — both ways, while extending only, or over a [`FrictionSpot`] —
//!   and a stiff spot over part of the stroke).
//!
//! The same bus in virtual time, without I/O:
//!
//! ```
//! use std::time::{Duration, Instant};
//! use lj9da_sim::{BusModel, ReturnPacket, ShortPacket, SimConfig};
//!
//! let start = Instant::now();
//! let mut bus = BusModel::new(&SimConfig::default(), start);
//! // Ask servo 1 for registers 42–59 (spec vector `FA AF 01 09 00 00 01 09`).
//! bus.receive(start, &ShortPacket::request(1, 0x09).encode(), Some(115_200));
//! let later = start + Duration::from_millis(10);
//! bus.advance(later);
//! let bytes: Vec<u8> = bus.poll_transmit(later).iter().map(|tx| tx.byte).collect();
//! let (reply, _) = ReturnPacket::parse(&bytes).expect("a valid reply");
//! assert_eq!(reply.u16_at(52), Some(1200)); // 12.00 V
//! ```

pub mod bus;
pub mod config;
pub mod events;
pub mod fault;
pub mod protocol;
pub mod runtime;
pub mod servo;

pub use bus::BusModel;
pub use config::{ConfigError, SimConfig};
pub use events::{
    BusEvent, BusStats, DamageEvent, DamageKind, IgnoreReason, PacketEvent, ReplyEvent,
};
pub use fault::{Fault, FaultKind};
pub use protocol::host_packet::{HostPacket, LongBlock, LongPacket, ShortPacket, SpecialCommand};
pub use protocol::return_packet::ReturnPacket;
pub use runtime::{SimBus, SimHandle};
pub use servo::physics::{FrictionSpot, StiffSpot, Wear};
pub use servo::{Force, ServoSnapshot};

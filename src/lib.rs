//! MAVLink ↔ Futaba LJ9DA41 bridge.
//!
//! Layers, bottom up:
//! - [`protocol`]: the LJ9DA41 RS485 protocol as pure data (no I/O, no clock).
//! - [`dronecan`]: DroneCAN (UAVCAN v0) frames, transfers and data types as pure data.
//! - [`bus`]: the sans-IO bus master that schedules commands and telemetry on one RS485 bus,
//!   and the thin tokio driver that runs it over a serial port.
//! - [`config`]: mapping files (TOML) and the autopilot-output → servo-position mapping.
//! - [`mavlink`]: the MAVLink side: outputs in, servo health out.
//! - [`runtime`]: `lj9da-bridge run`, the tokio shell joining MAVLink and the buses.
//! - [`ui`]: how a running bridge and the servos are shown: live view, plain table, terminal.
//! - [`serial`]: serial ports: a UART's RS485 mode, the list of ports (`lj9da-bridge ports`).
//! - `simulation`: `lj9da-bridge sitl`, the whole chain with simulated servos and autopilot
//!   (feature `sitl`, on by default; the Debian package is built without it).

pub mod bus;
pub mod can_node;
pub mod commission;
pub mod config;
pub mod deploy;
pub mod dronecan;
#[doc(hidden)]
pub mod fuzz_targets;
pub mod mavlink;
pub mod protocol;
pub mod record;
pub mod runtime;
pub mod serial;
#[cfg(feature = "sitl")]
pub mod simulation;
pub mod ui;

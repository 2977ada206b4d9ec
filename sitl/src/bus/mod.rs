//! The simulated RS485 line and the servos on it, without I/O (see [`model`]).

pub mod model;
pub mod wire;

pub use model::BusModel;
pub use wire::{TxByte, TxSource, byte_time};

//! The simulated LJ9DA41 itself: memory map, device state machine and physics.

pub mod device;
pub mod memory_map;
pub mod physics;

pub use device::{Force, Reception, Servo, ServoConfig, ServoSnapshot};

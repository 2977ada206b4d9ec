//! Serial ports as the operating system has them: the RS485 mode of a UART ([`rs485`]), the
//! latency timer of USB adapters ([`latency`]), one program at a time on a port ([`lock`]) and the list of serial ports with what each one
//! is ([`ports`]). Nothing here knows of mapping files or the bridge above it.

pub mod latency;
pub mod lock;
pub mod ports;
pub mod rs485;

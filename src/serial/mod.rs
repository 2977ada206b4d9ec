//! Serial ports as the operating system has them: the RS485 mode of a UART ([`rs485`]) and
//! the list of serial ports with what each one is ([`ports`]).

pub mod ports;
pub mod rs485;

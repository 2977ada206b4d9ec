//! How a running bridge and the servos are shown to a person: the live view redrawn in place
//! ([`live`]), the plain table for a pipe or `--plain` and the final snapshot ([`table`]), and
//! the terminal they are drawn on: a screen of text, the quit keys, the log lines kept while a
//! screen owns the terminal ([`terminal`]).
//!
//! The commands above use it: `sitl` shows its bridge with [`live`] or [`table`],
//! `commission monitor` draws on [`terminal::TextScreen`], and `main` sends the logs to
//! [`terminal::LogWriter`] while the live view is up.
//!
//! What it shows comes from runtime's [`BridgeView`](crate::runtime::BridgeView) (and the bus
//! and MAVLink types that view holds); it uses nothing above `runtime` (`tests/layers.rs`).
//! Nothing here decides anything about the bridge: it only reads and draws.

pub mod live;
pub mod table;
pub mod terminal;

//! Commissioning tools: find, inspect and configure LJ9DA41 servos from the command line
//! (`lj9da-bridge scan | info | set | move | force | factory-reset | monitor`).
//!
//! Each subcommand is a function that takes a [`Link`] (one serial port, one transaction at a
//! time) and returns a plain data report; [`print`](mod@print) turns reports into tables and JSON, and
//! [`cli`] holds the command-line arguments and the glue. Every value is validated by the
//! protocol core before anything is written, and every write is read back; a refused command
//! writes nothing at all.
//!
//! Layout, one idea per file:
//! - [`link`]: the serial port, transactions with computed timeouts, retries for reads.
//! - [`settings`]: `key=value` arguments of `set`, parsed and validated into packets.
//! - [`scan`], [`info`], [`set`], [`motion`] (`move`, `force`), [`reset`]
//!   (`factory-reset`), [`monitor`]: the subcommands.
//! - [`print`](mod@print), [`json`]: output for people and for scripts.
//! - [`cli`]: clap arguments and dispatch.

pub mod cli;
pub mod info;
pub mod json;
pub mod link;
pub mod monitor;
pub mod motion;
pub mod print;
pub mod reset;
pub mod scan;
pub mod set;
pub mod settings;

pub use link::{Link, LinkError, Reply};
pub use settings::Setting;

use crate::protocol::{BaudRate, ProtocolError, ServoId};
use std::time::Duration;
use thiserror::Error;

/// How long to wait after a flash write (or factory reset) before the next packet; the manual
/// asks for at least 1 s.
pub const FLASH_WAIT: Duration = Duration::from_millis(1200);
/// How long a rebooting servo may take to answer again.
pub const REBOOT_WAIT: Duration = Duration::from_secs(2);

/// Why a commissioning command stopped. [`CommissionError::is_refusal`] tells a refusal
/// (nothing was written) from a failure part-way.
#[derive(Debug, Error)]
pub enum CommissionError {
    #[error(transparent)]
    Link(#[from] LinkError),
    /// A value the protocol core refuses; its message says why.
    #[error("refused: {0}; nothing was written")]
    Protocol(#[from] ProtocolError),
    #[error("refused: `{arg}`: {reason}; nothing was written")]
    BadSetting { arg: String, reason: String },
    #[error(
        "servo {id} does not answer at {baud}; nothing was written (find it with `lj9da-bridge scan --all-bauds`)"
    )]
    NoServo { id: ServoId, baud: BaudRate },
    #[error(
        "refused: ID {new} is already taken: a servo answers there at {baud}; nothing was written (give each servo its own ID)"
    )]
    IdTaken { new: ServoId, baud: BaudRate },
    #[error(
        "refused: servo {id} reports model 0x{model:04X}, not an LJ9DA41 (0x7510); nothing was written"
    )]
    NotLj9da41 { id: ServoId, model: u16 },
    #[error("refused: {reason}; nothing was written")]
    Refused { reason: String },
    #[error("servo {id}: {what} reads back {got}, expected {expected}{hint}")]
    Verify {
        id: ServoId,
        what: String,
        expected: String,
        got: String,
        hint: String,
    },
    #[error("{0}")]
    Failed(String),
}

impl CommissionError {
    /// The command was refused before anything was written to any servo.
    pub fn is_refusal(&self) -> bool {
        matches!(
            self,
            CommissionError::Protocol(_)
                | CommissionError::BadSetting { .. }
                | CommissionError::NoServo { .. }
                | CommissionError::IdTaken { .. }
                | CommissionError::NotLj9da41 { .. }
                | CommissionError::Refused { .. }
                | CommissionError::Link(LinkError::Rs485 { .. })
        )
    }
}

/// Read registers 0–29 of servo `id`, refusing (nothing written yet) if it does not answer or
/// is not an LJ9DA41.
pub(crate) async fn require_servo(
    link: &mut Link,
    id: ServoId,
) -> Result<crate::protocol::MemoryMap, CommissionError> {
    let reply = match link
        .read(id, crate::protocol::ReplyRequest::Registers0To29)
        .await
    {
        Ok(reply) => reply,
        Err(LinkError::Timeout { .. }) => {
            return Err(CommissionError::NoServo {
                id,
                baud: link.baud(),
            });
        }
        Err(e) => return Err(e.into()),
    };
    let mut map = crate::protocol::MemoryMap::default();
    map.store(reply.address, &reply.data);
    let model = map.model_number();
    if model != crate::protocol::LJ9DA41_MODEL_NUMBER {
        return Err(CommissionError::NotLj9da41 { id, model });
    }
    Ok(map)
}

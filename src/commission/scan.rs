//! `scan`: which IDs answer on the bus, at one baud rate or at every rate of the table.
//!
//! Each ID gets one ACK ping with a tight timeout (the scan margin); an ID that answers is then
//! read (registers 0–29 for model and firmware, 42–59 for position, temperature, voltage) with
//! the ordinary margin and retries. The read also proves the ACK was really that servo's: a
//! lone `07h` of noise does not survive it. Nothing is written.

use super::CommissionError;
use super::link::{Link, LinkError};
use crate::protocol::registers::addr;
use crate::protocol::{BaudRate, ReplyFlags, ReplyRequest, ServoId, Telemetry};
use std::time::{Duration, Instant};

/// What to probe.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ScanOptions {
    /// IDs to ping, in order.
    pub ids: Vec<ServoId>,
    /// Baud rates to try, in order; the link is left at its own rate afterwards.
    pub bauds: Vec<BaudRate>,
    /// Margin of each ACK ping's timeout (beyond wire time).
    pub ping_margin: Duration,
}

impl ScanOptions {
    /// Every ID 1–127 at `baud` (or at every rate of the table with `all_bauds`).
    pub fn new(baud: BaudRate, all_bauds: bool) -> Self {
        ScanOptions {
            ids: ServoId::all().collect(),
            bauds: if all_bauds {
                BaudRate::ALL.to_vec()
            } else {
                vec![baud]
            },
            ping_margin: Link::SCAN_MARGIN,
        }
    }
}

/// One servo that answered.
#[derive(Debug, Clone, PartialEq)]
pub struct FoundServo {
    pub id: ServoId,
    /// The rate it answered at.
    pub baud: BaudRate,
    /// Registers 0–1 (`None` if its register replies did not come through).
    pub model: Option<u16>,
    /// Register 2.
    pub firmware: Option<u8>,
    /// Registers 42–59.
    pub telemetry: Option<Telemetry>,
    /// Status flags of the last reply.
    pub flags: Option<ReplyFlags>,
    /// Something odd about this servo (a reply that did not come through, a model that is not
    /// an LJ9DA41, …).
    pub problem: Option<String>,
}

/// What a scan found.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanReport {
    pub found: Vec<FoundServo>,
    pub bauds: Vec<BaudRate>,
    /// IDs pinged at each rate.
    pub ids_probed: usize,
    pub elapsed: Duration,
}

impl ScanReport {
    /// The IDs found, in the order found.
    pub fn ids(&self) -> Vec<u8> {
        self.found.iter().map(|f| f.id.get()).collect()
    }
}

/// Ping every ID of `options` at every rate of `options`; see the module docs.
pub async fn scan(link: &mut Link, options: &ScanOptions) -> Result<ScanReport, CommissionError> {
    let started = Instant::now();
    let home = link.baud();
    let mut found = Vec::new();
    let result = async {
        for &baud in &options.bauds {
            link.reopen(baud).await?;
            for &id in &options.ids {
                if let Some(servo) = probe(link, id, options.ping_margin).await? {
                    found.push(servo);
                }
            }
        }
        Ok::<(), LinkError>(())
    }
    .await;
    // Leave the port as it was, even after an error.
    let back = link.reopen(home).await;
    result?;
    back?;
    Ok(ScanReport {
        found,
        bauds: options.bauds.clone(),
        ids_probed: options.ids.len(),
        elapsed: started.elapsed(),
    })
}

async fn ping_with_margin(
    link: &mut Link,
    id: ServoId,
    margin: Duration,
) -> Result<bool, LinkError> {
    let ordinary = link.margin();
    link.set_margin(margin);
    let answered = link.ping(id).await;
    link.set_margin(ordinary);
    answered
}

/// Ping `id`; if it answers, read what the table shows.
async fn probe(
    link: &mut Link,
    id: ServoId,
    margin: Duration,
) -> Result<Option<FoundServo>, LinkError> {
    if !ping_with_margin(link, id, margin).await? {
        return Ok(None);
    }
    let mut servo = FoundServo {
        id,
        baud: link.baud(),
        model: None,
        firmware: None,
        telemetry: None,
        flags: None,
        problem: None,
    };
    match link.read(id, ReplyRequest::Registers0To29).await {
        Ok(fixed) => {
            let model = fixed
                .data
                .get(usize::from(addr::MODEL_NUMBER)..usize::from(addr::MODEL_NUMBER) + 2)
                .map(|b| u16::from_le_bytes([b[0], b[1]]));
            servo.model = model;
            servo.firmware = fixed.data.get(usize::from(addr::FIRMWARE_VERSION)).copied();
            servo.flags = Some(fixed.flags);
            if model != Some(crate::protocol::LJ9DA41_MODEL_NUMBER) {
                servo.problem = Some("not an LJ9DA41 (model number is not 0x7510)".into());
            }
        }
        Err(LinkError::Timeout { .. }) => {
            // A lone 07h of noise does not answer twice; a real servo whose register replies
            // are lost (two servos sharing the ID collide) does.
            if !ping_with_margin(link, id, margin).await? {
                return Ok(None);
            }
            servo.problem = Some(
                "answers pings but its register replies do not come through: two servos may share this ID (connect one at a time)"
                    .into(),
            );
            return Ok(Some(servo));
        }
        Err(e) => return Err(e),
    }
    match link.read(id, ReplyRequest::Registers42To59).await {
        Ok(live) => {
            servo.telemetry = live.telemetry().ok();
            servo.flags = Some(live.flags);
        }
        Err(LinkError::Timeout { .. }) => {
            servo.problem = Some("registers 42–59 did not come through".into());
        }
        Err(e) => return Err(e),
    }
    Ok(Some(servo))
}

/// Whether some servo answers at `id` (pinged twice with the ordinary margin, so that a busy
/// moment of the bus is not taken for a free ID).
pub async fn id_answers(link: &mut Link, id: ServoId) -> Result<bool, LinkError> {
    for _ in 0..2 {
        if link.ping(id).await? {
            return Ok(true);
        }
    }
    Ok(false)
}

//! `monitor`: poll registers 30–59 of a few servos over and over, until Ctrl-C or a set number
//! of samples or seconds. Nothing is written. A servo that misses a poll shows "no answer" for
//! that sample; only a failing port stops the monitor.

use super::CommissionError;
use super::link::{Link, LinkError, Reply};
use crate::protocol::{
    ForceMode, MemoryMap, MmCenti, ReplyFlags, ReplyRequest, ServoId, ShortPacket, Telemetry,
};
use std::future::Future;
use std::time::{Duration, Instant};

/// One servo's registers 30–59 at one moment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    pub telemetry: Telemetry,
    pub goal: MmCenti,
    pub force: Option<ForceMode>,
    pub max_force_percent: u8,
    pub flags: ReplyFlags,
}

/// One row of the table.
#[derive(Debug, Clone, PartialEq)]
pub struct MonitorRow {
    pub id: ServoId,
    /// The sample, or why there is none.
    pub reading: Result<Sample, String>,
}

/// When the monitor stops on its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MonitorOptions {
    /// Time from the start of one sample to the start of the next.
    pub interval: Duration,
    /// Stop after this many samples.
    pub count: Option<u64>,
    /// Stop after this long.
    pub duration: Option<Duration>,
}

impl Default for MonitorOptions {
    fn default() -> Self {
        MonitorOptions {
            interval: Duration::from_millis(250),
            count: None,
            duration: None,
        }
    }
}

/// Poll each of `ids` once (one attempt each).
pub async fn sample(link: &mut Link, ids: &[ServoId]) -> Result<Vec<MonitorRow>, LinkError> {
    let mut rows = Vec::with_capacity(ids.len());
    for &id in ids {
        let packet = ShortPacket::request(id, ReplyRequest::Registers30To59);
        let reading = match link.exchange(&packet).await {
            Ok(Reply::Packet(reply)) => {
                let mut map = MemoryMap::default();
                map.store(reply.address, &reply.data);
                Ok(Sample {
                    telemetry: map.telemetry(),
                    goal: map.goal_position(),
                    force: map.force_mode().ok(),
                    max_force_percent: map.max_force_raw(),
                    flags: reply.flags,
                })
            }
            Ok(_) | Err(LinkError::Timeout { .. }) => Err("no answer".to_string()),
            Err(e) => return Err(e),
        };
        rows.push(MonitorRow { id, reading });
    }
    Ok(rows)
}

/// Sample `ids` every `options.interval`, handing each sample (numbered from 1) to
/// `on_sample`, until `stop` completes or a limit of `options` is reached. Returns the number
/// of samples taken.
pub async fn monitor(
    link: &mut Link,
    ids: &[ServoId],
    options: MonitorOptions,
    stop: impl Future<Output = ()>,
    mut on_sample: impl FnMut(u64, &[MonitorRow]),
) -> Result<u64, CommissionError> {
    if ids.is_empty() {
        return Err(CommissionError::Refused {
            reason: "no servo IDs to monitor (e.g. --ids 1,2,3)".into(),
        });
    }
    let started = Instant::now();
    tokio::pin!(stop);
    let mut taken = 0u64;
    loop {
        let sample_started = tokio::time::Instant::now();
        let rows = tokio::select! {
            rows = sample(link, ids) => rows?,
            () = &mut stop => return Ok(taken),
        };
        taken += 1;
        on_sample(taken, &rows);
        if options.count.is_some_and(|n| taken >= n)
            || options.duration.is_some_and(|d| started.elapsed() >= d)
        {
            return Ok(taken);
        }
        let Some(next) = sample_started.checked_add(options.interval) else {
            // An interval too long to schedule: nothing more to sample before the stop.
            stop.await;
            return Ok(taken);
        };
        tokio::select! {
            () = tokio::time::sleep_until(next) => {}
            () = &mut stop => return Ok(taken),
        }
    }
}

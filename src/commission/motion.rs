//! `move` and `force`: drive one servo to a position, switch its force on, off or to brake.
//!
//! A servo moves only with force on. `move` refuses when force is off unless asked to switch it
//! on first; force on makes the present position the goal, so nothing jumps. Every write is
//! acknowledged and read back; the servo's own refusals (force on while the rod is outside the
//! limits or after a temperature error) are reported with their reason.

use super::link::{Link, LinkError};
use super::{CommissionError, require_servo};
use crate::protocol::registers::addr;
use crate::protocol::{
    Destination, ForceMode, MemoryMap, MmCenti, Ms10, ReplyFlags, ReplyRequest, ServoId,
    ShortPacket, Telemetry,
};
use std::time::{Duration, Instant};

/// Slowest rod speed assumed when waiting for a move without a goal time (the servo does
/// 105 mm/s unloaded at 14.8 V; less at lower voltage or under load).
const SLOWEST_SPEED_MM_S: f64 = 40.0;
/// Waiting for arrival gives up this long after the expected end of the move.
const ARRIVAL_ALLOWANCE: Duration = Duration::from_millis(1500);
/// Present position is quantised to about 0.02 mm: arrival allows this beyond the margin.
const RESOLUTION: MmCenti = MmCenti(2);

/// What `move` is asked to do.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MoveOptions {
    pub goal: MmCenti,
    /// Travel time (`None`: as fast as the servo can).
    pub time: Option<Ms10>,
    /// Switch force on first if it is off.
    pub force_on: bool,
    /// Wait until the servo reports arrival (or gives up after the expected travel time).
    pub wait: bool,
}

/// What `move` did.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveReport {
    pub id: ServoId,
    pub requested: MmCenti,
    /// The Goal Position register after the write (the servo clamps it to its limits).
    pub goal: MmCenti,
    pub switched_force_on: bool,
    /// Present position when the command finished.
    pub position: MmCenti,
    /// The servo reported a position within its compliance margin of the goal.
    pub arrived: bool,
    /// Whether the command waited for arrival.
    pub waited: bool,
    pub elapsed: Duration,
}

impl MoveReport {
    /// The servo clamped the goal to a position limit.
    pub fn clamped(&self) -> bool {
        self.goal != self.requested
    }
}

/// What `force` did.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceReport {
    pub id: ServoId,
    pub before: Option<ForceMode>,
    pub after: ForceMode,
    pub position: MmCenti,
    pub flags: ReplyFlags,
}

fn force_name(mode: Option<ForceMode>) -> &'static str {
    match mode {
        Some(ForceMode::Off) => "off",
        Some(ForceMode::On) => "on",
        Some(ForceMode::Brake) => "brake",
        None => "unknown",
    }
}

/// Force mode as a word (`on`, `off`, `brake`).
pub fn force_label(mode: ForceMode) -> &'static str {
    force_name(Some(mode))
}

async fn read_ram(link: &mut Link, id: ServoId) -> Result<(MemoryMap, ReplyFlags), LinkError> {
    let mut map = MemoryMap::default();
    let ram = link.read(id, ReplyRequest::Registers30To59).await?;
    map.store(ram.address, &ram.data);
    Ok((map, ram.flags))
}

fn refused_force_on(id: ServoId, rom: &MemoryMap, ram: &MemoryMap, flags: ReplyFlags) -> String {
    let position = ram.telemetry().present_position;
    let reason = if flags.temperature_error() {
        "its temperature error is latched: let it cool, then power-cycle it".to_string()
    } else if position < rom.minus_limit() || position > rom.plus_limit() {
        format!(
            "the rod is at {position}, outside the limits {} … {}: move it back inside by hand first",
            rom.minus_limit(),
            rom.plus_limit()
        )
    } else {
        "force enable still reads off".to_string()
    };
    format!("servo {id} refused force on: {reason}")
}

/// Write Force Enable and check that the servo took it.
async fn write_force(
    link: &mut Link,
    id: ServoId,
    mode: ForceMode,
    rom: &MemoryMap,
) -> Result<(MemoryMap, ReplyFlags), CommissionError> {
    let packet = ShortPacket::write(
        Destination::Servo(id),
        addr::FORCE_ENABLE,
        &[mode as u8],
        ReplyRequest::Ack,
    )?;
    link.transact(&packet).await?;
    let (ram, flags) = read_ram(link, id).await?;
    let now = ram.force_mode().ok();
    if now != Some(mode) {
        if mode == ForceMode::On {
            return Err(CommissionError::Failed(refused_force_on(
                id, rom, &ram, flags,
            )));
        }
        return Err(CommissionError::Verify {
            id,
            what: "force enable".into(),
            expected: force_label(mode).into(),
            got: force_name(now).into(),
            hint: String::new(),
        });
    }
    Ok((ram, flags))
}

/// Switch servo `id`'s force on, off or to brake.
pub async fn set_force(
    link: &mut Link,
    id: ServoId,
    mode: ForceMode,
) -> Result<ForceReport, CommissionError> {
    let rom = require_servo(link, id).await?;
    let (before, _) = read_ram(link, id).await?;
    let (after, flags) = write_force(link, id, mode, &rom).await?;
    Ok(ForceReport {
        id,
        before: before.force_mode().ok(),
        after: mode,
        position: after.telemetry().present_position,
        flags,
    })
}

/// Move servo `id` to `options.goal`; see the module docs.
pub async fn move_to(
    link: &mut Link,
    id: ServoId,
    options: MoveOptions,
) -> Result<MoveReport, CommissionError> {
    let started = Instant::now();
    let [p0, p1] = options.goal.within_stroke()?.to_le_bytes();
    // Goal time is always written: a time left from an earlier move would slow this one.
    let [t0, t1] = options.time.unwrap_or_default().0.to_le_bytes();
    let goal_packet = ShortPacket::write(
        Destination::Servo(id),
        addr::GOAL_POSITION,
        &[p0, p1, t0, t1],
        ReplyRequest::Ack,
    )?;
    let rom = require_servo(link, id).await?;
    let (ram, _) = read_ram(link, id).await?;
    let mut switched_force_on = false;
    match ram.force_mode() {
        Ok(ForceMode::On) => {}
        other => {
            if !options.force_on {
                return Err(CommissionError::Refused {
                    reason: format!(
                        "servo {id} has force {} and would not move; add --force-on to switch force on first (force on holds the present position, so nothing jumps)",
                        force_name(other.ok())
                    ),
                });
            }
            write_force(link, id, ForceMode::On, &rom).await?;
            switched_force_on = true;
        }
    }
    link.transact(&goal_packet).await?;
    let (ram, _) = read_ram(link, id).await?;
    let goal = ram.goal_position();
    let mut position = ram.telemetry().present_position;
    let (plus_margin, minus_margin) = rom.compliance_margins();
    let arrived_at = |p: MmCenti| {
        let error = i32::from(p.0) - i32::from(goal.0);
        let margin = if error >= 0 {
            plus_margin
        } else {
            minus_margin
        };
        error.abs() <= i32::from(margin) + i32::from(RESOLUTION.0)
    };
    let mut arrived = arrived_at(position);
    if options.wait && !arrived {
        let travel_mm = (goal.mm() - position.mm()).abs();
        let travel = Duration::from_secs_f64(travel_mm / SLOWEST_SPEED_MM_S);
        let planned = Duration::from_millis(u64::from(options.time.unwrap_or_default().millis()));
        let deadline = Instant::now() + travel.max(planned) + ARRIVAL_ALLOWANCE;
        while Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(20)).await;
            let live = link.read(id, ReplyRequest::Registers42To59).await?;
            if let Ok(t) = live.telemetry() {
                position = t.present_position;
                if arrived_at(position) {
                    arrived = true;
                    break;
                }
            }
        }
    }
    Ok(MoveReport {
        id,
        requested: options.goal,
        goal,
        switched_force_on,
        position,
        arrived,
        waited: options.wait,
        elapsed: started.elapsed(),
    })
}

/// Registers 42–59 of servo `id`, once.
pub async fn telemetry(
    link: &mut Link,
    id: ServoId,
) -> Result<(Telemetry, ReplyFlags), CommissionError> {
    let live = link.read(id, ReplyRequest::Registers42To59).await?;
    let t = live
        .telemetry()
        .map_err(|e| CommissionError::Failed(format!("servo {id}: {e}")))?;
    Ok((t, live.flags))
}

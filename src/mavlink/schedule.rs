//! When each telemetry carrier goes out, sans-IO: NAMED_VALUE_FLOAT, ESC_INFO and ESC_STATUS
//! each at the rate of the mapping's `[telemetry]` table, and a NAMED_VALUE_FLOAT value only
//! when it has changed since it was last sent, or after [`NAMED_VALUE_REFRESH_S`] without a
//! send (for a ground station that connects late). A servo going offline or raising a failure
//! flag sends ESC_INFO at the next look (the NAMED_VALUE_FLOAT rate) instead of waiting for its
//! own slower rate. Each servo's state (NAMED_VALUE_INT `LJ9_<label>`, for a script on the
//! autopilot) goes out every [`STATE_REFRESH`] and, when it changes, within [`STATE_LOOK`].
//! Everything the bridge sends is forwarded by
//! the autopilot to every link, a 57 600-baud telemetry radio included.

use super::health::ServoReport;
use super::telemetry;
use crate::config::mavlink::NAMED_VALUE_REFRESH_S;
use crate::config::{Config, Quantity};
use mavlink::dialects::common::MavMessage;
use std::time::{Duration, Instant};

/// How often the servos' states are compared with those last sent.
pub const STATE_LOOK: Duration = Duration::from_millis(100);
/// Each servo's state goes out at least this often (a script counts a state not heard for its
/// timeout, 3 s by default, as the servo lost).
pub const STATE_REFRESH: Duration = Duration::from_secs(1);

/// See the module docs.
#[derive(Debug)]
pub struct TelemetrySchedule {
    started: Instant,
    next_named: Instant,
    next_esc_info: Instant,
    next_esc_status: Instant,
    esc_counter: u16,
    /// Per servo, per quantity (in [`Quantity::ALL`] order): the value last sent and when.
    sent: Vec<[Option<(f32, Instant)>; 4]>,
    /// Per block of four: the online bits and failure flags of the ESC_INFO last sent.
    esc_state_sent: Vec<(u8, [u16; 4])>,
    next_state_look: Instant,
    next_state_refresh: Instant,
    /// Per servo: the state bits last sent.
    state_sent: Vec<Option<i32>>,
}

/// What ESC_INFO says of the servos' state (not their measurements), per block.
fn esc_states(blocks: &[MavMessage]) -> Vec<(u8, [u16; 4])> {
    blocks
        .iter()
        .filter_map(|m| match m {
            MavMessage::ESC_INFO(i) => Some((i.info, i.failure_flags)),
            _ => None,
        })
        .collect()
}

fn period(hz: f32) -> Duration {
    Duration::from_secs_f32(1.0 / hz.max(0.1))
}

/// The next time after `now` on the grid of `hz` that `next` is on: the rate holds however
/// late the caller is, without a burst to catch up.
fn advance(next: &mut Instant, hz: f32, now: Instant) {
    *next += period(hz);
    if *next <= now {
        *next = now + period(hz);
    }
}

impl TelemetrySchedule {
    pub fn new(servos: usize, now: Instant) -> Self {
        TelemetrySchedule {
            started: now,
            next_named: now,
            next_esc_info: now,
            next_esc_status: now,
            esc_counter: 0,
            sent: vec![[None; 4]; servos],
            esc_state_sent: Vec::new(),
            next_state_look: now,
            next_state_refresh: now,
            state_sent: vec![None; servos],
        }
    }

    /// When [`TelemetrySchedule::due`] next has something to send.
    pub fn next_deadline(&self) -> Instant {
        self.next_named
            .min(self.next_esc_info)
            .min(self.next_esc_status)
            .min(self.next_state_look)
    }

    /// The messages due at `now` for the servos' `reports` (mapping order); `failsafe(i)`:
    /// servo `i` holds its failsafe position.
    pub fn due(
        &mut self,
        cfg: &Config,
        reports: &[ServoReport],
        failsafe: impl Fn(usize) -> bool,
        now: Instant,
    ) -> Vec<MavMessage> {
        let t = &cfg.telemetry;
        let since_boot = now.duration_since(self.started);
        let us = since_boot.as_micros().min(u128::from(u64::MAX)) as u64;
        let mut out = Vec::new();
        if now >= self.next_named {
            advance(&mut self.next_named, t.rate_hz, now);
            if t.named_value_float {
                let ms = since_boot.as_millis().min(u128::from(u32::MAX)) as u32;
                self.named_values(cfg, reports, ms, now, &mut out);
            }
            if t.esc {
                let blocks = telemetry::esc_info_blocks(reports, t.esc_index_base, us, 0);
                if esc_states(&blocks) != self.esc_state_sent {
                    self.next_esc_info = now;
                }
            }
        }
        if now >= self.next_esc_info {
            advance(&mut self.next_esc_info, t.esc_info_hz, now);
            if t.esc && !reports.is_empty() {
                self.esc_counter = self.esc_counter.wrapping_add(1);
                let base = t.esc_index_base;
                let blocks = telemetry::esc_info_blocks(reports, base, us, self.esc_counter);
                self.esc_state_sent = esc_states(&blocks);
                out.extend(blocks);
            }
        }
        if now >= self.next_esc_status {
            advance(&mut self.next_esc_status, t.esc_status_hz, now);
            if t.esc && !reports.is_empty() {
                out.extend(telemetry::esc_status_blocks(reports, t.esc_index_base, us));
            }
        }
        if now >= self.next_state_look {
            self.next_state_look = now + STATE_LOOK;
            let all = now >= self.next_state_refresh;
            if all {
                self.next_state_refresh = now + STATE_REFRESH;
            }
            if t.servo_state {
                let ms = since_boot.as_millis().min(u128::from(u32::MAX)) as u32;
                self.states(cfg, reports, &failsafe, all, ms, &mut out);
            }
        }
        out
    }

    /// Each servo's state whose bits changed since last sent, or every one when `all`.
    fn states(
        &mut self,
        cfg: &Config,
        reports: &[ServoReport],
        failsafe: impl Fn(usize) -> bool,
        all: bool,
        ms: u32,
        out: &mut Vec<MavMessage>,
    ) {
        let servos = cfg.servos.iter().zip(reports).zip(&mut self.state_sent);
        for (i, ((servo, report), sent)) in servos.enumerate() {
            let bits = telemetry::state_bits(report, failsafe(i));
            if all || *sent != Some(bits) {
                *sent = Some(bits);
                out.push(telemetry::servo_state(&servo.label, bits, ms));
            }
        }
    }

    fn named_values(
        &mut self,
        cfg: &Config,
        reports: &[ServoReport],
        ms: u32,
        now: Instant,
        out: &mut Vec<MavMessage>,
    ) {
        let refresh = Duration::from_secs(NAMED_VALUE_REFRESH_S);
        for ((servo, report), sent) in cfg.servos.iter().zip(reports).zip(&mut self.sent) {
            for &q in servo.named_values(&cfg.telemetry) {
                let Some(value) = telemetry::quantity(report, q) else {
                    continue;
                };
                let slot = &mut sent[quantity_index(q)];
                let fresh = match slot {
                    Some((last, at)) => *last == value && now.duration_since(*at) < refresh,
                    None => false,
                };
                if fresh {
                    continue;
                }
                *slot = Some((value, now));
                out.push(telemetry::named_value(&servo.label, q, value, ms));
            }
        }
    }
}

fn quantity_index(q: Quantity) -> usize {
    Quantity::ALL.iter().position(|x| *x == q).unwrap_or(0)
}

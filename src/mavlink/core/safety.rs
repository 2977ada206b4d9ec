//! ArduPilot's safety switch, obeyed: while it is on, ArduPilot drives only the outputs of its
//! `BRD_SAFETY_MASK`, but its SERVO_OUTPUT_RAW goes on reporting what it would output
//! (`hal.rcout->read()`). So the bridge watches the autopilot's SYS_STATUS
//! (`MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS` present and not enabled: the safety is on), reads
//! `BRD_SAFETY_MASK` from the autopilot, and meanwhile moves no servo whose output is not in
//! the mask: each does as the mapping's `[bridge] while_safe` says, by default holding its
//! last goal, as a servo on the autopilot's own output does without its pulse (or force off,
//! or brake). Until the mask is read, no servo moves. A servo may still be switched off or
//! braked (a failsafe action that moves nothing); a failsafe position waits too.
//!
//! PX4 has no safety mask and reports its outputs' disarmed values itself: only an ArduPilot
//! autopilot's SYS_STATUS counts.

use super::{AUTOPILOT_LINK, BridgeCore, LinkId, Outgoing};
use crate::bus::Goal;
use crate::config::bridge::ForceAction;
use crate::mavlink::health::BridgeEvent;
use mavlink::dialects::common::{
    MavMessage, MavSysStatusSensor, PARAM_REQUEST_READ_DATA, PARAM_VALUE_DATA, SYS_STATUS_DATA,
};
use std::time::{Duration, Instant};

/// The autopilot's parameter of the outputs that move with the safety on.
pub const SAFETY_MASK_PARAM: &str = "BRD_SAFETY_MASK";

/// How often the mask is asked for while it is not known.
const ASK_AGAIN: Duration = Duration::from_secs(1);

/// How long an ArduPilot autopilot may go without a SYS_STATUS before the user is told that
/// its safety switch cannot be seen: five periods of its default 1 Hz.
pub const NO_STATUS_AFTER: Duration = Duration::from_secs(5);

/// An ArduPilot autopilot's SYS_STATUS as the bridge reads it: its motor outputs present, and
/// enabled unless its safety switch is on (the other sensors' bits are left out).
pub fn sys_status(safety_on: bool) -> MavMessage {
    let outputs = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS;
    MavMessage::SYS_STATUS(SYS_STATUS_DATA {
        onboard_control_sensors_present: outputs,
        onboard_control_sensors_enabled: if safety_on {
            MavSysStatusSensor::empty()
        } else {
            outputs
        },
        onboard_control_sensors_health: outputs,
        ..Default::default()
    })
}

/// What the bridge knows of the autopilot's safety switch.
#[derive(Debug, Default)]
pub(super) struct Safety {
    /// The autopilot is ArduPilot (its HEARTBEAT says so).
    ardupilot: bool,
    /// Its SYS_STATUS says the outputs are held safe.
    on: bool,
    /// `BRD_SAFETY_MASK`, once read: bit n-1 is output n.
    mask: Option<u32>,
    asked_at: Option<Instant>,
    /// When its first HEARTBEAT came, until its first SYS_STATUS has (then `None`).
    unseen_since: Option<Instant>,
    /// Its SYS_STATUS has come at least once.
    status_heard: bool,
    /// The user was told that no SYS_STATUS comes.
    told: bool,
}

impl Safety {
    /// What goes to a servo on `channel` for `goal` now: the goal itself, or while the safety
    /// holds that servo, `while_safe` in place of a move (`None`: nothing, it holds).
    pub(super) fn gate(&self, channel: u8, goal: Goal, while_safe: ForceAction) -> Option<Goal> {
        let moves = matches!(goal, Goal::Position(_));
        let in_mask =
            (1..=32).contains(&channel) && self.mask.is_some_and(|m| m & (1 << (channel - 1)) != 0);
        if !(self.on && moves && !in_mask) {
            return Some(goal);
        }
        match while_safe {
            ForceAction::Hold => None,
            ForceAction::Off => Some(Goal::Off),
            ForceAction::Brake => Some(Goal::Brake),
        }
    }
}

impl BridgeCore {
    /// The autopilot's HEARTBEAT: which autopilot it is.
    pub(super) fn safety_heartbeat(&mut self, ardupilot: bool, now: Instant) {
        self.safety.ardupilot = ardupilot;
        if !ardupilot {
            self.safety.on = false;
        } else if !self.safety.status_heard && self.safety.unseen_since.is_none() {
            self.safety.unseen_since = Some(now);
        }
    }

    /// An ArduPilot autopilot that sends the bridge no SYS_STATUS: its safety switch cannot be
    /// seen, and the servos follow the outputs whatever it says. Said once, as a warning.
    pub(super) fn check_safety_status(&mut self, now: Instant) {
        let s = &mut self.safety;
        if !s.ardupilot || s.status_heard || s.told {
            return;
        }
        if s.unseen_since
            .is_some_and(|at| now.saturating_duration_since(at) >= NO_STATUS_AFTER)
        {
            s.told = true;
            self.notes.push(format!(
                "no SYS_STATUS from the autopilot in {} s: the bridge cannot see ArduPilot's safety \
                 switch, and the servos follow its outputs whatever the switch says. Stream \
                 EXTENDED_STATUS to the bridge's port at 1 Hz or more (MAVn_EXT_STAT, SRn_EXT_STAT \
                 before 4.7)",
                NO_STATUS_AFTER.as_secs()
            ));
        }
    }

    /// SYS_STATUS from the autopilot on its link.
    pub(super) fn handle_sys_status(
        &mut self,
        link: LinkId,
        from: (u8, u8),
        s: &SYS_STATUS_DATA,
        now: Instant,
    ) {
        if link != AUTOPILOT_LINK || Some(from) != self.autopilot || !self.safety.ardupilot {
            return;
        }
        self.safety.status_heard = true;
        self.safety.unseen_since = None;
        let outputs = MavSysStatusSensor::MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS;
        let on = s.onboard_control_sensors_present.contains(outputs)
            && !s.onboard_control_sensors_enabled.contains(outputs);
        if on != self.safety.on {
            self.safety.on = on;
            let servos = self.cfg.bridge.while_safe;
            self.event(BridgeEvent::Safety { on, servos }, now);
        }
        self.ask_safety_mask(now);
    }

    /// PARAM_VALUE from the autopilot on its link: the mask when it is the mask.
    pub(super) fn handle_autopilot_param(
        &mut self,
        link: LinkId,
        from: (u8, u8),
        p: &PARAM_VALUE_DATA,
    ) {
        if link != AUTOPILOT_LINK
            || Some(from) != self.autopilot
            || p.param_id.to_str().ok() != Some(SAFETY_MASK_PARAM)
            || !(p.param_value.is_finite() && p.param_value >= 0.0)
        {
            return;
        }
        self.safety.mask = Some(p.param_value.round() as u32);
    }

    /// While the safety is on and the mask unknown, ask for it (again every [`ASK_AGAIN`]).
    fn ask_safety_mask(&mut self, now: Instant) {
        let Some((target_system, target_component)) = self.autopilot else {
            return;
        };
        let due = self
            .safety
            .asked_at
            .is_none_or(|at| now.saturating_duration_since(at) >= ASK_AGAIN);
        if !self.safety.on || self.safety.mask.is_some() || !due {
            return;
        }
        self.safety.asked_at = Some(now);
        let mut param_id = [0u8; 16];
        param_id[..SAFETY_MASK_PARAM.len()].copy_from_slice(SAFETY_MASK_PARAM.as_bytes());
        self.outgoing.push_back(Outgoing {
            message: MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
                param_index: -1,
                target_system,
                target_component,
                param_id: param_id.into(),
            }),
            link: Some(AUTOPILOT_LINK),
            sender: None,
        });
    }
}

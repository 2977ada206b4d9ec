//! Commands to the bridge, carried out and answered: DO_SET_SERVO and DO_SET_ACTUATOR (from the
//! autopilot's link only), REQUEST_MESSAGE for what the bridge is. Which commands are the
//! bridge's, and how a broadcast is treated, is [`crate::mavlink::commands`]'s.

use super::{AUTOPILOT_LINK, BridgeCore, LinkId, Outgoing};
use crate::bus::Goal;
use crate::mavlink::commands::{Command, Handling, handling};
use mavlink::dialects::common::{
    AUTOPILOT_VERSION_DATA, COMMAND_ACK_DATA, COMPONENT_INFORMATION_BASIC_DATA, MavCmd, MavMessage,
    MavProtocolCapability, MavResult,
};
use std::time::Instant;

/// The messages that say what a component is.
const AUTOPILOT_VERSION_ID: u32 = 148;
const COMPONENT_INFORMATION_BASIC_ID: u32 = 396;

/// The bridge's version as AUTOPILOT_VERSION carries it: major, minor, patch, then the
/// release type (255: official).
fn software_version() -> u32 {
    let part = |s: &str| s.parse::<u32>().unwrap_or(0).min(255);
    (part(env!("CARGO_PKG_VERSION_MAJOR")) << 24)
        | (part(env!("CARGO_PKG_VERSION_MINOR")) << 16)
        | (part(env!("CARGO_PKG_VERSION_PATCH")) << 8)
        | 255
}

impl BridgeCore {
    /// A command (DO_SET_SERVO, DO_SET_ACTUATOR) moves servo `i`: like an output message
    /// carrying its channel, it ends the servo's failsafe and restarts the watch for it.
    fn command_override(&mut self, i: usize, command: Goal, now: Instant) {
        let slot = &mut self.servos[i];
        slot.carried_at = Some(now);
        slot.failsafe = false;
        slot.ticked = true;
        self.command(i, command);
    }

    pub(super) fn handle_command(
        &mut self,
        link: LinkId,
        from: (u8, u8),
        cmd: &Command,
        now: Instant,
    ) {
        let Some(system_id) = self.system_id else {
            return;
        };
        let how = handling(cmd, (system_id, self.cfg.mavlink.component_id));
        if how == Handling::Ignore {
            return;
        }
        let moves = matches!(
            cmd.command,
            MavCmd::MAV_CMD_DO_SET_SERVO | MavCmd::MAV_CMD_DO_SET_ACTUATOR
        );
        let result = match cmd.command {
            // What moves the servos comes from the autopilot's link only: the ground-station
            // link is a view (see docs/mavlink.md). Addressed to the bridge: DENIED, so that
            // the ground station says why; a broadcast is ignored, as any other refusal of one.
            _ if moves && link != AUTOPILOT_LINK => MavResult::MAV_RESULT_DENIED,
            // One source commands the servos: with DroneCAN's, MAVLink moves nothing.
            _ if moves && self.dronecan_commands() => MavResult::MAV_RESULT_DENIED,
            MavCmd::MAV_CMD_DO_SET_SERVO => self.do_set_servo(cmd.params[0], cmd.params[1], now),
            MavCmd::MAV_CMD_DO_SET_ACTUATOR => self.do_set_actuator(&cmd.params, now),
            MavCmd::MAV_CMD_REQUEST_MESSAGE if how == Handling::Own => {
                self.describe_self(cmd.params[0], now)
            }
            // Superseded by REQUEST_MESSAGE, and still sent by ground stations of the time.
            #[allow(deprecated)]
            MavCmd::MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES if how == Handling::Own => {
                self.describe_self(AUTOPILOT_VERSION_ID as f32, now)
            }
            _ => MavResult::MAV_RESULT_UNSUPPORTED,
        };
        if how == Handling::Broadcast && result != MavResult::MAV_RESULT_ACCEPTED {
            // None of ours: the autopilot's answer is the one that counts.
            return;
        }
        self.outgoing.push_back(Outgoing {
            message: MavMessage::COMMAND_ACK(COMMAND_ACK_DATA {
                command: cmd.command,
                result,
                progress: 0,
                result_param2: 0,
                target_system: from.0,
                target_component: from.1,
            }),
            link: Some(link),
            sender: None,
        });
        // The protocol: the ACK first, then the message asked for.
        if result == MavResult::MAV_RESULT_ACCEPTED
            && let Some(message) = self.described.take()
        {
            self.outgoing.push_back(Outgoing {
                message,
                link: Some(link),
                sender: None,
            });
        }
    }

    /// MAV_CMD_REQUEST_MESSAGE for AUTOPILOT_VERSION or COMPONENT_INFORMATION_BASIC: what the
    /// bridge is (name, version, and that it speaks MAVLink 2 with C-cast parameters), which
    /// ground stations show for a component. Any other message is DENIED.
    fn describe_self(&mut self, message_id: f32, now: Instant) -> MavResult {
        let capabilities = MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
            | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | MavProtocolCapability::MAV_PROTOCOL_CAPABILITY_COMMAND_INT;
        let message = if message_id == AUTOPILOT_VERSION_ID as f32 {
            MavMessage::AUTOPILOT_VERSION(AUTOPILOT_VERSION_DATA {
                capabilities,
                flight_sw_version: software_version(),
                ..Default::default()
            })
        } else if message_id == COMPONENT_INFORMATION_BASIC_ID as f32 {
            MavMessage::COMPONENT_INFORMATION_BASIC(COMPONENT_INFORMATION_BASIC_DATA {
                capabilities,
                time_boot_ms: u32::try_from(now.duration_since(self.started).as_millis())
                    .unwrap_or(u32::MAX),
                vendor_name: "lj9da-bridge".into(),
                model_name: "LJ9DA41 RS485 servo bridge".into(),
                software_version: env!("CARGO_PKG_VERSION").into(),
                ..Default::default()
            })
        } else {
            return MavResult::MAV_RESULT_DENIED;
        };
        self.described = Some(message);
        MavResult::MAV_RESULT_ACCEPTED
    }

    /// MAV_CMD_DO_SET_SERVO: param 1 = output channel, param 2 = PWM in µs. Denied, and
    /// nothing moves, unless the channel has a servo and the PWM is inside the PWM range of
    /// every servo on it: a pulse the servo would only hold on is not a command carried out.
    fn do_set_servo(&mut self, channel: f32, us: f32, now: Instant) -> MavResult {
        let valid = (1.0..=32.0).contains(&channel) && (0.0..=65535.0).contains(&us);
        if !valid {
            return MavResult::MAV_RESULT_DENIED;
        }
        let (channel, us) = (channel.round() as u8, us.round() as u16);
        let targets: Vec<usize> = (0..self.servos.len())
            .filter(|i| self.servos[*i].channel == channel)
            .collect();
        let mut positions = Vec::with_capacity(targets.len());
        for &i in &targets {
            match self.cfg.servos[i].map_pwm(us) {
                Some(position) => positions.push((i, position)),
                None => return MavResult::MAV_RESULT_DENIED,
            }
        }
        if positions.is_empty() {
            return MavResult::MAV_RESULT_DENIED;
        }
        for (i, position) in positions {
            self.servos[i].override_latch = Some(self.channels[usize::from(channel)]);
            self.command_override(i, Goal::Position(position), now);
        }
        MavResult::MAV_RESULT_ACCEPTED
    }

    /// MAV_CMD_DO_SET_ACTUATOR: params 1–6 = −1…+1 for actuators 1–6 of the set in param 7
    /// (set 0 = actuators 1–6, set 1 = 7–12, …); NaN leaves an actuator as it is. A value
    /// outside −1…+1 (the spec's bounds) denies the whole command, and nothing moves.
    fn do_set_actuator(&mut self, params: &[f32; 7], now: Instant) -> MavResult {
        let index = params[6];
        if !index.is_finite() || !(0.0..=20.0).contains(&index) {
            return MavResult::MAV_RESULT_DENIED;
        }
        let set = index.round() as u16;
        let params: [f32; 6] = std::array::from_fn(|k| params[k]);
        if params
            .iter()
            .any(|v| !v.is_nan() && !(-1.0..=1.0).contains(v))
        {
            return MavResult::MAV_RESULT_DENIED;
        }
        let mut matched = false;
        for (k, value) in params.into_iter().enumerate() {
            let actuator = set * 6 + k as u16 + 1;
            if value.is_nan() {
                continue;
            }
            for i in 0..self.servos.len() {
                if self.cfg.servos[i].actuator.map(u16::from) != Some(actuator) {
                    continue;
                }
                matched = true;
                let command = match self.cfg.servos[i].map_normalized(value) {
                    Some(position) => Goal::Position(position),
                    None => Goal::Hold,
                };
                let channel = usize::from(self.servos[i].channel);
                self.servos[i].override_latch = Some(self.channels.get(channel).copied().flatten());
                self.command_override(i, command, now);
            }
        }
        if matched {
            MavResult::MAV_RESULT_ACCEPTED
        } else {
            MavResult::MAV_RESULT_DENIED
        }
    }
}

//! The bridge's MAVLink logic, sans-IO: it is handed MAVLink messages, servo reports, events
//! and the time, and answers with servo commands and MAVLink messages to send. It never touches
//! a socket or reads the clock, so every rule below is tested at exact instants.
//!
//! Rules:
//! - Only output messages from the autopilot (configured, or learned from the first
//!   autopilot HEARTBEAT on the autopilot's link) that arrive on the autopilot's link
//!   ([`AUTOPILOT_LINK`]) are obeyed; commands (COMMAND_LONG or COMMAND_INT) are obeyed and
//!   answered when addressed to the bridge, and broadcast ones as [`super::commands`] says,
//!   but DO_SET_SERVO and DO_SET_ACTUATOR only from the autopilot's link: on the
//!   ground-station link ([`GCS_LINK`]) they move nothing (DENIED when addressed to the
//!   bridge).
//! - Each output channel maps to its servos through the PWM-mode law of the mapping file; a
//!   value that means "no output" makes the servo hold.
//! - The output stream is requested with MAV_CMD_SET_MESSAGE_INTERVAL until it arrives. A
//!   denial that can only be about the rate (DENIED for a rate above 40 Hz, which ArduPilot
//!   gives above 0.8 × SCHED_LOOP_RATE) is retried lower, and the user is told once which
//!   parameter limits it. Any other refusal (DENIED at 40 Hz or less, UNSUPPORTED, FAILED, …)
//!   means the autopilot does not provide the message: the requests stop and the user is told
//!   once, in the log and by STATUSTEXT.
//! - Failsafe is per servo, kept by the messages that carry its channel (SERVO_OUTPUT_RAW
//!   port 0 carries channels 1–16, port 1 channels 17–32; ACTUATOR_OUTPUT_STATUS the channels
//!   it marks active). No output message at all for the failsafe timeout: every servo takes its
//!   failsafe action, announced once for the bridge; the first output message ends it for the
//!   servos it carries. Output messages that keep coming without a servo's channel for the
//!   timeout: that servo takes its failsafe action, announced once for the servo, until a
//!   message carries its channel again. A DO_SET_SERVO or DO_SET_ACTUATOR that moves a servo
//!   ends its failsafe like a message carrying its channel. A servo with an `actuator` key
//!   whose channel no output message has ever carried is driven by commands alone: only the
//!   stream's failsafe applies to it.
//! - While ArduPilot's safety switch is on (its SYS_STATUS), a servo off its
//!   `BRD_SAFETY_MASK` gets no goal that moves it (`core/safety.rs`).
//! - The autopilot's HEARTBEAT is relayed to the ground-station link (`[mavlink] gcs`), so
//!   that QGroundControl, which creates a vehicle only from an autopilot's HEARTBEAT, shows
//!   the bridge's messages there.
//! - HEARTBEAT at 1 Hz, servo telemetry as [`super::schedule`] says, STATUSTEXT once per
//!   event.

mod commands;
mod safety;
pub use safety::{NO_STATUS_AFTER, sys_status};

use super::commands::Command;
use super::health::{BridgeEvent, ServoReport};
use super::outputs::{ChannelValues, from_actuator_output_status, from_servo_output_raw};
use super::param_server::{ParamOut, ParamServer, ParamSet};
use super::params::{ServoInfo, copy_tunables};
use super::rate::{LOW_SHARE, RateMeter};
use super::schedule::TelemetrySchedule;
use super::statustext::{Throttle, describe, with_folded};
use super::telemetry;
use crate::bus::Goal;
use crate::config::{CommandSource, Config, FailsafeAction, Source};
use crate::dronecan::messages as can;
use mavlink::MavHeader;
use mavlink::dialects::common::{
    COMMAND_LONG_DATA, MavAutopilot, MavCmd, MavMessage, MavResult, MavType,
};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Which MAVLink link a message came in on or goes out on (0 = the autopilot's link).
pub type LinkId = usize;
pub const AUTOPILOT_LINK: LinkId = 0;

/// The extra link for a ground station (`[mavlink] gcs`), when there is one.
pub const GCS_LINK: LinkId = 1;

/// A message to send: on one link, or on every link.
#[derive(Debug, Clone, PartialEq)]
pub struct Outgoing {
    pub message: MavMessage,
    pub link: Option<LinkId>,
    /// `None`: the bridge's own message, sent with [`BridgeCore::header`] and numbered by the
    /// link. `Some(header)`: another's message relayed under its own ids and sequence number
    /// (the autopilot's HEARTBEAT on the ground-station link), so that a ground station
    /// counting each component's sequence sees neither the bridge's numbers in the
    /// autopilot's nor gaps in the bridge's.
    pub sender: Option<MavHeader>,
}

/// Rates tried, highest first, after the autopilot denies the requested one for its rate:
/// 0.8 × the SCHED_LOOP_RATE values ArduPilot is flown with (400, 300, 200, 100, 50 Hz).
const FALLBACK_RATES_HZ: [f32; 5] = [320.0, 240.0, 160.0, 80.0, 40.0];
/// The highest rate no ArduPilot denies for being too fast: 0.8 × its lowest SCHED_LOOP_RATE
/// (50 Hz). A denial at this rate or below is about the message, not the rate.
const NEVER_TOO_FAST_HZ: f32 = 40.0;
const STREAM_REQUEST_PERIOD: Duration = Duration::from_secs(1);
const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
const STATUSTEXT_HOLD_OFF: Duration = Duration::from_secs(3);

/// MAVLink message ids of the two output messages.
const SERVO_OUTPUT_RAW_ID: u32 = 36;
const ACTUATOR_OUTPUT_STATUS_ID: u32 = 375;

/// A servo's channel missing from the output messages that go on without it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Absence {
    /// Not missing (or not for `failsafe_timeout_ms` yet): watched.
    None,
    /// Missing for the timeout: the failsafe is taken, the text waits for the next output
    /// message that comes without the channel (the stream lives on without it). If the whole
    /// stream stops first, the stream's failsafe text says it all; if the next message carries
    /// the channel, nothing is said.
    Unsaid,
    /// Missing, and said: its return is said too.
    Said,
}

#[derive(Debug)]
struct ServoSlot {
    channel: u8,
    /// The autopilot's value of the channel when a command overrode it: the override holds
    /// until the autopilot's own output for the channel changes.
    override_latch: Option<Option<u16>>,
    last_command: Option<Goal>,
    /// When a message last carried this servo's channel, or when the watch for it began (the
    /// first output message, or the stream's return after a failsafe).
    carried_at: Option<Instant>,
    /// The servo has taken its failsafe action and not yet had its channel back.
    failsafe: bool,
    /// Where its channel's absence stands (once per absence).
    absence: Absence,
    /// Some output message has carried its channel.
    ever_carried: bool,
    /// An output message or command has carried it since [`BridgeCore::take_output_ticks`].
    ticked: bool,
}

/// See the module docs.
#[derive(Debug)]
pub struct BridgeCore {
    cfg: Config,
    started: Instant,
    system_id: Option<u8>,
    autopilot: Option<(u8, u8)>,
    servos: Vec<ServoSlot>,
    /// Latest value of every channel 1–32 from the autopilot.
    channels: [Option<u16>; 33],
    /// Per servo, the latest DroneCAN command of its actuator id (DroneCAN commanding).
    can_commands: Vec<Option<can::Command>>,
    last_output_at: Option<Instant>,
    /// No output message at all for the failsafe timeout.
    stream_failsafe: bool,
    /// The stream runs as asked: the autopilot accepted the rate, or it arrives at ≥ 70 % of it.
    stream_ok: bool,
    /// The stream's rate as received, per port.
    rate: RateMeter,
    requested_rate_hz: f32,
    /// The SCHED_LOOP_RATE advice has been given.
    rate_advice_given: bool,
    /// The autopilot refused the source for another reason than its rate: asking stops.
    source_refused: bool,
    next_stream_request: Instant,
    next_heartbeat: Instant,
    telemetry: TelemetrySchedule,
    throttle: Throttle,
    commands: VecDeque<(usize, Goal)>,
    outgoing: VecDeque<Outgoing>,
    notes: Vec<String>,
    params: ParamServer,
    /// The answer to a MAV_CMD_REQUEST_MESSAGE, sent after its ACK.
    described: Option<MavMessage>,
    /// What was read from each servo (model, firmware), for the read-only parameters.
    servo_info: Vec<ServoInfo>,
    /// The autopilot's clock as its latest output message carried it, for the flight record.
    clock: Option<AutopilotClock>,
    /// When a clock was last handed out by [`BridgeCore::poll_autopilot_clock`].
    clock_taken_at: Option<Instant>,
    /// The autopilot's safety switch (see `core/safety.rs`).
    safety: safety::Safety,
}

/// The autopilot's boot clock as one of its output messages carried it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AutopilotClock {
    /// µs since the autopilot booted (modulo 2³² when `bits` is 32).
    pub time_usec: u64,
    /// The width of the message's field: 32 (SERVO_OUTPUT_RAW) or 64 (ACTUATOR_OUTPUT_STATUS).
    pub bits: u8,
    /// When the message was handled.
    pub at: Instant,
}

impl AutopilotClock {
    /// How often the flight record is given the clock: often enough to follow a restart of
    /// the autopilot or a 32-bit wrap, rarely enough to cost nothing.
    pub const PERIOD: Duration = Duration::from_secs(1);
}

impl BridgeCore {
    pub fn new(cfg: Config, now: Instant) -> Self {
        let servo_count = cfg.servos.len();
        let servos = cfg
            .servos
            .iter()
            .map(|s| ServoSlot {
                channel: s.channel,
                override_latch: None,
                last_command: None,
                carried_at: None,
                failsafe: false,
                absence: Absence::None,
                ever_carried: false,
                ticked: false,
            })
            .collect();
        Self {
            system_id: cfg.mavlink.system_id,
            autopilot: cfg
                .mavlink
                .autopilot_system_id
                .map(|sys| (sys, cfg.mavlink.autopilot_component_id)),
            requested_rate_hz: cfg.mavlink.output_rate_hz,
            rate_advice_given: false,
            source_refused: false,
            servos,
            started: now,
            channels: [None; 33],
            can_commands: vec![None; cfg.servos.len()],
            last_output_at: None,
            stream_failsafe: false,
            stream_ok: false,
            rate: RateMeter::new(
                cfg.mavlink.source,
                cfg.servos.iter().map(|s| s.channel),
                now,
            ),
            next_stream_request: now,
            next_heartbeat: now,
            telemetry: TelemetrySchedule::new(servo_count, now),
            throttle: Throttle::new(STATUSTEXT_HOLD_OFF),
            commands: VecDeque::new(),
            outgoing: VecDeque::new(),
            notes: Vec::new(),
            params: ParamServer::new(&cfg, now),
            described: None,
            servo_info: vec![ServoInfo::default(); servo_count],
            clock: None,
            clock_taken_at: None,
            safety: safety::Safety::default(),
            cfg,
        }
    }

    /// The header of the bridge's own messages, once the vehicle's system id is known.
    pub fn header(&self) -> Option<MavHeader> {
        Some(MavHeader {
            system_id: u32::from(self.system_id?),
            component_id: self.cfg.mavlink.component_id,
            sequence: 0,
        })
    }

    pub fn autopilot(&self) -> Option<(u8, u8)> {
        self.autopilot
    }

    /// Whether an output message of the autopilot's has been obeyed since the start.
    pub fn outputs_heard(&self) -> bool {
        self.last_output_at.is_some()
    }

    /// Some servo is in failsafe (the whole stream is missing, or its channel is).
    pub fn in_failsafe(&self) -> bool {
        self.servos.iter().any(|s| s.failsafe)
    }

    /// Servo `servo` (mapping order) is in failsafe.
    pub fn servo_in_failsafe(&self, servo: usize) -> bool {
        self.servos.get(servo).is_some_and(|s| s.failsafe)
    }

    /// The output rate being asked for now (lower than configured after a denial).
    pub fn requested_rate_hz(&self) -> f32 {
        self.requested_rate_hz
    }

    /// Messages for the user about the autopilot link (e.g. which parameter limits the rate),
    /// to be said as warnings.
    pub fn take_notes(&mut self) -> Vec<String> {
        std::mem::take(&mut self.notes)
    }

    /// New measurements of the output rate received (see [`super::rate`]), to be said as
    /// information.
    pub fn take_rate_news(&mut self) -> Vec<String> {
        self.rate.take_news()
    }

    /// The output rate received per message port over the last measurement (see
    /// [`super::rate`]); empty before the first.
    pub fn received_rates_hz(&self) -> Vec<(u8, f32)> {
        self.rate.received_hz()
    }

    /// Whether [`BridgeCore::handle_message`] acts on a message of this kind (from anyone);
    /// the others it drops at once. The links' readers drop them before they reach the loop
    /// (see [`super::admission`]).
    pub fn handles(msg: &MavMessage) -> bool {
        matches!(
            msg,
            MavMessage::HEARTBEAT(_)
                | MavMessage::COMMAND_LONG(_)
                | MavMessage::COMMAND_INT(_)
                | MavMessage::PARAM_REQUEST_LIST(_)
                | MavMessage::PARAM_REQUEST_READ(_)
                | MavMessage::PARAM_SET(_)
                | MavMessage::COMMAND_ACK(_)
                | MavMessage::SERVO_OUTPUT_RAW(_)
                | MavMessage::ACTUATOR_OUTPUT_STATUS(_)
                | MavMessage::SYS_STATUS(_)
                | MavMessage::PARAM_VALUE(_)
        )
    }

    /// A message arrived on `link`.
    pub fn handle_message(
        &mut self,
        link: LinkId,
        header: &MavHeader,
        msg: &MavMessage,
        now: Instant,
    ) {
        // MAVLink system ids are one byte on the wire; a larger one is no peer of ours.
        let Ok(system_id) = u8::try_from(header.system_id) else {
            return;
        };
        let from = (system_id, header.component_id);
        if let MavMessage::HEARTBEAT(hb) = msg {
            if self.autopilot.is_none()
                && link == AUTOPILOT_LINK
                && hb.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID
                && hb.mavtype != MavType::MAV_TYPE_GCS
                && header.component_id == self.cfg.mavlink.autopilot_component_id
            {
                self.autopilot = Some(from);
                self.system_id.get_or_insert(system_id);
                self.next_stream_request = now;
                tracing::info!(system = from.0, component = from.1, "autopilot found");
            }
            if link == AUTOPILOT_LINK && Some(from) == self.autopilot {
                let ardupilot = hb.autopilot == MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA;
                self.safety_heartbeat(ardupilot, now);
            }
            if link == AUTOPILOT_LINK
                && Some(from) == self.autopilot
                && self.cfg.mavlink.gcs.is_some()
            {
                // QGroundControl creates a vehicle only from an autopilot's HEARTBEAT: without
                // it, the ground-station link would show nothing of the bridge.
                self.outgoing.push_back(Outgoing {
                    message: msg.clone(),
                    link: Some(GCS_LINK),
                    sender: Some(*header),
                });
            }
            return;
        }
        if let MavMessage::COMMAND_LONG(cmd) = msg {
            self.handle_command(link, from, &Command::from_long(cmd), now);
            return;
        }
        if let MavMessage::COMMAND_INT(cmd) = msg {
            self.handle_command(link, from, &Command::from_int(cmd), now);
            return;
        }
        if matches!(
            msg,
            MavMessage::PARAM_REQUEST_LIST(_)
                | MavMessage::PARAM_REQUEST_READ(_)
                | MavMessage::PARAM_SET(_)
        ) {
            if let Some(system_id) = self.system_id {
                let us = (system_id, self.cfg.mavlink.component_id);
                let out = self
                    .params
                    .handle(link, msg, us, &self.cfg, &self.servo_info);
                self.send_params(out);
            }
            return;
        }
        if let MavMessage::SYS_STATUS(status) = msg {
            self.handle_sys_status(link, from, status, now);
            return;
        }
        if let MavMessage::PARAM_VALUE(value) = msg {
            self.handle_autopilot_param(link, from, value);
            return;
        }
        if let MavMessage::COMMAND_ACK(ack) = msg {
            let to_us =
                ack.target_component == 0 || ack.target_component == self.cfg.mavlink.component_id;
            if link == AUTOPILOT_LINK
                && Some(from) == self.autopilot
                && ack.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL
                && to_us
            {
                self.handle_interval_ack(ack.result, now);
            }
            return;
        }
        // The autopilot's outputs are taken from the autopilot's link alone: its ids on another
        // link are anyone's (a replay, a ground station's mistake).
        if link != AUTOPILOT_LINK || Some(from) != self.autopilot {
            return;
        }
        let (port, values, time_usec, bits) = match (msg, self.cfg.mavlink.source) {
            (MavMessage::SERVO_OUTPUT_RAW(m), Source::ServoOutputRaw) => {
                (m.port, from_servo_output_raw(m), u64::from(m.time_usec), 32)
            }
            (MavMessage::ACTUATOR_OUTPUT_STATUS(m), Source::ActuatorOutputStatus) => {
                (0, from_actuator_output_status(m), m.time_usec, 64)
            }
            _ => return,
        };
        // One source commands the servos: with DroneCAN's, the outputs move nothing (the
        // autopilot's clock they carry is still kept for the flight record).
        if !self.dronecan_commands() {
            self.handle_outputs(port, &values, now);
        }
        // A sender that fills in no time (0) has no clock to keep.
        if time_usec != 0 {
            self.clock = Some(AutopilotClock {
                time_usec,
                bits,
                at: now,
            });
        }
    }

    fn handle_outputs(&mut self, port: u8, values: &ChannelValues, now: Instant) {
        if self.stream_failsafe {
            // The rate is measured from the stream's return (see `RateMeter::restart`).
            self.rate.restart(now);
        }
        let carried: Vec<bool> = self
            .servos
            .iter()
            .map(|s| values.get(s.channel).is_some())
            .collect();
        let channels: Vec<u8> = self.servos.iter().map(|s| s.channel).collect();
        self.say_missing(&carried, &channels, now);
        let fastest = self.rate.count(port, self.requested_rate_hz, now);
        self.judge_rate(fastest);
        self.carried(&carried, &channels, now);
        for (channel, us) in values.iter() {
            if let Some(slot) = self.channels.get_mut(usize::from(channel)) {
                *slot = Some(us);
            }
        }
        for i in 0..self.servos.len() {
            let channel = self.servos[i].channel;
            let Some(us) = values.get(channel) else {
                continue;
            };
            if let Some(latched) = self.servos[i].override_latch {
                if latched == Some(us) {
                    continue;
                }
                self.servos[i].override_latch = None;
            }
            let command = match self.cfg.servos[i].map_pwm(us) {
                Some(position) => Goal::Position(position),
                None => Goal::Hold,
            };
            self.command(i, command);
        }
    }

    /// DroneCAN's ArrayCommand, received at `now` (with `[bridge] commands = "dronecan"`; with
    /// MAVLink commanding, it moves nothing): each servo follows the command of its
    /// `dronecan_id`, mapped by [`crate::config::ServoConfig::map_can_command`]; a command it
    /// cannot take (a force, a speed, not a number) or a value that means no output makes it
    /// hold. The failsafe is kept as for output messages: an ArrayCommand stands for one, each
    /// actuator id it carries for a channel.
    pub fn handle_can_commands(&mut self, commands: &[can::Command], now: Instant) {
        let Some(dronecan) = self
            .cfg
            .dronecan
            .as_ref()
            .filter(|_| self.dronecan_commands())
        else {
            return;
        };
        let unitless = dronecan.unitless;
        let wanted: Vec<Option<&can::Command>> = self
            .cfg
            .servos
            .iter()
            .map(|s| {
                commands
                    .iter()
                    .rev()
                    .find(|c| c.actuator_id == s.dronecan_id)
            })
            .collect();
        let carried: Vec<bool> = wanted.iter().map(Option::is_some).collect();
        let goals: Vec<Option<Goal>> = wanted
            .iter()
            .zip(&self.cfg.servos)
            .map(|(c, servo)| {
                c.map(
                    |c| match servo.map_can_command(c.command_type, c.value, unitless) {
                        Some(position) => Goal::Position(position),
                        None => Goal::Hold,
                    },
                )
            })
            .collect();
        for (slot, c) in self.can_commands.iter_mut().zip(&wanted) {
            if let Some(c) = c {
                *slot = Some(**c);
            }
        }
        let ids: Vec<u8> = self.cfg.servos.iter().map(|s| s.dronecan_id).collect();
        self.say_missing(&carried, &ids, now);
        self.carried(&carried, &ids, now);
        for (i, goal) in goals.into_iter().enumerate() {
            if let Some(goal) = goal {
                self.command(i, goal);
            }
        }
    }

    /// The output stream is to be asked for: MAVLink commands the servos, and the stream
    /// neither runs as asked nor was refused.
    fn asks_for_outputs(&self) -> bool {
        !self.dronecan_commands() && !self.stream_ok && !self.source_refused
    }

    /// The servos take their goals from DroneCAN (`[bridge] commands = "dronecan"`).
    fn dronecan_commands(&self) -> bool {
        self.cfg.bridge.commands == CommandSource::DroneCan
    }

    /// A message that stands for the outputs came (`carried`: per servo, whether it carries
    /// the servo's channel, named `numbers[i]` in what is said): a servo whose channel's
    /// absence is not said yet is said missing now if this message goes on without its
    /// channel; if it carries the channel, that was a pause, not an absence, and nothing is
    /// said either way. [`Self::carried`] follows.
    fn say_missing(&mut self, carried: &[bool], numbers: &[u8], now: Instant) {
        self.last_output_at = Some(now);
        let timeout_ms = self.cfg.mavlink.failsafe_timeout_ms;
        for i in 0..self.servos.len() {
            let slot = &mut self.servos[i];
            if slot.absence != Absence::Unsaid {
                continue;
            }
            if carried[i] {
                slot.absence = Absence::None;
            } else {
                slot.absence = Absence::Said;
                let missing = BridgeEvent::ChannelMissing {
                    servo: i,
                    channel: numbers[i],
                    timeout_ms,
                };
                self.event(missing, now);
            }
        }
    }

    /// After [`Self::say_missing`]: the stream's failsafe ends if it was on; the servos whose
    /// channel the message carries leave their failsafe; the watch for the others begins now
    /// if it has not begun, or begins again after the stream's failsafe.
    fn carried(&mut self, carried: &[bool], numbers: &[u8], now: Instant) {
        let stream_back = std::mem::replace(&mut self.stream_failsafe, false);
        if stream_back {
            self.event(BridgeEvent::FailsafeLeft, now);
        }
        for i in 0..self.servos.len() {
            let slot = &mut self.servos[i];
            if !carried[i] {
                if slot.carried_at.is_none() || stream_back {
                    slot.carried_at = Some(now);
                }
                continue;
            }
            slot.carried_at = Some(now);
            slot.ever_carried = true;
            slot.ticked = true;
            slot.failsafe = false;
            if std::mem::replace(&mut slot.absence, Absence::None) == Absence::Said {
                let channel = numbers[i];
                self.event(BridgeEvent::ChannelBack { servo: i, channel }, now);
            }
        }
    }

    /// A measurement window of the rate meter closed with `fastest` the fastest port's rate:
    /// at ≥ 70 % of the rate asked the stream runs as asked, whether or not an ACK said so, and
    /// is not asked for again. The meter's warning, if it has one, goes to the notes.
    fn judge_rate(&mut self, fastest: Option<f32>) {
        if fastest.is_some_and(|hz| hz >= LOW_SHARE * self.requested_rate_hz) {
            self.stream_ok = true;
        }
        self.notes.extend(self.rate.take_warnings());
    }

    fn command(&mut self, servo: usize, command: Goal) {
        let slot = &mut self.servos[servo];
        // Held back by the autopilot's safety switch: not sent, and not taken as sent, so that
        // the same goal goes out once the switch is off; or force off or brake in its place.
        let Some(command) = self
            .safety
            .gate(slot.channel, command, self.cfg.bridge.while_safe)
        else {
            return;
        };
        if slot.last_command != Some(command) {
            slot.last_command = Some(command);
            self.commands.push_back((servo, command));
        }
    }

    fn handle_interval_ack(&mut self, result: MavResult, now: Instant) {
        match result {
            MavResult::MAV_RESULT_ACCEPTED => self.stream_ok = true,
            MavResult::MAV_RESULT_IN_PROGRESS | MavResult::MAV_RESULT_TEMPORARILY_REJECTED => {}
            MavResult::MAV_RESULT_DENIED if self.requested_rate_hz > NEVER_TOO_FAST_HZ => {
                self.step_rate_down();
            }
            _ => self.refuse_source(result, now),
        }
    }

    /// The autopilot denied the rate: ask again at once, lower, and say which parameter
    /// limits it (once).
    fn step_rate_down(&mut self) {
        let denied = self.requested_rate_hz;
        let next = FALLBACK_RATES_HZ
            .into_iter()
            .find(|r| *r < denied)
            .unwrap_or(NEVER_TOO_FAST_HZ);
        self.requested_rate_hz = next;
        if !std::mem::replace(&mut self.rate_advice_given, true) {
            let message = self.cfg.mavlink.source.message_name();
            self.notes.push(format!(
                "the autopilot denied {message} at {denied} Hz; asking for less (now {next} Hz). \
                 On ArduPilot the limit is 0.8 × SCHED_LOOP_RATE: raise SCHED_LOOP_RATE, or lower \
                 [mavlink] output_rate_hz"
            ));
        }
        self.next_stream_request = self.started;
    }

    /// The autopilot does not provide the chosen source: stop asking, and say so once.
    fn refuse_source(&mut self, result: MavResult, now: Instant) {
        if std::mem::replace(&mut self.source_refused, true) {
            return;
        }
        let source = self.cfg.mavlink.source;
        let message = source.message_name();
        let rate = self.requested_rate_hz;
        self.notes.push(format!(
            "the autopilot refused {message} at {rate} Hz ({result:?}), which is not a refusal \
             of the rate: this autopilot does not provide {message}. The servos get no outputs; \
             set [mavlink] source to a message it sends (ArduPilot: SERVO_OUTPUT_RAW; PX4: \
             ACTUATOR_OUTPUT_STATUS or SERVO_OUTPUT_RAW)"
        ));
        self.event(BridgeEvent::SourceRefused { source }, now);
    }

    /// Something happened on a bus (or to the bridge): announce it.
    pub fn event(&mut self, event: BridgeEvent, now: Instant) {
        if let Some(folded) = self.throttle.admit(&event, now) {
            self.statustext(&event, folded);
        }
    }

    fn statustext(&mut self, event: &BridgeEvent, folded: u32) {
        if !self.cfg.telemetry.statustext {
            return;
        }
        let name = match event {
            BridgeEvent::Servo { servo, .. }
            | BridgeEvent::ChannelMissing { servo, .. }
            | BridgeEvent::ChannelBack { servo, .. } => self
                .cfg
                .servos
                .get(*servo)
                .map(|s| s.name.as_str())
                .unwrap_or("servo"),
            _ => "",
        };
        let (severity, text) = describe(event, name);
        let text = with_folded(text, folded);
        tracing::info!(severity = ?severity, "{text}");
        self.outgoing.push_back(Outgoing {
            message: telemetry::statustext(severity, &text),
            link: None,
            sender: None,
        });
    }

    /// Time has come (see [`BridgeCore::poll_timeout`]): failsafe, stream requests, telemetry.
    pub fn handle_timeout(&mut self, now: Instant, reports: &[ServoReport]) {
        self.check_failsafe(now);
        self.check_safety_status(now);
        if self.last_output_at.is_some() && !self.dronecan_commands() {
            let fastest = self.rate.roll(self.requested_rate_hz, now);
            self.judge_rate(fastest);
        }
        for (event, folded) in self.throttle.due(now) {
            self.statustext(&event, folded);
        }
        if self.system_id.is_none() {
            return;
        }
        if now >= self.next_stream_request {
            self.next_stream_request = now + STREAM_REQUEST_PERIOD;
            if self.asks_for_outputs() {
                self.request_stream();
            }
        }
        if now >= self.next_heartbeat {
            self.next_heartbeat = now + HEARTBEAT_PERIOD;
            let status = telemetry::system_status(reports, self.in_failsafe());
            self.outgoing.push_back(Outgoing {
                message: telemetry::heartbeat(status),
                link: None,
                sender: None,
            });
        }
        let servos = &self.servos;
        let failsafe = |i: usize| servos.get(i).is_some_and(|s| s.failsafe);
        for message in self.telemetry.due(&self.cfg, reports, failsafe, now) {
            self.outgoing.push_back(Outgoing {
                message,
                link: None,
                sender: None,
            });
        }
        for (info, r) in self.servo_info.iter_mut().zip(reports) {
            info.model = r.model.or(info.model);
            info.firmware = r.firmware.or(info.firmware);
        }
        let out = self.params.due(now);
        self.send_params(out);
    }

    fn send_params(&mut self, out: Vec<ParamOut>) {
        for out in out {
            let (message, link) = match out {
                ParamOut::Value { link, index } => (
                    self.params
                        .value_message(index, &self.cfg, &self.servo_info),
                    link,
                ),
                ParamOut::Text(severity, text) => {
                    self.notes.push(text.clone());
                    (telemetry::statustext(severity, &text), None)
                }
            };
            self.outgoing.push_back(Outgoing {
                message,
                link,
                sender: None,
            });
        }
    }

    /// The next parameter change for the caller to make in the mapping file; report how it
    /// went with [`BridgeCore::param_set_done`].
    pub fn poll_param_set(&mut self) -> Option<ParamSet> {
        self.params.poll_set()
    }

    /// How a change from [`BridgeCore::poll_param_set`] went: the mapping file as it now
    /// reads, or why it refused the change. An accepted change takes effect at once: a servo
    /// that is not in failsafe moves to its latest command under the new mapping (its
    /// channel's latest value, or with DroneCAN commanding its actuator id's latest command).
    pub fn param_set_done(&mut self, set: &ParamSet, result: Result<Config, String>, now: Instant) {
        let before = self.cfg.clone();
        let result = result.map(|changed| {
            copy_tunables(&changed, &mut self.cfg);
            self.notes
                .push(format!("parameter {} set to {}", set.name, set.value));
        });
        let ok = result.is_ok();
        let out = self
            .params
            .set_done(set, result, &before, &self.cfg, &self.servo_info);
        self.send_params(out);
        if ok {
            self.reconfigured(&before, now);
        }
    }

    /// Apply what a parameter change altered in the configuration.
    fn reconfigured(&mut self, before: &Config, now: Instant) {
        if self.cfg.mavlink.output_rate_hz != before.mavlink.output_rate_hz {
            self.requested_rate_hz = self.cfg.mavlink.output_rate_hz;
            self.stream_ok = false;
            self.source_refused = false;
            self.rate_advice_given = false;
            self.next_stream_request = now;
        }
        for i in 0..self.servos.len() {
            let channel = self.cfg.servos[i].channel;
            let slot = &mut self.servos[i];
            if slot.channel != channel {
                slot.channel = channel;
                slot.override_latch = None;
                slot.absence = Absence::None;
                slot.ever_carried = false;
                slot.carried_at = self.last_output_at.map(|_| now);
            }
            if slot.failsafe || slot.override_latch.is_some() {
                continue;
            }
            let servo = &self.cfg.servos[i];
            let mapped = match (&self.cfg.dronecan, self.dronecan_commands()) {
                (Some(d), true) => self.can_commands[i]
                    .map(|c| servo.map_can_command(c.command_type, c.value, d.unitless)),
                _ => self.channels[usize::from(channel)].map(|us| servo.map_pwm(us)),
            };
            if let Some(position) = mapped {
                let command = match position {
                    Some(position) => Goal::Position(position),
                    None => Goal::Hold,
                };
                self.command(i, command);
            }
        }
    }

    fn request_stream(&mut self) {
        let Some((target_system, target_component)) = self.autopilot else {
            return;
        };
        let id = match self.cfg.mavlink.source {
            Source::ServoOutputRaw => SERVO_OUTPUT_RAW_ID,
            Source::ActuatorOutputStatus => ACTUATOR_OUTPUT_STATUS_ID,
        };
        let interval_us = (1e6 / self.requested_rate_hz.max(0.1)).round();
        self.outgoing.push_back(Outgoing {
            message: MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                param1: id as f32,
                param2: interval_us,
                command: MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL,
                target_system,
                target_component,
                ..Default::default()
            }),
            link: Some(AUTOPILOT_LINK),
            sender: None,
        });
    }

    fn failsafe_timeout(&self) -> Duration {
        Duration::from_millis(u64::from(self.cfg.mavlink.failsafe_timeout_ms))
    }

    fn check_failsafe(&mut self, now: Instant) {
        let Some(last) = self.last_output_at else {
            return;
        };
        let timeout = self.failsafe_timeout();
        let timeout_ms = self.cfg.mavlink.failsafe_timeout_ms;
        if self.stream_failsafe {
            return;
        }
        if now.duration_since(last) >= timeout {
            self.stream_failsafe = true;
            // An outage is the failsafe's, not a slow stream: its window is not judged.
            self.rate.restart(now);
            // The autopilot may have restarted and forgotten the rate: ask again until it runs.
            self.stream_ok = false;
            self.next_stream_request = now;
            for i in 0..self.servos.len() {
                self.enter_servo_failsafe(i);
                // The stream's text covers a channel whose absence was not said yet.
                let slot = &mut self.servos[i];
                if slot.absence == Absence::Unsaid {
                    slot.absence = Absence::None;
                }
            }
            self.event(BridgeEvent::FailsafeEntered { timeout_ms }, now);
            return;
        }
        for i in 0..self.servos.len() {
            let slot = &self.servos[i];
            let missing = slot
                .carried_at
                .is_some_and(|at| now.duration_since(at) >= timeout);
            if !missing || slot.absence != Absence::None || self.commanded_only(i) {
                continue;
            }
            // The failsafe now; the text once another message shows the stream goes on
            // without the channel (`say_missing_channels`).
            self.servos[i].absence = Absence::Unsaid;
            self.enter_servo_failsafe(i);
        }
    }

    /// A servo with an `actuator` key whose channel no output message has carried is driven
    /// by DO_SET_ACTUATOR alone: its channel is not missing, it was never there.
    fn commanded_only(&self, i: usize) -> bool {
        self.cfg.servos[i].actuator.is_some() && !self.servos[i].ever_carried
    }

    /// Servo `i` takes its failsafe action (once: a servo already in failsafe keeps it).
    fn enter_servo_failsafe(&mut self, i: usize) {
        if std::mem::replace(&mut self.servos[i].failsafe, true) {
            return;
        }
        // A command's override ends with the failsafe: the channel's return commands again.
        self.servos[i].override_latch = None;
        let command = match self.cfg.servos[i].failsafe {
            FailsafeAction::Hold => Goal::Hold,
            FailsafeAction::Off => Goal::Off,
            FailsafeAction::Brake => Goal::Brake,
            FailsafeAction::Position(p) => Goal::Position(p),
        };
        self.command(i, command);
    }

    /// The servos (indices in mapping order) that an output message or command carried since
    /// the last call, whether or not it changed their goal: each is a tick of the autopilot's
    /// rhythm for the servo's bus, so that the bus keeps the rhythm while the outputs hold.
    pub fn take_output_ticks(&mut self) -> Vec<usize> {
        let mut ticked = Vec::new();
        for (i, slot) in self.servos.iter_mut().enumerate() {
            if std::mem::take(&mut slot.ticked) {
                ticked.push(i);
            }
        }
        ticked
    }

    /// The autopilot's clock for the flight record: the first an output message carried, then
    /// the latest at most once every [`AutopilotClock::PERIOD`].
    pub fn poll_autopilot_clock(&mut self) -> Option<AutopilotClock> {
        let clock = self.clock?;
        if self
            .clock_taken_at
            .is_some_and(|taken| clock.at < taken + AutopilotClock::PERIOD)
        {
            return None;
        }
        self.clock_taken_at = Some(clock.at);
        self.clock = None;
        Some(clock)
    }

    /// The next servo command: (servo index in mapping order, command).
    pub fn poll_command(&mut self) -> Option<(usize, Goal)> {
        self.commands.pop_front()
    }

    /// The next MAVLink message to send.
    pub fn poll_message(&mut self) -> Option<Outgoing> {
        self.outgoing.pop_front()
    }

    /// When [`BridgeCore::handle_timeout`] must next be called; `None`: not before a message
    /// arrives. Until an autopilot is found the bridge has no system ID to send with, so its
    /// heartbeat, stream requests, telemetry and parameter answers wait for one, and only the
    /// failsafe and held-back texts can fall due: a bridge waiting for its autopilot sleeps.
    pub fn poll_timeout(&self) -> Option<Instant> {
        let mut t = self.throttle.next_deadline();
        if let Some(last) = self.last_output_at.filter(|_| !self.stream_failsafe) {
            let timeout = self.failsafe_timeout();
            let mut due = last + timeout;
            let watched = (0..self.servos.len())
                .filter(|i| self.servos[*i].absence == Absence::None && !self.commanded_only(*i))
                .map(|i| &self.servos[i]);
            if let Some(at) = watched.filter_map(|s| s.carried_at).min() {
                due = due.min(at + timeout);
            }
            t = earliest(t, Some(due));
        }
        if self.last_output_at.is_some() && !self.dronecan_commands() {
            t = earliest(t, Some(self.rate.deadline()));
        }
        if self.system_id.is_none() {
            return t;
        }
        t = earliest(
            t,
            Some(self.next_heartbeat.min(self.telemetry.next_deadline())),
        );
        if self.asks_for_outputs() {
            t = earliest(t, Some(self.next_stream_request));
        }
        earliest(t, self.params.next_deadline())
    }
}

fn earliest(a: Option<Instant>, b: Option<Instant>) -> Option<Instant> {
    match (a, b) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

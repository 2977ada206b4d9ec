//! What the bus master knows and wants of one servo: its start-up phase, identity, latest
//! telemetry, force state, goals and stall watch. The bus master (`master.rs`) decides when the
//! bus is free; this record decides what the servo needs next and digests its replies.
//!
//! Pure state: every method is handed the time, nothing here reads a clock or does I/O.

use super::config::{BusConfig, ServoSetup};
use super::event::BusEvent;
use super::goal::Goal;
use super::quality::ReplyWatch;
use super::status::{ForceState, Health, ServoIdentity, ServoStatus};
use crate::protocol::{
    ForceMode, LJ9DA41_MODEL_NUMBER, MemoryMap, MmCenti, Ms10, PositionLimits, ReplyFlags,
    ReplyRequest, ShortPacket, Telemetry, registers::addr,
};
use std::time::{Duration, Instant};

/// Bytes of a position-and-current read (registers 42–49).
pub(super) const MOTION_LEN: u8 = 8;

/// How long a temperature event from a reply without a temperature waits for the full read
/// that follows it (see [`Servo::hold_temperature_events`]).
pub(super) const TEMPERATURE_WAIT: Duration = Duration::from_millis(200);

/// Where a servo is in its life on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Phase {
    /// Read registers 0–29: model number, firmware, reverse, return delay, limits.
    Identify,
    /// Write max force (if configured) and read registers 30–41: force state and goal.
    ReadRam,
    /// Read registers 42–59 once before going online.
    FirstTelemetry,
    /// Online: polled for telemetry, commanded.
    Ready,
    /// Missed too many replies; probed at `next_probe`, the wait doubling up to a maximum.
    Offline {
        next_probe: Instant,
        backoff: Duration,
    },
    /// Not an LJ9DA41: never commanded, never polled again.
    WrongModel { found: u16 },
}

/// A request-and-reply exchange with one servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Transaction {
    Identify,
    Probe,
    ReadRam,
    Telemetry,
    /// Registers 42–49 (position and current), the poll between two full ones.
    Motion,
    /// Registers 42–43 alone, in bus time too short for any other poll.
    Position,
    Verify,
    Force(ForceMode),
}

/// The goal last put on the wire for a servo and the move it started.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct SentGoal {
    pub position: MmCenti,
    /// When the long packet carrying it started on the wire.
    pub at: Instant,
    /// The goal time it was sent with (zero: full speed).
    pub move_time: Duration,
}

impl SentGoal {
    /// The goal time that makes a re-sent goal arrive when the original move would have.
    pub fn remaining(&self, at: Instant) -> Duration {
        (self.at + self.move_time).saturating_duration_since(at)
    }
}

#[derive(Debug, Clone)]
pub(super) struct Servo {
    pub setup: ServoSetup,
    pub phase: Phase,
    pub consecutive_timeouts: u32,
    /// Since when the servo has not been heard at all (the first of its silent timeouts).
    pub silent_since: Option<Instant>,
    pub timeouts: u64,
    pub telemetry_count: u64,
    /// Requests answered with a good reply, of every kind.
    pub answered: u64,
    /// Whether too many of its replies are bad (see [`super::quality`]).
    pub replies: ReplyWatch,

    pub identity: ServoIdentity,

    pub telemetry: Option<Telemetry>,
    pub telemetry_at: Option<Instant>,
    /// When a position-only read last refreshed the telemetry's position (`None` since the
    /// last full poll).
    pub position_at: Option<Instant>,
    /// When a position-and-current read last refreshed the telemetry's position and current.
    pub motion_at: Option<Instant>,
    /// A reading (full, or of the position) arrived that no status has carried yet (see
    /// [`super::BusMaster::awaited_reply_hides_a_reading`]).
    pub reading_unshown: bool,
    /// The temperature flags changed in a reply that carried no temperature: read it at the
    /// servo's next poll.
    pub full_wanted: bool,
    /// Temperature events of such a reply, held until that read (at most
    /// [`TEMPERATURE_WAIT`]), and since when.
    pub held: Option<(Instant, Vec<BusEvent>)>,
    pub flags: ReplyFlags,
    pub last_poll_at: Option<Instant>,
    pub last_verify_at: Option<Instant>,
    /// The latest known rod position (telemetry, or the goal register right after force ON).
    pub last_position: Option<MmCenti>,

    pub force: ForceState,
    pub force_retry_at: Option<Instant>,
    pub force_backoff: Duration,

    pub desired: Option<Goal>,
    pub sent: Option<SentGoal>,
    /// Register 32 (goal time) as last read or written; `None` when unknown.
    pub goal_time_reg: Option<Ms10>,
    /// The next new goal starts a soft-start move.
    pub soft_pending: bool,
    /// A soft-start move is under way until then (or until the servo arrives).
    pub soft_until: Option<Instant>,

    /// Since when the servo has been off its goal at high current without closing in, and how
    /// far off it was then (0.01 mm).
    pub stall_since: Option<(Instant, u32)>,
    pub stalled: bool,
}

impl Servo {
    /// The servo's return delay (register 7) once read; until then the configured assumption.
    pub fn return_delay(&self, cfg: &BusConfig) -> Duration {
        self.identity
            .return_delay
            .unwrap_or(cfg.assumed_return_delay)
    }

    pub fn new(setup: ServoSetup) -> Self {
        Servo {
            setup,
            phase: Phase::Identify,
            consecutive_timeouts: 0,
            silent_since: None,
            timeouts: 0,
            telemetry_count: 0,
            answered: 0,
            replies: ReplyWatch::default(),
            identity: ServoIdentity::default(),
            telemetry: None,
            telemetry_at: None,
            position_at: None,
            motion_at: None,
            reading_unshown: false,
            full_wanted: false,
            held: None,
            flags: ReplyFlags::default(),
            last_poll_at: None,
            last_verify_at: None,
            last_position: None,
            force: ForceState::Unknown,
            force_retry_at: None,
            force_backoff: Duration::ZERO,
            desired: None,
            sent: None,
            goal_time_reg: None,
            soft_pending: true,
            soft_until: None,
            stall_since: None,
            stalled: false,
        }
    }

    pub fn id(&self) -> crate::protocol::ServoId {
        self.setup.id
    }

    /// `position` clamped into the servo's limits (the full stroke until they are read), as
    /// the servo itself would clamp it.
    pub fn clamp(&self, position: MmCenti) -> MmCenti {
        self.identity
            .limits
            .unwrap_or(PositionLimits::FULL_STROKE)
            .clamp(position)
    }

    pub fn temperature_error(&self) -> bool {
        self.flags.temperature_error()
    }

    /// The position goal, clamped to the limits known now.
    pub fn desired_position(&self) -> Option<MmCenti> {
        match self.desired {
            Some(Goal::Position(p)) => Some(self.clamp(p)),
            _ => None,
        }
    }

    /// A position goal that is not on the wire yet.
    pub fn unsent_position(&self) -> Option<MmCenti> {
        let p = self.desired_position()?;
        (self.sent.map(|s| s.position) != Some(p)).then_some(p)
    }

    /// Whether the servo gets an entry in the next long packet: an LJ9DA41 past start-up,
    /// force ON, no temperature error, and a position goal. An offline servo whose force was
    /// ON keeps its entry: a servo whose replies are lost may still hear its goals.
    pub fn commandable(&self) -> bool {
        matches!(self.phase, Phase::Ready | Phase::Offline { .. })
            && self.force == ForceState::On
            && !self.temperature_error()
            && self.desired_position().is_some()
    }

    /// The force write this servo needs, and from when (a refused force-ON waits for its
    /// retry time; a servo with a temperature error is never asked for force ON).
    pub fn force_due(&self) -> Option<(Option<Instant>, ForceMode)> {
        if self.phase != Phase::Ready {
            return None;
        }
        let mode = match self.desired? {
            Goal::Position(_) if self.force != ForceState::On && !self.temperature_error() => {
                ForceMode::On
            }
            Goal::Off if self.force != ForceState::Off => ForceMode::Off,
            Goal::Brake if self.force != ForceState::Brake => ForceMode::Brake,
            _ => return None,
        };
        Some((self.force_retry_at, mode))
    }

    /// The next read this servo needs and from when (`None` time: now).
    pub fn poll_due(&self, cfg: &BusConfig) -> Option<(Option<Instant>, Transaction)> {
        match self.phase {
            Phase::Identify => Some((None, Transaction::Identify)),
            Phase::ReadRam => Some((None, Transaction::ReadRam)),
            Phase::FirstTelemetry => Some((None, Transaction::Telemetry)),
            Phase::Offline { next_probe, .. } => Some((Some(next_probe), Transaction::Probe)),
            Phase::WrongModel { .. } => None,
            Phase::Ready => {
                let verify_at = self.last_verify_at.map(|t| t + cfg.verify_interval);
                let poll_at = self.last_poll_at.map(|t| t + cfg.telemetry_min_interval);
                match (verify_at, poll_at) {
                    (None, _) => Some((None, Transaction::Verify)),
                    (Some(v), Some(p)) if v <= p => Some((Some(v), Transaction::Verify)),
                    (Some(_), p) => Some((p, self.periodic_read(p, cfg))),
                }
            }
        }
    }

    /// The periodic read due at `at` (`None`: now): the full registers 42–59 when the
    /// temperature and voltage are `full_telemetry_interval` old then, position and current
    /// otherwise.
    fn periodic_read(&self, at: Option<Instant>, cfg: &BusConfig) -> Transaction {
        let full_due = match (self.telemetry_at, at.or(self.last_poll_at)) {
            (Some(full), Some(at)) => {
                at.saturating_duration_since(full) >= cfg.full_telemetry_interval
            }
            _ => true,
        };
        if full_due || self.full_wanted {
            Transaction::Telemetry
        } else {
            Transaction::Motion
        }
    }

    /// The request packet of a transaction.
    pub fn request(&self, tx: Transaction) -> ShortPacket {
        let id = self.id();
        match tx {
            Transaction::Identify | Transaction::Probe => {
                ShortPacket::request(id, ReplyRequest::Registers0To29)
            }
            Transaction::Telemetry => ShortPacket::request(id, ReplyRequest::Registers42To59),
            // Registers 42–43 are always a valid read; were they not, a full poll would do.
            Transaction::Position => ShortPacket::read(id, addr::PRESENT_POSITION, 2)
                .unwrap_or_else(|_| ShortPacket::request(id, ReplyRequest::Registers42To59)),
            // Registers 42–49: position, present time, reserved, load.
            Transaction::Motion => ShortPacket::read(id, addr::PRESENT_POSITION, MOTION_LEN)
                .unwrap_or_else(|_| ShortPacket::request(id, ReplyRequest::Registers42To59)),
            Transaction::Verify => ShortPacket::request(id, ReplyRequest::Registers30To41),
            Transaction::ReadRam => self
                .setup
                .max_force
                .and_then(|f| {
                    ShortPacket::write(
                        id.into(),
                        addr::MAX_FORCE,
                        &[f.get()],
                        ReplyRequest::Registers30To41,
                    )
                    .ok()
                })
                .unwrap_or_else(|| ShortPacket::request(id, ReplyRequest::Registers30To41)),
            Transaction::Force(mode) => ShortPacket::write(
                id.into(),
                addr::FORCE_ENABLE,
                &[mode as u8],
                ReplyRequest::Registers30To41,
            )
            .unwrap_or_else(|_| ShortPacket::force(id.into(), mode)),
        }
    }

    /// Digest the status bits of a reply.
    pub fn apply_flags(&mut self, flags: ReplyFlags, events: &mut Vec<BusEvent>) {
        let id = self.id();
        let old = self.flags;
        let new = flags.meaningful();
        self.flags = new;
        if new.temperature_alarm() != old.temperature_alarm()
            || new.temperature_error() != old.temperature_error()
        {
            self.full_wanted = true;
        }
        if new.temperature_alarm() != old.temperature_alarm() {
            events.push(BusEvent::TemperatureAlarm {
                id,
                on: new.temperature_alarm(),
            });
        }
        if new.temperature_error() && !old.temperature_error() {
            events.push(BusEvent::TemperatureError { id });
            // The servo switched its force off itself.
            if self.force != ForceState::Unknown {
                self.force = ForceState::Off;
            }
            self.sent = None;
        }
        if !new.temperature_error() && old.temperature_error() && self.phase == Phase::Ready {
            // Only a reset or power cycle clears the error: start again from the identity.
            events.push(BusEvent::ServoRestarted { id });
            self.restart();
        }
        if new.flash_write_error() && !old.flash_write_error() {
            events.push(BusEvent::FlashWriteError { id });
        }
    }

    /// The events of one reply as they may go out now: a temperature event from a reply that
    /// carried no temperature is held back until the full read that the flag change asked for
    /// (`full_wanted`), so that whoever reads the servo's status for the event finds the
    /// temperature of the moment, not one read before the flag. Once that read is in, the
    /// held events go out first, in order.
    pub fn hold_temperature_events(
        &mut self,
        events: Vec<BusEvent>,
        now: Instant,
    ) -> Vec<BusEvent> {
        if !self.full_wanted {
            let mut out = self.held.take().map(|(_, e)| e).unwrap_or_default();
            out.extend(events);
            return out;
        }
        let (temperature, other): (Vec<_>, Vec<_>) = events.into_iter().partition(|e| {
            matches!(
                e,
                BusEvent::TemperatureAlarm { .. } | BusEvent::TemperatureError { .. }
            )
        });
        if !temperature.is_empty() {
            self.held
                .get_or_insert((now, Vec::new()))
                .1
                .extend(temperature);
        }
        other
    }

    /// Held temperature events whose wait is over without a full read (the servo stopped
    /// answering, or the bus had no time for the read): they go out with the reading there
    /// is, whose age then tells it is older than the event.
    pub fn overdue_temperature_events(&mut self, now: Instant) -> Vec<BusEvent> {
        match self.held {
            Some((since, _)) if now.saturating_duration_since(since) >= TEMPERATURE_WAIT => {
                self.held.take().map(|(_, e)| e).unwrap_or_default()
            }
            _ => Vec::new(),
        }
    }

    /// Forget what the servo's RAM held and read it again from the start.
    pub fn restart(&mut self) {
        self.phase = Phase::Identify;
        self.force = ForceState::Unknown;
        self.sent = None;
        self.goal_time_reg = None;
        self.force_retry_at = None;
        self.force_backoff = Duration::ZERO;
        self.soft_until = None;
        self.stall_since = None;
    }

    /// Registers 0–29 arrived (start-up read or probe).
    pub fn on_identity(&mut self, data: &[u8], probe: bool, events: &mut Vec<BusEvent>) {
        let id = self.id();
        let mut map = MemoryMap::default();
        map.store(0, data);
        let model = map.model_number();
        self.identity.model = Some(model);
        self.identity.firmware = Some(map.firmware_version());
        self.identity.reversed = Some(map.reversed());
        self.identity.return_delay = Some(Duration::from_millis(u64::from(map.return_delay_ms())));
        self.identity.temperature_limit = Some(map.temperature_limit());
        self.identity.limits = PositionLimits::new(map.minus_limit(), map.plus_limit()).ok();
        if probe {
            events.push(BusEvent::ServoBack { id });
        }
        if model != LJ9DA41_MODEL_NUMBER {
            self.phase = Phase::WrongModel { found: model };
            self.force = ForceState::Unknown;
            events.push(BusEvent::WrongModel { id, found: model });
            return;
        }
        if probe {
            self.restart();
        }
        self.phase = Phase::ReadRam;
        if self.stalled {
            self.stalled = false;
            events.push(BusEvent::Stalled { id, on: false });
        }
    }

    /// Registers 30–41 decoded: force state, goal register, goal time.
    fn ram(data: &[u8]) -> (ForceState, MmCenti, Ms10) {
        let mut map = MemoryMap::default();
        map.store(30, data);
        let force = match map.force_mode() {
            Ok(ForceMode::Off) => ForceState::Off,
            Ok(ForceMode::On) => ForceState::On,
            Ok(ForceMode::Brake) => ForceState::Brake,
            Err(_) => ForceState::Unknown,
        };
        (force, map.goal_position(), map.goal_time())
    }

    /// Registers 30–41 arrived at start-up.
    pub fn on_ram(&mut self, data: &[u8], now: Instant) {
        let (force, goal, goal_time) = Self::ram(data);
        self.force = if self.temperature_error() {
            ForceState::Off
        } else {
            force
        };
        self.goal_time_reg = Some(goal_time);
        self.sent = (self.force == ForceState::On).then_some(SentGoal {
            position: goal,
            at: now,
            move_time: Duration::ZERO,
        });
        self.phase = Phase::FirstTelemetry;
    }

    /// Registers 30–41 arrived as the periodic read-back.
    pub fn on_verify(&mut self, data: &[u8], now: Instant, events: &mut Vec<BusEvent>) {
        let (force, goal, goal_time) = Self::ram(data);
        self.goal_time_reg = Some(goal_time);
        if self.force == ForceState::On && force == ForceState::Off && !self.temperature_error() {
            events.push(BusEvent::ServoRestarted { id: self.id() });
            self.restart();
            return;
        }
        self.force = force;
        if force == ForceState::On {
            if self.sent.map(|s| s.position) != Some(goal) {
                // A long packet was lost (or the servo clamped the goal): the goal in the
                // servo is what is on the wire now; a different wish will be sent again.
                self.sent = Some(SentGoal {
                    position: goal,
                    at: now,
                    move_time: Duration::ZERO,
                });
            }
        } else {
            self.sent = None;
        }
    }

    /// Registers 30–41 arrived after a force write: did the servo take it?
    pub fn on_force(
        &mut self,
        mode: ForceMode,
        data: &[u8],
        now: Instant,
        cfg: &BusConfig,
        events: &mut Vec<BusEvent>,
    ) {
        let (force, goal, goal_time) = Self::ram(data);
        self.goal_time_reg = Some(goal_time);
        let wanted = match mode {
            ForceMode::Off => ForceState::Off,
            ForceMode::On => ForceState::On,
            ForceMode::Brake => ForceState::Brake,
        };
        let was = self.force;
        self.force = force;
        if force == wanted {
            self.force_retry_at = None;
            self.force_backoff = Duration::ZERO;
            if wanted == ForceState::On {
                // Force ON took the present position as goal: nothing jumps.
                if was != ForceState::On {
                    self.soft_pending = true;
                }
                self.last_position = Some(goal);
                self.sent = Some(SentGoal {
                    position: goal,
                    at: now,
                    move_time: Duration::ZERO,
                });
            } else {
                self.sent = None;
                self.soft_until = None;
            }
            return;
        }
        if force != ForceState::On {
            self.sent = None;
        }
        if self.temperature_error() {
            return;
        }
        let first = self.force_backoff.is_zero();
        self.force_backoff = cfg.force_retry_backoff.after(self.force_backoff);
        self.force_retry_at = Some(now + self.force_backoff);
        if first && wanted == ForceState::On {
            events.push(BusEvent::ForceRefused { id: self.id() });
        }
    }

    /// Registers 42–59 arrived.
    /// Keep a telemetry reading as the servo's latest, whatever its start-up phase: the values
    /// are true even while it is being re-initialised.
    pub fn store_reading(&mut self, t: Telemetry, now: Instant) {
        self.full_wanted = false;
        self.telemetry = Some(t);
        self.telemetry_at = Some(now);
        self.position_at = None;
        self.reading_unshown = true;
        self.telemetry_count += 1;
        self.last_position = Some(t.present_position);
    }

    /// Registers 42–43 arrived (a position-only read): the position of the latest telemetry
    /// is replaced, its other values and their time are kept.
    pub fn store_position(&mut self, position: MmCenti, now: Instant) {
        if let Some(t) = self.telemetry.as_mut() {
            t.present_position = position;
            self.position_at = Some(now);
            self.reading_unshown = true;
        }
        self.last_position = Some(position);
    }

    /// Registers 42–49 arrived (position and current): the position and current of the
    /// latest telemetry are replaced; its temperature, voltage and their time are kept.
    pub fn store_motion(&mut self, data: &[u8], now: Instant) {
        let Some(motion) = Telemetry::motion_from_registers(data) else {
            return;
        };
        if let Some(t) = self.telemetry.as_mut() {
            t.present_position = motion.present_position;
            t.present_time = motion.present_time;
            t.present_load = motion.present_load;
            self.position_at = Some(now);
            self.motion_at = Some(now);
            self.reading_unshown = true;
        }
        self.last_position = Some(motion.present_position);
    }

    /// When the position was last read, by any poll.
    pub fn position_read_at(&self) -> Option<Instant> {
        self.position_at.or(self.telemetry_at)
    }

    /// A reply came (good or garbled): the servo is there.
    pub fn heard(&mut self) {
        self.consecutive_timeouts = 0;
        self.silent_since = None;
    }

    pub fn on_telemetry(
        &mut self,
        t: Telemetry,
        now: Instant,
        cfg: &BusConfig,
        events: &mut Vec<BusEvent>,
    ) {
        let id = self.id();
        self.store_reading(t, now);
        let error = self
            .sent
            .map(|s| (i32::from(t.present_position.0) - i32::from(s.position.0)).unsigned_abs());
        let tolerance = u32::from(cfg.stall.tolerance.0.unsigned_abs());

        if let (Some(until), Some(error)) = (self.soft_until, error)
            && (error <= tolerance || now >= until)
        {
            self.soft_until = None;
        }
        // A first goal the servo already sits at needs no slow move: as in PWM mode, the soft
        // start ends once the position error is inside the dead band.
        if self.soft_pending
            && self.unsent_position().is_none()
            && self.desired_position().is_some()
            && error.is_some_and(|e| e <= tolerance)
        {
            self.soft_pending = false;
        }

        let stalling = self.force == ForceState::On
            && error.is_some_and(|e| e > tolerance)
            && t.present_load >= cfg.stall.current;
        if stalling {
            let error = error.unwrap_or_default();
            // Closing in by more than the tolerance is following, however slowly (a heavy load
            // draws high current while it moves): the watch starts again.
            let since = match self.stall_since {
                Some((since, start_error)) if error.saturating_add(tolerance) >= start_error => {
                    since
                }
                _ => {
                    self.stall_since = Some((now, error));
                    now
                }
            };
            if !self.stalled && now.saturating_duration_since(since) >= cfg.stall.time {
                self.stalled = true;
                events.push(BusEvent::Stalled { id, on: true });
            }
        } else {
            self.stall_since = None;
            if self.stalled {
                self.stalled = false;
                events.push(BusEvent::Stalled { id, on: false });
            }
        }

        if self.phase == Phase::FirstTelemetry {
            self.phase = Phase::Ready;
            self.last_verify_at = Some(now);
            events.push(BusEvent::ServoOnline { id });
        }
    }

    /// No usable reply came: none at all (`garbled` false), or one with a bad sum. A garbled
    /// reply counts as missed but shows the servo is there: only silence takes it offline.
    pub fn on_timeout(
        &mut self,
        garbled: bool,
        now: Instant,
        cfg: &BusConfig,
        events: &mut Vec<BusEvent>,
    ) {
        self.timeouts += 1;
        if garbled && !matches!(self.phase, Phase::Offline { .. }) {
            self.heard();
            return;
        }
        if let Phase::Offline { backoff, .. } = self.phase {
            let backoff = cfg.probe_backoff.after(backoff);
            self.phase = Phase::Offline {
                next_probe: now + backoff,
                backoff,
            };
            return;
        }
        self.consecutive_timeouts = self.consecutive_timeouts.saturating_add(1);
        let silent_since = *self.silent_since.get_or_insert(now);
        if self.consecutive_timeouts >= cfg.offline_after_timeouts.max(1)
            && now.saturating_duration_since(silent_since) >= cfg.offline_after_silence
        {
            let backoff = cfg.probe_backoff.first;
            self.phase = Phase::Offline {
                next_probe: now + backoff,
                backoff,
            };
            self.stall_since = None;
            // Silence is its own event: whatever the replies were before, "lost" says more.
            self.replies.forget();
            events.push(BusEvent::ServoLost { id: self.id() });
        }
    }

    /// The soft-start goal time for a move to `goal`, or `None` when soft start is off.
    pub fn soft_start_time(&self, goal: MmCenti, cfg: &BusConfig) -> Option<Duration> {
        let speed = cfg.soft_start_speed_mm_s;
        if !(speed.is_finite() && speed > 0.0) {
            return None;
        }
        let from = self
            .last_position
            .or(self.sent.map(|s| s.position))
            .unwrap_or_default();
        let distance_mm = (f64::from(goal.0) - f64::from(from.0)).abs() / 100.0;
        let seconds = (distance_mm / speed).min(f64::from(u16::MAX) / 100.0);
        Some(Duration::from_secs_f64(seconds))
    }

    pub fn health(&self, now: Instant, cfg: &BusConfig) -> Health {
        match self.phase {
            Phase::Identify | Phase::ReadRam | Phase::FirstTelemetry => Health::Starting,
            Phase::Offline { .. } => Health::Offline,
            Phase::WrongModel { .. } => Health::WrongModel,
            Phase::Ready if self.temperature_error() => Health::TemperatureError,
            Phase::Ready => match self.telemetry_at {
                Some(at) if now.saturating_duration_since(at) <= cfg.stale_after => Health::Online,
                _ => Health::Stale,
            },
        }
    }

    pub fn status(&self, now: Instant, cfg: &BusConfig) -> ServoStatus {
        ServoStatus {
            id: self.id(),
            name: self.setup.name.clone(),
            health: self.health(now, cfg),
            telemetry: self.telemetry,
            telemetry_at: self.telemetry_at,
            position_at: self.position_at,
            motion_at: self.motion_at.filter(|&at| self.position_at == Some(at)),
            age: self
                .telemetry_at
                .map(|at| now.saturating_duration_since(at)),
            flags: self.flags,
            goal: self.sent.map(|s| s.position),
            force: self.force,
            stalled: self.stalled,
            identity: self.identity,
            consecutive_timeouts: self.consecutive_timeouts,
            telemetry_count: self.telemetry_count,
            answered: self.answered,
            timeouts: self.timeouts,
            degraded: self.replies.degraded(),
        }
    }
}

/// A duration as a goal time, rounded up to the next 10 ms and saturated.
pub(super) fn ms10_ceil(d: Duration) -> Ms10 {
    let ms10 = d.as_nanos().div_ceil(10_000_000);
    Ms10(u16::try_from(ms10).unwrap_or(u16::MAX))
}

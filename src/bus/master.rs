//! The sans-IO bus master: decides what one RS485 bus carries next.
//!
//! In the style of quinn-proto, it is a deterministic state machine. The caller hands it new
//! goals ([`BusMaster::set_goal`]), the bytes that came back ([`BusMaster::handle_input`]) and
//! the passing of time ([`BusMaster::handle_timeout`]), always with the current time; it answers
//! with the next packet to write ([`BusMaster::poll_transmit`]), the next deadline
//! ([`BusMaster::poll_timeout`]), events ([`BusMaster::poll_event`]) and a status snapshot.
//!
//! It never does I/O and never reads a clock: every time it uses was handed to it. It never
//! panics, whatever bytes arrive.
//!
//! The schedule, in priority order, whenever no reply is pending:
//! 1. a long packet, when the position goal of any commanded servo differs from the one on
//!    the wire: one frame with an entry for every commanded servo;
//! 2. a force write (answered with registers 30–41 to confirm it), before a servo's first
//!    goal or when a goal asks for force OFF or brake;
//! 3. one servo's next read, round-robin: start-up reads, the telemetry poll (registers 42–49,
//!    position and current; the full 42–59 every `full_telemetry_interval`), a periodic
//!    read-back of registers 30–41, or a probe of an offline servo;
//! 4. while a goal is expected too soon for any of those, a read of one position (42–43).
//!
//! Requests (2–4) wait while the autopilot's tick is still coming in (`tick_gather` after its
//! first goal, and, while the goals keep a rhythm, until the tick has had as many messages as
//! the one before it, which also ends the wait at once), and start only if they end before the
//! next tick is expected ([`GoalRhythm`]): the messages of one tick all reach the wire before
//! the next poll. With a telemetry rate, the first read of a period goes out right behind the
//! tick's long packet, written by the same caller; the others follow each reply.
//!
//! Besides the schedule: every [`quality::WINDOW`] each servo's share of bad replies is judged
//! (degraded or well, see [`quality`]), and a temperature flag that changes in a reply without
//! the temperature makes that servo's next read a full one, its event held until that read is
//! in (at most 200 ms), so that the event and the temperature of the moment come out together.
//!
//! Never a word over a servo: the bytes of a whole return packet that is not the reply awaited
//! (a servo that answered after its allowance, when the bus master had moved on) never count as
//! the awaited reply's; while the decoder holds the start of a return packet that is not known
//! to be the awaited one, the bytes read do not end the request; and a reply still coming when
//! its allowance ended, or one that comes while none is awaited, holds the line until its rest
//! can have come and a few byte times after its latest byte ([`QUIET_AFTER_GARBLED_BYTES`]).
//!
//! A long packet expects no reply; the reply timeout of a request queued behind one counts from
//! the moment the bytes before it have left the wire (and from the real write, see
//! [`BusMaster::handle_written`]). A long packet is never queued more than one frame ahead of
//! the wire: goals that arrive while the wire is busy are coalesced in the bus master, not
//! queued in the port.

mod schedule;

use super::config::BusConfig;
use super::event::BusEvent;
use super::goal::{Goal, ShutdownForce};
use super::quality::{self, Counts, QualityChange};
use super::rhythm::GoalRhythm;
use super::servo::{Phase, Servo, Transaction};
use super::status::{BusCounters, BusStatus};
use crate::protocol::decoder::BegunHeader;
use crate::protocol::packet::ExpectedReply;
use crate::protocol::{DecodeError, Decoded, Decoder, ReturnPacket, ServoId};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Events kept at most when nobody takes them; the oldest are dropped beyond it.
const MAX_QUEUED_EVENTS: usize = 1024;
/// Allowed besides wire time and return delay for the servo and the adapter to react, when
/// judging whether a request ends before the next goal.
const REACTION: Duration = Duration::from_micros(150);
/// A reply garbled in its header frees the bus this many byte times (and the lateness learned for
/// replies) after the latest byte read, once as many bytes as the reply has were read (see
/// `BusMaster::hold_for_garbled_bytes`): the tail of a reply that this many bytes of noise
/// came before is then off the wire, and in the driver's hands.
pub const QUIET_AFTER_GARBLED_BYTES: usize = 4;

/// A request on the wire whose reply is awaited.
#[derive(Debug, Clone, Copy)]
struct Pending {
    index: usize,
    tx: Transaction,
    expected: ExpectedReply,
    /// When the whole reply can have arrived at the earliest (request sent, return delay,
    /// reply's wire time).
    complete_at: Instant,
    deadline: Instant,
    /// A look before the deadline found the reply incomplete: the driver then waited for its
    /// last bytes, so the read that completes it happens when it completed.
    looked: bool,
    /// A return packet with a bad sum arrived meanwhile: the servo answered, garbled.
    garbled: bool,
    /// Bytes received, and of them echoes and garbage skipped, when the request was sent
    /// (see [`BusMaster::reply_spent`]).
    received_before: u64,
    skipped_before: u64,
    /// When the request has left the wire: no byte read before is the servo's.
    request_ends: Instant,
    /// Bytes read since the request left the wire that were not its echo, garbage included.
    heard: u64,
    /// [`BusMaster::foreign_bytes`] when the request was sent.
    foreign_before: u64,
}

#[derive(Debug, Clone, Copy)]
struct Shutdown {
    leave: ShutdownForce,
    /// Servos already given their final packet (for [`ShutdownForce::Off`]).
    next: usize,
    done: bool,
}

/// The bus master of one RS485 bus; see the module docs.
#[derive(Debug)]
pub struct BusMaster {
    cfg: BusConfig,
    servos: Vec<Servo>,
    decoder: Decoder,
    pending: Option<Pending>,
    /// How much later than their earliest possible end replies are read whole (learned; see
    /// [`BusMaster::reply_look_at`]).
    reply_lateness: Duration,
    /// When the bytes already handed out will have left the wire.
    wire_free_at: Instant,
    /// When the packet handed out last was to start on the wire (see
    /// [`BusMaster::handle_written`]).
    last_start: Option<Instant>,
    /// The servo that had the last round-robin turn.
    cursor: usize,
    events: VecDeque<BusEvent>,
    counters: BusCounters,
    /// The latest time handed in.
    now: Instant,
    port_open: bool,
    /// When goals arrive, so that no poll is started just before the next one.
    rhythm: GoalRhythm,
    /// The window in which the messages of one autopilot tick are gathered: (opened, ends).
    gather: Option<(Instant, Instant)>,
    /// Send a long packet with every commanded servo even if no goal changed.
    resend_all: bool,
    shutdown: Option<Shutdown>,
    /// Something a status snapshot shows changed since [`BusMaster::take_changed`].
    changed: bool,
    /// When the servos' reply quality was last judged.
    judged_at: Instant,
    /// Until when a periodic read may start early, and how early: the instant a reply ended
    /// or a long packet was handed out, and a little (see [`BusMaster::next_request`]).
    chain_until: Option<(Instant, Duration)>,
    /// When the current burst of reads began: the tick's long packet, or a read started when
    /// it was due. A servo read since then is not read early again in the same burst.
    burst_began: Instant,
    /// Bytes of whole return packets that were not the reply awaited (a servo that answered
    /// after its allowance): they never count as the awaited reply's.
    foreign_bytes: u64,
    /// Until when a servo may still be talking although no reply is awaited (a reply begun
    /// when its allowance ended, or one that came after it): nothing is written before.
    line_busy_until: Option<Instant>,
    /// When bytes were last read.
    last_input_at: Instant,
}

impl BusMaster {
    /// A bus master for `cfg`; every servo starts with its identity read. A servo ID listed
    /// twice is kept once (the first entry).
    pub fn new(cfg: BusConfig, now: Instant) -> Self {
        let mut servos: Vec<Servo> = Vec::with_capacity(cfg.servos.len());
        for setup in &cfg.servos {
            if servos.iter().all(|s| s.id() != setup.id) {
                servos.push(Servo::new(setup.clone()));
            }
        }
        let cursor = servos.len().saturating_sub(1);
        let rhythm = GoalRhythm::new(cfg.tick_gather);
        BusMaster {
            cfg,
            servos,
            decoder: Decoder::new(),
            pending: None,
            reply_lateness: Duration::ZERO,
            wire_free_at: now,
            last_start: None,
            cursor,
            events: VecDeque::new(),
            counters: BusCounters::default(),
            now,
            port_open: true,
            rhythm,
            gather: None,
            resend_all: false,
            shutdown: None,
            changed: true,
            judged_at: now,
            chain_until: None,
            burst_began: now,
            foreign_bytes: 0,
            line_busy_until: None,
            last_input_at: now,
        }
    }

    /// The measured period of incoming goal messages, once known.
    pub fn goal_period(&self) -> Option<Duration> {
        self.rhythm.period()
    }

    pub fn config(&self) -> &BusConfig {
        &self.cfg
    }

    fn touch(&mut self, now: Instant) {
        if now > self.now {
            self.now = now;
        }
    }

    fn index_of(&self, id: ServoId) -> Option<usize> {
        self.servos.iter().position(|s| s.id() == id)
    }

    /// An output message of the autopilot arrived (SERVO_OUTPUT_RAW of either port,
    /// ACTUATOR_OUTPUT_STATUS, an output command), whether or not it changed a goal: a tick of
    /// the autopilot's rhythm ([`GoalRhythm`]). Its goals follow through
    /// [`BusMaster::set_goal`] at the same instant.
    pub fn output_message(&mut self, now: Instant) {
        self.touch(now);
        self.gather_goal(now);
        self.rhythm.message_at(now);
    }

    /// The newest goal for servo `id`. It replaces a goal that has not reached the wire yet. A
    /// position goal is clamped to the servo's limits when it is sent. An ID not on this bus is
    /// ignored (and counted). The message that carried it is told with
    /// [`BusMaster::output_message`].
    pub fn set_goal(&mut self, id: ServoId, goal: Goal, now: Instant) {
        self.touch(now);
        let Some(i) = self.index_of(id) else {
            self.counters.goals_unknown_id += 1;
            return;
        };
        self.counters.goals_received += 1;
        self.changed = true;
        let s = &mut self.servos[i];
        let waiting = s.unsent_position();
        s.desired = Some(goal);
        match (waiting, s.unsent_position()) {
            (Some(old), Some(new)) if old == new => self.counters.goals_unchanged += 1,
            (Some(_), _) => {
                self.counters.goals_superseded += 1;
                if matches!(goal, Goal::Position(_)) && s.unsent_position().is_none() {
                    self.counters.goals_unchanged += 1;
                }
            }
            (None, None) if matches!(goal, Goal::Position(_)) => self.counters.goals_unchanged += 1,
            _ => {}
        }
    }

    /// Bytes read from the port.
    pub fn handle_input(&mut self, bytes: &[u8], now: Instant) {
        self.touch(now);
        if !bytes.is_empty() {
            self.last_input_at = now;
        }
        self.counters.bytes_received += bytes.len() as u64;
        let echoes_before = self.counters.echo_bytes;
        let foreign_before = self.foreign_bytes;
        self.decoder.push(bytes);
        self.drain_decoder(now);
        let echoed = self.counters.echo_bytes - echoes_before;
        let foreign = self.foreign_bytes - foreign_before;
        if let Some(p) = self.pending.as_mut()
            && now >= p.request_ends
        {
            p.heard += (bytes.len() as u64).saturating_sub(echoed + foreign);
        }
        let talk = (bytes.len() as u64).saturating_sub(echoed) > 0;
        if self.pending.is_none()
            && (foreign > 0
                || self.decoder.begun_reply().is_some()
                || (talk && self.line_busy(now)))
        {
            // A servo talks while no reply is awaited: the line is busy until the rest of a
            // reply begun can have come, and quiet after it.
            let missing = self.begun_reply_missing().unwrap_or(0);
            self.hold_line(now + self.cfg.wire_time(missing) + self.quiet_after_talk());
        }
        self.hold_for_garbled_bytes(now);
        if self.reply_spent(now)
            && let Some(p) = self.pending.as_mut()
        {
            p.garbled = true;
            p.deadline = p.deadline.min(now);
        }
        if self.pending.is_some_and(|p| p.garbled && p.deadline <= now) {
            self.expire_pending(now);
        }
        self.judge_replies(now);
        self.release_overdue(now);
    }

    /// Temperature events that waited [`super::servo::TEMPERATURE_WAIT`] for a temperature
    /// read in vain.
    fn release_overdue(&mut self, now: Instant) {
        let events: Vec<BusEvent> = self
            .servos
            .iter_mut()
            .flat_map(|s| s.overdue_temperature_events(now))
            .collect();
        self.push_events(events);
    }

    /// Once per [`quality::WINDOW`], every servo's share of bad replies (see [`quality`]).
    fn judge_replies(&mut self, now: Instant) {
        if now.saturating_duration_since(self.judged_at) < quality::WINDOW {
            return;
        }
        self.judged_at = now;
        self.changed = true;
        let mut events = Vec::new();
        for s in &mut self.servos {
            if s.phase != Phase::Ready {
                s.replies.pause();
                continue;
            }
            // A silent run still going on is left to the next window (see `quality`).
            let counts = Counts {
                answered: s.answered,
                missed: s.timeouts.saturating_sub(u64::from(s.consecutive_timeouts)),
            };
            let id = s.id();
            match s.replies.judge(counts) {
                Some(QualityChange::Degraded { percent }) => {
                    events.push(BusEvent::RepliesDegraded { id, percent })
                }
                Some(QualityChange::Recovered) => events.push(BusEvent::RepliesOk { id }),
                None => {}
            }
        }
        self.push_events(events);
    }

    fn drain_decoder(&mut self, now: Instant) {
        while let Some(item) = self.decoder.poll() {
            match item {
                Ok(Decoded::Reply(reply)) => self.on_reply(reply, now),
                Ok(Decoded::Echo { len }) => {
                    self.counters.echoes += 1;
                    self.counters.echo_bytes += len as u64;
                }
                Ok(Decoded::Ack) => self.counters.unexpected_replies += 1,
                Err(DecodeError::ReplyBadChecksum {
                    id,
                    address,
                    length,
                    ..
                }) => {
                    self.counters.bad_sums += 1;
                    self.on_garbled_reply(id, address, length, now);
                }
                Err(DecodeError::BadChecksum { .. }) => {
                    self.counters.bad_sums += 1;
                    if let Some(p) = self.pending.as_mut() {
                        p.garbled = true;
                    }
                }
                Err(DecodeError::Garbage { skipped, .. }) => {
                    self.counters.garbage_bytes += skipped as u64
                }
                Err(_) => self.counters.garbage_bytes += 1,
            }
        }
    }

    /// Bytes of echoes and garbage the decoder has passed over so far.
    fn skipped_bytes(&self) -> u64 {
        self.counters.garbage_bytes + self.counters.echo_bytes
    }

    /// Whether the servo awaited has sent as many bytes as its reply has, from its earliest
    /// end on, and none of them made the reply: a reply garbled in its header or length (the
    /// decoder then waits for a frame longer than any reply). The servo has stopped talking,
    /// so the request ends as a garbled reply instead of holding the bus to its deadline.
    /// Echoes and garbage skipped before the reply do not count as its bytes.
    fn reply_spent(&self, now: Instant) -> bool {
        let Some(p) = self.pending else {
            return false;
        };
        if self.other_reply_begun(&p) {
            return false;
        }
        let received = self.counters.bytes_received - p.received_before;
        let skipped = self.skipped_bytes() - p.skipped_before;
        let foreign = self.foreign_bytes - p.foreign_before;
        now >= p.complete_at
            && received.saturating_sub(skipped + foreign) >= p.expected.wire_len() as u64
    }

    /// Whether the decoder holds the start of a return packet that is not known to be the
    /// reply `p` awaits (its header not in yet, or another servo's or registers'): its rest is
    /// on its way, and the bytes read so far do not tell that the awaited servo has finished.
    fn other_reply_begun(&self, p: &Pending) -> bool {
        let Some(begun) = self.decoder.begun_reply() else {
            return false;
        };
        let awaited = |h: &BegunHeader| {
            self.servos
                .get(p.index)
                .is_some_and(|s| s.id().get() == h.id)
                && matches!(p.expected, ExpectedReply::Registers { address, .. } if address == h.address)
        };
        !begun.header.as_ref().is_some_and(awaited)
    }

    /// The bytes still to come of a return packet begun in the decoder, if one is and they
    /// are not all in: for the reply awaited (its servo and registers in the header), as many
    /// as that reply has (the servo's length byte may be garbled); for any other, as many as
    /// its header says, or as the longest reply before the header is in.
    fn begun_reply_missing(&self) -> Option<usize> {
        let begun = self.decoder.begun_reply()?;
        let missing = match self.pending {
            Some(p) if !self.other_reply_begun(&p) => {
                p.expected.wire_len().saturating_sub(begun.buffered)
            }
            _ => begun.missing(),
        };
        (missing > 0).then_some(missing)
    }

    /// How long after the last byte of a servo's talk the line is quiet: a few byte times, and
    /// the lateness learned for replies (an adapter that holds bytes back).
    fn quiet_after_talk(&self) -> Duration {
        self.cfg.wire_time(QUIET_AFTER_GARBLED_BYTES) + self.reply_lateness
    }

    /// Nothing is written before `until` (a servo may be talking).
    fn hold_line(&mut self, until: Instant) {
        self.line_busy_until = Some(self.line_busy_until.map_or(until, |t| t.max(until)));
    }

    /// Whether a servo may still be talking at `now` with no reply awaited.
    pub(super) fn line_busy(&self, now: Instant) -> bool {
        self.line_busy_until.is_some_and(|t| now < t)
    }

    /// The servo awaited may have sent a reply whose header was garbled: the decoder skips its
    /// bytes as garbage, one by one, and no reply comes out. Once as many bytes as the reply has
    /// were read since the request left the wire, from the reply's earliest end on, the bus is
    /// free [`QUIET_AFTER_GARBLED_BYTES`] byte times after the latest of them, and the lateness
    /// learned for replies (an adapter that holds bytes back; see
    /// [`BusMaster::reply_look_at`]); a later byte moves that on. That is instead of the end
    /// of the reply allowance. Bytes of noise before the reply count as its bytes, so the tail
    /// of the real reply may still be on the wire when the count is reached: up to that many
    /// bytes of noise, it is off the wire, and read, before the bus is free. While the decoder
    /// holds the start of a reply whose rest has not come, the allowance stands: the noise,
    /// not the reply, made up the count. A clean reply still ends the request at once.
    fn hold_for_garbled_bytes(&mut self, now: Instant) {
        let quiet = self.quiet_after_talk();
        let turnaround = self.cfg.turnaround;
        // A reply begun in the decoder is left its allowance: noise before it made the count.
        let reply_begun = self.decoder.buffered() > 0;
        if let Some(p) = self.pending.as_mut()
            && !reply_begun
            && now >= p.complete_at
            && p.heard >= p.expected.wire_len() as u64
        {
            p.garbled = true;
            // The allowance's end, as the request was given it (both move with a late write).
            p.deadline = (p.complete_at + turnaround).min(now + quiet);
        }
    }

    /// A whole return packet with a bad sum came in. When it is the reply awaited (its servo,
    /// registers and length), the servo has finished talking and the line is quiet: the
    /// request ends now as a garbled reply, as soon as a clean one would have, instead of
    /// holding the bus until its deadline. Any other is only counted against the pending one.
    fn on_garbled_reply(&mut self, id: u8, address: u8, length: u8, now: Instant) {
        let Some(p) = self.pending.as_mut() else {
            return;
        };
        p.garbled = true;
        let awaited = self.servos.get(p.index).is_some_and(|s| s.id().get() == id)
            && p.expected == ExpectedReply::Registers { address, length };
        if awaited {
            p.deadline = p.deadline.min(now);
        }
    }

    fn on_reply(&mut self, reply: ReturnPacket, now: Instant) {
        let Some(p) = self.pending else {
            self.counters.unexpected_replies += 1;
            self.foreign_bytes += reply.wire_len() as u64;
            return;
        };
        let ExpectedReply::Registers { address, length } = p.expected else {
            self.counters.unexpected_replies += 1;
            self.foreign_bytes += reply.wire_len() as u64;
            return;
        };
        let Some(servo) = self.servos.get(p.index) else {
            self.pending = None;
            return;
        };
        if reply.id != servo.id().get()
            || reply.address != address
            || reply.data.len() != usize::from(length)
        {
            self.counters.unexpected_replies += 1;
            self.foreign_bytes += reply.wire_len() as u64;
            return;
        }
        self.pending = None;
        self.changed = true;
        self.chain_until = Some((now + REACTION, self.chain_early()));
        self.learn_lateness(&p, now);
        self.counters.wire_busy_ns += self.cfg.baud.wire_time_ns(reply.wire_len());
        let mut events = Vec::new();
        let cfg = &self.cfg;
        let s = &mut self.servos[p.index];
        s.heard();
        s.answered += 1;
        s.apply_flags(reply.flags, &mut events);
        match p.tx {
            Transaction::Identify | Transaction::Probe => {
                if s.phase != Phase::Ready {
                    s.on_identity(&reply.data, p.tx == Transaction::Probe, &mut events);
                }
            }
            Transaction::ReadRam => {
                if s.phase == Phase::ReadRam {
                    s.on_ram(&reply.data, now);
                }
            }
            Transaction::Verify => {
                if s.phase == Phase::Ready {
                    s.on_verify(&reply.data, now, &mut events);
                }
            }
            Transaction::Force(mode) => {
                if s.phase == Phase::Ready {
                    s.on_force(mode, &reply.data, now, cfg, &mut events);
                }
            }
            Transaction::Motion => {
                self.counters.telemetry_replies += 1;
                s.store_motion(&reply.data, now);
            }
            Transaction::Position => {
                if let [lo, hi] = reply.data[..] {
                    s.store_position(crate::protocol::MmCenti(i16::from_le_bytes([lo, hi])), now);
                }
            }
            Transaction::Telemetry => {
                self.counters.telemetry_replies += 1;
                if let Ok(t) = reply.telemetry() {
                    if matches!(s.phase, Phase::Ready | Phase::FirstTelemetry) {
                        s.on_telemetry(t, now, cfg, &mut events);
                    } else {
                        // E.g. the reply that showed a restart: its values are current.
                        s.store_reading(t, now);
                    }
                }
            }
        }
        let events = s.hold_temperature_events(events, now);
        self.push_events(events);
    }

    fn push_events(&mut self, events: Vec<BusEvent>) {
        for e in events {
            self.changed = true;
            if self.events.len() >= MAX_QUEUED_EVENTS {
                self.events.pop_front();
            }
            self.events.push_back(e);
        }
    }

    /// The packet [`BusMaster::poll_transmit`] handed out last was written to the port at `at`.
    /// A write later than the instant the packet was to start on the wire (the writing thread
    /// was preempted in between) delays it and everything behind it: the reply awaited is
    /// expected that much later, so its bytes are never taken for missing and nothing is
    /// written into them.
    pub fn handle_written(&mut self, at: Instant) {
        let Some(planned) = self.last_start.take() else {
            return;
        };
        let Some(shift) = at.checked_duration_since(planned).filter(|d| !d.is_zero()) else {
            return;
        };
        self.wire_free_at += shift;
        if let Some(p) = self.pending.as_mut() {
            p.complete_at += shift;
            p.deadline += shift;
            p.request_ends += shift;
        }
    }

    /// Time has passed: a reply that is overdue has timed out.
    pub fn handle_timeout(&mut self, now: Instant) {
        self.touch(now);
        self.judge_replies(now);
        self.release_overdue(now);
        let Some(p) = self.pending else {
            return;
        };
        if now < p.deadline {
            if now >= self.look_at(&p)
                && let Some(p) = self.pending.as_mut()
            {
                p.looked = true;
            }
            return;
        }
        self.expire_pending(now);
    }

    /// The pending request's deadline has passed (or its reply came garbled): it ends as a
    /// timeout, counted for its servo.
    fn expire_pending(&mut self, now: Instant) {
        // A reply begun (the servo answered late, or this is another servo's): the line is
        // busy until its rest can have come, counted from its latest byte.
        if let Some(missing) = self.begun_reply_missing() {
            let ends = self.last_input_at + self.cfg.wire_time(missing) + self.quiet_after_talk();
            if ends > now {
                self.hold_line(ends);
            }
        }
        // A complete reply may sit behind a candidate that never completed.
        self.decoder.abandon_partial();
        self.drain_decoder(now);
        let Some(p) = self.pending.take() else {
            return;
        };
        self.changed = true;
        self.counters.timeouts += 1;
        let mut events = Vec::new();
        if let Some(s) = self.servos.get_mut(p.index) {
            s.on_timeout(p.garbled, now, &self.cfg, &mut events);
        }
        self.push_events(events);
    }

    /// The serial port failed: the reply awaited will never come (not counted as a timeout),
    /// and bytes half received are forgotten.
    pub fn handle_port_lost(&mut self, reason: impl Into<String>, now: Instant) {
        self.touch(now);
        self.pending = None;
        self.line_busy_until = None;
        self.decoder.clear();
        if self.port_open {
            self.port_open = false;
            self.push_events(vec![BusEvent::PortLost {
                reason: reason.into(),
            }]);
        }
    }

    /// The serial port is open again: every commanded servo gets its goal again and every
    /// servo's force state is read back at its next turn.
    pub fn handle_port_back(&mut self, now: Instant) {
        self.touch(now);
        self.pending = None;
        self.line_busy_until = None;
        self.decoder.clear();
        self.wire_free_at = now;
        self.resend_all = true;
        for s in &mut self.servos {
            s.last_verify_at = None;
        }
        if !self.port_open {
            self.port_open = true;
            self.push_events(vec![BusEvent::PortBack]);
        }
    }

    /// When the bus master next needs to be woken ([`BusMaster::handle_timeout`], then
    /// [`BusMaster::poll_transmit`]): the pending reply's deadline, or the earliest time a
    /// request falls due. `None`: nothing is timed; wait for goals or bytes.
    pub fn poll_timeout(&self) -> Option<Instant> {
        if let Some(p) = self.pending {
            return Some(p.deadline);
        }
        let due = self.next_due()?;
        Some(match self.line_busy_until {
            Some(busy) if self.line_busy(self.now) => due.max(busy),
            _ => due,
        })
    }

    /// [`BusMaster::poll_timeout`] with no reply pending, as if the line were quiet.
    fn next_due(&self) -> Option<Instant> {
        if self.shutdown.is_some() {
            return None;
        }
        if self.command_needed() {
            let lead = self
                .wire_free_at
                .checked_sub(self.command_lead())
                .map_or(self.now, |t| t.max(self.now));
            return Some(
                self.rest_of_tick(self.now)
                    .map_or(lead, |rest| rest.max(lead)),
            );
        }
        let next = self
            .servos
            .iter()
            .flat_map(|s| {
                let force = s.force_due().map(|(at, _)| at.unwrap_or(self.now));
                let poll = s.poll_due(&self.cfg).map(|(at, _)| at.unwrap_or(self.now));
                [force, poll]
            })
            .flatten()
            .min()?;
        let at = next.max(self.now);
        let at = at.max(self.gathering_until(at));
        if self.next_request(at).is_some() {
            return Some(at);
        }
        // Held for an expected tick (a message arriving meanwhile is taken at once through
        // `output_message`): the window's end, when everything fits again.
        let start = self.wire_free_at.max(at);
        let closes = self.rhythm.window(start).map_or(at, |(_, closes)| closes);
        Some(closes.max(at))
    }

    /// How many more bytes would complete the reply awaited (at least 1), or `None` when no
    /// reply is pending. Fewer bytes cannot finish the transaction, so a driver may sleep until
    /// this many have arrived (or the deadline of [`BusMaster::poll_timeout`] passes) instead
    /// of waking for every byte. Bytes already buffered count towards the reply, so garbage or
    /// an echo only makes the figure smaller, never too large.
    pub fn bytes_awaited(&self) -> Option<usize> {
        let p = self.pending?;
        Some(
            p.expected
                .wire_len()
                .saturating_sub(self.decoder.buffered())
                .max(1),
        )
    }

    /// When the awaited reply can be complete at the earliest (request sent, return delay,
    /// reply's wire time), or `None` when no reply is pending.
    pub fn reply_complete_at(&self) -> Option<Instant> {
        self.pending.map(|p| p.complete_at)
    }

    /// When a driver that leaves the port unread while a reply comes in should first look for
    /// it (then, if part is missing, wait for [`BusMaster::bytes_awaited`] bytes): when three
    /// replies in four have been found whole so far, never before
    /// [`BusMaster::reply_complete_at`]. `None` when no reply is pending.
    ///
    /// The lateness is learned from the replies, as the one three in four stay under: a reply
    /// completed while the driver waited for its last bytes tells when it completed, and
    /// raises the lateness by 3/16 of a byte time if that was later; any other lowers it by
    /// 1/16 (one found whole at the first look completed before that look). A look that finds
    /// the reply whole costs the driver one wake-up for the transaction; one that comes early
    /// costs a second (and a change of the tty's read threshold); one that comes late leaves
    /// the bus idle until then.
    pub fn reply_look_at(&self) -> Option<Instant> {
        self.pending.as_ref().map(|p| self.look_at(p))
    }

    /// The lateness learned so far (see [`BusMaster::reply_look_at`]).
    pub fn reply_lateness(&self) -> Duration {
        self.reply_lateness
    }

    fn look_at(&self, p: &Pending) -> Instant {
        (p.complete_at + self.reply_lateness).min(p.deadline)
    }

    fn learn_lateness(&mut self, p: &Pending, now: Instant) {
        // Fixed steps, three up for one down, track the lateness three replies in four stay
        // under; one reply, however late (a servo or adapter that stalled), moves it by 3/16
        // of a byte time only.
        let step = self.cfg.wire_time(1) / 16;
        let later = p.looked && now.saturating_duration_since(p.complete_at) > self.reply_lateness;
        self.reply_lateness = if later {
            (self.reply_lateness + step * 3).min(self.cfg.turnaround)
        } else {
            self.reply_lateness.saturating_sub(step)
        };
    }

    /// The driver's thread woke late (see [`BusCounters::late_wakeups`]).
    pub fn note_late_wakeup(&mut self) {
        self.counters.late_wakeups += 1;
    }

    /// The next event, oldest first.
    pub fn poll_event(&mut self) -> Option<BusEvent> {
        self.events.pop_front()
    }

    /// Every servo's state at the latest time handed in.
    pub fn status(&self) -> BusStatus {
        self.status_at(self.now)
    }

    /// Every servo's state, ages measured to `now`.
    pub fn status_at(&self, now: Instant) -> BusStatus {
        BusStatus {
            name: self.cfg.name.clone(),
            port_open: self.port_open,
            servos: self
                .servos
                .iter()
                .map(|s| s.status(now, &self.cfg))
                .collect(),
            counters: self.counters,
            at: now,
            telemetry_asked_hz: (!self.cfg.telemetry_min_interval.is_zero())
                .then(|| 1.0 / self.cfg.telemetry_min_interval.as_secs_f32()),
            thread: Default::default(),
        }
    }

    /// Whether anything a status snapshot shows (besides ages) changed since
    /// [`BusMaster::take_changed`], without resetting it.
    pub fn has_changed(&self) -> bool {
        self.changed
    }

    /// Whether anything a status snapshot shows (besides ages) changed since the last call.
    /// Call it when a snapshot is taken: every reading so far counts as shown from then on.
    pub fn take_changed(&mut self) -> bool {
        for s in &mut self.servos {
            s.reading_unshown = false;
        }
        std::mem::take(&mut self.changed)
    }

    /// Whether the reply awaited, once read, would replace a reading of its servo that no
    /// snapshot has carried since [`BusMaster::take_changed`]. A driver that holds snapshots
    /// back to save work takes one before it reads such a reply, so that whoever keeps every
    /// reading (the flight record) misses none.
    pub fn awaited_reply_hides_a_reading(&self) -> bool {
        self.pending
            .is_some_and(|p| self.servos.get(p.index).is_some_and(|s| s.reading_unshown))
    }

    pub fn counters(&self) -> &BusCounters {
        &self.counters
    }

    /// [`BusMaster::bytes_awaited`], while no look has yet found the awaited reply incomplete:
    /// what a driver compares with the bytes the port holds at its first look (see
    /// [`BusMaster::note_reply_incomplete`]). `None` after such a look, or when no reply is
    /// pending.
    pub fn bytes_awaited_at_first_look(&self) -> Option<usize> {
        self.pending.filter(|p| !p.looked)?;
        self.bytes_awaited()
    }

    /// The driver found fewer bytes in the port than the awaited reply still misses, and
    /// waits for the rest: the bytes that complete it arrive when it completed, which teaches
    /// [`BusMaster::reply_look_at`] to look later. (A tty whose bytes are still on their way
    /// through the kernel's worker holds the read that looks for them until they are in, and
    /// that read then finds the reply whole: only the port's count before the read tells that
    /// the look came early.)
    pub fn note_reply_incomplete(&mut self) {
        if let Some(p) = self.pending.as_mut() {
            p.looked = true;
        }
    }

    /// Whether a reply is awaited (nothing is transmitted until it arrives or times out).
    pub fn reply_pending(&self) -> bool {
        self.pending.is_some()
    }

    /// Stop polling and commanding; queue the final packets: the newest goals still waiting
    /// ([`ShutdownForce::AsIs`]) or force OFF for every servo ([`ShutdownForce::Off`]). They are
    /// handed out by [`BusMaster::poll_transmit`] once no reply is pending. A second call
    /// changes nothing.
    pub fn shutdown(&mut self, leave: ShutdownForce) {
        if self.shutdown.is_none() {
            self.shutdown = Some(Shutdown {
                leave,
                next: 0,
                done: false,
            });
        }
    }

    /// Whether [`BusMaster::shutdown`] was called.
    pub fn shutdown_requested(&self) -> bool {
        self.shutdown.is_some()
    }

    /// Whether every final packet has been handed out (after [`BusMaster::shutdown`]).
    pub fn is_shut_down(&self) -> bool {
        self.pending.is_none() && self.shutdown.is_some_and(|s| s.done)
    }

    /// When the bytes handed out so far will have left the wire.
    pub fn wire_idle_at(&self) -> Instant {
        self.wire_free_at
    }
}

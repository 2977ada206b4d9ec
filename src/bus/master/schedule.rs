//! What the bus carries next ([`BusMaster::poll_transmit`]): the schedule of the module docs, in
//! priority order, and the packets it writes (long packets, requests, the final packets of a
//! shutdown).

use super::{BusMaster, Pending, REACTION};
use crate::bus::goal::ShutdownForce;
use crate::bus::servo::{Phase, SentGoal, Transaction, ms10_ceil};
use crate::bus::status::ForceState;
use crate::bus::transmit::{Transmit, TxKind};
use crate::protocol::{ForceMode, GoalEntry, LongPacket, Ms10, ShortPacket};
use std::time::{Duration, Instant};

impl BusMaster {
    /// Whether a long packet is due.
    pub(super) fn command_needed(&self) -> bool {
        self.servos
            .iter()
            .any(|s| s.commandable() && (self.resend_all || s.unsent_position().is_some()))
    }

    /// The next packet to write, or `None` when nothing may or need be sent now (a reply is
    /// pending, or nothing is due until [`BusMaster::poll_timeout`]). Call it again after
    /// writing: several packets may be due at once.
    pub fn poll_transmit(&mut self, now: Instant) -> Option<Transmit> {
        self.touch(now);
        if self.pending.is_some() || self.line_busy(now) {
            return None;
        }
        if self.shutdown.is_some() {
            return self.shutdown_transmit(now);
        }
        if self.command_needed() {
            // Never more than one frame queued ahead of the wire: goals that arrive while the
            // wire is busy are coalesced here, not queued in the port.
            if self.wire_free_at > now + self.command_lead() || self.rest_of_tick(now).is_some() {
                return None;
            }
            let packet = self.long_packet(now);
            if packet.is_some() {
                // Whoever writes the tick's frame writes a read due within half an interval
                // behind it: the reads of a period then begin behind its tick, and one that
                // fell behind (a read-back took its turn) comes back there. At most half the
                // autopilot's period early: at ticks much faster than the telemetry rate,
                // reads started early would come faster than asked.
                self.chain_until = Some((now + REACTION, self.chain_early()));
                self.burst_began = now;
            }
            return packet;
        }
        let (i, tx) = self.next_request(now)?;
        if !matches!(tx, Transaction::Force(_) | Transaction::Position) {
            self.cursor = i;
        }
        Some(self.start(i, tx, now))
    }

    /// The request [`BusMaster::poll_transmit`] would start at `at` (no long packet due, no
    /// reply pending), if any. A request starts only when it ends before the next goal is
    /// expected ([`GoalRhythm::hold_until`]) and not within [`BusConfig::tick_gather`] of the
    /// latest goal. In order: a force write that is due; the next servo's read in round-robin
    /// (a full telemetry poll that does not fit becomes a read of position and current);
    /// while a goal is expected soon, a position-only read that still fits, for the servo
    /// whose position was read longest ago.
    ///
    /// [`GoalRhythm::hold_until`]: crate::bus::rhythm::GoalRhythm::hold_until
    /// [`BusConfig::tick_gather`]: crate::bus::BusConfig::tick_gather
    pub(super) fn next_request(&self, at: Instant) -> Option<(usize, Transaction)> {
        if at < self.gathering_until(at) {
            return None;
        }
        let due = |when: Option<Instant>| when.is_none_or(|t| t <= at);
        if let Some((i, mode)) = self.servos.iter().enumerate().find_map(|(i, s)| {
            s.force_due()
                .filter(|(when, _)| due(*when))
                .map(|(_, m)| (i, m))
        }) && self.fits(i, Transaction::Force(mode), at)
        {
            return Some((i, Transaction::Force(mode)));
        }
        // Right after a reply or a long packet, a periodic read due soon starts now
        // ([`BusMaster::chain_early`]): with a telemetry rate the servos are read one after
        // the other, the first written behind the tick's long packet by the thread that wrote
        // it, each of the others started by the reply before it, and the bus thread wakes
        // once per reply, not also to start a burst. A servo is read once in a burst: a burst
        // longer than the early margin would otherwise go round again, faster than asked.
        let early = self
            .chain_until
            .filter(|(until, _)| at <= *until)
            .map_or(Duration::ZERO, |(_, early)| early);
        let n = self.servos.len();
        for k in 1..=n {
            let i = (self.cursor + k) % n;
            let Some((when, tx)) = self.servos[i].poll_due(&self.cfg) else {
                continue;
            };
            let periodic = matches!(tx, Transaction::Telemetry | Transaction::Motion);
            let due_early = periodic
                && when.is_some_and(|t| t <= at + early)
                && self.servos[i]
                    .last_poll_at
                    .is_none_or(|t| t < self.burst_began);
            if !(due(when) || due_early) {
                continue;
            }
            if self.fits(i, tx, at) {
                return Some((i, tx));
            }
            if tx == Transaction::Telemetry
                && self.servos[i].phase == Phase::Ready
                && self.fits(i, Transaction::Motion, at)
            {
                return Some((i, Transaction::Motion));
            }
        }
        self.position_read_fitting(at)
            .map(|i| (i, Transaction::Position))
    }

    /// A message came at `now`: the first after a quiet spell of [`BusConfig::tick_gather`]
    /// opens a window of that length for the other messages of its tick; each message in the
    /// window extends it by as much, up to twice that length from its opening. Messages that
    /// never leave such a spell (a stream faster than the gathering) open none, so polls go on
    /// between them.
    ///
    /// [`BusConfig::tick_gather`]: crate::bus::BusConfig::tick_gather
    pub(super) fn gather_goal(&mut self, now: Instant) {
        let gather = self.cfg.tick_gather;
        self.gather = match self.gather {
            Some((opened, ends)) if now < ends => {
                Some((opened, (now + gather).min(opened + gather * 2)))
            }
            _ if self
                .rhythm
                .latest_message()
                .is_none_or(|latest| now.saturating_duration_since(latest) >= gather) =>
            {
                Some((now, now + gather))
            }
            other => other,
        };
    }

    /// Until when, seen at `at`, no request may start because the autopilot's tick is still
    /// coming in: the gathering window ([`BusMaster::gather_goal`]), closed as soon as the tick
    /// has had as many messages as the tick before (while the rhythm is known); and, while the
    /// rhythm is known, until half a period after the tick began as long as it has had fewer
    /// messages than the tick before (a message of the tick is late). Not after `at` when
    /// nothing holds requests back.
    pub(super) fn gathering_until(&self, at: Instant) -> Instant {
        // A tick with as many messages as the one before it is whole: nothing is gathered.
        let gather = match self.gather {
            Some((_, ends)) if !self.rhythm.tick_complete(at) => ends,
            _ => at,
        };
        let incomplete = self.rhythm.tick(at).and_then(|(start, period)| {
            let until = start + period / 2;
            (self.rhythm.tick_incomplete(at) && at < until).then_some(until)
        });
        incomplete.map_or(gather, |until| until.max(gather))
    }

    /// While the autopilot's tick still lacks a message that comes so soon that waiting for it
    /// costs less than a second long packet queued behind the first (one frame's wire time),
    /// the instant until which the long packet waits, so that one frame carries the whole tick.
    pub(super) fn rest_of_tick(&self, at: Instant) -> Option<Instant> {
        self.rhythm.rest_of_tick(at, self.command_lead())
    }

    /// How long transaction `tx` with servo `i` holds the bus: request and reply on the wire,
    /// the servo's return delay, and a little for the servo and the adapter to react.
    fn busy_of(&self, i: usize, tx: Transaction) -> Duration {
        let s = &self.servos[i];
        let packet = s.request(tx);
        let bytes = packet.wire_len() + packet.expected_reply().wire_len();
        self.cfg.wire_time(bytes) + s.return_delay(&self.cfg) + REACTION
    }

    /// Whether transaction `tx` with servo `i`, started at `at` (behind whatever is still on
    /// the wire), ends before the next goal is expected.
    fn fits(&self, i: usize, tx: Transaction, at: Instant) -> bool {
        let start = self.wire_free_at.max(at);
        self.rhythm.hold_until(start, self.busy_of(i, tx)).is_none()
    }

    /// While a goal is expected too soon for the next servo's poll: the ready servo whose
    /// position was read longest ago, if a read of its position alone still ends in time.
    /// Only on a bus that reads as often as it can (a telemetry rate leaves the bus idle).
    fn position_read_fitting(&self, at: Instant) -> Option<usize> {
        if !self.cfg.telemetry_min_interval.is_zero() {
            return None;
        }
        let start = self.wire_free_at.max(at);
        let (i, _) = self
            .servos
            .iter()
            .enumerate()
            .filter(|(_, s)| s.phase == Phase::Ready)
            .min_by_key(|(_, s)| s.position_read_at())?;
        let gated = self
            .rhythm
            .hold_until(start, self.busy_of(i, Transaction::Motion))
            .is_some();
        (gated && self.fits(i, Transaction::Position, at)).then_some(i)
    }

    /// How early a periodic read may start right behind a long packet or a reply: half the
    /// telemetry interval, and at most half the autopilot's period (at ticks much faster than
    /// the telemetry rate, reads started early would come faster than asked); a quarter of
    /// the interval while the period is unknown. As wide after a reply as after the packet:
    /// the reads of a period stay together behind its tick, where a narrower margin after a
    /// reply let one that once fell behind (a slow reply, a read-back) stay behind, costing
    /// a wake-up of its own in every period.
    pub(super) fn chain_early(&self) -> Duration {
        let early = self.cfg.telemetry_min_interval / 2;
        self.rhythm.period().map_or(early / 2, |p| early.min(p / 2))
    }

    /// How far ahead of the wire a long packet may be queued: one frame of the largest size.
    pub(super) fn command_lead(&self) -> Duration {
        self.cfg.wire_time(8 + 5 * self.servos.len())
    }

    /// Write a request to servo `i` and wait for its reply.
    fn start(&mut self, i: usize, tx: Transaction, now: Instant) -> Transmit {
        let s = &mut self.servos[i];
        let id = s.id();
        let packet = s.request(tx);
        let chained = self.chain_until.is_some_and(|(until, _)| now <= until);
        match tx {
            Transaction::Telemetry | Transaction::Motion => {
                if !chained {
                    // Started when due, not behind a packet or a reply: a new burst.
                    self.burst_began = now;
                }
                s.last_poll_at = Some(now);
            }
            Transaction::Verify => s.last_verify_at = Some(now),
            _ => {}
        }
        let return_delay = s.return_delay(&self.cfg);
        let kind = match tx {
            Transaction::Identify | Transaction::ReadRam => TxKind::Init(id),
            Transaction::Probe => TxKind::Probe(id),
            Transaction::Telemetry => TxKind::Poll(id),
            Transaction::Motion => TxKind::MotionPoll(id),
            Transaction::Position => TxKind::PositionPoll(id),
            Transaction::Verify => TxKind::Verify(id),
            Transaction::Force(_) => TxKind::Force(id),
        };
        match tx {
            Transaction::Telemetry => self.counters.polls += 1,
            Transaction::Motion => self.counters.motion_polls += 1,
            Transaction::Position => self.counters.position_polls += 1,
            _ => self.counters.other_requests += 1,
        }
        let expected = packet.expected_reply();
        let transmit = self.emit(packet.to_bytes(), kind, now);
        if expected.wire_len() > 0 {
            let complete_at =
                self.wire_free_at + return_delay + self.cfg.wire_time(expected.wire_len());
            self.pending = Some(Pending {
                index: i,
                tx,
                expected,
                complete_at,
                looked: false,
                garbled: false,
                deadline: complete_at + self.cfg.turnaround,
                received_before: self.counters.bytes_received,
                skipped_before: self.skipped_bytes(),
                request_ends: self.wire_free_at,
                heard: 0,
                foreign_before: self.foreign_bytes,
            });
        }
        Transmit {
            expects_reply: expected.wire_len() > 0,
            ..transmit
        }
    }

    /// Account for `bytes` going on the wire after whatever is still queued.
    fn emit(&mut self, bytes: Vec<u8>, kind: TxKind, now: Instant) -> Transmit {
        self.changed = true;
        let wire_time = self.cfg.wire_time(bytes.len());
        let start = self.wire_free_at.max(now);
        self.wire_free_at = start + wire_time;
        self.last_start = Some(start);
        self.counters.bytes_sent += bytes.len() as u64;
        self.counters.wire_busy_ns += self.cfg.baud.wire_time_ns(bytes.len());
        Transmit {
            bytes,
            kind,
            expects_reply: false,
            wire_time,
        }
    }

    /// One long packet with an entry for every commanded servo. A new goal carries the
    /// servo's goal time (or a soft-start time); a goal sent again carries the time left of
    /// the move it started, so that re-sending never slows a move down. Goal times are left
    /// out of the frame when every entry's is zero and every servo's register already is.
    fn long_packet(&mut self, now: Instant) -> Option<Transmit> {
        let start = self.wire_free_at.max(now);
        struct Entry {
            index: usize,
            position: crate::protocol::MmCenti,
            new: bool,
            soft: bool,
            time: Duration,
        }
        let mut entries = Vec::new();
        let mut with_time = false;
        for (index, s) in self.servos.iter().enumerate() {
            if !s.commandable() {
                continue;
            }
            let Some(position) = s.desired_position() else {
                continue;
            };
            let new = s.unsent_position().is_some();
            let soft_active = s.soft_pending || s.soft_until.is_some_and(|u| start < u);
            let (time, soft) = if new {
                match soft_active
                    .then(|| s.soft_start_time(position, &self.cfg))
                    .flatten()
                {
                    Some(t) => (t, true),
                    None => (
                        s.setup
                            .goal_time
                            .map_or(Duration::ZERO, |t| Duration::from_millis(t.millis().into())),
                        false,
                    ),
                }
            } else {
                (s.sent.map_or(Duration::ZERO, |g| g.remaining(start)), false)
            };
            with_time |= ms10_ceil(time) != Ms10(0) || s.goal_time_reg != Some(Ms10(0));
            entries.push(Entry {
                index,
                position,
                new,
                soft,
                time,
            });
        }
        self.resend_all = false;
        if entries.is_empty() {
            return None;
        }
        let goals: Vec<GoalEntry> = entries
            .iter()
            .map(|e| GoalEntry {
                id: self.servos[e.index].id(),
                position: e.position,
                time: with_time.then(|| ms10_ceil(e.time)),
            })
            .collect();
        let packet = match LongPacket::goals(&goals) {
            Ok(p) => p,
            Err(_) => {
                // Cannot happen (positions are clamped, IDs unique); never retry it forever.
                for e in &entries {
                    let s = &mut self.servos[e.index];
                    s.sent = Some(SentGoal {
                        position: e.position,
                        at: start,
                        move_time: e.time,
                    });
                }
                return None;
            }
        };
        for e in &entries {
            let s = &mut self.servos[e.index];
            if e.new {
                self.counters.goals_sent += 1;
                s.sent = Some(SentGoal {
                    position: e.position,
                    at: start,
                    move_time: e.time,
                });
                // The first soft move fixes how long the soft start lasts; goals that change
                // meanwhile are approached at the soft speed but never extend it.
                if e.soft && s.soft_pending {
                    s.soft_pending = false;
                    s.soft_until = Some(start + e.time);
                }
            }
            if with_time {
                s.goal_time_reg = Some(ms10_ceil(e.time));
            }
        }
        self.counters.command_frames += 1;
        Some(self.emit(packet.to_bytes(), TxKind::Command, now))
    }

    fn shutdown_transmit(&mut self, now: Instant) -> Option<Transmit> {
        let mut sd = self.shutdown?;
        if sd.done {
            return None;
        }
        let out = match sd.leave {
            ShutdownForce::AsIs => {
                sd.done = true;
                if self.command_needed() {
                    self.long_packet(now)
                } else {
                    None
                }
            }
            ShutdownForce::Off | ShutdownForce::Brake => {
                let (mode, state) = match sd.leave {
                    ShutdownForce::Brake => (ForceMode::Brake, ForceState::Brake),
                    _ => (ForceMode::Off, ForceState::Off),
                };
                let next = self.servos[sd.next.min(self.servos.len())..]
                    .iter()
                    .position(|s| !matches!(s.phase, Phase::WrongModel { .. }))
                    .map(|k| sd.next + k);
                match next {
                    Some(i) => {
                        sd.next = i + 1;
                        let s = &mut self.servos[i];
                        let id = s.id();
                        s.force = state;
                        s.sent = None;
                        let bytes = ShortPacket::force(id.into(), mode).to_bytes();
                        Some(self.emit(bytes, TxKind::Final(Some(id)), now))
                    }
                    None => {
                        sd.done = true;
                        None
                    }
                }
            }
        };
        self.shutdown = Some(sd);
        out
    }
}

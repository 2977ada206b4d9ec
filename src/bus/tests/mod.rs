//! Unit tests of the sans-IO bus master, one per rule, driven with simulated time: they never
//! sleep and check timing to the nanosecond.
//!
//! `FakeServo` is a minimal LJ9DA41 (memory map, force rules, replies); `Rig` carries packets
//! between it and the bus master, keeping wire time at the bus speed. Both, and the helpers
//! the tests share, are here; the tests are in one file per topic:
//! - `startup`: what is read and written before the first goal;
//! - `goals`: goals into long packets (coalesced, clamped, soft start, goal time);
//! - `force`: force ON, OFF and brake, and a refused force ON;
//! - `exchange`: one request at a time on the wire, and its reply deadline;
//! - `reply_looks`: when the bus thread looks for a reply, and what it learns;
//! - `bad_replies`: echoes, garbage, bad sums and replies of another servo;
//! - `late_replies`: a reply after its allowance, or begun when it ends: never a word over it;
//! - `reply_quality`: a servo's share of bad replies (degraded, never lost);
//! - `health`: a servo lost, probed, back, restarted;
//! - `alarms`: temperature alarm and error, stall;
//! - `telemetry`: the polls, what they replace, and what the driver shows of them;
//! - `goal_timing`: an autopilot's goals against the polls (the bus free when they come);
//! - `ticks`: the autopilot's ticks as a real autopilot sends them;
//! - `port`: the port lost and back;
//! - `shutdown`: the last packets.

use super::*;
use crate::protocol::{
    BaudRate, Ma10, MmCenti, Ms10, Percent, ReplyFlags, ReturnPacket, ServoId, registers::addr,
};
use std::time::{Duration, Instant};

fn id(n: u8) -> ServoId {
    ServoId::new(n).unwrap()
}

fn us(n: u64) -> Duration {
    Duration::from_micros(n)
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// Wire time of `n` bytes at 115 200 bit/s.
fn wire(n: usize) -> Duration {
    Duration::from_nanos(BaudRate::B115200.wire_time_ns(n))
}

/// A minimal servo: stores writes, answers requests, applies the force rules.
#[derive(Debug, Clone)]
struct FakeServo {
    id: u8,
    model: u16,
    return_delay_ms: u8,
    reverse: u8,
    plus: i16,
    minus: i16,
    goal: i16,
    goal_time: u16,
    max_force: u8,
    force: u8,
    position: i16,
    load: u16,
    temperature: i16,
    voltage: u16,
    flags: u8,
    /// Answers at all.
    present: bool,
    /// Refuses force ON (as with the rod outside the limits).
    refuse_force: bool,
    /// The rod does not follow the goal.
    stuck: bool,
    /// Every reply goes out with a bad sum.
    garble: bool,
    /// This share of the replies goes out with a bad sum (a deterministic sequence).
    garble_share: f64,
    /// Replies so far, for `garble_share`.
    replies: u64,
    /// Every goal write seen: (position, goal time if written).
    goal_writes: Vec<(i16, Option<u16>)>,
}

impl FakeServo {
    fn new(id: u8) -> Self {
        FakeServo {
            id,
            model: 0x7510,
            return_delay_ms: 0,
            reverse: 0,
            plus: 2500,
            minus: -2500,
            goal: 0,
            goal_time: 0,
            max_force: 100,
            force: 0,
            position: 0,
            load: 7,
            temperature: 30,
            voltage: 1200,
            flags: 0,
            present: true,
            refuse_force: false,
            stuck: false,
            garble: false,
            garble_share: 0.0,
            replies: 0,
            goal_writes: Vec::new(),
        }
    }

    fn power_cycle(&mut self) {
        self.force = 0;
        self.goal = 0;
        self.goal_time = 0;
        self.flags = 0;
        self.max_force = 100;
    }

    fn regs(&self) -> [u8; 60] {
        let mut r = [0u8; 60];
        let mut put16 = |a: usize, v: u16| r[a..a + 2].copy_from_slice(&v.to_le_bytes());
        put16(0, self.model);
        put16(8, self.plus as u16);
        put16(10, self.minus as u16);
        put16(14, 85);
        put16(30, self.goal as u16);
        put16(32, self.goal_time);
        put16(42, self.position as u16);
        put16(48, self.load);
        put16(50, self.temperature as u16);
        put16(52, self.voltage);
        r[2] = 3;
        r[4] = self.id;
        r[5] = self.reverse;
        r[6] = 7;
        r[7] = self.return_delay_ms;
        r[35] = self.max_force;
        r[36] = self.force;
        r[59] = 0xFF;
        r
    }

    fn write(&mut self, address: u8, data: &[u8]) {
        let mut goal_write: Option<(i16, Option<u16>)> = None;
        for (k, b) in data.iter().enumerate() {
            let a = address as usize + k;
            match a {
                0x1E => {
                    let p = i16::from_le_bytes([*b, data.get(k + 1).copied().unwrap_or(0)]);
                    self.goal = p.clamp(self.minus, self.plus);
                    goal_write = Some((p, None));
                }
                0x20 => {
                    self.goal_time =
                        u16::from_le_bytes([*b, data.get(k + 1).copied().unwrap_or(0)]);
                    if let Some((p, _)) = goal_write {
                        goal_write = Some((p, Some(self.goal_time)));
                    }
                }
                0x23 => self.max_force = *b,
                0x24 => match *b {
                    1 if self.refuse_force || self.flags & 0x80 != 0 => {}
                    1 => {
                        self.force = 1;
                        self.goal = self.position;
                    }
                    v => self.force = v,
                },
                _ => {}
            }
        }
        if let Some(w) = goal_write {
            self.goal_writes.push(w);
        }
        if self.force == 1 && !self.stuck {
            self.position = self.goal;
        }
    }

    /// Handle one host packet; the reply bytes, if it asks for one.
    fn handle(&mut self, p: &[u8]) -> Option<Vec<u8>> {
        if p.len() < 8 || p[0] != 0xFA || p[1] != 0xAF {
            return None;
        }
        let (pid, flag, address, len, count) = (p[2], p[3], p[4], p[5] as usize, p[6] as usize);
        if pid == 0 && flag == 0 {
            for e in p[7..p.len() - 1].chunks(len) {
                if e[0] == self.id {
                    self.write(address, &e[1..]);
                }
            }
            return None;
        }
        if pid != self.id {
            return None;
        }
        if count == 1 && len > 0 {
            self.write(address, &p[7..7 + len]);
        }
        let (a, n) = match flag & 0x0F {
            0x3 => (0usize, 30usize),
            0x5 => (30, 30),
            0x9 => (42, 18),
            0xB => (30, 12),
            0xF => (address as usize, len),
            _ => return None,
        };
        if !self.present {
            return None;
        }
        let regs = self.regs();
        let mut reply = ReturnPacket {
            id: self.id,
            flags: ReplyFlags(self.flags),
            address: a as u8,
            data: regs[a..a + n].to_vec(),
        }
        .to_bytes();
        self.replies += 1;
        // Spread evenly: reply k is garbled when the running share falls behind.
        let share_due = (self.replies as f64 * self.garble_share).floor()
            > ((self.replies - 1) as f64 * self.garble_share).floor();
        if (self.garble || share_due)
            && let Some(sum) = reply.last_mut()
        {
            *sum ^= 0x55;
        }
        Some(reply)
    }
}

/// One packet the bus master wrote, and when.
#[derive(Debug, Clone)]
struct Sent {
    at: Instant,
    tx: Transmit,
}

/// The bus master, the fake servos and the simulated wire between them.
struct Rig {
    m: BusMaster,
    servos: Vec<FakeServo>,
    t: Instant,
    t0: Instant,
    wire_free: Instant,
    reply: Option<(Instant, Vec<u8>)>,
    log: Vec<Sent>,
    events: Vec<BusEvent>,
    /// The adapter echoes every packet written.
    echo: bool,
    /// Bytes put on the line before every reply.
    noise: Vec<u8>,
    /// Time from the end of a request to the servo's first reply byte, besides the return
    /// delay.
    latency: Duration,
    /// When each reply was handed to the bus master.
    replied_at: Vec<Instant>,
    /// When set, takes snapshots at the rig's turns as the driver publishes them.
    publisher: Option<Publisher>,
}

/// The driver's publishing, at each turn of the rig (a reply handed in, or a timeout): a
/// snapshot when something changed, at most every `spacing`; one at the first turn after each
/// `event_every`, as for an event; and, when `guarded`, one before a reply is handed in that
/// would replace a reading no snapshot has shown.
struct Publisher {
    spacing: Duration,
    event_every: Duration,
    guarded: bool,
    taken_at: Instant,
    next_event: Instant,
    snapshots: Vec<BusStatus>,
    /// Snapshots taken before a reply.
    guards: usize,
    /// Every this many replies, the driver looks for one 200 µs before it has arrived (a wake-up
    /// that finds it incomplete), and which reply it looked at so.
    early_every: usize,
    looked_early: Option<Instant>,
}

impl Publisher {
    fn take(&mut self, m: &mut BusMaster, now: Instant) {
        m.take_changed();
        self.snapshots.push(m.status_at(now));
    }

    /// When to look early for the reply due at `reply_at`, the `replies`th.
    fn early_look(&self, reply_at: Instant, replies: usize) -> Option<Instant> {
        (replies.is_multiple_of(self.early_every) && self.looked_early != Some(reply_at))
            .then(|| reply_at - us(200))
    }

    fn before_reply(&mut self, m: &mut BusMaster, now: Instant) {
        if self.guarded && m.awaited_reply_hides_a_reading() {
            self.take(m, now);
            self.guards += 1;
        }
    }

    fn after_turn(&mut self, m: &mut BusMaster, now: Instant) {
        let event = now >= self.next_event;
        if event || (m.has_changed() && now - self.taken_at >= self.spacing) {
            while self.next_event <= now {
                self.next_event += self.event_every;
            }
            self.take(m, now);
            self.taken_at = now;
        }
    }
}

impl Rig {
    fn new(cfg: BusConfig) -> Self {
        let t0 = Instant::now();
        let servos = cfg
            .servos
            .iter()
            .map(|s| FakeServo::new(s.id.get()))
            .collect();
        Rig {
            m: BusMaster::new(cfg, t0),
            servos,
            t: t0,
            t0,
            wire_free: t0,
            reply: None,
            log: Vec::new(),
            events: Vec::new(),
            echo: false,
            noise: Vec::new(),
            latency: us(100),
            replied_at: Vec::new(),
            publisher: None,
        }
    }

    fn with_ids(ids: &[u8]) -> Self {
        Self::new(config(ids))
    }

    fn servo(&mut self, n: u8) -> &mut FakeServo {
        self.servos.iter_mut().find(|s| s.id == n).unwrap()
    }

    fn wire(&self, bytes: usize) -> Duration {
        self.m.config().wire_time(bytes)
    }

    /// Write everything the bus master has due at the current time.
    fn transmit(&mut self) {
        while let Some(tx) = self.m.poll_transmit(self.t) {
            let start = self.wire_free.max(self.t);
            self.wire_free = start + self.wire(tx.bytes.len());
            if self.echo {
                self.m.handle_input(&tx.bytes, self.wire_free);
            }
            let mut answer = None;
            for s in &mut self.servos {
                if let Some(r) = s.handle(&tx.bytes) {
                    answer = Some((r, s.return_delay_ms));
                }
            }
            if let Some((bytes, delay)) = answer {
                let at =
                    self.wire_free + ms(u64::from(delay)) + self.latency + self.wire(bytes.len());
                self.reply = Some((at, bytes));
            }
            self.log.push(Sent { at: self.t, tx });
            assert!(
                self.log.len() < 1_000_000,
                "runaway: {:?}",
                &self.log[self.log.len() - 5..]
            );
        }
    }

    /// Run the bus until `d` after the current time.
    fn run(&mut self, d: Duration) {
        let end = self.t + d;
        loop {
            self.transmit();
            let next = match (&self.reply, self.m.poll_timeout()) {
                (Some((r, _)), Some(t)) => Some((*r).min(t.max(self.t))),
                (Some((r, _)), None) => Some(*r),
                (None, t) => t.map(|t| t.max(self.t)),
            };
            let early = match (&self.publisher, &self.reply) {
                (Some(p), Some((r, _))) => p
                    .early_look(*r, self.replied_at.len())
                    .filter(|&at| at >= self.t && next.is_none_or(|n| at < n)),
                _ => None,
            };
            if let (Some(at), Some(p)) = (early, self.publisher.as_mut())
                && at <= end
            {
                self.t = at;
                p.looked_early = self.reply.as_ref().map(|(r, _)| *r);
                self.m.handle_timeout(at);
                p.after_turn(&mut self.m, at);
                self.drain_events();
                continue;
            }
            match next {
                Some(n) if n <= end => self.t = n,
                _ => {
                    self.t = end;
                    self.m.handle_timeout(self.t);
                    break;
                }
            }
            if self.reply.as_ref().is_some_and(|(r, _)| *r <= self.t) {
                let (_, bytes) = self.reply.take().unwrap();
                if let Some(p) = self.publisher.as_mut() {
                    p.before_reply(&mut self.m, self.t);
                }
                if !self.noise.is_empty() {
                    let noise = self.noise.clone();
                    self.m.handle_input(&noise, self.t);
                }
                // Deliver in two pieces, as a port would.
                let (a, b) = bytes.split_at(bytes.len() / 2);
                self.m.handle_input(a, self.t);
                self.m.handle_input(b, self.t);
                self.replied_at.push(self.t);
            } else {
                self.m.handle_timeout(self.t);
            }
            if let Some(p) = self.publisher.as_mut() {
                p.after_turn(&mut self.m, self.t);
            }
            self.drain_events();
        }
        self.drain_events();
    }

    /// Complete the exchange in flight (its reply, or its timeout) and stop there, before the
    /// bus master writes anything else.
    fn settle(&mut self) {
        if let Some((at, bytes)) = self.reply.take() {
            self.t = self.t.max(at);
            self.m.handle_input(&bytes, self.t);
        } else if let Some(deadline) = self.m.poll_timeout().filter(|_| self.m.reply_pending()) {
            self.t = self.t.max(deadline);
            self.m.handle_timeout(self.t);
        }
        self.drain_events();
        assert!(!self.m.reply_pending());
    }

    fn drain_events(&mut self) {
        while let Some(e) = self.m.poll_event() {
            self.events.push(e);
        }
    }

    fn set_goal(&mut self, n: u8, goal: Goal) {
        self.m.set_goal(id(n), goal, self.t);
    }

    /// An output message of the autopilot at the current time, with the goals it changed
    /// (none: it repeated the last ones).
    fn message(&mut self, goals: &[(u8, Goal)]) {
        self.m.output_message(self.t);
        for &(n, goal) in goals {
            self.set_goal(n, goal);
        }
    }

    fn health(&self, n: u8) -> Health {
        self.m.status().servo(id(n)).unwrap().health
    }

    fn sent_since(&self, from: usize) -> &[Sent] {
        &self.log[from..]
    }

    fn commands_since(&self, from: usize) -> Vec<Vec<(u8, i16, Option<u16>)>> {
        self.sent_since(from)
            .iter()
            .filter(|s| s.tx.kind == TxKind::Command)
            .map(|s| parse_long(&s.tx.bytes))
            .collect()
    }

    fn kinds_since(&self, from: usize) -> Vec<TxKind> {
        self.sent_since(from).iter().map(|s| s.tx.kind).collect()
    }

    /// Start every servo and switch force ON with a first goal at its present position.
    fn online_with_force(ids: &[u8]) -> Self {
        Self::online_with_force_on(config(ids))
    }

    /// Servo 1 alone, online, every poll a full one, settled; then its next poll handed out
    /// (and not written): the rig at the instant of that poll, and the poll.
    fn at_a_full_poll() -> (Self, Transmit) {
        let mut rig = Self::online_with_force_on(full_polls_only(&[1]));
        rig.settle();
        rig.run(ms(50));
        rig.settle();
        rig.t = rig.m.poll_timeout().expect("a poll is due").max(rig.t);
        rig.m.handle_timeout(rig.t);
        let tx = rig.m.poll_transmit(rig.t).expect("a poll");
        assert_eq!(tx.kind, TxKind::Poll(id(1)));
        (rig, tx)
    }

    /// [`Rig::online_with_force`] on the bus `cfg`.
    fn online_with_force_on(cfg: BusConfig) -> Self {
        let ids: Vec<u8> = cfg.servos.iter().map(|s| s.id.get()).collect();
        let ids = &ids[..];
        let mut rig = Self::new(cfg);
        rig.run(ms(100));
        for &n in ids {
            assert_eq!(rig.health(n), Health::Online, "servo {n} online");
            rig.set_goal(n, Goal::Position(MmCenti(0)));
        }
        rig.run(ms(100));
        for &n in ids {
            assert_eq!(rig.servo(n).force, 1, "servo {n} force on");
        }
        rig
    }
}

fn config(ids: &[u8]) -> BusConfig {
    BusConfig::new(
        "test",
        BaudRate::B115200,
        ids.iter()
            .map(|&n| ServoSetup::new(id(n), format!("s{n}")))
            .collect(),
    )
}

/// A bus whose every poll reads the full registers 42–59 (no reads of position and current
/// alone between them).
fn full_polls_only(ids: &[u8]) -> BusConfig {
    let mut cfg = config(ids);
    cfg.full_telemetry_interval = Duration::ZERO;
    cfg
}

/// (VID, position, goal time) of every entry of a long packet.
fn parse_long(b: &[u8]) -> Vec<(u8, i16, Option<u16>)> {
    assert_eq!(&b[..4], &[0xFA, 0xAF, 0, 0], "a long packet");
    assert_eq!(b[4], addr::GOAL_POSITION);
    let (len, count) = (b[5] as usize, b[6] as usize);
    assert_eq!(b.len(), 8 + len * count);
    b[7..b.len() - 1]
        .chunks(len)
        .map(|e| {
            let pos = i16::from_le_bytes([e[1], e[2]]);
            let time = (len == 5).then(|| u16::from_le_bytes([e[3], e[4]]));
            (e[0], pos, time)
        })
        .collect()
}

/// A deterministic uniform offset in ±`range_us` for tick `k`.
fn uniform(k: usize, salt: usize, range_us: i64) -> i64 {
    let mut x = (k as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (salt as u64) << 32;
    x ^= x >> 29;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 32;
    (x % (2 * range_us as u64 + 1)) as i64 - range_us
}

mod alarms;
mod bad_replies;
mod exchange;
mod force;
mod goal_timing;
mod goals;
mod health;
mod late_replies;
mod port;
mod reply_looks;
mod reply_quality;
mod shutdown;
mod startup;
mod telemetry;
mod ticks;

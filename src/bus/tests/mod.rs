//! Unit tests of the sans-IO bus master, one per rule, driven with simulated time: they never
//! sleep and check timing to the nanosecond.
//!
//! `FakeServo` is a minimal LJ9DA41 (memory map, force rules, replies); `Rig` carries packets
//! between it and the bus master, keeping wire time at the bus speed.

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

#[test]
fn startup_reads_identity_ram_and_telemetry_and_leaves_force_off() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(2).reverse = 1;
    rig.servo(2).plus = 2000;
    rig.servo(2).minus = -1500;
    rig.servo(2).return_delay_ms = 1;
    rig.run(ms(100));
    let kinds = rig.kinds_since(0);
    let of = |n: u8| -> Vec<Vec<u8>> {
        rig.log
            .iter()
            .filter(|s| s.tx.bytes[2] == n)
            .map(|s| s.tx.bytes.clone())
            .take(3)
            .collect()
    };
    // Registers 0–29, then 30–41, then 42–59.
    assert_eq!(of(1)[0], vec![0xFA, 0xAF, 1, 0x03, 0, 0, 1, 0x03]);
    assert_eq!(of(1)[1], vec![0xFA, 0xAF, 1, 0x0B, 0, 0, 1, 0x0B]);
    assert_eq!(of(1)[2], vec![0xFA, 0xAF, 1, 0x09, 0, 0, 1, 0x09]);
    assert!(
        kinds
            .iter()
            .all(|k| !matches!(k, TxKind::Force(_) | TxKind::Command))
    );
    let st = rig.m.status();
    let s2 = st.servo(id(2)).unwrap();
    assert_eq!(s2.health, Health::Online);
    assert_eq!(s2.identity.model, Some(0x7510));
    assert_eq!(s2.identity.firmware, Some(3));
    assert_eq!(s2.identity.reversed, Some(true));
    assert_eq!(s2.identity.return_delay, Some(ms(1)));
    assert_eq!(
        s2.identity.limits.map(|l| (l.minus(), l.plus())),
        Some((MmCenti(-1500), MmCenti(2000)))
    );
    assert_eq!(s2.force, ForceState::Off);
    assert!(rig.events.contains(&BusEvent::ServoOnline { id: id(1) }));
    assert!(rig.events.contains(&BusEvent::ServoOnline { id: id(2) }));
    assert_eq!(rig.servo(1).force, 0, "no force before the first goal");
}

#[test]
fn max_force_is_written_at_startup_when_configured() {
    let mut cfg = config(&[1]);
    cfg.servos[0].max_force = Some(Percent::new(80).unwrap());
    let mut rig = Rig::new(cfg);
    rig.run(ms(50));
    assert_eq!(rig.servo(1).max_force, 80);
    let mut cfg = config(&[1]);
    cfg.servos[0].max_force = None;
    let mut rig = Rig::new(cfg);
    rig.servo(1).max_force = 55;
    rig.run(ms(50));
    assert_eq!(rig.servo(1).max_force, 55, "left alone when not configured");
}

#[test]
fn first_goal_switches_force_on_before_the_long_packet() {
    let mut rig = Rig::with_ids(&[1]);
    rig.run(ms(100));
    rig.servo(1).position = 321;
    rig.run(ms(20));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(400)));
    rig.run(ms(50));
    let kinds = rig.kinds_since(from);
    let force = kinds
        .iter()
        .position(|k| *k == TxKind::Force(id(1)))
        .unwrap();
    let command = kinds.iter().position(|k| *k == TxKind::Command).unwrap();
    assert!(force < command, "force ON first: {kinds:?}");
    // Force ON took the present position as goal; the first goal written is ours.
    assert_eq!(rig.servo(1).goal_writes.first().map(|w| w.0), Some(400));
    assert_eq!(rig.servo(1).position, 400);
    let st = rig.m.status();
    assert_eq!(st.servo(id(1)).unwrap().force, ForceState::On);
    assert_eq!(st.servo(id(1)).unwrap().goal, Some(MmCenti(400)));
}

#[test]
fn a_goal_change_sends_one_long_packet_with_every_servo() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    rig.set_goal(1, Goal::Position(MmCenti(100)));
    rig.set_goal(2, Goal::Position(MmCenti(-200)));
    rig.set_goal(3, Goal::Position(MmCenti(300)));
    rig.set_goal(4, Goal::Position(MmCenti(-400)));
    rig.run(ms(300));
    // Only servo 3 changes: the next bus slot is one long packet carrying all four.
    let from = rig.log.len();
    rig.set_goal(3, Goal::Position(MmCenti(333)));
    assert!(rig.m.reply_pending(), "a poll is in flight");
    rig.run(ms(10));
    let sent = rig.sent_since(from);
    let first = sent
        .iter()
        .position(|s| s.tx.kind == TxKind::Command)
        .unwrap();
    assert!(
        sent[..first].iter().all(|s| !s.tx.expects_reply),
        "the command takes the first free slot"
    );
    let commands = rig.commands_since(from);
    assert_eq!(commands.len(), 1, "one frame");
    let entries: Vec<(u8, i16)> = commands[0].iter().map(|e| (e.0, e.1)).collect();
    assert_eq!(entries, vec![(1, 100), (2, -200), (3, 333), (4, -400)]);
    assert_eq!(rig.servo(3).position, 333);
}

#[test]
fn nothing_is_transmitted_while_a_reply_is_pending() {
    let mut rig = Rig::with_ids(&[1, 2]);
    let t0 = rig.t0;
    let tx = rig.m.poll_transmit(t0).unwrap();
    assert!(tx.expects_reply);
    let deadline = rig.m.poll_timeout().unwrap();
    // New goals, time passing, unrelated bytes: still nothing until the reply or the deadline.
    rig.m
        .set_goal(id(2), Goal::Position(MmCenti(5)), t0 + us(10));
    for k in 0..50u32 {
        let t = t0 + (deadline - t0) * k / 50;
        rig.m.handle_input(&[0x00, 0x13], t);
        rig.m.handle_timeout(t);
        assert!(rig.m.poll_transmit(t).is_none(), "at {:?}", t - t0);
    }
    rig.m.handle_timeout(deadline - Duration::from_nanos(1));
    assert!(
        rig.m
            .poll_transmit(deadline - Duration::from_nanos(1))
            .is_none()
    );
    rig.m.handle_timeout(deadline);
    assert!(
        rig.m.poll_transmit(deadline).is_some(),
        "free after the timeout"
    );

    // Over a long run with every servo answering: each request's reply (or timeout) comes
    // before the next packet is written.
    let mut rig = Rig::online_with_force(&[1, 2, 3]);
    for k in 0..200 {
        rig.set_goal(1 + (k % 3) as u8, Goal::Position(MmCenti(k as i16)));
        rig.run(us(1700));
    }
    let c = rig.m.counters();
    let replies = c.telemetry_replies + c.other_requests + u64::from(rig.m.reply_pending());
    let requests = c.polls + c.motion_polls + c.other_requests;
    assert_eq!(replies, requests, "every request answered");
    assert_eq!(rig.m.counters().timeouts, 0);
    assert_eq!(rig.m.counters().unexpected_replies, 0);
}

#[test]
fn reply_timeout_is_wire_time_plus_return_delay_plus_turnaround() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    // Identity read before register 7 is known: 8-byte request, 38-byte reply, assumed delay.
    let expected = t0 + wire(8) + wire(38) + ms(5) + ms(2);
    let tx = rig.m.poll_transmit(t0).unwrap();
    assert_eq!(tx.wire_time, wire(8));
    assert_eq!(rig.m.poll_timeout(), Some(expected));

    // Once register 7 says 3 ms, a telemetry poll: 8 + 26 bytes + 3 ms + 2 ms.
    let mut rig = Rig::new(full_polls_only(&[1]));
    rig.servo(1).return_delay_ms = 3;
    rig.run(ms(100));
    assert_eq!(rig.health(1), Health::Online);
    rig.settle();
    rig.servo(1).present = false;
    let t = rig.t + us(7);
    rig.m.handle_timeout(t);
    let tx = rig.m.poll_transmit(t).unwrap();
    assert_eq!(tx.kind, TxKind::Poll(id(1)));
    assert_eq!(
        rig.m.poll_timeout(),
        Some(t + wire(8) + wire(26) + ms(3) + ms(2))
    );

    // A request queued behind a long packet counts from the end of that packet.
    let mut cfg = config(&[1, 2]);
    cfg.tick_gather = Duration::ZERO;
    let mut rig = Rig::online_with_force_on(cfg);
    rig.settle();
    let t = rig.t;
    rig.set_goal(1, Goal::Position(MmCenti(10)));
    let long = rig.m.poll_transmit(t).unwrap();
    assert_eq!(long.kind, TxKind::Command);
    let poll = rig.m.poll_transmit(t).unwrap();
    assert!(poll.expects_reply);
    let reply_len = match poll.kind {
        TxKind::Poll(_) => 26,
        TxKind::MotionPoll(_) => 16,
        _ => 20,
    };
    assert_eq!(
        rig.m.poll_timeout(),
        Some(t + long.wire_time + wire(8) + wire(reply_len) + ms(2))
    );
}

#[test]
fn a_servo_goes_offline_after_n_timeouts_and_is_probed_with_backoff() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.servo(2).present = false;
    let silent_from = rig.t;
    // Three missed replies are not enough: the servo must also have been silent for
    // `offline_after_silence`.
    while rig.m.status().servo(id(2)).unwrap().consecutive_timeouts < 3 {
        rig.run(ms(1));
    }
    assert_eq!(rig.health(2), Health::Online);
    assert!(!rig.events.contains(&BusEvent::ServoLost { id: id(2) }));
    while !rig.events.contains(&BusEvent::ServoLost { id: id(2) }) {
        rig.run(ms(1));
        assert!(
            rig.t - silent_from < ms(400),
            "not lost after 400 ms of silence"
        );
    }
    assert!(
        rig.t - silent_from >= ms(300),
        "lost after {:?}",
        rig.t - silent_from
    );
    assert_eq!(rig.health(2), Health::Offline);
    assert!(rig.m.status().servo(id(2)).unwrap().consecutive_timeouts >= 3);
    assert_eq!(
        rig.health(1),
        Health::Online,
        "the other servo is unaffected"
    );
    let from = rig.log.len();
    rig.run(ms(8000));
    let probes: Vec<Instant> = rig
        .sent_since(from)
        .iter()
        .filter(|s| s.tx.kind == TxKind::Probe(id(2)))
        .map(|s| s.at)
        .collect();
    let gaps: Vec<u128> = probes
        .windows(2)
        .map(|w| (w[1] - w[0]).as_millis())
        .collect();
    // 100 ms after going offline, then 200, 400, 800, 1600, 2000, 2000 … (each gap also
    // holds the probe's own timeout and at most one other poll).
    let expect = [200u128, 400, 800, 1600, 2000, 2000];
    assert!(gaps.len() >= expect.len(), "{gaps:?}");
    for (gap, want) in gaps.iter().zip(expect) {
        assert!(
            *gap >= want && *gap <= want + 20,
            "gaps {gaps:?}, expected {expect:?}"
        );
    }
    // Polls of the offline servo are probes only.
    assert!(
        !rig.kinds_since(from).contains(&TxKind::Poll(id(2))),
        "offline servo not polled"
    );
}

#[test]
fn a_servo_that_comes_back_is_reinitialised() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.set_goal(2, Goal::Position(MmCenti(500)));
    rig.run(ms(3000));
    assert_eq!(rig.servo(2).position, 500);
    rig.servo(2).present = false;
    rig.run(ms(500));
    assert_eq!(rig.health(2), Health::Offline);
    // Power-cycled while away: force OFF, goal 0.
    rig.servo(2).power_cycle();
    rig.servo(2).present = true;
    let from = rig.log.len();
    let ev_from = rig.events.len();
    rig.run(ms(2500));
    assert_eq!(rig.health(2), Health::Online);
    let events = &rig.events[ev_from..];
    assert!(events.contains(&BusEvent::ServoBack { id: id(2) }));
    assert!(events.contains(&BusEvent::ServoOnline { id: id(2) }));
    let kinds: Vec<TxKind> = rig
        .kinds_since(from)
        .into_iter()
        .filter(
            |k| matches!(k, TxKind::Probe(i) | TxKind::Init(i) | TxKind::Force(i) if *i == id(2)),
        )
        .collect();
    let probe = kinds
        .iter()
        .rposition(|k| *k == TxKind::Probe(id(2)))
        .unwrap();
    assert_eq!(
        &kinds[probe..],
        &[
            TxKind::Probe(id(2)),
            TxKind::Init(id(2)),
            TxKind::Force(id(2))
        ],
        "re-read then force ON again"
    );
    assert_eq!(rig.servo(2).force, 1);
    assert_eq!(rig.servo(2).goal, 500, "its goal is sent again");
}

#[test]
fn a_different_model_is_refused_and_never_commanded() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(2).model = 0x1234;
    rig.run(ms(100));
    assert_eq!(rig.health(2), Health::WrongModel);
    assert!(rig.events.contains(&BusEvent::WrongModel {
        id: id(2),
        found: 0x1234
    }));
    assert_eq!(
        BusEvent::WrongModel {
            id: id(2),
            found: 0x1234
        }
        .to_string(),
        "servo 2 is model 0x1234, not an LJ9DA41 (0x7510): not commanded"
    );
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(50)));
    rig.set_goal(2, Goal::Position(MmCenti(50)));
    rig.run(ms(500));
    assert!(rig.sent_since(from).iter().all(|s| s.tx.bytes[2] != 2));
    assert!(
        rig.commands_since(from)
            .iter()
            .all(|c| c.iter().all(|e| e.0 != 2))
    );
    assert_eq!(rig.servo(2).force, 0);
    assert_eq!(rig.servo(1).position, 50);
}

#[test]
fn a_temperature_error_is_reported_and_force_on_is_not_retried() {
    let mut rig = Rig::online_with_force_on(full_polls_only(&[1, 2]));
    rig.set_goal(1, Goal::Position(MmCenti(100)));
    rig.run(ms(50));
    // The servo overheats: error flag, force off, refuses force ON.
    rig.servo(1).flags = 0x80 | 0x20;
    rig.servo(1).force = 0;
    let ev_from = rig.events.len();
    // Learnt from the next reply of servo 1.
    rig.run(ms(20));
    let from = rig.log.len();
    for k in 0..100 {
        rig.set_goal(1, Goal::Position(MmCenti(200 + k)));
        rig.set_goal(2, Goal::Position(MmCenti(200 + k)));
        rig.run(ms(50));
    }
    let events = &rig.events[ev_from..];
    assert!(events.contains(&BusEvent::TemperatureError { id: id(1) }));
    assert!(events.contains(&BusEvent::TemperatureAlarm {
        id: id(1),
        on: true
    }));
    assert_eq!(rig.health(1), Health::TemperatureError);
    assert!(
        !rig.kinds_since(from).contains(&TxKind::Force(id(1))),
        "no force-ON attempts"
    );
    assert!(
        rig.commands_since(from)
            .iter()
            .all(|c| c.iter().all(|e| e.0 != 1))
    );
    assert!(
        rig.kinds_since(from).contains(&TxKind::Poll(id(1))),
        "still watched"
    );
    assert_eq!(rig.servo(2).position, 299, "the other servo keeps working");
    // Power-cycled and cool again: re-initialised, force ON, goal sent. The reply that shows
    // the restart already carries the new temperature, and the status has it at once.
    rig.servo(1).temperature = 31;
    rig.servo(1).power_cycle();
    let restart_seen = rig.events.len();
    while !rig.events[restart_seen..].contains(&BusEvent::ServoRestarted { id: id(1) }) {
        rig.run(ms(1));
    }
    let t = rig.m.status().servo(id(1)).unwrap().telemetry.unwrap();
    assert_eq!(
        t.present_temperature.0, 31,
        "the restart reply's reading is kept"
    );
    rig.run(ms(3000));
    assert!(
        rig.events[ev_from..].contains(&BusEvent::ServoRestarted { id: id(1) }),
        "{:?}",
        &rig.events[ev_from..]
    );
    assert_eq!(rig.health(1), Health::Online);
    assert_eq!(rig.servo(1).force, 1);
    assert_eq!(rig.servo(1).position, 299);
}

#[test]
fn a_refused_force_on_is_retried_with_backoff() {
    let mut rig = Rig::with_ids(&[1]);
    rig.run(ms(100));
    rig.servo(1).refuse_force = true;
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(10)));
    rig.run(ms(4000));
    let tries: Vec<Instant> = rig
        .sent_since(from)
        .iter()
        .filter(|s| s.tx.kind == TxKind::Force(id(1)))
        .map(|s| s.at)
        .collect();
    let gaps: Vec<u128> = tries
        .windows(2)
        .map(|w| (w[1] - w[0]).as_millis())
        .collect();
    assert_eq!(tries.len(), 4, "at 0, 0.5, 1.5 and 3.5 s: {gaps:?}");
    for (gap, want) in gaps.iter().zip([500u128, 1000, 2000]) {
        assert!(*gap >= want && *gap <= want + 10, "{gaps:?}");
    }
    assert_eq!(
        rig.events
            .iter()
            .filter(|e| **e == BusEvent::ForceRefused { id: id(1) })
            .count(),
        1
    );
}

#[test]
fn a_stall_is_reported_after_the_configured_time_at_high_current() {
    let mut rig = Rig::online_with_force(&[1]);
    // Far from the goal but drawing little current: a slow move, not a stall.
    rig.servo(1).stuck = true;
    rig.set_goal(1, Goal::Position(MmCenti(1000)));
    rig.run(ms(3000));
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
    // High current at the goal: working against a load, not a stall.
    rig.servo(1).stuck = false;
    rig.set_goal(1, Goal::Position(MmCenti(1200)));
    rig.servo(1).load = 300;
    rig.run(ms(3000));
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
    // A heavy load: high current and far from the goal, but closing in: not a stall.
    rig.servo(1).stuck = true;
    rig.set_goal(1, Goal::Position(MmCenti(-1000)));
    for step in 1..=20 {
        rig.servo(1).position = 1200 - step * 100;
        rig.run(ms(50));
    }
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
    rig.servo(1).position = -1000;
    rig.run(ms(50));
    // Rod blocked and high current: stalled once it lasts 500 ms, not before.
    rig.servo(1).stuck = true;
    rig.set_goal(1, Goal::Position(MmCenti(-500)));
    rig.run(ms(50));
    let started = rig.t;
    let ev_from = rig.events.len();
    rig.run(ms(440));
    assert!(!rig.events[ev_from..].contains(&BusEvent::Stalled {
        id: id(1),
        on: true
    }));
    rig.run(ms(100));
    assert!(
        rig.events[ev_from..].contains(&BusEvent::Stalled {
            id: id(1),
            on: true
        }),
        "stalled within {:?}",
        rig.t - started
    );
    assert!(rig.m.status().servo(id(1)).unwrap().stalled);
    // Freed: it follows, the stall clears.
    rig.servo(1).stuck = false;
    rig.servo(1).load = 20;
    rig.set_goal(1, Goal::Position(MmCenti(-400)));
    rig.run(ms(100));
    assert!(rig.events.contains(&BusEvent::Stalled {
        id: id(1),
        on: false
    }));
    assert!(!rig.m.status().servo(id(1)).unwrap().stalled);
}

#[test]
fn the_first_move_uses_a_soft_start_goal_time() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(1).position = -1000;
    rig.servo(1).stuck = true; // the rod lags, as a slow move would
    rig.servo(2).position = 500;
    rig.run(ms(100));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(1000)));
    rig.set_goal(2, Goal::Position(MmCenti(500)));
    rig.run(ms(100));
    let commands = rig.commands_since(from);
    // 20 mm at 10 mm/s = 2 s. Servo 2 is already at its goal: force ON was all it needed.
    assert_eq!(commands, vec![vec![(1, 1000, Some(200))]]);
    assert_eq!(rig.servo(2).force, 1);
    assert_eq!(rig.servo(1).goal_writes, vec![(1000, Some(200))]);
    // A goal that changes during the soft start is approached at the soft speed too …
    rig.run(ms(900));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(2000)));
    rig.run(ms(30));
    assert_eq!(
        rig.commands_since(from)[0][0],
        (1, 2000, Some(300)),
        "30 mm at 10 mm/s"
    );
    // … but does not make it last longer than the first move's 2 s: then full speed, and once
    // every goal-time register is zero the frames carry positions only.
    rig.run(ms(1100));
    rig.servo(1).stuck = false;
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(-2000)));
    rig.run(ms(30));
    rig.set_goal(1, Goal::Position(MmCenti(-1900)));
    rig.run(ms(30));
    let commands = rig.commands_since(from);
    assert_eq!(commands[0], vec![(1, -2000, Some(0)), (2, 500, Some(0))]);
    assert_eq!(commands[1], vec![(1, -1900, None), (2, 500, None)]);
}

#[test]
fn a_goal_sent_again_carries_the_time_left_of_its_move() {
    let mut cfg = config(&[1, 2]);
    cfg.servos[0].goal_time = Some(Ms10(100)); // 1 s
    cfg.soft_start_speed_mm_s = 0.0; // soft start off
    let mut rig = Rig::new(cfg);
    rig.run(ms(100));
    rig.set_goal(1, Goal::Position(MmCenti(0)));
    rig.set_goal(2, Goal::Position(MmCenti(0)));
    rig.run(ms(100));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(800)));
    rig.run(ms(300));
    rig.set_goal(2, Goal::Position(MmCenti(50)));
    rig.run(ms(10));
    let commands = rig.commands_since(from);
    assert_eq!(commands.len(), 2);
    assert_eq!(commands[0][0], (1, 800, Some(100)));
    let (vid, pos, time) = commands[1][0];
    assert_eq!((vid, pos), (1, 800));
    let left = time.unwrap();
    assert!((69..=71).contains(&left), "about 0.7 s left: {left}");
    assert_eq!(commands[1][1], (2, 50, Some(0)));
}

#[test]
fn long_packets_never_queue_more_than_one_frame_ahead_of_the_wire() {
    let mut rig = Rig::online_with_force(&[1]);
    // Nothing to poll (the only servo is offline): goals every 100 µs, far faster than frames.
    rig.servo(1).present = false;
    rig.run(ms(500));
    assert_eq!(rig.health(1), Health::Offline);
    let from = rig.log.len();
    let start = rig.t;
    let mut queued_ahead = Vec::new();
    for k in 0..2000 {
        rig.set_goal(1, Goal::Position(MmCenti(k % 500)));
        let before = rig.wire_free;
        let n = rig.log.len();
        rig.run(us(100));
        if rig.log[n..].iter().any(|s| s.tx.kind == TxKind::Command) {
            queued_ahead.push(before.saturating_duration_since(rig.log[n].at));
        }
    }
    let frame = wire(8 + 3);
    let frames = rig.commands_since(from).len() as u32;
    let elapsed = rig.t - start;
    assert!(
        queued_ahead.iter().all(|q| *q <= wire(8 + 5)),
        "at most one frame queued: {:?}",
        queued_ahead.iter().max()
    );
    assert!(
        frames <= elapsed.div_duration_f64(frame).ceil() as u32 + 1,
        "{frames}"
    );
    assert!(frames > 100, "the wire is kept busy: {frames}");
}

#[test]
fn goals_are_coalesced_and_counted() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    assert!(rig.m.reply_pending());
    let before = *rig.m.counters();
    let from = rig.log.len();
    for k in 1..=5 {
        rig.set_goal(1, Goal::Position(MmCenti(k * 10)));
    }
    rig.set_goal(2, Goal::Position(MmCenti(0))); // unchanged
    rig.set_goal(9, Goal::Position(MmCenti(0))); // not on this bus
    rig.run(ms(5));
    let commands = rig.commands_since(from);
    assert_eq!(commands.len(), 1);
    assert_eq!(commands[0], vec![(1, 50, None), (2, 0, None)]);
    let c = rig.m.counters();
    assert_eq!(c.goals_received - before.goals_received, 6);
    assert_eq!(c.goals_superseded - before.goals_superseded, 4);
    assert_eq!(c.goals_sent - before.goals_sent, 1);
    assert_eq!(c.goals_unchanged - before.goals_unchanged, 1);
    assert_eq!(c.goals_unknown_id - before.goals_unknown_id, 1);
}

#[test]
fn telemetry_polls_go_round_robin_and_are_published() {
    let mut rig = Rig::online_with_force_on(full_polls_only(&[1, 2, 3, 4]));
    rig.servo(3).position = 77;
    rig.servo(3).load = 42;
    rig.servo(3).temperature = 51;
    rig.servo(3).voltage = 1111;
    rig.servo(3).flags = 0x20 | 0x02;
    let from = rig.log.len();
    rig.run(ms(200));
    let polled: Vec<u8> = rig
        .sent_since(from)
        .iter()
        .filter_map(|s| match s.tx.kind {
            TxKind::Poll(i) => Some(i.get()),
            _ => None,
        })
        .collect();
    assert!(polled.len() >= 40, "{}", polled.len());
    for w in polled.windows(2) {
        assert_eq!(w[1], w[0] % 4 + 1, "{polled:?}");
    }
    let st = rig.m.status();
    let s3 = st.servo(id(3)).unwrap();
    let t = s3.telemetry.unwrap();
    assert_eq!(t.present_position, MmCenti(77));
    assert_eq!(t.present_load, Ma10(42));
    assert_eq!(t.present_temperature.0, 51);
    assert_eq!(t.present_voltage.0, 1111);
    assert_eq!(s3.flags, ReplyFlags(0x20), "bit 1 ignored");
    assert!(s3.age.unwrap() < ms(20));
    assert_eq!(s3.health, Health::Online);
    // With no replies for longer than stale_after (but fewer timeouts than needed for
    // offline), the servo is stale.
    let mut m = rig.m;
    let later = rig.t + ms(600);
    m.handle_timeout(later);
    assert_eq!(m.status().servo(id(3)).unwrap().health, Health::Stale);
    assert!(m.status().servo(id(3)).unwrap().age.unwrap() >= ms(600));
}

/// A driver's view (see [`Publisher`]) of the readings of servos `ids`, polled at 50 Hz, over
/// 2 s of goals at 50 Hz on two ports, with an event every 13 ms. Returns the readings the servos gave
/// (full, position-and-current, position-only) and the readings the snapshots showed.
fn readings_shown(ids: &[u8], guarded: bool) -> (u64, u64) {
    let mut cfg = config(ids);
    cfg.telemetry_min_interval = ms(20);
    let spacing = driver::publish_spacing(&cfg);
    let mut rig = Rig::online_with_force_on(cfg);
    rig.settle();
    rig.m.take_changed();
    rig.publisher = Some(Publisher {
        spacing,
        event_every: ms(13),
        guarded,
        taken_at: rig.t,
        next_event: rig.t + ms(13),
        snapshots: vec![rig.m.status_at(rig.t)],
        guards: 0,
        early_every: 3,
        looked_early: None,
    });
    let from = rig.log.len();
    let mut position = 0;
    for _ in 0..100 {
        position = (position + 37) % 2000;
        let goals: Vec<(u8, Goal)> = ids
            .iter()
            .map(|&n| (n, Goal::Position(MmCenti(position - 1000))))
            .collect();
        // Two messages a tick, as from an autopilot's two output ports: the second closes
        // the tick's gathering window, and its frame goes out at once.
        rig.message(&goals);
        rig.run(us(100));
        rig.message(&[]);
        rig.run(ms(20) - us(100));
    }
    rig.settle();
    let mut publisher = rig.publisher.take().unwrap();
    publisher.take(&mut rig.m, rig.t);
    assert!(
        !guarded || publisher.guards > 0,
        "no reply would have hidden a reading"
    );
    let given = rig
        .sent_since(from)
        .iter()
        .filter(|s| {
            matches!(
                s.tx.kind,
                TxKind::Poll(_) | TxKind::MotionPoll(_) | TxKind::PositionPoll(_)
            )
        })
        .count() as u64;
    let mut shown = 0;
    for &n in ids {
        let reading = |s: &BusStatus| {
            let servo = s.servo(id(n)).unwrap();
            (servo.telemetry_count, servo.position_at)
        };
        shown += publisher
            .snapshots
            .windows(2)
            .filter(|w| reading(&w[0]) != reading(&w[1]))
            .count() as u64;
    }
    (given, shown)
}

#[test]
fn a_reply_that_would_replace_an_unshown_reading_is_announced_before_it_is_read() {
    for ids in [&[1][..], &[1, 2]] {
        let (given, shown) = readings_shown(ids, true);
        assert!(given >= 90 * ids.len() as u64, "{ids:?}: {given} readings");
        assert_eq!(shown, given, "{ids:?}: readings shown of those given");
        // The same driver without the look before each reply misses readings: the test can
        // tell.
        let (given, shown) = readings_shown(ids, false);
        assert!(shown < given, "{ids:?}: {shown} of {given} shown unguarded");
    }
}

#[test]
fn hold_sends_nothing_and_off_and_brake_switch_force() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.set_goal(1, Goal::Position(MmCenti(300)));
    rig.run(ms(20));
    let from = rig.log.len();
    rig.set_goal(1, Goal::Hold);
    rig.set_goal(2, Goal::Position(MmCenti(40)));
    rig.run(ms(20));
    let commands = rig.commands_since(from);
    assert_eq!(commands, vec![vec![(2, 40, None)]], "held servo left out");
    assert_eq!(rig.servo(1).position, 300);
    assert_eq!(rig.servo(1).force, 1);
    rig.set_goal(1, Goal::Off);
    rig.run(ms(20));
    assert_eq!(rig.servo(1).force, 0);
    assert_eq!(rig.m.status().servo(id(1)).unwrap().force, ForceState::Off);
    rig.set_goal(1, Goal::Brake);
    rig.run(ms(20));
    assert_eq!(rig.servo(1).force, 2);
    // Back to a position: force ON again, with a soft start.
    let from = rig.log.len();
    rig.set_goal(1, Goal::Position(MmCenti(500)));
    rig.run(ms(30));
    assert!(rig.kinds_since(from).contains(&TxKind::Force(id(1))));
    assert_eq!(rig.servo(1).force, 1);
    let commands = rig.commands_since(from);
    assert_eq!(commands[0][0], (1, 500, Some(20)), "2 mm at 10 mm/s");
}

#[test]
fn goals_are_clamped_to_the_servo_limits() {
    let mut rig = Rig::with_ids(&[1]);
    rig.servo(1).plus = 1500;
    rig.run(ms(100));
    rig.set_goal(1, Goal::Position(MmCenti(i16::MAX)));
    rig.run(ms(3000));
    assert_eq!(rig.servo(1).goal_writes.last().unwrap().0, 1500);
    assert_eq!(
        rig.m.status().servo(id(1)).unwrap().goal,
        Some(MmCenti(1500))
    );
    // A goal given before the limits were read is clamped to them too.
    let mut rig = Rig::with_ids(&[1]);
    rig.servo(1).minus = -800;
    rig.set_goal(1, Goal::Position(MmCenti(-2400)));
    rig.run(ms(4000));
    assert_eq!(rig.servo(1).goal_writes.last().unwrap().0, -800);
    assert_eq!(rig.servo(1).position, -800);
}

#[test]
fn echoes_and_garbage_on_the_line_are_skipped() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.echo = true;
    rig.noise = vec![0x00, 0xFF, 0x07, 0xFD, 0x11, 0xFA, 0x12, 0x34];
    rig.run(ms(100));
    rig.set_goal(1, Goal::Position(MmCenti(100)));
    rig.set_goal(2, Goal::Position(MmCenti(-100)));
    rig.run(ms(3000));
    assert_eq!(rig.health(1), Health::Online);
    assert_eq!(rig.health(2), Health::Online);
    assert_eq!(rig.servo(1).position, 100);
    assert_eq!(rig.servo(2).position, -100);
    let c = rig.m.counters();
    assert_eq!(c.timeouts, 0);
    assert_eq!(
        c.echoes,
        rig.log.len() as u64,
        "every packet's echo skipped"
    );
    assert!(c.garbage_bytes >= 8 * (c.telemetry_replies), "{c:?}");
}

/// The bytes of servo `id`'s reply to a read of `length` registers from register 0 (the
/// identity read is 30), with its sum spoiled when `garbled`.
fn registers_reply(id: u8, length: usize, garbled: bool) -> Vec<u8> {
    let mut reply = ReturnPacket {
        id,
        flags: ReplyFlags(0),
        address: 0,
        data: vec![0; length],
    }
    .to_bytes();
    if garbled {
        let last = reply.len() - 1;
        reply[last] ^= 0x55;
    }
    reply
}

#[test]
fn a_corrupted_reply_is_counted_and_times_out() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let reply = registers_reply(1, 30, true);
    // Its first half leaves the request waiting; the whole garbled reply ends it at once:
    // the servo has stopped talking, so the bus is free as after a clean reply.
    let (a, b) = reply.split_at(reply.len() / 2);
    rig.m.handle_input(a, t0 + ms(3));
    assert!(rig.m.reply_pending());
    rig.m.handle_input(b, t0 + ms(4));
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().bad_sums, 1);
    assert_eq!(rig.m.counters().timeouts, 1);
    assert!(
        rig.m.poll_transmit(t0 + ms(4)).is_some(),
        "the next request"
    );
}

#[test]
fn a_reply_garbled_in_its_length_frees_the_bus_once_as_many_bytes_as_a_reply_came() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let mut reply = registers_reply(1, 30, false);
    // Length 30 read as 31: the decoder waits for one byte more than the servo sends.
    reply[5] = 31;
    let complete_at = rig.m.reply_complete_at().unwrap();
    let (a, b) = reply.split_at(reply.len() - 1);
    rig.m.handle_input(a, complete_at);
    assert!(
        rig.m.reply_pending(),
        "a byte of the reply is still to come"
    );
    rig.m.handle_input(b, complete_at);
    assert!(
        !rig.m.reply_pending(),
        "the servo has sent a whole reply's bytes"
    );
    assert_eq!(rig.m.counters().timeouts, 1);
    assert!(
        rig.m.poll_transmit(complete_at).is_some(),
        "the next request"
    );
}

#[test]
fn a_garbled_reply_from_another_servo_or_of_another_length_keeps_the_request_waiting() {
    let mut rig = Rig::with_ids(&[1, 2]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    rig.m
        .handle_input(&registers_reply(2, 30, true), t0 + ms(3));
    rig.m
        .handle_input(&registers_reply(1, 12, true), t0 + ms(3));
    assert!(rig.m.reply_pending(), "the awaited reply may still come");
    assert_eq!(rig.m.counters().bad_sums, 2);
    let deadline = rig.m.poll_timeout().unwrap();
    rig.m.handle_timeout(deadline);
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().timeouts, 1);
}

#[test]
fn a_reply_from_another_servo_is_not_taken_for_the_one_awaited() {
    let mut rig = Rig::with_ids(&[1]);
    let t0 = rig.t0;
    let _ = rig.m.poll_transmit(t0).unwrap();
    let mut other = FakeServo::new(7);
    let reply = other.handle(&[0xFA, 0xAF, 7, 0x03, 0, 0, 1, 0x05]).unwrap();
    rig.m.handle_input(&reply, t0 + ms(4));
    assert!(rig.m.reply_pending());
    assert_eq!(rig.m.counters().unexpected_replies, 1);
}

#[test]
fn a_servo_found_force_off_is_reinitialised() {
    let mut rig = Rig::online_with_force(&[1]);
    rig.set_goal(1, Goal::Position(MmCenti(700)));
    rig.run(ms(2000));
    // A quick power cycle: no reply missed, but force is off and the goal is gone.
    rig.servo(1).power_cycle();
    rig.run(ms(1500));
    assert!(rig.events.contains(&BusEvent::ServoRestarted { id: id(1) }));
    assert_eq!(rig.servo(1).force, 1);
    assert_eq!(rig.servo(1).goal, 700);
}

#[test]
fn a_lost_long_packet_is_noticed_by_the_read_back() {
    let mut rig = Rig::online_with_force(&[1]);
    rig.set_goal(1, Goal::Position(MmCenti(700)));
    rig.run(ms(2000));
    // The servo's goal register differs from what was sent (a frame lost to noise).
    rig.servo(1).goal = 123;
    rig.servo(1).position = 123;
    rig.run(ms(1500));
    assert_eq!(rig.servo(1).goal, 700);
}

#[test]
fn a_lost_port_drops_the_pending_reply_and_resends_goals_when_back() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.set_goal(1, Goal::Position(MmCenti(10)));
    rig.run(ms(10));
    assert!(rig.m.reply_pending());
    let t = rig.t;
    rig.m.handle_port_lost("read failed: EIO", t);
    rig.reply = None;
    assert!(!rig.m.reply_pending());
    assert!(!rig.m.status().port_open);
    assert_eq!(
        rig.m.poll_event(),
        Some(BusEvent::PortLost {
            reason: "read failed: EIO".into()
        })
    );
    let timeouts = rig.m.counters().timeouts;
    rig.t = t + ms(300);
    rig.m.handle_port_back(rig.t);
    rig.wire_free = rig.t;
    assert_eq!(rig.m.poll_event(), Some(BusEvent::PortBack));
    let from = rig.log.len();
    rig.run(ms(20));
    assert_eq!(
        rig.m.counters().timeouts,
        timeouts,
        "a lost port is not a timeout"
    );
    assert_eq!(rig.kinds_since(from)[0], TxKind::Command, "goals first");
    assert_eq!(
        rig.commands_since(from)[0],
        vec![(1, 10, None), (2, 0, None)]
    );
}

#[test]
fn shutdown_waits_for_the_pending_reply_then_switches_force_off() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    assert!(rig.m.reply_pending());
    rig.m.shutdown(ShutdownForce::Off);
    assert!(rig.m.poll_transmit(rig.t).is_none(), "reply still pending");
    assert!(!rig.m.is_shut_down());
    let from = rig.log.len();
    rig.run(ms(20));
    let kinds = rig.kinds_since(from);
    assert_eq!(
        kinds,
        vec![TxKind::Final(Some(id(1))), TxKind::Final(Some(id(2)))]
    );
    assert!(rig.m.is_shut_down());
    assert_eq!(rig.servo(1).force, 0);
    assert_eq!(rig.servo(2).force, 0);

    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    rig.set_goal(2, Goal::Position(MmCenti(-5)));
    rig.m.shutdown(ShutdownForce::AsIs);
    let from = rig.log.len();
    rig.run(ms(100));
    assert_eq!(
        rig.kinds_since(from),
        vec![TxKind::Command],
        "newest goals, then nothing"
    );
    assert_eq!(rig.servo(2).position, -5);
    assert_eq!(rig.servo(2).force, 1);

    let mut rig = Rig::online_with_force(&[1, 2]);
    rig.run(ms(1));
    rig.m.shutdown(ShutdownForce::Brake);
    let from = rig.log.len();
    rig.run(ms(20));
    assert_eq!(
        rig.kinds_since(from),
        vec![TxKind::Final(Some(id(1))), TxKind::Final(Some(id(2)))]
    );
    assert_eq!(rig.servo(1).force, 2);
    assert_eq!(rig.servo(2).force, 2);
}

#[test]
fn a_servo_missing_at_startup_is_reported_lost() {
    let mut rig = Rig::with_ids(&[1, 2]);
    rig.servo(2).present = false;
    rig.run(ms(500));
    assert_eq!(rig.health(2), Health::Offline);
    assert!(rig.events.contains(&BusEvent::ServoLost { id: id(2) }));
    assert_eq!(rig.health(1), Health::Online);
}

mod properties {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(200))]

        /// Whatever arrives, whenever: no panic, and never a transmit while a reply is pending.
        #[test]
        fn any_bytes_goals_and_times_never_panic(
            steps in proptest::collection::vec(
                (0u8..4, proptest::collection::vec(any::<u8>(), 0..40), 0u64..5000, any::<i16>(), 1u8..4),
                1..80,
            )
        ) {
            let mut m = BusMaster::new(config(&[1, 2, 3]), Instant::now());
            let mut t = Instant::now();
            for (what, bytes, dt, pos, n) in steps {
                t += us(dt);
                match what {
                    0 => m.handle_input(&bytes, t),
                    1 => m.set_goal(id(n), Goal::Position(MmCenti(pos)), t),
                    2 => m.handle_timeout(t),
                    _ => {
                        let pending = m.reply_pending();
                        if let Some(tx) = m.poll_transmit(t) {
                            prop_assert!(!pending);
                            prop_assert!(!tx.bytes.is_empty());
                        }
                    }
                }
                let _ = m.poll_timeout();
                while m.poll_event().is_some() {}
                let _ = m.status();
            }
        }
    }
}

#[test]
fn periodic_goals_find_the_bus_free_and_the_time_left_is_read() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let period = ms(20);
    let mut delays = Vec::new();
    let mut position_reads = Vec::new();
    let polls_before = rig.m.counters().polls;
    let motion_before = rig.m.counters().motion_polls;
    let t_start = rig.t;
    for k in 0..100i16 {
        let at = rig.t;
        let goals: Vec<_> = (1..=4u8)
            .map(|n| (n, Goal::Position(MmCenti(k * 10 + i16::from(n)))))
            .collect();
        rig.message(&goals);
        let from = rig.log.len();
        rig.run(period);
        let sent = rig.sent_since(from);
        let command = sent
            .iter()
            .find(|s| s.tx.kind == TxKind::Command)
            .expect("a frame");
        if k >= 10 {
            delays.push(command.at.duration_since(at));
            position_reads.extend(
                sent.iter()
                    .filter(|s| matches!(s.tx.kind, TxKind::PositionPoll(_)))
                    .map(|s| s.tx.bytes.clone()),
            );
        }
    }
    assert_eq!(rig.m.goal_period(), Some(period));
    let c = *rig.m.counters();
    let polls = c.polls - polls_before;
    let motion_polls = c.motion_polls - motion_before;
    let seconds = rig.t.duration_since(t_start).as_secs_f64();
    // Once the rhythm is known, every frame leaves the moment its goals arrive: no poll or
    // position read holds the bus then.
    assert!(delays.iter().all(|d| *d == Duration::ZERO), "{delays:?}");
    // ... position and current are still read at more than 60 Hz per servo, temperature and
    // voltage at more than 10 Hz.
    let motion_hz = (polls + motion_polls) as f64 / seconds / 4.0;
    let full_hz = polls as f64 / seconds / 4.0;
    assert!(
        motion_hz > 60.0,
        "position and current at {motion_hz:.1} Hz per servo"
    );
    assert!(
        full_hz > 10.0,
        "temperature and voltage at {full_hz:.1} Hz per servo"
    );
    // Reads of position and current are registers 42–49.
    let motion_reads: Vec<_> = rig
        .log
        .iter()
        .filter(|s| matches!(s.tx.kind, TxKind::MotionPoll(_)))
        .collect();
    assert!(!motion_reads.is_empty());
    for s in motion_reads {
        assert_eq!(
            &s.tx.bytes[3..7],
            &[0x0F, 0x2A, 0x08, 0x00],
            "{:02X?}",
            s.tx.bytes
        );
    }
    // The time left before a goal, too short for any other poll, carries a read of registers
    // 42–43 alone when it fits (see the position-read test for the period where it does).
    for bytes in &position_reads {
        assert_eq!(&bytes[3..7], &[0x0F, 0x2A, 0x02, 0x00], "{bytes:02X?}");
    }
}

#[test]
fn a_goal_waits_for_the_reply_in_flight_and_nothing_else() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    // Irregular arrivals (no rhythm to keep the bus free for): some goals find a poll in
    // flight, some an idle bus.
    let gaps = [
        7_300u64, 11_100, 2_900, 15_700, 5_300, 9_900, 3_700, 13_300, 6_100,
    ];
    let mut behind_a_reply = 0;
    for (k, gap) in gaps.iter().cycle().take(180).enumerate() {
        rig.run(us(*gap));
        let set_at = rig.t;
        let reply_end = if rig.m.reply_pending() {
            Some(
                rig.reply
                    .as_ref()
                    .map(|(end, _)| *end)
                    .expect("a reply on its way"),
            )
        } else {
            None
        };
        let from = rig.log.len();
        rig.set_goal(1 + (k % 4) as u8, Goal::Position(MmCenti(k as i16 * 7 + 1)));
        rig.run(ms(4));
        let frame_at = rig
            .sent_since(from)
            .iter()
            .find(|s| s.tx.kind == TxKind::Command)
            .expect("a frame")
            .at;
        // The frame is written the instant the reply in flight is complete, or at once.
        match reply_end {
            Some(end) => {
                behind_a_reply += 1;
                assert_eq!(
                    frame_at,
                    end,
                    "goal {k}: written {:?} after the reply",
                    frame_at - end
                );
            }
            None => assert_eq!(frame_at, set_at, "goal {k} on an idle bus"),
        }
    }
    assert!(
        behind_a_reply >= 60,
        "{behind_a_reply} of 180 goals behind a reply"
    );
}

#[test]
fn a_reply_is_awaited_from_its_earliest_end_and_counted_down_byte_by_byte() {
    let (mut rig, tx) = Rig::at_a_full_poll();
    // A telemetry poll: 8 bytes out, 26 back.
    let request_end = rig.t + rig.wire(tx.bytes.len());
    let complete_at = rig.m.reply_complete_at().expect("a reply is awaited");
    let deadline = rig.m.poll_timeout().expect("the reply's deadline");
    // No earlier than the request and the whole reply on the wire; the deadline adds only the
    // turnaround allowance.
    assert!(complete_at >= request_end + rig.wire(26), "{complete_at:?}");
    assert_eq!(deadline - complete_at, rig.m.config().turnaround);
    assert_eq!(rig.m.bytes_awaited(), Some(26));

    let reply = rig.servo(1).handle(&tx.bytes).expect("the servo answers");
    // An echo of the request is not part of the reply.
    rig.m.handle_input(&tx.bytes, request_end);
    assert_eq!(rig.m.bytes_awaited(), Some(26));
    rig.m.handle_input(&reply[..20], complete_at);
    assert_eq!(rig.m.bytes_awaited(), Some(6));
    rig.m.handle_input(&reply[20..25], complete_at);
    assert_eq!(rig.m.bytes_awaited(), Some(1));
    rig.m.handle_input(&reply[25..], complete_at);
    assert_eq!(rig.m.bytes_awaited(), None);
    assert_eq!(rig.m.reply_complete_at(), None);
    assert_eq!(rig.m.counters().timeouts, 0);
}

#[test]
fn a_position_read_replaces_only_the_position_of_the_latest_telemetry() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    for n in 1..=4 {
        rig.servo(n).stuck = true;
    }
    // Every period the rods stand somewhere else and draw another current: a value read tells
    // the period it was read in.
    let mut periods = Vec::new();
    let position_read = |rig: &Rig, from: usize| {
        rig.sent_since(from)
            .iter()
            .any(|s| matches!(s.tx.kind, TxKind::PositionPoll(_)))
    };
    'stream: for k in 0..80i16 {
        periods.push(rig.t);
        for n in 1..=4u8 {
            rig.servo(n).position = 2000 + k;
            rig.servo(n).load = 100 + k as u16;
        }
        let goals: Vec<_> = (1..=4u8)
            .map(|n| (n, Goal::Position(MmCenti(k * 10 + i16::from(n)))))
            .collect();
        rig.message(&goals);
        // At 55.6 Hz the time left before each goal often fits a position read, not more.
        if k < 40 {
            rig.run(ms(18));
            continue;
        }
        // Then stop at the first position read, once its reply is in.
        let (from, end) = (rig.log.len(), rig.t + ms(18));
        while rig.t < end {
            rig.run(us(50));
            if position_read(&rig, from) {
                break 'stream;
            }
        }
    }
    rig.settle();
    let period_of = |t: Instant| periods.iter().rposition(|p| *p <= t).unwrap() as i16;
    // The fake servo answers with the values of the instant a request is written.
    let last_request = |n: u8, kinds: &[fn(ServoId) -> TxKind]| {
        rig.log
            .iter()
            .rev()
            .find(|s| kinds.iter().any(|k| s.tx.kind == k(id(n))))
            .map(|s| s.at)
            .expect("a request")
    };
    let status = rig.m.status();
    let mut position_only = 0;
    for s in &status.servos {
        let n = s.id.get();
        let t = s.telemetry.expect("telemetry");
        let full = last_request(n, &[TxKind::Poll]);
        let load = last_request(n, &[TxKind::Poll, TxKind::MotionPoll]);
        let position = last_request(n, &[TxKind::Poll, TxKind::MotionPoll, TxKind::PositionPoll]);
        // Temperature and voltage of the last full poll; the load of the last full poll or
        // read of position and current; the position of the last read of any kind.
        assert!(s.telemetry_at.unwrap() > full);
        assert_eq!(t.present_load.0, 100 + period_of(load) as u16, "servo {n}");
        assert_eq!(
            t.present_position.0,
            2000 + period_of(position),
            "servo {n}"
        );
        if position > load {
            position_only += 1;
        }
    }
    assert!(
        position_only > 0,
        "no servo was last read by a position read"
    );
}

impl Rig {
    /// Write what is due; when a request went out, take its reply (when it is whole on the
    /// wire, and its bytes) and move to the bus master's look at it. Otherwise move to the next
    /// deadline and return `None`.
    fn request_and_look(&mut self) -> Option<(Instant, Vec<u8>)> {
        self.transmit();
        if !self.m.reply_pending() {
            self.t = self.m.poll_timeout().expect("a request is due").max(self.t);
            self.m.handle_timeout(self.t);
            return None;
        }
        let reply = self.reply.take().expect("the servo answers");
        self.t = self
            .t
            .max(self.m.reply_look_at().expect("a reply is awaited"));
        Some(reply)
    }
}

/// Run `requests` requests like the bus thread does: look when [`BusMaster::reply_look_at`]
/// says, and when part of the reply is missing, wait until it is all in (the tty's read
/// threshold) and read it then. The n-th reply is late by `lateness(n)` besides the return
/// delay. Returns, per answered request, the bytes missing at the first look and how long the
/// reply had been whole when it was read.
fn run_like_the_bus_thread(
    rig: &mut Rig,
    requests: usize,
    mut lateness: impl FnMut(usize) -> Duration,
) -> Vec<(usize, Duration)> {
    let byte = rig.wire(1);
    let mut out = Vec::new();
    let mut sent = 0;
    while sent < requests {
        rig.latency = lateness(sent);
        let Some((at, bytes)) = rig.request_and_look() else {
            continue;
        };
        sent += 1;
        let missing = at
            .saturating_duration_since(rig.t)
            .as_nanos()
            .div_ceil(byte.as_nanos());
        let missing = (missing as usize).min(bytes.len());
        rig.m.handle_input(&bytes[..bytes.len() - missing], rig.t);
        rig.m.handle_timeout(rig.t);
        let read_at = if missing > 0 {
            assert_eq!(rig.m.bytes_awaited(), Some(missing));
            rig.t = at;
            rig.m.handle_input(&bytes[bytes.len() - missing..], at);
            at
        } else {
            rig.t
        };
        assert!(!rig.m.reply_pending());
        out.push((missing, read_at.duration_since(at)));
        rig.drain_events();
    }
    out
}

#[test]
fn the_first_look_at_a_reply_learns_to_come_about_a_byte_before_its_end() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let byte = rig.wire(1);
    // Replies 200–380 µs later than the return delay says (the servo's processing, the
    // adapter), in an order with no pattern.
    let lateness = |n: usize| us(200 + (n as u64 * 7919 % 10) * 20);
    run_like_the_bus_thread(&mut rig, 200, lateness);
    let looks = run_like_the_bus_thread(&mut rig, 1000, |n| lateness(n + 200));
    let learned = rig.m.reply_lateness();
    assert!(
        learned >= us(200) && learned <= us(380) + byte,
        "learned {learned:?}"
    );
    // The bus is left idle after a reply (found whole at a look that came late) for less
    // than a byte time on average ...
    let idle: Duration = looks.iter().map(|(_, idle)| *idle).sum();
    assert!(
        idle / looks.len() as u32 <= byte,
        "mean idle {:?}",
        idle / looks.len() as u32
    );
    // ... and a look that comes early finds only the last few bytes missing (each one a
    // wake-up of the thread waiting for them, in the kernel).
    let missing: usize = looks.iter().map(|(m, _)| m).sum();
    assert!(
        missing <= looks.len() * 3,
        "{missing} bytes missing at {} first looks",
        looks.len()
    );
}

#[test]
fn without_a_learned_lateness_a_late_servo_costs_a_wait_for_many_bytes() {
    // The baseline of the test above: at the start nothing is learned, and the first looks of
    // replies 380 µs late come when more than four bytes are still on their way.
    let mut rig = Rig::online_with_force(&[1]);
    rig.settle();
    assert_eq!(rig.m.reply_lateness(), Duration::ZERO);
    let first = run_like_the_bus_thread(&mut rig, 1, |_| us(380));
    assert!(first[0].0 >= 4, "{first:?}");
    let later = run_like_the_bus_thread(&mut rig, 100, |_| us(380));
    assert!(
        later[60..].iter().all(|(m, _)| *m <= 2),
        "{:?}",
        &later[60..]
    );
}

#[test]
fn one_very_late_reply_does_not_delay_the_looks_at_the_next_ones() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    let byte = rig.wire(1);
    run_like_the_bus_thread(&mut rig, 100, |_| us(300));
    let learned = rig.m.reply_lateness();
    // One reply 1.5 ms late (the servo or the adapter stalled), then the usual again.
    let looks = run_like_the_bus_thread(&mut rig, 20, |n| if n == 0 { us(1800) } else { us(300) });
    assert!(rig.m.reply_lateness() <= learned + byte / 4);
    assert!(
        looks[1..].iter().all(|(_, idle)| *idle <= byte),
        "{looks:?}"
    );
}

/// Run `requests` requests through a port that passes each reply on `passed_on` after it is
/// whole on the wire (a tty's bytes go through the kernel's worker). A look before the reply is
/// whole finds part of it and waits for the rest; a look after that, before the port has it,
/// is held by the read until the bytes are in and then finds the reply whole, and the bus
/// master is told that the port held less than the reply at the look only if `tell`. Returns
/// how many looks came before the port had the reply.
fn looks_before_the_port_has_the_reply(
    rig: &mut Rig,
    requests: usize,
    passed_on: Duration,
    tell: bool,
) -> usize {
    let mut early = 0;
    let mut sent = 0;
    while sent < requests {
        let Some((at, bytes)) = rig.request_and_look() else {
            continue;
        };
        sent += 1;
        let in_port = at + passed_on;
        if rig.t < in_port {
            early += 1;
            if rig.t < at {
                // Part of it is in: the driver waits for the rest.
                rig.m.handle_timeout(rig.t);
            } else if tell {
                // As the driver does: the port's count is asked for at the first look only.
                let missing = rig.m.bytes_awaited_at_first_look();
                assert_eq!(missing, Some(bytes.len()), "the first look at this reply");
                rig.m.note_reply_incomplete();
                assert_eq!(rig.m.bytes_awaited_at_first_look(), None, "looked at");
            }
            rig.t = in_port;
        }
        rig.m.handle_input(&bytes, rig.t);
        assert!(!rig.m.reply_pending());
        rig.drain_events();
    }
    early
}

#[test]
fn a_look_held_until_the_kernel_passes_the_reply_on_teaches_a_later_look() {
    let passed_on = us(150);
    let early = |tell: bool| {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        looks_before_the_port_has_the_reply(&mut rig, 200, passed_on, tell);
        looks_before_the_port_has_the_reply(&mut rig, 400, passed_on, tell)
    };
    // Untold, the looks learn to come when the reply is whole on the wire, and nearly every
    // one is then held by the read (a second wake-up of the bus thread, in the kernel).
    let untold = early(false);
    assert!(untold >= 300, "{untold} of 400 looks came early");
    // Told, three looks in four come once the port has the reply.
    let told = early(true);
    assert!(told <= 140, "{told} of 400 looks came early");
}

/// Goals at `period` with the given arrival offsets (µs, may be negative) per tick, each tick
/// in `messages` messages `spacing` apart, each message carrying a new goal for `servos`.
/// Returns, per goal message after the first 20 ticks, how long its frame waited, and what the
/// bus carried when the message came.
fn run_autopilot(
    rig: &mut Rig,
    ticks: usize,
    offset_us: impl Fn(usize, usize) -> i64,
    messages: &[(&[u8], Duration)],
) -> Vec<(Duration, Option<TxKind>)> {
    let period = ms(20);
    let t0 = rig.t + ms(5);
    let mut arrivals: Vec<(Instant, usize, usize)> = Vec::new();
    for k in 0..ticks {
        for (m, (_, spacing)) in messages.iter().enumerate() {
            let base = t0 + period * k as u32 + *spacing;
            let off = offset_us(k, m);
            let at = if off >= 0 {
                base + us(off as u64)
            } else {
                base - us(off.unsigned_abs())
            };
            arrivals.push((at, k, m));
        }
    }
    arrivals.sort_by_key(|a| a.0);
    let mut messages_at = Vec::new();
    for (n, (at, k, m)) in arrivals.into_iter().enumerate() {
        let value = (n % 2000) as i16 + 1;
        rig.run(at.saturating_duration_since(rig.t));
        let in_flight = rig
            .m
            .reply_pending()
            .then(|| rig.log.last().map(|s| s.tx.kind))
            .flatten();
        let goals: Vec<_> = messages[m]
            .0
            .iter()
            .map(|&n| (n, Goal::Position(MmCenti(value))))
            .collect();
        rig.message(&goals);
        messages_at.push((rig.t, rig.log.len(), k, in_flight));
    }
    rig.run(period);
    // Each message's wait: until the first frame handed out at or after it.
    messages_at
        .into_iter()
        .filter(|(_, _, k, _)| *k >= 20)
        .map(|(at, from, _, in_flight)| {
            let frame = rig
                .sent_since(from)
                .iter()
                .find(|s| s.tx.kind == TxKind::Command)
                .expect("a frame after every message")
                .at;
            (frame - at, in_flight)
        })
        .collect()
}

const PORT0: &[u8] = &[1, 2, 3];
const PORT1: &[u8] = &[4];

#[test]
fn no_goal_of_a_tick_waits_behind_a_poll_started_after_the_tick_began() {
    // Ports 0 and 1 of each tick, 0.1 ms apart; a command 1.5 ms after port 0 in every tenth.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let frames_before = rig.m.counters().command_frames;
    let waits = run_autopilot(&mut rig, 120, |_, _| 0, &[(PORT0, us(0)), (PORT1, us(100))]);
    let behind_poll: Vec<_> = waits.iter().filter(|w| w.1.is_some()).collect();
    assert!(behind_poll.is_empty(), "{behind_poll:?}");
    // One tick, one frame: port 0's goals wait the 0.1 ms for port 1's (known from the ticks
    // before), which leave with them at once, instead of 1.5 ms behind a frame of their own.
    let frames = rig.m.counters().command_frames - frames_before;
    assert!(frames <= 121, "{frames} frames for 120 ticks");
    for pair in waits.chunks(2) {
        assert_eq!(pair[0].0, us(100), "port 0: {pair:?}");
        assert_eq!(pair[1].0, Duration::ZERO, "port 1: {pair:?}");
    }
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let waits = run_autopilot(
        &mut rig,
        120,
        |_, _| 0,
        &[(PORT0, us(0)), (PORT1, us(100)), (&[2], us(1600))],
    );
    assert!(waits.iter().all(|w| w.1.is_none()), "{waits:?}");
}

/// No goal message found a poll in flight when it came.
fn assert_no_goal_behind_a_poll(waits: &[(Duration, Option<TxKind>)]) {
    let behind: Vec<_> = waits.iter().filter(|w| w.1.is_some()).collect();
    assert!(
        behind.is_empty(),
        "{} of {}: {behind:?}",
        behind.len(),
        waits.len()
    );
}

/// A deterministic uniform offset in ±`range_us` for tick `k`.
fn uniform(k: usize, salt: usize, range_us: i64) -> i64 {
    let mut x = (k as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (salt as u64) << 32;
    x ^= x >> 29;
    x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x ^= x >> 32;
    (x % (2 * range_us as u64 + 1)) as i64 - range_us
}

#[test]
fn a_jittery_autopilot_finds_the_bus_free_and_telemetry_keeps_its_rates() {
    // The tick's send time jitters by ±1 ms; both ports go out together.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let c0 = *rig.m.counters();
    let t0 = rig.t;
    let waits = run_autopilot(
        &mut rig,
        150,
        |k, _| uniform(k, 0, 1000),
        &[(PORT0, us(0)), (PORT1, us(100))],
    );
    assert_no_goal_behind_a_poll(&waits);
    let c = rig.m.counters();
    let seconds = (rig.t - t0).as_secs_f64();
    let motion_hz =
        ((c.polls + c.motion_polls) - (c0.polls + c0.motion_polls)) as f64 / seconds / 4.0;
    let full_hz = (c.polls - c0.polls) as f64 / seconds / 4.0;
    assert!(motion_hz >= 60.0, "{motion_hz:.1} Hz");
    assert!(full_hz >= 10.0, "{full_hz:.1} Hz");

    // One message in twenty is 3–8 ms late: the bus is still free when it comes.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let late = |k: usize, m: usize| {
        if uniform(k, m + 7, 1000).rem_euclid(20) == 0 {
            3000 + uniform(k, m + 11, 2500) + 2500
        } else {
            0
        }
    };
    let waits = run_autopilot(&mut rig, 200, late, &[(PORT0, us(0)), (PORT1, us(100))]);
    let behind_full: Vec<_> = waits
        .iter()
        .filter(|w| matches!(w.1, Some(TxKind::Poll(_))))
        .collect();
    assert!(behind_full.is_empty(), "{behind_full:?}");
    assert_no_goal_behind_a_poll(&waits);
}

#[test]
fn a_write_later_than_planned_moves_the_reply_deadline_and_nothing_talks_over_the_reply() {
    let (mut rig, tx) = Rig::at_a_full_poll();
    let planned = rig.t;
    // The writing thread was preempted for 3 ms before the write.
    let written = planned + ms(3);
    rig.m.handle_written(written);
    // The reply comes after the request really left, then late by 1.5 ms of turnaround.
    let reply = rig.servo(1).handle(&tx.bytes).expect("an answer");
    let reply_end = written + wire(tx.bytes.len()) + ms(1) + us(500) + wire(reply.len());
    // Until the reply is in, nothing is written and no timeout is counted, whatever the time.
    let mut t = planned;
    while t < reply_end {
        rig.m.handle_timeout(t);
        assert!(
            rig.m.poll_transmit(t).is_none(),
            "talked over the reply at {:?}",
            t - planned
        );
        t += us(100);
    }
    assert_eq!(rig.m.counters().timeouts, 0);
    rig.m.handle_input(&reply, reply_end);
    assert!(!rig.m.reply_pending());
    assert_eq!(rig.m.counters().timeouts, 0);
    assert_eq!(rig.m.counters().telemetry_replies, rig.m.counters().polls);
}

#[test]
fn a_servo_whose_replies_are_garbled_is_degraded_never_lost() {
    let mut rig = Rig::online_with_force(&[1, 2]);
    // Every reply of servo 1 has a bad sum: counted as missed, but the servo is answering.
    rig.servo(1).garble = true;
    let c0 = *rig.m.counters();
    let from = rig.events.len();
    rig.run(ms(1000));
    let c = rig.m.counters();
    assert!(
        c.bad_sums - c0.bad_sums >= 20,
        "{} bad sums",
        c.bad_sums - c0.bad_sums
    );
    assert!(!rig.events[from..].contains(&BusEvent::ServoLost { id: id(1) }));
    assert_ne!(rig.health(1), Health::Offline);
    assert!(rig.m.status().servo(id(1)).unwrap().timeouts >= 20);
}

#[test]
fn a_temperature_flag_seen_in_a_short_reply_makes_the_next_poll_read_the_temperature() {
    let mut rig = Rig::online_with_force(&[1]);
    rig.run(ms(100));
    rig.servo(1).temperature = 77;
    rig.servo(1).flags = 0x20;
    // Run until the alarm is out (it waits for the temperature read).
    let from = rig.log.len();
    while !rig.events.contains(&BusEvent::TemperatureAlarm {
        id: id(1),
        on: true,
    }) {
        rig.run(ms(1));
    }
    let reads: Vec<TxKind> = rig
        .kinds_since(from)
        .into_iter()
        .filter(|k| *k != TxKind::Command)
        .collect();
    // The first read saw the flag; a short one is followed by a full one at once.
    if reads.first() == Some(&TxKind::MotionPoll(id(1))) {
        assert_eq!(reads.get(1), Some(&TxKind::Poll(id(1))), "{reads:?}");
    }
    assert_eq!(
        rig.m
            .status()
            .servo(id(1))
            .unwrap()
            .telemetry
            .unwrap()
            .present_temperature
            .0,
        77
    );
}

#[test]
fn goals_faster_than_the_gathering_do_not_starve_telemetry() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let c0 = *rig.m.counters();
    // A goal every 300 µs for a second: no quiet spell ever opens a gathering window after
    // the first.
    for k in 0..3333i16 {
        rig.set_goal(1 + (k % 4) as u8, Goal::Position(MmCenti(k % 2000)));
        rig.run(us(300));
    }
    let c = rig.m.counters();
    let reads = (c.polls + c.motion_polls) - (c0.polls + c0.motion_polls);
    assert!(reads >= 200, "{reads} telemetry reads in a second");
}

#[test]
fn garbled_replies_at_10_20_30_and_60_percent_never_make_a_servo_lost_and_silence_does() {
    for share in [0.1, 0.2, 0.3, 0.6] {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        rig.servo(1).garble_share = share;
        let from = rig.events.len();
        let c0 = *rig.m.counters();
        let answered0 = rig.m.status().servo(id(1)).unwrap().answered;
        for k in 0..250i16 {
            for n in 1..=4u8 {
                rig.set_goal(n, Goal::Position(MmCenti(k * 4 + i16::from(n))));
            }
            rig.run(ms(20));
        }
        let lost: Vec<_> = rig.events[from..]
            .iter()
            .filter(|e| matches!(e, BusEvent::ServoLost { .. }))
            .collect();
        assert!(lost.is_empty(), "{share}: {lost:?}");
        assert_eq!(rig.health(1), Health::Online, "{share}");
        // Every garbled reply is counted, so the share of bad replies can be told.
        let bad = rig.m.counters().bad_sums - c0.bad_sums;
        let answered = rig.m.status().servo(id(1)).unwrap().answered - answered0;
        let seen = bad as f64 / (bad + answered) as f64;
        assert!((seen - share).abs() < 0.05, "{share}: {seen:.3} seen");
        // The servo keeps following its goals.
        assert_eq!(rig.servo(1).goal, 249 * 4 + 1, "{share}");
    }
    // Unplugged: silent, and lost once silent for `offline_after_silence`.
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    rig.servo(1).present = false;
    let from = rig.events.len();
    rig.run(ms(500));
    assert!(
        rig.events[from..].contains(&BusEvent::ServoLost { id: id(1) }),
        "{:?}",
        &rig.events[from..]
    );
}

/// The reply-quality events of servo 1 (and any other servo's, which there must be none of).
fn quality_events(events: &[BusEvent]) -> Vec<BusEvent> {
    events
        .iter()
        .filter(|e| {
            matches!(
                e,
                BusEvent::RepliesDegraded { .. }
                    | BusEvent::RepliesOk { .. }
                    | BusEvent::ServoLost { .. }
                    | BusEvent::ServoBack { .. }
            )
        })
        .cloned()
        .collect()
}

/// Goals to every servo of a four-servo rig every 20 ms, for `d`.
fn run_with_goals(rig: &mut Rig, d: Duration) {
    let steps = d.as_millis() / 20;
    for k in 0..steps {
        for n in 1..=4u8 {
            rig.set_goal(
                n,
                Goal::Position(MmCenti((k % 500) as i16 * 4 + i16::from(n))),
            );
        }
        rig.run(ms(20));
    }
}

#[test]
fn garbled_replies_at_10_percent_leave_a_servo_online_and_at_20_30_60_percent_degrade_it_once() {
    for (share, degrades) in [(0.1, false), (0.2, true), (0.3, true), (0.6, true)] {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        rig.servo(1).garble_share = share;
        let from = rig.events.len();
        // Ten windows of garbled replies.
        run_with_goals(&mut rig, super::quality::WINDOW * 10);
        let events = quality_events(&rig.events[from..]);
        let status = rig.m.status();
        let degraded = status.servo(id(1)).unwrap().degraded;
        if !degrades {
            assert_eq!(events, vec![], "{share}");
            assert_eq!(degraded, None, "{share}");
        } else {
            // One "degraded", with the share in it; never "ok" while it lasts, never "lost".
            let [BusEvent::RepliesDegraded { id: servo, percent }] = events[..] else {
                panic!("{share}: {events:?}");
            };
            assert_eq!(servo, id(1), "{share}");
            let expected = (share * 100.0) as i32;
            assert!(
                (i32::from(percent) - expected).abs() <= 3,
                "{share}: {percent}%"
            );
            assert!(
                degraded.is_some_and(|p| (i32::from(p) - expected).abs() <= 3),
                "{share}: {degraded:?}"
            );
        }
        assert_eq!(rig.health(1), Health::Online, "{share}");
        for n in 2..=4 {
            assert_eq!(
                status.servo(id(n)).unwrap().degraded,
                None,
                "{share}: servo {n}"
            );
        }
        // The line is clean again: one "replies ok" (if it was degraded) within two windows.
        rig.servo(1).garble_share = 0.0;
        let from = rig.events.len();
        run_with_goals(&mut rig, super::quality::WINDOW * 2);
        let expected = if degrades {
            vec![BusEvent::RepliesOk { id: id(1) }]
        } else {
            vec![]
        };
        assert_eq!(quality_events(&rig.events[from..]), expected, "{share}");
        assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
    }
}

#[test]
fn a_share_of_bad_replies_wandering_between_8_and_30_percent_gives_one_degraded() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    let from = rig.events.len();
    // The share changes every 3 s, out of step with the windows, on both sides of 15 %.
    for share in [0.3, 0.12, 0.2, 0.08, 0.25, 0.12]
        .into_iter()
        .cycle()
        .take(20)
    {
        rig.servo(1).garble_share = share;
        run_with_goals(&mut rig, ms(3000));
    }
    let events = quality_events(&rig.events[from..]);
    assert!(
        matches!(events[..], [BusEvent::RepliesDegraded { .. }]),
        "{events:?}"
    );
    assert!(rig.m.status().servo(id(1)).unwrap().degraded.is_some());
}

#[test]
fn an_unplugged_servo_is_lost_not_degraded_and_back_when_plugged_in() {
    // A loose connector: 8 % of the replies garbled (not degraded), then none at all.
    // Unplugged at every 100 ms of a window: the silence before "lost" (300 ms, 15 % of a
    // window) falls at a window's end in some of these runs, and never counts as bad replies.
    for offset in (0..super::quality::WINDOW.as_millis() as u64).step_by(100) {
        let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
        rig.servo(1).garble_share = 0.08;
        run_with_goals(&mut rig, super::quality::WINDOW * 2 + ms(offset));
        let from = rig.events.len();
        rig.servo(1).present = false;
        run_with_goals(&mut rig, super::quality::WINDOW * 3);
        assert_eq!(
            quality_events(&rig.events[from..]),
            vec![BusEvent::ServoLost { id: id(1) }],
            "unplugged {offset} ms into a window"
        );
        assert_eq!(rig.health(1), Health::Offline);
        assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
        let from = rig.events.len();
        rig.servo(1).present = true;
        rig.servo(1).garble_share = 0.0;
        run_with_goals(&mut rig, super::quality::WINDOW * 3);
        assert_eq!(
            quality_events(&rig.events[from..]),
            vec![BusEvent::ServoBack { id: id(1) }],
            "plugged in {offset} ms into a window"
        );
        assert_eq!(rig.health(1), Health::Online);
        assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
    }
}

#[test]
fn a_degraded_servo_unplugged_is_lost_and_comes_back_without_its_old_state() {
    let mut rig = Rig::online_with_force(&[1, 2, 3, 4]);
    rig.servo(1).garble_share = 0.3;
    run_with_goals(&mut rig, super::quality::WINDOW * 3);
    assert!(rig.m.status().servo(id(1)).unwrap().degraded.is_some());
    let from = rig.events.len();
    rig.servo(1).present = false;
    run_with_goals(&mut rig, super::quality::WINDOW * 2);
    // "Lost" says more than a share of bad replies: the state goes without a word.
    assert_eq!(
        quality_events(&rig.events[from..]),
        vec![BusEvent::ServoLost { id: id(1) }]
    );
    assert_eq!(rig.m.status().servo(id(1)).unwrap().degraded, None);
    rig.servo(1).garble_share = 0.0;
    rig.servo(1).present = true;
    let from = rig.events.len();
    run_with_goals(&mut rig, super::quality::WINDOW * 3);
    assert_eq!(
        quality_events(&rig.events[from..]),
        vec![BusEvent::ServoBack { id: id(1) }]
    );
}

/// A rig whose polls between two full ones are position-and-current reads for a second: a
/// flag that changes is seen first in a reply without the temperature.
fn rig_with_rare_full_reads() -> Rig {
    let mut cfg = config(&[1]);
    cfg.full_telemetry_interval = ms(1000);
    let mut rig = Rig::online_with_force_on(cfg);
    rig.run(ms(100));
    rig
}

/// The first poll after `from` in the log, and whether it is a short one.
fn first_read_is_short(rig: &Rig, from: usize) -> bool {
    rig.kinds_since(from)
        .into_iter()
        .find(|k| *k != TxKind::Command)
        .is_some_and(|k| k != TxKind::Poll(id(1)))
}

#[test]
fn a_temperature_event_from_a_short_reply_waits_for_the_temperature_read_after_it() {
    for alarm in [true, false] {
        let mut rig = rig_with_rare_full_reads();
        let read_before = rig.m.status().servo(id(1)).unwrap().telemetry_at.unwrap();
        // Heating up from 30 °C, unread: the flag arrives in a position-and-current reply.
        rig.servo(1).temperature = 86;
        rig.servo(1).flags = if alarm { 0x20 } else { 0x80 };
        let (from_log, from_events) = (rig.log.len(), rig.events.len());
        let wanted = |e: &BusEvent| {
            matches!(
                e,
                BusEvent::TemperatureAlarm { on: true, .. } | BusEvent::TemperatureError { .. }
            )
        };
        let mut seen = None;
        for _ in 0..200 {
            rig.run(us(100));
            if rig.events[from_events..].iter().any(wanted) {
                // What a reader of the status finds when the event comes out.
                seen = Some(rig.m.status());
                break;
            }
        }
        let status = seen.expect("the temperature event");
        assert!(
            first_read_is_short(&rig, from_log),
            "{:?}",
            rig.kinds_since(from_log)
        );
        let servo = status.servo(id(1)).unwrap();
        let t = servo.telemetry.unwrap();
        assert_eq!(t.present_temperature.0, 86, "alarm {alarm}");
        let read_at = servo.telemetry_at.unwrap();
        assert!(read_at > read_before);
        assert!(
            rig.t.saturating_duration_since(read_at) < ms(1),
            "alarm {alarm}: read {:?} before the event",
            rig.t.saturating_duration_since(read_at)
        );
    }
}

#[test]
fn a_temperature_event_whose_read_never_comes_goes_out_after_200_ms() {
    let mut rig = rig_with_rare_full_reads();
    rig.servo(1).temperature = 86;
    rig.servo(1).flags = 0x20;
    let (from, from_log) = (rig.events.len(), rig.log.len());
    // The flag arrives in a short reply, then the servo falls silent: no full read.
    let mut flagged_at = None;
    for _ in 0..200 {
        rig.run(us(100));
        if rig
            .m
            .status()
            .servo(id(1))
            .unwrap()
            .flags
            .temperature_alarm()
        {
            flagged_at = Some(rig.t);
            rig.servo(1).present = false;
            // A reply already on its way is lost too.
            rig.reply = None;
            break;
        }
    }
    let flagged_at = flagged_at.expect("the flag seen");
    assert!(
        first_read_is_short(&rig, from_log),
        "{:?}",
        rig.kinds_since(from_log)
    );
    let alarm = BusEvent::TemperatureAlarm {
        id: id(1),
        on: true,
    };
    rig.run(super::servo::TEMPERATURE_WAIT - ms(5));
    assert!(!rig.events[from..].contains(&alarm), "out before its wait");
    rig.run(ms(10));
    assert!(
        rig.events[from..].contains(&alarm),
        "{:?}",
        &rig.events[from..]
    );
    // Out before the servo is lost, with the reading from before the flag.
    let status = rig.m.status();
    let servo = status.servo(id(1)).unwrap();
    assert_eq!(servo.telemetry.unwrap().present_temperature.0, 30);
    assert!(servo.age.unwrap() > rig.t.saturating_duration_since(flagged_at));
}

mod ticks;

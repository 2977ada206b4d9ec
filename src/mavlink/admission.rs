//! Which received messages reach the bridge's loop. The loop runs at real-time priority (in
//! `run`), above every ordinary program on the companion computer, so what it is handed must
//! not be anyone's to choose: the links' readers pass on only
//!
//! - the kinds of message the core acts on ([`BridgeCore::handles`]): an autopilot's other
//!   streams (attitude, GPS, …) and a ground station's joystick stay on the readers' thread;
//! - from any sender but the autopilot, at most [`BUDGET_PER_SECOND`] a second on average
//!   (bursts of [`BURST`]), per sender: its network address on a `udpin` link, the link itself
//!   on the others (one peer at the other end), whatever system and component ids it claims, so
//!   that more ids buy nothing. Enough for a ground station's parameter download or a burst of
//!   commands; a stranger's flood of valid frames costs the loop that much and no more.
//!
//! [`TRACKED`] senders have a budget each. A newcomer takes, with a full budget, a free place,
//! else the place of a sender silent for [`FORGET_AFTER`], else the place of the sender that
//! last went over its budget (at most [`TAKEN_PER_SECOND`] such places a second, so that ever
//! new addresses buy a flood little). The sender it replaces, and any sender without a place
//! that goes over budget, draws from the flooders' one budget until it has kept within it for
//! [`FORGET_AFTER`]. Other newcomers share one budget, which a flooder therefore leaves at its
//! first drop: a newcomer is never pushed in with a flood.
//!
//! The autopilot's messages on its own link always pass: once it is known (its HEARTBEAT, or
//! the mapping's ids) by its ids, and while it is not, the HEARTBEAT that identifies it (an
//! autopilot's, of the mapping's autopilot component) whoever sends it.
//!
//! The newest value wins: a PARAM_SET over its sender's budget is not dropped but held, the
//! newest one of each parameter (an older one held is replaced, and one that passes drops the
//! older one held), and handed on as its sender's budget refills ([`Admission::release`]).
//! What is dropped or coalesced is said within a second of the first ([`Admission::news`],
//! every [`SAY_EVERY`] while it goes on, once more when it ends) and in all at exit.
//!
//! Without signing, anyone may claim the autopilot's ids: the budget guards the loop's time
//! against a flood of valid frames only where signing keeps strangers' frames out.
//!
//! Sans-IO: handed the messages, their senders, the autopilot's identity and the time.

use super::core::{AUTOPILOT_LINK, BridgeCore, LinkId};
use mavlink::MavHeader;
use mavlink::dialects::common::{MavAutopilot, MavMessage, MavType, PARAM_SET_DATA};
use std::collections::VecDeque;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

/// Messages a second a sender other than the autopilot may pass to the loop, on average.
pub const BUDGET_PER_SECOND: f64 = 100.0;
/// As many at once, after a quiet spell.
pub const BURST: f64 = 200.0;
/// Senders with a budget of their own on one link.
pub const TRACKED: usize = 16;
/// A sender silent this long gives its budget's place to a new sender (its budget would be
/// full again anyway); a flooder within its budget this long has a place again.
pub const FORGET_AFTER: Duration = Duration::from_secs(10);
/// How often, at most, the messages dropped or coalesced are said while it goes on.
pub const SAY_EVERY: Duration = Duration::from_secs(10);
/// A spell of drops ends this long after the last one (its closing line is then said).
pub const SPELL_ENDS_AFTER: Duration = Duration::from_secs(2);
/// Places taken from a flooder by a newcomer, a second on average (bursts of
/// [`TAKEN_BURST`]): each gives the newcomer a full budget, so ever new addresses buy a flood
/// at most this many budgets a second.
pub const TAKEN_PER_SECOND: f64 = 1.0;
/// As many at once.
pub const TAKEN_BURST: f64 = 4.0;
/// Flooders remembered at most (the oldest is forgotten first: it is a newcomer again).
pub const FLOODERS: usize = 64;
/// PARAM_SETs held at most (one per parameter and target: the bridge has far fewer
/// parameters); beyond, the oldest held is dropped.
pub const HELD: usize = 256;

/// Who sent a message, for its budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sender {
    /// A datagram's source on a `udpin` link.
    Address(SocketAddr),
    /// The one peer of a stream link (`serial`, `tcpout`, …) or of `udpout`.
    Link,
}

impl Sender {
    /// The sender of a datagram from `from`, or of a stream link's frame (`None`).
    pub fn of(from: Option<SocketAddr>) -> Sender {
        from.map_or(Sender::Link, Sender::Address)
    }
}

/// What becomes of a received message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// To the loop.
    Pass,
    /// Of a kind the core does not act on: dropped, as the core would.
    NotHandled,
    /// Its sender spent its budget: dropped and counted.
    OverBudget,
    /// A PARAM_SET over its sender's budget: held, the newest of its parameter, until the
    /// budget refills ([`Admission::release`]).
    Held,
}

/// A token bucket.
#[derive(Clone, Copy, Debug)]
struct Bucket {
    tokens: f64,
    at: Instant,
    per_second: f64,
    burst: f64,
}

impl Bucket {
    /// A sender's budget, full.
    fn full(now: Instant) -> Bucket {
        Bucket::new(BUDGET_PER_SECOND, BURST, now)
    }

    fn new(per_second: f64, burst: f64, now: Instant) -> Bucket {
        Bucket {
            tokens: burst,
            at: now,
            per_second,
            burst,
        }
    }

    fn refill(&mut self, now: Instant) {
        let refill = now.saturating_duration_since(self.at).as_secs_f64() * self.per_second;
        self.tokens = (self.tokens + refill).min(self.burst);
        self.at = self.at.max(now);
    }

    fn take(&mut self, now: Instant) -> bool {
        self.refill(now);
        if self.tokens >= 1.0 {
            self.tokens -= 1.0;
            true
        } else {
            false
        }
    }
}

/// A tracked sender's place.
#[derive(Clone, Copy, Debug)]
struct Place {
    sender: Sender,
    bucket: Bucket,
    /// When it last went over its budget.
    dropped_at: Option<Instant>,
}

/// Where a sender's budget is.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Budget {
    Own(usize),
    Flooders,
    Shared,
}

/// A PARAM_SET held for want of budget.
#[derive(Clone, Debug)]
struct Held {
    sender: Sender,
    header: MavHeader,
    message: MavMessage,
}

/// What was dropped and coalesced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    /// Messages dropped for want of budget (PARAM_SETs held beyond [`HELD`] included).
    pub dropped: u64,
    /// PARAM_SETs replaced by a newer one of the same parameter while held.
    pub coalesced: u64,
}

impl Counts {
    fn since(self, before: Counts) -> Counts {
        Counts {
            dropped: self.dropped - before.dropped,
            coalesced: self.coalesced - before.coalesced,
        }
    }

    fn any(self) -> bool {
        self.dropped + self.coalesced > 0
    }
}

impl std::fmt::Display for Counts {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (self.dropped, self.coalesced) {
            (0, 0) => write!(f, "nothing dropped"),
            (d, 0) => write!(f, "{d} messages dropped"),
            (0, c) => write!(
                f,
                "{c} PARAM_SETs coalesced (a newer value of the parameter won)"
            ),
            (d, c) => write!(
                f,
                "{d} messages dropped and {c} PARAM_SETs coalesced (a newer value of the \
                 parameter won)"
            ),
        }
    }
}

/// A spell of drops: when it began, when its latest drop was, what was last said.
#[derive(Clone, Copy, Debug)]
struct Spell {
    began: Instant,
    latest: Instant,
    said_at: Option<Instant>,
    said: Counts,
    at_start: Counts,
}

/// The admission of one link's messages.
#[derive(Debug)]
pub struct Admission {
    link: LinkId,
    /// The autopilot's component in the mapping: its identifying HEARTBEAT's.
    autopilot_component: u8,
    places: Vec<Place>,
    /// Senders that went over budget without a place of their own, and when they last did.
    flooders: VecDeque<(Sender, Instant)>,
    flooders_bucket: Bucket,
    shared: Bucket,
    /// Places a newcomer may take from a flooder.
    taken: Bucket,
    held: VecDeque<Held>,
    counts: Counts,
    spell: Option<Spell>,
}

impl Admission {
    /// The admission of `link`'s messages; `autopilot_component`: the mapping's autopilot
    /// component id.
    pub fn new(link: LinkId, autopilot_component: u8, now: Instant) -> Admission {
        Admission {
            link,
            autopilot_component,
            places: Vec::new(),
            flooders: VecDeque::new(),
            flooders_bucket: Bucket::full(now),
            shared: Bucket::full(now),
            taken: Bucket::new(TAKEN_PER_SECOND, TAKEN_BURST, now),
            held: VecDeque::new(),
            counts: Counts::default(),
            spell: None,
        }
    }

    /// Judge a message from `header`, sent by `sender`, on this link at `now`; `autopilot`:
    /// the autopilot's system and component, once known.
    pub fn judge(
        &mut self,
        header: &MavHeader,
        message: &MavMessage,
        sender: Sender,
        autopilot: Option<(u8, u8)>,
        now: Instant,
    ) -> Verdict {
        if !BridgeCore::handles(message) {
            return Verdict::NotHandled;
        }
        let Ok(system) = u8::try_from(header.system_id) else {
            return Verdict::NotHandled;
        };
        let from = (system, header.component_id);
        if self.link == AUTOPILOT_LINK {
            let identifying = |hb: &mavlink::dialects::common::HEARTBEAT_DATA| {
                hb.autopilot != MavAutopilot::MAV_AUTOPILOT_INVALID
                    && hb.mavtype != MavType::MAV_TYPE_GCS
                    && header.component_id == self.autopilot_component
            };
            match (autopilot, message) {
                (Some(known), _) if known == from => return Verdict::Pass,
                (None, MavMessage::HEARTBEAT(hb)) if identifying(hb) => return Verdict::Pass,
                _ => {}
            }
        }
        let budget = self.budget_of(sender, now);
        if self.bucket(budget).take(now) {
            if let MavMessage::PARAM_SET(set) = message {
                // The newest value wins: an older one held for the parameter is dropped.
                if let Some(i) = self.held_index(set) {
                    self.held.remove(i);
                    self.count(now, |c| c.coalesced += 1);
                }
            }
            return Verdict::Pass;
        }
        self.went_over(sender, budget, now);
        let MavMessage::PARAM_SET(set) = message else {
            self.count(now, |c| c.dropped += 1);
            return Verdict::OverBudget;
        };
        let held = Held {
            sender,
            header: *header,
            message: message.clone(),
        };
        match self.held_index(set) {
            Some(i) => {
                self.held[i] = held;
                self.count(now, |c| c.coalesced += 1);
            }
            None => {
                if self.held.len() >= HELD {
                    self.held.pop_front();
                    self.count(now, |c| c.dropped += 1);
                }
                self.held.push_back(held);
            }
        }
        Verdict::Held
    }

    /// The held PARAM_SETs whose senders' budgets have refilled by `now`, oldest first: to the
    /// loop.
    pub fn release(&mut self, now: Instant) -> Vec<(MavHeader, MavMessage)> {
        let mut released = Vec::new();
        let mut kept = VecDeque::with_capacity(self.held.len());
        while let Some(held) = self.held.pop_front() {
            let budget = self.budget_of(held.sender, now);
            if self.bucket(budget).take(now) {
                released.push((held.header, held.message));
            } else {
                kept.push_back(held);
            }
        }
        self.held = kept;
        released
    }

    /// When [`Admission::release`] or [`Admission::news`] may next have something to do
    /// (`None`: nothing held and no spell of drops).
    pub fn next_due(&self, now: Instant) -> Option<Instant> {
        let release =
            (!self.held.is_empty()).then(|| now + Duration::from_secs_f64(1.0 / BUDGET_PER_SECOND));
        let news = self.spell.map(|spell| match spell.said_at {
            None => now,
            Some(at) => (at + SAY_EVERY).min(spell.latest + SPELL_ENDS_AFTER),
        });
        release.into_iter().chain(news).min()
    }

    /// What was dropped and coalesced since the start.
    pub fn counts(&self) -> Counts {
        self.counts
    }

    /// Messages dropped for want of budget since the start.
    pub fn dropped(&self) -> u64 {
        self.counts.dropped
    }

    /// What to say of drops at `now`: the first line of a spell at once, then at most every
    /// [`SAY_EVERY`] what came since, and a closing line [`SPELL_ENDS_AFTER`] after the last.
    pub fn news(&mut self, now: Instant) -> Option<String> {
        let mut spell = self.spell?;
        let link = self.link;
        let since_said = self.counts.since(spell.said);
        if now.saturating_duration_since(spell.latest) >= SPELL_ENDS_AFTER && self.held.is_empty() {
            self.spell = None;
            let whole = self.counts.since(spell.at_start);
            let more = if since_said.any() && spell.said_at.is_some() {
                format!(" ({since_said} since the last line)")
            } else {
                String::new()
            };
            return Some(format!(
                "MAVLink link {link}: senders over their budget of {BUDGET_PER_SECOND} messages a \
                 second for {:.1} s, now within it: {whole}{more}; since the start: {}",
                spell
                    .latest
                    .saturating_duration_since(spell.began)
                    .as_secs_f64(),
                self.counts
            ));
        }
        let due = spell
            .said_at
            .is_none_or(|at| now.saturating_duration_since(at) >= SAY_EVERY);
        if !due || !since_said.any() {
            return None;
        }
        spell.said_at = Some(now);
        spell.said = self.counts;
        self.spell = Some(spell);
        Some(format!(
            "MAVLink link {link}: senders over their budget of {BUDGET_PER_SECOND} messages a \
             second: {since_said}; since the start: {} (a PARAM_SET over budget waits for it, \
             the newest of each parameter)",
            self.counts
        ))
    }

    /// What to say at exit, if anything was ever dropped or coalesced.
    pub fn summary(&self) -> Option<String> {
        self.counts.any().then(|| {
            format!(
                "MAVLink link {}: since the start, {} over their senders' budgets",
                self.link, self.counts
            )
        })
    }

    fn count(&mut self, now: Instant, what: impl FnOnce(&mut Counts)) {
        let before = self.counts;
        what(&mut self.counts);
        let spell = self.spell.get_or_insert(Spell {
            began: now,
            latest: now,
            said_at: None,
            said: before,
            at_start: before,
        });
        spell.latest = now;
    }

    fn held_index(&self, set: &PARAM_SET_DATA) -> Option<usize> {
        self.held.iter().position(|h| {
            matches!(&h.message, MavMessage::PARAM_SET(old)
                if old.param_id == set.param_id
                    && old.target_system == set.target_system
                    && old.target_component == set.target_component)
        })
    }

    fn bucket(&mut self, budget: Budget) -> &mut Bucket {
        match budget {
            Budget::Own(i) => &mut self.places[i].bucket,
            Budget::Flooders => &mut self.flooders_bucket,
            Budget::Shared => &mut self.shared,
        }
    }

    /// The budget `sender` draws from at `now`, giving it a place if it is new (see the module
    /// docs).
    fn budget_of(&mut self, sender: Sender, now: Instant) -> Budget {
        if let Some(i) = self.places.iter().position(|p| p.sender == sender) {
            return Budget::Own(i);
        }
        if let Some(i) = self.flooders.iter().position(|(s, _)| *s == sender) {
            if now.saturating_duration_since(self.flooders[i].1) < FORGET_AFTER {
                return Budget::Flooders;
            }
            self.flooders.remove(i);
        }
        let fresh = Place {
            sender,
            bucket: Bucket::full(now),
            dropped_at: None,
        };
        if self.places.len() < TRACKED {
            self.places.push(fresh);
            return Budget::Own(self.places.len() - 1);
        }
        let silent = (0..self.places.len())
            .min_by_key(|&i| self.places[i].bucket.at)
            .filter(|&i| now.saturating_duration_since(self.places[i].bucket.at) >= FORGET_AFTER);
        if let Some(i) = silent {
            self.places[i] = fresh;
            return Budget::Own(i);
        }
        let flooding = (0..self.places.len())
            .filter_map(|i| Some((i, self.places[i].dropped_at?)))
            .filter(|(_, at)| now.saturating_duration_since(*at) < FORGET_AFTER)
            .max_by_key(|(_, at)| *at);
        if let Some((i, at)) = flooding
            && self.taken.take(now)
        {
            self.remember_flooder(self.places[i].sender, at);
            self.places[i] = fresh;
            return Budget::Own(i);
        }
        Budget::Shared
    }

    fn went_over(&mut self, sender: Sender, budget: Budget, now: Instant) {
        match budget {
            Budget::Own(i) => self.places[i].dropped_at = Some(now),
            Budget::Flooders => {
                if let Some(f) = self.flooders.iter_mut().find(|(s, _)| *s == sender) {
                    f.1 = now;
                }
            }
            Budget::Shared => self.remember_flooder(sender, now),
        }
    }

    fn remember_flooder(&mut self, sender: Sender, at: Instant) {
        if self.flooders.len() >= FLOODERS {
            self.flooders.pop_front();
        }
        self.flooders.push_back((sender, at));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{
        ATTITUDE_DATA, HEARTBEAT_DATA, MavParamType, SERVO_OUTPUT_RAW_DATA,
    };

    const AUTOPILOT_COMPONENT: u8 = 1;

    fn header(system: u8, component: u8) -> MavHeader {
        MavHeader {
            system_id: u32::from(system),
            component_id: component,
            sequence: 0,
        }
    }

    fn heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA::default())
    }

    fn autopilot_heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            mavtype: MavType::MAV_TYPE_FIXED_WING,
            ..HEARTBEAT_DATA::default()
        })
    }

    fn param_set(name: &str, value: f32) -> MavMessage {
        MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: value,
            target_system: 1,
            target_component: 140,
            param_id: name.into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        })
    }

    fn address(port: u16) -> Sender {
        Sender::Address(SocketAddr::from(([10, 0, 0, 2], port)))
    }

    fn admission(link: LinkId, now: Instant) -> Admission {
        Admission::new(link, AUTOPILOT_COMPONENT, now)
    }

    /// Of `n` HEARTBEATs from `from` sent by `sender` at `at`, how many pass.
    fn passed(a: &mut Admission, sender: Sender, from: (u8, u8), at: Instant, n: usize) -> usize {
        (0..n)
            .filter(|_| {
                a.judge(
                    &header(from.0, from.1),
                    &heartbeat(),
                    sender,
                    Some((1, 1)),
                    at,
                ) == Verdict::Pass
            })
            .count()
    }

    #[test]
    fn a_kind_the_core_ignores_stays_with_the_reader() {
        let now = Instant::now();
        let mut a = admission(AUTOPILOT_LINK, now);
        let attitude = MavMessage::ATTITUDE(ATTITUDE_DATA::default());
        assert_eq!(
            a.judge(&header(1, 1), &attitude, Sender::Link, Some((1, 1)), now),
            Verdict::NotHandled
        );
        let outputs = MavMessage::SERVO_OUTPUT_RAW(SERVO_OUTPUT_RAW_DATA::default());
        assert_eq!(
            a.judge(&header(1, 1), &outputs, Sender::Link, Some((1, 1)), now),
            Verdict::Pass
        );
    }

    #[test]
    fn a_stranger_gets_its_budget_and_the_autopilot_all_it_sends() {
        let t0 = Instant::now();
        let mut a = admission(AUTOPILOT_LINK, t0);
        let (stranger, autopilot) = (address(9000), address(14550));
        // A flood at one instant: the burst, then nothing.
        assert_eq!(passed(&mut a, stranger, (9, 1), t0, 1000), BURST as usize);
        assert_eq!(a.dropped(), 1000 - BURST as u64);
        // The autopilot, meanwhile: everything.
        assert_eq!(passed(&mut a, autopilot, (1, 1), t0, 1000), 1000);
        // A second later, a second's budget.
        let t1 = t0 + Duration::from_secs(1);
        assert_eq!(
            passed(&mut a, stranger, (9, 1), t1, 1000),
            BUDGET_PER_SECOND as usize
        );
        // On another link the autopilot's ids are anyone's.
        let mut gcs = admission(AUTOPILOT_LINK + 1, t0);
        assert_eq!(
            passed(&mut gcs, autopilot, (1, 1), t0, 1000),
            BURST as usize
        );
    }

    /// One address claiming ever new system and component ids has one budget.
    #[test]
    fn more_ids_from_one_sender_buy_nothing() {
        let t0 = Instant::now();
        let mut a = admission(AUTOPILOT_LINK, t0);
        let flooder = address(9000);
        let passed = (0..1000u32)
            .filter(|i| {
                let from = header(100 + (i % 100) as u8, (i / 100) as u8);
                a.judge(&from, &heartbeat(), flooder, Some((1, 1)), t0) == Verdict::Pass
            })
            .count();
        assert_eq!(passed, BURST as usize);
    }

    /// A flooder keeps every place warm from addresses of its own; a ground station that comes
    /// later still gets a whole budget.
    #[test]
    fn a_newcomer_is_never_pushed_in_with_a_flood() {
        let t0 = Instant::now();
        let mut a = admission(AUTOPILOT_LINK, t0);
        for second in 0..3 {
            let at = t0 + Duration::from_secs(second);
            for port in 0..TRACKED as u16 + 4 {
                passed(&mut a, address(9000 + port), (9, 1), at, 500);
            }
        }
        let late = t0 + Duration::from_secs(3);
        assert_eq!(
            passed(&mut a, address(14551), (255, 190), late, 150),
            150,
            "the ground station's burst"
        );
        assert_eq!(
            passed(&mut a, address(14552), (254, 190), late, 150),
            150,
            "a second ground station's, a budget of its own too"
        );
        // The flooder it replaced shares the flooders' one budget with those without a place:
        // the flood has a second's budget in each place left to it, and that one.
        let flooders: usize = (0..TRACKED as u16 + 4)
            .map(|port| passed(&mut a, address(9000 + port), (9, 1), late, 500))
            .sum();
        let bound = (TRACKED - 1) as f64 * BUDGET_PER_SECOND + BURST;
        assert!(
            flooders as f64 <= bound,
            "{flooders} of the flood passed at once (bound {bound})"
        );
        assert_eq!(
            passed(&mut a, address(14551), (255, 190), late, 50),
            50,
            "the ground station keeps its place"
        );
    }

    /// Ever new addresses buy a flood at most a few budgets a second.
    #[test]
    fn ever_new_addresses_buy_little() {
        let t0 = Instant::now();
        let mut a = admission(AUTOPILOT_LINK, t0);
        let passed_in = |a: &mut Admission, from_port: u16, at: Instant| -> usize {
            (0..2000u16)
                .map(|k| passed(a, address(from_port.wrapping_add(k)), (9, 1), at, 5))
                .sum()
        };
        // The first spell fills the places; the next seconds are what new addresses buy.
        passed_in(&mut a, 0, t0);
        let mut most = 0;
        for second in 1..5u16 {
            let at = t0 + Duration::from_secs(u64::from(second));
            most = most.max(passed_in(&mut a, second * 2000, at));
        }
        // Each place's second of budget, the shared and flooders' budgets, and the places taken.
        let bound = (TRACKED as f64 + 2.0) * BUDGET_PER_SECOND + TAKEN_BURST * BURST;
        assert!(
            (most as f64) <= bound,
            "{most} messages passed in a second from new addresses (bound {bound})"
        );
    }

    #[test]
    fn a_sender_silent_for_long_gives_its_place_to_a_new_one() {
        let t0 = Instant::now();
        let mut a = admission(1, t0);
        for port in 0..TRACKED as u16 {
            a.judge(&header(1, 1), &heartbeat(), address(port), None, t0);
        }
        let late = t0 + FORGET_AFTER;
        // Senders 1.. speak again; sender 0 stays silent and gives its place.
        for port in 1..TRACKED as u16 {
            a.judge(&header(1, 1), &heartbeat(), address(port), None, late);
        }
        assert_eq!(
            passed(&mut a, address(7000), (7, 1), late, 1000),
            BURST as usize,
            "a budget of its own"
        );
        // Every place is taken by a sender heard within FORGET_AFTER: the next newcomer takes
        // the place of the one that went over its budget, with a budget of its own.
        assert_eq!(
            passed(&mut a, address(8000), (8, 1), late, 1000),
            BURST as usize,
            "7000 went over its budget: its place is 8000's now"
        );
        assert_eq!(
            passed(&mut a, address(7000), (7, 1), late, 1000),
            BURST as usize,
            "7000 draws from the flooders' budget (full: nobody spent it)"
        );
        assert_eq!(passed(&mut a, address(7000), (7, 1), late, 1000), 0);
    }

    /// While the autopilot is unknown, its identifying HEARTBEAT passes whatever else its
    /// sender spent.
    #[test]
    fn the_autopilots_heartbeat_is_never_throttled_while_it_is_unknown() {
        let t0 = Instant::now();
        let mut a = admission(AUTOPILOT_LINK, t0);
        let sitl = address(5760);
        // A ground station's messages from the same address (MAVProxy's --out) spend its budget.
        passed(&mut a, sitl, (255, 190), t0, 1000);
        assert_eq!(
            a.judge(
                &header(1, AUTOPILOT_COMPONENT),
                &autopilot_heartbeat(),
                sitl,
                None,
                t0
            ),
            Verdict::Pass
        );
        // A GCS's HEARTBEAT, or another component's, is a stranger's.
        assert_eq!(
            a.judge(&header(1, 2), &autopilot_heartbeat(), sitl, None, t0),
            Verdict::OverBudget
        );
        let gcs = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            mavtype: MavType::MAV_TYPE_GCS,
            ..HEARTBEAT_DATA::default()
        });
        assert_eq!(
            a.judge(&header(1, AUTOPILOT_COMPONENT), &gcs, sitl, None, t0),
            Verdict::OverBudget
        );
    }

    /// A burst of PARAM_SETs of one parameter: the newest is held and handed on when the
    /// budget allows; the ones between are coalesced, and counted.
    #[test]
    fn the_newest_param_set_of_a_burst_is_handed_on() {
        let t0 = Instant::now();
        let mut a = admission(1, t0);
        let gcs = address(14551);
        let mut passed = 0;
        for k in 0..=1000 {
            match a.judge(
                &header(255, 190),
                &param_set("LJ_S1_TRIM", k as f32),
                gcs,
                None,
                t0,
            ) {
                Verdict::Pass => passed += 1,
                Verdict::Held => {}
                other => panic!("{other:?}"),
            }
        }
        assert_eq!(passed, BURST as usize);
        assert_eq!(a.release(t0), vec![], "no budget yet");
        let later = t0 + Duration::from_millis(20);
        let released = a.release(later);
        assert_eq!(released.len(), 1);
        assert!(
            matches!(&released[0].1, MavMessage::PARAM_SET(p) if p.param_value == 1000.0),
            "{released:?}"
        );
        assert_eq!(
            a.counts(),
            Counts {
                dropped: 0,
                coalesced: 1000 - BURST as u64
            }
        );
        assert!(a.next_due(later).is_some(), "the spell is still to be said");
    }

    /// A value that passes drops an older one held for the same parameter: never an older one
    /// after it.
    #[test]
    fn a_param_set_that_passes_drops_the_older_one_held() {
        let t0 = Instant::now();
        let mut a = admission(1, t0);
        let (flooder, other) = (address(14551), address(14552));
        for _ in 0..BURST as usize {
            a.judge(
                &header(255, 190),
                &param_set("LJ_S1_TRIM", 1.0),
                flooder,
                None,
                t0,
            );
        }
        assert_eq!(
            a.judge(
                &header(255, 190),
                &param_set("LJ_S1_TRIM", 2.0),
                flooder,
                None,
                t0
            ),
            Verdict::Held
        );
        assert_eq!(
            a.judge(
                &header(254, 190),
                &param_set("LJ_S1_TRIM", 3.0),
                other,
                None,
                t0
            ),
            Verdict::Pass
        );
        assert_eq!(a.release(t0 + Duration::from_secs(1)), vec![]);
        assert_eq!(a.counts().coalesced, 1);
    }

    /// The first drop of a spell is said at once, then at most every ten seconds, and a
    /// closing line when the spell ends; the total at exit.
    #[test]
    fn drops_are_said_at_once_then_every_ten_seconds_and_when_they_end() {
        let t0 = Instant::now();
        let mut a = admission(1, t0);
        let s = address(9000);
        passed(&mut a, s, (9, 1), t0, 250);
        assert_eq!(a.next_due(t0), Some(t0), "said at once");
        let said = a.news(t0).expect("50 dropped");
        assert!(
            said.contains("link 1") && said.contains(": 50 messages dropped"),
            "{said}"
        );
        let t5 = t0 + Duration::from_secs(1);
        passed(&mut a, s, (9, 1), t5, 110);
        assert_eq!(a.news(t5), None, "within ten seconds of the last line");
        assert_eq!(
            a.news(t5 + Duration::from_secs(1)),
            None,
            "the spell goes on"
        );
        let end = t5 + SPELL_ENDS_AFTER;
        assert_eq!(a.next_due(t5), Some(end));
        let closing = a.news(end).expect("the spell ended");
        assert!(
            closing.contains("now within it: 60 messages dropped")
                && closing.contains("(10 messages dropped"),
            "{closing}"
        );
        assert_eq!(a.news(end + SAY_EVERY), None, "nothing new");
        assert_eq!(a.next_due(end), None);
        let summary = a.summary().expect("drops since the start");
        assert!(summary.contains("60 messages dropped"), "{summary}");
    }
}

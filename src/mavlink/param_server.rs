//! The MAVLink parameter protocol, served by the bridge's component: PARAM_REQUEST_LIST,
//! PARAM_REQUEST_READ (by name or index) and PARAM_SET, answered with PARAM_VALUE.
//!
//! - A list or a read is addressed to the bridge's system (or 0) and its component (or 0,
//!   which is how QGroundControl asks every component at once). A set must name the bridge's
//!   component: a broadcast set is for the autopilot.
//! - A list is answered on the link it came in on, one value every [`LIST_PERIOD`] (20 a
//!   second, whatever the links), so that it fits a telemetry radio beside everything else the
//!   aircraft sends. A value already waiting to go out on that link is not queued twice: a
//!   flood of requests costs at most one pass over the table.
//! - A read of an unknown name or index gets no answer (the protocol's rule); a set of an
//!   unknown name gets a STATUSTEXT.
//! - A set that passes [`Param::edits`] is handed to the caller ([`ParamServer::poll_set`]),
//!   which changes the mapping file and reports back with [`ParamServer::set_done`]. Either way
//!   the current value goes out on every link (the protocol asks for a broadcast), and a
//!   refusal also says why in a STATUSTEXT.
//! - What a sender can make the bridge write is bounded: one change is being written at a time
//!   ([`ParamServer::poll_set`] gives the next only after [`ParamServer::set_done`]), and at
//!   most one waits per parameter, the latest (a later set replaces it). A set is compared
//!   with the value the file will hold once the change being written is done, not with the
//!   current one: a ground station's retry during a slow write is not a second write. So a
//!   burst of sets costs at most two writes per parameter it names.

use super::LinkId;
use super::params::{PARAM_TYPE, Param, ParamTable, ServoInfo};
use super::statustext::fit;
use crate::config::Config;
use crate::config::edit::Edit;
use mavlink::dialects::common::{MavMessage, MavParamType, MavSeverity, PARAM_VALUE_DATA};
use std::collections::{HashSet, VecDeque};
use std::time::{Duration, Instant};

/// The time between two PARAM_VALUEs of a list: 20 a second, 740 bytes/s (1 000 signed), an
/// eighth to a sixth of a 57 600-baud telemetry radio (≈ 5.7 kB/s for everything the aircraft
/// sends). Four servos' 61 parameters take 3 s, eight servos' 117 take 6 s; QGroundControl
/// and MAVProxy ask again only for values missing after seconds without any.
pub const LIST_PERIOD: Duration = Duration::from_millis(50);

/// A change asked for by PARAM_SET, for the caller to make in the mapping file.
#[derive(Debug, Clone)]
pub struct ParamSet {
    pub index: usize,
    pub name: String,
    pub value: f32,
    pub edits: Vec<Edit>,
}

/// Something for the bridge to send.
#[derive(Debug, Clone, PartialEq)]
pub enum ParamOut {
    /// A PARAM_VALUE on one link, or (`None`) on every link.
    Value { link: Option<LinkId>, index: usize },
    /// A STATUSTEXT.
    Text(MavSeverity, String),
}

/// See the module docs.
#[derive(Debug)]
pub struct ParamServer {
    table: ParamTable,
    queue: VecDeque<(LinkId, usize)>,
    queued: HashSet<(LinkId, usize)>,
    next_value: Instant,
    /// Changes waiting for the file: at most one per parameter.
    sets: VecDeque<ParamSet>,
    /// The change being written: (parameter index, value).
    writing: Option<(usize, f32)>,
}

impl ParamServer {
    pub fn new(cfg: &Config, now: Instant) -> Self {
        ParamServer {
            table: ParamTable::new(cfg),
            queue: VecDeque::new(),
            queued: HashSet::new(),
            next_value: now,
            sets: VecDeque::new(),
            writing: None,
        }
    }

    pub fn table(&self) -> &ParamTable {
        &self.table
    }

    /// A parameter message arrived on `link`; `us` is the bridge's (system, component).
    /// Returns what to send now. Other messages are not looked at.
    pub fn handle(
        &mut self,
        link: LinkId,
        msg: &MavMessage,
        us: (u8, u8),
        cfg: &Config,
        info: &[ServoInfo],
    ) -> Vec<ParamOut> {
        let to_us = |system: u8, component: u8| {
            (system == us.0 || system == 0) && (component == us.1 || component == 0)
        };
        match msg {
            MavMessage::PARAM_REQUEST_LIST(m) if to_us(m.target_system, m.target_component) => {
                for index in 0..self.table.len() {
                    if self.queued.insert((link, index)) {
                        self.queue.push_back((link, index));
                    }
                }
                Vec::new()
            }
            MavMessage::PARAM_REQUEST_READ(m) if to_us(m.target_system, m.target_component) => {
                let index = if m.param_index < 0 {
                    self.table.index_of(name_of(&m.param_id[..]))
                } else {
                    Some(m.param_index as usize).filter(|i| *i < self.table.len())
                };
                index
                    .map(|index| ParamOut::Value {
                        link: Some(link),
                        index,
                    })
                    .into_iter()
                    .collect()
            }
            MavMessage::PARAM_SET(m)
                if (m.target_system == us.0 || m.target_system == 0)
                    && m.target_component == us.1 =>
            {
                let name = name_of(&m.param_id[..]);
                let Some(index) = self.table.index_of(name) else {
                    return vec![ParamOut::Text(
                        MavSeverity::MAV_SEVERITY_WARNING,
                        fit(format!("no parameter {}", printable(name))),
                    )];
                };
                let param = self.table.get(index).expect("index from the table");
                self.set(index, param, m.param_value, m.param_type, cfg, info)
            }
            _ => Vec::new(),
        }
    }

    fn set(
        &mut self,
        index: usize,
        param: Param,
        value: f32,
        ty: MavParamType,
        cfg: &Config,
        info: &[ServoInfo],
    ) -> Vec<ParamOut> {
        let every_link = ParamOut::Value { link: None, index };
        let name = param.name();
        match param.edits(cfg, value, ty) {
            Err(refusal) => vec![
                every_link,
                ParamOut::Text(
                    MavSeverity::MAV_SEVERITY_WARNING,
                    fit(format!("{name} {}: {refusal}", number(value))),
                ),
            ],
            Ok(edits) => {
                let waiting = self.sets.iter().position(|s| s.index == index);
                let writing = self.writing.filter(|(i, _)| *i == index).map(|(_, v)| v);
                if edits.is_empty() || writing.unwrap_or_else(|| param.value(cfg, info)) == value {
                    // What the file will hold: no change waits for it. The write under way
                    // answers when it is done.
                    if let Some(at) = waiting {
                        self.sets.remove(at);
                    }
                    return if writing.is_some() {
                        Vec::new()
                    } else {
                        vec![every_link]
                    };
                }
                let set = ParamSet {
                    index,
                    name,
                    value,
                    edits,
                };
                match waiting {
                    Some(at) => self.sets[at] = set,
                    None => self.sets.push_back(set),
                }
                Vec::new()
            }
        }
    }

    /// The next change for the caller to make in the mapping file; none while one is being
    /// made (until [`ParamServer::set_done`]).
    pub fn poll_set(&mut self) -> Option<ParamSet> {
        if self.writing.is_some() {
            return None;
        }
        let set = self.sets.pop_front()?;
        self.writing = Some((set.index, set.value));
        Some(set)
    }

    /// Changes waiting for the file, the one being written not counted.
    pub fn sets_waiting(&self) -> usize {
        self.sets.len()
    }

    /// How the change went: `Err` holds why the mapping file refused it (or could not be
    /// saved). `before` and `after` are the configurations around it: every parameter whose
    /// value it changed goes out (FS_ACT = 3 also moves FS_POS).
    pub fn set_done(
        &mut self,
        set: &ParamSet,
        result: Result<(), String>,
        before: &Config,
        after: &Config,
        info: &[ServoInfo],
    ) -> Vec<ParamOut> {
        self.writing = None;
        match result {
            Ok(()) => {
                let mut out: Vec<ParamOut> = self
                    .table
                    .iter()
                    .enumerate()
                    .filter(|(i, p)| {
                        *i == set.index || p.value(before, info) != p.value(after, info)
                    })
                    .map(|(index, _)| ParamOut::Value { link: None, index })
                    .collect();
                out.sort_by_key(|o| match o {
                    ParamOut::Value { index, .. } => usize::from(*index != set.index),
                    ParamOut::Text(..) => 2,
                });
                out
            }
            Err(reason) => vec![
                ParamOut::Value {
                    link: None,
                    index: set.index,
                },
                ParamOut::Text(
                    MavSeverity::MAV_SEVERITY_WARNING,
                    fit(format!("{} {}: {reason}", set.name, number(set.value))),
                ),
            ],
        }
    }

    /// The value of a list due at `now`, if one is.
    pub fn due(&mut self, now: Instant) -> Vec<ParamOut> {
        if now < self.next_value {
            return Vec::new();
        }
        let Some((link, index)) = self.queue.pop_front() else {
            return Vec::new();
        };
        self.queued.remove(&(link, index));
        // Paced from when this value went, not from when it was due: a late wake-up does not
        // make the next ones go faster.
        self.next_value = now + LIST_PERIOD;
        vec![ParamOut::Value {
            link: Some(link),
            index,
        }]
    }

    /// When [`ParamServer::due`] has something to send.
    pub fn next_deadline(&self) -> Option<Instant> {
        (!self.queue.is_empty()).then_some(self.next_value)
    }

    /// The PARAM_VALUE of parameter `index`.
    pub fn value_message(&self, index: usize, cfg: &Config, info: &[ServoInfo]) -> MavMessage {
        let param = self.table.get(index);
        MavMessage::PARAM_VALUE(PARAM_VALUE_DATA {
            param_value: param.map_or(0.0, |p| p.value(cfg, info)),
            param_count: u16::try_from(self.table.len()).unwrap_or(u16::MAX),
            param_index: u16::try_from(index).unwrap_or(u16::MAX),
            param_id: param.map(Param::name).unwrap_or_default().as_str().into(),
            param_type: PARAM_TYPE,
        })
    }
}

/// A parameter name as sent: up to 16 bytes, NUL-terminated when shorter.
fn name_of(id: &[u8]) -> &str {
    let end = id.iter().position(|b| *b == 0).unwrap_or(id.len());
    std::str::from_utf8(&id[..end]).unwrap_or("")
}

/// A name from the wire, safe to print.
fn printable(name: &str) -> String {
    name.chars()
        .filter(|c| c.is_ascii_graphic())
        .take(16)
        .collect()
}

/// A value as a person would write it.
fn number(value: f32) -> String {
    if value.is_finite() {
        value.to_string()
    } else {
        "NaN".into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::{
        PARAM_REQUEST_LIST_DATA, PARAM_REQUEST_READ_DATA, PARAM_SET_DATA,
    };

    const US: (u8, u8) = (1, 140);

    fn cfg() -> Config {
        Config::default_sitl()
    }

    fn list(component: u8) -> MavMessage {
        MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
            target_system: 1,
            target_component: component,
        })
    }

    fn set_msg(name: &str, value: f32, ty: MavParamType) -> MavMessage {
        MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: value,
            target_system: 1,
            target_component: 140,
            param_id: name.into(),
            param_type: ty,
        })
    }

    /// Every value of the lists queued, with when it went, calling `due` whenever it is due.
    fn drain_timed(
        server: &mut ParamServer,
        start: Instant,
    ) -> Vec<(Instant, Option<LinkId>, usize)> {
        let mut sent = Vec::new();
        let mut now = start;
        while let Some(at) = server.next_deadline() {
            now = now.max(at);
            for out in server.due(now) {
                let ParamOut::Value { link, index } = out else {
                    panic!("{out:?}")
                };
                sent.push((now, link, index));
            }
        }
        sent
    }

    fn drain(server: &mut ParamServer, start: Instant) -> Vec<(Option<LinkId>, usize)> {
        drain_timed(server, start)
            .into_iter()
            .map(|(_, link, index)| (link, index))
            .collect()
    }

    #[test]
    fn a_list_to_every_component_sends_each_value_once_paced_for_a_radio() {
        let cfg = cfg();
        let t0 = Instant::now();
        let mut server = ParamServer::new(&cfg, t0);
        assert!(server.handle(1, &list(0), US, &cfg, &[]).is_empty());
        assert_eq!(server.due(t0).len(), 1);
        assert!(server.due(t0).is_empty(), "the next value waits");
        assert_eq!(server.next_deadline(), Some(t0 + LIST_PERIOD));
        let rest = drain_timed(&mut server, t0);
        let n = server.table().len();
        assert_eq!(1 + rest.len(), n);
        assert!(rest.iter().all(|(_, link, _)| *link == Some(1)));
        let indexes: Vec<usize> = rest.iter().map(|(_, _, i)| *i).collect();
        assert_eq!(indexes, (1..n).collect::<Vec<_>>());
        // One value every 50 ms: 20 a second.
        let took = rest.last().unwrap().0 - t0;
        assert_eq!(took, LIST_PERIOD * (n as u32 - 1));
        // A signed PARAM_VALUE is 50 bytes on the wire (10 header, 25 payload, 2 CRC, 13
        // signature): 20 a second is a fifth of a 57 600-baud radio at most.
        let per_second = Duration::from_secs(1).as_secs_f64() / LIST_PERIOD.as_secs_f64();
        assert!(per_second * 50.0 <= 5760.0 / 5.0, "{per_second} values/s");
        // A late wake-up does not make the next value go sooner.
        server.handle(0, &list(0), US, &cfg, &[]);
        let late = t0 + Duration::from_secs(100);
        assert_eq!(server.due(late).len(), 1);
        assert_eq!(server.next_deadline(), Some(late + LIST_PERIOD));
    }

    #[test]
    fn a_burst_of_sets_costs_at_most_two_writes_per_parameter_and_the_latest_wins() {
        let cfg = cfg();
        let mut server = ParamServer::new(&cfg, Instant::now());
        let real = MavParamType::MAV_PARAM_TYPE_REAL32;
        // One change is being written (slowly) when the burst comes.
        server.handle(0, &set_msg("S1_PWM_TRIM", 1400.0, real), US, &cfg, &[]);
        let writing = server.poll_set().unwrap();
        assert!(server.poll_set().is_none(), "one write at a time");
        for i in 0..1000 {
            for name in ["S1_PWM_TRIM", "S2_PWM_TRIM"] {
                let value = 1400.0 + (i % 7) as f32;
                server.handle(0, &set_msg(name, value, real), US, &cfg, &[]);
            }
        }
        assert_eq!(server.sets_waiting(), 2, "one change waits per parameter");
        server.set_done(&writing, Ok(()), &cfg, &cfg, &[]);
        let mut written = Vec::new();
        while let Some(set) = server.poll_set() {
            server.set_done(&set, Ok(()), &cfg, &cfg, &[]);
            written.push((set.name, set.value));
        }
        let last = 1400.0 + (999 % 7) as f32;
        written.sort_by(|a, b| a.0.cmp(&b.0));
        assert_eq!(
            written,
            vec![("S1_PWM_TRIM".into(), last), ("S2_PWM_TRIM".into(), last)]
        );
    }

    #[test]
    fn a_retry_during_a_slow_write_is_not_a_second_write() {
        let cfg = cfg();
        let mut server = ParamServer::new(&cfg, Instant::now());
        let real = MavParamType::MAV_PARAM_TYPE_REAL32;
        let set = set_msg("S1_PWM_TRIM", 1400.0, real);
        server.handle(0, &set, US, &cfg, &[]);
        let writing = server.poll_set().unwrap();
        // The ground station hears nothing yet and asks again: answered once the write is done.
        assert!(server.handle(0, &set, US, &cfg, &[]).is_empty());
        assert_eq!(server.sets_waiting(), 0);
        // Back to the value the file holds now: that is a change from what it will hold.
        server.handle(0, &set_msg("S1_PWM_TRIM", 1520.0, real), US, &cfg, &[]);
        assert_eq!(server.sets_waiting(), 1);
        // And 1400 again: what the file will hold after the write; nothing waits.
        assert!(server.handle(0, &set, US, &cfg, &[]).is_empty());
        assert_eq!(server.sets_waiting(), 0);
        let out = server.set_done(&writing, Ok(()), &cfg, &cfg, &[]);
        assert!(out.contains(&ParamOut::Value {
            link: None,
            index: writing.index
        }));
        assert!(server.poll_set().is_none());
    }

    #[test]
    fn a_flood_of_lists_costs_one_pass_over_the_table() {
        let cfg = cfg();
        let t0 = Instant::now();
        let mut server = ParamServer::new(&cfg, t0);
        for _ in 0..1000 {
            server.handle(0, &list(140), US, &cfg, &[]);
        }
        assert_eq!(drain(&mut server, t0).len(), server.table().len());
    }

    #[test]
    fn lists_for_another_component_or_system_are_not_answered() {
        let cfg = cfg();
        let t0 = Instant::now();
        let mut server = ParamServer::new(&cfg, t0);
        server.handle(0, &list(1), US, &cfg, &[]);
        let other_system = MavMessage::PARAM_REQUEST_LIST(PARAM_REQUEST_LIST_DATA {
            target_system: 2,
            target_component: 0,
        });
        server.handle(0, &other_system, US, &cfg, &[]);
        assert_eq!(server.next_deadline(), None);
    }

    #[test]
    fn a_read_by_name_or_index_is_answered_on_its_link_and_an_unknown_one_is_not() {
        let cfg = cfg();
        let mut server = ParamServer::new(&cfg, Instant::now());
        let read = |name: &str, index: i16| {
            MavMessage::PARAM_REQUEST_READ(PARAM_REQUEST_READ_DATA {
                param_index: index,
                target_system: 1,
                target_component: 0,
                param_id: name.into(),
            })
        };
        let trim = server.table().index_of("S2_PWM_TRIM").unwrap();
        assert_eq!(
            server.handle(1, &read("S2_PWM_TRIM", -1), US, &cfg, &[]),
            vec![ParamOut::Value {
                link: Some(1),
                index: trim
            }]
        );
        assert_eq!(
            server.handle(0, &read("", 3), US, &cfg, &[]),
            vec![ParamOut::Value {
                link: Some(0),
                index: 3
            }]
        );
        assert!(
            server
                .handle(0, &read("NOPE", -1), US, &cfg, &[])
                .is_empty()
        );
        assert!(server.handle(0, &read("", 9999), US, &cfg, &[]).is_empty());
        let MavMessage::PARAM_VALUE(v) = server.value_message(trim, &cfg, &[]) else {
            panic!()
        };
        assert_eq!(v.param_value, 1520.0);
        assert_eq!(usize::from(v.param_index), trim);
        assert_eq!(usize::from(v.param_count), server.table().len());
        assert_eq!(v.param_type, PARAM_TYPE);
        assert_eq!(name_of(&v.param_id[..]), "S2_PWM_TRIM");
    }

    #[test]
    fn a_set_becomes_an_edit_and_every_refusal_answers_with_the_old_value_and_a_reason() {
        let cfg = cfg();
        let mut server = ParamServer::new(&cfg, Instant::now());
        let real = MavParamType::MAV_PARAM_TYPE_REAL32;
        let trim = server.table().index_of("S1_PWM_TRIM").unwrap();
        assert!(
            server
                .handle(0, &set_msg("S1_PWM_TRIM", 1500.0, real), US, &cfg, &[])
                .is_empty()
        );
        let set = server.poll_set().unwrap();
        assert_eq!(
            (set.index, set.name.as_str(), set.value),
            (trim, "S1_PWM_TRIM", 1500.0)
        );
        // The file refuses it (and the next set is compared with the current value again).
        server.set_done(&set, Err("refused".into()), &cfg, &cfg, &[]);

        for (msg, why) in [
            (
                set_msg("S1_PWM_TRIM", f32::NAN, real),
                "S1_PWM_TRIM NaN: not a number",
            ),
            (
                set_msg("S1_PWM_TRIM", 1500.5, real),
                "S1_PWM_TRIM 1500.5: needs a whole number",
            ),
            (
                set_msg("S1_PWM_TRIM", 1500.0, MavParamType::MAV_PARAM_TYPE_INT32),
                "S1_PWM_TRIM 1500: type 6 not REAL32",
            ),
        ] {
            let out = server.handle(0, &msg, US, &cfg, &[]);
            assert_eq!(
                out,
                vec![
                    ParamOut::Value {
                        link: None,
                        index: trim
                    },
                    ParamOut::Text(MavSeverity::MAV_SEVERITY_WARNING, why.into())
                ]
            );
        }
        let out = server.handle(0, &set_msg("S1_ID", 9.0, real), US, &cfg, &[]);
        assert!(
            matches!(&out[1], ParamOut::Text(_, t) if t == "S1_ID 9: read-only"),
            "{out:?}"
        );
        let out = server.handle(0, &set_msg("S9_PWM_TRIM", 1.0, real), US, &cfg, &[]);
        assert_eq!(
            out,
            vec![ParamOut::Text(
                MavSeverity::MAV_SEVERITY_WARNING,
                "no parameter S9_PWM_TRIM".into()
            )]
        );
        // The same value again: answered, nothing to change.
        let out = server.handle(0, &set_msg("S1_PWM_TRIM", 1520.0, real), US, &cfg, &[]);
        assert_eq!(
            out,
            vec![ParamOut::Value {
                link: None,
                index: trim
            }]
        );
        // A set broadcast to every component is the autopilot's.
        let mut broadcast = set_msg("S1_PWM_TRIM", 1400.0, real);
        if let MavMessage::PARAM_SET(m) = &mut broadcast {
            m.target_component = 0;
        }
        assert!(server.handle(0, &broadcast, US, &cfg, &[]).is_empty());
        assert!(server.poll_set().is_none());
    }

    #[test]
    fn after_a_set_every_value_it_changed_goes_out_and_a_refusal_says_why() {
        let before = cfg();
        let mut server = ParamServer::new(&before, Instant::now());
        let mut after = before.clone();
        after.servos[0].failsafe =
            crate::config::FailsafeAction::Position(crate::protocol::MmCenti(0));
        let act = server.table().index_of("S1_FS_ACT").unwrap();
        let set = ParamSet {
            index: act,
            name: "S1_FS_ACT".into(),
            value: 3.0,
            edits: Vec::new(),
        };
        assert_eq!(
            server.set_done(&set, Ok(()), &before, &after, &[]),
            vec![ParamOut::Value {
                link: None,
                index: act
            }]
        );
        after.servos[0].failsafe =
            crate::config::FailsafeAction::Position(crate::protocol::MmCenti(250));
        let pos = server.table().index_of("S1_FS_POS").unwrap();
        assert_eq!(
            server.set_done(&set, Ok(()), &before, &after, &[]),
            vec![
                ParamOut::Value {
                    link: None,
                    index: act
                },
                ParamOut::Value {
                    link: None,
                    index: pos
                }
            ]
        );
        let out = server.set_done(
            &set,
            Err("a reason long enough to need cutting at fifty characters".into()),
            &before,
            &before,
            &[],
        );
        let ParamOut::Text(_, text) = &out[1] else {
            panic!()
        };
        assert_eq!(text.len(), super::super::statustext::MAX_TEXT);
        assert!(text.starts_with("S1_FS_ACT 3: a reason"));
    }
}

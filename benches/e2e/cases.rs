//! The bench's cases (servos, rate, ports, bit rate, scenario, hogs) and what the autopilot
//! sends in each: the output messages in send order, and their SERVO_OUTPUT_RAW.

use lj9da_bridge::mavlink::outputs::servo_output_raw;
use mavlink::dialects::common::MavMessage;
use std::time::{Duration, Instant};

#[derive(Clone, Copy, PartialEq)]
pub(super) enum Jitter {
    None,
    /// Each tick sent up to 1 ms early or late (uniform).
    Uniform1Ms,
    /// One message in twenty sent 3–8 ms late.
    Late5Pct,
}

impl Jitter {
    fn name(self) -> &'static str {
        match self {
            Jitter::None => "steady",
            Jitter::Uniform1Ms => "±1ms",
            Jitter::Late5Pct => "5%late",
        }
    }
}

/// What the autopilot's outputs do over a run.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Scenario {
    /// Every message changes its goals.
    Sweep(Jitter),
    /// The outputs hold still; both ports step every 0.8 s.
    Steps,
    /// Steps every 0.3 s; port 1 silent for 2.5 s after a third of the run.
    PortGap,
    /// Steps every 0.3 s; 12.5 Hz for 3 s after a third of the run, then 50 Hz again.
    RateDrop,
    /// The steady sweep with a fifth of servo 1's replies corrupted.
    Garbled,
}

impl Scenario {
    pub(super) fn name(self) -> &'static str {
        match self {
            Scenario::Sweep(j) => j.name(),
            Scenario::Steps => "steps",
            Scenario::PortGap => "gap",
            Scenario::RateDrop => "rate",
            Scenario::Garbled => "garbled",
        }
    }

    pub(super) fn jitter(self) -> Jitter {
        match self {
            Scenario::Sweep(j) => j,
            _ => Jitter::None,
        }
    }

    /// Ticks between steps (`None`: every message changes).
    pub(super) fn step_every(self) -> Option<usize> {
        match self {
            Scenario::Sweep(_) | Scenario::Garbled => None,
            Scenario::Steps => Some(40),
            Scenario::PortGap | Scenario::RateDrop => Some(15),
        }
    }

    /// Seconds the case runs at least (a disturbance and the time after it).
    pub(super) fn min_seconds(self) -> f64 {
        match self {
            Scenario::PortGap | Scenario::RateDrop => 10.0,
            Scenario::Steps => 8.0,
            _ => 0.0,
        }
    }
}

pub(super) struct Case {
    pub(super) servos: usize,
    pub(super) rate_hz: f64,
    /// The bus's bit rate.
    pub(super) baud: u32,
    /// Ports the autopilot sends: 1, or 2 (SERVO_OUTPUT_RAW port 0 and port 1).
    pub(super) ports: u8,
    /// With two ports: the last servo is on channel 17 (port 1). Without, every servo is on
    /// port 0 and port 1's messages carry nothing the bridge maps (most planes).
    pub(super) port1_mapped: bool,
    pub(super) scenario: Scenario,
    pub(super) hogs: usize,
}

impl Case {
    pub(super) fn name(&self) -> String {
        format!(
            "{}x{}{}{}{}",
            self.servos,
            self.rate_hz,
            match (self.ports, self.port1_mapped) {
                (2, true) => "x2p",
                (2, false) => "x2pu",
                _ => "",
            },
            match self.scenario {
                Scenario::Sweep(Jitter::None) => "",
                Scenario::Sweep(Jitter::Uniform1Ms) => "j",
                Scenario::Sweep(Jitter::Late5Pct) => "l",
                Scenario::Steps => "s",
                Scenario::PortGap => "g",
                Scenario::RateDrop => "r",
                Scenario::Garbled => "c",
            },
            if self.baud == 115_200 { "" } else { "@460k" },
        )
    }
}

/// One output message of the autopilot.
pub(super) struct Message {
    pub(super) at: Instant,
    pub(super) port: u8,
    /// Which values it carries (see [`pwm`]).
    pub(super) value: usize,
    /// Its values differ from its port's message before it: its latency is measured.
    pub(super) changed: bool,
    /// Sent at least 1 s after the scenario's disturbance began or ended.
    pub(super) settled: bool,
    /// The autopilot's tick it belongs to.
    pub(super) tick: usize,
}

/// A measured message as it was sent.
pub(super) struct Send {
    pub(super) at: Instant,
    pub(super) port: usize,
    pub(super) goal: i16,
    pub(super) settled: bool,
    /// The autopilot's tick it belongs to (both ports' messages of a tick share it).
    pub(super) tick: usize,
}

/// The messages of `case` from `t0`, in send order.
pub(super) fn schedule(case: &Case, seconds: f64, t0: Instant) -> Vec<Message> {
    let period = Duration::from_secs_f64(1.0 / case.rate_hz);
    let n = (seconds * case.rate_hz) as usize;
    let mut rng = XorShift(0x2545_F491_4F6C_DD1D);
    // The disturbance of `gap` and `rate`: from a third of the run, 2.5 s or 3 s long.
    let (from, until) = (n / 3, n / 3 + (case.rate_hz * 2.5) as usize);
    let until = if case.scenario == Scenario::RateDrop {
        n / 3 + (case.rate_hz * 3.0) as usize
    } else {
        until
    };
    let settle = case.rate_hz as usize;
    let mut out = Vec::with_capacity(n * usize::from(case.ports));
    for i in 1..=n {
        let disturbed = (from..until).contains(&i);
        if case.scenario == Scenario::RateDrop && disturbed && (i - from) % 4 != 0 {
            continue;
        }
        let tick = t0 + period * i as u32;
        let tick = match case.scenario.jitter() {
            Jitter::Uniform1Ms => {
                let offset = Duration::from_secs_f64(rng.unit() * 2e-3);
                tick + offset - Duration::from_millis(1)
            }
            _ => tick,
        };
        let (value, changed) = match case.scenario.step_every() {
            None => (i, true),
            Some(every) => (i / every, i % every == 0),
        };
        let settled = match case.scenario {
            Scenario::PortGap | Scenario::RateDrop => {
                (i >= from + settle && i < until) || i >= until + settle
            }
            _ => false,
        };
        for port in 0..case.ports {
            if case.scenario == Scenario::PortGap && port == 1 && disturbed {
                continue;
            }
            let mut at = tick + Duration::from_micros(100) * u32::from(port);
            if case.scenario.jitter() == Jitter::Late5Pct && rng.unit() < 0.05 {
                at += Duration::from_secs_f64(3e-3 + rng.unit() * 5e-3);
            }
            out.push(Message {
                at,
                port,
                value,
                changed,
                settled,
                tick: i,
            });
        }
    }
    out.sort_by_key(|m| m.at);
    out
}

/// SERVO_OUTPUT_RAW of message `i` for `port`: channels 1–16 (port 0) or 17–32 (port 1).
pub(super) fn outputs(servos: usize, marked: usize, port: u8, i: usize) -> MavMessage {
    let mut raw = [0u16; 16];
    for s in 1..=servos {
        let on_port1 = marked != 1 && s == marked;
        if on_port1 == (port == 1) {
            let channel = if on_port1 { 0 } else { s - 1 };
            raw[channel] = pwm(s, i, marked);
        }
    }
    servo_output_raw(port, raw, 0)
}

/// The PWM of servo `s` in message `i`: servo 1 (port 0) and the servo on port 1 walk through
/// 800 distinct values.
pub(super) fn pwm(s: usize, i: usize, marked: usize) -> u16 {
    if s == 1 || s == marked {
        1120 + (i % 800) as u16
    } else {
        (1520.0 + 300.0 * ((i as f64) * 0.01 + s as f64).sin()) as u16
    }
}

/// A small deterministic generator for the jittery autopilot.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

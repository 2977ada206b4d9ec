//! The output stream's rate as received, per message port, beside the rate asked for.
//!
//! An autopilot may send its outputs slower than the bridge asked: PX4's onboard link starts
//! SERVO_OUTPUT_RAW at 10 Hz until the request raises it, and slows every stream when the link
//! is over its `MAV_n_RATE`; ArduPilot caps a stream at 0.8 × SCHED_LOOP_RATE (4.5 and earlier
//! accept a faster request and send at the cap). The servos then follow at the rate received,
//! whatever was asked. So the rate is measured over windows of [`WINDOW`] for each port that
//! carries a mapped servo's channel (SERVO_OUTPUT_RAW port 0: channels 1–16, port 1: 17–32;
//! ACTUATOR_OUTPUT_STATUS: one message, port 0), and:
//! - each first measurement, and each change by more than [`NEWS_CHANGE`], is news for the log
//!   and the flight record;
//! - a port that keeps sending below [`LOW_SHARE`] of the rate asked for [`LOW_WINDOWS`]
//!   windows in a row is said once, as a warning naming the parameters that set the rate.
//!
//! A port that sends nothing at all is the failsafe's business (announced there), not a low
//! rate. Sans-IO: it is handed the time.

use crate::config::Source;
use std::time::{Duration, Instant};

/// The length of one measurement.
pub const WINDOW: Duration = Duration::from_secs(2);
/// Below this share of the rate asked for, a port is slow (the stream is "ok" at or above it).
pub const LOW_SHARE: f32 = 0.7;
/// Windows in a row a port must be slow for before it is said: 6 s.
pub const LOW_WINDOWS: u32 = 3;
/// A measured rate that moves by more than this share of the last one reported is news.
pub const NEWS_CHANGE: f32 = 0.2;

/// Message ports: SERVO_OUTPUT_RAW carries 0 and 1.
const PORTS: usize = 2;

#[derive(Debug)]
pub struct RateMeter {
    source: Source,
    /// The ports that carry a mapped servo's channel.
    used: [bool; PORTS],
    start: Instant,
    counts: [u32; PORTS],
    received_hz: [Option<f32>; PORTS],
    reported_hz: [Option<f32>; PORTS],
    slow_windows: [u32; PORTS],
    warned: bool,
    news: Vec<String>,
    warnings: Vec<String>,
}

impl RateMeter {
    /// A meter for `source`, whose mapped servos take `channels` (1–32).
    pub fn new(source: Source, channels: impl IntoIterator<Item = u8>, now: Instant) -> Self {
        let mut used = [false; PORTS];
        for channel in channels {
            let port = match source {
                Source::ServoOutputRaw => usize::from(channel > 16),
                Source::ActuatorOutputStatus => 0,
            };
            used[port] = true;
        }
        Self {
            source,
            used,
            start: now,
            counts: [0; PORTS],
            received_hz: [None; PORTS],
            reported_hz: [None; PORTS],
            slow_windows: [0; PORTS],
            warned: false,
            news: Vec::new(),
            warnings: Vec::new(),
        }
    }

    /// An output message of `port` arrived. Returns the fastest port's rate when a window
    /// closed.
    pub fn count(&mut self, port: u8, asked_hz: f32, now: Instant) -> Option<f32> {
        if let Some(n) = self.counts.get_mut(usize::from(port)) {
            *n += 1;
        }
        self.roll(asked_hz, now)
    }

    /// Close the window if it is due (also called without a message, so that a port that
    /// slows to nothing is measured as such). Returns the fastest port's rate when it closed.
    pub fn roll(&mut self, asked_hz: f32, now: Instant) -> Option<f32> {
        let window = now.duration_since(self.start);
        if window < WINDOW {
            return None;
        }
        let secs = window.as_secs_f32();
        let mut fastest = 0.0f32;
        for port in 0..PORTS {
            let count = std::mem::take(&mut self.counts[port]);
            let hz = count as f32 / secs;
            fastest = fastest.max(hz);
            if !self.used[port] && count == 0 {
                self.received_hz[port] = None;
                continue;
            }
            self.received_hz[port] = Some(hz);
            if self.used[port] {
                self.judge(port, hz, count, asked_hz);
            }
        }
        self.start = now;
        Some(fastest)
    }

    fn judge(&mut self, port: usize, hz: f32, count: u32, asked_hz: f32) {
        let moved = self.reported_hz[port]
            .is_none_or(|last| (hz - last).abs() > NEWS_CHANGE * last.max(1.0));
        if count > 0 && moved {
            self.reported_hz[port] = Some(hz);
            self.news.push(format!(
                "output rate received: {} {hz:.1} Hz (asked {asked_hz} Hz)",
                self.port_name(port)
            ));
        }
        if count > 0 && hz < LOW_SHARE * asked_hz {
            self.slow_windows[port] += 1;
        } else {
            self.slow_windows[port] = 0;
        }
        if self.slow_windows[port] >= LOW_WINDOWS && !std::mem::replace(&mut self.warned, true) {
            let seconds = (WINDOW * LOW_WINDOWS).as_secs();
            self.warnings.push(format!(
                "the autopilot sends {} at {hz:.1} Hz, below the {asked_hz} Hz asked for, for \
                 {seconds} s: the servos follow it at that rate. ArduPilot: the stream's rate is \
                 SRm_RC_CHAN (MAV<m+1>_RC_CHAN from 4.7; m the port's MAVLink channel), capped \
                 at 0.8 × SCHED_LOOP_RATE; PX4: raise \
                 MAV_n_RATE (the link's byte budget) or lower MAV_n_MODE's other streams; or \
                 lower [mavlink] output_rate_hz (docs/autopilot.md)",
                self.port_name(port)
            ));
        }
    }

    fn port_name(&self, port: usize) -> String {
        match self.source {
            Source::ServoOutputRaw => format!("SERVO_OUTPUT_RAW port {port}"),
            Source::ActuatorOutputStatus => "ACTUATOR_OUTPUT_STATUS".into(),
        }
    }

    /// The rate received per port, over the last window: ports that carry a mapped channel, and
    /// any other that sent something.
    pub fn received_hz(&self) -> Vec<(u8, f32)> {
        (0..PORTS)
            .filter_map(|p| self.received_hz[p].map(|hz| (p as u8, hz)))
            .collect()
    }

    /// Start measuring afresh at `now`, as after an outage of the whole stream (its failsafe
    /// entered, or the stream back): the window under way and the count of slow windows are
    /// dropped, so that neither the silence nor an autopilot that restarted and is still at its
    /// default rate until it hears the request again is taken for a slow stream.
    pub fn restart(&mut self, now: Instant) {
        self.start = now;
        self.counts = [0; PORTS];
        self.slow_windows = [0; PORTS];
    }

    /// When the current window closes.
    pub fn deadline(&self) -> Instant {
        self.start + WINDOW
    }

    /// New measurements to say (log, flight record).
    pub fn take_news(&mut self) -> Vec<String> {
        std::mem::take(&mut self.news)
    }

    /// The slow-stream warning, once.
    pub fn take_warnings(&mut self) -> Vec<String> {
        std::mem::take(&mut self.warnings)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Feed `port` at `hz` from `from` for `secs`, rolling as the core does.
    fn feed(m: &mut RateMeter, port: u8, hz: f32, asked: f32, from: Instant, secs: f32) -> Instant {
        let step = Duration::from_secs_f32(1.0 / hz);
        let mut t = from;
        while t < from + Duration::from_secs_f32(secs) {
            m.count(port, asked, t);
            t += step;
        }
        t
    }

    #[test]
    fn a_stream_at_the_rate_asked_is_news_once_and_never_a_warning() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ServoOutputRaw, [1, 2, 3], t0);
        feed(&mut m, 0, 50.0, 50.0, t0, 20.0);
        let news = m.take_news();
        assert_eq!(news.len(), 1, "{news:?}");
        assert!(news[0].starts_with("output rate received: SERVO_OUTPUT_RAW port 0 5"));
        assert!(m.take_warnings().is_empty());
        let [(0, hz)] = m.received_hz()[..] else {
            panic!("{:?}", m.received_hz())
        };
        assert!((hz - 50.0).abs() < 1.0, "{hz}");
    }

    #[test]
    fn a_stream_slower_than_asked_for_six_seconds_is_said_once_with_the_parameters() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ServoOutputRaw, [1, 17], t0);
        // Port 0 at 10 Hz (PX4's onboard default), port 1 as asked.
        let mut t = t0;
        let step = Duration::from_millis(20);
        let mut n = 0u32;
        let mut warned_at = None;
        while t < t0 + Duration::from_secs(20) {
            m.count(1, 50.0, t);
            if n.is_multiple_of(5) {
                m.count(0, 50.0, t);
            }
            if warned_at.is_none() && !m.warnings.is_empty() {
                warned_at = Some(t.duration_since(t0));
            }
            n += 1;
            t += step;
        }
        let warnings = m.take_warnings();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("SERVO_OUTPUT_RAW port 0 at 10.0 Hz, below the 50 Hz"),
            "{}",
            warnings[0]
        );
        for parameter in [
            "SRm_RC_CHAN",
            "SCHED_LOOP_RATE",
            "MAV_n_RATE",
            "output_rate_hz",
        ] {
            assert!(warnings[0].contains(parameter), "{parameter}");
        }
        let at = warned_at.unwrap();
        assert!(
            (Duration::from_secs(6)..Duration::from_secs(7)).contains(&at),
            "said after {at:?}"
        );
        let received = m.received_hz();
        assert_eq!(received.len(), 2, "{received:?}");
    }

    #[test]
    fn a_port_that_stops_is_the_failsafes_and_not_a_slow_rate() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ServoOutputRaw, [1], t0);
        let t = feed(&mut m, 0, 50.0, 50.0, t0, 4.0);
        for s in 0..20 {
            m.roll(50.0, t + Duration::from_secs(s));
        }
        assert!(m.take_warnings().is_empty());
        assert_eq!(m.received_hz(), vec![(0, 0.0)]);
        assert_eq!(m.take_news().len(), 1, "only the first measurement is news");
    }

    /// An autopilot killed and started again: its stream stops mid-window, stays silent,
    /// and comes back at its default rate before the request raises it. Measured afresh at the
    /// failsafe and at the return, as the core does, that is no slow stream.
    #[test]
    fn an_outage_and_a_slow_return_are_not_a_slow_stream() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ServoOutputRaw, [1], t0);
        let t = feed(&mut m, 0, 40.0, 40.0, t0, 3.0);
        // Killed at 3 s; its failsafe at 3.5 s.
        m.restart(t + Duration::from_millis(500));
        m.roll(40.0, t + Duration::from_millis(1500));
        // Back at 5.5 s: half a second at 40 Hz, 2.5 s at its default 4 Hz, then 40 Hz.
        let back = t + Duration::from_millis(2500);
        m.restart(back);
        let t = feed(&mut m, 0, 40.0, 40.0, back, 0.5);
        let t = feed(&mut m, 0, 4.0, 40.0, t, 2.5);
        feed(&mut m, 0, 40.0, 40.0, t, 6.0);
        assert!(m.take_warnings().is_empty());
    }

    /// The same stream measured through the outage (no restart) is taken for a slow one: the
    /// rule above is what keeps it quiet.
    #[test]
    fn without_a_restart_the_same_outage_reads_as_a_slow_stream() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ServoOutputRaw, [1], t0);
        let t = feed(&mut m, 0, 40.0, 40.0, t0, 3.0);
        let back = t + Duration::from_millis(2500);
        m.roll(40.0, t + Duration::from_millis(1500));
        let t = feed(&mut m, 0, 40.0, 40.0, back, 0.5);
        let t = feed(&mut m, 0, 4.0, 40.0, t, 2.5);
        feed(&mut m, 0, 40.0, 40.0, t, 6.0);
        assert_eq!(m.take_warnings().len(), 1);
    }

    #[test]
    fn channels_17_to_32_are_judged_on_port_1() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ServoOutputRaw, [17], t0);
        let mut t = t0;
        let mut n = 0u32;
        while t < t0 + Duration::from_secs(10) {
            m.count(0, 50.0, t);
            if n.is_multiple_of(5) {
                m.count(1, 50.0, t);
            }
            n += 1;
            t += Duration::from_millis(20);
        }
        let warnings = m.take_warnings();
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("port 1 at 10.0 Hz"), "{}", warnings[0]);
    }

    #[test]
    fn a_port_no_servo_uses_is_shown_but_never_judged() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ServoOutputRaw, [1], t0);
        let mut t = t0;
        while t < t0 + Duration::from_secs(20) {
            m.count(0, 50.0, t);
            if (t.duration_since(t0).as_millis() / 20).is_multiple_of(10) {
                m.count(1, 50.0, t);
            }
            t += Duration::from_millis(20);
        }
        assert!(m.take_warnings().is_empty());
        let ports: Vec<u8> = m.received_hz().iter().map(|(p, _)| *p).collect();
        assert_eq!(ports, vec![0, 1]);
        assert!(m.take_news().iter().all(|n| n.contains("port 0")));
    }

    #[test]
    fn actuator_output_status_is_one_port() {
        let t0 = Instant::now();
        let mut m = RateMeter::new(Source::ActuatorOutputStatus, [1, 20], t0);
        assert_eq!(m.used, [true, false]);
        feed(&mut m, 0, 5.0, 50.0, t0, 10.0);
        let warnings = m.take_warnings();
        assert_eq!(warnings.len(), 1);
        assert!(
            warnings[0].contains("ACTUATOR_OUTPUT_STATUS at 5.0 Hz"),
            "{}",
            warnings[0]
        );
    }
}

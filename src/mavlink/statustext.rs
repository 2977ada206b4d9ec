//! Events as STATUSTEXT: one message per event, with the severity the MAVLink conventions give
//! it, and never a flood: a repeat of the same kind of event for the same servo (or the same
//! bus) within the hold-off is counted and folded into the next message instead of being sent.

use super::health::{BridgeEvent, ServoEvent, TemperatureReading};
use mavlink::dialects::common::MavSeverity;
use std::collections::HashMap;
use std::time::{Duration, Instant};

/// STATUSTEXT carries at most 50 characters in one chunk.
pub const MAX_TEXT: usize = 50;

/// Severity and text of an event. `servo_name` names the servo of a servo event.
pub fn describe(event: &BridgeEvent, servo_name: &str) -> (MavSeverity, String) {
    use MavSeverity::*;
    let (severity, text) = match event {
        BridgeEvent::Servo { event, .. } => match event {
            ServoEvent::Lost => (MAV_SEVERITY_CRITICAL, format!("{servo_name}: servo lost")),
            ServoEvent::Back => (MAV_SEVERITY_NOTICE, format!("{servo_name}: servo back")),
            ServoEvent::TemperatureAlarm {
                on: true,
                reading: r,
            } => (
                MAV_SEVERITY_WARNING,
                format!("{servo_name}: temperature alarm{}", reading(*r)),
            ),
            ServoEvent::TemperatureAlarm {
                on: false,
                reading: r,
            } => (
                MAV_SEVERITY_NOTICE,
                format!("{servo_name}: temperature ok{}", reading(*r)),
            ),
            ServoEvent::TemperatureError { last_read } => (
                MAV_SEVERITY_CRITICAL,
                format!("{servo_name}: overheat, force off{}", reading(*last_read)),
            ),
            ServoEvent::Stalled { on: true } => {
                (MAV_SEVERITY_ERROR, format!("{servo_name}: stalled"))
            }
            ServoEvent::Stalled { on: false } => {
                (MAV_SEVERITY_NOTICE, format!("{servo_name}: moving again"))
            }
            ServoEvent::WrongModel { found } => (
                MAV_SEVERITY_ERROR,
                format!("{servo_name}: model 0x{found:04X} not LJ9DA41"),
            ),
            ServoEvent::FlashWriteError => (
                MAV_SEVERITY_ERROR,
                format!("{servo_name}: flash write error"),
            ),
            ServoEvent::RepliesDegraded { percent } => (
                MAV_SEVERITY_WARNING,
                format!("{servo_name}: degraded, {percent}% replies bad"),
            ),
            ServoEvent::RepliesOk => (MAV_SEVERITY_INFO, format!("{servo_name}: replies ok")),
        },
        BridgeEvent::FailsafeEntered { timeout_ms } => (
            MAV_SEVERITY_WARNING,
            format!("LJ9DA failsafe: no outputs for {timeout_ms} ms"),
        ),
        BridgeEvent::FailsafeLeft => (MAV_SEVERITY_NOTICE, "LJ9DA failsafe cleared".to_string()),
        BridgeEvent::ChannelMissing {
            channel,
            timeout_ms,
            ..
        } => (
            MAV_SEVERITY_WARNING,
            format!("{servo_name}: failsafe, no ch{channel} for {timeout_ms} ms"),
        ),
        BridgeEvent::ChannelBack { channel, .. } => (
            MAV_SEVERITY_NOTICE,
            format!("{servo_name}: ch{channel} back, failsafe cleared"),
        ),
        BridgeEvent::SourceRefused { source } => (
            MAV_SEVERITY_ERROR,
            format!("LJ9DA: autopilot refuses {source}"),
        ),
        BridgeEvent::PortLost { bus } => {
            (MAV_SEVERITY_CRITICAL, format!("LJ9DA bus {bus}: port lost"))
        }
        BridgeEvent::PortBack { bus } => {
            (MAV_SEVERITY_NOTICE, format!("LJ9DA bus {bus}: port back"))
        }
        BridgeEvent::Safety { on: true, servos } => (
            MAV_SEVERITY_NOTICE,
            format!("LJ9DA: autopilot safety on, servos {servos}"),
        ),
        BridgeEvent::Safety { on: false, .. } => (
            MAV_SEVERITY_NOTICE,
            "LJ9DA: autopilot safety off".to_string(),
        ),
    };
    (severity, fit(text))
}

/// "; 80C 0.4s ago": a reading quoted with its age, since it may predate the event it is
/// quoted with (every temperature text quotes its reading so); nothing when no fresh reading
/// is at hand.
fn reading(last_read: Option<TemperatureReading>) -> String {
    last_read
        .map(|r| format!("; {}C {:.1}s ago", r.celsius, r.age.as_secs_f32()))
        .unwrap_or_default()
}

/// `text` as a STATUSTEXT carries it: in ASCII (the text is a C string that ground stations do
/// not all read as UTF-8: `µs` becomes `us`, dashes `-`), cut to [`MAX_TEXT`] characters.
pub fn fit(text: String) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            'µ' => out.push('u'),
            '–' | '—' | '−' => out.push('-'),
            '…' => out.push_str("..."),
            '×' => out.push('x'),
            '°' => {}
            c if c.is_ascii() => out.push(c),
            _ => out.push('?'),
        }
    }
    out.truncate(MAX_TEXT);
    out
}

/// What an event is about, for the flood guard: events about different servos or different
/// buses never hold each other back.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
enum Subject {
    Servo(usize),
    Bus(String),
    Bridge,
}

/// The kind of an event and what it is about, for the flood guard: an alarm going on and off
/// again is one kind.
fn kind(event: &BridgeEvent) -> (Subject, u8) {
    match event {
        BridgeEvent::Servo { servo, event } => (
            Subject::Servo(*servo),
            match event {
                ServoEvent::Lost | ServoEvent::Back => 0,
                ServoEvent::TemperatureAlarm { .. } => 1,
                ServoEvent::TemperatureError { .. } => 2,
                ServoEvent::Stalled { .. } => 3,
                ServoEvent::WrongModel { .. } => 4,
                ServoEvent::FlashWriteError => 5,
                ServoEvent::RepliesDegraded { .. } | ServoEvent::RepliesOk => 7,
            },
        ),
        BridgeEvent::FailsafeEntered { .. } | BridgeEvent::FailsafeLeft => (Subject::Bridge, 10),
        BridgeEvent::ChannelMissing { servo, .. } | BridgeEvent::ChannelBack { servo, .. } => {
            (Subject::Servo(*servo), 6)
        }
        BridgeEvent::SourceRefused { .. } => (Subject::Bridge, 13),
        BridgeEvent::Safety { .. } => (Subject::Bridge, 14),
        BridgeEvent::PortLost { bus } | BridgeEvent::PortBack { bus } => {
            (Subject::Bus(bus.clone()), 11)
        }
    }
}

/// The flood guard. Each kind of event (per servo, per bus) is sent at most once per hold-off. Events
/// that arrive inside the hold-off are counted; when it ends, the latest of them is sent (with
/// the count) if it differs from the last one sent, so the operator always ends up seeing the
/// current state: a servo that flaps lost/back/lost is reported lost, not back.
#[derive(Debug)]
pub struct Throttle {
    hold_off: Duration,
    slots: HashMap<(Subject, u8), Slot>,
}

#[derive(Debug)]
struct Slot {
    sent_at: Instant,
    last_sent: BridgeEvent,
    pending: Option<BridgeEvent>,
    held: u32,
}

impl Throttle {
    pub fn new(hold_off: Duration) -> Self {
        Self {
            hold_off,
            slots: HashMap::new(),
        }
    }

    /// Whether to send `event` now; `Some(n)`: send it, noting `n` events held back before it.
    pub fn admit(&mut self, event: &BridgeEvent, now: Instant) -> Option<u32> {
        let key = kind(event);
        match self.slots.get_mut(&key) {
            Some(slot) if now.duration_since(slot.sent_at) < self.hold_off => {
                slot.held += 1;
                slot.pending = Some(event.clone());
                None
            }
            Some(slot) => {
                let folded = slot.held;
                *slot = Slot {
                    sent_at: now,
                    last_sent: event.clone(),
                    pending: None,
                    held: 0,
                };
                Some(folded)
            }
            None => {
                self.slots.insert(
                    key,
                    Slot {
                        sent_at: now,
                        last_sent: event.clone(),
                        pending: None,
                        held: 0,
                    },
                );
                Some(0)
            }
        }
    }

    /// Held-back events whose hold-off has ended and that change what the operator last saw.
    pub fn due(&mut self, now: Instant) -> Vec<(BridgeEvent, u32)> {
        let mut out = Vec::new();
        for slot in self.slots.values_mut() {
            if now.duration_since(slot.sent_at) < self.hold_off {
                continue;
            }
            if let Some(pending) = slot.pending.take() {
                if pending != slot.last_sent {
                    out.push((pending.clone(), slot.held.saturating_sub(1)));
                    slot.last_sent = pending;
                    slot.sent_at = now;
                }
                slot.held = 0;
            }
        }
        out
    }

    /// When [`Throttle::due`] may next have something.
    pub fn next_deadline(&self) -> Option<Instant> {
        self.slots
            .values()
            .filter(|s| s.pending.is_some())
            .map(|s| s.sent_at + self.hold_off)
            .min()
    }
}

/// The text with the number of held-back repeats appended, within the 50 characters.
pub fn with_folded(text: String, folded: u32) -> String {
    if folded == 0 {
        text
    } else {
        let suffix = format!(" (+{folded})");
        let mut t = fit(text);
        while t.len() + suffix.len() > MAX_TEXT {
            t.pop();
        }
        t + &suffix
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn alarm(on: bool) -> BridgeEvent {
        BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureAlarm {
                on,
                reading: Some(TemperatureReading {
                    celsius: 76,
                    age: Duration::from_millis(30),
                }),
            },
        }
    }

    #[test]
    fn severities_follow_the_mavlink_conventions() {
        let sev = |e: &BridgeEvent| describe(e, "x").0;
        assert_eq!(sev(&alarm(true)), MavSeverity::MAV_SEVERITY_WARNING);
        assert_eq!(
            sev(&BridgeEvent::Servo {
                servo: 0,
                event: ServoEvent::TemperatureError {
                    last_read: Some(TemperatureReading {
                        celsius: 85,
                        age: Duration::from_millis(400)
                    })
                }
            }),
            MavSeverity::MAV_SEVERITY_CRITICAL
        );
        assert_eq!(
            sev(&BridgeEvent::Servo {
                servo: 0,
                event: ServoEvent::Lost
            }),
            MavSeverity::MAV_SEVERITY_CRITICAL
        );
        assert_eq!(
            sev(&BridgeEvent::Servo {
                servo: 0,
                event: ServoEvent::Back
            }),
            MavSeverity::MAV_SEVERITY_NOTICE
        );
        assert_eq!(
            sev(&BridgeEvent::FailsafeEntered { timeout_ms: 500 }),
            MavSeverity::MAV_SEVERITY_WARNING
        );
    }

    #[test]
    fn texts_fit_in_50_characters() {
        let long_name = "a_very_long_servo_name_that_goes_on_and_on_forever";
        let (_, t) = describe(
            &BridgeEvent::Servo {
                servo: 0,
                event: ServoEvent::TemperatureError {
                    last_read: Some(TemperatureReading {
                        celsius: 85,
                        age: Duration::from_millis(400),
                    }),
                },
            },
            long_name,
        );
        assert!(t.len() <= MAX_TEXT);
        assert!(with_folded(t, 12).ends_with(" (+12)"));
    }

    fn overheat(last_read: Option<TemperatureReading>) -> BridgeEvent {
        BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureError { last_read },
        }
    }

    #[test]
    fn an_overheat_quotes_the_last_reading_with_its_age_not_as_the_present_temperature() {
        // The flag may arrive in a reply without a temperature: the reading quoted is older
        // than the event, and the text says how much older.
        let reading = TemperatureReading {
            celsius: 80,
            age: Duration::from_millis(430),
        };
        let (_, text) = describe(&overheat(Some(reading)), "rudder");
        assert_eq!(text, "rudder: overheat, force off; 80C 0.4s ago");
        let (_, text) = describe(&overheat(Some(reading)), "aileron_right");
        assert_eq!(text, "aileron_right: overheat, force off; 80C 0.4s ago");
    }

    #[test]
    fn a_temperature_alarm_quotes_its_reading_with_its_age_too() {
        let alarm = |on, reading| BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureAlarm { on, reading },
        };
        let read = |celsius, ms| {
            Some(TemperatureReading {
                celsius,
                age: Duration::from_millis(ms),
            })
        };
        // Read right after the flag (the bus master waits for that read) ...
        let (sev, text) = describe(&alarm(true, read(86, 10)), "rudder");
        assert_eq!(sev, MavSeverity::MAV_SEVERITY_WARNING);
        assert_eq!(text, "rudder: temperature alarm; 86C 0.0s ago");
        // ... or not, and then the age says the reading is older than the alarm.
        let (_, text) = describe(&alarm(true, read(80, 430)), "aileron_right");
        assert_eq!(text, "aileron_right: temperature alarm; 80C 0.4s ago");
        let (_, text) = describe(&alarm(true, None), "rudder");
        assert_eq!(text, "rudder: temperature alarm");
        let (sev, text) = describe(&alarm(false, None), "rudder");
        assert_eq!(sev, MavSeverity::MAV_SEVERITY_NOTICE);
        assert_eq!(text, "rudder: temperature ok");
    }

    #[test]
    fn an_overheat_without_a_fresh_reading_quotes_no_temperature() {
        let (_, text) = describe(&overheat(None), "rudder");
        assert_eq!(text, "rudder: overheat, force off");
    }

    fn replies(servo: usize, event: ServoEvent) -> BridgeEvent {
        BridgeEvent::Servo { servo, event }
    }

    #[test]
    fn a_degraded_servo_is_a_warning_with_its_share_and_its_recovery_an_info() {
        let (sev, text) = describe(
            &replies(0, ServoEvent::RepliesDegraded { percent: 23 }),
            "rudder",
        );
        assert_eq!(sev, MavSeverity::MAV_SEVERITY_WARNING);
        assert_eq!(text, "rudder: degraded, 23% replies bad");
        let (sev, text) = describe(&replies(0, ServoEvent::RepliesOk), "rudder");
        assert_eq!(sev, MavSeverity::MAV_SEVERITY_INFO);
        assert_eq!(text, "rudder: replies ok");
        // A long name still leaves room for the share and a count of folded repeats.
        let (_, text) = describe(
            &replies(0, ServoEvent::RepliesDegraded { percent: 100 }),
            "aileron_right_outboard",
        );
        assert_eq!(text, "aileron_right_outboard: degraded, 100% replies bad");
        assert!(with_folded(text, 3).len() <= MAX_TEXT);
    }

    #[test]
    fn degraded_and_ok_of_one_servo_fold_like_lost_and_back() {
        let t0 = Instant::now();
        let s = Duration::from_secs;
        let mut th = Throttle::new(s(5));
        let degraded = replies(0, ServoEvent::RepliesDegraded { percent: 20 });
        let ok = replies(0, ServoEvent::RepliesOk);
        assert_eq!(th.admit(&degraded, t0), Some(0));
        assert_eq!(th.admit(&ok, t0 + s(1)), None);
        assert_eq!(th.admit(&degraded, t0 + s(2)), None);
        // Another servo is not held back by it.
        assert_eq!(
            th.admit(&replies(1, ServoEvent::RepliesDegraded { percent: 30 }), t0),
            Some(0)
        );
        // The latest state equals the one sent: nothing more.
        assert!(th.due(t0 + s(5)).is_empty());
    }

    #[test]
    fn a_flapping_event_is_sent_once_per_hold_off_and_ends_on_the_latest_state() {
        let t0 = Instant::now();
        let s = Duration::from_secs;
        let mut th = Throttle::new(s(5));
        let lost = BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::Lost,
        };
        let back = BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::Back,
        };
        assert_eq!(th.admit(&lost, t0), Some(0));
        assert_eq!(th.admit(&back, t0 + s(1)), None);
        assert_eq!(th.admit(&lost, t0 + s(2)), None);
        assert!(th.due(t0 + s(4)).is_empty(), "hold-off not over yet");
        // The latest held event (lost) equals the last one sent: nothing to correct.
        assert!(th.due(t0 + s(5)).is_empty());
        // The hold-off is over: the next event goes out at once ...
        assert_eq!(th.admit(&back, t0 + s(6)), Some(0));
        // ... and one inside the new hold-off is sent when it ends, since it changes the state.
        assert_eq!(th.admit(&lost, t0 + s(7)), None);
        assert_eq!(th.next_deadline(), Some(t0 + s(11)));
        assert!(th.due(t0 + s(10)).is_empty());
        assert_eq!(th.due(t0 + s(11)), vec![(lost.clone(), 0)]);
        assert_eq!(th.next_deadline(), None);
    }

    #[test]
    fn different_servos_and_kinds_do_not_hold_each_other_back() {
        let t0 = Instant::now();
        let mut th = Throttle::new(Duration::from_secs(5));
        assert!(th.admit(&alarm(true), t0).is_some());
        let other = BridgeEvent::Servo {
            servo: 1,
            event: ServoEvent::TemperatureAlarm {
                on: true,
                reading: None,
            },
        };
        assert!(th.admit(&other, t0).is_some());
        let err = BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureError {
                last_read: Some(TemperatureReading {
                    celsius: 85,
                    age: Duration::from_millis(400),
                }),
            },
        };
        assert!(th.admit(&err, t0).is_some());
    }

    #[test]
    fn each_bus_has_its_own_hold_off() {
        let t0 = Instant::now();
        let mut th = Throttle::new(Duration::from_secs(5));
        let lost = |bus: &str| BridgeEvent::PortLost { bus: bus.into() };
        // Three adapters unplugged at once: the operator reads each of them.
        for bus in ["wing", "tail", "gear"] {
            assert_eq!(th.admit(&lost(bus), t0), Some(0), "{bus}");
        }
        // The same bus again within the hold-off is held back.
        assert_eq!(th.admit(&lost("wing"), t0 + Duration::from_secs(1)), None);
    }
}

//! What the bridge sends of its own: HEARTBEAT, the servos' telemetry (NAMED_VALUE_FLOAT,
//! ESC_INFO, ESC_STATUS) and event STATUSTEXTs, driven through the sans-IO core at exact instants.

mod mavlink_support;

use lj9da_bridge::config::Config;
use lj9da_bridge::mavlink::{
    BridgeCore, BridgeEvent, ServoEvent, ServoReport, ServoState, TemperatureReading,
};
use mavlink::MavHeader;
use mavlink::dialects::common::*;
use mavlink_support::{AP, MAPPING, autopilot_heartbeat, header, messages, running, statustexts};
use std::time::{Duration, Instant};

#[test]
fn heartbeat_goes_out_once_a_second_with_the_worst_servo_state() {
    let t0 = Instant::now();
    let mut c = running(t0);
    let ok = ServoReport {
        state: Some(ServoState::Online),
        position_mm: Some(0.0),
        current_a: Some(0.07),
        temperature_c: Some(30.0),
        voltage_v: Some(12.0),
        ..Default::default()
    };
    let lost = ServoReport {
        state: Some(ServoState::Offline),
        ..Default::default()
    };
    let mut heartbeats = Vec::new();
    for ms in (0..=3000).step_by(10) {
        c.handle_timeout(t0 + Duration::from_millis(ms), &[ok, ok, lost]);
        for o in messages(&mut c) {
            if let MavMessage::HEARTBEAT(h) = o.message {
                heartbeats.push(h);
            }
        }
    }
    assert_eq!(heartbeats.len(), 4, "at 0, 1, 2 and 3 s");
    assert!(
        heartbeats
            .iter()
            .all(|h| h.mavtype == MavType::MAV_TYPE_SERVO
                && h.autopilot == MavAutopilot::MAV_AUTOPILOT_INVALID
                && h.system_status == MavState::MAV_STATE_EMERGENCY)
    );
}

fn online(position_mm: f32) -> ServoReport {
    ServoReport {
        state: Some(ServoState::Online),
        position_mm: Some(position_mm),
        current_a: Some(0.06),
        temperature_c: Some(45.0),
        voltage_v: Some(11.1),
        ..Default::default()
    }
}

/// Every message the core sends in `seconds`, called every 5 ms with `report(ms)` for each of
/// its `servos`.
fn sent_for(
    c: &mut BridgeCore,
    t0: Instant,
    seconds: u64,
    servos: usize,
    report: impl Fn(u64) -> ServoReport,
) -> Vec<MavMessage> {
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    let mut out = Vec::new();
    for ms in (0..seconds * 1000).step_by(5) {
        let r = report(ms);
        c.handle_timeout(t0 + Duration::from_millis(ms), &vec![r; servos]);
        out.extend(messages(c).into_iter().map(|o| o.message));
    }
    out
}

fn named(out: &[MavMessage]) -> Vec<(String, f32)> {
    out.iter()
        .filter_map(|m| match m {
            MavMessage::NAMED_VALUE_FLOAT(v) => {
                Some((v.name.to_str().unwrap().to_string(), v.value))
            }
            _ => None,
        })
        .collect()
}

#[test]
fn named_values_go_out_when_they_change_and_are_refreshed_every_5_s() {
    let t0 = Instant::now();
    let mut c = running(t0);
    // rate_hz = 5: looked at every 200 ms. Only the left aileron's position changes.
    let out = sent_for(&mut c, t0, 10, 3, |ms| {
        online(-12.0 + (ms / 200) as f32 * 0.01)
    });
    let names = named(&out);
    let count = |name: &str| names.iter().filter(|(n, _)| n == name).count();
    assert_eq!(count("ail_l_pos"), 50, "changed at every look, 5 Hz × 10 s");
    assert_eq!(
        count("ail_l_tmp"),
        2,
        "unchanged: at 0 s and refreshed at 5 s"
    );
    assert_eq!(count("gear_vlt"), 2);
    assert!(names.contains(&("gear_tmp".to_string(), 45.0)));
}

#[test]
fn each_esc_carrier_has_its_own_rate_and_esc_info_defaults_to_1_hz() {
    let t0 = Instant::now();
    let mapping = MAPPING.replace("[telemetry]", "[telemetry]\nesc_status_hz = 2");
    let mut c = BridgeCore::new(Config::parse(&mapping, "t.toml").unwrap(), t0);
    let out = sent_for(&mut c, t0, 10, 3, |_| online(0.0));
    let info = out
        .iter()
        .filter(|m| matches!(m, MavMessage::ESC_INFO(_)))
        .count();
    let status = out
        .iter()
        .filter(|m| matches!(m, MavMessage::ESC_STATUS(_)))
        .count();
    assert_eq!(
        (info, status),
        (10, 20),
        "1 Hz and 2 Hz × 1 block of four, 10 s"
    );
}

#[test]
fn a_servo_going_offline_sends_esc_info_at_the_next_look_not_a_second_later() {
    let t0 = Instant::now();
    let mut c = running(t0);
    // rate_hz = 5: looks every 200 ms; ESC_INFO at 1 Hz.
    let out = sent_for(&mut c, t0, 2, 3, |_| online(0.0));
    let before = out
        .iter()
        .filter(|m| matches!(m, MavMessage::ESC_INFO(_)))
        .count();
    assert_eq!(before, 2, "1 Hz: at 0 and 1 s");
    let lost = ServoReport {
        state: Some(ServoState::Offline),
        ..Default::default()
    };
    // The second servo is lost at 2.1 s: the look then (due since 2.0 s) sends ESC_INFO,
    // whose own turn would be at 3 s.
    let reports = [online(0.0), lost, online(0.0)];
    c.handle_timeout(t0 + Duration::from_millis(2100), &reports);
    let info: Vec<u8> = messages(&mut c)
        .into_iter()
        .filter_map(|o| match o.message {
            MavMessage::ESC_INFO(i) => Some(i.info),
            _ => None,
        })
        .collect();
    assert_eq!(info, vec![0b101], "servo 2 offline, sent at once");
}

#[test]
fn esc_indexes_start_clear_of_the_motor_escs_unless_the_mapping_says() {
    let index = |mapping: &str| {
        let t0 = Instant::now();
        let mut c = BridgeCore::new(Config::parse(mapping, "t.toml").unwrap(), t0);
        let out = sent_for(&mut c, t0, 1, 3, |_| online(0.0));
        out.iter()
            .filter_map(|m| match m {
                MavMessage::ESC_INFO(i) => Some(("info", i.index)),
                MavMessage::ESC_STATUS(s) => Some(("status", s.index)),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(index(MAPPING), vec![("info", 16), ("status", 16)]);
    let at_zero = MAPPING.replace("[telemetry]", "[telemetry]\nesc_index_base = 0");
    assert_eq!(index(&at_zero), vec![("info", 0), ("status", 0)]);
}

#[test]
fn the_mapping_chooses_the_named_quantities() {
    let mapping = MAPPING.replace(
        "[telemetry]",
        "[telemetry]\nnamed_values = [\"tmp\", \"pos\"]",
    );
    assert_eq!(
        names_sent_in_3_s(&mapping),
        [
            "ail_l_pos",
            "ail_l_tmp",
            "ail_r_pos",
            "ail_r_tmp",
            "gear_pos",
            "gear_tmp"
        ]
    );
}

#[test]
fn a_servo_with_a_list_of_its_own_sends_that_list_and_the_others_the_telemetry_list() {
    let mapping = MAPPING
        .replace("[telemetry]", "[telemetry]\nnamed_values = []")
        .replace(
            "label = \"ail_r\"",
            "label = \"ail_r\"\nnamed_values = [\"cur\", \"pos\"]",
        );
    assert_eq!(names_sent_in_3_s(&mapping), ["ail_r_cur", "ail_r_pos"]);
}

/// The NAMED_VALUE_FLOAT names a bridge with `mapping` sends in its first 3 s, servos online
/// and still (each value once: unchanged values are sent again only after 5 s), sorted.
fn names_sent_in_3_s(mapping: &str) -> Vec<String> {
    let t0 = Instant::now();
    let mut c = BridgeCore::new(Config::parse(mapping, "t.toml").unwrap(), t0);
    let mut names: Vec<String> = named(&sent_for(&mut c, t0, 1, 3, |_| online(0.0)))
        .into_iter()
        .map(|(n, _)| n)
        .collect();
    names.sort();
    names
}

/// Bytes on the wire of MAVLink 2 frames.
fn wire_bytes(out: &[MavMessage]) -> usize {
    let header = MavHeader::default();
    out.iter()
        .map(|m| {
            let mut buf = Vec::new();
            mavlink::write_v2_msg(&mut buf, header, m).unwrap();
            buf.len()
        })
        .sum()
}

#[test]
fn default_telemetry_of_four_moving_servos_fits_a_tenth_of_a_57600_baud_radio() {
    // 57 600 baud = 5 760 bytes/s, shared with all of the autopilot's own telemetry.
    let mapping = lj9da_bridge::config::SITL_DEFAULT_TOML;
    let t0 = Instant::now();
    let mut c = BridgeCore::new(Config::parse(mapping, "t.toml").unwrap(), t0);
    let servos = c_servos(mapping);
    // Worst case: every value changes all the time.
    let out = sent_for(&mut c, t0, 60, servos, |ms| ServoReport {
        current_a: Some(0.01 * (ms % 97) as f32),
        temperature_c: Some(40.0 + (ms % 13) as f32),
        voltage_v: Some(11.0 + 0.01 * (ms % 7) as f32),
        ..online(0.01 * (ms % 1000) as f32)
    });
    // The servos' states (for the autopilot's script, `servo_state = false` without one) are
    // counted apart: 30 bytes per servo per second.
    let (states, rest): (Vec<MavMessage>, Vec<MavMessage>) = out
        .into_iter()
        .partition(|m| matches!(m, MavMessage::NAMED_VALUE_INT(_)));
    let per_s = wire_bytes(&rest) / 60;
    let states_per_s = wire_bytes(&states) / 60;
    println!(
        "default telemetry, {servos} servos, every value changing: {per_s} bytes/s, and the \
         servo states {states_per_s} bytes/s"
    );
    assert!(per_s <= 576, "{per_s} bytes/s");
    assert!(
        states_per_s <= 30 * servos,
        "servo states: {states_per_s} bytes/s for {servos} servos"
    );
}

fn c_servos(mapping: &str) -> usize {
    Config::parse(mapping, "t.toml").unwrap().servos.len()
}

#[test]
fn events_become_one_statustext_each() {
    let t0 = Instant::now();
    let mut c = running(t0);
    messages(&mut c);
    c.event(
        BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureAlarm {
                on: true,
                reading: Some(TemperatureReading {
                    celsius: 76,
                    age: Duration::from_millis(20),
                }),
            },
        },
        t0,
    );
    c.event(
        BridgeEvent::Servo {
            servo: 0,
            event: ServoEvent::TemperatureError {
                last_read: Some(TemperatureReading {
                    celsius: 85,
                    age: Duration::from_millis(400),
                }),
            },
        },
        t0,
    );
    let texts = statustexts(&messages(&mut c));
    assert_eq!(
        texts,
        vec![
            (
                MavSeverity::MAV_SEVERITY_WARNING,
                "aileron_left: temperature alarm; 76C 0.0s ago".to_string()
            ),
            (
                MavSeverity::MAV_SEVERITY_CRITICAL,
                "aileron_left: overheat, force off; 85C 0.4s ago".to_string()
            ),
        ]
    );
}

/// The servo states sent (NAMED_VALUE_INT `LJ9_<label>`) up to `to_ms`, in ms from `t0`; the
/// core is called every 5 ms with `reports(ms)`, and given an output message every 20 ms
/// while `outputs_until_ms` has not passed.
fn states(
    c: &mut BridgeCore,
    t0: Instant,
    to_ms: u64,
    outputs_until_ms: u64,
    reports: impl Fn(u64) -> Vec<ServoReport>,
) -> Vec<(u64, String, i32)> {
    let mut out = Vec::new();
    for ms in (0..to_ms).step_by(5) {
        let now = t0 + Duration::from_millis(ms);
        if ms % 20 == 0 && ms < outputs_until_ms {
            c.handle_message(
                0,
                &header(AP),
                &mavlink_support::outputs(0, &[(1, 1520), (9, 1520)]),
                now,
            );
            mavlink_support::commands(c);
        }
        c.handle_timeout(now, &reports(ms));
        for o in messages(c) {
            if let MavMessage::NAMED_VALUE_INT(v) = o.message {
                out.push((ms, v.name.to_str().unwrap().to_string(), v.value));
            }
        }
    }
    out
}

fn state_of(sent: &[(u64, String, i32)], name: &str) -> Vec<(u64, i32)> {
    sent.iter()
        .filter(|(_, n, _)| n == name)
        .map(|(ms, _, v)| (*ms, *v))
        .collect()
}

#[test]
fn each_servo_state_goes_out_every_second_and_a_change_within_100_ms() {
    let t0 = Instant::now();
    let mut c = running(t0);
    // The outputs keep coming (no failsafe); the gear's replies stop at 2.3 s.
    let lost = ServoReport {
        state: Some(ServoState::Offline),
        ..Default::default()
    };
    let sent = states(&mut c, t0, 4000, 4000, |ms| {
        let gear = if ms >= 2300 { lost } else { online(0.0) };
        vec![online(0.0), online(0.0), gear]
    });
    assert_eq!(
        state_of(&sent, "LJ9_ail_l"),
        vec![(0, 0), (1000, 0), (2000, 0), (3000, 0)],
        "all well, once a second: {sent:?}"
    );
    let gear = state_of(&sent, "LJ9_gear");
    let first_lost = gear
        .iter()
        .find(|(_, v)| *v != 0)
        .expect("the lost servo said");
    assert!(
        (2300..=2400).contains(&first_lost.0),
        "the change went out at {} ms, not within 100 ms of 2300: {gear:?}",
        first_lost.0
    );
    assert_eq!(first_lost.1, 1, "offline: {gear:?}");
}

#[test]
fn a_servo_state_says_each_trouble_in_its_own_bit() {
    let t0 = Instant::now();
    let mut c = running(t0);
    let hot_and_stalled = ServoReport {
        temperature_alarm: true,
        stalled: true,
        ..online(0.0)
    };
    let starting = ServoReport::default();
    let stale = ServoReport {
        state: Some(ServoState::Stale),
        ..online(0.0)
    };
    // The outputs stop at 1 s: failsafe after the mapping's 500 ms.
    let sent = states(&mut c, t0, 2600, 1000, |_| {
        vec![hot_and_stalled, starting, stale]
    });
    assert_eq!(state_of(&sent, "LJ9_ail_l")[0], (0, 4 | 8), "{sent:?}");
    assert_eq!(state_of(&sent, "LJ9_ail_r")[0], (0, 2), "{sent:?}");
    assert_eq!(state_of(&sent, "LJ9_gear")[0], (0, 32), "{sent:?}");
    let failsafe = state_of(&sent, "LJ9_gear")
        .into_iter()
        .find(|(_, v)| v & 16 != 0)
        .expect("failsafe said");
    assert!(
        (1500..=1700).contains(&failsafe.0),
        "failsafe at {failsafe:?}: {sent:?}"
    );
}

#[test]
fn servo_states_can_be_turned_off() {
    let t0 = Instant::now();
    let mapping = MAPPING.replace("[telemetry]", "[telemetry]\nservo_state = false");
    let mut c = BridgeCore::new(Config::parse(&mapping, "t.toml").unwrap(), t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    let sent = states(&mut c, t0, 3000, 3000, |_| vec![online(0.0); 3]);
    assert!(sent.is_empty(), "{sent:?}");
}

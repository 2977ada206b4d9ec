//! The messages that carry servo health to the ground station (bridge-design.md, "What the
//! operator sees"): HEARTBEAT, NAMED_VALUE_FLOAT, ESC_INFO + ESC_STATUS, STATUSTEXT.

use super::health::{ServoReport, ServoState};
use crate::config::Quantity;
use mavlink::dialects::common::{
    ESC_INFO_DATA, ESC_STATUS_DATA, EscConnectionType, EscFailureFlags, HEARTBEAT_DATA,
    MavAutopilot, MavMessage, MavModeFlag, MavSeverity, MavState, MavType, NAMED_VALUE_FLOAT_DATA,
    NAMED_VALUE_INT_DATA, STATUSTEXT_DATA,
};

/// NAMED_VALUE_FLOAT names have at most 10 characters.
pub const MAX_NAME: usize = 10;

/// The bridge's HEARTBEAT: a servo component of the vehicle, with the worst servo's state.
pub fn heartbeat(system_status: MavState) -> MavMessage {
    MavMessage::HEARTBEAT(HEARTBEAT_DATA {
        custom_mode: 0,
        mavtype: MavType::MAV_TYPE_SERVO,
        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
        base_mode: MavModeFlag::empty(),
        system_status,
        mavlink_version: 3,
    })
}

/// System status from the servos: standby until any servo is driven, active when all are
/// well, critical when one is stale, alarmed, stalled or in failsafe, emergency when one is
/// lost or has switched its force off.
pub fn system_status<'a>(
    reports: impl IntoIterator<Item = &'a ServoReport>,
    failsafe: bool,
) -> MavState {
    let mut status = MavState::MAV_STATE_ACTIVE;
    let mut any_started = false;
    let rank = |s: MavState| match s {
        MavState::MAV_STATE_STANDBY => 0,
        MavState::MAV_STATE_ACTIVE => 1,
        MavState::MAV_STATE_CRITICAL => 2,
        _ => 3,
    };
    let worsen = |s: MavState, status: &mut MavState| {
        if rank(s) > rank(*status) {
            *status = s;
        }
    };
    for r in reports {
        let s = match r.state() {
            ServoState::Online => {
                any_started = true;
                MavState::MAV_STATE_ACTIVE
            }
            ServoState::Starting => MavState::MAV_STATE_STANDBY,
            ServoState::Stale => MavState::MAV_STATE_CRITICAL,
            ServoState::Offline | ServoState::Fault => MavState::MAV_STATE_EMERGENCY,
        };
        worsen(s, &mut status);
        if r.temperature_error {
            worsen(MavState::MAV_STATE_EMERGENCY, &mut status);
        } else if r.temperature_alarm || r.stalled {
            worsen(MavState::MAV_STATE_CRITICAL, &mut status);
        }
    }
    if failsafe {
        worsen(MavState::MAV_STATE_CRITICAL, &mut status);
    }
    if !any_started && status == MavState::MAV_STATE_ACTIVE {
        MavState::MAV_STATE_STANDBY
    } else {
        status
    }
}

/// The value of one quantity in a report, if it has been measured.
pub fn quantity(report: &ServoReport, q: Quantity) -> Option<f32> {
    match q {
        Quantity::Position => report.position_mm,
        Quantity::Current => report.current_a,
        Quantity::Temperature => report.temperature_c,
        Quantity::Voltage => report.voltage_v,
    }
}

/// One NAMED_VALUE_FLOAT named `<label>_<quantity>` (a label has at most 6 characters, so
/// every name fits MAVLink's 10).
pub fn named_value(label: &str, q: Quantity, value: f32, time_boot_ms: u32) -> MavMessage {
    let name = format!("{label}_{}", q.key());
    MavMessage::NAMED_VALUE_FLOAT(NAMED_VALUE_FLOAT_DATA {
        time_boot_ms,
        value,
        name: name.as_str().into(),
    })
}

/// NAMED_VALUE_FLOAT for each quantity of a servo that has been measured.
pub fn named_values(label: &str, report: &ServoReport, time_boot_ms: u32) -> Vec<MavMessage> {
    Quantity::ALL
        .into_iter()
        .filter_map(|q| Some(named_value(label, q, quantity(report, q)?, time_boot_ms)))
        .collect()
}

/// ESC_INFO and ESC_STATUS for every block of four servos, in that order per block, the first
/// servo at ESC index 0.
pub fn esc_blocks(reports: &[ServoReport], time_usec: u64, counter: u16) -> Vec<MavMessage> {
    esc_info_blocks(reports, 0, time_usec, counter)
        .into_iter()
        .zip(esc_status_blocks(reports, 0, time_usec))
        .flat_map(|(info, status)| [info, status])
        .collect()
}

/// The ESC index of each block of four servos from `base`; a block past index 255 is left out.
fn block_indexes(reports: &[ServoReport], base: u8) -> impl Iterator<Item = (u8, &[ServoReport])> {
    reports
        .chunks(4)
        .enumerate()
        .filter_map(move |(block, chunk)| {
            let index = u8::try_from(usize::from(base) + block * 4).ok()?;
            Some((index, chunk))
        })
}

/// ESC_INFO for every block of four servos, the first servo at ESC index `base`.
pub fn esc_info_blocks(
    reports: &[ServoReport],
    base: u8,
    time_usec: u64,
    counter: u16,
) -> Vec<MavMessage> {
    let count = reports.len().min(u8::MAX as usize) as u8;
    let mut out = Vec::new();
    for (index, chunk) in block_indexes(reports, base) {
        let mut info = ESC_INFO_DATA {
            time_usec,
            counter,
            index,
            count,
            connection_type: EscConnectionType::ESC_CONNECTION_TYPE_SERIAL,
            temperature: [i16::MAX; 4],
            ..Default::default()
        };
        for (i, r) in chunk.iter().enumerate() {
            if r.online() {
                info.info |= 1 << i;
            }
            info.error_count[i] = r.error_count;
            info.failure_flags[i] = failure_flags(r).bits();
            if let Some(t) = r.temperature_c {
                info.temperature[i] = (t * 100.0)
                    .round()
                    .clamp(f32::from(i16::MIN), f32::from(i16::MAX - 1))
                    as i16;
            }
        }
        out.push(MavMessage::ESC_INFO(info));
    }
    out
}

/// ESC_STATUS for every block of four servos, the first servo at ESC index `base`.
pub fn esc_status_blocks(reports: &[ServoReport], base: u8, time_usec: u64) -> Vec<MavMessage> {
    block_indexes(reports, base)
        .map(|(index, chunk)| {
            let mut status = ESC_STATUS_DATA {
                time_usec,
                index,
                ..Default::default()
            };
            for (i, r) in chunk.iter().enumerate() {
                status.voltage[i] = r.voltage_v.unwrap_or(0.0);
                status.current[i] = r.current_a.unwrap_or(0.0);
            }
            MavMessage::ESC_STATUS(status)
        })
        .collect()
}

/// ESC failure flags of a servo: over-temperature for the alarm and the error, stuck for a
/// stall, generic for a servo that is lost or unusable.
pub fn failure_flags(r: &ServoReport) -> EscFailureFlags {
    let mut f = EscFailureFlags::empty();
    if r.temperature_alarm || r.temperature_error {
        f |= EscFailureFlags::ESC_FAILURE_OVER_TEMPERATURE;
    }
    if r.stalled {
        f |= EscFailureFlags::ESC_FAILURE_MOTOR_STUCK;
    }
    if matches!(r.state(), ServoState::Offline | ServoState::Fault) {
        f |= EscFailureFlags::ESC_FAILURE_GENERIC;
    }
    f
}

/// A servo's state as the bits of its NAMED_VALUE_INT `LJ9_<label>` (0: all well), for an
/// autopilot's script to refuse arming or act on (`packaging/ardupilot/lj9da.lua`). The bits
/// are a published interface (`docs/autopilot.md`): never renumbered, only added to.
pub mod state_bit {
    /// Not answering, or answering but unusable (wrong model, force off by its temperature
    /// limit).
    pub const OFFLINE: i32 = 1;
    /// Has not answered yet since the bridge started.
    pub const STARTING: i32 = 2;
    /// Temperature alarm or error.
    pub const OVER_TEMPERATURE: i32 = 4;
    /// Stalled: far from its goal while pushing.
    pub const STALLED: i32 = 8;
    /// It holds its failsafe position: its output stopped coming from the autopilot.
    pub const FAILSAFE: i32 = 16;
    /// Answering, but its latest replies are missing.
    pub const STALE: i32 = 32;
}

/// The prefix of a servo's state name: `LJ9_` and a label of at most 6 characters fit
/// NAMED_VALUE_INT's 10.
pub const STATE_PREFIX: &str = "LJ9_";

/// The bits of [`state_bit`] that hold for a servo (`failsafe`: it holds its failsafe position).
pub fn state_bits(r: &ServoReport, failsafe: bool) -> i32 {
    let mut bits = match r.state() {
        ServoState::Online => 0,
        ServoState::Starting => state_bit::STARTING,
        ServoState::Stale => state_bit::STALE,
        ServoState::Offline | ServoState::Fault => state_bit::OFFLINE,
    };
    if r.temperature_alarm || r.temperature_error {
        bits |= state_bit::OVER_TEMPERATURE;
    }
    if r.stalled {
        bits |= state_bit::STALLED;
    }
    if failsafe {
        bits |= state_bit::FAILSAFE;
    }
    bits
}

/// One servo's state: NAMED_VALUE_INT `LJ9_<label>` with [`state_bits`].
pub fn servo_state(label: &str, bits: i32, time_boot_ms: u32) -> MavMessage {
    let name = format!("{STATE_PREFIX}{label}");
    MavMessage::NAMED_VALUE_INT(NAMED_VALUE_INT_DATA {
        time_boot_ms,
        value: bits,
        name: name.as_str().into(),
    })
}

pub fn statustext(severity: MavSeverity, text: &str) -> MavMessage {
    MavMessage::STATUSTEXT(STATUSTEXT_DATA {
        severity,
        text: text.into(),
        id: 0,
        chunk_seq: 0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn online(temp: f32) -> ServoReport {
        ServoReport {
            state: Some(ServoState::Online),
            position_mm: Some(1.5),
            current_a: Some(0.26),
            temperature_c: Some(temp),
            voltage_v: Some(12.0),
            ..Default::default()
        }
    }

    #[test]
    fn heartbeat_is_a_servo_with_no_autopilot() {
        let MavMessage::HEARTBEAT(h) = heartbeat(MavState::MAV_STATE_ACTIVE) else {
            panic!()
        };
        assert_eq!(h.mavtype, MavType::MAV_TYPE_SERVO);
        assert_eq!(h.autopilot, MavAutopilot::MAV_AUTOPILOT_INVALID);
    }

    #[test]
    fn system_status_is_the_worst_servo() {
        let ok = online(30.0);
        let alarm = ServoReport {
            temperature_alarm: true,
            ..ok
        };
        let lost = ServoReport {
            state: Some(ServoState::Offline),
            ..ok
        };
        assert_eq!(system_status([&ok, &ok], false), MavState::MAV_STATE_ACTIVE);
        assert_eq!(
            system_status([&ok, &alarm], false),
            MavState::MAV_STATE_CRITICAL
        );
        assert_eq!(
            system_status([&alarm, &lost], false),
            MavState::MAV_STATE_EMERGENCY
        );
        assert_eq!(system_status([&ok], true), MavState::MAV_STATE_CRITICAL);
        assert_eq!(
            system_status([&ServoReport::default()], false),
            MavState::MAV_STATE_STANDBY
        );
    }

    #[test]
    fn named_values_fit_ten_characters() {
        let msgs = named_values("ail_lx", &online(41.0), 5);
        let names: Vec<String> = msgs
            .iter()
            .map(|m| match m {
                MavMessage::NAMED_VALUE_FLOAT(v) => v.name.to_str().unwrap().to_string(),
                _ => panic!("only NAMED_VALUE_FLOAT"),
            })
            .collect();
        assert_eq!(
            names,
            ["ail_lx_pos", "ail_lx_cur", "ail_lx_tmp", "ail_lx_vlt"]
        );
        assert!(names.iter().all(|n| n.len() <= MAX_NAME));
    }

    #[test]
    fn esc_messages_come_in_blocks_of_four_with_online_bits_and_flags() {
        let mut reports = vec![online(40.0); 5];
        reports[1].state = Some(ServoState::Offline);
        reports[2].stalled = true;
        reports[4].temperature_error = true;
        let msgs = esc_blocks(&reports, 1, 7);
        assert_eq!(msgs.len(), 4);
        let MavMessage::ESC_INFO(first) = &msgs[0] else {
            panic!()
        };
        assert_eq!((first.index, first.count, first.info), (0, 5, 0b1101));
        assert_eq!(first.temperature[0], 4000, "cdegC");
        assert_eq!(
            first.failure_flags[1],
            EscFailureFlags::ESC_FAILURE_GENERIC.bits()
        );
        assert_eq!(
            first.failure_flags[2],
            EscFailureFlags::ESC_FAILURE_MOTOR_STUCK.bits()
        );
        let MavMessage::ESC_INFO(second) = &msgs[2] else {
            panic!()
        };
        assert_eq!((second.index, second.info), (4, 0b1));
        assert_eq!(
            second.failure_flags[0],
            EscFailureFlags::ESC_FAILURE_OVER_TEMPERATURE.bits()
        );
        assert_eq!(
            second.temperature[1],
            i16::MAX,
            "no fifth-block servo: not supplied"
        );
        let MavMessage::ESC_STATUS(s) = &msgs[1] else {
            panic!()
        };
        assert_eq!(s.voltage[0], 12.0);
        assert_eq!(s.current[3], 0.26);
    }
}

//! One servo's replies in which two status flags rise between full reads only: a temperature
//! alarm that comes and goes within the 50 ms between two full reads (seen by a motion
//! record at 20 ms), and a flash write error carried by two position records (rising at
//! 70 ms). Whoever counts alarms over them finds two.

use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Motion, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::RecordBody;

/// When the temperature alarm rises, in µs.
pub const ALARM_AT_US: u64 = 20_000;
/// When the flash write error rises, in µs.
pub const FLASH_ERROR_AT_US: u64 = 70_000;

/// The records of servo 0, with their times in µs, the last an end of the run.
pub fn flag_records() -> Vec<(u64, RecordBody)> {
    let telemetry = |flags| RecordBody::Telemetry {
        servo: 0,
        telemetry: Telemetry {
            present_position: MmCenti(0),
            present_time: Ms10(0),
            present_load: Ma10(30),
            present_temperature: Celsius(35),
            present_voltage: Mv10(1200),
        },
        flags: ReplyFlags(flags),
    };
    let motion = |flags| RecordBody::Motion {
        servo: 0,
        motion: Motion {
            present_position: MmCenti(0),
            present_time: Ms10(0),
            present_load: Ma10(30),
        },
        flags: ReplyFlags(flags),
    };
    let position = |flags| RecordBody::Position {
        servo: 0,
        position: MmCenti(0),
        flags: ReplyFlags(flags),
    };
    vec![
        (0, telemetry(0)),
        (ALARM_AT_US, motion(ReplyFlags::TEMPERATURE_ALARM)),
        (40_000, motion(0)),
        (50_000, telemetry(0)),
        (FLASH_ERROR_AT_US, position(ReplyFlags::FLASH_WRITE_ERROR)),
        // Still on: not a second alarm.
        (90_000, position(ReplyFlags::FLASH_WRITE_ERROR)),
        (100_000, telemetry(0)),
        (200_000, RecordBody::End { continued: false }),
    ]
}

//! Autopilot outputs as channel values: SERVO_OUTPUT_RAW (ArduPilot and PX4) and
//! ACTUATOR_OUTPUT_STATUS (PX4), both in µs.
//!
//! Channels are numbered 1–32 as the autopilots number their outputs: SERVO_OUTPUT_RAW with
//! `port = 0` carries 1–16 (9–16 are MAVLink 2 extension fields, read as 0 when a MAVLink 1
//! sender leaves them out), `port = 1` carries 17–32. ACTUATOR_OUTPUT_STATUS carries up to 32
//! outputs in one message.

use mavlink::dialects::common::{ACTUATOR_OUTPUT_STATUS_DATA, MavMessage, SERVO_OUTPUT_RAW_DATA};

/// The highest output channel an autopilot reports.
pub const MAX_CHANNEL: u8 = 32;

/// One output message turned into `(channel, µs)` pairs. Values are passed on as sent: 0 and
/// 65535 ("no output") are the mapping's business, not this decoder's.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ChannelValues {
    values: Vec<(u8, u16)>,
}

impl ChannelValues {
    pub fn iter(&self) -> impl Iterator<Item = (u8, u16)> + '_ {
        self.values.iter().copied()
    }

    /// The value of `channel`, if this message carries it.
    pub fn get(&self, channel: u8) -> Option<u16> {
        self.values
            .iter()
            .find(|(c, _)| *c == channel)
            .map(|(_, v)| *v)
    }

    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }
}

/// Channels of a SERVO_OUTPUT_RAW. A port above 1 carries no channel the bridge knows.
pub fn from_servo_output_raw(m: &SERVO_OUTPUT_RAW_DATA) -> ChannelValues {
    let raw = [
        m.servo1_raw,
        m.servo2_raw,
        m.servo3_raw,
        m.servo4_raw,
        m.servo5_raw,
        m.servo6_raw,
        m.servo7_raw,
        m.servo8_raw,
        m.servo9_raw,
        m.servo10_raw,
        m.servo11_raw,
        m.servo12_raw,
        m.servo13_raw,
        m.servo14_raw,
        m.servo15_raw,
        m.servo16_raw,
    ];
    if m.port > 1 {
        return ChannelValues::default();
    }
    let first = m.port * 16 + 1;
    ChannelValues {
        values: raw
            .iter()
            .enumerate()
            .map(|(i, v)| (first + i as u8, *v))
            .collect(),
    }
}

/// A SERVO_OUTPUT_RAW carrying `raw[0..16]` as the 16 channels of `port` (the inverse of
/// [`from_servo_output_raw`]); for the simulated autopilot, tests and benchmarks.
pub fn servo_output_raw(port: u8, raw: [u16; 16], time_usec: u32) -> MavMessage {
    MavMessage::SERVO_OUTPUT_RAW(SERVO_OUTPUT_RAW_DATA {
        time_usec,
        servo1_raw: raw[0],
        servo2_raw: raw[1],
        servo3_raw: raw[2],
        servo4_raw: raw[3],
        servo5_raw: raw[4],
        servo6_raw: raw[5],
        servo7_raw: raw[6],
        servo8_raw: raw[7],
        port,
        servo9_raw: raw[8],
        servo10_raw: raw[9],
        servo11_raw: raw[10],
        servo12_raw: raw[11],
        servo13_raw: raw[12],
        servo14_raw: raw[13],
        servo15_raw: raw[14],
        servo16_raw: raw[15],
    })
}

/// Channels of an ACTUATOR_OUTPUT_STATUS (values in µs for PWM outputs). PX4 fills `active`
/// with a count rather than the bitmask the spec defines; either reading is accepted: a
/// channel counts as present when its bit is set or its index is below the count. A value
/// that is not a finite number in 0–65535 is passed on as 0 ("no output").
pub fn from_actuator_output_status(m: &ACTUATOR_OUTPUT_STATUS_DATA) -> ChannelValues {
    let as_count = m.active.min(u32::from(MAX_CHANNEL));
    let values = m
        .actuator
        .iter()
        .enumerate()
        .filter(|(i, _)| (m.active >> i) & 1 == 1 || (*i as u32) < as_count)
        .map(|(i, v)| {
            let us = if v.is_finite() && (0.0..=65535.0).contains(v) {
                v.round() as u16
            } else {
                0
            };
            (i as u8 + 1, us)
        })
        .collect();
    ChannelValues { values }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn port_0_is_channels_1_to_16_and_port_1_is_17_to_32() {
        let mut m = SERVO_OUTPUT_RAW_DATA {
            servo1_raw: 1100,
            servo16_raw: 1900,
            ..Default::default()
        };
        let v = from_servo_output_raw(&m);
        assert_eq!(v.get(1), Some(1100));
        assert_eq!(v.get(16), Some(1900));
        assert_eq!(v.get(17), None);
        m.port = 1;
        let v = from_servo_output_raw(&m);
        assert_eq!(v.get(17), Some(1100));
        assert_eq!(v.get(32), Some(1900));
        assert_eq!(v.get(1), None);
        m.port = 2;
        assert!(from_servo_output_raw(&m).is_empty());
    }

    #[test]
    fn servo_output_raw_is_the_inverse_of_reading_it() {
        let raw: [u16; 16] = std::array::from_fn(|i| 1000 + i as u16);
        let MavMessage::SERVO_OUTPUT_RAW(m) = servo_output_raw(1, raw, 7) else {
            panic!("a SERVO_OUTPUT_RAW")
        };
        let v = from_servo_output_raw(&m);
        assert_eq!(
            v.iter().collect::<Vec<_>>(),
            (17..=32).zip(raw).collect::<Vec<_>>()
        );
    }

    #[test]
    fn actuator_output_status_takes_px4s_count_and_the_specs_bitmask() {
        let mut m = ACTUATOR_OUTPUT_STATUS_DATA {
            active: 3,
            ..Default::default()
        };
        m.actuator[0] = 1500.4;
        m.actuator[1] = f32::NAN;
        m.actuator[2] = 2000.0;
        m.actuator[5] = 1200.0;
        let v = from_actuator_output_status(&m);
        // As a count: 1, 2, 3. As a bitmask (0b11): 1, 2. Their union is 1, 2, 3.
        assert_eq!(
            v.iter().collect::<Vec<_>>(),
            vec![(1, 1500), (2, 0), (3, 2000)]
        );
        m.active = 1 << 5;
        let v = from_actuator_output_status(&m);
        assert_eq!(v.get(6), Some(1200));
    }
}

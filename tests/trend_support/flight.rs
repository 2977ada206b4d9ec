//! A flight of simulated servos in virtual time, written as the bridge records one: the
//! `lj9da-sim` servo model (with its wear knob) driven by goals, its registers recorded as
//! telemetry. For `record trend`'s tests, the fleet tests and the fleet bench.

use lj9da_bridge::bus::{Goal, Health};
use lj9da_bridge::protocol::{Celsius, Ma10, MmCenti, Ms10, Mv10, ReplyFlags, Telemetry};
use lj9da_bridge::record::format::{RecordHeader, RecordServo, encode_header, encode_record};
use lj9da_bridge::record::{Record, RecordBody};
use lj9da_sim::Wear;
use lj9da_sim::servo::memory_map::{FACTORY_ROM, ROM_START, reg};
use lj9da_sim::servo::{Servo, ServoConfig};
use lj9da_sim::{HostPacket, ShortPacket};
use std::path::Path;
use std::time::{Duration, Instant};

/// One flight. The motion: a sine sweep of ±10 mm (its amplitude a little different each
/// flight, by `n`) for 4 s, then 2 s holding at 5 mm, again and again; goals every 20 ms,
/// telemetry every 13 ms; the ambient temperature differs from flight to flight (by `n`).
#[derive(Debug, Clone)]
pub struct Flight {
    /// The flight's number, 0-based: it varies the amplitude and the ambient temperature.
    pub n: usize,
    /// The run's start, ns since 1970.
    pub start_ns: i64,
    pub seconds: u64,
    pub servos: Vec<RecordServo>,
    /// The wear of each servo, in the order of `servos`.
    pub wear: Vec<Wear>,
    /// The aircraft the header names.
    pub aircraft: Option<String>,
    /// Added to the flight's ambient temperature, °C (a hot day: 0 for the usual 20–29 °C).
    pub ambient_offset_c: f64,
}

/// The four servos of `record trend`'s tests and the fleet bench: two ailerons on bus `wing`,
/// the elevator and the rudder on `tail`, ids and channels 1–4.
pub fn four_servos() -> Vec<RecordServo> {
    vec![
        RecordServo::new("aileron_left", "wing", 1, 1),
        RecordServo::new("aileron_right", "wing", 2, 2),
        RecordServo::new("elevator", "tail", 3, 3),
        RecordServo::new("rudder", "tail", 4, 4),
    ]
}

fn write(servo: &mut Servo, now: Instant, id: u8, address: usize, data: &[u8]) {
    let packet = HostPacket::Short(ShortPacket::write(id, address as u8, data, 0));
    servo.receive(now, &packet);
}

fn u16_at(registers: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([registers[at], registers[at + 1]])
}

impl Flight {
    /// The flight's record file's bytes.
    pub fn bytes(&self) -> Vec<u8> {
        let start = Instant::now();
        let n = self.n;
        let ambient = 20.0 + (n * 7 % 10) as f64 + self.ambient_offset_c;
        let amplitude_centi = 1000.0 * (1.0 + 0.04 * (((n * 3) % 5) as f64 - 2.0) / 2.0);
        let mut sim: Vec<Servo> = self
            .servos
            .iter()
            .zip(&self.wear)
            .map(|(s, wear)| {
                let mut servo = Servo::new(
                    ServoConfig {
                        id: s.id,
                        baud_code: FACTORY_ROM[reg::BAUD_RATE - ROM_START],
                        return_delay_ms: FACTORY_ROM[reg::RETURN_DELAY_MS - ROM_START],
                        voltage_v: 12.0,
                        ambient_c: ambient,
                    },
                    start,
                );
                write(&mut servo, start, s.id, reg::FORCE_ENABLE, &[1]);
                servo.set_wear(start, *wear);
                servo
            })
            .collect();
        let header = RecordHeader::new(self.start_ns, self.servos.clone())
            .with_aircraft(self.aircraft.as_deref());
        let mut bytes = encode_header(&header);
        let mut put = |t_us: u64, body: RecordBody| {
            encode_record(&Record { t_us, body }, &mut bytes);
        };
        for index in 0..self.servos.len() {
            put(
                0,
                RecordBody::Health {
                    servo: index as u8,
                    health: Health::Online,
                    stalled: false,
                },
            );
        }
        let mut goals = vec![i16::MIN; self.servos.len()];
        // Goals every 20 ms, each to be reached in 20 ms (a goal time, as a mapping may set);
        // telemetry every 13 ms, so that samples fall anywhere in a goal's period.
        for ms in 0..self.seconds * 1000 {
            let now = start + Duration::from_millis(ms);
            let phase = (ms % 6000) as f64 / 1000.0;
            let goal_centi = if phase < 4.0 {
                (amplitude_centi * (std::f64::consts::PI * phase).sin()).round() as i16
            } else {
                500
            };
            for (index, (servo, s)) in sim.iter_mut().zip(&self.servos).enumerate() {
                if ms.is_multiple_of(20) && goals[index] != goal_centi {
                    let mut data = goal_centi.to_le_bytes().to_vec();
                    data.extend_from_slice(&2u16.to_le_bytes());
                    write(servo, now, s.id, reg::GOAL_POSITION, &data);
                    goals[index] = goal_centi;
                    put(
                        ms * 1000,
                        RecordBody::Goal {
                            servo: index as u8,
                            goal: Goal::Position(MmCenti(goal_centi)),
                        },
                    );
                }
                if !(ms + index as u64 * 3).is_multiple_of(13) {
                    continue;
                }
                servo.update(now);
                let r = servo.registers();
                put(
                    ms * 1000 + 500,
                    RecordBody::Telemetry {
                        servo: index as u8,
                        telemetry: Telemetry {
                            present_position: MmCenti(u16_at(r, reg::PRESENT_POSITION) as i16),
                            present_time: Ms10(u16_at(r, reg::PRESENT_TIME)),
                            present_load: Ma10(u16_at(r, reg::PRESENT_LOAD)),
                            present_temperature: Celsius(u16_at(r, reg::PRESENT_TEMPERATURE) as i16),
                            present_voltage: Mv10(u16_at(r, reg::PRESENT_VOLTAGE)),
                        },
                        flags: ReplyFlags(servo.status_flags()),
                    },
                );
            }
        }
        let end_us = self.seconds * 1_000_000 + 10_000;
        for index in 0..self.servos.len() {
            put(
                end_us,
                RecordBody::Replies {
                    servo: index as u8,
                    answered: (self.seconds * 1000 / 13) as u32,
                    missed: if index == 3 { 40 } else { 0 },
                },
            );
        }
        put(end_us, RecordBody::End { continued: false });
        bytes
    }

    /// Write the flight's record file at `path`.
    pub fn write(&self, path: &Path) {
        std::fs::write(path, self.bytes()).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    }
}

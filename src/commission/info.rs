//! `info`: one servo's whole memory map, decoded with names, units and readings, and the
//! status flags of its reply explained. Nothing is written.

use super::CommissionError;
use super::json::Json;
use super::link::{Link, LinkError};
use crate::protocol::registers::{Access, Area, Register};
use crate::protocol::{BaudRate, MemoryMap, ReplyFlags, ServoId};

/// One servo's memory map as read.
#[derive(Debug, Clone, PartialEq)]
pub struct InfoReport {
    pub id: ServoId,
    /// The rate the servo was read at.
    pub baud: BaudRate,
    pub map: MemoryMap,
    /// Status flags of the last reply (registers 30–59).
    pub flags: ReplyFlags,
}

/// Read registers 0–29 and 30–59 of servo `id`.
pub async fn info(link: &mut Link, id: ServoId) -> Result<InfoReport, CommissionError> {
    match link.read_all(id).await {
        Ok((map, flags)) => Ok(InfoReport {
            id,
            baud: link.baud(),
            map,
            flags,
        }),
        Err(LinkError::Timeout { .. }) => Err(CommissionError::NoServo {
            id,
            baud: link.baud(),
        }),
        Err(e) => Err(e.into()),
    }
}

fn access_name(access: Access) -> &'static str {
    match access {
        Access::ReadOnly => "R",
        Access::ReadWrite => "RW",
        Access::Reserved => "reserved",
    }
}

fn area_name(area: Area) -> &'static str {
    match area {
        Area::Fixed => "fixed",
        Area::Rom => "rom",
        Area::Ram => "ram",
    }
}

impl InfoReport {
    /// Every register: description, raw value and reading (from the protocol core).
    pub fn registers(&self) -> Vec<(Register, u16, String)> {
        self.map.describe()
    }

    /// Each status flag with whether it is set and what it means.
    pub fn flag_explanations(&self) -> Vec<(&'static str, bool, &'static str)> {
        let f = self.flags;
        vec![
            (
                "temperature error (bit 7)",
                f.temperature_error(),
                "the temperature limit was reached and force was switched off; force on is refused until the servo is cool and power-cycled",
            ),
            (
                "temperature alarm (bit 5)",
                f.temperature_alarm(),
                "within 10 °C of the temperature limit",
            ),
            (
                "flash write error (bit 3)",
                f.flash_write_error(),
                "the last flash write failed; settings may not survive power-off",
            ),
        ]
    }

    /// The report for scripts (`info --json`).
    pub fn to_json(&self) -> Json {
        let m = &self.map;
        let (plus_margin, minus_margin) = m.compliance_margins();
        let (plus_slope, minus_slope) = m.compliance_slopes();
        let t = m.telemetry();
        let summary = Json::object([
            ("model_number", Json::Int(i64::from(m.model_number()))),
            (
                "is_lj9da41",
                Json::Bool(m.model_number() == crate::protocol::LJ9DA41_MODEL_NUMBER),
            ),
            (
                "firmware_version",
                Json::Int(i64::from(m.firmware_version())),
            ),
            (
                "servo_id",
                Json::Int(i64::from(
                    m.bytes()[usize::from(crate::protocol::registers::addr::SERVO_ID)],
                )),
            ),
            ("reversed", Json::Bool(m.reversed())),
            (
                "baud",
                m.baud_rate()
                    .map_or(Json::Null, |b| Json::Int(i64::from(b.bits_per_second()))),
            ),
            ("return_delay_ms", Json::Int(i64::from(m.return_delay_ms()))),
            ("plus_limit_mm", Json::Float(m.plus_limit().mm(), 2)),
            ("minus_limit_mm", Json::Float(m.minus_limit().mm(), 2)),
            (
                "temperature_limit_c",
                Json::Int(i64::from(m.temperature_limit().0)),
            ),
            ("plus_compliance_margin", Json::Int(i64::from(plus_margin))),
            (
                "minus_compliance_margin",
                Json::Int(i64::from(minus_margin)),
            ),
            ("plus_compliance_slope", Json::Int(i64::from(plus_slope))),
            ("minus_compliance_slope", Json::Int(i64::from(minus_slope))),
            ("punch_raw", Json::Int(i64::from(m.punch_raw()))),
            ("goal_position_mm", Json::Float(m.goal_position().mm(), 2)),
            ("goal_time_ms", Json::Int(i64::from(m.goal_time().millis()))),
            ("max_force_percent", Json::Int(i64::from(m.max_force_raw()))),
            (
                "force",
                Json::str(match m.force_mode() {
                    Ok(crate::protocol::ForceMode::Off) => "off",
                    Ok(crate::protocol::ForceMode::On) => "on",
                    Ok(crate::protocol::ForceMode::Brake) => "brake",
                    Err(_) => "unknown",
                }),
            ),
            (
                "present_position_mm",
                Json::Float(t.present_position.mm(), 2),
            ),
            (
                "present_time_ms",
                Json::Int(i64::from(t.present_time.millis())),
            ),
            (
                "present_load_ma",
                Json::Int(i64::from(t.present_load.0) * 10),
            ),
            (
                "present_temperature_c",
                Json::Int(i64::from(t.present_temperature.0)),
            ),
            (
                "present_voltage_v",
                Json::Float(t.present_voltage.volts(), 2),
            ),
        ]);
        let flags = Json::object([
            ("raw", Json::Int(i64::from(self.flags.0))),
            (
                "temperature_error",
                Json::Bool(self.flags.temperature_error()),
            ),
            (
                "temperature_alarm",
                Json::Bool(self.flags.temperature_alarm()),
            ),
            (
                "flash_write_error",
                Json::Bool(self.flags.flash_write_error()),
            ),
            ("text", Json::str(self.flags.to_string())),
        ]);
        let registers = self
            .registers()
            .into_iter()
            .map(|(r, raw, reading)| {
                Json::object([
                    ("address", Json::Int(i64::from(r.address))),
                    ("size", Json::Int(i64::from(r.size))),
                    ("name", Json::str(r.name)),
                    ("access", Json::str(access_name(r.access))),
                    ("area", Json::str(area_name(r.area))),
                    ("unit", Json::str(r.unit)),
                    ("raw", Json::Int(i64::from(raw))),
                    ("reading", Json::str(reading)),
                ])
            })
            .collect();
        Json::object([
            ("id", Json::Int(i64::from(self.id.get()))),
            ("baud", Json::Int(i64::from(self.baud.bits_per_second()))),
            ("flags", flags),
            ("summary", summary),
            ("registers", Json::Array(registers)),
        ])
    }
}

/// Short access name for tables.
pub fn access_label(access: Access) -> &'static str {
    access_name(access)
}

/// Short area name for tables.
pub fn area_label(area: Area) -> &'static str {
    area_name(area)
}

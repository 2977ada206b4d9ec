//! `info`: one servo's whole memory map, decoded with names, units and readings, and the
//! status flags of its reply explained. Nothing is written.

use super::CommissionError;
use super::json::{Fixed, centi};
use super::link::{Link, LinkError};
use crate::protocol::registers::{Access, Area, Register};
use crate::protocol::{BaudRate, MemoryMap, ReplyFlags, ServoId};
use serde::Serialize;

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
    pub fn to_json(&self) -> InfoJson {
        let m = &self.map;
        let (plus_margin, minus_margin) = m.compliance_margins();
        let (plus_slope, minus_slope) = m.compliance_slopes();
        let t = m.telemetry();
        let summary = SummaryJson {
            model_number: m.model_number(),
            is_lj9da41: m.model_number() == crate::protocol::LJ9DA41_MODEL_NUMBER,
            firmware_version: m.firmware_version(),
            servo_id: m.bytes()[usize::from(crate::protocol::registers::addr::SERVO_ID)],
            reversed: m.reversed(),
            baud: m.baud_rate().ok().map(|b| b.bits_per_second()),
            return_delay_ms: m.return_delay_ms(),
            plus_limit_mm: centi(m.plus_limit().mm()),
            minus_limit_mm: centi(m.minus_limit().mm()),
            temperature_limit_c: m.temperature_limit().0,
            plus_compliance_margin: plus_margin,
            minus_compliance_margin: minus_margin,
            plus_compliance_slope: plus_slope,
            minus_compliance_slope: minus_slope,
            punch_raw: m.punch_raw(),
            goal_position_mm: centi(m.goal_position().mm()),
            goal_time_ms: m.goal_time().millis(),
            max_force_percent: m.max_force_raw(),
            force: match m.force_mode() {
                Ok(crate::protocol::ForceMode::Off) => "off",
                Ok(crate::protocol::ForceMode::On) => "on",
                Ok(crate::protocol::ForceMode::Brake) => "brake",
                Err(_) => "unknown",
            },
            present_position_mm: centi(t.present_position.mm()),
            present_time_ms: t.present_time.millis(),
            present_load_ma: u32::from(t.present_load.0) * 10,
            present_temperature_c: t.present_temperature.0,
            present_voltage_v: centi(t.present_voltage.volts()),
        };
        let flags = FlagsJson {
            raw: self.flags.0,
            temperature_error: self.flags.temperature_error(),
            temperature_alarm: self.flags.temperature_alarm(),
            flash_write_error: self.flags.flash_write_error(),
            text: self.flags.to_string(),
        };
        let registers = self
            .registers()
            .into_iter()
            .map(|(r, raw, reading)| RegisterJson {
                address: r.address,
                size: r.size,
                name: r.name,
                access: access_name(r.access),
                area: area_name(r.area),
                unit: r.unit,
                raw,
                reading,
            })
            .collect();
        InfoJson {
            id: self.id.get(),
            baud: self.baud.bits_per_second(),
            flags,
            summary,
            registers,
        }
    }
}

/// `info --json`: the servo, its reply's flags, the memory map's meaning, and every register.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct InfoJson {
    pub id: u8,
    pub baud: u32,
    pub flags: FlagsJson,
    pub summary: SummaryJson,
    pub registers: Vec<RegisterJson>,
}

impl InfoJson {
    /// Indented by two spaces per level.
    pub fn pretty(&self) -> String {
        super::json::pretty(self)
    }
}

impl std::fmt::Display for InfoJson {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.pretty())
    }
}

/// The status flags of the servo's reply.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FlagsJson {
    pub raw: u8,
    pub temperature_error: bool,
    pub temperature_alarm: bool,
    pub flash_write_error: bool,
    pub text: String,
}

/// The memory map's settings and readings, in their units.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SummaryJson {
    pub model_number: u16,
    pub is_lj9da41: bool,
    pub firmware_version: u8,
    pub servo_id: u8,
    pub reversed: bool,
    /// `null` when register 6 holds no known rate.
    pub baud: Option<u32>,
    pub return_delay_ms: u8,
    pub plus_limit_mm: Fixed,
    pub minus_limit_mm: Fixed,
    pub temperature_limit_c: i16,
    pub plus_compliance_margin: u8,
    pub minus_compliance_margin: u8,
    pub plus_compliance_slope: u8,
    pub minus_compliance_slope: u8,
    pub punch_raw: u16,
    pub goal_position_mm: Fixed,
    pub goal_time_ms: u32,
    pub max_force_percent: u8,
    pub force: &'static str,
    pub present_position_mm: Fixed,
    pub present_time_ms: u32,
    pub present_load_ma: u32,
    pub present_temperature_c: i16,
    pub present_voltage_v: Fixed,
}

/// One register: where it is, what it is, and what it holds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RegisterJson {
    pub address: u8,
    pub size: u8,
    pub name: &'static str,
    pub access: &'static str,
    pub area: &'static str,
    pub unit: &'static str,
    pub raw: u16,
    pub reading: String,
}

/// Short access name for tables.
pub fn access_label(access: Access) -> &'static str {
    access_name(access)
}

/// Short area name for tables.
pub fn area_label(area: Area) -> &'static str {
    area_name(area)
}

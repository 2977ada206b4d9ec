//! The mapping file as written, before validation: every key the file may contain, each value
//! kept with its position so that a refusal can point at it. Unknown keys are refused here, so a
//! typo never silently becomes a default. Numbers are read wide (`i64`, `f64`) so that a value
//! out of range is reported with its own range rather than as a type error.

use serde::Deserialize;
use toml::Spanned;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawFile {
    pub mavlink: Option<Spanned<RawMavlink>>,
    pub telemetry: Option<Spanned<RawTelemetry>>,
    pub bridge: Option<Spanned<RawBridge>>,
    pub record: Option<Spanned<RawRecord>>,
    pub dronecan: Option<Spanned<RawDroneCan>>,
    #[serde(default)]
    pub bus: Vec<Spanned<RawBus>>,
    #[serde(default)]
    pub servo: Vec<Spanned<RawServo>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMavlink {
    pub connection: Spanned<String>,
    pub system_id: Option<Spanned<i64>>,
    pub autopilot_system_id: Option<Spanned<i64>>,
    pub autopilot_component_id: Option<Spanned<i64>>,
    pub component_id: Option<Spanned<i64>>,
    pub source: Option<Spanned<String>>,
    pub output_rate_hz: Option<Spanned<f64>>,
    pub failsafe_timeout_ms: Option<Spanned<i64>>,
    pub gcs: Option<Spanned<String>>,
    pub signing_key: Option<Spanned<String>>,
    pub signing_key_file: Option<Spanned<String>>,
    pub signing_passphrase: Option<Spanned<String>>,
    pub signing_timestamp_file: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawTelemetry {
    pub rate_hz: Option<Spanned<f64>>,
    pub named_value_float: Option<bool>,
    pub named_values: Option<Spanned<Vec<Spanned<String>>>>,
    pub esc: Option<bool>,
    pub esc_info_hz: Option<Spanned<f64>>,
    pub esc_status_hz: Option<Spanned<f64>>,
    pub esc_index_base: Option<Spanned<i64>>,
    pub statustext: Option<bool>,
    pub servo_state: Option<bool>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawBridge {
    pub on_exit: Option<Spanned<String>>,
    pub while_safe: Option<Spanned<String>>,
    pub commands: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawDroneCan {
    pub interface: Spanned<String>,
    pub node_id: Spanned<RawNodeId>,
    pub unitless: Option<Spanned<String>>,
    pub status_hz: Option<Spanned<f64>>,
}

/// `node_id = 42` or `node_id = "dynamic"`.
#[derive(Debug)]
pub(crate) enum RawNodeId {
    Number(i64),
    Text(String),
}

impl<'de> Deserialize<'de> for RawNodeId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = RawNodeId;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a node id 1–125, or \"dynamic\"")
            }
            fn visit_i64<E>(self, n: i64) -> Result<RawNodeId, E> {
                Ok(RawNodeId::Number(n))
            }
            fn visit_u64<E>(self, n: u64) -> Result<RawNodeId, E> {
                Ok(RawNodeId::Number(i64::try_from(n).unwrap_or(i64::MAX)))
            }
            fn visit_str<E>(self, t: &str) -> Result<RawNodeId, E> {
                Ok(RawNodeId::Text(t.to_string()))
            }
        }
        d.deserialize_any(Visitor)
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawRecord {
    pub enabled: Option<bool>,
    pub dir: Option<Spanned<String>>,
    pub max_total_mb: Option<Spanned<i64>>,
    pub aircraft: Option<Spanned<String>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawBus {
    pub name: Spanned<String>,
    pub port: Spanned<String>,
    pub baud: Option<Spanned<i64>>,
    pub turnaround_ms: Option<Spanned<f64>>,
    pub soft_start_mm_s: Option<Spanned<f64>>,
    pub telemetry_hz: Option<Spanned<RawRate>>,
    pub rs485: Option<Spanned<RawRs485>>,
}

/// `rs485 = { … }` of a bus: the kernel's RS485 mode for a UART.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawRs485 {
    pub rts_on_send: Option<Spanned<bool>>,
    pub rts_after_send: Option<Spanned<bool>>,
    pub delay_before_send_ms: Option<Spanned<i64>>,
    pub delay_after_send_ms: Option<Spanned<i64>>,
    pub rx_during_tx: Option<Spanned<bool>>,
}

/// A rate in Hz, or a word such as `"max"`.
#[derive(Debug, Deserialize)]
#[serde(untagged)]
pub(crate) enum RawRate {
    Hz(f64),
    Word(String),
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawServo {
    pub name: Spanned<String>,
    pub label: Option<Spanned<String>>,
    pub bus: Spanned<String>,
    pub id: Spanned<i64>,
    pub channel: Spanned<i64>,
    pub pwm_min_us: Option<Spanned<i64>>,
    pub pwm_trim_us: Option<Spanned<i64>>,
    pub pwm_max_us: Option<Spanned<i64>>,
    pub travel_mm: Option<Spanned<Vec<f64>>>,
    pub min_mm: Option<Spanned<f64>>,
    pub max_mm: Option<Spanned<f64>>,
    pub reverse: Option<bool>,
    pub goal_time_ms: Option<Spanned<i64>>,
    pub max_force_percent: Option<Spanned<i64>>,
    pub failsafe: Option<Spanned<toml::Value>>,
    pub actuator: Option<Spanned<i64>>,
    pub dronecan_id: Option<Spanned<i64>>,
    pub named_values: Option<Spanned<Vec<Spanned<String>>>>,
}

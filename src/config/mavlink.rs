//! The `[mavlink]` and `[telemetry]` tables: how the bridge reaches the autopilot, whose outputs
//! it obeys, and what it reports back.

use super::error::{ConfigError, Scope};
use super::raw::{RawMavlink, RawTelemetry};
use super::signing_key::SigningKey;
use std::fmt;
use std::path::{Path, PathBuf};
use toml::Spanned;

/// The connection types of the `mavlink` crate's address strings that the bridge accepts.
pub const CONNECTION_SCHEMES: [&str; 6] =
    ["udpin", "udpout", "udpbcast", "tcpin", "tcpout", "serial"];

/// MAV_COMP_ID_SERVO1: the bridge's component id unless the file sets another.
pub const DEFAULT_COMPONENT_ID: u8 = 140;
/// MAV_COMP_ID_AUTOPILOT1.
pub const DEFAULT_AUTOPILOT_COMPONENT_ID: u8 = 1;
/// The output rate requested from the autopilot unless the file sets another.
pub const DEFAULT_OUTPUT_RATE_HZ: f32 = 50.0;
/// How long without outputs before each servo's failsafe action, unless the file sets another.
pub const DEFAULT_FAILSAFE_TIMEOUT_MS: u32 = 500;
/// How often NAMED_VALUE_FLOAT values are looked at unless the file sets another: a value
/// goes out when it has changed, and at least every [`NAMED_VALUE_REFRESH_S`] seconds.
pub const DEFAULT_TELEMETRY_RATE_HZ: f32 = 1.0;
/// A NAMED_VALUE_FLOAT that has not changed is sent again after this long, for a ground
/// station that connects late.
pub const NAMED_VALUE_REFRESH_S: u64 = 5;
/// ESC_INFO's rate unless the file sets another (the rate MAVLink recommends for it).
pub const DEFAULT_ESC_INFO_HZ: f32 = 1.0;
/// ESC_STATUS's rate unless the file sets another (MAVLink meant it for fast links).
pub const DEFAULT_ESC_STATUS_HZ: f32 = 1.0;
/// The ESC index of the first servo unless the file sets another: above the motor ESCs an
/// autopilot reports itself (ArduPilot up to 16, PX4 up to 8), whose entries share one table
/// keyed by index in QGroundControl.
pub const DEFAULT_ESC_INDEX_BASE: u8 = 16;

const OUTPUT_RATE_MAX_HZ: f64 = 500.0;
const TELEMETRY_RATE_MAX_HZ: f64 = 50.0;
const FAILSAFE_TIMEOUT_MAX_MS: i64 = 60_000;

/// The message that carries the autopilot's outputs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Source {
    /// SERVO_OUTPUT_RAW (36), from ArduPilot and PX4. Channels 1–16 have `port = 0`, 17–32
    /// `port = 1` (on PX4 the port is the output driver instance).
    #[default]
    ServoOutputRaw,
    /// ACTUATOR_OUTPUT_STATUS (375), from PX4 only; channel n is `actuator[n − 1]`.
    ActuatorOutputStatus,
}

impl Source {
    /// The MAVLink message name, as written in a mapping file.
    pub const fn message_name(self) -> &'static str {
        match self {
            Source::ServoOutputRaw => "SERVO_OUTPUT_RAW",
            Source::ActuatorOutputStatus => "ACTUATOR_OUTPUT_STATUS",
        }
    }

    /// The MAVLink message id, as used in MAV_CMD_SET_MESSAGE_INTERVAL.
    pub const fn message_id(self) -> u32 {
        match self {
            Source::ServoOutputRaw => 36,
            Source::ActuatorOutputStatus => 375,
        }
    }
}

impl fmt::Display for Source {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.message_name())
    }
}

/// The `[mavlink]` table.
#[derive(Debug, Clone, PartialEq)]
pub struct MavlinkConfig {
    /// A `mavlink` crate address: `udpin:0.0.0.0:14560`, `udpout:…`, `udpbcast:…`, `tcpin:…`,
    /// `tcpout:…` or `serial:/dev/ttyAMA0:921600`.
    pub connection: String,
    /// The system id of the bridge's own messages, which must be the vehicle's for the ground
    /// stations to show them with the vehicle. `None`: take the autopilot's, from its heartbeat.
    /// If only one of `system_id` and `autopilot_system_id` is set, the other follows it.
    pub system_id: Option<u8>,
    /// The autopilot whose outputs are obeyed; messages from any other system are ignored.
    /// `None`: the first system whose HEARTBEAT has an autopilot field other than
    /// MAV_AUTOPILOT_INVALID.
    pub autopilot_system_id: Option<u8>,
    /// The autopilot's component id (default 1, MAV_COMP_ID_AUTOPILOT1).
    pub autopilot_component_id: u8,
    /// The bridge's own component id (default 140, MAV_COMP_ID_SERVO1).
    pub component_id: u8,
    /// Which message carries the outputs (default SERVO_OUTPUT_RAW).
    pub source: Source,
    /// The rate requested with MAV_CMD_SET_MESSAGE_INTERVAL (default 50 Hz). ArduPilot denies a
    /// rate above 0.8 × SCHED_LOOP_RATE (stock Plane: 40 Hz accepted, 50 Hz denied); the bridge
    /// then falls back to a lower rate.
    pub output_rate_hz: f32,
    /// With no output message for this long, every servo takes its failsafe action (default 500).
    pub failsafe_timeout_ms: u32,
    /// An extra, telemetry-only output (e.g. `udpout:127.0.0.1:14550`) for a ground station
    /// that the autopilot does not route to.
    pub gcs: Option<String>,
    /// MAVLink 2 signing on every link; `None`: off (messages neither signed nor checked).
    pub signing: Option<SigningSetup>,
}

/// Where a signing key came from (what `check` shows instead of the key).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum KeySource {
    /// `signing_key`: 64 hex digits in the mapping file.
    Hex,
    /// `signing_key_file`: read from this file.
    File(PathBuf),
    /// `signing_passphrase`: SHA-256 of the passphrase, as MAVProxy's `signing setup` derives it.
    Passphrase,
}

impl fmt::Display for KeySource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            KeySource::Hex => f.write_str("key in the file"),
            KeySource::File(path) => write!(f, "key from {}", path.display()),
            KeySource::Passphrase => f.write_str("key from a passphrase"),
        }
    }
}

/// MAVLink 2 signing, from the `signing_*` keys of `[mavlink]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SigningSetup {
    /// The secret (its `Debug` does not show it).
    pub key: SigningKey,
    pub key_source: KeySource,
    /// Where the signing timestamp's reservation is kept: `signing_timestamp_file` (relative to
    /// the mapping file's folder), else `<mapping file>.signing-timestamp`. `None` for a mapping
    /// given as text without a file (the bridge then keeps it in the flight record's folder, or
    /// the system's temporary folder).
    pub timestamp_file: Option<PathBuf>,
}

/// The file name the default signing timestamp file gets beside a mapping file.
pub const SIGNING_TIMESTAMP_SUFFIX: &str = ".signing-timestamp";

/// A servo quantity that NAMED_VALUE_FLOAT can carry, named by its name suffix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Quantity {
    /// `pos`: position in mm.
    Position,
    /// `cur`: current in A.
    Current,
    /// `tmp`: temperature in °C.
    Temperature,
    /// `vlt`: voltage in V.
    Voltage,
}

impl Quantity {
    pub const ALL: [Quantity; 4] = [
        Quantity::Position,
        Quantity::Current,
        Quantity::Temperature,
        Quantity::Voltage,
    ];

    /// As written in `named_values` and at the end of a NAMED_VALUE_FLOAT name (`<label>_pos`).
    pub const fn key(self) -> &'static str {
        match self {
            Quantity::Position => "pos",
            Quantity::Current => "cur",
            Quantity::Temperature => "tmp",
            Quantity::Voltage => "vlt",
        }
    }
}

/// The `[telemetry]` table: what the bridge reports to the ground station, and how often.
/// Everything the bridge sends is forwarded by the autopilot to every link, a 57 600-baud
/// telemetry radio included: the defaults stay near 10 % of such a radio.
#[derive(Debug, Clone, PartialEq)]
pub struct TelemetryConfig {
    /// How often the NAMED_VALUE_FLOAT values are looked at (default 1 Hz); a value goes out
    /// only when it has changed, or every [`NAMED_VALUE_REFRESH_S`] s.
    pub rate_hz: f32,
    /// NAMED_VALUE_FLOAT per servo and quantity.
    pub named_value_float: bool,
    /// Which quantities go out as NAMED_VALUE_FLOAT (default all four), in this order.
    pub named_values: Vec<Quantity>,
    /// ESC_INFO + ESC_STATUS, in blocks of four servos (QGroundControl's ESC indicator).
    pub esc: bool,
    /// ESC_INFO's rate (default 1 Hz).
    pub esc_info_hz: f32,
    /// ESC_STATUS's rate (default 1 Hz).
    pub esc_status_hz: f32,
    /// The ESC index of the first servo (default 16, clear of the motor ESCs).
    pub esc_index_base: u8,
    /// STATUSTEXT for alarms, lost servos and failsafe.
    pub statustext: bool,
    /// Each servo's state as NAMED_VALUE_INT `LJ9_<label>` (1 Hz, and on a change), for the
    /// autopilot's script (`packaging/ardupilot/lj9da.lua`).
    pub servo_state: bool,
}

impl Default for TelemetryConfig {
    fn default() -> Self {
        TelemetryConfig {
            rate_hz: DEFAULT_TELEMETRY_RATE_HZ,
            named_value_float: true,
            named_values: Quantity::ALL.to_vec(),
            esc: true,
            esc_info_hz: DEFAULT_ESC_INFO_HZ,
            esc_status_hz: DEFAULT_ESC_STATUS_HZ,
            esc_index_base: DEFAULT_ESC_INDEX_BASE,
            statustext: true,
            servo_state: true,
        }
    }
}

impl MavlinkConfig {
    /// The serial ports of the links on `serial:` (`connection`, `gcs`), by key.
    pub fn serial_links(&self) -> Vec<(&'static str, &str)> {
        fn port(address: &str) -> Option<&str> {
            let rest = address.strip_prefix("serial:")?;
            Some(rest.rsplit_once(':').map_or(rest, |(port, _)| port))
        }
        let connection = port(&self.connection).map(|p| ("connection", p));
        let gcs = self.gcs.as_deref().and_then(port).map(|p| ("gcs", p));
        connection.into_iter().chain(gcs).collect()
    }
}

/// Check a `mavlink` crate address string; the reason names what is wrong and shows an example.
pub fn check_connection(address: &str) -> Result<(), String> {
    const EXAMPLES: &str =
        "e.g. udpin:0.0.0.0:14560, tcpout:127.0.0.1:5760, serial:/dev/ttyAMA0:921600";
    let Some((scheme, rest)) = address.split_once(':') else {
        return Err(format!(
            "\"{address}\" has no connection type; write <type>:<address> with type udpin, udpout, udpbcast, tcpin, tcpout or serial ({EXAMPLES})"
        ));
    };
    if !CONNECTION_SCHEMES.contains(&scheme) {
        return Err(format!(
            "\"{scheme}:\" is not a connection type; use udpin:, udpout:, udpbcast:, tcpin:, tcpout: or serial: ({EXAMPLES})"
        ));
    }
    if scheme == "serial" {
        let Some((port, baud)) = rest.split_once(':') else {
            return Err(format!(
                "a serial connection is serial:<port>:<baud>, e.g. serial:/dev/ttyAMA0:921600; \"{address}\" has no baud rate"
            ));
        };
        if port.is_empty() {
            return Err(format!(
                "\"{address}\" names no serial port; e.g. serial:/dev/ttyAMA0:921600"
            ));
        }
        match baud.parse::<u32>() {
            Ok(b) if b > 0 => Ok(()),
            _ => Err(format!(
                "\"{baud}\" is not a baud rate; e.g. serial:{port}:921600"
            )),
        }
    } else {
        let Some((host, port)) = rest.rsplit_once(':') else {
            return Err(format!(
                "a network connection is {scheme}:<host>:<port>, e.g. {scheme}:127.0.0.1:14560; \"{address}\" has no port"
            ));
        };
        if host.is_empty() {
            return Err(format!(
                "\"{address}\" names no host; e.g. {scheme}:0.0.0.0:{port}"
            ));
        }
        match port.parse::<u16>() {
            Ok(p) if p > 0 => Ok(()),
            _ => Err(format!(
                "\"{port}\" is not a port number (1–65535); e.g. {scheme}:{host}:14560"
            )),
        }
    }
}

/// A MAVLink system or component id: 1–255 (0 means "every system" and cannot be one's own).
fn mavlink_id(scope: &Scope<'_>, value: &Spanned<i64>, key: &str) -> Result<u8, ConfigError> {
    match u8::try_from(*value.get_ref()) {
        Ok(id) if id >= 1 => Ok(id),
        _ => Err(scope.error_on(
            value,
            key,
            format!(
                "{} is outside 1–255 (0 addresses every system and cannot be used here)",
                value.get_ref()
            ),
        )),
    }
}

/// A rate in Hz: finite, above 0 and at most `max`.
fn rate(scope: &Scope<'_>, value: &Spanned<f64>, key: &str, max: f64) -> Result<f32, ConfigError> {
    let hz = *value.get_ref();
    if hz.is_finite() && hz > 0.0 && hz <= max {
        Ok(hz as f32)
    } else {
        Err(scope.error_on(value, key, format!("{hz} Hz is outside (0, {max}] Hz")))
    }
}

/// A path from the file: relative to the mapping file's folder (or the current folder).
fn resolve(path: &str, mapping: Option<&Path>) -> PathBuf {
    let path = PathBuf::from(path);
    match mapping.and_then(Path::parent) {
        Some(dir) if path.is_relative() => dir.join(path),
        _ => path,
    }
}

/// The `signing_*` keys: at most one key form, each checked, and where timestamps are kept.
fn signing(
    raw: &RawMavlink,
    scope: &Scope<'_>,
    mapping: Option<&Path>,
) -> Result<Option<SigningSetup>, ConfigError> {
    let forms = [
        ("signing_key", &raw.signing_key),
        ("signing_key_file", &raw.signing_key_file),
        ("signing_passphrase", &raw.signing_passphrase),
    ];
    let given: Vec<(&str, &Spanned<String>)> = forms
        .iter()
        .filter_map(|(key, value)| value.as_ref().map(|v| (*key, v)))
        .collect();
    let (key, key_source) = match given.as_slice() {
        [] => {
            if let Some(t) = &raw.signing_timestamp_file {
                return Err(scope.error_on(
                    t,
                    "signing_timestamp_file",
                    "is set but signing is off; add signing_key, signing_key_file or signing_passphrase, or remove this key",
                ));
            }
            return Ok(None);
        }
        [(name, value)] => {
            // The reasons never quote the key.
            let text = value.get_ref();
            match *name {
                "signing_key" => (
                    SigningKey::from_hex(text.trim())
                        .map_err(|e| scope.error_on(value, name, format!("the key {e}")))?,
                    KeySource::Hex,
                ),
                "signing_key_file" => {
                    let path = resolve(text.trim(), mapping);
                    let contents = std::fs::read(&path).map_err(|e| {
                        scope.error_on(value, name, format!("cannot read {}: {e}", path.display()))
                    })?;
                    let key = SigningKey::from_file_contents(&contents).map_err(|e| {
                        scope.error_on(value, name, format!("{} {e}", path.display()))
                    })?;
                    (key, KeySource::File(path))
                }
                _ => (
                    SigningKey::from_passphrase(text)
                        .map_err(|e| scope.error_on(value, name, format!("the passphrase {e}")))?,
                    KeySource::Passphrase,
                ),
            }
        }
        [(first, _), (second, value), ..] => {
            return Err(scope.error_on(
                value,
                second,
                format!(
                    "{first} is set as well; give the signing key one way only (signing_key, signing_key_file or signing_passphrase)"
                ),
            ));
        }
    };
    let timestamp_file = match &raw.signing_timestamp_file {
        Some(t) if t.get_ref().trim().is_empty() => {
            return Err(scope.error_on(
                t,
                "signing_timestamp_file",
                format!(
                    "is empty; leave the key out for <mapping file>{SIGNING_TIMESTAMP_SUFFIX} beside this file"
                ),
            ));
        }
        Some(t) => Some(resolve(t.get_ref().trim(), mapping)),
        None => mapping.map(|m| {
            let mut name = m.as_os_str().to_os_string();
            name.push(SIGNING_TIMESTAMP_SUFFIX);
            PathBuf::from(name)
        }),
    };
    Ok(Some(SigningSetup {
        key,
        key_source,
        timestamp_file,
    }))
}

impl MavlinkConfig {
    /// `mapping`: the mapping file's path, for the relative paths of the signing keys.
    pub(crate) fn from_raw(
        raw: &RawMavlink,
        scope: &Scope<'_>,
        mapping: Option<&Path>,
    ) -> Result<Self, ConfigError> {
        let connection = raw.connection.get_ref().trim().to_string();
        check_connection(&connection)
            .map_err(|reason| scope.error_on(&raw.connection, "connection", reason))?;
        let gcs = match &raw.gcs {
            None => None,
            Some(gcs) => {
                let address = gcs.get_ref().trim().to_string();
                check_connection(&address).map_err(|reason| scope.error_on(gcs, "gcs", reason))?;
                if address == connection {
                    return Err(scope.error_on(
                        gcs,
                        "gcs",
                        "is the same address as `connection`; give the ground station its own (e.g. udpout:127.0.0.1:14550) or remove the key",
                    ));
                }
                Some(address)
            }
        };

        let opt_id = |value: &Option<Spanned<i64>>, key: &str| {
            value
                .as_ref()
                .map(|v| mavlink_id(scope, v, key))
                .transpose()
        };
        let own_system = opt_id(&raw.system_id, "system_id")?;
        let autopilot_system = opt_id(&raw.autopilot_system_id, "autopilot_system_id")?;
        let component_id =
            opt_id(&raw.component_id, "component_id")?.unwrap_or(DEFAULT_COMPONENT_ID);
        let autopilot_component_id = opt_id(&raw.autopilot_component_id, "autopilot_component_id")?
            .unwrap_or(DEFAULT_AUTOPILOT_COMPONENT_ID);
        let system_id = own_system.or(autopilot_system);
        let autopilot_system_id = autopilot_system.or(own_system);
        if component_id == autopilot_component_id && system_id == autopilot_system_id {
            let (span, key) = match (&raw.component_id, &raw.autopilot_component_id) {
                (Some(c), _) => (c.span(), "component_id"),
                (None, Some(a)) => (a.span(), "autopilot_component_id"),
                (None, None) => (raw.connection.span(), "component_id"),
            };
            return Err(scope.error(
                span,
                key,
                format!(
                    "the bridge and the autopilot would both be component {component_id} of one system; give the bridge its own component id (e.g. 140, MAV_COMP_ID_SERVO1)"
                ),
            ));
        }

        let source = match &raw.source {
            None => Source::default(),
            Some(s) => {
                let name = s.get_ref().trim();
                [Source::ServoOutputRaw, Source::ActuatorOutputStatus]
                    .into_iter()
                    .find(|candidate| candidate.message_name().eq_ignore_ascii_case(name))
                    .ok_or_else(|| {
                        scope.error_on(
                            s,
                            "source",
                            format!(
                                "\"{name}\" is not a source; use \"SERVO_OUTPUT_RAW\" (ArduPilot, PX4) or \"ACTUATOR_OUTPUT_STATUS\" (PX4)"
                            ),
                        )
                    })?
            }
        };

        let output_rate_hz = match &raw.output_rate_hz {
            None => DEFAULT_OUTPUT_RATE_HZ,
            Some(r) => rate(scope, r, "output_rate_hz", OUTPUT_RATE_MAX_HZ)?,
        };
        let failsafe_timeout_ms = match &raw.failsafe_timeout_ms {
            None => DEFAULT_FAILSAFE_TIMEOUT_MS,
            Some(t) => match u32::try_from(*t.get_ref()) {
                Ok(ms) if ms >= 1 && i64::from(ms) <= FAILSAFE_TIMEOUT_MAX_MS => ms,
                _ => {
                    return Err(scope.error_on(
                        t,
                        "failsafe_timeout_ms",
                        format!(
                            "{} ms is outside 1–{FAILSAFE_TIMEOUT_MAX_MS} ms",
                            t.get_ref()
                        ),
                    ));
                }
            },
        };
        // Two output intervals must fit in the timeout, or the failsafe would trip between two
        // ordinary messages.
        let two_intervals_ms = 2000.0 / f64::from(output_rate_hz);
        if f64::from(failsafe_timeout_ms) < two_intervals_ms {
            let reason = format!(
                "a failsafe timeout of {failsafe_timeout_ms} ms is shorter than two output intervals at {output_rate_hz} Hz ({two_intervals_ms:.0} ms): the failsafe would trip between two ordinary messages; raise failsafe_timeout_ms or output_rate_hz"
            );
            return Err(match (&raw.failsafe_timeout_ms, &raw.output_rate_hz) {
                (Some(t), _) => scope.error_on(t, "failsafe_timeout_ms", reason),
                (None, Some(r)) => scope.error_on(r, "output_rate_hz", reason),
                (None, None) => scope.error_on(&raw.connection, "failsafe_timeout_ms", reason),
            });
        }

        Ok(MavlinkConfig {
            connection,
            system_id,
            autopilot_system_id,
            autopilot_component_id,
            component_id,
            source,
            output_rate_hz,
            failsafe_timeout_ms,
            gcs,
            signing: signing(raw, scope, mapping)?,
        })
    }
}

/// A `named_values` list (of `[telemetry]` or of a `[[servo]]`): each quantity once, in the
/// order written.
pub(crate) fn quantities(
    list: &Spanned<Vec<Spanned<String>>>,
    scope: &Scope<'_>,
) -> Result<Vec<Quantity>, ConfigError> {
    let mut out = Vec::new();
    for name in list.get_ref() {
        let key = name.get_ref().trim();
        let q = Quantity::ALL
            .into_iter()
            .find(|q| q.key() == key)
            .ok_or_else(|| {
                scope.error_on(
                    name,
                    "named_values",
                    format!(
                        "\"{key}\" is not a quantity; use \"pos\" (position), \"cur\" (current), \"tmp\" (temperature) or \"vlt\" (voltage)"
                    ),
                )
            })?;
        if !out.contains(&q) {
            out.push(q);
        }
    }
    Ok(out)
}

impl TelemetryConfig {
    pub(crate) fn from_raw(raw: &RawTelemetry, scope: &Scope<'_>) -> Result<Self, ConfigError> {
        let default = TelemetryConfig::default();
        let rate_or = |value: &Option<Spanned<f64>>, key: &str, default: f32| match value {
            None => Ok(default),
            Some(r) => rate(scope, r, key, TELEMETRY_RATE_MAX_HZ),
        };
        let named_values = match &raw.named_values {
            None => default.named_values.clone(),
            Some(list) => quantities(list, scope)?,
        };
        let esc_index_base = match &raw.esc_index_base {
            None => default.esc_index_base,
            Some(b) => match u8::try_from(*b.get_ref()) {
                Ok(base) => base,
                Err(_) => {
                    return Err(scope.error_on(
                        b,
                        "esc_index_base",
                        format!(
                            "{} is outside 0–255 (0 puts the first servo where QGroundControl shows ESC 1)",
                            b.get_ref()
                        ),
                    ));
                }
            },
        };
        Ok(TelemetryConfig {
            rate_hz: rate_or(&raw.rate_hz, "rate_hz", default.rate_hz)?,
            named_value_float: raw.named_value_float.unwrap_or(default.named_value_float),
            named_values,
            esc: raw.esc.unwrap_or(default.esc),
            esc_info_hz: rate_or(&raw.esc_info_hz, "esc_info_hz", default.esc_info_hz)?,
            esc_status_hz: rate_or(&raw.esc_status_hz, "esc_status_hz", default.esc_status_hz)?,
            esc_index_base,
            statustext: raw.statustext.unwrap_or(default.statustext),
            servo_state: raw.servo_state.unwrap_or(default.servo_state),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_connection_type_of_the_mavlink_crate_is_accepted() {
        for ok in [
            "udpin:0.0.0.0:14560",
            "udpout:127.0.0.1:14550",
            "udpbcast:192.168.1.255:14550",
            "tcpin:0.0.0.0:5760",
            "tcpout:127.0.0.1:5760",
            "serial:/dev/ttyAMA0:921600",
            "serial:COM3:57600",
            "udpin:[::]:14560",
        ] {
            assert_eq!(check_connection(ok), Ok(()), "{ok}");
            assert!(
                ::mavlink::ConnectionAddress::parse_address(ok).is_ok(),
                "the mavlink crate refuses {ok}"
            );
        }
    }

    #[test]
    fn malformed_connections_are_refused_with_the_reason() {
        let cases = [
            ("udp:0.0.0.0:14560", "not a connection type"),
            ("0.0.0.0:14560", "not a connection type"),
            ("localhost", "no connection type"),
            ("udpin:14560", "no port"),
            ("udpin::14560", "names no host"),
            ("udpin:0.0.0.0:port", "not a port number"),
            ("udpin:0.0.0.0:70000", "not a port number"),
            ("serial:/dev/ttyAMA0", "no baud rate"),
            ("serial::921600", "names no serial port"),
            ("serial:/dev/ttyAMA0:fast", "not a baud rate"),
        ];
        for (address, reason) in cases {
            let e = check_connection(address).expect_err(address);
            assert!(e.contains(reason), "{address}: {e}");
        }
    }

    #[test]
    fn sources_are_named_after_their_messages() {
        assert_eq!(Source::default(), Source::ServoOutputRaw);
        assert_eq!(Source::ServoOutputRaw.message_id(), 36);
        assert_eq!(Source::ActuatorOutputStatus.message_id(), 375);
        assert_eq!(
            Source::ActuatorOutputStatus.to_string(),
            "ACTUATOR_OUTPUT_STATUS"
        );
    }
}

//! Mapping files and the output → position mapping.
//!
//! A mapping file (`mappings/*.toml`, one per airframe) says where the autopilot is
//! (`[mavlink]`), what the bridge reports (`[telemetry]`), how it stops (`[bridge]`), which
//! RS485 lines exist (`[[bus]]`) and which autopilot output drives which servo (`[[servo]]`).
//! The files in `mappings/` are commented for a new user; the keys and their defaults:
//!
//! | table | key | default | meaning |
//! |---|---|---|---|
//! | `[mavlink]` | `connection` | (required) | `udpin:`, `udpout:`, `udpbcast:`, `tcpin:`, `tcpout:` or `serial:<port>:<baud>` |
//! | | `system_id` | from the autopilot's heartbeat | the vehicle's system id, used by the bridge's own messages |
//! | | `autopilot_system_id` | `system_id`, else the first autopilot heartbeat | whose outputs are obeyed |
//! | | `autopilot_component_id` | 1 | the autopilot's component |
//! | | `component_id` | 140 (MAV_COMP_ID_SERVO1) | the bridge's component |
//! | | `source` | `"SERVO_OUTPUT_RAW"` | or `"ACTUATOR_OUTPUT_STATUS"` (PX4) |
//! | | `output_rate_hz` | 50 | requested rate; ArduPilot denies more than 0.8 × SCHED_LOOP_RATE |
//! | | `failsafe_timeout_ms` | 500 | no message carrying a servo's channel for this long → its failsafe |
//! | | `gcs` | none | an extra telemetry-only output (the autopilot's HEARTBEAT is relayed there), e.g. `udpout:127.0.0.1:14550` |
//! | | `signing_key` / `signing_key_file` / `signing_passphrase` | none (signing off) | MAVLink 2 signing: 64 hex digits, a file of them (or of 32 raw bytes), or MAVProxy's passphrase; at most one |
//! | | `signing_timestamp_file` | `<mapping file>.signing-timestamp` | where the signing timestamp's reservation is kept |
//! | `[telemetry]` | `rate_hz` | 1 | how often NAMED_VALUE_FLOAT values are looked at; sent when changed, or every 5 s |
//! | | `named_values` | `["pos", "cur", "tmp", "vlt"]` | which quantities go out as NAMED_VALUE_FLOAT |
//! | | `esc_info_hz`, `esc_status_hz` | 1, 1 | the rates of ESC_INFO and ESC_STATUS |
//! | | `esc_index_base` | 16 | the ESC index of the first servo (clear of motor ESCs) |
//! | | `named_value_float`, `esc`, `statustext`, `servo_state` | true | which carriers are sent |
//! | `[record]` | `aircraft` | the host name | the aircraft's name in every record file (one baseline per name) |
//! | | `enabled`, `dir`, `max_total_mb` | true, `records/` beside the mapping, 512 | the flight record, its folder, its disk budget |
//! | `[bridge]` | `on_exit` | `"hold"` | `"hold"`, `"off"` or `"brake"` when the bridge stops |
//! | | `while_safe` | `"hold"` | `"hold"`, `"off"` or `"brake"` for a servo off ArduPilot's `BRD_SAFETY_MASK` while its safety switch is on |
//! | | `commands` | `"mavlink"` | where the goals come from: `"mavlink"` (outputs, DO_SET_SERVO) or `"dronecan"` (ArrayCommand; needs `[dronecan]`) |
//! | `[dronecan]` | `interface`, `node_id` | (required) | `"can0"` (SocketCAN) or `"mcast:N"` (ArduPilot SITL's multicast CAN); the node's id, 1–125, or `"dynamic"` (asked of the bus's allocator) |
//! | | `unitless` | `"ardupilot"` | what an UNITLESS command means: ArduPilot's pulse, or `"normalized"` (±1 ↔ ±25 mm) |
//! | | `status_hz` | 10 | each servo's actuator Status per second, 1–50 |
//! | `[[bus]]` | `name`, `port` | (required) | the bus's name and serial port |
//! | | `baud` | 115200 | one of the servo's rates, 9600 … 460800 |
//! | | `turnaround_ms` | bus master's own | extra reply allowance (return delay + adapter latency) |
//! | | `soft_start_mm_s` | 10 | speed of the first move after the bridge switches a servo's force on, 1–105 mm/s |
//! | | `telemetry_hz` | 50 | reads of position and current per servo per second, or `"max"` (every free moment) |
//! | | `rs485` | none (the port's setting is left alone) | `{ rts_on_send, rts_after_send, delay_before_send_ms, delay_after_send_ms, rx_during_tx }`: the kernel's RS485 mode for a UART whose transceiver's driver enable is on RTS (see `docs/rs485.md`) |
//! | `[[servo]]` | `name`, `bus`, `id`, `channel` | (required) | name, bus, ID 1–127, output 1–32 |
//! | | `label` | name if ≤ 6 chars, else `s<n>` | NAMED_VALUE_FLOAT prefix, ≤ 6 chars |
//! | | `pwm_min_us`, `pwm_trim_us`, `pwm_max_us` | 920, 1520, 2120 | ↔ −25, 0, +25 mm |
//! | | `travel_mm = [min, max]` or `min_mm`, `max_mm` | ±25 | clamp, servo coordinates |
//! | | `reverse` | false | negate the position |
//! | | `goal_time_ms` | none | Goal Time sent with each move |
//! | | `max_force_percent` | none (servo's own) | Max Force set at start, 1–100 |
//! | | `failsafe` | `"hold"` | `"hold"`, `"off"`, `"brake"` or a position in mm |
//! | | `actuator` | none | also follow MAV_CMD_DO_SET_ACTUATOR actuator 1–126 sent to the bridge |
//! | | `dronecan_id` | `channel` | the ArrayCommand actuator id it follows, 0–255 (ArduPilot: the output's number; PX4: from 0) |
//! | | `named_values` | `[telemetry]`'s | this servo's NAMED_VALUE_FLOAT quantities (`[]`: none), for more servos than a ground station shows names |
//!
//! Reading a file never panics: a garbled or impossible file is refused with a [`ConfigError`]
//! that names the file, line, column, table, key and reason. Unknown keys are refused, so a typo
//! never silently becomes a default. This module does no I/O beyond [`Config::load`] reading
//! the file.
//!
//! One file per idea: [`error`] (located errors), `raw` (the file as written), [`mavlink`]
//! (`[mavlink]`, `[telemetry]`), [`bus`], [`servo`] (and the PWM mapping), [`bridge`], `table`
//! (the `check` output), [`edit`] (changes made by the running bridge, saved into the file).

pub mod bridge;
pub mod bus;
pub mod dronecan;
pub mod edit;
pub mod error;
pub mod mavlink;
mod raw;
pub mod record;
pub mod servo;
pub mod signing_key;
mod table;
pub mod warnings;

pub use bridge::{BridgeSection, CommandSource, ForceAction};
pub use bus::{BusSection, TelemetryRate};
pub use dronecan::{CanInterface, DroneCanConfig, NodeId};
pub use error::{ConfigError, Location};
pub use mavlink::{MavlinkConfig, Quantity, Source, TelemetryConfig};
pub use record::RecordSection;
pub use servo::{FailsafeAction, PwmRange, ServoConfig};

use error::{Doc, entry_scope};
use raw::RawFile;
use std::path::{Path, PathBuf};

/// The built-in airframe of `lj9da-bridge sitl`: `mappings/sitl-default.toml`.
pub const SITL_DEFAULT_TOML: &str = include_str!("../../mappings/sitl-default.toml");

/// The name the built-in airframe's errors and `check` output go by.
pub const SITL_DEFAULT_ORIGIN: &str = "mappings/sitl-default.toml (built in)";

/// A validated mapping file.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    pub mavlink: MavlinkConfig,
    pub telemetry: TelemetryConfig,
    pub buses: Vec<BusSection>,
    pub servos: Vec<ServoConfig>,
    pub bridge: BridgeSection,
    pub record: RecordSection,
    /// The DroneCAN node, with the table; `None`: no node.
    pub dronecan: Option<DroneCanConfig>,
}

impl Config {
    /// Two of the serial ports the mapping opens (the buses', the `serial:` MAVLink links')
    /// that are one device once `resolve` has followed their names (`/dev/serial0` is a link to
    /// `/dev/ttyAMA0` or `/dev/ttyS0` on a Raspberry Pi), said as an error; `None` when each
    /// is a device of its own. [`Config::load`] refuses equal names; this is for `check` and
    /// `run`, which pass [`std::fs::canonicalize`] (a port that does not exist yet resolves to
    /// its own name).
    pub fn shared_device(&self, resolve: impl Fn(&Path) -> Option<PathBuf>) -> Option<String> {
        let mut ports: Vec<(String, &Path)> = self
            .buses
            .iter()
            .map(|b| (format!("bus \"{}\"", b.name), b.port.as_path()))
            .collect();
        for (key, link) in self.mavlink.serial_links() {
            ports.push((format!("[mavlink] {key}"), Path::new(link)));
        }
        // Each name followed once.
        let devices: Vec<PathBuf> = ports
            .iter()
            .map(|(_, p)| resolve(p).unwrap_or_else(|| p.to_path_buf()))
            .collect();
        for (i, ((who, port), device)) in ports.iter().zip(&devices).enumerate() {
            for ((other, other_port), other_device) in ports[..i].iter().zip(&devices) {
                if device == other_device {
                    return Some(format!(
                        "{who} ({}) and {other} ({}) are one device, {}: a serial port carries \
                         one bus or one MAVLink link",
                        port.display(),
                        other_port.display(),
                        device.display()
                    ));
                }
            }
        }
        None
    }

    /// Read and validate the mapping file at `path`.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse_at(&text, &path.display().to_string(), Some(path))
    }

    /// Validate the text of a mapping file; `origin` is the file name used in error messages.
    /// Paths in it (`signing_key_file`, `signing_timestamp_file`) are relative to the current
    /// folder, and a signing timestamp file has no default place (see
    /// [`mavlink::SigningSetup::timestamp_file`]).
    pub fn parse(text: &str, origin: &str) -> Result<Config, ConfigError> {
        Self::parse_at(text, origin, None)
    }

    /// As [`Config::parse`], for the file at `path` (`None`: text without a file).
    pub fn parse_at(text: &str, origin: &str, path: Option<&Path>) -> Result<Config, ConfigError> {
        let doc = Doc::new(text, origin);
        let raw: RawFile = toml::from_str(text).map_err(|e| doc.toml_error(&e))?;
        Self::from_raw(&raw, doc, path)
    }

    /// The built-in airframe used by `lj9da-bridge sitl` without a mapping file: four servos
    /// (aileron_left, aileron_right, elevator, rudder) with IDs 1–4 on channels 1–4 of one bus
    /// named `sim`, whose port is a placeholder that `sitl` replaces with the simulated servos'
    /// pseudo-terminal.
    pub fn default_sitl() -> Config {
        // The embedded file is checked by this module's tests, so it always parses.
        Self::parse(SITL_DEFAULT_TOML, SITL_DEFAULT_ORIGIN)
            .expect("the built-in mappings/sitl-default.toml is valid")
    }

    /// The bus called `name`.
    pub fn bus(&self, name: &str) -> Option<&BusSection> {
        self.buses.iter().find(|b| b.name == name)
    }

    /// The servos on the bus called `bus`, in file order.
    pub fn servos_on<'a>(&'a self, bus: &'a str) -> impl Iterator<Item = &'a ServoConfig> + 'a {
        self.servos.iter().filter(move |s| s.bus == bus)
    }

    /// The resolved table printed by `lj9da-bridge check`: the MAVLink side, the buses, and per
    /// servo its bus, ID, channel, reverse, the position at the PWM range's min / trim / max,
    /// travel, failsafe, max force and goal time.
    pub fn resolved_table(&self) -> String {
        table::resolved_table(self)
    }

    /// What `check` warns about: valid, but not what the author expects (see [`warnings`]).
    pub fn warnings(&self) -> Vec<String> {
        warnings::warnings(self)
    }

    fn from_raw(raw: &RawFile, doc: Doc<'_>, path: Option<&Path>) -> Result<Config, ConfigError> {
        let Some(raw_mavlink) = &raw.mavlink else {
            return Err(doc.error_at(
                Some(0),
                None,
                Some("mavlink"),
                "the file has no [mavlink] table; add one with e.g. connection = \"udpin:0.0.0.0:14560\"",
            ));
        };
        let mavlink =
            MavlinkConfig::from_raw(raw_mavlink.get_ref(), &doc.scope("[mavlink]"), path)?;
        let telemetry = match &raw.telemetry {
            None => TelemetryConfig::default(),
            Some(t) => TelemetryConfig::from_raw(t.get_ref(), &doc.scope("[telemetry]"))?,
        };
        let bridge = match &raw.bridge {
            None => BridgeSection::default(),
            Some(b) => BridgeSection::from_raw(b.get_ref(), &doc.scope("[bridge]"))?,
        };
        let record = match &raw.record {
            None => RecordSection::default(),
            Some(r) => RecordSection::from_raw(r.get_ref(), &doc.scope("[record]"))?,
        };
        let dronecan = raw
            .dronecan
            .as_ref()
            .map(|d| DroneCanConfig::from_raw(d.get_ref(), &doc.scope("[dronecan]")))
            .transpose()?;
        if bridge.commands == CommandSource::DroneCan && dronecan.is_none() {
            let commands = raw
                .bridge
                .as_ref()
                .and_then(|b| b.get_ref().commands.as_ref())
                .expect("commands = \"dronecan\" was read from the [bridge] table");
            return Err(doc.scope("[bridge]").error_on(
                commands,
                "commands",
                "\"dronecan\" needs a [dronecan] table (interface, node_id) to hear the commands on",
            ));
        }

        let mut buses: Vec<BusSection> = Vec::with_capacity(raw.bus.len());
        for (index, spanned) in raw.bus.iter().enumerate() {
            let entry = spanned.get_ref();
            let scope = doc.scope(entry_scope("bus", index, Some(entry.name.get_ref())));
            let bus = BusSection::from_raw(entry, &scope)?;
            for (earlier, raw_earlier) in buses.iter().zip(&raw.bus) {
                let line = line_of(doc, raw_earlier.span().start);
                if earlier.name == bus.name {
                    return Err(scope.error_on(
                        &entry.name,
                        "name",
                        format!(
                            "a bus called \"{}\" is already defined on line {line}; give each [[bus]] its own name",
                            bus.name
                        ),
                    ));
                }
                if earlier.port == bus.port {
                    return Err(scope.error_on(
                        &entry.port,
                        "port",
                        format!(
                            "{} is already the port of bus \"{}\" (line {line}); one serial port carries one bus, so put its servos in that [[bus]]",
                            bus.port.display(),
                            earlier.name
                        ),
                    ));
                }
            }
            for (key, link) in mavlink.serial_links() {
                if Path::new(link) == bus.port {
                    return Err(scope.error_on(
                        &entry.port,
                        "port",
                        format!(
                            "{} is already the MAVLink link's port ([mavlink] {key}); a serial port \
                             carries the autopilot's MAVLink or a servo bus, not both: put the bus \
                             on another UART or a USB adapter",
                            bus.port.display()
                        ),
                    ));
                }
            }
            buses.push(bus);
        }

        if raw.servo.is_empty() {
            return Err(doc.error_at(
                Some(0),
                None,
                Some("servo"),
                "the file has no [[servo]] table; a mapping needs at least one servo",
            ));
        }
        let mut servos: Vec<ServoConfig> = Vec::with_capacity(raw.servo.len());
        for (index, spanned) in raw.servo.iter().enumerate() {
            let entry = spanned.get_ref();
            let scope = doc.scope(entry_scope("servo", index, Some(entry.name.get_ref())));
            let servo = ServoConfig::from_raw(entry, index, &scope)?;
            if !buses.iter().any(|b| b.name == servo.bus) {
                let known = if buses.is_empty() {
                    "the file defines no [[bus]]".to_string()
                } else {
                    format!(
                        "the buses are {}",
                        buses
                            .iter()
                            .map(|b| format!("\"{}\"", b.name))
                            .collect::<Vec<_>>()
                            .join(", ")
                    )
                };
                return Err(scope.error_on(
                    &entry.bus,
                    "bus",
                    format!("no [[bus]] is called \"{}\"; {known}", servo.bus),
                ));
            }
            for (earlier, raw_earlier) in servos.iter().zip(&raw.servo) {
                let line = line_of(doc, raw_earlier.span().start);
                if earlier.name == servo.name {
                    return Err(scope.error_on(
                        &entry.name,
                        "name",
                        format!(
                            "a servo called \"{}\" is already defined on line {line}; give each servo its own name",
                            servo.name
                        ),
                    ));
                }
                if earlier.bus == servo.bus && earlier.id == servo.id {
                    return Err(scope.error_on(
                        &entry.id,
                        "id",
                        format!(
                            "id {} is already used on bus \"{}\" by servo \"{}\" (line {line}); two servos with one ID on a bus cannot be told apart",
                            servo.id, servo.bus, earlier.name
                        ),
                    ));
                }
                if earlier.label.eq_ignore_ascii_case(&servo.label) {
                    let reason = format!(
                        "label \"{}\" is already used by servo \"{}\" (line {line}); set a distinct label (≤ 6 characters)",
                        servo.label, earlier.name
                    );
                    return Err(match &entry.label {
                        Some(label) => scope.error_on(label, "label", reason),
                        None => scope.error_on(&entry.name, "label", reason),
                    });
                }
            }
            servos.push(servo);
        }

        Ok(Config {
            mavlink,
            telemetry,
            buses,
            servos,
            bridge,
            record,
            dronecan,
        })
    }
}

fn line_of(doc: Doc<'_>, offset: usize) -> usize {
    Location::of_offset(doc.text, offset).line
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::{BaudRate, MmCenti, ServoId};

    #[test]
    fn the_built_in_sitl_airframe_is_four_servos_on_bus_sim() {
        let c = Config::default_sitl();
        assert_eq!(c.buses.len(), 1);
        assert_eq!(c.buses[0].name, "sim");
        assert_eq!(c.buses[0].baud, BaudRate::B115200);
        let names: Vec<_> = c.servos.iter().map(|s| s.name.as_str()).collect();
        assert_eq!(
            names,
            ["aileron_left", "aileron_right", "elevator", "rudder"]
        );
        for (i, s) in c.servos.iter().enumerate() {
            assert_eq!(s.bus, "sim");
            assert_eq!(s.id, ServoId::new(i as u8 + 1).unwrap());
            assert_eq!(usize::from(s.channel), i + 1);
            assert_eq!(s.pwm, PwmRange::SERVO_DEFAULT);
        }
        assert_eq!(c.servos_on("sim").count(), 4);
        assert!(c.bus("sim").is_some());
        assert!(c.bus("wing").is_none());
    }

    #[test]
    fn defaults_fill_every_optional_key() {
        let c = Config::parse(
            "[mavlink]\nconnection = \"udpin:0.0.0.0:14560\"\n[[bus]]\nname = \"wing\"\nport = \"/dev/ttyUSB0\"\n[[servo]]\nname = \"aileron_left\"\nbus = \"wing\"\nid = 1\nchannel = 5\n",
            "minimal.toml",
        )
        .unwrap();
        let m = &c.mavlink;
        assert_eq!(m.system_id, None);
        assert_eq!(m.autopilot_system_id, None);
        assert_eq!(m.autopilot_component_id, 1);
        assert_eq!(m.component_id, 140);
        assert_eq!(m.source, Source::ServoOutputRaw);
        assert_eq!(m.output_rate_hz, 50.0);
        assert_eq!(m.failsafe_timeout_ms, 500);
        assert_eq!(m.gcs, None);
        assert_eq!(c.telemetry, TelemetryConfig::default());
        // Defaults that fit a 57 600-baud telemetry radio, ESC indexes clear of motor ESCs.
        assert_eq!(c.telemetry.rate_hz, 1.0);
        assert_eq!(c.telemetry.esc_info_hz, 1.0);
        assert_eq!(c.telemetry.esc_status_hz, 1.0);
        assert_eq!(c.telemetry.esc_index_base, 16);
        assert_eq!(c.telemetry.named_values, mavlink::Quantity::ALL.to_vec());
        assert_eq!(c.bridge.on_exit, ForceAction::Hold);
        assert_eq!(c.buses[0].baud, BaudRate::B115200);
        assert_eq!(c.buses[0].turnaround_ms, None);
        assert_eq!(c.buses[0].soft_start_mm_s, 10.0);
        let s = &c.servos[0];
        assert_eq!(s.label, "s1");
        assert_eq!(s.channel, 5);
        assert_eq!(s.pwm, PwmRange::SERVO_DEFAULT);
        assert_eq!(s.travel.minus(), MmCenti(-2500));
        assert_eq!(s.travel.plus(), MmCenti(2500));
        assert!(!s.reverse);
        assert_eq!(s.goal_time_ms, None);
        assert_eq!(s.max_force_percent, None);
        assert_eq!(s.failsafe, FailsafeAction::Hold);
    }

    #[test]
    fn one_system_id_stands_for_both_the_vehicle_and_the_autopilot() {
        let base = "[[bus]]\nname = \"b\"\nport = \"p\"\n[[servo]]\nname = \"s\"\nbus = \"b\"\nid = 1\nchannel = 1\n[mavlink]\nconnection = \"udpin:0.0.0.0:14560\"\n";
        let c = Config::parse(&format!("{base}system_id = 7\n"), "t.toml").unwrap();
        assert_eq!(c.mavlink.system_id, Some(7));
        assert_eq!(c.mavlink.autopilot_system_id, Some(7));
        let c = Config::parse(&format!("{base}autopilot_system_id = 3\n"), "t.toml").unwrap();
        assert_eq!(c.mavlink.system_id, Some(3));
        assert_eq!(c.mavlink.autopilot_system_id, Some(3));
    }

    #[test]
    fn a_missing_file_is_reported_with_its_path() {
        let e = Config::load(Path::new("/nonexistent/plane.toml")).unwrap_err();
        assert!(matches!(e, ConfigError::Read { .. }));
        assert!(e.to_string().contains("/nonexistent/plane.toml"), "{e}");
    }
}

//! The bridge's MAVLink parameters: what a ground station's parameter page shows and may
//! change, and how a change becomes an edit of the mapping file.
//!
//! The parameters are the mapping file's values that take effect at the next goal (a servo's
//! channel, PWM range, reverse, travel, failsafe, actuator; the failsafe timeout, the output
//! rate asked of the autopilot and the telemetry rates), plus read-only values worth seeing
//! (each servo's ID, model, firmware and bus baud). Names are `BRG_…` for the bridge and
//! `S<n>_…` for the n-th `[[servo]]` table of the file (from 1); the full table is in the
//! README.
//!
//! Not parameters: the servo's own registers in flash (limits, punch, dead band, …), `goal_time_ms`
//! and `max_force_percent` (written to the servo when its bus starts). `lj9da-bridge set`
//! changes the first with its own refusals and an explicit save; the others take a restart.
//!
//! **Encoding.** Every parameter is sent as MAV_PARAM_TYPE_REAL32. A ground station decodes an
//! integer parameter either by C cast (ArduPilot's convention, MAVProxy and pymavlink) or
//! byte-wise (PX4's); QGroundControl picks by the vehicle's autopilot, and the bridge lives on
//! vehicles of both. A REAL32 value reads the same under both, and every value here (at most
//! 460 800, or a position in 0.01 mm) is exact in an `f32`. AUTOPILOT_VERSION declares C-cast
//! encoding, which REAL32 values satisfy.
//!
//! A PARAM_SET is refused before the file is touched when its value is not a number, is not a
//! whole number where one is needed, has another type than REAL32, or names a read-only
//! parameter; everything else is decided by the file reader itself ([`crate::config::edit`]).

use crate::config::edit::{Edit, Section, TravelEnd};
use crate::config::{Config, FailsafeAction};
use mavlink::dialects::common::MavParamType;
use toml_edit::Value;

/// The type of every parameter (see the module docs).
pub const PARAM_TYPE: MavParamType = MavParamType::MAV_PARAM_TYPE_REAL32;

/// The longest parameter name MAVLink carries.
pub const NAME_MAX_LEN: usize = 16;

/// A bridge-wide parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BridgeParam {
    /// `[mavlink] failsafe_timeout_ms`.
    FailsafeMs,
    /// `[mavlink] output_rate_hz`.
    OutputHz,
    /// `[telemetry] rate_hz`.
    TelemetryHz,
    /// `[telemetry] esc_info_hz`.
    EscInfoHz,
    /// `[telemetry] esc_status_hz`.
    EscStatusHz,
}

/// A parameter of one servo.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ServoParam {
    Channel,
    PwmMin,
    PwmTrim,
    PwmMax,
    Reverse,
    /// 0 hold, 1 off, 2 brake, 3 go to `FailsafePos`.
    FailsafeAction,
    FailsafePos,
    TravelMin,
    TravelMax,
    /// 0: none.
    Actuator,
    /// Read-only.
    Id,
    /// Read-only; 0 until read from the servo.
    Model,
    /// Read-only; 0 until read from the servo.
    Firmware,
    /// Read-only: the bus's baud rate.
    Baud,
}

const BRIDGE_PARAMS: [(BridgeParam, &str); 5] = [
    (BridgeParam::FailsafeMs, "BRG_FS_MS"),
    (BridgeParam::OutputHz, "BRG_OUT_HZ"),
    (BridgeParam::TelemetryHz, "BRG_TLM_HZ"),
    (BridgeParam::EscInfoHz, "BRG_ESCI_HZ"),
    (BridgeParam::EscStatusHz, "BRG_ESCS_HZ"),
];

const SERVO_PARAMS: [(ServoParam, &str); 14] = [
    (ServoParam::Channel, "CHAN"),
    (ServoParam::PwmMin, "PWM_MIN"),
    (ServoParam::PwmTrim, "PWM_TRIM"),
    (ServoParam::PwmMax, "PWM_MAX"),
    (ServoParam::Reverse, "REV"),
    (ServoParam::FailsafeAction, "FS_ACT"),
    (ServoParam::FailsafePos, "FS_POS"),
    (ServoParam::TravelMin, "TRAV_MIN"),
    (ServoParam::TravelMax, "TRAV_MAX"),
    (ServoParam::Actuator, "ACTUATOR"),
    (ServoParam::Id, "ID"),
    (ServoParam::Model, "MODEL"),
    (ServoParam::Firmware, "FW"),
    (ServoParam::Baud, "BAUD"),
];

/// One parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Param {
    Bridge(BridgeParam),
    /// The servo's place in the mapping file (from 0).
    Servo(usize, ServoParam),
}

/// What the bridge knows of a servo beyond its mapping (read from the servo at start).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServoInfo {
    pub model: Option<u16>,
    pub firmware: Option<u8>,
}

/// Why a PARAM_SET is refused before the file is touched.
#[derive(Debug, Clone, PartialEq)]
pub enum Refusal {
    ReadOnly,
    NotANumber,
    NotWhole,
    WrongType(MavParamType),
    /// `S<n>_FS_POS` while `S<n>_FS_ACT` is not 3.
    FailsafePosUnused,
    OutOfRange(&'static str),
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Refusal::ReadOnly => f.write_str("read-only"),
            Refusal::NotANumber => f.write_str("not a number"),
            Refusal::NotWhole => f.write_str("needs a whole number"),
            Refusal::WrongType(t) => write!(f, "type {} not REAL32", *t as u8),
            Refusal::FailsafePosUnused => f.write_str("used only when FS_ACT=3"),
            Refusal::OutOfRange(range) => write!(f, "outside {range}"),
        }
    }
}

/// The parameters of a mapping, in the order of their MAVLink index.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamTable {
    params: Vec<Param>,
}

impl ParamTable {
    pub fn new(cfg: &Config) -> Self {
        let bridge = BRIDGE_PARAMS.iter().map(|(p, _)| Param::Bridge(*p));
        let servos = (0..cfg.servos.len())
            .flat_map(|i| SERVO_PARAMS.iter().map(move |(p, _)| Param::Servo(i, *p)));
        ParamTable {
            params: bridge.chain(servos).collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.params.len()
    }

    pub fn is_empty(&self) -> bool {
        self.params.is_empty()
    }

    pub fn get(&self, index: usize) -> Option<Param> {
        self.params.get(index).copied()
    }

    /// The index of the parameter called `name` (exact, as MAVLink names are).
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.params.iter().position(|p| p.name() == name)
    }

    pub fn iter(&self) -> impl Iterator<Item = Param> + '_ {
        self.params.iter().copied()
    }
}

impl Param {
    /// Its MAVLink name, at most [`NAME_MAX_LEN`] characters.
    pub fn name(self) -> String {
        match self {
            Param::Bridge(p) => BRIDGE_PARAMS
                .iter()
                .find(|(q, _)| *q == p)
                .map(|(_, n)| (*n).to_string())
                .unwrap_or_default(),
            Param::Servo(i, p) => {
                let suffix = SERVO_PARAMS
                    .iter()
                    .find(|(q, _)| *q == p)
                    .map(|(_, n)| *n)
                    .unwrap_or_default();
                format!("S{}_{suffix}", i + 1)
            }
        }
    }

    pub fn read_only(self) -> bool {
        matches!(
            self,
            Param::Servo(
                _,
                ServoParam::Id | ServoParam::Model | ServoParam::Firmware | ServoParam::Baud
            )
        )
    }

    /// Its value under `cfg`; `info` holds what was read from each servo (mapping order).
    pub fn value(self, cfg: &Config, info: &[ServoInfo]) -> f32 {
        match self {
            Param::Bridge(p) => match p {
                BridgeParam::FailsafeMs => cfg.mavlink.failsafe_timeout_ms as f32,
                BridgeParam::OutputHz => cfg.mavlink.output_rate_hz,
                BridgeParam::TelemetryHz => cfg.telemetry.rate_hz,
                BridgeParam::EscInfoHz => cfg.telemetry.esc_info_hz,
                BridgeParam::EscStatusHz => cfg.telemetry.esc_status_hz,
            },
            Param::Servo(i, p) => {
                let Some(s) = cfg.servos.get(i) else {
                    return 0.0;
                };
                let info = info.get(i).copied().unwrap_or_default();
                match p {
                    ServoParam::Channel => f32::from(s.channel),
                    ServoParam::PwmMin => f32::from(s.pwm.min_us),
                    ServoParam::PwmTrim => f32::from(s.pwm.trim_us),
                    ServoParam::PwmMax => f32::from(s.pwm.max_us),
                    ServoParam::Reverse => f32::from(u8::from(s.reverse)),
                    ServoParam::FailsafeAction => match s.failsafe {
                        FailsafeAction::Hold => 0.0,
                        FailsafeAction::Off => 1.0,
                        FailsafeAction::Brake => 2.0,
                        FailsafeAction::Position(_) => 3.0,
                    },
                    ServoParam::FailsafePos => match s.failsafe {
                        FailsafeAction::Position(p) => p.mm() as f32,
                        _ => 0.0,
                    },
                    ServoParam::TravelMin => s.travel.minus().mm() as f32,
                    ServoParam::TravelMax => s.travel.plus().mm() as f32,
                    ServoParam::Actuator => s.actuator.map_or(0.0, f32::from),
                    ServoParam::Id => f32::from(s.id.get()),
                    ServoParam::Model => info.model.map_or(0.0, f32::from),
                    ServoParam::Firmware => info.firmware.map_or(0.0, f32::from),
                    ServoParam::Baud => cfg
                        .bus(&s.bus)
                        .map_or(0.0, |b| b.baud.bits_per_second() as f32),
                }
            }
        }
    }

    /// The change of the mapping file that sets this parameter to `value`, sent with type
    /// `ty`. An empty list: the value is already so, nothing to change.
    pub fn edits(self, cfg: &Config, value: f32, ty: MavParamType) -> Result<Vec<Edit>, Refusal> {
        if self.read_only() {
            return Err(Refusal::ReadOnly);
        }
        if ty != PARAM_TYPE {
            return Err(Refusal::WrongType(ty));
        }
        if !value.is_finite() {
            return Err(Refusal::NotANumber);
        }
        let whole = || {
            if value.fract() == 0.0 {
                Ok(value as i64)
            } else {
                Err(Refusal::NotWhole)
            }
        };
        let set = |section, key, value| {
            Ok(vec![Edit::Set {
                section,
                key,
                value,
            }])
        };
        match self {
            Param::Bridge(p) => match p {
                BridgeParam::FailsafeMs => {
                    set(Section::Mavlink, "failsafe_timeout_ms", whole()?.into())
                }
                BridgeParam::OutputHz => set(Section::Mavlink, "output_rate_hz", real(value)),
                BridgeParam::TelemetryHz => set(Section::Telemetry, "rate_hz", real(value)),
                BridgeParam::EscInfoHz => set(Section::Telemetry, "esc_info_hz", real(value)),
                BridgeParam::EscStatusHz => set(Section::Telemetry, "esc_status_hz", real(value)),
            },
            Param::Servo(i, p) => {
                let section = Section::Servo(i);
                let failsafe = cfg.servos.get(i).map(|s| s.failsafe).unwrap_or_default();
                match p {
                    ServoParam::Channel => set(section, "channel", whole()?.into()),
                    ServoParam::PwmMin => set(section, "pwm_min_us", whole()?.into()),
                    ServoParam::PwmTrim => set(section, "pwm_trim_us", whole()?.into()),
                    ServoParam::PwmMax => set(section, "pwm_max_us", whole()?.into()),
                    ServoParam::Reverse => match whole()? {
                        0 => set(section, "reverse", false.into()),
                        1 => set(section, "reverse", true.into()),
                        _ => Err(Refusal::OutOfRange("0-1")),
                    },
                    ServoParam::FailsafeAction => {
                        let action = match whole()? {
                            0 => "hold",
                            1 => "off",
                            2 => "brake",
                            3 => {
                                // Keep a position already set; else the centre, until
                                // FS_POS says otherwise.
                                let mm = match failsafe {
                                    FailsafeAction::Position(p) => p.mm() as f32,
                                    _ => 0.0,
                                };
                                return set(section, "failsafe", real(mm));
                            }
                            _ => return Err(Refusal::OutOfRange("0-3")),
                        };
                        set(section, "failsafe", action.into())
                    }
                    ServoParam::FailsafePos => match failsafe {
                        FailsafeAction::Position(_) => set(section, "failsafe", real(value)),
                        // What the parameter page shows then: setting it is no change.
                        _ if value == 0.0 => Ok(Vec::new()),
                        _ => Err(Refusal::FailsafePosUnused),
                    },
                    ServoParam::TravelMin | ServoParam::TravelMax => Ok(vec![Edit::Travel {
                        servo: i,
                        end: if p == ServoParam::TravelMin {
                            TravelEnd::Min
                        } else {
                            TravelEnd::Max
                        },
                        mm: f64::from(value),
                    }]),
                    ServoParam::Actuator => match whole()? {
                        0 => Ok(vec![Edit::Remove {
                            section,
                            key: "actuator",
                        }]),
                        n => set(section, "actuator", n.into()),
                    },
                    ServoParam::Id
                    | ServoParam::Model
                    | ServoParam::Firmware
                    | ServoParam::Baud => Err(Refusal::ReadOnly),
                }
            }
        }
    }
}

/// The parameters and their values as `check` prints them: one line for the bridge, one per
/// servo (read-only values from the servo itself show as `?`).
pub fn listing(cfg: &Config) -> String {
    let table = ParamTable::new(cfg);
    let mut out = format!(
        "MAVLink parameters of component {} ({} in all; set from a ground station, saved into this file):\n",
        cfg.mavlink.component_id,
        table.len()
    );
    let mut line = |label: &str, params: &mut dyn Iterator<Item = Param>| {
        let items: Vec<String> = params
            .map(|p| match p {
                Param::Servo(_, ServoParam::Model | ServoParam::Firmware) => {
                    format!("{}=?", p.name())
                }
                _ => format!("{}={}", p.name(), p.value(cfg, &[])),
            })
            .collect();
        out.push_str(&format!("  {label}: {}\n", items.join(" ")));
    };
    line(
        "bridge",
        &mut table.iter().filter(|p| matches!(p, Param::Bridge(_))),
    );
    for (i, servo) in cfg.servos.iter().enumerate() {
        line(
            &servo.name,
            &mut table
                .iter()
                .filter(|p| matches!(p, Param::Servo(j, _) if *j == i)),
        );
    }
    out.push_str("  (S<n>_ID, _MODEL, _FW and _BAUD are read-only)\n");
    out
}

/// An `f32` as the decimal a person would write (`12.3`, not `12.300000190734863`).
fn real(value: f32) -> Value {
    let shortest: f64 = value.to_string().parse().unwrap_or(f64::from(value));
    Value::from(shortest)
}

/// Copy what the parameters can change from `from` into `into`, leaving the rest of `into`
/// (connection addresses, ports, ids set by the command line) as the run has it.
pub fn copy_tunables(from: &Config, into: &mut Config) {
    into.mavlink.failsafe_timeout_ms = from.mavlink.failsafe_timeout_ms;
    into.mavlink.output_rate_hz = from.mavlink.output_rate_hz;
    into.telemetry.rate_hz = from.telemetry.rate_hz;
    into.telemetry.esc_info_hz = from.telemetry.esc_info_hz;
    into.telemetry.esc_status_hz = from.telemetry.esc_status_hz;
    for (to, from) in into.servos.iter_mut().zip(&from.servos) {
        to.channel = from.channel;
        to.pwm = from.pwm;
        to.reverse = from.reverse;
        to.failsafe = from.failsafe;
        to.travel = from.travel;
        to.actuator = from.actuator;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::edit::MappingFile;

    const FILE: &str = r#"
[mavlink]
connection = "udpin:0.0.0.0:14560"

[[bus]]
name = "wing"
port = "/dev/ttyUSB0"
baud = 230400

[[servo]]
name = "aileron_left"
bus = "wing"
id = 7
channel = 1
failsafe = "brake"

[[servo]]
name = "rudder"
bus = "wing"
id = 2
channel = 4
failsafe = -3.5
"#;

    fn cfg() -> Config {
        Config::parse(FILE, "t.toml").unwrap()
    }

    fn set(file: &mut MappingFile, name: &str, value: f32) -> Result<Config, String> {
        let cfg = Config::parse(&file.text(), "t.toml").unwrap();
        let table = ParamTable::new(&cfg);
        let param = table.get(table.index_of(name).expect(name)).unwrap();
        let edits = param
            .edits(&cfg, value, PARAM_TYPE)
            .map_err(|r| r.to_string())?;
        file.apply(&edits).map_err(|e| e.reason())
    }

    #[test]
    fn names_fit_in_sixteen_characters_are_unique_and_indexed_in_order() {
        let mut text = format!("{FILE}\n[[bus]]\nname = \"tail\"\nport = \"/dev/ttyUSB1\"\n");
        for i in 3..=127 {
            text.push_str(&format!(
                "\n[[servo]]\nname = \"s{i}\"\nbus = \"tail\"\nid = {}\nchannel = {}\n",
                i - 2,
                (i % 32) + 1
            ));
        }
        let cfg = Config::parse(&text, "many.toml").unwrap();
        let table = ParamTable::new(&cfg);
        assert_eq!(table.len(), 5 + 127 * 14);
        let mut names = std::collections::HashSet::new();
        for (i, p) in table.iter().enumerate() {
            let name = p.name();
            assert!(name.len() <= NAME_MAX_LEN, "{name}");
            assert_eq!(table.index_of(&name), Some(i));
            assert!(names.insert(name));
        }
        assert!(names.contains("S127_ACTUATOR"));
    }

    #[test]
    fn values_are_the_mappings_and_what_was_read_from_the_servo() {
        let cfg = cfg();
        let table = ParamTable::new(&cfg);
        let info = [ServoInfo {
            model: Some(0x4c4a),
            firmware: Some(3),
        }];
        let value = |name: &str| {
            table
                .get(table.index_of(name).unwrap())
                .unwrap()
                .value(&cfg, &info)
        };
        assert_eq!(value("BRG_FS_MS"), 500.0);
        assert_eq!(value("BRG_OUT_HZ"), 50.0);
        assert_eq!(value("S1_PWM_TRIM"), 1520.0);
        assert_eq!(value("S1_FS_ACT"), 2.0);
        assert_eq!(value("S1_FS_POS"), 0.0);
        assert_eq!(value("S2_FS_ACT"), 3.0);
        assert_eq!(value("S2_FS_POS"), -3.5);
        assert_eq!(value("S1_ID"), 7.0);
        assert_eq!(value("S1_MODEL"), f32::from(0x4c4a_u16));
        assert_eq!(value("S1_FW"), 3.0);
        assert_eq!(value("S2_MODEL"), 0.0, "not read yet");
        assert_eq!(value("S2_BAUD"), 230400.0);
        assert_eq!(value("S1_TRAV_MIN"), -25.0);
    }

    #[test]
    fn a_set_is_checked_by_the_file_reader_and_reads_back_as_stored() {
        let mut file = MappingFile::in_memory(FILE, "t.toml").unwrap();
        let cfg = set(&mut file, "S1_PWM_TRIM", 1500.0).unwrap();
        assert_eq!(cfg.servos[0].pwm.trim_us, 1500);
        let err = set(&mut file, "S1_PWM_TRIM", 2500.0).unwrap_err();
        assert!(err.contains("2500"), "{err}");
        let cfg = set(&mut file, "S2_FS_POS", 12.345).unwrap();
        // The file keeps 0.01 mm: the parameter reads back what the bridge will use.
        assert_eq!(
            cfg.servos[1].failsafe,
            FailsafeAction::Position(MmCenti(1235))
        );
        assert!(file.text().contains("failsafe = 12.345"), "{}", file.text());
        let err = set(&mut file, "S1_TRAV_MAX", 30.0).unwrap_err();
        assert!(err.contains("beyond the stroke"), "{err}");
        let err = set(&mut file, "BRG_OUT_HZ", 0.0).unwrap_err();
        assert!(!err.is_empty());
    }

    use crate::protocol::MmCenti;

    #[test]
    fn refusals_before_the_file_is_touched() {
        let cfg = cfg();
        let table = ParamTable::new(&cfg);
        let param = |name: &str| table.get(table.index_of(name).unwrap()).unwrap();
        let refuse = |name: &str, value: f32, ty| param(name).edits(&cfg, value, ty).unwrap_err();
        assert_eq!(refuse("S1_ID", 3.0, PARAM_TYPE), Refusal::ReadOnly);
        assert_eq!(refuse("S1_BAUD", 9600.0, PARAM_TYPE), Refusal::ReadOnly);
        assert_eq!(
            refuse("S1_PWM_TRIM", f32::NAN, PARAM_TYPE),
            Refusal::NotANumber
        );
        assert_eq!(
            refuse("BRG_OUT_HZ", f32::INFINITY, PARAM_TYPE),
            Refusal::NotANumber
        );
        assert_eq!(refuse("S1_PWM_TRIM", 1500.5, PARAM_TYPE), Refusal::NotWhole);
        assert_eq!(
            refuse("S1_PWM_TRIM", 1500.0, MavParamType::MAV_PARAM_TYPE_INT32),
            Refusal::WrongType(MavParamType::MAV_PARAM_TYPE_INT32)
        );
        assert_eq!(
            refuse("S1_REV", 2.0, PARAM_TYPE),
            Refusal::OutOfRange("0-1")
        );
        assert_eq!(
            refuse("S1_FS_ACT", 4.0, PARAM_TYPE),
            Refusal::OutOfRange("0-3")
        );
        assert_eq!(
            refuse("S1_FS_POS", 5.0, PARAM_TYPE),
            Refusal::FailsafePosUnused
        );
        assert!(
            param("S1_FS_POS")
                .edits(&cfg, 0.0, PARAM_TYPE)
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn failsafe_action_and_position_and_actuator_round_trip_through_the_file() {
        let mut file = MappingFile::in_memory(FILE, "t.toml").unwrap();
        let cfg = set(&mut file, "S1_FS_ACT", 3.0).unwrap();
        assert_eq!(cfg.servos[0].failsafe, FailsafeAction::Position(MmCenti(0)));
        let cfg = set(&mut file, "S1_FS_POS", -7.5).unwrap();
        assert_eq!(
            cfg.servos[0].failsafe,
            FailsafeAction::Position(MmCenti(-750))
        );
        let cfg = set(&mut file, "S1_FS_ACT", 1.0).unwrap();
        assert_eq!(cfg.servos[0].failsafe, FailsafeAction::Off);
        let cfg = set(&mut file, "S2_ACTUATOR", 5.0).unwrap();
        assert_eq!(cfg.servos[1].actuator, Some(5));
        let cfg = set(&mut file, "S2_ACTUATOR", 0.0).unwrap();
        assert_eq!(cfg.servos[1].actuator, None);
        assert!(!file.text().contains("actuator"));
        let cfg = set(&mut file, "S2_REV", 1.0).unwrap();
        assert!(cfg.servos[1].reverse);
        let cfg = set(&mut file, "BRG_TLM_HZ", 2.5).unwrap();
        assert_eq!(cfg.telemetry.rate_hz, 2.5);
        assert!(file.text().contains("rate_hz = 2.5"));
    }

    #[test]
    fn check_lists_every_parameter_with_its_value() {
        let text = listing(&cfg());
        assert!(text.contains("component 140 (33 in all"), "{text}");
        assert!(
            text.contains("  bridge: BRG_FS_MS=500 BRG_OUT_HZ=50 "),
            "{text}"
        );
        assert!(
            text.contains("  rudder: S2_CHAN=4 S2_PWM_MIN=920 S2_PWM_TRIM=1520 "),
            "{text}"
        );
        assert!(text.contains("S2_FS_ACT=3 S2_FS_POS=-3.5 "), "{text}");
        assert!(text.contains("S1_MODEL=? S1_FW=? S1_BAUD=230400"), "{text}");
    }

    #[test]
    fn only_tunables_are_copied_into_the_running_configuration() {
        let mut running = cfg();
        running.mavlink.connection = "udpin:127.0.0.1:9999".into();
        let mut file = MappingFile::in_memory(FILE, "t.toml").unwrap();
        let changed = set(&mut file, "S2_CHAN", 9.0).unwrap();
        copy_tunables(&changed, &mut running);
        assert_eq!(running.servos[1].channel, 9);
        assert_eq!(running.mavlink.connection, "udpin:127.0.0.1:9999");
    }
}

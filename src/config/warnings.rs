//! What `lj9da-bridge check` warns about: a mapping that is valid but will not do what its
//! author expects with a given autopilot or ground station. Warnings never refuse a file.

use super::bus::{TelemetryRate, max_telemetry_hz};
use super::{BusSection, Config, Source};
use std::time::Duration;

/// How many NAMED_VALUE_FLOAT names Mission Planner shows (`CurrentState.cs` keeps 20 slots,
/// taken in order of arrival): a name past the 20th never appears in its Status tab.
pub const MISSION_PLANNER_NAMED_VALUES: usize = 20;

/// The first channel SERVO_OUTPUT_RAW carries with `port = 1`.
const FIRST_PORT_1_CHANNEL: u8 = 17;

/// Each warning as one paragraph that names the servo or key and says what to do.
pub fn warnings(cfg: &Config) -> Vec<String> {
    let mut out = Vec::new();
    out.extend(px4_port_1_channels(cfg));
    out.extend(mission_planner_names(cfg));
    out.extend(unsigned_outside_links(cfg));
    out.extend(
        cfg.buses
            .iter()
            .filter_map(|b| telemetry_beyond_wire(cfg, b)),
    );
    out.extend(cfg.buses.iter().filter_map(rs485_hold_after_send));
    out.extend(cfg.buses.iter().filter_map(rs485_on_usb_adapter));
    out
}

/// A bus asking for the kernel's RS485 mode on what its name says is a USB adapter: those
/// switch direction by themselves and their drivers have no RS485 mode, so the bus would not
/// start.
pub fn rs485_on_usb_adapter(bus: &BusSection) -> Option<String> {
    bus.rs485?;
    let port = bus.port.to_string_lossy();
    let usb = ["/ttyUSB", "/ttyACM", "/serial/by-id/usb-"]
        .iter()
        .any(|p| port.contains(p))
        || (port.contains("/serial/by-path/") && port.contains("-usb-"));
    usb.then(|| {
        format!(
            "warning: bus \"{}\" asks for RS485 mode (rs485 = {{ … }}) on {port}, a USB \
             adapter by its name: USB–RS485 adapters switch direction by themselves and their \
             drivers refuse RS485 mode, so this bus would not start. Remove `rs485` from it; it \
             is for an RS485 board on a UART (/dev/ttyAMA0, /dev/serial0).",
            bus.name
        )
    })
}

/// A bus whose transceiver stays driven after each packet: a servo that answers sooner (its
/// Return Delay Time, register 7, is 0 ms from the factory) is talked over. (Said by `check`,
/// and once when the bridge starts.)
pub fn rs485_hold_after_send(bus: &BusSection) -> Option<String> {
    let ms = bus.rs485?.delay_after_send_ms;
    (ms > 0).then(|| {
        format!(
            "warning: bus \"{name}\" keeps driving the line {ms} ms after each packet \
             (rs485 delay_after_send_ms = {ms}), while the LJ9DA41 answers after its Return \
             Delay Time (register 7, 0 ms from the factory): every servo on it needs a return \
             delay of at least {ms} ms (lj9da-bridge set --port {port} --id N return-delay={ms} \
             --save), or the start of each reply is lost.",
            name = bus.name,
            port = bus.port.display()
        )
    })
}

/// A bus whose `telemetry_hz` asks more reads than its wire carries: it reads as often as it
/// can, which is what `"max"` says. (Said by `check`, and once when the bridge starts.)
pub fn telemetry_beyond_wire(cfg: &Config, bus: &BusSection) -> Option<String> {
    let TelemetryRate::Hz(asked) = bus.telemetry else {
        return None;
    };
    let servos = cfg.servos_on(&bus.name).count();
    let goal_period = Duration::from_secs_f64(1.0 / f64::from(cfg.mavlink.output_rate_hz));
    let allowed = max_telemetry_hz(bus.baud, servos, goal_period);
    // The estimate is rough: only a rate clearly beyond it is worth a word.
    (servos > 0 && asked > allowed * 1.15).then(|| {
        format!(
            "warning: bus \"{}\" asks telemetry_hz = {asked} for {servos} servo(s) at {}, \
             where the wire carries about {allowed:.0} reads a second per servo beside \
             {} Hz of goals: it reads as often as it can (telemetry_hz = \"max\" says so).",
            bus.name, bus.baud, cfg.mavlink.output_rate_hz
        )
    })
}

/// Whether a connection address stays on this computer: a network address whose host is
/// 127.x.x.x, ::1 or localhost. A serial port, `0.0.0.0` (every interface) and any other host
/// are reachable from outside.
pub fn is_loopback(address: &str) -> bool {
    let Some((scheme, rest)) = address.split_once(':') else {
        return false;
    };
    if scheme == "serial" {
        return false;
    }
    let host = rest.rsplit_once(':').map_or(rest, |(host, _)| host);
    let host = host.trim_start_matches('[').trim_end_matches(']');
    host.eq_ignore_ascii_case("localhost")
        || host
            .parse::<std::net::IpAddr>()
            .is_ok_and(|ip| ip.is_loopback())
}

/// Without signing, anyone who can reach a link can command the servos.
fn unsigned_outside_links(cfg: &Config) -> Option<String> {
    let m = &cfg.mavlink;
    if m.signing.is_some() {
        return None;
    }
    let outside: Vec<String> = [("connection", Some(&m.connection)), ("gcs", m.gcs.as_ref())]
        .into_iter()
        .filter_map(|(key, address)| {
            let address = address?;
            (!is_loopback(address)).then(|| format!("{key} = \"{address}\""))
        })
        .collect();
    if outside.is_empty() {
        return None;
    }
    Some(format!(
        "warning: MAVLink 2 signing is off and {} not on this computer alone (a serial port, or \
         a host other than 127.0.0.1, ::1 or localhost): whoever can send on it can move the \
         servos. If the autopilot signs (ArduPilot; PX4 only from 1.17: not 1.16 or older), set \
         [mavlink] signing_passphrase to the passphrase given to the autopilot (MAVProxy: \
         `signing setup <passphrase>`), or signing_key / signing_key_file: with a key the bridge \
         drops every unsigned message, so an autopilot that does not sign is cut off.",
        if outside.len() == 1 {
            format!("{} is", outside[0])
        } else {
            format!("{} are", outside.join(" and "))
        }
    ))
}

/// PX4 streams its first output driver only, in both messages: SERVO_OUTPUT_RAW port 0
/// (MAV_CMD_SET_MESSAGE_INTERVAL for message 36 reaches the `_0` stream; its `port` numbers
/// drivers, not channels 17–32) and ACTUATOR_OUTPUT_STATUS (PX4's
/// `src/modules/mavlink/streams/ACTUATOR_OUTPUT_STATUS.hpp` reads `actuator_outputs` instance 0,
/// 16 outputs). A servo on channel 17 or above is carried by ArduPilot's SERVO_OUTPUT_RAW port 1
/// alone: from PX4 it would never be commanded, only failsafed.
fn px4_port_1_channels(cfg: &Config) -> Option<String> {
    let high: Vec<String> = cfg
        .servos
        .iter()
        .filter(|s| s.channel >= FIRST_PORT_1_CHANNEL)
        .map(|s| format!("{} (channel {})", s.name, s.channel))
        .collect();
    if high.is_empty() {
        return None;
    }
    let carried = match cfg.mavlink.source {
        Source::ServoOutputRaw => "ArduPilot sends those in SERVO_OUTPUT_RAW port 1; PX4 does not",
        Source::ActuatorOutputStatus => "ACTUATOR_OUTPUT_STATUS from PX4 carries none of them",
    };
    Some(format!(
        "warning: {} read channels 17–32. {carried}: PX4 streams its first output driver's \
         outputs only, in SERVO_OUTPUT_RAW port 0 and ACTUATOR_OUTPUT_STATUS alike. On PX4 put \
         these servos on that driver's outputs (channels 1–16, e.g. MAIN on a board with an I/O \
         processor), or they will only ever take their failsafe action.",
        high.join(", ")
    ))
}

/// Mission Planner shows at most 20 NAMED_VALUE_FLOAT names. The advice is one that fits: a
/// count per servo while one or more each fits, else a list for the servos that matter and
/// none for the rest (a servo's own `named_values`), ESC_INFO carrying every servo anyway.
fn mission_planner_names(cfg: &Config) -> Option<String> {
    let t = &cfg.telemetry;
    if !t.named_value_float {
        return None;
    }
    let names: usize = cfg.servos.iter().map(|s| s.named_values(t).len()).sum();
    if names <= MISSION_PLANNER_NAMED_VALUES {
        return None;
    }
    let servos = cfg.servos.len();
    let said = format!(
        "warning: {servos} servos send {names} NAMED_VALUE_FLOAT names; Mission Planner shows \
         the first {MISSION_PLANNER_NAMED_VALUES} to arrive only (fewer when the autopilot sends \
         names of its own)."
    );
    let esc = "QGroundControl's ESC indicator (5.1 and later; esc = true, ESC_INFO/ESC_STATUS) \
               still shows every servo's current, temperature and voltage.";
    let fit = MISSION_PLANNER_NAMED_VALUES / servos.max(1);
    if fit >= 1 {
        return Some(format!(
            "{said} Choose at most {fit} per servo with [telemetry] named_values (e.g. \
             named_values = [\"pos\"]), or a list of its own in the [[servo]] tables that \
             matter; {esc}"
        ));
    }
    let example: Vec<&str> = cfg
        .servos
        .iter()
        .take(MISSION_PLANNER_NAMED_VALUES)
        .map(|s| s.name.as_str())
        .collect();
    Some(format!(
        "{said} Not even one name per servo fits: set [telemetry] named_values = [] and give \
         at most {MISSION_PLANNER_NAMED_VALUES} servos that matter a list of their own in \
         their [[servo]] table (e.g. named_values = [\"pos\"] for {} …), or set \
         named_value_float = false; {esc}",
        example[..example.len().min(3)].join(", ")
    ))
}

//! The resolved table that `lj9da-bridge check` prints: every default filled in, every mapping
//! evaluated, so that what the bridge will do can be read before it does it.

use super::Config;
use super::servo::ServoConfig;

pub(super) fn resolved_table(config: &Config) -> String {
    let m = &config.mavlink;
    let system = match (m.system_id, m.autopilot_system_id) {
        (Some(own), Some(autopilot)) if own != autopilot => {
            format!("bridge system id {own}, autopilot system id {autopilot}")
        }
        (own, autopilot) => own.or(autopilot).map_or_else(
            || "system id from the first autopilot heartbeat".to_string(),
            |id| format!("system id {id}"),
        ),
    };
    let mut out = format!(
        "mavlink: {} | {system} | autopilot component {} | bridge component {}\n",
        m.connection, m.autopilot_component_id, m.component_id
    );
    out.push_str(&match &m.signing {
        None => "signing: off\n".to_string(),
        Some(s) => format!(
            "signing: MAVLink 2, every message signed and checked ({}) | timestamps kept in {}\n",
            s.key_source,
            s.timestamp_file.as_ref().map_or_else(
                || "the flight record's folder".to_string(),
                |p| p.display().to_string()
            )
        ),
    });
    out.push_str(&format!(
        "outputs: {} requested at {} Hz | failsafe after {} ms without outputs\n",
        m.source, m.output_rate_hz, m.failsafe_timeout_ms
    ));
    let t = &config.telemetry;
    let quantities: Vec<&str> = t.named_values.iter().map(|q| q.key()).collect();
    let named = format!(
        "NAMED_VALUE_FLOAT {} at {} Hz on change",
        quantities.join("/"),
        t.rate_hz
    );
    let esc = format!(
        "ESC_INFO {} Hz + ESC_STATUS {} Hz from ESC index {}",
        t.esc_info_hz, t.esc_status_hz, t.esc_index_base
    );
    let carriers: Vec<&str> = [
        (t.named_value_float, named.as_str()),
        (t.esc, esc.as_str()),
        (t.statustext, "STATUSTEXT"),
        (t.servo_state, "servo states (NAMED_VALUE_INT)"),
    ]
    .into_iter()
    .filter_map(|(on, name)| on.then_some(name))
    .collect();
    out.push_str(&format!(
        "telemetry: {} | extra GCS output: {} | on exit: {} | while the safety is on: {}\n\n",
        if carriers.is_empty() {
            "HEARTBEAT only".to_string()
        } else {
            carriers.join(", ")
        },
        m.gcs.as_deref().unwrap_or("none"),
        config.bridge.on_exit,
        config.bridge.while_safe
    ));
    let commands = match (&config.dronecan, config.bridge.commands) {
        (Some(d), super::CommandSource::DroneCan) => format!(
            "goals from DroneCAN ArrayCommand on {} ({}, UNITLESS as {:?}, actuator Status {} Hz)",
            d.interface,
            node_text(d.node_id),
            d.unitless,
            d.status_hz
        ),
        (Some(d), super::CommandSource::Mavlink) => format!(
            "goals from MAVLink; DroneCAN {} on {} reports only (actuator Status {} Hz)",
            node_text(d.node_id),
            d.interface,
            d.status_hz
        ),
        (None, _) => "goals from MAVLink".to_string(),
    };
    out.push_str(&format!("{commands}\n\n"));

    let mut buses = vec![row([
        "bus",
        "port",
        "baud",
        "turnaround",
        "servos",
        "telemetry (wire allows)",
        "rs485",
    ])];
    let goal_period =
        std::time::Duration::from_secs_f64(1.0 / f64::from(config.mavlink.output_rate_hz));
    for bus in &config.buses {
        let servos = config.servos_on(&bus.name).count();
        let allowed = super::bus::max_telemetry_hz(bus.baud, servos, goal_period);
        buses.push(vec![
            bus.name.clone(),
            bus.port.display().to_string(),
            bus.baud.to_string(),
            bus.turnaround_ms
                .map_or("default".to_string(), |ms| format!("{ms} ms")),
            servos.to_string(),
            format!("{} (≈ {allowed:.0} Hz)", bus.telemetry),
            bus.rs485
                .map_or("port's own".to_string(), |m| m.to_string()),
        ]);
    }
    out.push_str(&aligned(&buses));
    out.push('\n');

    let mut servos = vec![row([
        "servo",
        "label",
        "bus",
        "id",
        "ch",
        "rev",
        "µs → mm at min/trim/max",
        "travel mm",
        "failsafe",
        "force",
        "goal time",
        "actuator",
    ])];
    for s in &config.servos {
        servos.push(vec![
            s.name.clone(),
            s.label.clone(),
            s.bus.clone(),
            s.id.to_string(),
            s.channel.to_string(),
            if s.reverse { "yes" } else { "no" }.to_string(),
            pwm_points(s),
            format!(
                "{:+.2}..{:+.2}",
                s.travel.minus().mm(),
                s.travel.plus().mm()
            ),
            s.failsafe.to_string(),
            s.max_force_percent
                .map_or("servo's".to_string(), |p| p.to_string()),
            s.goal_time_ms
                .map_or("none".to_string(), |ms| format!("{ms} ms")),
            s.actuator.map_or("-".to_string(), |n| n.to_string()),
        ]);
    }
    out.push_str(&aligned(&servos));
    out
}

/// `920→-25.00 1520→+0.00 2120→+25.00`: the resolved position at the range's three points.
fn pwm_points(servo: &ServoConfig) -> String {
    [servo.pwm.min_us, servo.pwm.trim_us, servo.pwm.max_us]
        .into_iter()
        .map(|us| match servo.map_pwm(us) {
            Some(p) => format!("{us}→{:+.2}", p.mm()),
            None => format!("{us}→hold"),
        })
        .collect::<Vec<_>>()
        .join(" ")
}

fn row<const N: usize>(cells: [&str; N]) -> Vec<String> {
    cells.iter().map(|c| c.to_string()).collect()
}

/// Rows as columns separated by two spaces, each as wide as its widest cell (in characters).
fn aligned(rows: &[Vec<String>]) -> String {
    let columns = rows.iter().map(Vec::len).max().unwrap_or(0);
    let widths: Vec<usize> = (0..columns)
        .map(|c| {
            rows.iter()
                .filter_map(|r| r.get(c))
                .map(|cell| cell.chars().count())
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    for r in rows {
        let mut line = String::new();
        for (cell, width) in r.iter().zip(&widths) {
            line.push_str(cell);
            line.push_str(&" ".repeat(width - cell.chars().count() + 2));
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}

/// The DroneCAN node's id as the table says it.
fn node_text(id: super::NodeId) -> String {
    match id {
        super::NodeId::Static(n) => format!("node {n}"),
        super::NodeId::Dynamic => "node with an id from the bus's allocator".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_are_aligned_by_characters() {
        let rows = vec![row(["µs", "b"]), row(["abcd", "e"])];
        assert_eq!(aligned(&rows), "µs    b\nabcd  e\n");
    }

    #[test]
    fn the_sitl_table_shows_the_pwm_law_at_its_three_points() {
        let table = Config::default_sitl().resolved_table();
        assert!(
            table.contains("920→-25.00 1520→+0.00 2120→+25.00"),
            "{table}"
        );
        assert!(table.contains("aileron_left"), "{table}");
        assert!(table.contains("115200 bit/s"), "{table}");
    }
}

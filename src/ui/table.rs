//! The live terminal table of `sitl` (and the final snapshot it prints).

use crate::runtime::BridgeView;
use std::fmt::Write;
use std::time::Duration;
use tokio::sync::watch;

fn opt(v: Option<f32>, width: usize, decimals: usize) -> String {
    match v {
        Some(v) => format!("{v:>width$.decimals$}"),
        None => format!("{:>width$}", "-"),
    }
}

/// What the links dropped, appended to the autopilot line: with signing on, the incoming
/// messages refused; the outgoing ones a link was too slow for (see
/// [`crate::mavlink::outbox`]), once there are any; and the incoming datagrams the kernel
/// dropped before the bridge read them, once there are any. Empty when there is nothing to say.
pub fn drops_text(view: &BridgeView) -> String {
    let mut text = String::new();
    if !view.signing_drops.is_empty() {
        let sum = |f: fn(&crate::mavlink::signing::DropCounts) -> u64| {
            view.signing_drops.iter().map(f).sum::<u64>()
        };
        let _ = write!(
            text,
            "   signed, dropped: {} unsigned, {} bad signature, {} old timestamp",
            sum(|d| d.unsigned),
            sum(|d| d.bad_signature),
            sum(|d| d.old_timestamp)
        );
    }
    for (label, counts) in [
        ("unsent (link too slow)", &view.send_drops),
        ("lost unread (bridge held up)", &view.receive_drops),
    ] {
        if counts.iter().any(|d| *d > 0) {
            let per_link: Vec<String> = counts.iter().map(u64::to_string).collect();
            let _ = write!(text, "   {label}: {}", per_link.join("/"));
        }
    }
    text
}

/// The output rate asked of the autopilot, and the rate received per message port (one rate
/// when one port sends): `output rate asked: 50 Hz, received: 10.0 Hz`.
pub fn rates_text(view: &BridgeView) -> String {
    let received = match &view.outputs_received_hz[..] {
        [] => "–".to_string(),
        [(_, hz)] => format!("{hz:.1} Hz"),
        ports => ports
            .iter()
            .map(|(port, hz)| format!("{hz:.1} Hz (port {port})"))
            .collect::<Vec<_>>()
            .join(", "),
    };
    format!(
        "output rate asked: {:.0} Hz, received: {received}",
        view.output_rate_hz
    )
}

/// The table as text.
pub fn render(view: &BridgeView) -> String {
    let mut out = String::new();
    let autopilot = match view.autopilot {
        Some((s, c)) => format!("autopilot {s}/{c}"),
        None => "waiting for the autopilot's heartbeat".into(),
    };
    let _ = writeln!(
        out,
        "{autopilot}   {}   failsafe: {}{}",
        rates_text(view),
        if view.failsafe { "ACTIVE" } else { "no" },
        drops_text(view)
    );
    // The name and bus columns are as wide as their longest entry: the columns after them
    // stay in line whatever the mapping file calls its servos and buses.
    let width = |header: &str, values: &mut dyn Iterator<Item = usize>| {
        values.fold(header.chars().count(), usize::max)
    };
    let name_w = width(
        "servo",
        &mut view.servos.iter().map(|s| s.name.chars().count()),
    );
    let bus_w = width(
        "bus",
        &mut view.servos.iter().map(|s| s.bus.chars().count()),
    );
    let _ = writeln!(
        out,
        "{:<name_w$} {:<bus_w$} {:>3} {:>3} {:>9} {:>9} {:>9} {:>7} {:>7}  state",
        "servo", "bus", "id", "ch", "goal mm", "pos mm", "current A", "temp C", "volt V"
    );
    for s in &view.servos {
        let r = &s.report;
        let state = state_text(s);
        let _ = writeln!(
            out,
            "{:<name_w$} {:<bus_w$} {:>3} {:>3} {} {} {} {} {}  {}",
            s.name,
            s.bus,
            s.id,
            s.channel,
            opt(s.goal_mm.map(|g| g as f32), 9, 2),
            opt(r.position_mm, 9, 2),
            opt(r.current_a, 9, 2),
            opt(r.temperature_c, 7, 0),
            opt(r.voltage_v, 7, 2),
            state
        );
    }
    out
}

/// Show the table until the task is aborted: redrawn in place on a terminal (`plain` false),
/// or printed once a second.
pub async fn show(mut view: watch::Receiver<BridgeView>, plain: bool) {
    let period = if plain {
        Duration::from_secs(1)
    } else {
        Duration::from_millis(200)
    };
    let mut lines_drawn = 0usize;
    loop {
        tokio::time::sleep(period).await;
        if view.has_changed().is_err() {
            return;
        }
        let text = render(&view.borrow_and_update());
        if plain {
            println!("{text}");
        } else {
            if lines_drawn > 0 {
                print!("\x1b[{lines_drawn}A\x1b[J");
            }
            print!("{text}");
            lines_drawn = text.lines().count();
        }
        use std::io::Write as _;
        let _ = std::io::stdout().flush();
    }
}

/// A servo's state as the tables show it: its health (`Degraded 23%` for a servo that answers
/// with too many bad replies, 23 % lately), then a temperature error or alarm and a stall.
pub fn state_text(s: &crate::runtime::ServoView) -> String {
    let r = &s.report;
    let mut state = match (s.health, r.degraded) {
        (crate::bus::Health::Online | crate::bus::Health::Stale, Some(percent)) => {
            format!("Degraded {percent}%")
        }
        (health, _) => format!("{health:?}"),
    };
    if r.temperature_error {
        state.push_str(" TEMP-ERROR");
    } else if r.temperature_alarm {
        state.push_str(" temp-alarm");
    }
    if r.stalled {
        state.push_str(" STALLED");
    }
    state
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mavlink::signing::DropCounts;

    #[test]
    fn the_columns_stay_in_line_with_long_servo_and_bus_names() {
        let servo = |name: &str, bus: &str, id: u8| crate::runtime::ServoView {
            name: name.into(),
            bus: bus.into(),
            id: crate::protocol::ServoId::new(id).unwrap(),
            channel: id,
            report: crate::mavlink::ServoReport {
                position_mm: Some(-12.5),
                current_a: Some(0.25),
                ..Default::default()
            },
            goal_mm: Some(-12.5),
            health: crate::bus::Health::Online,
        };
        let view = BridgeView {
            servos: vec![
                servo("left_outer_aileron", "surfaces", 1),
                servo("rudder", "tail", 12),
            ],
            ..BridgeView::default()
        };
        let text = render(&view);
        let lines: Vec<&str> = text.lines().skip(1).collect();
        // The state column starts, and the goal column (right-aligned) ends, where the
        // header's do.
        let header_state = lines[0].find("  state").unwrap();
        for line in &lines[1..] {
            assert_eq!(line.rfind("  "), Some(header_state), "{text}");
            assert_eq!(
                line.find("-12.50").map(|at| at + "-12.50".len()),
                lines[0].find("goal mm").map(|at| at + "goal mm".len()),
                "{text}"
            );
        }
    }

    #[test]
    fn the_autopilot_line_shows_signing_drops_only_with_signing_on() {
        let mut view = BridgeView::default();
        assert!(!render(&view).contains("signed"));
        view.signing_drops = vec![
            DropCounts {
                unsigned: 3,
                bad_signature: 1,
                old_timestamp: 0,
            },
            DropCounts {
                unsigned: 2,
                bad_signature: 0,
                old_timestamp: 4,
            },
        ];
        let first = render(&view).lines().next().unwrap_or("").to_string();
        assert!(
            first.ends_with("signed, dropped: 5 unsigned, 1 bad signature, 4 old timestamp"),
            "{first}"
        );
    }

    #[test]
    fn the_autopilot_line_shows_unsent_messages_per_link_once_there_are_any() {
        let mut view = BridgeView {
            send_drops: vec![0, 0],
            ..BridgeView::default()
        };
        assert!(!render(&view).contains("unsent"));
        view.send_drops = vec![0, 1234];
        let first = render(&view).lines().next().unwrap_or("").to_string();
        assert!(first.ends_with("unsent (link too slow): 0/1234"), "{first}");
    }

    #[test]
    fn the_autopilot_line_shows_datagrams_lost_unread_once_there_are_any() {
        let mut view = BridgeView {
            receive_drops: vec![0, 0],
            ..BridgeView::default()
        };
        assert!(!render(&view).contains("lost unread"));
        view.receive_drops = vec![17, 0];
        let first = render(&view).lines().next().unwrap_or("").to_string();
        assert!(
            first.ends_with("lost unread (bridge held up): 17/0"),
            "{first}"
        );
    }
}

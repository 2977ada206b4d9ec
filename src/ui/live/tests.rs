use super::*;
use crate::bus::Health;
use crate::mavlink::{ServoReport, ServoState};
use crate::protocol::ServoId;
use crate::runtime::ServoView;

fn servo(goal: Option<f64>, position: Option<f32>, current: Option<f32>) -> ServoView {
    ServoView {
        name: "rudder".into(),
        bus: "wing".into(),
        id: ServoId::new(4).unwrap(),
        channel: 4,
        report: ServoReport {
            state: Some(ServoState::Online),
            position_mm: position,
            current_a: current,
            temperature_c: Some(41.0),
            voltage_v: Some(12.0),
            ..Default::default()
        },
        goal_mm: goal,
        health: Health::Online,
    }
}

fn bus(at: Instant, counters: BusCounters) -> BusStatus {
    BusStatus {
        name: "wing".into(),
        port_open: true,
        servos: vec![],
        counters,
        at,
        telemetry_asked_hz: Some(50.0),
        thread: Default::default(),
    }
}

#[test]
fn a_servo_row_shows_its_error_and_keeps_a_bounded_history() {
    let mut m = LiveModel::default();
    for i in 0..(HISTORY + 5) {
        let view = BridgeView {
            servos: vec![servo(Some(2.0), Some(1.5 + i as f32 * 0.01), Some(0.3))],
            ..Default::default()
        };
        m.update(&view, vec![]);
    }
    let row = &m.servos[0];
    assert_eq!(row.error_history.len(), HISTORY);
    assert!((row.error_mm.unwrap() - (1.5 + (HISTORY + 4) as f32 * 0.01 - 2.0)).abs() < 1e-4);
    assert_eq!(row.current_history.len(), HISTORY);
    assert_eq!(row.state, "Online");
}

#[test]
fn a_missing_reading_is_shown_as_missing_not_as_zero() {
    let mut m = LiveModel::default();
    let view = BridgeView {
        servos: vec![servo(None, None, None)],
        ..Default::default()
    };
    m.update(&view, vec![]);
    assert_eq!(m.servos[0].error_mm, None);
    assert!(m.servos[0].error_history.is_empty());
    assert_eq!(cell(m.servos[0].position_mm, 2), "-");
}

#[test]
fn a_servo_in_temperature_error_says_so() {
    let mut s = servo(Some(0.0), Some(0.0), Some(0.07));
    s.health = Health::TemperatureError;
    s.report.temperature_error = true;
    s.report.temperature_c = Some(86.0);
    let mut m = LiveModel::default();
    m.update(
        &BridgeView {
            servos: vec![s],
            ..Default::default()
        },
        vec![],
    );
    assert_eq!(m.servos[0].state, "TemperatureError TEMP-ERROR");
    assert_eq!(m.servos[0].temperature_c, Some(86.0));
}

#[test]
fn a_degraded_servo_shows_its_share_of_bad_replies_as_its_state() {
    let mut s = servo(Some(0.0), Some(0.0), Some(0.07));
    s.report.degraded = Some(23);
    let mut m = LiveModel::default();
    m.update(
        &BridgeView {
            servos: vec![s.clone()],
            ..Default::default()
        },
        vec![],
    );
    assert_eq!(m.servos[0].state, "Degraded 23%");
    assert!(
        crate::ui::table::render(&BridgeView {
            servos: vec![s.clone()],
            ..Default::default()
        })
        .lines()
        .any(|l| l.starts_with("rudder") && l.ends_with("  Degraded 23%"))
    );
    // Lost is lost, whatever its replies were before.
    s.health = Health::Offline;
    m.update(
        &BridgeView {
            servos: vec![s],
            ..Default::default()
        },
        vec![],
    );
    assert_eq!(m.servos[0].state, "Offline");
}

#[test]
fn bus_rates_come_from_the_counters_between_two_views() {
    let t0 = Instant::now();
    let mut m = LiveModel::default();
    let first = BridgeView {
        buses: vec![bus(t0, BusCounters::default())],
        ..Default::default()
    };
    m.update(&first, vec![]);
    assert_eq!(
        m.buses[0].utilisation_percent, None,
        "no rate from one view"
    );
    let counters = BusCounters {
        polls: 60,
        motion_polls: 20,
        position_polls: 10,
        other_requests: 10,
        // 5 of the 15 missed replies came garbled: bad sums, not more bad replies.
        timeouts: 15,
        bad_sums: 5,
        wire_busy_ns: 150_000_000,
        late_wakeups: 3,
        ..Default::default()
    };
    let second = BridgeView {
        buses: vec![bus(t0 + Duration::from_millis(200), counters)],
        texts: vec!["rudder: servo lost".into()],
        ..Default::default()
    };
    m.update(&second, vec!["a log line".into()]);
    let b = &m.buses[0];
    assert_eq!(b.utilisation_percent, Some(75.0));
    assert_eq!(b.bad_replies_percent, Some(15.0));
    assert_eq!(b.late_wakeups, 3);
    assert_eq!(m.texts, vec!["rudder: servo lost".to_string()]);
    assert_eq!(m.log, vec!["a log line".to_string()]);
}

#[test]
fn the_link_line_says_whom_the_rates_asked_and_received_and_whether_in_failsafe() {
    let mut m = LiveModel::default();
    m.update(&BridgeView::default(), vec![]);
    assert_eq!(m.link, "waiting for the autopilot's heartbeat");
    let view = BridgeView {
        autopilot: Some((1, 1)),
        failsafe: true,
        output_rate_hz: 40.0,
        ..Default::default()
    };
    m.update(&view, vec![]);
    assert_eq!(
        m.link,
        "autopilot 1/1   output rate asked: 40 Hz, received: –   failsafe: ACTIVE"
    );
    // The rate received, per port when two send.
    let one = BridgeView {
        outputs_received_hz: vec![(0, 10.04)],
        ..view.clone()
    };
    m.update(&one, vec![]);
    assert!(
        m.link.contains("asked: 40 Hz, received: 10.0 Hz   "),
        "{}",
        m.link
    );
    let two = BridgeView {
        outputs_received_hz: vec![(0, 39.96), (1, 10.0)],
        ..view
    };
    m.update(&two, vec![]);
    assert!(
        m.link
            .contains("asked: 40 Hz, received: 40.0 Hz (port 0), 10.0 Hz (port 1)   "),
        "{}",
        m.link
    );
}

#[test]
fn sparklines_scale_to_the_largest_value_or_the_floor() {
    let h: VecDeque<f32> = [0.0, 1.0, 2.0, 4.0].into();
    assert_eq!(sparkline(&h, HISTORY, 0.5), "▁▃▅█");
    let small: VecDeque<f32> = [0.01, 0.02].into();
    assert_eq!(sparkline(&small, HISTORY, 0.5), "▁▁");
    assert_eq!(sparkline(&VecDeque::new(), HISTORY, 0.5), "");
    // Narrower than the history: the newest samples, scaled among themselves.
    assert_eq!(sparkline(&h, 2, 0.5), "▅█");
}

/// The built-in airframe of `sitl` as the bridge sees it mid-flight.
fn airframe() -> BridgeView {
    let t0 = Instant::now();
    let servo = |name: &str, id: u8, goal: f64, position: f32| {
        let mut s = servo(Some(goal), Some(position), Some(0.07));
        s.name = name.into();
        s.bus = "sim".into();
        s.id = ServoId::new(id).unwrap();
        s.report.temperature_c = Some(25.0);
        s
    };
    BridgeView {
        autopilot: Some((1, 1)),
        output_rate_hz: 40.0,
        servos: vec![
            servo("aileron_left", 1, 14.0, 13.98),
            servo("aileron_right", 2, -14.25, -14.31),
            servo("elevator", 3, 8.75, 9.28),
            servo("rudder", 4, -6.5, -7.3),
        ],
        buses: vec![bus(t0, BusCounters::default())],
        ..Default::default()
    }
}

/// The model drawn on a terminal of `width` × `height`, line by line.
fn screen(m: &LiveModel, width: u16, height: u16) -> Vec<String> {
    use ratatui::Terminal;
    use ratatui::backend::TestBackend;
    let mut terminal = Terminal::new(TestBackend::new(width, height)).unwrap();
    terminal.draw(|f| draw(f, m)).unwrap();
    let buffer = terminal.backend().buffer();
    (0..height)
        .map(|y| (0..width).map(|x| buffer[(x, y)].symbol()).collect())
        .collect()
}

/// The words of the screen: what is between blanks and box borders.
fn words(lines: &[String]) -> Vec<String> {
    lines
        .iter()
        .flat_map(|l| l.split(|c: char| c.is_whitespace() || "│┌┐└┘─".contains(c)))
        .filter(|w| !w.is_empty())
        .map(str::to_string)
        .collect()
}

/// Every name and every number of the airframe's rows is a whole word on the screen.
fn assert_whole(lines: &[String]) {
    let words = words(lines);
    let text = lines.join("\n");
    for whole in [
        "aileron_left",
        "aileron_right",
        "elevator",
        "rudder",
        "14.00",
        "13.98",
        "-0.02",
        "-14.25",
        "-14.31",
        "-0.06",
        "8.75",
        "9.28",
        "0.53",
        "-6.50",
        "-7.30",
        "-0.80",
        "0.07",
        "25",
        "12.00",
        "Online",
    ] {
        assert!(
            words.iter().any(|w| w == whole),
            "{whole} not whole on\n{text}"
        );
    }
    // One row per servo, each with its own name.
    for name in ["aileron_left", "aileron_right", "elevator", "rudder"] {
        let rows = lines
            .iter()
            .filter(|l| l.split_whitespace().any(|w| w.trim_matches('│') == name))
            .count();
        assert_eq!(rows, 1, "{name} on {rows} rows of\n{text}");
    }
}

fn sitl_model() -> LiveModel {
    let mut m = LiveModel::default();
    for _ in 0..HISTORY {
        m.update(&airframe(), vec![" INFO servo 4 online bus=sim".into()]);
    }
    m
}

#[test]
fn at_80_by_24_every_name_and_number_is_whole_and_the_histories_make_room() {
    let lines = screen(&sitl_model(), 80, 24);
    let text = lines.join("\n");
    assert_whole(&lines);
    assert!(!text.contains("history"), "a history header on\n{text}");
    assert!(
        !text.chars().any(|c| BARS.contains(&c)),
        "a history on\n{text}"
    );
    assert!(words(&lines).iter().any(|w| w == "state"), "{text}");
    assert!(text.contains("bad replies      -"), "{text}");
    assert!(text.contains("late wake-ups 0"), "{text}");
}

#[test]
fn at_160_by_48_the_histories_come_back_with_their_headers_whole() {
    // With two flaps whose names share a prefix, one of them in trouble.
    let mut view = airframe();
    let flap = |name: &str, id: u8| {
        let mut s = view.servos[2].clone();
        s.name = name.into();
        s.id = ServoId::new(id).unwrap();
        s
    };
    let inboard = flap("flap_left_inboard", 5);
    let mut outboard = flap("flap_left_outboard", 6);
    outboard.report.degraded = Some(23);
    outboard.report.temperature_alarm = true;
    outboard.report.stalled = true;
    view.servos.extend([inboard, outboard]);
    let mut m = LiveModel::default();
    for _ in 0..HISTORY {
        m.update(&view, vec![]);
    }
    let lines = screen(&m, 160, 48);
    let text = lines.join("\n");
    assert_whole(&lines);
    for whole in ["flap_left_inboard", "flap_left_outboard"] {
        assert!(
            words(&lines).iter().any(|w| w == whole),
            "{whole} not whole on\n{text}"
        );
    }
    assert!(text.contains("Degraded 23% temp-alarm STALLED"), "{text}");
    for header in ["|err| history", "current history"] {
        assert!(text.contains(header), "{header} not on\n{text}");
    }
    let elevator = lines.iter().find(|l| l.contains("elevator")).unwrap();
    assert!(
        elevator.chars().filter(|c| BARS.contains(c)).count() >= 2 * 20,
        "{elevator}"
    );
}

#[test]
fn the_statustext_box_holds_its_lines_and_the_log_takes_the_rest() {
    let mut m = sitl_model();
    let log: Vec<String> = (0..40).map(|i| format!(" INFO line {i}")).collect();
    m.update(&airframe(), log);
    let lines = screen(&m, 160, 48);
    let text = lines.join("\n");
    let top = |title: &str| lines.iter().position(|l| l.contains(title)).unwrap();
    // No STATUSTEXT yet: one empty line between the box's borders.
    assert_eq!(top(" log ") - top(" STATUSTEXT"), 3, "{text}");
    // The log box shows the latest lines, down to the help line.
    assert!(text.contains("line 39"), "{text}");
    assert_eq!(top("q: quit"), 47);
    assert!(
        lines[46].starts_with('└') && lines[45].contains("line 39"),
        "{text}"
    );
}

#[test]
fn names_too_long_for_the_terminal_give_way_to_labels_that_tell_servos_apart() {
    let mut view = airframe();
    let left = "aileron_left_outboard_trailing_edge";
    let right = "aileron_right_outboard_trailing_edge";
    view.servos[0].name = left.into();
    view.servos[1].name = right.into();
    let labels = [
        (left, "ail_lo"),
        (right, "ail_ro"),
        ("elevator", "elev"),
        ("rudder", "rudder"),
    ]
    .map(|(n, l)| (n.to_string(), l.to_string()));
    let mut m = LiveModel::with_labels(labels.into());
    m.update(&view, vec![]);
    let lines = screen(&m, 80, 24);
    let text = lines.join("\n");
    let words = words(&lines);
    for label in ["ail_lo", "ail_ro", "elev", "rudder"] {
        let n = words.iter().filter(|w| *w == label).count();
        assert_eq!(n, 1, "{label} {n} times on\n{text}");
    }
    assert!(!text.contains("aileron"), "a cut name on\n{text}");
    for number in ["-14.25", "-14.31", "12.00"] {
        assert!(words.iter().any(|w| w == number), "{number} on\n{text}");
    }
    // Where they fit, the names come back.
    let wide = screen(&m, 160, 48).join("\n");
    assert!(wide.contains(left) && wide.contains(right), "{wide}");
}

#[test]
fn columns_give_way_in_order_as_the_terminal_narrows_and_none_is_cut() {
    let m = sitl_model();
    let mut before = usize::MAX;
    for width in (30..=200).rev() {
        let table = ServoTable::lay_out(&m.servos, width);
        let shown: Vec<Column> = table.columns.iter().map(|c| c.0).collect();
        let needs = table.columns.iter().map(|c| c.1 + 1).sum::<usize>() - 1;
        let essential = [
            Column::Servo,
            Column::Position,
            Column::Error,
            Column::State,
        ];
        assert!(
            needs <= width || shown == essential,
            "{width}: {shown:?} need {needs}"
        );
        assert!(
            shown.len() <= before,
            "{width}: a column came back narrower"
        );
        before = shown.len();
        let dropped = GIVE_WAY.iter().any(|c| !shown.contains(c));
        let histories = shown.contains(&Column::ErrorHistory);
        assert!(!(dropped && histories), "{width}: {shown:?}");
        if shown.contains(&Column::CurrentHistory) {
            assert!(histories, "{width}: {shown:?}");
        }
        for &(column, w) in &table.columns {
            assert!(
                w >= width_of(column.header()),
                "{width}: {column:?} header cut"
            );
            for servo in &m.servos {
                let cell = ServoTable::cell(servo, column, table.labels, w);
                assert!(width_of(&cell) <= w, "{width}: {cell} cut to {w}");
            }
        }
    }
    // At 80 columns the airframe's rows lose only their histories.
    let at_80 = ServoTable::lay_out(&m.servos, 78);
    assert_eq!(at_80.columns.len(), 10, "{at_80:?}");
    assert!(!at_80.labels);
}

#[test]
fn the_log_shows_its_latest_lines_whole() {
    let log: Vec<String> = ["one two three", "four", "five six seven eight"]
        .map(String::from)
        .into();
    // In lines of 12: "one two" "  three", "four", "five six" "  seven" "  eight".
    let four = ["four", "five six", "  seven", "  eight"];
    assert_eq!(latest_whole(&log, 12, 4), four);
    assert_eq!(
        latest_whole(&log, 12, 5),
        four,
        "not from the middle of a line"
    );
    assert_eq!(latest_whole(&log, 12, 6).len(), 6);
    // The latest alone is taller than the box: its start.
    assert_eq!(latest_whole(&log, 12, 2), ["five six", "  seven"]);
    assert!(latest_whole(&log, 12, 0).is_empty());
}

#[test]
fn long_lines_wrap_at_blanks_and_long_words_are_cut_where_the_line_ends() {
    assert_eq!(wrap("servo 4 online", 80), ["servo 4 online"]);
    assert_eq!(
        wrap("bus thread woke 0.6 ms late", 12),
        ["bus thread", "  woke 0.6", "  ms late"]
    );
    assert_eq!(wrap("abcdefghijkl", 8), ["abcdefgh", "  ijkl"]);
    assert_eq!(wrap("", 8), [""]);
    assert_eq!(wrap(" INFO servo", 20), ["INFO servo"]);
}

#[test]
fn the_screen_shows_every_servo_bus_and_text() {
    use ratatui::Terminal;
    use ratatui::backend::TestBackend;
    let t0 = Instant::now();
    let mut m = LiveModel::default();
    let view = BridgeView {
        servos: vec![servo(Some(2.0), Some(1.5), Some(0.3))],
        buses: vec![bus(t0, BusCounters::default())],
        texts: vec!["rudder: overheat, force off; 80C 0.4s ago".into()],
        ..Default::default()
    };
    m.update(&view, vec![]);
    let mut terminal = Terminal::new(TestBackend::new(160, 24)).unwrap();
    terminal.draw(|f| draw(f, &m)).unwrap();
    let screen: String = terminal
        .backend()
        .buffer()
        .content()
        .iter()
        .map(|c| c.symbol())
        .collect();
    for needle in [
        "rudder",
        "-0.50",
        "wing",
        "late wake-ups 0",
        "overheat, force off; 80C 0.4s ago",
        "q: quit",
    ] {
        assert!(screen.contains(needle), "{needle} not on\n{screen}");
    }
}

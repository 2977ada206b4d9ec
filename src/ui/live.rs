//! The live view of `sitl`: a screen redrawn in place, like `top`, with a row per servo (goal,
//! position, error, current, temperature, voltage, state, and a short history of position
//! error and current), each bus's utilisation, bad replies and late wake-ups, the autopilot
//! link, the latest STATUSTEXTs and log lines; `q` quits.
//!
//! What is shown is [`LiveModel`], plain data updated from the bridge's [`BridgeView`] and
//! tested without a terminal; [`show`] only draws it with `ratatui` on `crossterm`.
//!
//! Their cost: 38 crates the project did not build before (ratatui's four, crossterm,
//! and small helpers such as `unicode-width`, `lru`, `strum`, `darling`). Built alone at
//! this project's dependency optimisation level, ratatui with crossterm took 140 s of CPU
//! (131 s on the clock) on the 2-core development machine while other builds ran; added
//! here, the changed features of shared dependencies also rebuilt the debug profile's
//! dependencies (460 s of CPU in all, on the same busy machine). That is paid once per
//! clean build; incremental builds of the project are unchanged. What they give back: a
//! screen that only rewrites the cells that changed, a layout that follows the terminal's
//! size, key input in raw mode, and the terminal restored on every way out (quit, end of
//! run, panic), none of which the project has to keep. The plain line output (`--plain`,
//! or when stdout is not a terminal) is [`super::table`], without them.

use crate::bus::{BusCounters, BusStatus};
use crate::runtime::BridgeView;
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Paragraph, Row, Table};
use std::collections::{HashMap, VecDeque};
use std::time::{Duration, Instant};
use tokio::sync::watch;

use crate::ui::terminal::{Restore, log_lines, quit_pressed};

/// Samples kept for a servo's history (one per redraw: 12 s), the most a history shows.
pub const HISTORY: usize = 60;
/// The fewest samples a history is drawn with (4 s): a shorter one shows no trend, and its
/// columns are better given to numbers.
const HISTORY_MIN: usize = 20;
/// How often the screen is redrawn (and `q` looked for).
const PERIOD: Duration = Duration::from_millis(200);
/// The eight heights of a sparkline.
const BARS: [char; 8] = ['▁', '▂', '▃', '▄', '▅', '▆', '▇', '█'];

/// One servo's row.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ServoRow {
    pub name: String,
    /// The mapping's short name for the servo (its telemetry prefix, at most 6 characters,
    /// unique): shown instead of the name where names do not fit. The name when not known.
    pub label: String,
    pub bus: String,
    pub id: u8,
    pub goal_mm: Option<f32>,
    pub position_mm: Option<f32>,
    /// Position − goal.
    pub error_mm: Option<f32>,
    pub current_a: Option<f32>,
    pub temperature_c: Option<f32>,
    pub voltage_v: Option<f32>,
    /// Health (or `Degraded N%`), then `TEMP-ERROR`, `temp-alarm` or `STALLED` when they hold.
    pub state: String,
    /// |position error| in mm, oldest first (a missing reading is not a sample).
    pub error_history: VecDeque<f32>,
    /// Current in A, oldest first.
    pub current_history: VecDeque<f32>,
}

/// One bus's line. Rates are over the time between the last two views.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct BusRow {
    pub name: String,
    pub port_open: bool,
    /// Wire time used, % of the time elapsed.
    pub utilisation_percent: Option<f32>,
    /// Replies missed or rejected for a bad sum, % of the requests that asked for one.
    pub bad_replies_percent: Option<f32>,
    /// Times the bus thread ran late since it started.
    pub late_wakeups: u64,
    /// Position-and-current reads per servo per second: achieved (between the last two views)
    /// and asked (`None`: as often as the bus allows).
    pub reads_hz: Option<f32>,
    pub reads_asked_hz: Option<f32>,
}

/// Everything the live view shows.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LiveModel {
    /// The autopilot link: who, the output rate asked for and received, failsafe.
    pub link: String,
    pub failsafe: bool,
    pub servos: Vec<ServoRow>,
    pub buses: Vec<BusRow>,
    /// The latest STATUSTEXTs, oldest first.
    pub texts: Vec<String>,
    /// The latest log lines, oldest first.
    pub log: Vec<String>,
    /// Each bus's previous counters, for the rates.
    previous: Vec<(Instant, BusCounters)>,
    /// Each servo's label, by name.
    labels: HashMap<String, String>,
}

fn push(history: &mut VecDeque<f32>, value: Option<f32>) {
    if let Some(v) = value {
        if history.len() == HISTORY {
            history.pop_front();
        }
        history.push_back(v);
    }
}

/// `value` as a share of `total`, in %; `None` when there is nothing to divide by.
fn percent(value: u64, total: u64) -> Option<f32> {
    (total > 0).then(|| (value as f64 / total as f64 * 100.0) as f32)
}

impl LiveModel {
    /// A model that knows the servos' labels (name → label), for a terminal too narrow for
    /// their names.
    pub fn with_labels(labels: HashMap<String, String>) -> Self {
        LiveModel {
            labels,
            ..Default::default()
        }
    }

    /// Take in a new view of the bridge (and the latest log lines).
    pub fn update(&mut self, view: &BridgeView, log: Vec<String>) {
        self.link = match view.autopilot {
            Some((s, c)) => format!(
                "autopilot {s}/{c}   {}   failsafe: {}{}",
                super::table::rates_text(view),
                if view.failsafe { "ACTIVE" } else { "no" },
                super::table::drops_text(view)
            ),
            None => format!(
                "waiting for the autopilot's heartbeat{}",
                super::table::drops_text(view)
            ),
        };
        self.failsafe = view.failsafe;
        self.servos
            .resize_with(view.servos.len(), ServoRow::default);
        for (row, s) in self.servos.iter_mut().zip(&view.servos) {
            let r = &s.report;
            let goal_mm = s.goal_mm.map(|g| g as f32);
            let error_mm = r.position_mm.zip(goal_mm).map(|(p, g)| p - g);
            let state = super::table::state_text(s);
            row.name.clone_from(&s.name);
            row.label
                .clone_from(self.labels.get(&s.name).unwrap_or(&s.name));
            row.bus.clone_from(&s.bus);
            row.id = s.id.get();
            row.goal_mm = goal_mm;
            row.position_mm = r.position_mm;
            row.error_mm = error_mm;
            row.current_a = r.current_a;
            row.temperature_c = r.temperature_c;
            row.voltage_v = r.voltage_v;
            row.state = state;
            push(&mut row.error_history, error_mm.map(f32::abs));
            push(&mut row.current_history, r.current_a);
        }
        self.buses = view
            .buses
            .iter()
            .enumerate()
            .map(|(i, b)| self.bus_row(i, b))
            .collect();
        self.previous = view.buses.iter().map(|b| (b.at, b.counters)).collect();
        self.texts.clone_from(&view.texts);
        self.log = log;
    }

    fn bus_row(&self, index: usize, bus: &BusStatus) -> BusRow {
        let c = &bus.counters;
        let (utilisation_percent, bad_replies_percent, reads_hz) = match self.previous.get(index) {
            Some((at, p)) if bus.at > *at => {
                let elapsed_ns = bus.at.duration_since(*at).as_nanos() as u64;
                let reads = (c.polls + c.motion_polls).saturating_sub(p.polls + p.motion_polls);
                let servos = bus.servos.len().max(1) as f32;
                let reads_hz = reads as f32 / (elapsed_ns as f32 * 1e-9) / servos;
                let asked = (c.polls + c.motion_polls + c.position_polls + c.other_requests)
                    .saturating_sub(p.polls + p.motion_polls + p.position_polls + p.other_requests);
                // A garbled reply is a timeout too (and a bad sum): counted once.
                let bad = c.timeouts.saturating_sub(p.timeouts);
                (
                    percent(c.wire_busy_ns.saturating_sub(p.wire_busy_ns), elapsed_ns),
                    percent(bad, asked),
                    (!bus.servos.is_empty()).then_some(reads_hz),
                )
            }
            _ => (None, None, None),
        };
        BusRow {
            name: bus.name.clone(),
            port_open: bus.port_open,
            utilisation_percent,
            bad_replies_percent,
            late_wakeups: c.late_wakeups,
            reads_hz,
            reads_asked_hz: bus.telemetry_asked_hz,
        }
    }
}

/// The newest `width` samples of the history as bars, scaled to their largest value (or
/// `floor`, if larger: a flat line of small values stays low).
pub fn sparkline(history: &VecDeque<f32>, width: usize, floor: f32) -> String {
    let shown = history.iter().skip(history.len().saturating_sub(width));
    let top = shown.clone().copied().fold(floor, f32::max);
    shown
        .map(|v| {
            let level = (v / top * (BARS.len() - 1) as f32).round();
            BARS[(level.max(0.0) as usize).min(BARS.len() - 1)]
        })
        .collect()
}

fn cell(v: Option<f32>, decimals: usize) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.decimals$}"))
}

/// Columns a text takes on the terminal.
fn width_of(text: &str) -> usize {
    Span::raw(text).width()
}

/// `text` cut into lines of at most `width` characters, at blanks where it can be; the lines
/// after the first are indented by two.
fn wrap(text: &str, width: usize) -> Vec<String> {
    let width = width.max(4);
    let mut lines = Vec::new();
    let mut line = String::new();
    for word in text.split(' ') {
        let mut word = word.to_string();
        loop {
            let room = width - line.chars().count();
            let gap = usize::from(!line.trim().is_empty());
            let n = word.chars().count();
            if n + gap <= room {
                if gap == 1 {
                    line.push(' ');
                }
                line.push_str(&word);
                break;
            }
            if !line.trim().is_empty() && n <= width - 2 {
                // The word goes whole on the next line.
                lines.push(std::mem::replace(&mut line, "  ".into()));
                continue;
            }
            // A word longer than a line: cut it where the line ends.
            let take = room.saturating_sub(gap);
            if take == 0 {
                lines.push(std::mem::replace(&mut line, "  ".into()));
                continue;
            }
            if gap == 1 {
                line.push(' ');
            }
            line.extend(word.chars().take(take));
            word = word.chars().skip(take).collect();
            lines.push(std::mem::replace(&mut line, "  ".into()));
            if word.is_empty() {
                break;
            }
        }
    }
    if !line.trim().is_empty() || lines.is_empty() {
        lines.push(line);
    }
    lines
}

/// Lines of text wrapped to `width`.
fn wrap_all<'a>(texts: impl IntoIterator<Item = &'a str>, width: usize) -> Vec<String> {
    texts.into_iter().flat_map(|t| wrap(t, width)).collect()
}

/// The latest of `texts` that fit whole in `room` lines of `width`, wrapped: a text is not
/// shown from its middle (unless the latest alone is taller than the room).
fn latest_whole(texts: &[String], width: usize, room: usize) -> Vec<String> {
    let mut shown: Vec<Vec<String>> = Vec::new();
    let mut used = 0;
    for text in texts.iter().rev() {
        let lines = wrap(text, width);
        if used + lines.len() > room {
            if shown.is_empty() {
                shown.push(lines.into_iter().take(room).collect());
            }
            break;
        }
        used += lines.len();
        shown.push(lines);
    }
    shown.into_iter().rev().flatten().collect()
}

/// A column of the servo table: its header and its cells, as drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Column {
    Servo,
    Bus,
    Id,
    Goal,
    Position,
    Error,
    Current,
    Temperature,
    Voltage,
    State,
    ErrorHistory,
    CurrentHistory,
}

impl Column {
    fn header(self) -> &'static str {
        match self {
            Column::Servo => "servo",
            Column::Bus => "bus",
            Column::Id => "id",
            Column::Goal => "goal mm",
            Column::Position => "pos mm",
            Column::Error => "err mm",
            Column::Current => "A",
            Column::Temperature => "°C",
            Column::Voltage => "V",
            Column::State => "state",
            Column::ErrorHistory => "|err| history",
            Column::CurrentHistory => "current history",
        }
    }

    /// Numbers are aligned on the right, text on the left.
    fn right(self) -> bool {
        !matches!(
            self,
            Column::Servo
                | Column::Bus
                | Column::State
                | Column::ErrorHistory
                | Column::CurrentHistory
        )
    }
}

/// What gives way, in this order, when the servo table is wider than the terminal: the
/// histories (the current's first), the names for the servos' labels, then the columns that
/// say least in flight (the goal last: it is the position less the error). The name,
/// position, error and state always stay.
const GIVE_WAY: [Column; 6] = [
    Column::Bus,
    Column::Id,
    Column::Voltage,
    Column::Current,
    Column::Temperature,
    Column::Goal,
];

/// The servo table for `width` columns (inside the box): the columns shown, each with its
/// width, and whether servos go by their labels. Every cell is whole: a column is dropped
/// rather than cut.
#[derive(Debug, PartialEq)]
struct ServoTable {
    columns: Vec<(Column, usize)>,
    labels: bool,
}

impl ServoTable {
    fn cell(servo: &ServoRow, column: Column, labels: bool, width: usize) -> String {
        match column {
            Column::Servo if labels => servo.label.clone(),
            Column::Servo => servo.name.clone(),
            Column::Bus => servo.bus.clone(),
            Column::Id => servo.id.to_string(),
            Column::Goal => cell(servo.goal_mm, 2),
            Column::Position => cell(servo.position_mm, 2),
            Column::Error => cell(servo.error_mm, 2),
            Column::Current => cell(servo.current_a, 2),
            Column::Temperature => cell(servo.temperature_c, 0),
            Column::Voltage => cell(servo.voltage_v, 2),
            Column::State => servo.state.clone(),
            Column::ErrorHistory => sparkline(&servo.error_history, width, 0.5),
            Column::CurrentHistory => sparkline(&servo.current_history, width, 0.5),
        }
    }

    /// The widest cell of a column of text or numbers, its header included.
    fn fit(servos: &[ServoRow], column: Column, labels: bool) -> usize {
        servos
            .iter()
            .map(|s| width_of(&Self::cell(s, column, labels, 0)))
            .fold(width_of(column.header()), usize::max)
    }

    fn lay_out(servos: &[ServoRow], width: usize) -> ServoTable {
        use Column::*;
        let mut shown = vec![
            Servo,
            Bus,
            Id,
            Goal,
            Position,
            Error,
            Current,
            Temperature,
            Voltage,
            State,
        ];
        let needs = |shown: &[Column], labels: bool| {
            shown
                .iter()
                .map(|c| Self::fit(servos, *c, labels) + 1)
                .sum::<usize>()
                - 1
        };
        let mut labels = false;
        let mut give_way = GIVE_WAY.iter();
        while needs(&shown, labels) > width {
            if !labels && needs(&shown, true) < needs(&shown, false) {
                labels = true;
                continue;
            }
            match give_way.next() {
                Some(column) => shown.retain(|c| c != column),
                None => break,
            }
        }
        let mut columns: Vec<(Column, usize)> = shown
            .into_iter()
            .map(|c| (c, Self::fit(servos, c, labels)))
            .collect();
        // The histories share what is left, each up to HISTORY samples.
        let used = columns.iter().map(|c| c.1 + 1).sum::<usize>() - 1;
        let left = width.saturating_sub(used);
        let least = |c: Column| HISTORY_MIN.max(width_of(c.header())) + 1;
        if left >= least(ErrorHistory) + least(CurrentHistory) {
            let error = (left / 2).clamp(least(ErrorHistory), HISTORY + 1);
            let current = (left - error).min(HISTORY + 1);
            columns.push((ErrorHistory, error - 1));
            columns.push((CurrentHistory, current - 1));
        } else if left >= least(ErrorHistory) {
            columns.push((ErrorHistory, (left - 1).min(HISTORY)));
        }
        ServoTable { columns, labels }
    }

    fn pad(text: &str, width: usize, right: bool) -> String {
        let fill = " ".repeat(width.saturating_sub(width_of(text)));
        if right {
            format!("{fill}{text}")
        } else {
            format!("{text}{fill}")
        }
    }

    fn header(&self) -> Row<'static> {
        Row::new(
            self.columns
                .iter()
                .map(|&(c, w)| Self::pad(c.header(), w, c.right())),
        )
        .style(Style::default().add_modifier(Modifier::BOLD))
    }

    fn row(&self, servo: &ServoRow) -> Row<'static> {
        let style = if servo.state == "Online" {
            Style::default()
        } else {
            Style::default().fg(Color::Yellow)
        };
        Row::new(
            self.columns
                .iter()
                .map(|&(c, w)| Self::pad(&Self::cell(servo, c, self.labels, w), w, c.right())),
        )
        .style(style)
    }

    fn widths(&self) -> Vec<Constraint> {
        self.columns
            .iter()
            .map(|&(_, w)| Constraint::Length(w as u16))
            .collect()
    }
}

/// A bus's line: its name padded to `name_width` (and `PORT LOST` while it is), its wire use,
/// bad replies, position-and-current reads per servo per second achieved and asked, and the
/// bus thread's late wake-ups.
fn bus_line(b: &BusRow, name_width: usize) -> String {
    format!(
        "{:<name_width$}{}  wire {:>6}  bad replies {:>6}  reads {}/{} Hz  late wake-ups {}",
        b.name,
        if b.port_open { "" } else { "  PORT LOST" },
        share(b.utilisation_percent),
        share(b.bad_replies_percent),
        b.reads_hz
            .map_or_else(|| "-".to_string(), |hz| format!("{hz:.0}")),
        b.reads_asked_hz
            .map_or_else(|| "max".to_string(), |hz| format!("{hz:.0}")),
        b.late_wakeups
    )
}

/// A percentage with one decimal, or `-` when there is none yet.
fn share(percent: Option<f32>) -> String {
    percent.map_or_else(|| "-".to_string(), |p| format!("{p:.1}%"))
}

/// Draw the model on a frame. Every box is as tall as what it holds, the log box takes the
/// rest; long lines wrap rather than end at the border.
pub fn draw(frame: &mut ratatui::Frame, model: &LiveModel) {
    let area = frame.area();
    let inside = usize::from(area.width.saturating_sub(2));
    let link_lines = wrap(&model.link, usize::from(area.width));
    let name_width = model
        .buses
        .iter()
        .map(|b| width_of(&b.name))
        .max()
        .unwrap_or(0);
    let bus_lines = wrap_all(
        model
            .buses
            .iter()
            .map(|b| bus_line(b, name_width))
            .collect::<Vec<_>>()
            .iter()
            .map(String::as_str),
        inside,
    );
    let text_lines = wrap_all(model.texts.iter().map(String::as_str), inside);
    let tall = |lines: usize| Constraint::Length(lines as u16 + 2);
    let [link, servos, buses, texts, log, help] = Layout::vertical([
        Constraint::Length(link_lines.len() as u16),
        tall(model.servos.len() + 1),
        tall(bus_lines.len()),
        tall(text_lines.len().max(1)),
        Constraint::Min(3),
        Constraint::Length(1),
    ])
    .areas(area);

    let link_style = if model.failsafe {
        Style::default().fg(Color::Red).add_modifier(Modifier::BOLD)
    } else {
        Style::default()
    };
    frame.render_widget(
        Paragraph::new(link_lines.into_iter().map(Line::from).collect::<Vec<_>>())
            .style(link_style),
        link,
    );

    let table = ServoTable::lay_out(&model.servos, inside);
    frame.render_widget(
        Table::new(model.servos.iter().map(|s| table.row(s)), table.widths())
            .header(table.header())
            .column_spacing(1)
            .block(Block::bordered().title(" servos ")),
        servos,
    );

    let lines = |texts: Vec<String>| texts.into_iter().map(Line::from).collect::<Vec<_>>();
    frame.render_widget(
        Paragraph::new(lines(bus_lines)).block(Block::bordered().title(" buses ")),
        buses,
    );
    frame.render_widget(
        Paragraph::new(lines(text_lines))
            .block(Block::bordered().title(" STATUSTEXT, latest last ")),
        texts,
    );
    let log_lines = latest_whole(
        &model.log,
        inside,
        usize::from(log.height.saturating_sub(2)),
    );
    frame.render_widget(
        Paragraph::new(lines(log_lines)).block(Block::bordered().title(" log ")),
        log,
    );
    frame.render_widget(Paragraph::new("q: quit"), help);
}

/// Show the live view until `q` is pressed (then return), or until the task is aborted or
/// the bridge is gone. `labels`: each servo's label, by name.
pub async fn show(
    mut view: watch::Receiver<BridgeView>,
    labels: HashMap<String, String>,
) -> std::io::Result<()> {
    let mut terminal = ratatui::try_init()?;
    let _restore = Restore;
    let mut model = LiveModel::with_labels(labels);
    loop {
        if view.has_changed().is_err() {
            return Ok(());
        }
        model.update(&view.borrow_and_update(), log_lines());
        terminal.draw(|frame| draw(frame, &model))?;
        if quit_pressed()? {
            return Ok(());
        }
        tokio::time::sleep(PERIOD).await;
    }
}

#[cfg(test)]
mod tests {
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
}

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
mod tests;

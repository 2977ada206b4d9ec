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
use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use ratatui::layout::{Constraint, Layout};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::Line;
use ratatui::widgets::{Block, Paragraph, Row, Table};
use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Samples kept for a servo's history (one per redraw).
pub const HISTORY: usize = 30;
/// Log lines kept for the view.
pub const LOG_LINES: usize = 5;
/// How often the screen is redrawn (and `q` looked for).
const PERIOD: Duration = Duration::from_millis(200);
/// The eight heights of a sparkline.
const BARS: [char; 8] = ['▁', '▂', '▃', '▄', '▅', '▆', '▇', '█'];

/// One servo's row.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ServoRow {
    pub name: String,
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
}

/// Everything the live view shows.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LiveModel {
    /// The autopilot link: who, the output rate asked for, failsafe.
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
    /// Take in a new view of the bridge (and the latest log lines).
    pub fn update(&mut self, view: &BridgeView, log: Vec<String>) {
        self.link = match view.autopilot {
            Some((s, c)) => format!(
                "autopilot {s}/{c}   output rate asked: {:.0} Hz   failsafe: {}{}",
                view.output_rate_hz,
                if view.failsafe { "ACTIVE" } else { "no" },
                super::table::signing_text(view)
            ),
            None => format!(
                "waiting for the autopilot's heartbeat{}",
                super::table::signing_text(view)
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
        let (utilisation_percent, bad_replies_percent) = match self.previous.get(index) {
            Some((at, p)) if bus.at > *at => {
                let elapsed_ns = bus.at.duration_since(*at).as_nanos() as u64;
                let asked = (c.polls + c.motion_polls + c.position_polls + c.other_requests)
                    .saturating_sub(p.polls + p.motion_polls + p.position_polls + p.other_requests);
                // A garbled reply is a timeout too (and a bad sum): counted once.
                let bad = c.timeouts.saturating_sub(p.timeouts);
                (
                    percent(c.wire_busy_ns.saturating_sub(p.wire_busy_ns), elapsed_ns),
                    percent(bad, asked),
                )
            }
            _ => (None, None),
        };
        BusRow {
            name: bus.name.clone(),
            port_open: bus.port_open,
            utilisation_percent,
            bad_replies_percent,
            late_wakeups: c.late_wakeups,
        }
    }
}

/// The history as bars, scaled to its largest value (or `floor`, if larger: a flat line of
/// small values stays low).
pub fn sparkline(history: &VecDeque<f32>, floor: f32) -> String {
    let top = history.iter().copied().fold(floor, f32::max);
    history
        .iter()
        .map(|v| {
            let level = (v / top * (BARS.len() - 1) as f32).round();
            BARS[(level.max(0.0) as usize).min(BARS.len() - 1)]
        })
        .collect()
}

fn cell(v: Option<f32>, decimals: usize) -> String {
    v.map_or_else(|| "-".to_string(), |v| format!("{v:.decimals$}"))
}

/// Draw the model on a frame.
pub fn draw(frame: &mut ratatui::Frame, model: &LiveModel) {
    let servo_rows = model.servos.len() as u16 + 3;
    let bus_rows = model.buses.len() as u16 + 2;
    let [link, servos, buses, texts, log, help] = Layout::vertical([
        Constraint::Length(1),
        Constraint::Length(servo_rows),
        Constraint::Length(bus_rows),
        Constraint::Min(3),
        Constraint::Length(LOG_LINES as u16 + 2),
        Constraint::Length(1),
    ])
    .areas(frame.area());

    let link_style = if model.failsafe {
        Style::default().fg(Color::Red).add_modifier(Modifier::BOLD)
    } else {
        Style::default()
    };
    frame.render_widget(Paragraph::new(model.link.as_str()).style(link_style), link);

    let header = Row::new([
        "servo",
        "bus",
        "id",
        "goal mm",
        "pos mm",
        "err mm",
        "A",
        "°C",
        "V",
        "state",
        "|err| history",
        "current history",
    ])
    .style(Style::default().add_modifier(Modifier::BOLD));
    let rows = model.servos.iter().map(|s| {
        let style = if s.state.starts_with("Online") && !s.state.contains(' ') {
            Style::default()
        } else {
            Style::default().fg(Color::Yellow)
        };
        Row::new([
            s.name.clone(),
            s.bus.clone(),
            s.id.to_string(),
            cell(s.goal_mm, 2),
            cell(s.position_mm, 2),
            cell(s.error_mm, 2),
            cell(s.current_a, 2),
            cell(s.temperature_c, 0),
            cell(s.voltage_v, 2),
            s.state.clone(),
            sparkline(&s.error_history, 0.5),
            sparkline(&s.current_history, 0.5),
        ])
        .style(style)
    });
    let widths = [
        Constraint::Length(14),
        Constraint::Length(8),
        Constraint::Length(3),
        Constraint::Length(8),
        Constraint::Length(8),
        Constraint::Length(7),
        Constraint::Length(6),
        Constraint::Length(4),
        Constraint::Length(6),
        Constraint::Length(22),
        Constraint::Length(HISTORY as u16),
        Constraint::Length(HISTORY as u16),
    ];
    frame.render_widget(
        Table::new(rows, widths)
            .header(header)
            .block(Block::bordered().title(" servos ")),
        servos,
    );

    let bus_lines: Vec<Line> = model
        .buses
        .iter()
        .map(|b| {
            Line::from(format!(
                "{:<10} {}   wire use {:>5}%   bad replies {:>5}%   late wake-ups {}",
                b.name,
                if b.port_open {
                    "port open"
                } else {
                    "PORT LOST"
                },
                cell(b.utilisation_percent, 1),
                cell(b.bad_replies_percent, 1),
                b.late_wakeups
            ))
        })
        .collect();
    frame.render_widget(
        Paragraph::new(bus_lines).block(Block::bordered().title(" buses ")),
        buses,
    );
    let text_lines: Vec<Line> = model.texts.iter().map(|t| Line::from(t.as_str())).collect();
    frame.render_widget(
        Paragraph::new(text_lines).block(Block::bordered().title(" STATUSTEXT, latest last ")),
        texts,
    );
    let log_lines: Vec<Line> = model.log.iter().map(|t| Line::from(t.as_str())).collect();
    frame.render_widget(
        Paragraph::new(log_lines).block(Block::bordered().title(" log ")),
        log,
    );
    frame.render_widget(Paragraph::new("q: quit"), help);
}

/// Log lines kept for the view while it owns the terminal.
static LOG: Mutex<VecDeque<String>> = Mutex::new(VecDeque::new());

/// A log writer for `tracing_subscriber` that keeps lines for the view instead of writing
/// them over the screen: `.with_writer(LogWriter::default)`.
#[derive(Debug, Default)]
pub struct LogWriter(Vec<u8>);

impl std::io::Write for LogWriter {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for LogWriter {
    fn drop(&mut self) {
        let text = String::from_utf8_lossy(&self.0);
        if let Ok(mut log) = LOG.lock() {
            for line in text.lines().filter(|l| !l.trim().is_empty()) {
                if log.len() == LOG_LINES {
                    log.pop_front();
                }
                log.push_back(line.to_string());
            }
        }
    }
}

fn log_lines() -> Vec<String> {
    LOG.lock()
        .map(|l| l.iter().cloned().collect())
        .unwrap_or_default()
}

/// Leaves the terminal as it was found, however the view ends (quit, end of run, abort).
struct Restore;

impl Drop for Restore {
    fn drop(&mut self) {
        ratatui::restore();
    }
}

/// Whether a key press asks to quit: `q`, Esc or Ctrl-C (raw mode turns Ctrl-C into a key).
fn quit_pressed() -> std::io::Result<bool> {
    while event::poll(Duration::ZERO)? {
        if let Event::Key(key) = event::read()?
            && key.kind == KeyEventKind::Press
            && (matches!(key.code, KeyCode::Char('q') | KeyCode::Esc)
                || (key.code == KeyCode::Char('c')
                    && key.modifiers.contains(KeyModifiers::CONTROL)))
        {
            return Ok(true);
        }
    }
    Ok(false)
}

/// A full screen of text redrawn in place (the live view of `monitor`), with the terminal
/// restored when it is dropped.
pub struct TextScreen {
    terminal: ratatui::DefaultTerminal,
    _restore: Restore,
}

impl TextScreen {
    pub fn open() -> std::io::Result<Self> {
        let terminal = ratatui::try_init()?;
        Ok(TextScreen {
            terminal,
            _restore: Restore,
        })
    }

    /// Show `text` with the help line below it.
    pub fn show(&mut self, text: &str) -> std::io::Result<()> {
        self.terminal.draw(|frame| {
            let [body, help] =
                Layout::vertical([Constraint::Min(1), Constraint::Length(1)]).areas(frame.area());
            frame.render_widget(Paragraph::new(text), body);
            frame.render_widget(Paragraph::new("q: quit"), help);
        })?;
        Ok(())
    }
}

/// Completes when `q`, Esc or Ctrl-C is pressed on a terminal in raw mode (looked for every
/// 100 ms); never if the keyboard cannot be read.
pub async fn quit_key() {
    loop {
        match quit_pressed() {
            Ok(true) => return,
            Ok(false) => tokio::time::sleep(Duration::from_millis(100)).await,
            Err(_) => std::future::pending::<()>().await,
        }
    }
}

/// Show the live view until `q` is pressed (then return), or until the task is aborted or
/// the bridge is gone.
pub async fn show(mut view: watch::Receiver<BridgeView>) -> std::io::Result<()> {
    let mut terminal = ratatui::try_init()?;
    let _restore = Restore;
    let mut model = LiveModel::default();
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
        assert!((row.error_mm.unwrap() - (1.5 + 34.0 * 0.01 - 2.0)).abs() < 1e-4);
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
            crate::simulation::table::render(&BridgeView {
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
    fn the_link_line_says_whom_and_whether_in_failsafe() {
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
            "autopilot 1/1   output rate asked: 40 Hz   failsafe: ACTIVE"
        );
    }

    #[test]
    fn sparklines_scale_to_the_largest_value_or_the_floor() {
        let h: VecDeque<f32> = [0.0, 1.0, 2.0, 4.0].into();
        assert_eq!(sparkline(&h, 0.5), "▁▃▅█");
        let small: VecDeque<f32> = [0.01, 0.02].into();
        assert_eq!(sparkline(&small, 0.5), "▁▁");
        assert_eq!(sparkline(&VecDeque::new(), 0.5), "");
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

//! The terminal as the live screens use it (`sitl`'s view, `monitor`): a screen of text redrawn
//! in place and restored on every way out, the quit keys, and the log lines kept while a screen
//! owns the terminal.

use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use ratatui::layout::{Constraint, Layout};
use ratatui::widgets::Paragraph;
use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Duration;

/// Log lines kept for the view; it shows the latest that fit.
pub const LOG_LINES: usize = 200;

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

pub(crate) fn log_lines() -> Vec<String> {
    LOG.lock()
        .map(|l| l.iter().cloned().collect())
        .unwrap_or_default()
}

/// Leaves the terminal as it was found, however the view ends (quit, end of run, abort).
pub(crate) struct Restore;

impl Drop for Restore {
    fn drop(&mut self) {
        ratatui::restore();
    }
}

/// Whether a key press asks to quit: `q`, Esc or Ctrl-C (raw mode turns Ctrl-C into a key).
pub(crate) fn quit_pressed() -> std::io::Result<bool> {
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

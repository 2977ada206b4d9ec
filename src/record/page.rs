//! One HTML page per flight: every servo's picture (goal and position, current, temperature,
//! voltage, alarms marked; see [`super::plot`]) and the flight's summary, in a single file that
//! opens in any browser with no network: the pictures are inline SVG, and the few lines of
//! script that zoom them are in the page.
//!
//! Zoom: the mouse wheel over a picture zooms it about the pointer, dragging pans it, a
//! double click shows the whole flight again. Without script the page is still complete.

use super::plot::servo_svg;
use super::reader::Recording;
use super::summary::summary;
use std::fmt::Write as _;
use std::io;
use std::path::{Path, PathBuf};

/// Wheel zoom, drag pan and double-click reset of every `svg[data-zoom]`, through its viewBox.
pub(crate) const ZOOM_SCRIPT: &str = r#"
for (const svg of document.querySelectorAll('svg[data-zoom]')) {
  const whole = svg.getAttribute('viewBox').split(' ').map(Number);
  let box = whole.slice();
  const show = () => svg.setAttribute('viewBox', box.join(' '));
  const at = (e) => {
    const r = svg.getBoundingClientRect();
    return [box[0] + (e.clientX - r.left) / r.width * box[2],
            box[1] + (e.clientY - r.top) / r.height * box[3]];
  };
  svg.addEventListener('wheel', (e) => {
    e.preventDefault();
    const [x, y] = at(e);
    const k = e.deltaY < 0 ? 0.8 : 1.25;
    const w = Math.min(whole[2], box[2] * k), h = Math.min(whole[3], box[3] * k);
    box = [x - (x - box[0]) * w / box[2], y - (y - box[1]) * h / box[3], w, h];
    show();
  }, { passive: false });
  let drag = null;
  svg.addEventListener('pointerdown', (e) => { drag = at(e); svg.setPointerCapture(e.pointerId); });
  svg.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const [x, y] = at(e);
    box[0] += drag[0] - x; box[1] += drag[1] - y;
    show();
  });
  svg.addEventListener('pointerup', () => { drag = null; });
  svg.addEventListener('dblclick', () => { box = whole.slice(); show(); });
}
"#;

/// Text for HTML.
fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// The page of a flight. `title` names the record (its file stem).
pub fn flight_page(rec: &Recording, title: &str) -> String {
    let mut html = String::with_capacity(256 * 1024);
    let _ = writeln!(html, "<!DOCTYPE html>");
    let _ = writeln!(html, r#"<html lang="en"><head><meta charset="utf-8">"#);
    let _ = writeln!(html, "<title>Flight {}</title>", escape(title));
    let _ = writeln!(
        html,
        "<style>body{{font-family:sans-serif;margin:1em 2em}}pre{{overflow-x:auto}}\
         svg{{max-width:100%;height:auto;border:1px solid #ccc;cursor:grab}}</style>"
    );
    let _ = writeln!(html, "</head><body>");
    let _ = writeln!(html, "<h1>Flight {}</h1>", escape(title));
    let _ = writeln!(
        html,
        "<p>Every servo: goal and position, current, temperature and voltage against time, \
         with alarms marked. Wheel: zoom; drag: pan; double click: the whole flight.</p>"
    );
    let _ = writeln!(html, "<pre>{}</pre>", escape(&summary(rec).to_string()));
    for (index, servo) in rec.header.servos.iter().enumerate() {
        let svg = servo_svg(rec, index, title);
        // Inline SVG takes no XML declaration.
        let svg = svg
            .trim_start()
            .strip_prefix("<?xml")
            .and_then(|rest| rest.split_once("?>"))
            .map_or(svg.as_str(), |(_, body)| body.trim_start());
        let svg = svg.replacen("<svg ", "<svg data-zoom=\"\" ", 1);
        let _ = writeln!(
            html,
            "<section data-servo=\"{}\"><h2>{}</h2>\n{svg}</section>",
            escape(&servo.name),
            escape(&servo.name)
        );
    }
    let _ = writeln!(html, "<script>{ZOOM_SCRIPT}</script>");
    let _ = writeln!(html, "</body></html>");
    html
}

/// Write the flight's page into `out_dir` (created if missing) as `<stem>.html`.
pub fn write_page(rec: &Recording, out_dir: &Path, stem: &str) -> io::Result<PathBuf> {
    std::fs::create_dir_all(out_dir)?;
    let path = out_dir.join(format!("{stem}.html"));
    std::fs::write(&path, flight_page(rec, stem))?;
    Ok(path)
}

//! Drawing SVG by hand, shared by `record plot` ([`super::plot`]) and `record trend --html`
//! ([`super::trend_html`]): text escaping, tick steps and their labels, and the parts of a chart panel — its frame and title, the grid with its labels,
//! reference lines, polylines and the "no data" note.
//!
//! Coordinates are written with one decimal. Each function appends whole lines to a `String`.

use std::fmt::Write as _;

/// Text for XML.
pub(crate) fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c if c.is_control() => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

/// A tick spacing of 1, 2 or 5 × 10ⁿ giving about `target` ticks over `span`.
pub(crate) fn nice_step(span: f64, target: f64) -> f64 {
    let raw = span / target;
    if !raw.is_finite() || raw <= 0.0 {
        return 1.0;
    }
    let magnitude = 10f64.powf(raw.log10().floor());
    let norm = raw / magnitude;
    let nice = if norm < 1.5 {
        1.0
    } else if norm < 3.0 {
        2.0
    } else if norm < 7.0 {
        5.0
    } else {
        10.0
    };
    nice * magnitude
}

/// The multiples of [`nice_step`] from `lo` to `hi` (at most 50).
pub(crate) fn ticks(lo: f64, hi: f64, target: f64) -> Vec<f64> {
    let step = nice_step(hi - lo, target);
    let mut v = (lo / step).ceil() * step;
    let mut out = Vec::new();
    while v <= hi + step * 1e-9 && out.len() < 50 {
        out.push(if v.abs() < step * 1e-9 { 0.0 } else { v });
        v += step;
    }
    out
}

/// A tick's value with as many decimals as its step needs.
pub(crate) fn tick_label(v: f64, step: f64) -> String {
    let decimals = if step >= 1.0 {
        0
    } else {
        (-step.log10().floor()) as usize
    };
    format!("{v:.decimals$}")
}

/// A polyline through `points` (already in SVG units): `<polyline {attributes} points="…"/>`.
pub(crate) fn polyline(
    svg: &mut String,
    attributes: &str,
    points: impl IntoIterator<Item = (f64, f64)>,
) {
    let mut coords = String::new();
    for (x, y) in points {
        if !coords.is_empty() {
            coords.push(' ');
        }
        let _ = write!(coords, "{x:.1},{y:.1}");
    }
    let _ = writeln!(svg, r#"<polyline {attributes} points="{coords}"/>"#);
}

/// A panel's plot area, in SVG units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Area {
    pub left: f64,
    pub top: f64,
    pub width: f64,
    pub height: f64,
}

impl Area {
    pub fn right(&self) -> f64 {
        self.left + self.width
    }

    pub fn bottom(&self) -> f64 {
        self.top + self.height
    }

    /// The height of `v` on an axis from `lo` (the bottom) to `hi` (the top).
    pub fn y_of(&self, v: f64, (lo, hi): (f64, f64)) -> f64 {
        self.top + (1.0 - (v - lo) / (hi - lo)) * self.height
    }

    /// The frame around the area.
    pub fn frame(&self, svg: &mut String) {
        let _ = writeln!(
            svg,
            r##"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="none" stroke="#999"/>"##,
            self.left, self.top, self.width, self.height
        );
    }

    /// The panel's title, above its left end.
    pub fn title(&self, svg: &mut String, title: &str) {
        let _ = writeln!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" font-weight="bold">{}</text>"#,
            self.left,
            self.top - 7.0,
            escape(title)
        );
    }

    /// Horizontal grid lines with their values at the left, about `target` of them over the
    /// axis `range` (bottom, top).
    pub fn y_grid(&self, svg: &mut String, range: (f64, f64), target: f64) {
        let (lo, hi) = range;
        let step = nice_step(hi - lo, target);
        for v in ticks(lo, hi, target) {
            let y = self.y_of(v, range);
            let _ = writeln!(
                svg,
                r##"<line x1="{:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#eee"/><text x="{:.1}" y="{:.1}" text-anchor="end">{}</text>"##,
                self.left,
                self.right(),
                self.left - 6.0,
                y + 4.0,
                tick_label(v, step)
            );
        }
    }

    /// A vertical grid line at `x`, with its `label` under the area (none: the line alone).
    pub fn x_tick(&self, svg: &mut String, x: f64, label: Option<&str>) {
        let (top, bottom) = (self.top, self.bottom());
        let _ = write!(
            svg,
            r##"<line x1="{x:.1}" y1="{top:.1}" x2="{x:.1}" y2="{bottom:.1}" stroke="#f2f2f2"/>"##
        );
        if let Some(label) = label {
            let _ = write!(
                svg,
                r##"<text x="{x:.1}" y="{:.1}" text-anchor="middle" fill="#555">{}</text>"##,
                bottom + 16.0,
                escape(label)
            );
        }
        svg.push('\n');
    }

    /// A dashed reference line across the area at height `y`, labelled at its right end.
    pub fn reference_line(&self, svg: &mut String, y: f64, color: &str, label: &str) {
        let _ = writeln!(
            svg,
            r#"<line class="reference" x1="{:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="{color}" stroke-dasharray="2 4"/><text x="{:.1}" y="{:.1}" fill="{color}" text-anchor="end">{}</text>"#,
            self.left,
            self.right(),
            self.right() - 4.0,
            y - 3.0,
            escape(label)
        );
    }

    /// "no data" in the middle of the area.
    pub fn no_data(&self, svg: &mut String) {
        let _ = writeln!(
            svg,
            r##"<text x="{:.1}" y="{:.1}" text-anchor="middle" fill="#999">no data</text>"##,
            self.left + self.width / 2.0,
            self.top + self.height / 2.0
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_and_labelled_with_the_decimals_their_step_needs() {
        let step = nice_step(1.16, 4.0);
        let labels: Vec<String> = ticks(-0.08, 1.08, 4.0)
            .into_iter()
            .map(|v| tick_label(v, step))
            .collect();
        assert_eq!(labels, ["0.0", "0.2", "0.4", "0.6", "0.8", "1.0"]);
        assert_eq!(tick_label(20.0, nice_step(100.0, 5.0)), "20");
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(escape("a<b & \"c\"\n"), "a&lt;b &amp; &quot;c&quot; ");
    }
}

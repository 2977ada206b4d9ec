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

/// The range an axis shows for values from `lo` to `hi`: padded on each side by `share` of
/// its span, or by `min_share` of the top's magnitude (at least 0.001) if that is more. A flat
/// range — a constant series, which would otherwise get an axis a few millionths wide labelled
/// with as many decimals — is first widened to its value ± 10 %, and a series of zeros to 0–1.
/// No values (`lo` or `hi` not finite): 0 to 1.
pub(crate) fn axis_range(lo: f64, hi: f64, share: f64, min_share: f64) -> (f64, f64) {
    let (lo, hi) = if !lo.is_finite() || !hi.is_finite() {
        (0.0, 1.0)
    } else if hi - lo <= lo.abs().max(hi.abs()) * 1e-9 {
        let v = (lo + hi) / 2.0;
        if v == 0.0 {
            (0.0, 1.0)
        } else {
            (v - v.abs() * 0.1, v + v.abs() * 0.1)
        }
    } else {
        (lo, hi)
    };
    let pad = ((hi - lo) * share).max(hi.abs().max(1e-3) * min_share);
    (lo - pad, hi + pad)
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

    /// A vertical grid line at `x`, with `labels` under the area, one a line, the first
    /// darker (none: the line alone).
    pub fn x_tick(&self, svg: &mut String, x: f64, labels: &[&str]) {
        let (top, bottom) = (self.top, self.bottom());
        let _ = write!(
            svg,
            r##"<line x1="{x:.1}" y1="{top:.1}" x2="{x:.1}" y2="{bottom:.1}" stroke="#f2f2f2"/>"##
        );
        for (k, label) in labels.iter().enumerate() {
            let _ = write!(
                svg,
                r##"<text x="{x:.1}" y="{:.1}" text-anchor="middle" fill="{}">{}</text>"##,
                bottom + 16.0 + 14.0 * k as f64,
                if k == 0 { "#555" } else { "#999" },
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
    fn a_flat_axis_is_its_value_give_or_take_a_tenth_and_zeros_are_0_to_1() {
        // Not flat: padded by the share of the span, or of the top's size if more.
        let close = |(a, b): (f64, f64), (c, d): (f64, f64)| {
            assert!((a - c).abs() < 1e-12 && (b - d).abs() < 1e-12, "{a}..{b}");
        };
        close(axis_range(2.0, 4.0, 0.1, 0.0), (1.8, 4.2));
        close(axis_range(100.0, 101.0, 0.1, 0.02), (97.98, 103.02));
        close(axis_range(0.07, 0.07, 0.0, 0.0), (0.063, 0.077));
        close(axis_range(-5.0, -5.0, 0.0, 0.0), (-5.5, -4.5));
        close(axis_range(0.0, 0.0, 0.08, 0.02), (-0.08, 1.08));
        close(
            axis_range(f64::INFINITY, f64::NEG_INFINITY, 0.0, 0.0),
            (0.0, 1.0),
        );
    }

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

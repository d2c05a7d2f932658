//! `ima-plot`: the figures of `ima` (the demo's world and trajectories, `ima scan`'s picture,
//! the heading experiment's plots) drawn with [`plotters`] on its SVG backend, with one look:
//! a title, axes in metres with their units, a 1 m (or coarser) grid, and a legend with a
//! scale bar beside the plot, so neither ever covers the data.
//!
//! No font is loaded: plotters is built without its `ttf` feature, so text is written as SVG
//! `<text>` elements (the viewer picks the sans-serif font) and laid out with plotters' own
//! width estimate. Nothing here needs a system library.
//!
//! Everything draws on an [`Area`] handed out by [`render`], which returns the SVG document as
//! a `String` and never fails: a drawing error (none is expected for an in-memory SVG) gives
//! a small SVG that names it. Non-finite coordinates are dropped before drawing, so no `NaN`
//! reaches the document. [`inspect`] checks a document's structure for tests.

#![warn(missing_docs)]

use std::ops::Range;

pub use plotters;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// A drawing area of an SVG document being rendered (pixels, origin top left).
pub type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// A chart with both axes in metres (or any `f64` unit).
pub type Chart<'a> = ChartContext<'a, SVGBackend<'a>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Whatever stopped a drawing.
pub type PlotError = Box<dyn std::error::Error>;

/// The font family of every text.
pub const FONT: &str = "sans-serif";

/// Height of the band [`titled`] takes for a title alone, pixels.
pub const TITLE_H: u32 = 30;
/// Height of the band [`titled`] takes for a title and a subtitle, pixels.
pub const TITLE_SUB_H: u32 = 48;
/// Height of the band [`captioned`] takes, pixels.
pub const CAPTION_H: u32 = 22;
/// Margin around a chart's plotting area (outside its axes' labels), pixels.
pub const MARGIN: u32 = 10;
/// Height under a chart for the x tick labels and the axis description, pixels.
pub const X_LABELS_H: u32 = 42;
/// Width left of a chart for the y tick labels and the axis description, pixels.
pub const Y_LABELS_W: u32 = 52;
/// Height of one legend row, pixels.
pub const LEGEND_ROW_H: u32 = 19;

/// Distinct colours for runs and robots (Okabe–Ito: told apart with the common kinds of
/// colour blindness), dark enough to read on white.
pub const PALETTE: [RGBColor; 7] = [
    RGBColor(0, 114, 178),   // blue
    RGBColor(213, 94, 0),    // vermillion
    RGBColor(0, 158, 115),   // bluish green
    RGBColor(204, 121, 167), // reddish purple
    RGBColor(230, 159, 0),   // orange
    RGBColor(86, 180, 233),  // sky blue
    RGBColor(90, 90, 90),    // grey
];

/// The `i`-th colour of [`PALETTE`], wrapping around.
#[must_use]
pub fn run_colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// Grey of the grid lines.
pub const GRID: RGBColor = RGBColor(226, 226, 226);
/// Dark grey of walls, axes and text.
pub const INK: RGBColor = RGBColor(40, 40, 40);
/// Mid grey of secondary text.
pub const MUTED: RGBColor = RGBColor(100, 100, 100);

/// A text style of `px` pixels (the font size written into the SVG) in `colour`.
#[must_use]
pub fn text_style(px: f64, colour: RGBColor) -> TextStyle<'static> {
    // The SVG backend writes size / 1.24 as the font size.
    (FONT, px * 1.24).into_font().color(&colour)
}

/// A bold text style of `px` pixels in `colour`.
#[must_use]
pub fn bold_style(px: f64, colour: RGBColor) -> TextStyle<'static> {
    (FONT, px * 1.24, FontStyle::Bold)
        .into_font()
        .color(&colour)
}

/// Render a `width` × `height` SVG document: a white page handed to `draw`.
///
/// Never fails: should drawing fail, the document is a page that names the error.
pub fn render(
    width: u32,
    height: u32,
    draw: impl FnOnce(&Area<'_>) -> Result<(), PlotError>,
) -> String {
    let (width, height) = (width.clamp(50, 20_000), height.clamp(50, 20_000));
    let mut out = String::new();
    let result = {
        let root = SVGBackend::with_string(&mut out, (width, height)).into_drawing_area();
        let drawn = root
            .fill(&WHITE)
            .map_err(PlotError::from)
            .and_then(|()| draw(&root));
        drawn.and_then(|()| root.present().map_err(PlotError::from))
    };
    match result {
        Ok(()) => out,
        Err(e) => failure_page(width, height, &e.to_string()),
    }
}

fn failure_page(width: u32, height: u32, message: &str) -> String {
    let escaped: String = message
        .chars()
        .map(|c| match c {
            '<' => "&lt;".to_owned(),
            '>' => "&gt;".to_owned(),
            '&' => "&amp;".to_owned(),
            c => c.to_string(),
        })
        .collect();
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{width}\" height=\"{height}\" \
         viewBox=\"0 0 {width} {height}\">\n<text x=\"10\" y=\"20\" font-family=\"{FONT}\" \
         font-size=\"14\">plot failed: {escaped}</text>\n</svg>\n"
    )
}

/// Write `text` at pixel `(x, y)` of `area` with the anchor `pos`.
pub fn text_at(
    area: &Area<'_>,
    text: &str,
    (x, y): (i32, i32),
    style: &TextStyle<'_>,
    pos: Pos,
) -> Result<(), PlotError> {
    area.draw_text(text, &style.pos(pos), (x, y))?;
    Ok(())
}

/// Put a title (16 px) and an optional subtitle (12 px) at the top of `area`; returns the
/// area below them.
pub fn titled<'a>(
    area: &Area<'a>,
    title: &str,
    subtitle: Option<&str>,
) -> Result<Area<'a>, PlotError> {
    let top = Pos::new(HPos::Left, VPos::Top);
    text_at(area, title, (10, 7), &text_style(16.0, INK), top)?;
    let band = if let Some(sub) = subtitle {
        text_at(area, sub, (10, 28), &text_style(12.0, MUTED), top)?;
        TITLE_SUB_H
    } else {
        TITLE_H
    };
    Ok(area.split_vertically(band).1)
}

/// Put a caption (13 px, bold, centred) at the top of `area`; returns the area below it.
pub fn captioned<'a>(area: &Area<'a>, caption: &str) -> Result<Area<'a>, PlotError> {
    let (w, _) = area.dim_in_pixel();
    let style = bold_style(13.0, INK);
    text_at(
        area,
        caption,
        (i32::try_from(w / 2).unwrap_or(0), 4),
        &style,
        Pos::new(HPos::Center, VPos::Top),
    )?;
    Ok(area.split_vertically(CAPTION_H).1)
}

/// A rectangle of the plane, metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Horizontal extent.
    pub x: Range<f64>,
    /// Vertical extent.
    pub y: Range<f64>,
}

impl Frame {
    /// The frame of `x` × `y`.
    #[must_use]
    pub fn new(x: Range<f64>, y: Range<f64>) -> Self {
        Self { x, y }
    }

    /// The smallest frame holding every finite point of `points`, grown by `margin` on each
    /// side (at least 1 wide and high); `None` without a finite point.
    #[must_use]
    pub fn around(points: impl IntoIterator<Item = (f64, f64)>, margin: f64) -> Option<Self> {
        let mut b: Option<(f64, f64, f64, f64)> = None;
        for (x, y) in points {
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            b = Some(match b {
                None => (x, x, y, y),
                Some((x0, x1, y0, y1)) => (x0.min(x), x1.max(x), y0.min(y), y1.max(y)),
            });
        }
        let (x0, x1, y0, y1) = b?;
        let m = if margin.is_finite() {
            margin.max(0.0)
        } else {
            0.0
        };
        let grow = |a: f64, b: f64| {
            let pad = ((1.0 - (b - a)) / 2.0).max(0.0);
            (a - m - pad)..(b + m + pad)
        };
        Some(Self {
            x: grow(x0, x1),
            y: grow(y0, y1),
        })
    }

    /// Width, metres.
    #[must_use]
    pub fn width(&self) -> f64 {
        self.x.end - self.x.start
    }

    /// Height, metres.
    #[must_use]
    pub fn height(&self) -> f64 {
        self.y.end - self.y.start
    }
}

/// The pixel size of an area whose [`metric_chart`] shows `frame` at `px_per_m` pixels per
/// metre on both axes (equal scales: a circle stays round).
#[must_use]
pub fn metric_chart_size(frame: &Frame, px_per_m: f64) -> (u32, u32) {
    let px = |m: f64| (m * px_per_m).round().clamp(10.0, 10_000.0) as u32;
    (
        px(frame.width()) + Y_LABELS_W + 2 * MARGIN,
        px(frame.height()) + X_LABELS_H + 2 * MARGIN,
    )
}

/// A grid step of at least `min_px` pixels at `px_per_m`: 0.5, 1, 2, 5, 10, 20, 50 m …
#[must_use]
pub fn grid_step(px_per_m: f64, min_px: f64) -> f64 {
    let mut step = 0.5;
    for _ in 0..12 {
        if step * px_per_m >= min_px {
            break;
        }
        let s = step * 2.0;
        step = if (s / 10f64.powf(s.log10().floor()) - 4.0).abs() < 1e-9 {
            step * 2.5 // 2 → 5, 20 → 50
        } else {
            s
        };
    }
    step
}

/// The widest frame a metric chart draws: 1,000 km (wider spans, e.g. from a world file's
/// wall at ±1e308 m, made the axis code spin).
pub const MAX_FRAME_M: f64 = 1e6;

/// A chart filling `area` that shows `frame` with axes described by `x_desc` and `y_desc`
/// (give the unit, e.g. `"x (m)"`), a grid of [`grid_step`] and tick labels on it.
///
/// # Errors
/// A frame wider or higher than [`MAX_FRAME_M`] (or not finite), or the backend's error.
pub fn metric_chart<'a>(
    area: &Area<'a>,
    frame: &Frame,
    x_desc: &str,
    y_desc: &str,
) -> Result<Chart<'a>, PlotError> {
    let (w, h) = (frame.width(), frame.height());
    if !(frame.x.start.is_finite() && frame.y.start.is_finite() && w.is_finite() && h.is_finite()) {
        return Err("cannot draw a frame whose edges are not finite numbers".into());
    }
    if !((0.0..=MAX_FRAME_M).contains(&w) && (0.0..=MAX_FRAME_M).contains(&h)) {
        return Err(format!(
            "cannot draw a frame of {w:.3e} m × {h:.3e} m (at most {MAX_FRAME_M:e} m a side)"
        )
        .into());
    }
    let mut chart = ChartBuilder::on(area)
        .margin(MARGIN)
        .x_label_area_size(X_LABELS_H)
        .y_label_area_size(Y_LABELS_W)
        .build_cartesian_2d(frame.x.clone(), frame.y.clone())?;
    let (w_px, h_px) = chart.plotting_area().dim_in_pixel();
    let ppm_x = f64::from(w_px) / frame.width().max(1e-9);
    let ppm_y = f64::from(h_px) / frame.height().max(1e-9);
    let (sx, sy) = (grid_step(ppm_x, 40.0), grid_step(ppm_y, 40.0));
    let ticks = |span: f64, step: f64| ((span / step).floor() as usize + 1).max(2);
    let fmt = |step: f64| move |v: &f64| format_tick(*v, step);
    let label = text_style(11.0, MUTED);
    let desc = text_style(12.0, INK);
    chart
        .configure_mesh()
        .x_labels(ticks(frame.width(), sx))
        .y_labels(ticks(frame.height(), sy))
        .max_light_lines(0)
        .bold_line_style(GRID.stroke_width(1))
        .axis_style(MUTED.stroke_width(1))
        .x_label_formatter(&fmt(sx))
        .y_label_formatter(&fmt(sy))
        .label_style(label)
        .axis_desc_style(desc)
        .x_desc(x_desc)
        .y_desc(y_desc)
        .draw()?;
    Ok(chart)
}

/// A tick label: no decimals on a whole-metre grid, one on a half-metre grid; `0` not `-0`.
#[must_use]
pub fn format_tick(v: f64, step: f64) -> String {
    let v = if v.abs() < step.abs() * 1e-3 { 0.0 } else { v };
    if step >= 1.0 {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

/// Drop the points with a non-finite coordinate.
pub fn finite(points: impl IntoIterator<Item = (f64, f64)>) -> Vec<(f64, f64)> {
    points
        .into_iter()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect()
}

/// A polyline through `points` (non-finite ones dropped), solid or dashed.
pub fn line(
    chart: &mut Chart<'_>,
    points: impl IntoIterator<Item = (f64, f64)>,
    colour: RGBColor,
    width: u32,
    dashed: bool,
) -> Result<(), PlotError> {
    let pts = finite(points);
    if pts.len() < 2 {
        return Ok(());
    }
    let style = colour.stroke_width(width);
    let area = chart.plotting_area();
    if dashed {
        area.draw(&DashedPathElement::new(pts, 6, 4, style))?;
    } else {
        area.draw(&PathElement::new(pts, style))?;
    }
    Ok(())
}

/// `n` points around the circle of centre `c` and radius `r`, closed (the first repeated).
#[must_use]
pub fn circle_points((cx, cy): (f64, f64), r: f64, n: usize) -> Vec<(f64, f64)> {
    let n = n.max(3);
    (0..=n)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / n as f64;
            (cx + r * a.cos(), cy + r * a.sin())
        })
        .collect()
}

/// A disc of radius `r_m` metres (drawn to scale), filled with `fill` and outlined with
/// `outline` when given.
pub fn disc(
    chart: &mut Chart<'_>,
    centre: (f64, f64),
    r_m: f64,
    fill: Option<RGBAColor>,
    outline: Option<ShapeStyle>,
) -> Result<(), PlotError> {
    if !(centre.0.is_finite() && centre.1.is_finite() && r_m.is_finite() && r_m > 0.0) {
        return Ok(());
    }
    let pts = circle_points(centre, r_m, 48);
    let area = chart.plotting_area();
    if let Some(f) = fill {
        area.draw(&Polygon::new(pts.clone(), f.filled()))?;
    }
    if let Some(o) = outline {
        area.draw(&PathElement::new(pts, o))?;
    }
    Ok(())
}

/// A ring of radius `r_m` metres, dashed or solid, drawn only where it lies inside the
/// chart's ranges.
pub fn ring(
    chart: &mut Chart<'_>,
    centre: (f64, f64),
    r_m: f64,
    colour: RGBColor,
    dashed: bool,
) -> Result<(), PlotError> {
    if !(centre.0.is_finite() && centre.1.is_finite() && r_m.is_finite() && r_m > 0.0) {
        return Ok(());
    }
    let (xr, yr) = (chart.x_range(), chart.y_range());
    let inside = |p: &(f64, f64)| xr.contains(&p.0) && yr.contains(&p.1);
    let mut run: Vec<(f64, f64)> = Vec::new();
    let pts = circle_points(centre, r_m, 144);
    // Start at a point outside, if any, so a run is never cut at the seam.
    let first_out = pts.iter().position(|p| !inside(p)).unwrap_or(0);
    let n = pts.len() - 1; // the last repeats the first
    for i in 0..=n {
        let p = pts[(first_out + i) % n];
        if inside(&p) {
            run.push(p);
        } else if !run.is_empty() {
            line(chart, run.drain(..), colour, 1, dashed)?;
        }
    }
    line(chart, run, colour, 1, dashed)
}

/// A marker of fixed pixel size at a point of the plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mark {
    /// A short line (a path in the legend).
    Line,
    /// A short dashed line.
    Dashed,
    /// A filled dot.
    Dot,
    /// A filled square.
    Square,
    /// An open circle.
    Ring,
    /// A diagonal cross.
    Cross,
    /// A filled swatch (an area's colour).
    Swatch,
}

/// Draw `mark` (about 9 px across) in `colour` at the data point `at`.
pub fn mark(
    chart: &mut Chart<'_>,
    at: (f64, f64),
    mark: Mark,
    colour: RGBColor,
) -> Result<(), PlotError> {
    if !(at.0.is_finite() && at.1.is_finite()) {
        return Ok(());
    }
    let area = chart.plotting_area();
    let p = EmptyElement::at(at);
    match mark {
        Mark::Dot => area.draw(&(p + Circle::new((0, 0), 4, colour.filled())))?,
        Mark::Ring => area.draw(&(p + Circle::new((0, 0), 5, colour.stroke_width(2))))?,
        Mark::Square | Mark::Swatch => {
            area.draw(&(p + Rectangle::new([(-4, -4), (4, 4)], colour.filled())))?;
        }
        Mark::Cross => area.draw(
            &(p + PathElement::new(vec![(-4, -4), (4, 4)], colour.stroke_width(2))
                + PathElement::new(vec![(-4, 4), (4, -4)], colour.stroke_width(2))),
        )?,
        Mark::Line | Mark::Dashed => {
            area.draw(&(p + PathElement::new(vec![(-6, 0), (6, 0)], colour.stroke_width(2))))?
        }
    }
    Ok(())
}

/// Write `text` next to the data point `at`, shifted by `offset` pixels, anchored at `pos`.
pub fn label(
    chart: &mut Chart<'_>,
    at: (f64, f64),
    text: &str,
    offset: (i32, i32),
    style: &TextStyle<'_>,
    pos: Pos,
) -> Result<(), PlotError> {
    label_on(chart, at, text, offset, style, pos, false)
}

/// [`label`] on a white backing, so a label over a path stays readable.
pub fn label_backed(
    chart: &mut Chart<'_>,
    at: (f64, f64),
    text: &str,
    offset: (i32, i32),
    style: &TextStyle<'_>,
    pos: Pos,
) -> Result<(), PlotError> {
    label_on(chart, at, text, offset, style, pos, true)
}

fn label_on(
    chart: &mut Chart<'_>,
    at: (f64, f64),
    text: &str,
    (dx, dy): (i32, i32),
    style: &TextStyle<'_>,
    pos: Pos,
    backed: bool,
) -> Result<(), PlotError> {
    if !(at.0.is_finite() && at.1.is_finite()) {
        return Ok(());
    }
    let area = chart.plotting_area();
    if backed {
        // The SVG's font size is the style's / 1.24; a sans-serif glyph is about 0.6 em.
        let px = style.font.get_size() / 1.24;
        let w = (0.6 * px * text.chars().count() as f64).ceil() as i32 + 4;
        let h = (1.2 * px).ceil() as i32;
        let x0 = match pos.h_pos {
            HPos::Left => dx - 2,
            HPos::Center => dx - w / 2,
            HPos::Right => dx - w + 2,
        };
        let y0 = match pos.v_pos {
            VPos::Top => dy - 1,
            VPos::Center => dy - h / 2,
            VPos::Bottom => dy - h + 1,
        };
        let backing = Rectangle::new([(x0, y0), (x0 + w, y0 + h)], WHITE.mix(0.8).filled());
        area.draw(&(EmptyElement::at(at) + backing))?;
    }
    let style = style.pos(pos);
    area.draw(&(EmptyElement::at(at) + Text::new(text.to_owned(), (dx, dy), style)))?;
    Ok(())
}

/// One row of a [`legend`].
#[derive(Debug, Clone, PartialEq)]
pub enum LegendRow {
    /// A bold heading over the entries below it.
    Heading(String),
    /// A marker in a colour and what it stands for.
    Entry {
        /// The marker.
        mark: Mark,
        /// Its colour.
        colour: RGBColor,
        /// The text.
        label: String,
    },
    /// A line of plain text.
    Note(String),
    /// A scale bar of `length_m` metres drawn at `px_per_m` (the chart's scale), labelled
    /// with its length.
    ScaleBar {
        /// The bar's length, metres.
        length_m: f64,
        /// The chart's pixels per metre.
        px_per_m: f64,
    },
}

impl LegendRow {
    /// An [`LegendRow::Entry`].
    #[must_use]
    pub fn entry(mark: Mark, colour: RGBColor, label: impl Into<String>) -> Self {
        Self::Entry {
            mark,
            colour,
            label: label.into(),
        }
    }

    /// A scale bar of a round length (1, 2, 5, 10 … m, or 0.5 m) between 40 and 150 pixels
    /// long at `px_per_m`.
    #[must_use]
    pub fn scale_bar(px_per_m: f64) -> Self {
        let px_per_m = if px_per_m.is_finite() && px_per_m > 0.0 {
            px_per_m
        } else {
            1.0
        };
        Self::ScaleBar {
            length_m: grid_step(px_per_m, 40.0),
            px_per_m,
        }
    }

    fn bar_px(length_m: f64, px_per_m: f64) -> i32 {
        (length_m * px_per_m).round().clamp(2.0, 400.0) as i32
    }

    fn width(&self) -> u32 {
        let chars = |s: &str| 7 * u32::try_from(s.chars().count()).unwrap_or(100).min(100);
        match self {
            Self::Heading(s) | Self::Note(s) => 8 + chars(s),
            Self::Entry { label, .. } => 46 + chars(label),
            Self::ScaleBar { length_m, px_per_m } => {
                10 + Self::bar_px(*length_m, *px_per_m).unsigned_abs() + 8 + chars("scale 50 m")
            }
        }
    }
}

/// Pixels a legend of `rows` needs: `(width, height)`.
#[must_use]
pub fn legend_size(rows: &[LegendRow]) -> (u32, u32) {
    let w = rows.iter().map(LegendRow::width).max().unwrap_or(0) + 12;
    let h = 12 + LEGEND_ROW_H * u32::try_from(rows.len()).unwrap_or(0).min(500);
    (w, h)
}

/// Draw a legend of `rows` from the top left of `area` (which [`legend_size`] fits), one
/// row under the other, so no label can cover another or the data.
pub fn legend(area: &Area<'_>, rows: &[LegendRow]) -> Result<(), PlotError> {
    let left = Pos::new(HPos::Left, VPos::Center);
    for (i, row) in rows.iter().enumerate() {
        let y = 12 + LEGEND_ROW_H as i32 * i as i32 + LEGEND_ROW_H as i32 / 2;
        match row {
            LegendRow::Heading(t) => {
                text_at(area, t, (8, y), &bold_style(12.0, INK), left)?;
            }
            LegendRow::Note(t) => text_at(area, t, (8, y), &text_style(11.0, MUTED), left)?,
            LegendRow::ScaleBar { length_m, px_per_m } => {
                let (x0, x1) = (10, 10 + LegendRow::bar_px(*length_m, *px_per_m));
                area.draw(&PathElement::new(
                    vec![(x0, y), (x1, y)],
                    INK.stroke_width(3),
                ))?;
                for x in [x0, x1] {
                    area.draw(&PathElement::new(
                        vec![(x, y - 5), (x, y + 4)],
                        INK.stroke_width(2),
                    ))?;
                }
                let text = if *length_m >= 1.0 {
                    format!("scale {length_m:.0} m")
                } else {
                    format!("scale {:.0} cm", length_m * 100.0)
                };
                text_at(area, &text, (x1 + 8, y), &text_style(12.0, INK), left)?;
            }
            LegendRow::Entry {
                mark,
                colour,
                label,
            } => {
                let c = *colour;
                let (x0, x1) = (10, 36);
                match mark {
                    Mark::Line => {
                        area.draw(&PathElement::new(vec![(x0, y), (x1, y)], c.stroke_width(2)))?;
                    }
                    Mark::Dashed => {
                        for (a, b) in [(x0, x0 + 6), (x0 + 10, x0 + 16), (x0 + 20, x1)] {
                            area.draw(&PathElement::new(vec![(a, y), (b, y)], c.stroke_width(2)))?;
                        }
                    }
                    Mark::Dot => area.draw(&Circle::new((23, y), 4, c.filled()))?,
                    Mark::Ring => area.draw(&Circle::new((23, y), 5, c.stroke_width(2)))?,
                    Mark::Square => {
                        area.draw(&Rectangle::new([(19, y - 4), (27, y + 4)], c.filled()))?;
                    }
                    Mark::Swatch => {
                        area.draw(&Rectangle::new([(x0, y - 6), (x1, y + 6)], c.filled()))?;
                    }
                    Mark::Cross => {
                        area.draw(&PathElement::new(
                            vec![(19, y - 4), (27, y + 4)],
                            c.stroke_width(2),
                        ))?;
                        area.draw(&PathElement::new(
                            vec![(19, y + 4), (27, y - 4)],
                            c.stroke_width(2),
                        ))?;
                    }
                }
                text_at(area, label, (46, y), &text_style(12.0, INK), left)?;
            }
        }
    }
    Ok(())
}

/// A vertical colour bar for values `lo..=hi` from the top left of `area`, `steps` bands
/// coloured by `colour`, with `title` above and the ends and middle labelled.
pub fn colour_bar(
    area: &Area<'_>,
    title: &str,
    (lo, hi): (f64, f64),
    steps: u32,
    colour: impl Fn(f64) -> RGBColor,
) -> Result<(), PlotError> {
    let steps = steps.clamp(2, 100);
    let (x0, x1, top, band) = (12, 34, 34, 14);
    text_at(
        area,
        title,
        (8, 10),
        &text_style(12.0, INK),
        Pos::new(HPos::Left, VPos::Top),
    )?;
    for i in 0..steps {
        // Highest value on top.
        let v = hi - (hi - lo) * (f64::from(i) + 0.5) / f64::from(steps);
        let y = top + band * i as i32;
        area.draw(&Rectangle::new(
            [(x0, y), (x1, y + band)],
            colour(v).filled(),
        ))?;
    }
    let bottom = top + band * steps as i32;
    let right = Pos::new(HPos::Left, VPos::Center);
    for (v, y) in [
        (hi, top),
        ((lo + hi) / 2.0, (top + bottom) / 2),
        (lo, bottom),
    ] {
        area.draw(&PathElement::new(
            vec![(x1, y), (x1 + 4, y)],
            INK.stroke_width(1),
        ))?;
        text_at(
            area,
            &format!("{v:.1}"),
            (x1 + 7, y),
            &text_style(11.0, INK),
            right,
        )?;
    }
    Ok(())
}

/// What [`inspect`] found in a well-formed SVG document.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Inspection {
    /// Elements, the root included.
    pub elements: usize,
    /// The text of every element that holds text, entities decoded, trimmed.
    pub texts: Vec<String>,
    /// How many elements of each of a few names: `polyline`, `circle`, `rect`, `polygon`,
    /// `text`, `line`, `path`.
    pub counts: Vec<(String, usize)>,
}

impl Inspection {
    /// Whether some text equals `s`.
    #[must_use]
    pub fn has_text(&self, s: &str) -> bool {
        self.texts.iter().any(|t| t == s)
    }

    /// Whether some text contains `s`.
    #[must_use]
    pub fn any_text_contains(&self, s: &str) -> bool {
        self.texts.iter().any(|t| t.contains(s))
    }

    /// How many `<name …>` elements there are.
    #[must_use]
    pub fn count(&self, name: &str) -> usize {
        self.counts
            .iter()
            .find(|(n, _)| n == name)
            .map_or(0, |(_, c)| *c)
    }
}

fn decode_entities(s: &str) -> Result<String, String> {
    let mut out = String::new();
    let mut rest = s;
    while let Some(i) = rest.find('&') {
        out.push_str(&rest[..i]);
        let tail = &rest[i + 1..];
        let end = tail
            .find(';')
            .ok_or_else(|| format!("unterminated entity near `{}`", &rest[i..]))?;
        let name = &tail[..end];
        let c = match name {
            "lt" => '<',
            "gt" => '>',
            "amp" => '&',
            "quot" => '"',
            "apos" => '\'',
            _ => {
                let code = if let Some(h) = name.strip_prefix("#x") {
                    u32::from_str_radix(h, 16).ok()
                } else if let Some(d) = name.strip_prefix('#') {
                    d.parse().ok()
                } else {
                    None
                };
                code.and_then(char::from_u32)
                    .ok_or_else(|| format!("unknown entity `&{name};`"))?
            }
        };
        out.push(c);
        rest = &tail[end + 1..];
    }
    out.push_str(rest);
    Ok(out)
}

/// Check that `svg` is one well-formed XML element `<svg …>` (tags nested and closed,
/// attributes quoted and unique, entities known, no stray `<`), with no `NaN` or `inf`
/// anywhere; return its texts and element counts. A structural check for tests, not a full
/// XML parser (no DTDs, CDATA or processing instructions other than an XML declaration).
pub fn inspect(svg: &str) -> Result<Inspection, String> {
    let mut stack: Vec<&str> = Vec::new();
    let mut found = Inspection::default();
    let mut rest = svg.trim_start();
    if let Some(r) = rest.strip_prefix("<?xml") {
        let end = r.find("?>").ok_or("unterminated XML declaration")?;
        rest = r[end + 2..].trim_start();
    }
    let mut text = String::new();
    let mut closed_root = false;
    for bad in ["NaN", "nan\"", "inf\"", "\"inf", "\"-inf"] {
        if svg.contains(bad) {
            return Err(format!("`{bad}` in the document"));
        }
    }
    while !rest.is_empty() {
        let lt = rest.find('<').unwrap_or(rest.len());
        let chunk = &rest[..lt];
        if chunk.contains('>') {
            return Err(format!("stray `>` in text `{chunk}`"));
        }
        if !chunk.trim().is_empty() {
            if stack.is_empty() {
                return Err(format!("text outside the root: `{}`", chunk.trim()));
            }
            text.push_str(&decode_entities(chunk)?);
        }
        rest = &rest[lt..];
        if rest.is_empty() {
            break;
        }
        if closed_root {
            return Err("content after the root element".into());
        }
        if let Some(r) = rest.strip_prefix("<!--") {
            let end = r.find("-->").ok_or("unterminated comment")?;
            rest = &r[end + 3..];
            continue;
        }
        let gt = rest.find('>').ok_or("unterminated tag")?;
        let tag = &rest[1..gt];
        rest = &rest[gt + 1..];
        if tag.contains('<') {
            return Err(format!("`<` inside the tag `{tag}`"));
        }
        if let Some(name) = tag.strip_prefix('/') {
            let name = name.trim();
            match stack.pop() {
                Some(open) if open == name => {}
                Some(open) => return Err(format!("`</{name}>` closes `<{open}>`")),
                None => return Err(format!("`</{name}>` closes nothing")),
            }
            let t = text.trim();
            if !t.is_empty() {
                found.texts.push(t.to_owned());
            }
            text.clear();
            closed_root = stack.is_empty();
            continue;
        }
        let self_closing = tag.ends_with('/');
        let body = tag.trim_end_matches('/');
        let name_end = body.find(|c: char| c.is_whitespace()).unwrap_or(body.len());
        let name = &body[..name_end];
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == ':' || c == '_')
        {
            return Err(format!("bad element name in `<{tag}>`"));
        }
        if stack.is_empty() && name != "svg" {
            return Err(format!("the root is `<{name}>`, not `<svg>`"));
        }
        // Attributes: name="value" pairs.
        let mut attrs = body[name_end..].trim();
        let mut names: Vec<&str> = Vec::new();
        while !attrs.is_empty() {
            let eq = attrs
                .find('=')
                .ok_or_else(|| format!("attribute without value in `<{tag}>`"))?;
            let an = attrs[..eq].trim();
            if an.is_empty() || an.contains(char::is_whitespace) {
                return Err(format!("bad attribute name `{an}` in `<{name}>`"));
            }
            if names.contains(&an) {
                return Err(format!("attribute `{an}` twice in `<{name}>`"));
            }
            names.push(an);
            let v = attrs[eq + 1..].trim_start();
            let q = v.chars().next().filter(|c| *c == '"' || *c == '\'');
            let q = q.ok_or_else(|| format!("unquoted attribute `{an}` in `<{name}>`"))?;
            let close = v[1..]
                .find(q)
                .ok_or_else(|| format!("unterminated attribute `{an}` in `<{name}>`"))?;
            decode_entities(&v[1..=close])?;
            attrs = v[close + 2..].trim_start();
        }
        found.elements += 1;
        if let Some(c) = found.counts.iter_mut().find(|(n, _)| n == name) {
            c.1 += 1;
        } else {
            found.counts.push((name.to_owned(), 1));
        }
        if self_closing {
            closed_root = stack.is_empty();
        } else {
            // Text before a child belongs to the parent: flush it.
            let t = text.trim();
            if !t.is_empty() {
                found.texts.push(t.to_owned());
            }
            text.clear();
            stack.push(name);
        }
    }
    if let Some(open) = stack.last() {
        return Err(format!("`<{open}>` is never closed"));
    }
    if found.elements == 0 {
        return Err("no element".into());
    }
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inspect_accepts_a_document_and_finds_its_texts() {
        let s = "<svg xmlns=\"x\" a='1'><g><text x=\"1\">a &amp; b</text><rect/></g>\n</svg>\n";
        let i = inspect(s).unwrap();
        assert_eq!(i.elements, 4);
        assert!(i.has_text("a & b"));
        assert_eq!(i.count("rect"), 1);
    }

    #[test]
    fn inspect_refuses_broken_documents() {
        for bad in [
            "<svg><g></svg>",
            "<svg></g></svg>",
            "<svg><text>a < b</text></svg>",
            "<svg><text>&bogus;</text></svg>",
            "<svg x=1></svg>",
            "<svg x=\"1\" x=\"2\"></svg>",
            "<svg><circle cx=\"NaN\"/></svg>",
            "<svg></svg><svg></svg>",
            "<g></g>",
            "<svg>",
            "",
        ] {
            assert!(inspect(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn grid_steps_are_round() {
        assert_eq!(grid_step(60.0, 40.0), 1.0);
        assert_eq!(grid_step(100.0, 40.0), 0.5);
        assert_eq!(grid_step(30.0, 40.0), 2.0);
        assert_eq!(grid_step(10.0, 40.0), 5.0);
        assert_eq!(grid_step(3.0, 40.0), 20.0);
        assert_eq!(format_tick(-0.0000001, 1.0), "0");
        assert_eq!(format_tick(2.5, 0.5), "2.5");
    }

    #[test]
    fn frame_grows_and_ignores_non_finite_points() {
        let f = Frame::around([(0.0, 0.0), (f64::NAN, 3.0), (2.0, 0.0)], 0.5).unwrap();
        assert_eq!(f.x, -0.5..2.5);
        assert_eq!(f.y, -1.0..1.0, "at least 1 m high before the margin");
        assert!(Frame::around([(f64::INFINITY, 0.0)], 1.0).is_none());
    }

    /// A world file's wall from −1e308 to 1e308 m made the axis code spin for ever.
    #[test]
    fn a_frame_too_wide_to_draw_is_an_error_not_a_hang() {
        for frame in [
            Frame::around([(-1e308, -1e308), (1e308, 1e308)], 0.5).unwrap(),
            Frame::new(0.0..2e6, 0.0..1.0),
            Frame::new(0.0..1.0, f64::NAN..1.0),
        ] {
            let svg = render(200, 200, |root| {
                metric_chart(root, &frame, "x (m)", "y (m)").map(|_| ())
            });
            let found = inspect(&svg).unwrap();
            assert!(
                found.any_text_contains("cannot draw a frame"),
                "{:?}",
                found.texts
            );
        }
    }

    #[test]
    fn a_chart_with_legend_and_scale_bar_renders_without_nan() {
        let frame = Frame::new(-2.0..3.0, -1.0..2.0);
        let (cw, ch) = metric_chart_size(&frame, 50.0);
        let rows = vec![
            LegendRow::Heading("runs".into()),
            LegendRow::entry(Mark::Line, run_colour(0), "run <1>"),
            LegendRow::entry(Mark::Dashed, run_colour(1), "run 2"),
            LegendRow::Note("a note".into()),
            LegendRow::scale_bar(50.0),
        ];
        let (lw, lh) = legend_size(&rows);
        let svg = render(cw + lw, ch.max(lh) + TITLE_H, |root| {
            let body = titled(root, "a title", None)?;
            let (plot, side) = body.split_horizontally(cw);
            let mut chart = metric_chart(&plot, &frame, "x (m)", "y (m)")?;
            line(
                &mut chart,
                [(0.0, 0.0), (f64::NAN, 1.0), (1.0, 1.0)],
                run_colour(0),
                2,
                false,
            )?;
            line(&mut chart, [(0.0, 1.0), (2.0, 1.5)], run_colour(1), 2, true)?;
            disc(
                &mut chart,
                (1.0, 0.0),
                0.3,
                Some(RED.to_rgba()),
                Some(INK.into()),
            )?;
            mark(&mut chart, (2.0, 0.0), Mark::Cross, INK)?;
            mark(&mut chart, (f64::NAN, 0.0), Mark::Dot, INK)?;
            label(
                &mut chart,
                (2.0, 0.0),
                "here",
                (6, 0),
                &text_style(11.0, INK),
                Pos::new(HPos::Left, VPos::Center),
            )?;
            legend(&side, &rows)?;
            Ok(())
        });
        let i = inspect(&svg).unwrap();
        for t in [
            "a title",
            "x (m)",
            "y (m)",
            "run <1>",
            "run 2",
            "a note",
            "here",
            "scale 1 m",
        ] {
            assert!(i.has_text(t), "{t} missing: {:?}", i.texts);
        }
        assert!(i.count("polyline") >= 3);
        assert!(svg.starts_with("<svg"));
    }

    #[test]
    fn rings_are_clipped_to_the_chart() {
        let frame = Frame::new(-1.0..1.0, -1.0..1.0);
        let polylines = |r: f64| {
            let svg = render(300, 300, |root| {
                let mut chart = metric_chart(root, &frame, "x (m)", "y (m)")?;
                ring(&mut chart, (0.0, 0.0), r, GRID, false)
            });
            inspect(&svg).unwrap().count("polyline")
        };
        let none = polylines(-1.0);
        assert_eq!(polylines(10.0), none, "wholly outside: nothing drawn");
        assert_eq!(polylines(0.5), none + 1, "wholly inside: one closed line");
        // Cut by the four sides: four arcs, none drawn outside.
        assert_eq!(polylines(1.2), none + 4);
    }

    #[test]
    fn a_failed_drawing_gives_a_page_that_says_so() {
        let svg = render(100, 100, |_| Err("no luck <here>".into()));
        let i = inspect(&svg).unwrap();
        assert!(i.any_text_contains("plot failed: no luck <here>"), "{svg}");
    }
}

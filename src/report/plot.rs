//! Charts as SVG text, drawn with plotters' SVG backend (no fonts or files needed: text is left
//! to the browser).
//!
//! A [`Figure`] is a grid of [`Panel`]s; a panel is a list of [`Item`]s (lines, bands, points,
//! bars, intervals) on linear or log axes, or on a categorical x axis. Log axes are drawn in
//! `log10` of the value with tick labels giving the value itself, so every combination of scales
//! shares one code path. A panel without any finite data is refused: a report never shows an
//! empty frame.
//!
//! For a screen and a reader: a figure is at most [`MAX_FIGURE_WIDTH_PX`] wide (wider requests
//! are scaled down) and carries a viewBox, so a page scales it to its width; each axis has its
//! ticks chosen here and labelled in one number format (all plain decimals, or all scientific);
//! the legend is drawn in a strip below the plot, never over the data.

use plotters::prelude::*;

use crate::io::format::significant;

/// Why a figure could not be drawn.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("cannot draw figure `{figure}`: {message}")]
pub struct PlotError {
    pub figure: String,
    pub message: String,
}

/// Scale of an axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AxisScale {
    Linear,
    Log,
}

/// Colours that stay distinct for colour-blind readers (Okabe & Ito).
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(86, 180, 233),
    RGBColor(120, 120, 120),
    RGBColor(0, 0, 0),
];

fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// Something drawn in a panel; `colour` indexes [`PALETTE`]; a `label` puts it in the legend.
#[derive(Debug, Clone, PartialEq)]
pub enum Item {
    Line {
        label: Option<String>,
        points: Vec<(f64, f64)>,
        colour: usize,
        dashed: bool,
    },
    /// The region between two curves sampled at the same x.
    Band {
        label: Option<String>,
        lower: Vec<(f64, f64)>,
        upper: Vec<(f64, f64)>,
        colour: usize,
    },
    Points {
        label: Option<String>,
        points: Vec<(f64, f64)>,
        colour: usize,
    },
    /// Rectangles `(x0, x1, y)` from the bottom of the axis (or zero) up to `y`.
    Bars {
        label: Option<String>,
        bars: Vec<(f64, f64, f64)>,
        colour: usize,
    },
    /// A marker at `value` with a vertical interval: `(x, value, low, high)`.
    Intervals {
        label: Option<String>,
        points: Vec<(f64, f64, f64, f64)>,
        colour: usize,
    },
}

/// One chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Panel {
    pub title: String,
    /// Axis titles, with units (`"horizon [s]"`).
    pub x_label: String,
    pub y_label: String,
    pub x_scale: AxisScale,
    pub y_scale: AxisScale,
    /// Names of the x positions `0..n` (a categorical axis; `x_scale` is then ignored).
    pub categories: Option<Vec<String>>,
    pub items: Vec<Item>,
}

impl Panel {
    pub fn new(title: impl Into<String>, x_label: impl Into<String>, y_label: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            x_label: x_label.into(),
            y_label: y_label.into(),
            x_scale: AxisScale::Linear,
            y_scale: AxisScale::Linear,
            categories: None,
            items: Vec::new(),
        }
    }

    pub fn log_x(mut self) -> Self {
        self.x_scale = AxisScale::Log;
        self
    }

    pub fn log_y(mut self) -> Self {
        self.y_scale = AxisScale::Log;
        self
    }

    pub fn categorical(mut self, names: Vec<String>) -> Self {
        self.categories = Some(names);
        self
    }

    pub fn with(mut self, item: Item) -> Self {
        self.items.push(item);
        self
    }

    /// Data points the panel can draw (finite, and positive on a log axis).
    pub fn data_points(&self) -> usize {
        let t = Transform::of(self);
        let ok = |x: f64, y: f64| t.x(x).is_some() && t.y(y).is_some();
        self.items
            .iter()
            .map(|item| match item {
                Item::Line { points, .. } | Item::Points { points, .. } => {
                    points.iter().filter(|p| ok(p.0, p.1)).count()
                }
                Item::Band { lower, upper, .. } => {
                    lower.iter().zip(upper).filter(|(l, u)| ok(l.0, l.1) && ok(u.0, u.1)).count()
                }
                Item::Bars { bars, .. } => bars.iter().filter(|b| ok(b.0, b.2) && ok(b.1, b.2)).count(),
                Item::Intervals { points, .. } => points.iter().filter(|p| ok(p.0, p.1)).count(),
            })
            .sum()
    }
}

/// A drawn figure.
#[derive(Debug, Clone, PartialEq)]
pub struct Figure {
    /// File stem of the SVG.
    pub name: String,
    pub title: String,
    /// What the figure shows and how to read it (HTML-escaped by the report).
    pub caption: String,
    pub svg: String,
    /// Finite data points drawn, over all panels.
    pub data_points: usize,
    /// Each panel's title, x-axis title, y-axis title and data points drawn.
    pub panels: Vec<PanelInfo>,
}

/// What a drawn panel shows, for checking a figure without parsing its SVG.
#[derive(Debug, Clone, PartialEq)]
pub struct PanelInfo {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub data_points: usize,
}

/// Maps values to drawing coordinates (log10 on a log axis); `None` for what cannot be drawn.
#[derive(Debug, Clone, Copy)]
struct Transform {
    x_log: bool,
    y_log: bool,
}

impl Transform {
    fn of(p: &Panel) -> Self {
        Self { x_log: p.categories.is_none() && p.x_scale == AxisScale::Log, y_log: p.y_scale == AxisScale::Log }
    }
    fn map(v: f64, log: bool) -> Option<f64> {
        if !v.is_finite() {
            return None;
        }
        if log { (v > 0.0).then(|| v.log10()) } else { Some(v) }
    }
    fn x(&self, v: f64) -> Option<f64> {
        Self::map(v, self.x_log)
    }
    fn y(&self, v: f64) -> Option<f64> {
        Self::map(v, self.y_log)
    }
}

/// Range of the values, padded; a single value gets a unit (or one-decade) range.
fn padded(values: impl Iterator<Item = f64>, log: bool, include_zero: bool) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return None;
    }
    if include_zero && !log {
        lo = lo.min(0.0);
        hi = hi.max(0.0);
    }
    if hi - lo < 1e-12 * (1.0 + lo.abs()) {
        let w = if log { 0.5 } else { 0.5 * lo.abs().max(1e-12) };
        return Some((lo - w, hi + w));
    }
    // A log axis spans at least a decade, so that small relative differences do not look large.
    if log && hi - lo < 1.0 {
        let mid = 0.5 * (lo + hi);
        return Some((mid - 0.5, mid + 0.5));
    }
    let pad = 0.05 * (hi - lo);
    Some((if include_zero && !log && lo == 0.0 { 0.0 } else { lo - pad }, hi + pad))
}

/// The widest figure drawn, px: a wider request is scaled down to it.
pub const MAX_FIGURE_WIDTH_PX: u32 = 1200;

/// At most this many ticks on an axis.
const MAX_TICKS: usize = 7;

/// Tick positions of an axis, in drawn coordinates (log10 of the value on a log axis), within
/// `range`: multiples of 1, 2 or 5 times a power of ten; on a log axis whole decades (every k-th
/// when there are many), or 1, 2 and 5 of each decade when the axis spans few.
pub fn axis_ticks(range: (f64, f64), log: bool) -> Vec<f64> {
    let (lo, hi) = (range.0.min(range.1), range.0.max(range.1));
    if !(lo.is_finite() && hi.is_finite()) || hi <= lo {
        return vec![lo];
    }
    if log {
        let (first, last) = (lo.ceil() as i64, hi.floor() as i64);
        let decades = (last - first + 1).max(0) as usize;
        if decades >= 3 {
            let stride = decades.div_ceil(MAX_TICKS) as i64;
            return (first..=last).filter(|e| e.rem_euclid(stride) == 0).map(|e| e as f64).collect();
        }
        for mantissas in [&[1.0f64, 2.0, 5.0][..], &[1.0f64, 3.0][..], &[1.0f64][..]] {
            let ticks: Vec<f64> = (lo.floor() as i64..=hi.ceil() as i64)
                .flat_map(|e| mantissas.iter().map(move |m: &f64| m.log10() + e as f64))
                .filter(|t| *t >= lo - 1e-9 && *t <= hi + 1e-9)
                .collect();
            if ticks.len() <= MAX_TICKS {
                return ticks;
            }
        }
        return vec![lo, hi];
    }
    let raw = (hi - lo) / (MAX_TICKS - 1) as f64;
    let magnitude = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * magnitude).find(|s| *s >= raw).unwrap_or(10.0 * magnitude);
    let first = (lo / step).ceil() as i64;
    let last = (hi / step).floor() as i64;
    (first..=last).map(|k| if k == 0 { 0.0 } else { k as f64 * step }).collect()
}

/// Labels of an axis's ticks in one number format: plain decimals (with the decimals the step
/// needs) when every value lies within 1e-3 and 1e5 in magnitude, else scientific (with the
/// mantissa digits the step needs); zero is "0".
pub fn tick_labels(ticks: &[f64], log: bool) -> Vec<String> {
    let values: Vec<f64> = if log { ticks.iter().map(|t| 10f64.powf(*t)).collect() } else { ticks.to_vec() };
    let nonzero: Vec<f64> = values.iter().map(|v| v.abs()).filter(|v| *v > 0.0).collect();
    if nonzero.is_empty() {
        return values.iter().map(|_| "0".to_string()).collect();
    }
    let largest = nonzero.iter().copied().fold(0.0, f64::max);
    let smallest = nonzero.iter().copied().fold(f64::INFINITY, f64::min);
    // The smallest difference the labels must show: the step, or on a log axis each value's own
    // leading digit (1, 2, 5 times a power of ten).
    let step = if log || values.len() < 2 {
        smallest
    } else {
        values.windows(2).map(|w| (w[1] - w[0]).abs()).fold(f64::INFINITY, f64::min)
    };
    let plain = largest < 1e5 && smallest >= 1e-3;
    let step_exponent = step.log10().floor();
    values
        .iter()
        .map(|&v| {
            if v == 0.0 {
                return "0".to_string();
            }
            if plain {
                let decimals = if log { (-v.log10().floor()).max(0.0) } else { (-step_exponent).max(0.0) } as usize;
                format!("{v:.decimals$}")
            } else {
                let own = if log { v.abs().log10().floor() } else { largest.log10().floor() };
                let digits = if log { 0 } else { (own - step_exponent).max(0.0) as usize };
                format!("{v:.digits$e}")
            }
        })
        .collect()
}

/// A linear coordinate (in drawn units) whose ticks are the given ones.
struct Ticked {
    range: std::ops::Range<f64>,
    ticks: Vec<f64>,
}

impl plotters::coord::ranged1d::Ranged for Ticked {
    type FormatOption = plotters::coord::ranged1d::DefaultFormatting;
    type ValueType = f64;

    /// As plotters maps its own f64 ranges.
    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let (lo, hi) = (self.range.start, self.range.end);
        if hi == lo {
            return (limit.1 - limit.0) / 2;
        }
        let share = (value - lo) / (hi - lo);
        let length = limit.1 - limit.0;
        if length >= 0 {
            limit.0 + (length as f64 * share + 1e-3).floor() as i32
        } else {
            limit.0 + (length as f64 * share - 1e-3).ceil() as i32
        }
    }

    fn key_points<Hint: plotters::coord::ranged1d::KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        if hint.weight().allow_light_points() { Vec::new() } else { self.ticks.clone() }
    }

    fn range(&self) -> std::ops::Range<f64> {
        self.range.clone()
    }
}

/// The label of a drawn coordinate: its tick's, or (off the ticks) the value itself.
fn label_at(v: f64, ticks: &[f64], labels: &[String], log: bool) -> String {
    let tolerance = 1e-9 * (1.0 + v.abs());
    match ticks.iter().position(|t| (t - v).abs() <= tolerance) {
        Some(i) => labels[i].clone(),
        None => significant(if log { 10f64.powf(v) } else { v }, 3),
    }
}

fn draw_error(figure: &str, e: impl std::fmt::Display) -> PlotError {
    PlotError { figure: figure.to_string(), message: e.to_string() }
}

/// Draws `panels` in a grid of `columns`, each panel `panel_px` pixels.
pub fn render(
    name: &str,
    title: &str,
    caption: &str,
    panels: &[Panel],
    columns: usize,
    panel_px: (u32, u32),
) -> Result<Figure, PlotError> {
    if panels.is_empty() {
        return Err(draw_error(name, "no panels"));
    }
    for p in panels {
        if p.data_points() == 0 {
            return Err(draw_error(name, format!("panel `{}` has no finite data", p.title)));
        }
    }
    let columns = columns.clamp(1, panels.len());
    let rows = panels.len().div_ceil(columns);
    // Scaled down to the widest figure a page shows; the height less, so that short panels keep
    // room for their plot.
    let panel_px = if panel_px.0 * columns as u32 > MAX_FIGURE_WIDTH_PX {
        let w = MAX_FIGURE_WIDTH_PX / columns as u32;
        let scale = w as f64 / panel_px.0 as f64;
        (w, ((panel_px.1 as f64 * scale) as u32).max(panel_px.1 * 3 / 4))
    } else {
        panel_px
    };
    let size = (panel_px.0 * columns as u32, panel_px.1 * rows as u32);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_error(name, e))?;
        let areas = root.split_evenly((rows, columns));
        // One legend strip's height for every panel, so that the plots of a row line up.
        let strip = panels.iter().map(|p| legend_strip_px(p, panel_px.0 as i32)).max().unwrap_or(0);
        for (panel, area) in panels.iter().zip(areas.iter()) {
            draw_panel(panel, area, strip).map_err(|e| draw_error(name, format!("panel `{}`: {e}", panel.title)))?;
        }
        root.present().map_err(|e| draw_error(name, e))?;
    }
    Ok(Figure {
        name: name.to_string(),
        title: title.to_string(),
        caption: caption.to_string(),
        svg,
        data_points: panels.iter().map(Panel::data_points).sum(),
        panels: panels
            .iter()
            .map(|p| PanelInfo {
                title: p.title.clone(),
                x_label: p.x_label.clone(),
                y_label: p.y_label.clone(),
                data_points: p.data_points(),
            })
            .collect(),
    })
}

type Area<'a> = DrawingArea<SVGBackend<'a>, plotters::coord::Shift>;

/// How an item shows in the legend.
#[derive(Debug, Clone, Copy)]
enum Glyph {
    Line { dashed: bool },
    Patch { opacity: f64 },
    Dot,
}

/// The legend's entries of a panel: (label, glyph, colour).
fn legend_entries(p: &Panel) -> Vec<(String, Glyph, RGBColor)> {
    p.items
        .iter()
        .filter_map(|item| match item {
            Item::Line { label, colour: c, dashed, .. } => {
                label.as_ref().map(|l| (l.clone(), Glyph::Line { dashed: *dashed }, colour(*c)))
            }
            Item::Band { label, colour: c, .. } => {
                label.as_ref().map(|l| (l.clone(), Glyph::Patch { opacity: 0.2 }, colour(*c)))
            }
            Item::Bars { label, colour: c, .. } => {
                label.as_ref().map(|l| (l.clone(), Glyph::Patch { opacity: 0.75 }, colour(*c)))
            }
            Item::Points { label, colour: c, .. } | Item::Intervals { label, colour: c, .. } => {
                label.as_ref().map(|l| (l.clone(), Glyph::Dot, colour(*c)))
            }
        })
        .collect()
}

const LEGEND_FONT_PX: f64 = 11.0;
const LEGEND_ROW_PX: i32 = 15;

/// Where each legend entry goes in a strip `width` wide, flowing left to right and wrapping:
/// `(x, row)` per entry, and the number of rows.
fn legend_layout(labels: &[String], width: i32) -> (Vec<(i32, i32)>, i32) {
    let (mut x, mut row) = (8, 0);
    let mut at = Vec::new();
    for l in labels {
        // A glyph, a gap and the text at about 0.6 em a character.
        let w = 24 + (0.6 * LEGEND_FONT_PX * l.chars().count() as f64).ceil() as i32 + 14;
        if x > 8 && x + w > width - 4 {
            x = 8;
            row += 1;
        }
        at.push((x, row));
        x += w;
    }
    (at, if labels.is_empty() { 0 } else { row + 1 })
}

/// The height of the legend strip a panel `width` wide needs (0 without a legend).
fn legend_strip_px(p: &Panel, width: i32) -> i32 {
    let labels: Vec<String> = legend_entries(p).into_iter().map(|e| e.0).collect();
    let (_, rows) = legend_layout(&labels, width);
    if rows > 0 { rows * LEGEND_ROW_PX + 6 } else { 0 }
}

fn draw_legend(area: &Area<'_>, entries: &[(String, Glyph, RGBColor)]) -> Result<(), Box<dyn std::error::Error>> {
    let labels: Vec<String> = entries.iter().map(|e| e.0.clone()).collect();
    let (at, _) = legend_layout(&labels, area.dim_in_pixel().0 as i32);
    let font = ("sans-serif", LEGEND_FONT_PX).into_font().color(&BLACK);
    for ((label, glyph, col), (x, row)) in entries.iter().zip(at) {
        let y = 4 + row * LEGEND_ROW_PX + LEGEND_ROW_PX / 2;
        match glyph {
            Glyph::Line { dashed: false } => {
                area.draw(&PathElement::new(vec![(x, y), (x + 18, y)], col.stroke_width(2)))?;
            }
            Glyph::Line { dashed: true } => {
                area.draw(&PathElement::new(vec![(x, y), (x + 6, y)], col.stroke_width(2)))?;
                area.draw(&PathElement::new(vec![(x + 11, y), (x + 18, y)], col.stroke_width(2)))?;
            }
            Glyph::Patch { opacity } => {
                area.draw(&Rectangle::new([(x, y - 5), (x + 18, y + 5)], col.mix(*opacity).filled()))?;
            }
            Glyph::Dot => {
                area.draw(&Circle::new((x + 9, y), 3, col.filled()))?;
            }
        }
        area.draw(&Text::new(label.clone(), (x + 24, y - 6), font.clone()))?;
    }
    Ok(())
}

fn draw_panel(p: &Panel, area: &Area<'_>, strip: i32) -> Result<(), Box<dyn std::error::Error>> {
    let t = Transform::of(p);
    // Ranges over everything drawable.
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    let mut has_bars = false;
    for item in &p.items {
        let mut push = |x: f64, y: f64| {
            if let (Some(x), Some(y)) = (t.x(x), t.y(y)) {
                xs.push(x);
                ys.push(y);
            }
        };
        match item {
            Item::Line { points, .. } | Item::Points { points, .. } => points.iter().for_each(|q| push(q.0, q.1)),
            Item::Band { lower, upper, .. } => lower.iter().chain(upper).for_each(|q| push(q.0, q.1)),
            Item::Bars { bars, .. } => {
                has_bars = true;
                bars.iter().for_each(|b| {
                    push(b.0, b.2);
                    push(b.1, b.2);
                })
            }
            Item::Intervals { points, .. } => points.iter().for_each(|q| {
                push(q.0, q.1);
                push(q.0, q.2);
                push(q.0, q.3);
            }),
        }
    }
    let (x0, x1) = match &p.categories {
        Some(names) => (-0.5, names.len().max(1) as f64 - 0.5),
        None => padded(xs.iter().copied(), t.x_log, false).ok_or("no x values")?,
    };
    let (y0, y1) = padded(ys.iter().copied(), t.y_log, has_bars).ok_or("no y values")?;
    // The legend goes in a strip below the plot: it never covers data.
    let entries = legend_entries(p);
    let (width, height) = area.dim_in_pixel();
    let (plot_area, legend_area) = area.split_vertically(height as i32 - strip);
    if !entries.is_empty() {
        draw_legend(&legend_area, &entries)?;
    }
    // Label areas and fonts shrink with small panels, so that the plot keeps most of the room.
    let small = width < 300;
    let n_categories = p.categories.as_ref().map(|c| c.len()).unwrap_or(0);
    let x_ticks: Vec<f64> = match &p.categories {
        Some(names) => (0..names.len()).map(|i| i as f64).collect(),
        None => axis_ticks((x0, x1), t.x_log),
    };
    let x_labels: Vec<String> = match &p.categories {
        Some(names) => names.clone(),
        None => tick_labels(&x_ticks, t.x_log),
    };
    let y_ticks = axis_ticks((y0, y1), t.y_log);
    let y_labels = tick_labels(&y_ticks, t.y_log);
    let mut chart = ChartBuilder::on(&plot_area)
        .caption(&p.title, ("sans-serif", if small { 12 } else { 15 }))
        .margin(if small { 4 } else { 8 })
        .x_label_area_size(if small { 34 } else { 42 })
        .y_label_area_size(if small { 50 } else { 62 })
        .build_cartesian_2d(
            Ticked { range: x0..x1, ticks: x_ticks.clone() },
            Ticked { range: y0..y1, ticks: y_ticks.clone() },
        )?;
    let x_fmt = |v: &f64| match &p.categories {
        Some(_) => {
            let i = v.round();
            if (v - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < x_labels.len() {
                x_labels[i as usize].clone()
            } else {
                String::new()
            }
        }
        None => label_at(*v, &x_ticks, &x_labels, t.x_log),
    };
    let y_fmt = |v: &f64| label_at(*v, &y_ticks, &y_labels, t.y_log);
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .axis_desc_style(("sans-serif", if small { 11 } else { 13 }))
        .light_line_style(WHITE.mix(0.0));
    mesh.y_labels(MAX_TICKS).label_style(("sans-serif", 10));
    if n_categories > 0 {
        mesh.x_labels(n_categories).disable_x_mesh();
    } else {
        mesh.x_labels(MAX_TICKS);
    }
    mesh.draw()?;
    let xy = |q: &(f64, f64)| Some((t.x(q.0)?, t.y(q.1)?));
    for item in &p.items {
        match item {
            Item::Line { points, colour: c, dashed, .. } => {
                let pts: Vec<(f64, f64)> = points.iter().filter_map(xy).collect();
                let style = colour(*c).stroke_width(2);
                if *dashed {
                    chart.draw_series(DashedLineSeries::new(pts, 6, 4, style))?;
                } else {
                    chart.draw_series(LineSeries::new(pts, style))?;
                }
            }
            Item::Band { lower, upper, colour: c, .. } => {
                let mut poly: Vec<(f64, f64)> = Vec::new();
                let pairs: Vec<((f64, f64), (f64, f64))> =
                    lower.iter().zip(upper).filter_map(|(l, u)| Some((xy(l)?, xy(u)?))).collect();
                poly.extend(pairs.iter().map(|p| p.1));
                poly.extend(pairs.iter().rev().map(|p| p.0));
                let col = colour(*c);
                chart.draw_series(std::iter::once(Polygon::new(poly, col.mix(0.2).filled())))?;
            }
            Item::Points { points, colour: c, .. } => {
                let col = colour(*c);
                chart.draw_series(points.iter().filter_map(xy).map(|q| Circle::new(q, 2, col.mix(0.6).filled())))?;
            }
            Item::Bars { bars, colour: c, .. } => {
                let col = colour(*c);
                let base = if t.y_log { y0 } else { 0.0f64.clamp(y0, y1) };
                chart.draw_series(bars.iter().filter_map(|b| {
                    let (xa, xb, y) = (t.x(b.0)?, t.x(b.1)?, t.y(b.2)?);
                    if y == base {
                        return None;
                    }
                    Some(Rectangle::new([(xa, base), (xb, y)], col.mix(0.75).filled()))
                }))?;
            }
            Item::Intervals { points, colour: c, .. } => {
                let col = colour(*c);
                for q in points {
                    if let (Some(x), Some(lo), Some(hi)) = (t.x(q.0), t.y(q.2), t.y(q.3)) {
                        chart.draw_series(std::iter::once(PathElement::new(
                            vec![(x, lo), (x, hi)],
                            col.stroke_width(2),
                        )))?;
                    }
                }
                chart.draw_series(
                    points.iter().filter_map(|q| xy(&(q.0, q.1))).map(|q| Circle::new(q, 3, col.filled())),
                )?;
            }
        }
    }
    Ok(())
}

/// Escapes text for HTML.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_axes_titles_and_data() {
        let panel = Panel::new("drift", "horizon [s]", "velocity error [m/s]")
            .log_x()
            .log_y()
            .with(Item::Line {
                label: Some("median".into()),
                points: vec![(1.0, 1e-3), (10.0, 1e-1)],
                colour: 0,
                dashed: false,
            })
            .with(Item::Points { label: None, points: vec![(2.0, -1.0)], colour: 1 });
        // The negative point cannot be drawn on a log axis.
        assert_eq!(panel.data_points(), 2);
        let f = render("t", "T", "", &[panel], 1, (400, 300)).unwrap();
        assert!(f.svg.contains("horizon [s]") && f.svg.contains("velocity error [m/s]"));
        assert!(f.svg.contains("<polyline"));
        assert_eq!(f.data_points, 2);
    }

    #[test]
    fn refuses_an_empty_panel() {
        let panel = Panel::new("empty", "x [1]", "y [1]").log_y().with(Item::Points {
            label: None,
            points: vec![(1.0, 0.0), (2.0, f64::NAN)],
            colour: 0,
        });
        let e = render("fig", "", "", &[panel], 1, (300, 200)).unwrap_err();
        assert!(e.message.contains("`empty` has no finite data"), "{e}");
    }
}

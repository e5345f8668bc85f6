//! Charts as SVG text, drawn with plotters' SVG backend (no fonts or files needed: text is left
//! to the browser).
//!
//! A [`Figure`] is a grid of [`Panel`]s; a panel is a list of [`Item`]s (lines, bands, points,
//! bars, intervals) on linear or log axes, or on a categorical x axis. Log axes are drawn in
//! `log10` of the value with tick labels giving the value itself, so every combination of scales
//! shares one code path. A panel without any finite data is refused: a report never shows an
//! empty frame.

use plotters::prelude::*;

use crate::io::csv::significant;

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

/// Tick label of a drawn coordinate on an axis spanning `range`: enough significant digits to
/// tell neighbouring ticks apart.
fn tick(v: f64, log: bool, range: (f64, f64)) -> String {
    if log {
        return significant(10f64.powf(v), 3);
    }
    let span = (range.1 - range.0).abs();
    if v.abs() < 1e-9 * span {
        return "0".into();
    }
    let extent = range.0.abs().max(range.1.abs());
    let digits = (2.0 + (extent / span).log10().ceil()).clamp(2.0, 12.0) as usize;
    significant(v, digits)
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
    let size = (panel_px.0 * columns as u32, panel_px.1 * rows as u32);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_error(name, e))?;
        let areas = root.split_evenly((rows, columns));
        for (panel, area) in panels.iter().zip(areas.iter()) {
            draw_panel(panel, area).map_err(|e| draw_error(name, format!("panel `{}`: {e}", panel.title)))?;
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

fn draw_panel(p: &Panel, area: &Area<'_>) -> Result<(), Box<dyn std::error::Error>> {
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
    let (y0, mut y1) = padded(ys.iter().copied(), t.y_log, has_bars).ok_or("no y values")?;
    // Headroom for the legend (upper left), so that it does not hide data.
    let entries = p
        .items
        .iter()
        .filter(|i| match i {
            Item::Line { label, .. }
            | Item::Band { label, .. }
            | Item::Points { label, .. }
            | Item::Bars { label, .. }
            | Item::Intervals { label, .. } => label.is_some(),
        })
        .count();
    if entries > 0 {
        y1 += (y1 - y0) * (0.1 * entries as f64 + 0.05).min(1.0);
    }
    let n_categories = p.categories.as_ref().map(|c| c.len()).unwrap_or(0);
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, ("sans-serif", 15))
        .margin(8)
        .x_label_area_size(42)
        .y_label_area_size(62)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    let x_fmt = |v: &f64| match &p.categories {
        Some(names) => {
            let i = v.round();
            if (v - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < names.len() {
                names[i as usize].clone()
            } else {
                String::new()
            }
        }
        None => tick(*v, t.x_log, (x0, x1)),
    };
    let y_fmt = |v: &f64| tick(*v, t.y_log, (y0, y1));
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .axis_desc_style(("sans-serif", 13))
        .light_line_style(WHITE.mix(0.0));
    mesh.y_labels(6).label_style(("sans-serif", 10));
    if n_categories > 0 {
        mesh.x_labels(n_categories).disable_x_mesh();
    } else {
        mesh.x_labels(6);
    }
    mesh.draw()?;
    let mut legend = false;
    let xy = |q: &(f64, f64)| Some((t.x(q.0)?, t.y(q.1)?));
    for item in &p.items {
        match item {
            Item::Line { label, points, colour: c, dashed } => {
                let pts: Vec<(f64, f64)> = points.iter().filter_map(xy).collect();
                let style = colour(*c).stroke_width(2);
                let series = if *dashed {
                    chart.draw_series(DashedLineSeries::new(pts, 6, 4, style))?
                } else {
                    chart.draw_series(LineSeries::new(pts, style))?
                };
                if let Some(l) = label {
                    legend = true;
                    let col = colour(*c);
                    series
                        .label(l)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2)));
                }
            }
            Item::Band { label, lower, upper, colour: c } => {
                let mut poly: Vec<(f64, f64)> = Vec::new();
                let pairs: Vec<((f64, f64), (f64, f64))> =
                    lower.iter().zip(upper).filter_map(|(l, u)| Some((xy(l)?, xy(u)?))).collect();
                poly.extend(pairs.iter().map(|p| p.1));
                poly.extend(pairs.iter().rev().map(|p| p.0));
                let col = colour(*c);
                let series = chart.draw_series(std::iter::once(Polygon::new(poly, col.mix(0.2).filled())))?;
                if let Some(l) = label {
                    legend = true;
                    series
                        .label(l)
                        .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 16, y + 4)], col.mix(0.2).filled()));
                }
            }
            Item::Points { label, points, colour: c } => {
                let col = colour(*c);
                let series = chart
                    .draw_series(points.iter().filter_map(xy).map(|q| Circle::new(q, 2, col.mix(0.6).filled())))?;
                if let Some(l) = label {
                    legend = true;
                    series.label(l).legend(move |(x, y)| Circle::new((x + 8, y), 3, col.filled()));
                }
            }
            Item::Bars { label, bars, colour: c } => {
                let col = colour(*c);
                let base = if t.y_log { y0 } else { 0.0f64.clamp(y0, y1) };
                let series = chart.draw_series(bars.iter().filter_map(|b| {
                    let (xa, xb, y) = (t.x(b.0)?, t.x(b.1)?, t.y(b.2)?);
                    if y == base {
                        return None;
                    }
                    Some(Rectangle::new([(xa, base), (xb, y)], col.mix(0.75).filled()))
                }))?;
                if let Some(l) = label {
                    legend = true;
                    series
                        .label(l)
                        .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 16, y + 4)], col.mix(0.75).filled()));
                }
            }
            Item::Intervals { label, points, colour: c } => {
                let col = colour(*c);
                for q in points {
                    if let (Some(x), Some(lo), Some(hi)) = (t.x(q.0), t.y(q.2), t.y(q.3)) {
                        chart.draw_series(std::iter::once(PathElement::new(
                            vec![(x, lo), (x, hi)],
                            col.stroke_width(2),
                        )))?;
                    }
                }
                let series = chart.draw_series(
                    points.iter().filter_map(|q| xy(&(q.0, q.1))).map(|q| Circle::new(q, 3, col.filled())),
                )?;
                if let Some(l) = label {
                    legend = true;
                    series.label(l).legend(move |(x, y)| Circle::new((x + 8, y), 3, col.filled()));
                }
            }
        }
    }
    if legend {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font(("sans-serif", 11))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .draw()?;
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

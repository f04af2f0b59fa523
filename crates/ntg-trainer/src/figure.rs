//! Figures as SVG and PNG (plotters), with text drawn from an embedded font
//! so no system font library is needed.

use std::path::Path;
use std::sync::OnceLock;

use anyhow::{Context, anyhow};
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::FontStyle;
use serde::{Deserialize, Serialize};

/// DejaVu Sans (Bitstream Vera license, see `assets/DejaVuSans-LICENSE.txt`).
const FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

fn register_font() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            plotters::style::register_font("sans-serif", FontStyle::Normal, FONT)
                .map_err(|_| "the embedded font could not be loaded".to_owned())
        })
        .clone()
        .map_err(|e| anyhow!(e))
}

/// One point of a series: a value with its interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Point {
    /// Position on the x axis.
    pub x: f64,
    /// Value.
    pub y: f64,
    /// Lower end of the error bar.
    pub lo: f64,
    /// Upper end of the error bar.
    pub hi: f64,
}

impl Point {
    /// A success rate at `x`, with its 95% interval as the error bar.
    pub fn success(x: f64, rate: &crate::stats::SuccessRate) -> Self {
        Point {
            x,
            y: rate.rate,
            lo: rate.ci_low,
            hi: rate.ci_high,
        }
    }

    /// A value at `x` without an error bar.
    pub fn exact(x: f64, y: f64) -> Self {
        Point { x, y, lo: y, hi: y }
    }
}

/// One line of a panel (a method).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// Points, in x order.
    pub points: Vec<Point>,
    /// How it is drawn; absent: a colour of its own by its name's place
    /// among the figure's series, round markers, a solid line.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub look: Option<Look>,
}

/// A point marker.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Marker {
    /// A filled circle.
    Circle,
    /// A filled triangle.
    Triangle,
    /// A filled square.
    Square,
    /// A filled diamond.
    Diamond,
    /// A cross.
    Cross,
}

/// A line's dash pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Dash {
    /// Unbroken.
    Solid,
    /// Dashes of 8 pixels.
    Dashed,
    /// Dots.
    Dotted,
    /// Dashes of 16 pixels.
    LongDashed,
    /// Dashes of 10 pixels with gaps as long.
    SparseDashed,
    /// Dots far apart.
    SparseDotted,
}

impl Dash {
    /// The dash patterns in the order variants of a method get them.
    pub const ALL: [Dash; 6] = [
        Dash::Solid,
        Dash::Dashed,
        Dash::Dotted,
        Dash::LongDashed,
        Dash::SparseDashed,
        Dash::SparseDotted,
    ];
}

/// How a series is drawn: a method's colour and marker ([`method_look`]),
/// and the dash that tells its variants (recipe, input) apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Look {
    /// Index into the palette.
    pub colour: usize,
    /// Point marker.
    pub marker: Marker,
    /// Line pattern.
    pub dash: Dash,
}

/// The methods of this project's figures, each with its colour and marker
/// in every figure (index: colour).
const METHOD_LOOKS: [(&str, Marker); 5] = [
    ("NTG (ours)", Marker::Circle),
    ("NTP", Marker::Triangle),
    ("NTP Flat", Marker::Square),
    ("NTP (Detector)", Marker::Diamond),
    ("Flat Policy", Marker::Cross),
];

/// The look of method `method` (its legend name, e.g. `NTP Flat`) drawn
/// with `dash`: the same colour and marker in every figure. A method not
/// in the table gets a colour after theirs.
pub fn method_look(method: &str, dash: Dash) -> Look {
    match METHOD_LOOKS.iter().position(|(name, _)| *name == method) {
        Some(i) => Look {
            colour: i,
            marker: METHOD_LOOKS[i].1,
            dash,
        },
        None => Look {
            colour: METHOD_LOOKS.len() + method.len() % (PALETTE.len() - METHOD_LOOKS.len()),
            marker: Marker::Circle,
            dash,
        },
    }
}

/// Each series' look in `panel`: its own, or the default one
/// ([`Series::look`]) with its colour by its name's place in `names`.
fn panel_looks(panel: &Panel, names: &[&str]) -> Vec<Look> {
    panel
        .series
        .iter()
        .map(|series| {
            series.look.unwrap_or_else(|| Look {
                colour: names
                    .iter()
                    .position(|n| *n == series.name)
                    .unwrap_or_default(),
                marker: Marker::Circle,
                dash: Dash::Solid,
            })
        })
        .collect()
}

/// The first pair of series of one panel drawn alike (the same colour,
/// marker and dash), as `(panel title, one name, the other)`; `None` when
/// every panel's series can be told apart.
pub fn same_looks(panels: &[Panel]) -> Option<(String, String, String)> {
    let names = series_names(panels);
    for panel in panels {
        let looks = panel_looks(panel, &names);
        for (i, a) in looks.iter().enumerate() {
            if let Some(j) = looks[i + 1..].iter().position(|b| b == a) {
                return Some((
                    panel.title.clone(),
                    panel.series[i].name.clone(),
                    panel.series[i + 1 + j].name.clone(),
                ));
            }
        }
    }
    None
}

/// One chart: lines with error bars over a (possibly logarithmic) x axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Panel {
    /// Title above the chart.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// Logarithmic x axis.
    pub x_log: bool,
    /// Ticks on a linear x axis only at the measured x values (e.g. a
    /// count such as the number of objects, which has no fractional
    /// values); a log axis always has them. Absent in panels saved before
    /// it: false.
    #[serde(default)]
    pub x_ticks_at_points: bool,
    /// y range.
    pub y_range: (f64, f64),
    /// The lines.
    pub series: Vec<Series>,
}

/// Series colours: the first five are the methods' ([`METHOD_LOOKS`]),
/// the rest go to series without a method's look.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn x_bounds(panel: &Panel) -> (f64, f64) {
    let xs = panel
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.x));
    let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
        (lo.min(x), hi.max(x))
    });
    if !lo.is_finite() {
        return (1.0, 10.0);
    }
    if panel.x_log {
        (lo / 1.3, hi * 1.3)
    } else {
        let pad = ((hi - lo) * 0.08).max(0.5);
        (lo - pad, hi + pad)
    }
}

/// How many x labels to ask plotters for: at most one per measured value
/// on a count axis ([`Panel::x_ticks_at_points`]), which puts a linear
/// axis's labels on whole steps over evenly spaced counts (plotters'
/// default of 10 over 1..5 gives halves); 10 otherwise.
fn x_label_count(panel: &Panel) -> usize {
    if panel.x_ticks_at_points && !panel.x_log {
        let mut xs: Vec<f64> = panel
            .series
            .iter()
            .flat_map(|s| s.points.iter().map(|p| p.x))
            .collect();
        xs.sort_by(f64::total_cmp);
        xs.dedup();
        xs.len().max(2)
    } else {
        10
    }
}

/// The label of x tick `x` (none for a fraction on a count axis).
fn x_label(panel: &Panel, x: f64) -> String {
    if panel.x_ticks_at_points && x.fract() != 0.0 {
        String::new()
    } else {
        format!("{x}")
    }
}

/// Every series name of `panels`, in order of first appearance: a name's
/// index is its colour in every panel and its place in the legend.
fn series_names(panels: &[Panel]) -> Vec<&str> {
    let mut names: Vec<&str> = Vec::new();
    for series in panels.iter().flat_map(|p| &p.series) {
        if !names.contains(&series.name.as_str()) {
            names.push(&series.name);
        }
    }
    names
}

/// Pixels per legend row (a series' first line).
const LEGEND_ROW: u32 = 18;

/// Pixels per further line of a series name wrapped in the legend.
const LEGEND_LINE: u32 = 14;

/// Characters per legend line: longer series names wrap at word
/// boundaries, so that a figure with long names (every addition a run
/// uses) keeps its panels large instead of widening its legends.
const LEGEND_LINE_CHARS: usize = 46;

/// Length in pixels of a legend's line sample, and where its text starts.
const LEGEND_SAMPLE: i32 = 56;
const LEGEND_TEXT_LEFT: i32 = LEGEND_SAMPLE + 8;

/// Size in pixels of one panel's chart (its legend goes to its right).
const CHART_WIDTH: u32 = 460;
const PANEL_HEIGHT: u32 = 360;

/// Panels per row of a figure; more go on further rows.
const PANELS_PER_ROW: usize = 2;

/// `name` in lines of at most [`LEGEND_LINE_CHARS`] characters, broken
/// after spaces (a word longer than a line gets a line of its own).
fn legend_lines(name: &str) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    let mut line = String::new();
    for word in name.split_inclusive(' ') {
        let fits = line.chars().count() + word.trim_end().chars().count() <= LEGEND_LINE_CHARS;
        if !line.is_empty() && !fits {
            lines.push(line.trim_end().to_string());
            line.clear();
        }
        line.push_str(word);
    }
    if !line.is_empty() || lines.is_empty() {
        lines.push(line.trim_end().to_string());
    }
    lines
}

/// Height in pixels of `panel`'s legend below its 40-pixel top margin.
fn legend_height(panel: &Panel) -> u32 {
    drawn(panel)
        .map(|(_, s)| LEGEND_ROW + (legend_lines(&s.name).len() as u32 - 1) * LEGEND_LINE)
        .sum()
}

/// Width in pixels of the legend beside each panel: room for the longest
/// line of the figure's series names (about 7 pixels per character at the
/// legend's 12-point font, after a 56-pixel line sample).
fn legend_width(panels: &[Panel]) -> u32 {
    let longest = panels
        .iter()
        .flat_map(|p| &p.series)
        .filter(|s| !s.points.is_empty())
        .flat_map(|s| legend_lines(&s.name))
        .map(|line| line.chars().count())
        .max();
    match longest {
        Some(chars) => (chars as u32 * 7 + LEGEND_TEXT_LEFT as u32 + 8).max(120),
        None => 0,
    }
}

/// The figure's size in pixels: panels in rows of [`PANELS_PER_ROW`], each
/// with its legend at its right; a panel's legend longer than the panel
/// makes its row taller.
fn figure_size(panels: &[Panel]) -> (u32, u32) {
    let columns = panels.len().clamp(1, PANELS_PER_ROW) as u32;
    let width = columns * (CHART_WIDTH + legend_width(panels));
    (
        width,
        row_heights(panels).iter().sum::<u32>().max(PANEL_HEIGHT),
    )
}

/// Each row's height: the panel's, or its longest legend's.
fn row_heights(panels: &[Panel]) -> Vec<u32> {
    panels
        .chunks(PANELS_PER_ROW)
        .map(|row| {
            let legend = row.iter().map(legend_height).max().unwrap_or(0);
            PANEL_HEIGHT.max(40 + legend + 8)
        })
        .collect()
}

/// The series of `panel` that have points, with their index in it.
fn drawn(panel: &Panel) -> impl Iterator<Item = (usize, &Series)> {
    panel
        .series
        .iter()
        .enumerate()
        .filter(|(_, s)| !s.points.is_empty())
}

/// The outline of `marker`, in pixels around its point (about 8 across;
/// a circle as an octagon, a cross as its outline), so that every marker
/// is one polygon element.
fn marker_outline(marker: Marker) -> Vec<(i32, i32)> {
    match marker {
        Marker::Circle => vec![
            (-2, -4),
            (2, -4),
            (4, -2),
            (4, 2),
            (2, 4),
            (-2, 4),
            (-4, 2),
            (-4, -2),
        ],
        Marker::Triangle => vec![(0, -5), (5, 4), (-5, 4)],
        Marker::Square => vec![(-4, -4), (4, -4), (4, 4), (-4, 4)],
        Marker::Diamond => vec![(0, -5), (5, 0), (0, 5), (-5, 0)],
        Marker::Cross => vec![
            (-4, -5),
            (0, -1),
            (4, -5),
            (5, -4),
            (1, 0),
            (5, 4),
            (4, 5),
            (0, 1),
            (-4, 5),
            (-5, 4),
            (-1, 0),
            (-5, -4),
        ],
    }
}

/// A marker of `look`'s shape and colour at `at` (a macro: plotters does
/// not name the type of a composed element).
macro_rules! marker {
    ($at:expr, $look:expr) => {
        EmptyElement::at($at)
            + Polygon::new(
                marker_outline($look.marker),
                PALETTE[$look.colour % PALETTE.len()].filled(),
            )
    };
}

/// The dash and gap lengths in pixels of a dashed `dash`; `None` for a
/// solid line.
fn dash_pattern(dash: Dash) -> Option<(i32, i32)> {
    match dash {
        Dash::Solid => None,
        Dash::Dashed => Some((8, 5)),
        Dash::Dotted => Some((2, 4)),
        Dash::LongDashed => Some((18, 5)),
        Dash::SparseDashed => Some((10, 10)),
        Dash::SparseDotted => Some((2, 10)),
    }
}

/// `panel`'s legend, one row per series with points: a sample of its line
/// and marker, then its name.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    looks: &[Look],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let style = TextStyle::from(("sans-serif", 12).into_font()).color(&BLACK);
    let mut top = 40;
    for (i, series) in drawn(panel) {
        let lines = legend_lines(&series.name);
        let (x, y) = (6, top + LEGEND_ROW as i32 / 2);
        top += (LEGEND_ROW + (lines.len() as u32 - 1) * LEGEND_LINE) as i32;
        let look = looks[i];
        let stroke = PALETTE[look.colour % PALETTE.len()].stroke_width(2);
        // The marker sits near the sample's start, so that the rest shows
        // at least two periods of the longest dash pattern.
        let sample = vec![(x, y), (x + LEGEND_SAMPLE, y)];
        match dash_pattern(look.dash) {
            None => area.draw(&PathElement::new(sample, stroke)),
            Some((dash, gap)) => area.draw(&DashedPathElement::new(sample, dash, gap, stroke)),
        }
        .and_then(|_| area.draw(&marker!((x + 8, y), look)))
        .and_then(|_| {
            lines.iter().enumerate().try_for_each(|(k, line)| {
                area.draw(&Text::new(
                    line.clone(),
                    (x + LEGEND_TEXT_LEFT, y - 7 + k as i32 * LEGEND_LINE as i32),
                    style.clone(),
                ))
            })
        })
        .map_err(|e| anyhow!("drawing the legend: {e}"))?;
    }
    Ok(())
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    looks: &[Look],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let (x0, x1) = x_bounds(panel);
    let x_labels = x_label_count(panel);
    let (y0, y1) = panel.y_range;
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(&panel.title, ("sans-serif", 17))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(48);
    macro_rules! body {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(panel.x_label.as_str())
                .y_desc(panel.y_label.as_str())
                .label_style(("sans-serif", 13))
                .x_labels(x_labels)
                .x_label_formatter(&|x| x_label(panel, *x))
                .light_line_style(WHITE)
                .draw()
                .map_err(|e| anyhow!("drawing the axes: {e}"))?;
            for (i, series) in drawn(panel) {
                let look = looks[i];
                let colour = PALETTE[look.colour % PALETTE.len()];
                // Left to right, whatever order the points came in (a
                // curve can gather points of several panels of a file).
                let mut points = series.points.clone();
                points.sort_by(|a, b| a.x.total_cmp(&b.x));
                let ys = |p: &Point| (p.x, p.y);
                let fail = |e| anyhow!("drawing {}: {e}", series.name);
                // The interval: a band along the line, or a bar where a
                // single point has no neighbour to span to.
                if points.len() > 1 && points.iter().any(|p| p.hi > p.lo) {
                    let band: Vec<(f64, f64)> = points
                        .iter()
                        .map(|p| (p.x, p.hi))
                        .chain(points.iter().rev().map(|p| (p.x, p.lo)))
                        .collect();
                    chart
                        .draw_series(std::iter::once(Polygon::new(
                            band,
                            colour.mix(0.15).filled(),
                        )))
                        .map_err(fail)?;
                } else if points.len() == 1 {
                    chart
                        .draw_series(points.iter().filter(|p| p.hi > p.lo).map(|p| {
                            ErrorBar::new_vertical(p.x, p.lo, p.y, p.hi, colour.stroke_width(1), 6)
                        }))
                        .map_err(fail)?;
                }
                // A lone point gets a short stretch of its line through it,
                // so that its dash still tells it from its method's other
                // variants.
                let stroke = colour.stroke_width(2);
                if let [lone] = points.as_slice() {
                    let stretch = vec![(-16, 0), (16, 0)];
                    let at = EmptyElement::at(ys(lone));
                    match dash_pattern(look.dash) {
                        None => chart
                            .draw_series(std::iter::once(at + PathElement::new(stretch, stroke))),
                        Some((dash, gap)) => chart.draw_series(std::iter::once(
                            at + DashedPathElement::new(stretch, dash, gap, stroke),
                        )),
                    }
                    .map_err(fail)?;
                } else {
                    let path: Vec<(f64, f64)> = points.iter().map(ys).collect();
                    match dash_pattern(look.dash) {
                        None => chart.draw_series(std::iter::once(PathElement::new(path, stroke))),
                        Some((dash, gap)) => chart.draw_series(std::iter::once(
                            DashedPathElement::new(path, dash, gap, stroke),
                        )),
                    }
                    .map_err(fail)?;
                }
                chart
                    .draw_series(points.iter().map(|p| marker!(ys(p), look)))
                    .map_err(fail)?;
            }
        }};
    }
    // Ticks exactly at the measured x values: a log axis's own ticks
    // crowd into unreadable labels over a short range.
    let mut ticks: Vec<f64> = panel
        .series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| p.x))
        .collect();
    ticks.sort_by(f64::total_cmp);
    ticks.dedup();
    if panel.x_log {
        body!(
            builder
                .build_cartesian_2d((x0..x1).log_scale().with_key_points(ticks), y0..y1)
                .map_err(|e| anyhow!("building the chart: {e}"))?
        );
    } else {
        body!(
            builder
                .build_cartesian_2d(x0..x1, y0..y1)
                .map_err(|e| anyhow!("building the chart: {e}"))?
        );
    }
    Ok(())
}

fn draw_all<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    panels: &[Panel],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let names = series_names(panels);
    let legend = legend_width(panels);
    let mut top = 0;
    for (row, height) in panels.chunks(PANELS_PER_ROW).zip(row_heights(panels)) {
        for (column, panel) in row.iter().enumerate() {
            let left = column as u32 * (CHART_WIDTH + legend);
            let area = root
                .clone()
                .shrink((left, top), (CHART_WIDTH + legend, height));
            let (chart, beside) = area.split_horizontally(CHART_WIDTH);
            let looks = panel_looks(panel, &names);
            draw_panel(
                &chart.shrink((0, 0), (CHART_WIDTH, PANEL_HEIGHT)),
                panel,
                &looks,
            )?;
            draw_legend(&beside, panel, &looks)?;
        }
        top += height;
    }
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// Writes `panels` as `<stem>.svg` and `<stem>.png`, in rows of
/// two, each with its legend at its right. Series of one
/// panel drawn alike ([`same_looks`]) are an error: the reader could not
/// tell them apart.
pub fn write_figure(panels: &[Panel], stem: &Path) -> anyhow::Result<()> {
    if let Some((panel, a, b)) = same_looks(panels) {
        anyhow::bail!(
            "{}: \"{a}\" and \"{b}\" of panel \"{panel}\" would be drawn alike (colour, marker and dash)",
            stem.display()
        );
    }
    register_font()?;
    let size = figure_size(panels);
    let svg = stem.with_extension("svg");
    let png = stem.with_extension("png");
    if let Some(dir) = stem.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    draw_all(SVGBackend::new(&svg, size).into_drawing_area(), panels)
        .with_context(|| format!("writing {}", svg.display()))?;
    write_png(&png, size, |area| draw_all(area, panels))
}

// --- Bar charts (fig. jigsaws) ---

/// One bar: a value with an error bar.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Bar {
    /// Category label under the bar.
    pub label: String,
    /// Height.
    pub value: f64,
    /// Lower end of the error bar.
    pub lo: f64,
    /// Upper end of the error bar.
    pub hi: f64,
}

/// A bar chart of categories, one colour per bar.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BarChart {
    /// Title above the chart.
    pub title: String,
    /// y-axis label.
    pub y_label: String,
    /// The bars, left to right.
    pub bars: Vec<Bar>,
}

/// The label of tick `x` on a category axis (categories at 0, 1, ...):
/// the category's at a whole number, none between.
fn category_label(labels: &[String], x: f64) -> String {
    let i = x.round();
    if (x - i).abs() < 1e-6 && i >= 0.0 {
        labels.get(i as usize).cloned().unwrap_or_default()
    } else {
        String::new()
    }
}

fn draw_bars<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    chart: &BarChart,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let top = chart
        .bars
        .iter()
        .map(|b| b.hi.max(b.value))
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let y1 = if top > 0.0 { top * 1.15 } else { 1.0 };
    let n = chart.bars.len().max(1);
    let mut c = ChartBuilder::on(&root)
        .caption(&chart.title, ("sans-serif", 18))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(52)
        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0.0..y1)
        .map_err(|e| anyhow!("building the chart: {e}"))?;
    let labels: Vec<String> = chart.bars.iter().map(|b| b.label.clone()).collect();
    c.configure_mesh()
        .disable_x_mesh()
        .x_labels(n)
        .x_label_formatter(&|x| category_label(&labels[..], *x))
        .y_desc(chart.y_label.as_str())
        .label_style(("sans-serif", 13))
        .light_line_style(WHITE)
        .draw()
        .map_err(|e| anyhow!("drawing the axes: {e}"))?;
    for (i, bar) in chart.bars.iter().enumerate() {
        let colour = PALETTE[i % PALETTE.len()];
        let x = i as f64;
        c.draw_series(std::iter::once(Rectangle::new(
            [(x - 0.3, 0.0), (x + 0.3, bar.value)],
            colour.mix(0.8).filled(),
        )))
        .map_err(|e| anyhow!("drawing {}: {e}", bar.label))?;
        c.draw_series(std::iter::once(ErrorBar::new_vertical(
            x,
            bar.lo,
            bar.value,
            bar.hi,
            BLACK.stroke_width(1),
            10,
        )))
        .map_err(|e| anyhow!("drawing {}: {e}", bar.label))?;
        c.draw_series(std::iter::once(Text::new(
            format!("{:.3}", bar.value),
            (x - 0.12, bar.hi.max(bar.value) + y1 * 0.07),
            ("sans-serif", 13),
        )))
        .map_err(|e| anyhow!("drawing {}: {e}", bar.label))?;
    }
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// Writes a bar chart as `<stem>.svg` and `<stem>.png`.
pub fn write_bar_chart(chart: &BarChart, stem: &Path) -> anyhow::Result<()> {
    register_font()?;
    let size = (560, 380);
    let svg = stem.with_extension("svg");
    let png = stem.with_extension("png");
    if let Some(dir) = stem.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    draw_bars(SVGBackend::new(&svg, size).into_drawing_area(), chart)
        .with_context(|| format!("writing {}", svg.display()))?;
    write_png(&png, size, |area| draw_bars(area, chart))
}

/// Draws into an RGB buffer with plotters' bitmap backend and writes it to
/// `path` as a PNG with `image` (plotters' own encoder would pull in a
/// second, older `image` and `png` crate).
fn write_png(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(DrawingArea<BitMapBackend<'_>, Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    draw(BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area())
        .with_context(|| format!("drawing {}", path.display()))?;
    let picture = image::RgbImage::from_raw(width, height, pixels)
        .expect("the buffer holds width x height RGB pixels");
    picture
        .save(path)
        .with_context(|| format!("writing {}", path.display()))
}

/// Bars of several series over shared categories (e.g. success and goals
/// met per model variant), drawn side by side within each category.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupedBars {
    /// Title above the chart.
    pub title: String,
    /// y-axis label.
    pub y_label: String,
    /// Category labels, left to right.
    pub categories: Vec<String>,
    /// Each series' name and its bar per category (`bars[i]` for
    /// `categories[i]`; a bar whose `lo` equals its `hi` has no error bar).
    pub series: Vec<(String, Vec<Bar>)>,
}

/// Least width in pixels of one grouped-bar chart's plot (its legend to
/// its right).
const GROUPED_WIDTH: u32 = 280;

/// Widest a row of grouped-bar charts gets before the next chart starts a
/// row of its own.
const GROUPED_ROW_WIDTH: u32 = 1800;

/// Width in pixels of `chart`'s plot: room for each category's label
/// (12-px text, about 7 px a character, plus a gap) and for its bars (about
/// 40 px each) and for its title, at least [`GROUPED_WIDTH`], so that a chart of few bars
/// stays narrow and one of many long labels does not run them together.
fn grouped_plot_width(chart: &GroupedBars) -> u32 {
    let longest = chart
        .categories
        .iter()
        .map(|l| l.chars().count())
        .max()
        .unwrap_or(0) as u32;
    let per_category = (longest * 7 + 12).max(40 * chart.series.len() as u32 + 24);
    // The y-axis label area (48 px) and the plot's margins; the title (17-px
    // text, about 9 px a character) fits above.
    let title = chart.title.chars().count() as u32 * 9 + 24;
    (64 + chart.categories.len() as u32 * per_category)
        .max(title)
        .max(GROUPED_WIDTH)
}

/// Width in pixels of `chart`'s legend: its longest series name.
fn grouped_legend_width(chart: &GroupedBars) -> u32 {
    let longest = chart
        .series
        .iter()
        .map(|(name, _)| name.chars().count())
        .max()
        .unwrap_or(0) as u32;
    (longest * 7 + 44).clamp(100, 300)
}

/// Where each chart goes (left, top), and the figure's size: charts side
/// by side, a new row where the next would make one wider than
/// [`GROUPED_ROW_WIDTH`].
fn grouped_layout(charts: &[GroupedBars]) -> (Vec<(u32, u32)>, (u32, u32)) {
    let (mut left, mut top, mut width) = (0, 0, 0);
    let mut places = Vec::new();
    for chart in charts {
        let w = grouped_plot_width(chart) + grouped_legend_width(chart);
        if left > 0 && left + w > GROUPED_ROW_WIDTH {
            left = 0;
            top += PANEL_HEIGHT;
        }
        places.push((left, top));
        left += w;
        width = width.max(left);
    }
    (places, (width.max(GROUPED_WIDTH), top + PANEL_HEIGHT))
}

fn draw_grouped<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    chart: &GroupedBars,
    plot_width: u32,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let (plot, beside) = area.split_horizontally(plot_width);
    let n = chart.categories.len().max(1);
    let mut c = ChartBuilder::on(&plot)
        .caption(&chart.title, ("sans-serif", 17))
        .margin(12)
        .x_label_area_size(56)
        .y_label_area_size(48)
        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0.0..1.05)
        .map_err(|e| anyhow!("building the chart: {e}"))?;
    let labels = &chart.categories;
    c.configure_mesh()
        .disable_x_mesh()
        .x_labels(n)
        .x_label_formatter(&|x| category_label(&labels[..], *x))
        .y_desc(chart.y_label.as_str())
        .label_style(("sans-serif", 12))
        .light_line_style(WHITE)
        .draw()
        .map_err(|e| anyhow!("drawing the axes: {e}"))?;
    let k = chart.series.len().max(1) as f64;
    let width = 0.8 / k;
    for (j, (name, bars)) in chart.series.iter().enumerate() {
        let colour = PALETTE[j % PALETTE.len()];
        let fail = |e| anyhow!("drawing {name}: {e}");
        for (i, bar) in bars.iter().enumerate() {
            let left = i as f64 - 0.4 + j as f64 * width;
            let mid = left + width / 2.0;
            c.draw_series(std::iter::once(Rectangle::new(
                [(left + 0.02, 0.0), (left + width - 0.02, bar.value)],
                colour.mix(0.85).filled(),
            )))
            .map_err(fail)?;
            if bar.hi > bar.lo {
                c.draw_series(std::iter::once(ErrorBar::new_vertical(
                    mid,
                    bar.lo,
                    bar.value,
                    bar.hi,
                    BLACK.stroke_width(1),
                    6,
                )))
                .map_err(fail)?;
            }
            // Three decimals, as the tables give them: two would round a
            // 0.899 up to the "0.90" of a threshold it is below.
            c.draw_series(std::iter::once(Text::new(
                format!("{:.3}", bar.value),
                (mid - width * 0.35, bar.hi.max(bar.value) + 0.045),
                ("sans-serif", 9),
            )))
            .map_err(fail)?;
        }
    }
    let style = TextStyle::from(("sans-serif", 12).into_font()).color(&BLACK);
    for (j, (name, _)) in chart.series.iter().enumerate() {
        let y = 40 + j as i32 * LEGEND_ROW as i32;
        beside
            .draw(&Rectangle::new(
                [(6, y), (26, y + 12)],
                PALETTE[j % PALETTE.len()].mix(0.85).filled(),
            ))
            .and_then(|_| beside.draw(&Text::new(name.clone(), (32, y), style.clone())))
            .map_err(|e| anyhow!("drawing the legend: {e}"))?;
    }
    Ok(())
}

/// Writes grouped-bar `charts` side by side (in rows of at most 1800 px),
/// each with its legend at its right, as `<stem>.svg` and `<stem>.png`.
pub fn write_grouped_bars(charts: &[GroupedBars], stem: &Path) -> anyhow::Result<()> {
    register_font()?;
    let (_, size) = grouped_layout(charts);
    let svg = stem.with_extension("svg");
    let png = stem.with_extension("png");
    if let Some(dir) = stem.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    draw_grouped_all(SVGBackend::new(&svg, size).into_drawing_area(), charts)
        .with_context(|| format!("writing {}", svg.display()))?;
    write_png(&png, size, |area| draw_grouped_all(area, charts))
}

fn draw_grouped_all<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    charts: &[GroupedBars],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let (places, _) = grouped_layout(charts);
    for (&(left, top), chart) in places.iter().zip(charts) {
        let plot = grouped_plot_width(chart);
        let area = root.clone().shrink(
            (left, top),
            (plot + grouped_legend_width(chart), PANEL_HEIGHT),
        );
        draw_grouped(&area, chart, plot)?;
    }
    root.present().map_err(|e| anyhow!("{e}"))
}

// --- end of bar charts ---

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grouped_bars_widen_for_many_long_category_labels() {
        let chart = |labels: &[&str]| GroupedBars {
            title: String::new(),
            y_label: String::new(),
            categories: labels.iter().map(|l| l.to_string()).collect(),
            series: Vec::new(),
        };
        assert_eq!(grouped_plot_width(&chart(&["NTG", "NTP"])), GROUPED_WIDTH);
        let many = chart(&["NTG rec. (nodetach)"; 8]);
        let width = grouped_plot_width(&many);
        assert!(width >= 8 * 19 * 7, "{width}");
        // A chart of one category stays narrow beside a wide one; a third
        // wide one starts a second row.
        let (places, size) = grouped_layout(&[many.clone(), chart(&["NTG"])]);
        assert_eq!(places, vec![(0, 0), (width + 100, 0)]);
        assert_eq!(size, (width + 100 + GROUPED_WIDTH + 100, PANEL_HEIGHT));
        let (places, size) = grouped_layout(&[many.clone(), many.clone()]);
        assert_eq!(places, vec![(0, 0), (0, PANEL_HEIGHT)]);
        assert_eq!(size, (width + 100, 2 * PANEL_HEIGHT));
    }

    #[test]
    fn grouped_bar_labels_do_not_round_up_to_a_threshold() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("grouped");
        let bar = |value: f64| Bar {
            label: String::new(),
            value,
            lo: value - 0.05,
            hi: value + 0.05,
        };
        let chart = GroupedBars {
            title: "structure".into(),
            y_label: "success".into(),
            categories: vec!["new".into(), "taller".into()],
            series: vec![("NTG".into(), vec![bar(0.98), bar(0.899)])],
        };
        write_grouped_bars(&[chart], &stem).unwrap();
        let svg = std::fs::read_to_string(stem.with_extension("svg")).unwrap();
        assert!(svg.contains("0.899") && svg.contains("0.980"), "{svg}");
        assert!(!svg.contains(">0.90<"), "{svg}");
    }

    #[test]
    fn a_count_axis_has_ticks_only_at_the_counts() {
        let dir = tempfile::tempdir().unwrap();
        let points = |y: f64| {
            (1..=5)
                .map(|n| Point {
                    x: n as f64,
                    y,
                    lo: y - 0.1,
                    hi: y + 0.1,
                })
                .collect()
        };
        let mut panel = Panel {
            title: "counts".into(),
            x_label: "N".into(),
            y_label: "success".into(),
            x_log: false,
            x_ticks_at_points: true,
            y_range: (0.0, 1.0),
            series: vec![Series {
                name: "a".into(),
                points: points(0.5),
                look: None,
            }],
        };
        // plotters' ticks over the panel's x range, with the label count
        // the panel asks for, are the counts 1..5 and nothing between.
        use plotters::coord::ranged1d::Ranged;
        let ticks = |panel: &Panel| {
            let (x0, x1) = x_bounds(panel);
            let coord: plotters::coord::types::RangedCoordf64 = (x0..x1).into();
            coord.key_points(x_label_count(panel))
        };
        let at_counts = ticks(&panel);
        assert_eq!(at_counts, vec![1.0, 2.0, 3.0, 4.0, 5.0]);
        assert!(
            at_counts
                .iter()
                .all(|&x| x_label(&panel, x) == format!("{x}"))
        );
        assert_eq!(x_label(&panel, 2.5), "");
        write_figure(&[panel.clone()], &dir.path().join("counts")).unwrap();
        // Other axes label fractions.
        panel.x_ticks_at_points = false;
        assert_eq!(x_label(&panel, 2.5), "2.5");
        assert_eq!(x_label_count(&panel), 10);
    }

    #[test]
    fn writes_svg_and_png() {
        let dir = tempfile::tempdir().unwrap();
        let panel = Panel {
            title: "(a) state".into(),
            x_label: "training tasks".into(),
            y_label: "success rate".into(),
            x_log: true,
            x_ticks_at_points: false,
            y_range: (0.0, 1.0),
            series: vec![Series {
                name: "NTG".into(),
                points: [50.0, 100.0, 500.0, 1000.0]
                    .iter()
                    .enumerate()
                    .map(|(i, &x)| Point {
                        x,
                        y: 0.2 * i as f64,
                        lo: 0.1 * i as f64,
                        hi: 0.25 * i as f64,
                    })
                    .collect(),
                look: None,
            }],
        };
        let stem = dir.path().join("fig");
        write_figure(&[panel.clone(), panel], &stem).unwrap();
        let svg = std::fs::read_to_string(stem.with_extension("svg")).unwrap();
        assert!(svg.contains("NTG") && svg.contains("training tasks"));
        let png = image::open(stem.with_extension("png")).unwrap();
        // Two panels in a row, each with its legend (its narrowest) at its
        // right.
        assert_eq!((png.width(), png.height()), (2 * (460 + 120), 360));
    }

    #[test]
    fn long_series_names_wrap_at_spaces_and_keep_the_legend_narrow() {
        let name = "NTG (ours), recommended recipe, learning rate 0.001, \
                    execution memory, localizer reads the previous frame";
        let lines = legend_lines(name);
        assert!(lines.len() > 1, "{lines:?}");
        assert!(lines.iter().all(|l| l.chars().count() <= LEGEND_LINE_CHARS));
        // Nothing is lost or reordered: the lines rejoin to the name.
        assert_eq!(lines.join(" "), name);
        assert_eq!(legend_lines("NTG"), vec!["NTG".to_string()]);
        // A word longer than a line keeps a line of its own.
        let long = "x".repeat(LEGEND_LINE_CHARS + 5);
        assert_eq!(
            legend_lines(&format!("a {long} b")),
            vec!["a", long.as_str(), "b"]
        );
        let panel = Panel {
            title: "p".into(),
            x_label: String::new(),
            y_label: String::new(),
            x_log: false,
            x_ticks_at_points: false,
            y_range: (0.0, 1.0),
            series: vec![Series {
                name: name.into(),
                points: vec![Point::exact(1.0, 0.5)],
                look: None,
            }],
        };
        assert!(
            legend_width(std::slice::from_ref(&panel))
                <= LEGEND_LINE_CHARS as u32 * 7 + LEGEND_TEXT_LEFT as u32 + 8
        );
        assert_eq!(
            legend_height(&panel),
            LEGEND_ROW + (lines.len() as u32 - 1) * LEGEND_LINE
        );
    }

    #[test]
    fn series_of_one_panel_drawn_alike_are_found_and_refused() {
        let series = |name: &str, look: Option<Look>| Series {
            name: name.into(),
            points: (0..3).map(|i| Point::exact(i as f64, 0.5)).collect(),
            look,
        };
        let panel = |title: &str, series: Vec<Series>| Panel {
            title: title.into(),
            x_label: String::new(),
            y_label: String::new(),
            x_log: false,
            x_ticks_at_points: false,
            y_range: (0.0, 1.0),
            series,
        };
        // A method keeps its colour and marker in every figure; dashes
        // tell its variants apart.
        let ntp = method_look("NTP", Dash::Solid);
        assert_eq!(
            ntp,
            Look {
                colour: 1,
                marker: Marker::Triangle,
                dash: Dash::Solid
            }
        );
        assert_ne!(method_look("NTP Flat", Dash::Solid), ntp);
        let recommended = method_look("NTP", Dash::Dashed);
        let distinct = [
            panel(
                "a",
                vec![
                    series("NTP", Some(ntp)),
                    series("NTP, recommended", Some(recommended)),
                ],
            ),
            // The same look in another panel is no clash; default looks
            // differ by name.
            panel(
                "b",
                vec![
                    series("NTP", Some(ntp)),
                    series("x", None),
                    series("y", None),
                ],
            ),
        ];
        assert_eq!(same_looks(&distinct), None);
        let dir = tempfile::tempdir().unwrap();
        write_figure(&distinct, &dir.path().join("fine")).unwrap();
        let clash = [panel(
            "c",
            vec![series("NTP", Some(ntp)), series("NTP, GRU core", Some(ntp))],
        )];
        assert_eq!(
            same_looks(&clash),
            Some(("c".into(), "NTP".into(), "NTP, GRU core".into()))
        );
        let err = write_figure(&clash, &dir.path().join("clash")).unwrap_err();
        assert!(format!("{err}").contains("drawn alike"), "{err}");
        assert!(!dir.path().join("clash.png").exists());
    }

    #[test]
    fn writes_a_bar_chart() {
        let dir = tempfile::tempdir().unwrap();
        let stem = dir.path().join("bars");
        let bar = |label: &str, value: f64| Bar {
            label: label.into(),
            value,
            lo: value - 0.1,
            hi: value + 0.1,
        };
        let chart = BarChart {
            title: "NLL".into(),
            y_label: "nats".into(),
            bars: vec![bar("uniform", 2.77), bar("full", 1.2)],
        };
        write_bar_chart(&chart, &stem).unwrap();
        let svg = std::fs::read_to_string(stem.with_extension("svg")).unwrap();
        assert!(svg.contains("uniform") && svg.contains("2.770"), "{svg}");
        let png = image::open(stem.with_extension("png")).unwrap();
        assert_eq!((png.width(), png.height()), (560, 380));
    }
}

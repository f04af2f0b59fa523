//! Figures as SVG and PNG (plotters), with text drawn from an embedded font
//! so no system font library is needed.

use std::path::Path;
use std::sync::OnceLock;

use anyhow::{Context, anyhow};
use plotters::coord::Shift;
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

/// Series colours, in order (the first six as before; ten, so that the
/// five curves of success and goals met in one panel stay distinct).
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

/// The legend's entries, `(colour index, name)`: the series names with
/// points in some panel (a profile completed run by run lists none it has
/// not drawn), each with its index in [`series_names`].
fn legend_entries(panels: &[Panel]) -> Vec<(usize, &str)> {
    series_names(panels)
        .into_iter()
        .enumerate()
        .filter(|&(_, name)| {
            panels
                .iter()
                .flat_map(|p| &p.series)
                .any(|s| s.name == name && !s.points.is_empty())
        })
        .collect()
}

/// Height in pixels of the legend strip under the panels: one row of
/// [`LEGEND_ROW`] pixels per `columns` names.
fn legend_height(names: usize, columns: usize) -> u32 {
    (names.div_ceil(columns.max(1)) as u32) * LEGEND_ROW + 8
}

/// Pixels per legend row.
const LEGEND_ROW: u32 = 18;

fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(usize, &str)],
    columns: usize,
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let (width, _) = area.dim_in_pixel();
    let column_width = (width / columns.max(1) as u32) as i32;
    let style = TextStyle::from(("sans-serif", 13).into_font()).color(&BLACK);
    for (i, &(colour, name)) in entries.iter().enumerate() {
        let colour = PALETTE[colour % PALETTE.len()];
        let (x, y) = (
            12 + (i % columns) as i32 * column_width,
            4 + (i / columns) as i32 * LEGEND_ROW as i32 + LEGEND_ROW as i32 / 2,
        );
        area.draw(&PathElement::new(
            vec![(x, y), (x + 18, y)],
            colour.stroke_width(2),
        ))
        .map_err(|e| anyhow!("drawing the legend: {e}"))?;
        area.draw(&Circle::new((x + 9, y), 3, colour.filled()))
            .map_err(|e| anyhow!("drawing the legend: {e}"))?;
        area.draw(&Text::new(name.to_string(), (x + 26, y - 7), style.clone()))
            .map_err(|e| anyhow!("drawing the legend: {e}"))?;
    }
    Ok(())
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    names: &[&str],
) -> anyhow::Result<()>
where
    DB::ErrorType: 'static,
{
    let (x0, x1) = x_bounds(panel);
    let x_labels = x_label_count(panel);
    let (y0, y1) = panel.y_range;
    let mut builder = ChartBuilder::on(area);
    builder
        .caption(&panel.title, ("sans-serif", 18))
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
            for series in &panel.series {
                let i = names
                    .iter()
                    .position(|n| *n == series.name)
                    .unwrap_or_default();
                let colour = PALETTE[i % PALETTE.len()];
                let style = ShapeStyle::from(&colour).stroke_width(2);
                // Left to right, whatever order the points came in (a
                // curve can gather points of several panels of a file).
                let mut line: Vec<(f64, f64)> = series.points.iter().map(|p| (p.x, p.y)).collect();
                line.sort_by(|a, b| a.0.total_cmp(&b.0));
                chart
                    .draw_series(LineSeries::new(line, style))
                    .map_err(|e| anyhow!("drawing {}: {e}", series.name))?;
                chart
                    .draw_series(series.points.iter().map(|p| {
                        ErrorBar::new_vertical(p.x, p.lo, p.y, p.hi, colour.stroke_width(1), 6)
                    }))
                    .map_err(|e| anyhow!("drawing {}: {e}", series.name))?;
                chart
                    .draw_series(
                        series
                            .points
                            .iter()
                            .map(|p| Circle::new((p.x, p.y), 3, colour.filled())),
                    )
                    .map_err(|e| anyhow!("drawing {}: {e}", series.name))?;
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
    // The legend under the panels, not over their lines: one entry per
    // series name, the same colour in every panel.
    let names = series_names(panels);
    let columns = legend_columns(panels);
    let (charts, legend) = root.split_vertically(PANEL_HEIGHT);
    let areas = charts.split_evenly((1, panels.len().max(1)));
    for (area, panel) in areas.iter().zip(panels) {
        draw_panel(area, panel, &names)?;
    }
    draw_legend(&legend, &legend_entries(panels), columns)?;
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

/// Height in pixels of the panels (the legend strip goes below).
const PANEL_HEIGHT: u32 = 360;

/// Legend columns: one per panel's width (460 pixels fits the longest
/// names).
fn legend_columns(panels: &[Panel]) -> usize {
    panels.len().max(1)
}

/// Writes `panels` side by side as `<stem>.svg` and `<stem>.png`.
pub fn write_figure(panels: &[Panel], stem: &Path) -> anyhow::Result<()> {
    register_font()?;
    let size = (
        460 * panels.len().max(1) as u32,
        PANEL_HEIGHT + legend_height(legend_entries(panels).len(), legend_columns(panels)),
    );
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
        .x_label_formatter(&|x| {
            let i = x.round();
            if (x - i).abs() < 1e-6 && i >= 0.0 {
                labels.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
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

// --- end of bar charts ---

#[cfg(test)]
mod tests {
    use super::*;

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
            }],
        };
        let stem = dir.path().join("fig");
        write_figure(&[panel.clone(), panel], &stem).unwrap();
        let svg = std::fs::read_to_string(stem.with_extension("svg")).unwrap();
        assert!(svg.contains("NTG") && svg.contains("training tasks"));
        let png = image::open(stem.with_extension("png")).unwrap();
        // The panels, then one legend row for the one series.
        assert_eq!((png.width(), png.height()), (920, 360 + 18 + 8));
    }

    #[test]
    fn the_legend_lists_drawn_series_once_with_one_colour_each() {
        let series = |name: &str, points: usize| Series {
            name: name.into(),
            points: (0..points).map(|i| Point::exact(i as f64, 0.5)).collect(),
        };
        let panel = |series: Vec<Series>| Panel {
            title: String::new(),
            x_label: String::new(),
            y_label: String::new(),
            x_log: false,
            x_ticks_at_points: false,
            y_range: (0.0, 1.0),
            series,
        };
        let panels = [
            panel(vec![series("a", 2), series("b", 0)]),
            panel(vec![series("c", 1), series("a", 1)]),
        ];
        assert_eq!(series_names(&panels), ["a", "b", "c"]);
        // "b" has no point: not in the legend, and "c" keeps its colour.
        assert_eq!(legend_entries(&panels), [(0, "a"), (2, "c")]);
        assert_eq!(legend_height(3, 2), 2 * LEGEND_ROW + 8);
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

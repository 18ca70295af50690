//! Small plotting helpers for every report in palpate: line/scatter plots with several series,
//! histograms, bar charts and a signed value on a projected surface ([`surface_map`]), written
//! atomically. A figure is asked for by its `.svg` path and written in the process'
//! [`PlotFormat`] (default both: the SVG and its PNG sibling; `palpate --plot-format
//! png|svg|both` sets it); a `.png` path writes the PNG only. Every function returns
//! the files it wrote, and [`shown`] names the one a document should link to.
//!
//! Layout rules every figure follows: the title is measured and set smaller, or on two lines, until
//! it fits the canvas; the legend goes into the corner of the plot with the fewest data under it,
//! and when every corner has data the y axis gets headroom so that it covers none; colours are
//! the Tableau 10 palette (no yellow on white).
//!
//! plotters needs a font to lay out any text; the project ships DejaVu Sans
//! (`fitter/assets/DejaVuSans.ttf`) and registers it as `sans-serif` on first use, so plots do not
//! depend on the fonts of the machine.
//!
//! ```no_run
//! use palpate_plot::{lines, Series, Style};
//! let pts = [(0.0, 1.0), (1.0, 0.5), (2.0, 0.2)];
//! lines("error.svg", "Marker error", "iteration", "rms error (m)", &[Series::new("fit", &pts, Style::LinePoints)])?;
//! # Ok::<(), palpate_plot::PlotError>(())
//! ```

use palpate_fem::io::atomic::write_atomic;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::path::{Path, PathBuf};

mod surface_map;
pub use surface_map::{diverging, magnitude_quantile, surface_map, SurfaceMap, NO_VALUE};

static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
const SIZE: (u32, u32) = (900, 560);

/// Which files a figure asked for as `name.svg` is written as.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PlotFormat {
    /// `name.png` only.
    Png,
    /// `name.svg` only.
    Svg,
    /// Both (the default).
    #[default]
    Both,
}

impl PlotFormat {
    /// The names `--plot-format` takes.
    pub const NAMES: [&'static str; 3] = ["png", "svg", "both"];
}

impl std::str::FromStr for PlotFormat {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "png" => Ok(Self::Png),
            "svg" => Ok(Self::Svg),
            "both" => Ok(Self::Both),
            o => Err(format!(
                "unknown plot format {o:?}: expected png, svg or both"
            )),
        }
    }
}

static FORMAT: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(2);

/// Sets the format of every figure this process writes from now on (a command line's choice).
pub fn set_format(f: PlotFormat) {
    let v = match f {
        PlotFormat::Png => 0,
        PlotFormat::Svg => 1,
        PlotFormat::Both => 2,
    };
    FORMAT.store(v, std::sync::atomic::Ordering::Relaxed);
}

/// The format figures are written in.
pub fn format() -> PlotFormat {
    match FORMAT.load(std::sync::atomic::Ordering::Relaxed) {
        0 => PlotFormat::Png,
        1 => PlotFormat::Svg,
        _ => PlotFormat::Both,
    }
}

/// The file a document (a Markdown report) should link to for the figure asked for as `file`:
/// the SVG when one is written, else the PNG.
pub fn shown(file: &str) -> String {
    shown_in(file, format())
}

fn shown_in(file: &str, format: PlotFormat) -> String {
    let p = Path::new(file);
    if p.extension().and_then(|e| e.to_str()) == Some("svg") && format == PlotFormat::Png {
        p.with_extension("png").to_string_lossy().into_owned()
    } else {
        file.to_string()
    }
}

/// Tableau 10: distinguishable on white, in print and for the common colour-vision deficiencies.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn colour(k: usize) -> RGBAColor {
    PALETTE[k % PALETTE.len()].to_rgba()
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// Connected line.
    Line,
    /// Markers only (scatter).
    Points,
    /// Line with markers.
    LinePoints,
}

/// One named series of (x, y) points.
#[derive(Debug, Clone, Copy)]
pub struct Series<'a> {
    /// Legend entry.
    pub name: &'a str,
    /// The points, in drawing order.
    pub points: &'a [(f64, f64)],
    /// How to draw them.
    pub style: Style,
}

impl<'a> Series<'a> {
    /// A series.
    pub fn new(name: &'a str, points: &'a [(f64, f64)], style: Style) -> Self {
        Series {
            name,
            points,
            style,
        }
    }
}

/// Axis scales of a line plot.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Axes {
    /// Logarithmic x axis (points with x ≤ 0 are left out).
    pub x_log: bool,
    /// Logarithmic y axis (points with y ≤ 0 are left out).
    pub y_log: bool,
}

/// Why a plot was not written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlotError {
    /// The extension is neither `.svg` nor `.png`.
    #[error("{file}: unknown plot extension: expected .svg or .png")]
    Extension {
        /// The file.
        file: PathBuf,
    },
    /// Nothing to draw (no finite points, no values, no bars).
    #[error("{file}: nothing to plot: {what}")]
    Empty {
        /// The file.
        file: PathBuf,
        /// What was empty.
        what: String,
    },
    /// plotters failed to draw.
    #[error("{file}: drawing failed: {message}")]
    Draw {
        /// The file.
        file: PathBuf,
        /// plotters' error.
        message: String,
    },
    /// Writing or encoding the file failed.
    #[error("{file}: cannot write: {message}")]
    Write {
        /// The file.
        file: PathBuf,
        /// The underlying error chain.
        message: String,
    },
}

/// A line/scatter plot of several series with linear axes.
pub fn lines(
    path: impl AsRef<Path>,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<Vec<PathBuf>, PlotError> {
    lines_with(path, title, x_label, y_label, series, Axes::default())
}

/// A line/scatter plot with a choice of linear or logarithmic axes (e.g. an L-curve). Non-finite
/// points, and non-positive ones on a log axis, are left out.
pub fn lines_with(
    path: impl AsRef<Path>,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    axes: Axes,
) -> Result<Vec<PathBuf>, PlotError> {
    let path = path.as_ref();
    // Log axes are drawn as linear axes over log10 of the data, labelled with the powers.
    let tf = |v: f64, log: bool| {
        if log {
            (v > 0.0).then(|| v.log10())
        } else {
            Some(v)
        }
    };
    let data: Vec<(&Series, Vec<(f64, f64)>)> = series
        .iter()
        .map(|s| {
            let pts = s
                .points
                .iter()
                .filter_map(|&(x, y)| Some((tf(x, axes.x_log)?, tf(y, axes.y_log)?)))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
                .collect();
            (s, pts)
        })
        .collect();
    let all: Vec<(f64, f64)> = data.iter().flat_map(|(_, p)| p.iter().copied()).collect();
    if all.is_empty() {
        return Err(PlotError::Empty {
            file: path.to_path_buf(),
            what: "no finite points in any series".into(),
        });
    }
    let xr = padded(all.iter().map(|p| p.0));
    let yr = padded(all.iter().map(|p| p.1));
    let ctx = LinesCtx {
        title,
        x_label,
        y_label,
        data: &data,
        xr,
        yr,
        axes,
        legend: series.len() > 1 || series.iter().any(|s| !s.name.is_empty()),
    };
    render_impl(path, &|r| draw_lines(r, &ctx), &|r| draw_lines(r, &ctx))
}

struct LinesCtx<'a> {
    title: &'a str,
    x_label: &'a str,
    y_label: &'a str,
    data: &'a [(&'a Series<'a>, Vec<(f64, f64)>)],
    xr: (f64, f64),
    yr: (f64, f64),
    axes: Axes,
    legend: bool,
}

fn draw_lines<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, c: &LinesCtx) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let LinesCtx {
        title,
        x_label,
        y_label,
        data,
        xr,
        yr,
        axes,
        legend,
    } = *c;
    let fmt = |log: bool, range: (f64, f64)| move |v: &f64| axis_tick(*v, log, range);
    let area = titled(&root, title)?;
    let build = |yr: (f64, f64)| {
        framed(&area, VALUE_LABEL_WIDTH).build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
    };
    // Where the legend goes: measured against the plot area before anything is drawn.
    let (position, yr) = if legend {
        let plot = build(yr)?.plotting_area().dim_in_pixel();
        let font: TextStyle = ("sans-serif", LEGEND_FONT).into_font().into();
        let mut text_w = 0;
        let mut line_h = 0;
        for (s, _) in data {
            let (w, h) =
                area.estimate_text_size(if s.name.is_empty() { " " } else { s.name }, &font)?;
            text_w = text_w.max(w);
            line_h = line_h.max(h);
        }
        // plotters' legend box: the labels' lines (1.25 × the font height) and the 30 px symbol
        // column, with a 10 px margin around them.
        let size = (
            f64::from(text_w) + 30.0 + 20.0,
            1.25 * f64::from(line_h) * data.len() as f64 + 20.0,
        );
        legend_place(data, xr, yr, plot, size)
    } else {
        (SeriesLabelPosition::UpperRight, yr)
    };
    let mut chart = build(yr)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(y_label)
        .x_label_formatter(&fmt(axes.x_log, xr))
        .y_label_formatter(&fmt(axes.y_log, yr))
        .label_style(("sans-serif", 14))
        .draw()?;
    for (k, (s, pts)) in data.iter().enumerate() {
        let color = colour(k);
        let line = matches!(s.style, Style::Line | Style::LinePoints);
        let dots = matches!(s.style, Style::Points | Style::LinePoints);
        if line {
            chart
                .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))?
                .label(s.name)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        if dots {
            let a = chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))?;
            if !line {
                a.label(s.name)
                    .legend(move |(x, y)| Circle::new((x + 10, y), 3, color.filled()));
            }
        }
    }
    if legend {
        chart
            .configure_series_labels()
            .position(position)
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .label_font(("sans-serif", LEGEND_FONT))
            .draw()?;
    }
    Ok(())
}

const LEGEND_FONT: u32 = 14;

/// The plot corner whose legend box (`size` in pixels, 5 px from the corner as plotters puts it)
/// covers the fewest data — points, and lines sampled between their points — and the y range to
/// draw: when every corner has data under it, the top of the y axis is raised until a band as
/// high as the legend is free, and the legend goes there.
fn legend_place(
    data: &[(&Series, Vec<(f64, f64)>)],
    xr: (f64, f64),
    yr: (f64, f64),
    plot: (u32, u32),
    size: (f64, f64),
) -> (SeriesLabelPosition, (f64, f64)) {
    use SeriesLabelPosition::{LowerLeft, LowerRight, UpperLeft, UpperRight};
    let (pw, ph) = (f64::from(plot.0), f64::from(plot.1));
    let mut samples: Vec<(f64, f64)> = Vec::new();
    for (s, pts) in data {
        samples.extend(pts.iter().copied());
        if matches!(s.style, Style::Line | Style::LinePoints) {
            for w in pts.windows(2) {
                for k in 1..10 {
                    let t = f64::from(k) / 10.0;
                    samples.push((
                        w[0].0 + t * (w[1].0 - w[0].0),
                        w[0].1 + t * (w[1].1 - w[0].1),
                    ));
                }
            }
        }
    }
    let count = |pos: &SeriesLabelPosition, yr: (f64, f64)| {
        let left = matches!(pos, UpperLeft | LowerLeft);
        let upper = matches!(pos, UpperLeft | UpperRight);
        let (x0, x1) = if left {
            (5.0, 5.0 + size.0)
        } else {
            (pw - 5.0 - size.0, pw - 5.0)
        };
        let (y0, y1) = if upper {
            (5.0, 5.0 + size.1)
        } else {
            (ph - 5.0 - size.1, ph - 5.0)
        };
        samples
            .iter()
            .filter(|&&(x, y)| {
                let px = (x - xr.0) / (xr.1 - xr.0) * pw;
                let py = (yr.1 - y) / (yr.1 - yr.0) * ph;
                px >= x0 - 3.0 && px <= x1 + 3.0 && py >= y0 - 3.0 && py <= y1 + 3.0
            })
            .count()
    };
    let corners = [UpperRight, UpperLeft, LowerRight, LowerLeft];
    let best = corners
        .into_iter()
        .map(|c| (count(&c, yr), c))
        .min_by_key(|(n, _)| *n);
    match best {
        Some((0, c)) => (c, yr),
        other => {
            // Headroom: the data's top at a fraction f below the new top of the axis.
            let f = (size.1 + 16.0) / ph;
            let top = samples
                .iter()
                .map(|p| p.1)
                .fold(f64::NEG_INFINITY, f64::max);
            if f < 0.6 && top.is_finite() {
                let new_top = (top - f * yr.0) / (1.0 - f);
                let yr2 = (yr.0, new_top.max(yr.1));
                let pick = if count(&UpperLeft, yr2) < count(&UpperRight, yr2) {
                    UpperLeft
                } else {
                    UpperRight
                };
                (pick, yr2)
            } else {
                (other.map_or(UpperRight, |(_, c)| c), yr)
            }
        }
    }
}

/// Width (px) of the y-axis label area for values with units (lines and bars).
const VALUE_LABEL_WIDTH: u32 = 80;
/// Width (px) of the y-axis label area for a histogram's counts, which are short integers.
const COUNT_LABEL_WIDTH: u32 = 60;

/// The chart frame every figure draws in under its title: a 12 px margin, 45 px for the x-axis
/// labels and `y_label_width` px for the y-axis labels. One place, so the figures line up.
fn framed<'a, 'b, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    y_label_width: u32,
) -> ChartBuilder<'a, 'b, DB> {
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(y_label_width);
    builder
}

/// Draws `title` centred at the top of `root` — at 24 px if it fits the canvas, else smaller or
/// on two lines (never below 13 px) — and returns the area under it.
fn titled<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    title: &str,
) -> Result<DrawingArea<DB, Shift>, Box<dyn std::error::Error>>
where
    DB::ErrorType: 'static,
{
    let (w, _) = root.dim_in_pixel();
    let avail = w.saturating_sub(40);
    let style = |size: u32| -> TextStyle { ("sans-serif", size).into_font().into() };
    let width = |t: &str, size: u32| -> u32 {
        root.estimate_text_size(t, &style(size))
            .map(|d| d.0)
            .unwrap_or(u32::MAX)
    };
    // The two-line split whose longer line is shortest.
    let split = |size: u32| -> Option<(u32, Vec<String>)> {
        title
            .char_indices()
            .filter(|&(_, ch)| ch == ' ')
            .map(|(i, _)| {
                let (a, b) = (title[..i].trim_end(), title[i..].trim_start());
                (
                    width(a, size).max(width(b, size)),
                    vec![a.to_string(), b.to_string()],
                )
            })
            .min_by_key(|(m, _)| *m)
    };
    let mut chosen = None;
    for size in [24u32, 22, 20, 18, 16] {
        if width(title, size) <= avail {
            chosen = Some((size, vec![title.to_string()]));
            break;
        }
        if size <= 20 {
            if let Some((m, lines)) = split(size) {
                if m <= avail {
                    chosen = Some((size, lines));
                    break;
                }
            }
        }
    }
    let (size, lines) = chosen.unwrap_or_else(|| {
        (
            13,
            split(13).map_or_else(|| vec![title.to_string()], |(_, l)| l),
        )
    });
    let centre = (w / 2) as i32;
    let mut y = 8i32;
    for line in &lines {
        root.draw_text(
            line,
            &style(size).pos(Pos::new(HPos::Center, VPos::Top)),
            (centre, y),
        )?;
        y += (f64::from(size) * 1.3).round() as i32;
    }
    Ok(root.split_vertically(y + 6).1)
}

/// A histogram of `values` in `bins` equal bins over their range (non-finite values left out).
pub fn histogram(
    path: impl AsRef<Path>,
    title: &str,
    x_label: &str,
    values: &[f64],
    bins: usize,
) -> Result<Vec<PathBuf>, PlotError> {
    let path = path.as_ref();
    let v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() || bins == 0 {
        return Err(PlotError::Empty {
            file: path.to_path_buf(),
            what: "no finite values or zero bins".into(),
        });
    }
    let (lo, hi) = v
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    // A constant sample (a homogeneous fit) is one bar: drawn over ±10 % of its value (±0.5
    // about zero) with the value in the title, so the ticks read as numbers, not as eleven copies
    // of the same one.
    let constant = hi <= lo;
    let (lo, hi) = if constant {
        let half = if lo == 0.0 { 0.5 } else { 0.1 * lo.abs() };
        (lo - half, hi + half)
    } else {
        (lo, hi)
    };
    let titled;
    let title = if constant {
        titled = if v.len() == 1 {
            format!("{title} (one value: {})", significant(v[0]))
        } else {
            format!("{title} (all {} values = {})", v.len(), significant(v[0]))
        };
        titled.as_str()
    } else {
        title
    };
    // Positive values over more than two decades (a per-element fit with a few elements at a
    // bound) are binned in log10: on a linear axis they would be one bar and an empty axis.
    let log = !constant && lo > 0.0 && hi / lo > 100.0;
    let (v, lo, hi) = if log {
        (
            v.iter().map(|x| x.log10()).collect::<Vec<_>>(),
            lo.log10(),
            hi.log10(),
        )
    } else {
        (v, lo, hi)
    };
    let logged;
    let x_label = if log {
        logged = format!("{x_label}, logarithmic bins");
        logged.as_str()
    } else {
        x_label
    };
    // An odd number of bins puts the value in the middle one: a narrow bar, not a block.
    let bins = if constant { 21 } else { bins };
    let counts = bin_counts(&v, lo, hi, bins);
    let w = (hi - lo) / bins as f64;
    let top = *counts.iter().max().unwrap_or(&1) as f64 * 1.08;
    let ctx = HistCtx {
        title,
        x_label,
        lo,
        hi,
        w,
        top,
        counts: &counts,
        log,
    };
    render_impl(path, &|r| draw_histogram(r, &ctx), &|r| {
        draw_histogram(r, &ctx)
    })
}

struct HistCtx<'a> {
    title: &'a str,
    x_label: &'a str,
    lo: f64,
    hi: f64,
    w: f64,
    top: f64,
    counts: &'a [usize],
    /// The x axis is log10 of the values.
    log: bool,
}

fn draw_histogram<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, c: &HistCtx) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let HistCtx {
        title,
        x_label,
        lo,
        hi,
        w,
        top,
        counts,
        log,
    } = *c;
    {
        let area = titled(&root, title)?;
        let mut chart =
            framed(&area, COUNT_LABEL_WIDTH).build_cartesian_2d(lo..hi, 0.0..top.max(1.0))?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc("count")
            .x_label_formatter(&|v| axis_tick(*v, log, (lo, hi)))
            .y_label_formatter(&|v| tick(*v, top))
            .label_style(("sans-serif", 14))
            .draw()?;
        let color = colour(0);
        chart.draw_series(counts.iter().enumerate().map(|(k, &c)| {
            let x0 = lo + k as f64 * w;
            let mut r = Rectangle::new([(x0, 0.0), (x0 + w, c as f64)], color.filled());
            r.set_margin(0, 0, 1, 1);
            r
        }))?;
        Ok(())
    }
}

/// A bar chart of labelled values (negative values draw downward from zero).
pub fn bars(
    path: impl AsRef<Path>,
    title: &str,
    y_label: &str,
    bars: &[(&str, f64)],
) -> Result<Vec<PathBuf>, PlotError> {
    let path = path.as_ref();
    let b: Vec<(&str, f64)> = bars
        .iter()
        .copied()
        .filter(|(_, v)| v.is_finite())
        .collect();
    if b.is_empty() {
        return Err(PlotError::Empty {
            file: path.to_path_buf(),
            what: "no bars with finite values".into(),
        });
    }
    let lo = b.iter().map(|x| x.1).fold(0.0, f64::min);
    let hi = b.iter().map(|x| x.1).fold(0.0, f64::max);
    let pad = 0.08 * (hi - lo).max(f64::MIN_POSITIVE);
    let ctx = BarsCtx {
        title,
        y_label,
        bars: &b,
        lo,
        hi,
        pad,
    };
    render_impl(path, &|r| draw_bars(r, &ctx), &|r| draw_bars(r, &ctx))
}

struct BarsCtx<'a> {
    title: &'a str,
    y_label: &'a str,
    bars: &'a [(&'a str, f64)],
    lo: f64,
    hi: f64,
    pad: f64,
}

fn draw_bars<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, c: &BarsCtx) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let BarsCtx {
        title,
        y_label,
        bars: b,
        lo,
        hi,
        pad,
    } = *c;
    let n = b.len();
    {
        let area = titled(&root, title)?;
        let mut chart = framed(&area, VALUE_LABEL_WIDTH).build_cartesian_2d(
            -0.5..(n as f64 - 0.5),
            (lo - if lo < 0.0 { pad } else { 0.0 })..(hi + pad),
        )?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .y_desc(y_label)
            .x_labels(n + 1)
            // Bars sit at integer x; plotters puts its "nice" ticks there when asked for n + 1.
            .x_label_formatter(&|v| {
                let i = v.round();
                if (v - i).abs() < 1e-6 && i >= 0.0 {
                    b.get(i as usize)
                        .map(|x| x.0.to_string())
                        .unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .y_label_formatter(&|v| tick(*v, hi - lo + pad))
            .label_style(("sans-serif", 14))
            .draw()?;
        let color = colour(0);
        chart.draw_series(b.iter().enumerate().map(|(i, &(_, v))| {
            Rectangle::new([(i as f64 - 0.4, 0.0), (i as f64 + 0.4, v)], color.filled())
        }))?;
        Ok(())
    }
}

/// Counts of `v` in `bins` equal bins over [lo, hi] (the last bin closed).
fn bin_counts(v: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<usize> {
    let mut counts = vec![0usize; bins];
    for &x in v {
        let k = (((x - lo) / (hi - lo)) * bins as f64).floor() as isize;
        counts[k.clamp(0, bins as isize - 1) as usize] += 1;
    }
    counts
}

/// Range of finite values with 5% padding (a unit range around a single value).
fn padded(v: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    });
    if hi > lo {
        let p = 0.05 * (hi - lo);
        (lo - p, hi + p)
    } else {
        let p = 0.5 * lo.abs().max(1e-12);
        (lo - p, hi + p)
    }
}

/// A tick label on an axis over `range`; on a log axis (`v` = log10 of the value) only the integer
/// powers of ten are labelled ("1e3") when the range holds two or more of them, else the values
/// themselves (an axis within one decade would otherwise have no label at all).
fn axis_tick(v: f64, log: bool, range: (f64, f64)) -> String {
    if !log {
        return tick(v, range.1 - range.0);
    }
    let powers = (range.1.floor() - range.0.ceil()) as i64 + 1;
    if powers >= 2 {
        if (v - v.round()).abs() < 1e-6 {
            format!("1e{}", v.round())
        } else {
            String::new()
        }
    } else {
        let x = 10f64.powf(v);
        tick(x, x)
    }
}

/// `v` to five significant digits, plain for moderate magnitudes ("19963", "0.4919").
fn significant(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || !(1e-3..1e5).contains(&a) {
        return tick(v, a);
    }
    let decimals = (4 - a.log10().floor() as i32).max(0) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Tick label: plain for moderate magnitudes, scientific otherwise; values within 1e-9 of the
/// axis span from zero are zero (round-off of the tick positions).
fn tick(v: f64, span: f64) -> String {
    let v = if v.abs() < 1e-9 * span.abs() { 0.0 } else { v };
    let a = v.abs();
    if a == 0.0 || (1e-3..1e5).contains(&a) {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        if s == "-0" {
            "0".into()
        } else {
            s.into()
        }
    } else {
        format!("{v:.2e}")
    }
}

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The bundled file is a valid TrueType font; if registration ever failed, drawing text
        // would report FontUnavailable as a PlotError::Draw, so the result can be ignored here.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

type DrawResult = Result<(), Box<dyn std::error::Error>>;

/// The files a figure asked for as `path` is written to in `format`.
fn targets(path: &Path, format: PlotFormat) -> Vec<PathBuf> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("svg") => match format {
            PlotFormat::Svg => vec![path.to_path_buf()],
            PlotFormat::Png => vec![path.with_extension("png")],
            PlotFormat::Both => vec![path.to_path_buf(), path.with_extension("png")],
        },
        _ => vec![path.to_path_buf()],
    }
}

/// Renders onto an SVG or PNG canvas chosen by the extension (`svg` and `png` are the same
/// generic drawing function at the two backends), then writes the file(s) atomically: a `.svg`
/// request in the process' [`format`], a `.png` request as PNG. Returns the files written.
fn render_impl(
    path: &Path,
    svg: &dyn Fn(DrawingArea<SVGBackend, Shift>) -> DrawResult,
    png: &dyn Fn(DrawingArea<BitMapBackend, Shift>) -> DrawResult,
) -> Result<Vec<PathBuf>, PlotError> {
    let targets = targets(path, format());
    for t in &targets {
        render_one(t, svg, png)?;
    }
    Ok(targets)
}

fn render_one(
    path: &Path,
    svg: &dyn Fn(DrawingArea<SVGBackend, Shift>) -> DrawResult,
    png: &dyn Fn(DrawingArea<BitMapBackend, Shift>) -> DrawResult,
) -> Result<(), PlotError> {
    register_font();
    let file = || path.to_path_buf();
    let draw_err = |e: Box<dyn std::error::Error>| PlotError::Draw {
        file: file(),
        message: e.to_string(),
    };
    let bytes = match path.extension().and_then(|e| e.to_str()) {
        Some("svg") => {
            let mut s = String::new();
            {
                let root = SVGBackend::with_string(&mut s, SIZE).into_drawing_area();
                root.fill(&WHITE).map_err(|e| draw_err(e.into()))?;
                svg(root.clone()).map_err(draw_err)?;
                root.present().map_err(|e| draw_err(e.into()))?;
            }
            s.into_bytes()
        }
        Some("png") => {
            let mut rgb = vec![0u8; (SIZE.0 * SIZE.1 * 3) as usize];
            {
                let root = BitMapBackend::with_buffer(&mut rgb, SIZE).into_drawing_area();
                root.fill(&WHITE).map_err(|e| draw_err(e.into()))?;
                png(root.clone()).map_err(draw_err)?;
                root.present().map_err(|e| draw_err(e.into()))?;
            }
            encode_png(&rgb).map_err(|e| PlotError::Write {
                file: file(),
                message: e.to_string(),
            })?
        }
        _ => return Err(PlotError::Extension { file: file() }),
    };
    write_atomic(path, &bytes).map_err(|e| PlotError::Write {
        file: file(),
        message: format!("{e:#}"),
    })
}

fn encode_png(rgb: &[u8]) -> Result<Vec<u8>, png::EncodingError> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, SIZE.0, SIZE.1);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        // Figures are mostly white with thin lines: adaptive filtering and the best deflate
        // level make them a tenth of the default size (fit for a repository and a web page).
        enc.set_compression(png::Compression::Best);
        enc.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
        let mut w = enc.write_header()?;
        w.write_image_data(rgb)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).unwrap();
        (info.width, info.height, buf)
    }

    #[test]
    fn line_plot_svg_holds_title_labels_and_series() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("l.svg");
        let a: Vec<(f64, f64)> = (0..20)
            .map(|i| (i as f64, (i as f64 * 0.3).sin()))
            .collect();
        let b: Vec<(f64, f64)> = (0..20).map(|i| (i as f64, 0.05 * i as f64)).collect();
        lines(
            &p,
            "Marker error",
            "iteration",
            "error (m)",
            &[
                Series::new("sine", &a, Style::Line),
                Series::new("ramp", &b, Style::Points),
            ],
        )
        .unwrap();
        let s = std::fs::read_to_string(&p).unwrap();
        for text in ["Marker error", "iteration", "error (m)", "sine", "ramp"] {
            assert!(s.contains(text), "svg lacks {text}");
        }
        // 20 scatter markers plus the legend marker.
        assert!(s.matches("<circle").count() >= 21);
        assert!(s.contains("<polyline"));
    }

    #[test]
    fn log_axes_png_is_a_real_image() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("lcurve.png");
        let pts: Vec<(f64, f64)> = (0..12)
            .map(|i| (10f64.powi(i - 6), 1.0 / (1.0 + 10f64.powi(i - 6))))
            .collect();
        lines_with(
            &p,
            "L-curve",
            "gamma",
            "residual",
            &[Series::new("fit", &pts, Style::LinePoints)],
            Axes {
                x_log: true,
                y_log: true,
            },
        )
        .unwrap();
        let (w, h, px) = decode_png(&std::fs::read(&p).unwrap());
        assert_eq!((w, h), SIZE);
        // Not blank: a good share of pixels is not white (text, axes, the curve).
        let ink = px.chunks(3).filter(|c| c.iter().any(|&v| v < 200)).count();
        assert!(ink > 2000, "only {ink} non-white pixels");
    }

    #[test]
    fn histogram_counts_and_files() {
        assert_eq!(
            bin_counts(&[0.0, 0.1, 0.5, 0.99, 1.0], 0.0, 1.0, 2),
            vec![2, 3]
        );
        let dir = tempfile::tempdir().unwrap();
        let v: Vec<f64> = (0..500)
            .map(|i| ((i * 7919) % 1000) as f64 / 1000.0)
            .collect();
        histogram(dir.path().join("h.svg"), "Fitted E", "E (Pa)", &v, 20).unwrap();
        let s = std::fs::read_to_string(dir.path().join("h.svg")).unwrap();
        assert!(s.contains("Fitted E") && s.matches("<rect").count() >= 20);
        histogram(dir.path().join("h.png"), "Fitted E", "E (Pa)", &v, 20).unwrap();
        assert!(std::fs::metadata(dir.path().join("h.png")).unwrap().len() > 5000);
    }

    /// An SVG request writes its PNG sibling too (a real PNG), and a constant sample's histogram
    /// says the value in its title instead of eleven identical tick labels.
    #[test]
    fn svg_comes_with_png_and_constant_histograms_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("h.svg");
        histogram(&p, "Young's modulus", "E (Pa)", &[19641.3; 7], 10).unwrap();
        let png = std::fs::read(dir.path().join("h.png")).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        let svg = std::fs::read_to_string(&p).unwrap();
        assert!(svg.contains("all 7 values = 19641)"), "title");
        assert_eq!(significant(19962.6772), "19963");
        // Values over four decades (a few elements at a bound) are binned in log10: the axis
        // says so and its labels are the values, not their logarithms.
        let spread: Vec<f64> = (0..200)
            .map(|i| 10f64.powf(1.0 + 0.02 * f64::from(i)))
            .collect();
        let q = dir.path().join("spread.svg");
        histogram(&q, "E", "E (Pa)", &spread, 20).unwrap();
        let spread_svg = std::fs::read_to_string(&q).unwrap();
        assert!(spread_svg.contains("E (Pa), logarithmic bins"), "x label");
        assert!(spread_svg.contains("\n1e3\n"), "a tick at 10³");
        assert_eq!(significant(0.49190), "0.4919");
        let ticks: Vec<&str> = svg.matches("19641").collect();
        assert!(ticks.len() < 5, "{} labels repeat the value", ticks.len());
    }

    #[test]
    fn bar_chart_names_every_bar() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("b.svg");
        bars(
            &p,
            "Error per measurement",
            "rms (mm)",
            &[("p1", 0.4), ("p2", 1.2), ("p3", -0.3)],
        )
        .unwrap();
        let s = std::fs::read_to_string(&p).unwrap();
        for text in ["Error per measurement", "p1", "p2", "p3", "rms (mm)"] {
            assert!(s.contains(text), "svg lacks {text}");
        }
        bars(
            dir.path().join("b.png"),
            "Error per measurement",
            "rms (mm)",
            &[("p1", 0.4)],
        )
        .unwrap();
    }

    /// `--plot-format`: which files a `.svg` request writes, and which one a report links to.
    #[test]
    fn the_format_decides_the_files() {
        let p = Path::new("out/fig.svg");
        assert_eq!(targets(p, PlotFormat::Svg), [p.to_path_buf()]);
        assert_eq!(targets(p, PlotFormat::Png), [p.with_extension("png")]);
        assert_eq!(
            targets(p, PlotFormat::Both),
            [p.to_path_buf(), p.with_extension("png")]
        );
        // An explicit PNG stays a PNG.
        let q = Path::new("fig.png");
        assert_eq!(targets(q, PlotFormat::Svg), [q.to_path_buf()]);
        assert_eq!(shown_in("fig.svg", PlotFormat::Png), "fig.png");
        assert_eq!(shown_in("fig.svg", PlotFormat::Both), "fig.svg");
        assert_eq!("both".parse::<PlotFormat>(), Ok(PlotFormat::Both));
        assert!("pdf"
            .parse::<PlotFormat>()
            .unwrap_err()
            .contains("png, svg or both"));
    }

    /// A title too long for the canvas is set smaller or on two lines, every line inside the
    /// canvas; a short one keeps 24 px on one line.
    #[test]
    fn titles_fit_the_canvas() {
        let dir = tempfile::tempdir().unwrap();
        let pts = [(0.0, 0.0), (1.0, 1.0)];
        let long = "A very long title that says everything about the figure: the residual of \
                    every marker against its distance from the contact, before and after adoption";
        for (title, max_lines) in [("Short", 1), (long, 2)] {
            let p = dir.path().join("t.svg");
            lines(
                &p,
                title,
                "x (m)",
                "y (m)",
                &[Series::new("a", &pts, Style::Line)],
            )
            .unwrap();
            let svg = std::fs::read_to_string(&p).unwrap();
            // The title's lines are the texts drawn centred ("middle") at the top.
            let heads: Vec<&str> = svg
                .split("<text")
                .skip(1)
                .filter(|t| {
                    t.contains("text-anchor=\"middle\"")
                        && !text_of(t).is_empty()
                        && title.contains(text_of(t))
                })
                .collect();
            assert!(
                !heads.is_empty() && heads.len() <= max_lines,
                "{title}: {heads:?}"
            );
            let joined: Vec<&str> = heads.iter().map(|t| text_of(t)).collect();
            assert_eq!(joined.join(" "), title);
            for t in &heads {
                let size = attr(t, "font-size");
                let chars = text_of(t).chars().count() as f64;
                // DejaVu Sans averages about 0.55 em per character.
                assert!(
                    0.55 * size * chars < SIZE.0 as f64,
                    "{title}: {size} px × {chars}"
                );
                if title == "Short" {
                    // plotters' SVG backend writes a font of n px as n / 1.24.
                    assert!((size * 1.24 - 24.0).abs() < 0.01, "{size}");
                }
            }
        }
    }

    fn text_of(t: &str) -> &str {
        t.split_once('>')
            .and_then(|(_, r)| r.split_once('<'))
            .map_or("", |(x, _)| x.trim())
    }

    fn attr(t: &str, name: &str) -> f64 {
        let at = t.find(&format!("{name}=\"")).unwrap() + name.len() + 2;
        t[at..]
            .split('"')
            .next()
            .unwrap()
            .trim_end_matches("px")
            .parse()
            .unwrap()
    }

    /// The legend goes to the empty corner; when every corner has data, the y axis gets
    /// headroom and the legend sits above the data.
    #[test]
    fn legends_do_not_cover_data() {
        let s = Series::new("a", &[], Style::Points);
        let plot = (800, 450);
        let size = (200.0, 60.0);
        // Data along the top right only: the legend goes elsewhere, the axis is unchanged.
        let pts: Vec<(f64, f64)> = (0..50).map(|i| (5.0 + 0.1 * i as f64, 9.5)).collect();
        let data = vec![(&s, pts)];
        let (pos, yr) = legend_place(&data, (0.0, 10.0), (0.0, 10.0), plot, size);
        assert!(!matches!(pos, SeriesLabelPosition::UpperRight), "{pos:?}");
        assert_eq!(yr, (0.0, 10.0));
        // A line through all four corners: headroom above the data's top.
        let line = Series::new("l", &[], Style::Line);
        let zig = vec![(0.0, 10.0), (10.0, 0.0), (0.0, 0.0), (10.0, 10.0)];
        let data = vec![(&line, zig)];
        let (pos, yr) = legend_place(&data, (0.0, 10.0), (0.0, 10.0), plot, size);
        assert!(matches!(
            pos,
            SeriesLabelPosition::UpperRight | SeriesLabelPosition::UpperLeft
        ));
        // The legend box (plus its 5 px offset) lies above y = 10 on the new axis.
        let below_box = (5.0 + size.1) / plot.1 as f64;
        assert!((yr.1 - 10.0) / (yr.1 - yr.0) > below_box, "{yr:?}");
    }

    #[test]
    fn bad_requests_are_errors_not_panics() {
        let dir = tempfile::tempdir().unwrap();
        let e = lines(
            dir.path().join("x.pdf"),
            "t",
            "x",
            "y",
            &[Series::new("a", &[(0.0, 1.0)], Style::Line)],
        );
        assert!(e
            .unwrap_err()
            .to_string()
            .contains("x.pdf: unknown plot extension"));
        let e = lines(
            dir.path().join("x.svg"),
            "t",
            "x",
            "y",
            &[Series::new("a", &[(f64::NAN, 1.0)], Style::Line)],
        );
        assert!(e.unwrap_err().to_string().contains("nothing to plot"));
        let e = histogram(dir.path().join("h.svg"), "t", "x", &[], 10);
        assert!(e.is_err());
    }
}

//! A map of a signed quantity on a surface: triangles already projected onto the page and given
//! in painter's order (farthest first), each filled with its value on a diverging scale
//! symmetric about zero, with a colour bar. Triangles without a value are grey.

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{framed, render_impl, titled, DrawResult, PlotError};

/// The fill of a triangle without a value: a mid grey, apart from every colour of the scale
/// (whose middle is near-white).
pub const NO_VALUE: RGBColor = RGBColor(150, 150, 150);

/// ColorBrewer's RdBu, 11 classes, from −1 (blue) to +1 (red): diverging, readable with the
/// common colour-vision deficiencies, its middle a light neutral.
const RDBU: [RGBColor; 11] = [
    RGBColor(5, 48, 97),
    RGBColor(33, 102, 172),
    RGBColor(67, 147, 195),
    RGBColor(146, 197, 222),
    RGBColor(209, 229, 240),
    RGBColor(247, 247, 247),
    RGBColor(253, 219, 199),
    RGBColor(244, 165, 130),
    RGBColor(214, 96, 77),
    RGBColor(178, 24, 43),
    RGBColor(103, 0, 31),
];

/// The colour of `value` on the scale from −`bound` (dark blue) through 0 (near-white) to
/// +`bound` (dark red), clipped beyond ±`bound`, interpolated between RdBu's 11 classes;
/// [`NO_VALUE`] for a non-finite value. A non-positive or non-finite `bound` puts every finite
/// value in the middle.
pub fn diverging(value: f64, bound: f64) -> RGBColor {
    if !value.is_finite() {
        return NO_VALUE;
    }
    let t = if bound > 0.0 && bound.is_finite() {
        (value / bound).clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let s = (t + 1.0) * 0.5 * (RDBU.len() - 1) as f64;
    let k = (s.floor() as usize).min(RDBU.len() - 2);
    let f = s - k as f64;
    let (a, b) = (RDBU[k], RDBU[k + 1]);
    let mix = |p: u8, q: u8| (f64::from(p) + f * (f64::from(q) - f64::from(p))).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// The `q`-quantile (0..1) of the finite values' magnitudes: a bound for the colour scale that a
/// few outlying triangles do not stretch. `None` when no value is finite.
pub fn magnitude_quantile(values: &[f64], q: f64) -> Option<f64> {
    let mut m: Vec<f64> = values
        .iter()
        .filter(|v| v.is_finite())
        .map(|v| v.abs())
        .collect();
    if m.is_empty() {
        return None;
    }
    m.sort_by(f64::total_cmp);
    let k = ((q.clamp(0.0, 1.0) * m.len() as f64).ceil() as usize).clamp(1, m.len()) - 1;
    Some(m[k])
}

/// `v` to three significant digits, as the colour bar's ticks and bound read.
fn significant3(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return if v == 0.0 { "0".into() } else { format!("{v}") };
    }
    let digits = (2 - v.abs().log10().floor() as i32).max(0) as usize;
    format!("{v:.digits$}")
}

/// What a surface map shows.
#[derive(Debug, Clone, Copy)]
pub struct SurfaceMap<'a> {
    /// The figure's title.
    pub title: &'a str,
    /// The page's x axis.
    pub x_label: &'a str,
    /// The page's y axis.
    pub y_label: &'a str,
    /// The colour bar's label (the quantity and its unit).
    pub value_label: &'a str,
    /// Triangles on the page, in drawing order (farthest first).
    pub triangles: &'a [[(f64, f64); 3]],
    /// Each triangle's value (NaN for none: grey).
    pub values: &'a [f64],
}

/// The 95th percentile of |value| bounds the colour scale.
const BOUND_QUANTILE: f64 = 0.95;

/// Draws `map` with equal scales on both axes; the colour scale is symmetric about 0 and clipped
/// at the 95th percentile of the triangles' |value|, which the colour bar states.
pub fn surface_map(path: impl AsRef<Path>, map: &SurfaceMap) -> Result<Vec<PathBuf>, PlotError> {
    let path = path.as_ref();
    if map.triangles.len() != map.values.len() {
        return Err(PlotError::Empty {
            file: path.to_path_buf(),
            what: format!(
                "{} triangles but {} values",
                map.triangles.len(),
                map.values.len()
            ),
        });
    }
    let corners: Vec<(f64, f64)> = map
        .triangles
        .iter()
        .flatten()
        .copied()
        .filter(|(x, y)| x.is_finite() && y.is_finite())
        .collect();
    if corners.is_empty() {
        return Err(PlotError::Empty {
            file: path.to_path_buf(),
            what: "no triangle with finite corners".into(),
        });
    }
    let bound = magnitude_quantile(map.values, BOUND_QUANTILE).unwrap_or(0.0);
    let range = |f: fn(&(f64, f64)) -> f64| {
        corners
            .iter()
            .map(f)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(v), b.max(v))
            })
    };
    let ctx = MapCtx {
        map,
        xr: range(|p| p.0),
        yr: range(|p| p.1),
        bound,
    };
    render_impl(path, &|r| draw_map(r, &ctx), &|r| draw_map(r, &ctx))
}

struct MapCtx<'a> {
    map: &'a SurfaceMap<'a>,
    xr: (f64, f64),
    yr: (f64, f64),
    bound: f64,
}

/// Width (px) of the colour bar's column, its labels included.
const BAR_WIDTH: u32 = 190;

fn draw_map<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, c: &MapCtx) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let m = c.map;
    let area = titled(&root, m.title)?;
    let (w, _) = area.dim_in_pixel();
    let (left, right) = area.split_horizontally(w.saturating_sub(BAR_WIDTH));
    // Equal scales: measure the plot area, then widen the shorter range about its middle.
    let probe = framed(&left, super::VALUE_LABEL_WIDTH)
        .build_cartesian_2d(c.xr.0..c.xr.1, c.yr.0..c.yr.1)?
        .plotting_area()
        .dim_in_pixel();
    let (pw, ph) = (f64::from(probe.0.max(1)), f64::from(probe.1.max(1)));
    let span = |r: (f64, f64)| (r.1 - r.0).max(1e-12);
    let scale = (span(c.xr) / pw).max(span(c.yr) / ph) * 1.04;
    let widen = |r: (f64, f64), px: f64| {
        let mid = 0.5 * (r.0 + r.1);
        (mid - 0.5 * scale * px, mid + 0.5 * scale * px)
    };
    let (xr, yr) = (widen(c.xr, pw), widen(c.yr, ph));
    let mut chart =
        framed(&left, super::VALUE_LABEL_WIDTH).build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(m.x_label)
        .y_desc(m.y_label)
        .label_style(("sans-serif", 14))
        .draw()?;
    // Each triangle filled, then outlined in its own colour before the next one: the hairline
    // closes the seams anti-aliasing leaves between neighbours without breaking painter's order.
    for (t, &v) in m.triangles.iter().zip(m.values) {
        let colour = diverging(v, c.bound);
        chart.draw_series(std::iter::once(Polygon::new(t.to_vec(), colour.filled())))?;
        let mut outline = t.to_vec();
        outline.push(t[0]);
        chart.draw_series(std::iter::once(PathElement::new(
            outline,
            colour.stroke_width(1),
        )))?;
    }

    // The colour bar: ±bound, the clip stated; under it, the grey of "no value".
    let b = if c.bound > 0.0 { c.bound } else { 1.0 };
    let label = format!(
        "{}, clipped at ±{} (95th pct)",
        m.value_label,
        significant3(c.bound)
    );
    let mut bar = ChartBuilder::on(&right)
        .margin_top(30)
        .margin_bottom(80)
        .margin_right(110)
        .margin_left(10)
        .y_label_area_size(0)
        .right_y_label_area_size(60)
        .build_cartesian_2d(0.0..1.0, -b..b)?;
    bar.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_desc(label)
        // A tick at 0 computed as −b + k·step reads 1e-17 otherwise.
        .y_label_formatter(&|v| {
            let t = significant3(if v.abs() < 1e-9 * b { 0.0 } else { *v });
            if t.contains('.') {
                t.trim_end_matches('0').trim_end_matches('.').to_string()
            } else {
                t
            }
        })
        .label_style(("sans-serif", 13))
        .draw()?;
    let steps = 100;
    bar.draw_series((0..steps).map(|k| {
        let lo = -b + 2.0 * b * k as f64 / steps as f64;
        let hi = lo + 2.0 * b / steps as f64;
        Rectangle::new(
            [(0.0, lo), (1.0, hi)],
            diverging(0.5 * (lo + hi), b).filled(),
        )
    }))?;
    let (_, h) = right.dim_in_pixel();
    let y = h as i32 - 62;
    right.draw(&Rectangle::new([(10, y), (34, y + 16)], NO_VALUE.filled()))?;
    right.draw_text(
        "no point nearest",
        &("sans-serif", 13).into_font().color(&BLACK),
        (40, y + 1),
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The scale's ends and middle are RdBu's, values beyond the bound are clipped to the ends,
    /// a value half-way to +bound is a light red, and no value is grey.
    #[test]
    fn values_get_their_colour() {
        assert_eq!(diverging(0.0, 2.0), RDBU[5]);
        assert_eq!(diverging(2.0, 2.0), RDBU[10]);
        assert_eq!(diverging(9.0, 2.0), RDBU[10]);
        assert_eq!(diverging(-2.0, 2.0), RDBU[0]);
        assert_eq!(diverging(-1e9, 2.0), RDBU[0]);
        // +1 of ±2: 3/4 along the scale, class 7.5: between 7 and 8.
        let c = diverging(1.0, 2.0);
        assert!(c.0 > c.2 && c.0 < RDBU[7].0 && c.0 > RDBU[8].0, "{c:?}");
        assert_eq!(diverging(f64::NAN, 2.0), NO_VALUE);
        assert_eq!(diverging(1.0, 0.0), RDBU[5]);
        assert_eq!(
            magnitude_quantile(&[1.0, -2.0, f64::NAN, 3.0, -4.0], 0.5),
            Some(2.0)
        );
        assert_eq!(magnitude_quantile(&[f64::NAN], 0.95), None);
        assert_eq!(significant3(0.101_04), "0.101");
        assert_eq!(significant3(-12.34), "-12.3");
        assert_eq!(significant3(250.0), "250");
    }

    /// Two overlapping squares, each two triangles: the one listed last (nearer) covers the
    /// other where they overlap; a triangle with a value at the bound is the scale's red end,
    /// one without a value grey. Read back from the PNG's pixels.
    #[test]
    fn the_last_triangle_covers_and_colours_are_painted() {
        let dir = tempfile::tempdir().unwrap();
        let square = |x0: f64, y0: f64| {
            [
                [(x0, y0), (x0 + 2.0, y0), (x0 + 2.0, y0 + 2.0)],
                [(x0, y0), (x0 + 2.0, y0 + 2.0), (x0, y0 + 2.0)],
            ]
        };
        let mut triangles = Vec::new();
        triangles.extend(square(0.0, 0.0)); // far: no value
        triangles.extend(square(1.0, 0.0)); // near: +1 (the bound)
        let values = [f64::NAN, f64::NAN, 1.0, 1.0];
        let map = SurfaceMap {
            title: "Overlap",
            x_label: "x (mm)",
            y_label: "y (mm)",
            value_label: "r (mm)",
            triangles: &triangles,
            values: &values,
        };
        let p = dir.path().join("m.png");
        surface_map(&p, &map).unwrap();
        let dec = png::Decoder::new(std::io::Cursor::new(std::fs::read(&p).unwrap()));
        let mut r = dec.read_info().unwrap();
        let mut buf = vec![0; r.output_buffer_size()];
        let info = r.next_frame(&mut buf).unwrap();
        // A row through the squares' middle (the canvas' middle, with equal scales): grey, then
        // red from where the near square begins.
        let y = info.height / 2;
        let (grey, red) = ([150u8, 150, 150], [103u8, 0, 31]);
        let mut runs: Vec<([u8; 3], u32)> = Vec::new();
        for x in 0..info.width - BAR_WIDTH {
            let i = 3 * (y * info.width + x) as usize;
            let c = [buf[i], buf[i + 1], buf[i + 2]];
            if c == grey || c == red {
                match runs.last_mut() {
                    Some((last, n)) if *last == c => *n += 1,
                    _ => runs.push((c, 1)),
                }
            }
        }
        assert_eq!(runs.len(), 2, "{runs:?}");
        assert_eq!((runs[0].0, runs[1].0), (grey, red));
        // The grey square shows only its left half: a third of the 3-unit-wide pair.
        let share = f64::from(runs[0].1) / f64::from(runs[0].1 + runs[1].1);
        assert!((share - 1.0 / 3.0).abs() < 0.03, "{share}");
        let svg = dir.path().join("m.svg");
        surface_map(&svg, &map).unwrap();
        let s = std::fs::read_to_string(&svg).unwrap();
        assert!(s.contains("Overlap") && s.contains("clipped at ±1.00 (95th pct"));
        assert!(s.matches("<polygon").count() >= 4);
    }
}

//! Residual signatures: how much of the residual (measured − model) each variable explains, the
//! way an engineer would look at a tension test or a sensor calibration:
//! - load magnitude: η² of the residual over 10 quantile bins of x (curvature → non-linearity);
//! - loading direction: the extra η² of (x bin × sign of ẋ) cells over x bins alone (hysteresis);
//! - rate: r² between ln |ẋ| and the mean loading residual across files (rate dependence);
//! - hold time: r² between ln(time since the hold began) and the residual at constant x, per hold
//!   segment about its mean (relaxation);
//! - run/file: η² of the per-file means (offsets, drift);
//! - top of range: the energy share of the mean residual over the top 10 % of x (saturation).

// Residuals, x, t and directions are parallel per-group arrays: indices read clearer than zips.
#![allow(clippy::needless_range_loop)]

use super::read::Group;
use palpate_static_fit::evidence::centred_products;

/// The variable a signal looks along.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Variable {
    /// Load magnitude x.
    Magnitude,
    /// Loading direction (sign of ẋ) at equal x.
    Direction,
    /// Rate across files.
    Rate,
    /// Time at constant x.
    HoldTime,
    /// File / run.
    Group,
    /// Top of the x range.
    Top,
}

impl Variable {
    /// Name.
    pub fn name(self) -> &'static str {
        match self {
            Variable::Magnitude => "load magnitude",
            Variable::Direction => "loading direction",
            Variable::Rate => "rate across files",
            Variable::HoldTime => "time at constant load",
            Variable::Group => "file / run",
            Variable::Top => "top of the range",
        }
    }
    /// Effects this signal points to.
    pub fn points_to(self) -> &'static str {
        match self {
            Variable::Magnitude => {
                "non-linearity (hyperelastic law, sensor power law / saturation)"
            }
            Variable::Direction => "hysteresis (viscosity)",
            Variable::Rate => "rate dependence (viscosity)",
            Variable::HoldTime => "relaxation (viscosity)",
            Variable::Group => "drift or offsets between runs",
            Variable::Top => "saturation",
        }
    }
}

/// One signal of the residual.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Signal {
    /// Variable.
    pub variable: Variable,
    /// Share of the residual explained (0–1; for rate and hold, an r² on the subset used).
    pub explained: f64,
    /// Details in words.
    pub detail: String,
}

/// The signature of a residual.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Signature {
    /// RMS residual.
    pub rms: f64,
    /// Signals, strongest first.
    pub signals: Vec<Signal>,
}

/// Rate ẋ per sample (central differences; one-sided at the ends).
pub fn rates(g: &Group) -> Vec<f64> {
    let n = g.x.len();
    (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
            let dt = g.t[b] - g.t[a];
            if dt > 0.0 {
                (g.x[b] - g.x[a]) / dt
            } else {
                0.0
            }
        })
        .collect()
}

/// Loading direction per sample: +1, −1, or 0 (holding: |ẋ| below 2 % of the largest rate).
pub fn directions(groups: &[Group]) -> Vec<Vec<i8>> {
    let r: Vec<Vec<f64>> = groups.iter().map(rates).collect();
    let top = r.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    r.iter()
        .map(|v| {
            v.iter()
                .map(|&q| {
                    if q.abs() <= 0.02 * top {
                        0
                    } else if q > 0.0 {
                        1
                    } else {
                        -1
                    }
                })
                .collect()
        })
        .collect()
}

fn quantile_edges(x: &[f64], bins: usize) -> Vec<f64> {
    let mut s: Vec<f64> = x.to_vec();
    s.sort_by(f64::total_cmp);
    (1..bins).map(|k| s[k * s.len() / bins]).collect()
}

fn bin_of(edges: &[f64], x: f64) -> usize {
    edges.partition_point(|&e| e <= x)
}

/// η²: share of Σr² explained by the cell means (cells keyed by `key`).
fn eta2(r: &[f64], key: &[usize]) -> f64 {
    let total: f64 = r.iter().map(|v| v * v).sum();
    if total <= 0.0 {
        return 0.0;
    }
    let k = key.iter().copied().max().map_or(0, |m| m + 1);
    let (mut s, mut c) = (vec![0.0; k], vec![0usize; k]);
    for (&v, &q) in r.iter().zip(key) {
        s[q] += v;
        c[q] += 1;
    }
    let expl: f64 = (0..k)
        .filter(|&q| c[q] > 0)
        .map(|q| s[q] * s[q] / c[q] as f64)
        .sum();
    (expl / total).clamp(0.0, 1.0)
}

fn r2(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    if a.len() < 3 {
        return 0.0;
    }
    let (sab, saa, sbb) = centred_products(a, b, n);
    if saa <= 0.0 || sbb <= 0.0 {
        0.0
    } else {
        sab * sab / (saa * sbb)
    }
}

/// Hold segments: runs of ≥ 5 samples with direction 0 away from x = 0 (|x| > 5 % of the range);
/// returns (group, first, last) index triples.
pub fn holds(groups: &[Group], dirs: &[Vec<i8>]) -> Vec<(usize, usize, usize)> {
    let xmax = groups
        .iter()
        .flat_map(|g| g.x.iter())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let mut out = Vec::new();
    for (gi, g) in groups.iter().enumerate() {
        let mut start: Option<usize> = None;
        for i in 0..=g.x.len() {
            let holding = i < g.x.len() && dirs[gi][i] == 0 && g.x[i].abs() > 0.05 * xmax;
            match (holding, start) {
                (true, None) => start = Some(i),
                (false, Some(s)) => {
                    if i - s >= 5 {
                        out.push((gi, s, i - 1));
                    }
                    start = None;
                }
                _ => {}
            }
        }
    }
    out
}

/// Evidence points (variable value, residual) of a signal, one series per label.
pub fn evidence(
    v: Variable,
    groups: &[Group],
    resid: &[Vec<f64>],
    time_series: bool,
) -> Vec<(String, Vec<(f64, f64)>)> {
    let dirs = if time_series {
        directions(groups)
    } else {
        groups.iter().map(|g| vec![0; g.x.len()]).collect()
    };
    let all = |f: &dyn Fn(usize, usize) -> Option<f64>| -> Vec<(f64, f64)> {
        let mut v = Vec::new();
        for (gi, g) in groups.iter().enumerate() {
            for i in 0..g.x.len() {
                if let Some(x) = f(gi, i) {
                    v.push((x, resid[gi][i]));
                }
            }
        }
        v
    };
    match v {
        Variable::Magnitude | Variable::Top => {
            vec![("all samples".into(), all(&|gi, i| Some(groups[gi].x[i])))]
        }
        Variable::Direction => vec![
            (
                "loading".into(),
                all(&|gi, i| (dirs[gi][i] > 0).then(|| groups[gi].x[i])),
            ),
            (
                "unloading".into(),
                all(&|gi, i| (dirs[gi][i] < 0).then(|| groups[gi].x[i])),
            ),
        ],
        Variable::Group => vec![("samples".into(), all(&|gi, _| Some(groups[gi].order)))],
        Variable::Rate => {
            let pts = groups
                .iter()
                .enumerate()
                .filter_map(|(gi, g)| {
                    let rt = rates(g);
                    let idx: Vec<usize> = (0..g.x.len()).filter(|&i| dirs[gi][i] > 0).collect();
                    (!idx.is_empty()).then(|| {
                        let n = idx.len() as f64;
                        (
                            idx.iter().map(|&i| rt[i].abs()).sum::<f64>() / n,
                            idx.iter().map(|&i| resid[gi][i]).sum::<f64>() / n,
                        )
                    })
                })
                .collect();
            vec![("mean loading residual per file vs mean rate".into(), pts)]
        }
        Variable::HoldTime => {
            let mut pts = Vec::new();
            for (gi, a, b) in holds(groups, &dirs) {
                for i in a..=b {
                    pts.push((groups[gi].t[i] - groups[gi].t[a], resid[gi][i]));
                }
            }
            vec![("samples at constant load".into(), pts)]
        }
    }
}

/// The signature of `resid` (measured − model, per group).
pub fn signature(groups: &[Group], resid: &[Vec<f64>], time_series: bool) -> Signature {
    let flat: Vec<f64> = resid.iter().flatten().copied().collect();
    let n = flat.len().max(1) as f64;
    let total: f64 = flat.iter().map(|v| v * v).sum();
    let rms = (total / n).sqrt();
    let xs: Vec<f64> = groups.iter().flat_map(|g| g.x.iter().copied()).collect();
    let edges = quantile_edges(&xs, 10);
    let bins: Vec<usize> = xs.iter().map(|&x| bin_of(&edges, x)).collect();
    let mut signals = Vec::new();
    let mag = eta2(&flat, &bins);
    signals.push(Signal {
        variable: Variable::Magnitude,
        explained: mag,
        detail: format!(
            "{:.0} % of Σr² explained by the mean residual in 10 bins of x",
            100.0 * mag
        ),
    });
    if time_series {
        time_signals(groups, resid, &flat, &bins, &mut signals);
    }
    if groups.len() >= 2 {
        let key: Vec<usize> = groups
            .iter()
            .enumerate()
            .flat_map(|(gi, g)| std::iter::repeat_n(gi, g.x.len()))
            .collect();
        let e = eta2(&flat, &key);
        signals.push(Signal {
            variable: Variable::Group,
            explained: e,
            detail: format!(
                "{:.0} % of Σr² explained by the per-file/run mean",
                100.0 * e
            ),
        });
    }
    let top_edge = quantile_edges(&xs, 10)
        .last()
        .copied()
        .unwrap_or(f64::INFINITY);
    let top: Vec<f64> = flat
        .iter()
        .zip(&xs)
        .filter(|(_, &x)| x >= top_edge)
        .map(|(r, _)| *r)
        .collect();
    if !top.is_empty() && total > 0.0 {
        let m = top.iter().sum::<f64>() / top.len() as f64;
        let e = (top.len() as f64 * m * m / total).clamp(0.0, 1.0);
        signals.push(Signal {
            variable: Variable::Top,
            explained: e,
            detail: format!(
                "mean residual {m:+.4} over the top 10 % of x ({} samples): {:.0} % of Σr²",
                top.len(),
                100.0 * e
            ),
        });
    }
    signals.sort_by(|a, b| b.explained.total_cmp(&a.explained));
    Signature { rms, signals }
}

/// The signals only a time series has: loading direction (hysteresis), rate across files and
/// time at constant load (relaxation), appended to `signals` (`flat`, `bins`: the residual and
/// its x bin, sample by sample over all groups).
fn time_signals(
    groups: &[Group],
    resid: &[Vec<f64>],
    flat: &[f64],
    bins: &[usize],
    signals: &mut Vec<Signal>,
) {
    let dirs = directions(groups);
    let d: Vec<i8> = dirs.iter().flatten().copied().collect();
    let moving: Vec<usize> = (0..flat.len()).filter(|&i| d[i] != 0).collect();
    if moving.len() > 10 && d.contains(&1) && d.contains(&-1) {
        let r: Vec<f64> = moving.iter().map(|&i| flat[i]).collect();
        let b: Vec<usize> = moving.iter().map(|&i| bins[i]).collect();
        let cells: Vec<usize> = moving
            .iter()
            .map(|&i| 2 * bins[i] + usize::from(d[i] > 0))
            .collect();
        let extra = (eta2(&r, &cells) - eta2(&r, &b)).max(0.0);
        let mean = |s: i8| {
            let v: Vec<f64> = moving
                .iter()
                .filter(|&&i| d[i] == s)
                .map(|&i| flat[i])
                .collect();
            v.iter().sum::<f64>() / v.len().max(1) as f64
        };
        signals.push(Signal {
                variable: Variable::Direction,
                explained: extra,
                detail: format!(
                    "loading vs unloading at equal x explains {:.0} % more of Σr² (mean residual {:+.4} loading, {:+.4} unloading)",
                    100.0 * extra,
                    mean(1),
                    mean(-1)
                ),
            });
    }
    let ev = evidence(Variable::Rate, groups, resid, true);
    let pts = &ev[0].1;
    let (lo, hi) = pts.iter().fold((f64::INFINITY, 0.0f64), |(a, b), p| {
        (a.min(p.0), b.max(p.0))
    });
    if pts.len() >= 3 && lo > 0.0 && hi / lo > 1.5 {
        let lr: Vec<f64> = pts.iter().map(|p| p.0.ln()).collect();
        let mr: Vec<f64> = pts.iter().map(|p| p.1).collect();
        let c = r2(&lr, &mr);
        signals.push(Signal {
                variable: Variable::Rate,
                explained: c,
                detail: format!(
                    "r² = {c:.2} between ln(mean loading rate) and the mean loading residual over {} files (rates {lo:.3}–{hi:.3} per s)",
                    pts.len()
                ),
            });
    }
    let hs = holds(groups, &dirs);
    if !hs.is_empty() {
        let (mut lt, mut rr) = (Vec::new(), Vec::new());
        for &(gi, a, b) in &hs {
            let m = resid[gi][a..=b].iter().sum::<f64>() / (b - a + 1) as f64;
            let t0 = groups[gi].t[a];
            let dt = (groups[gi].t[b] - t0) / (b - a) as f64;
            for i in a..=b {
                lt.push((groups[gi].t[i] - t0 + dt).ln());
                rr.push(resid[gi][i] - m);
            }
        }
        let c = r2(&lt, &rr);
        signals.push(Signal {
                variable: Variable::HoldTime,
                explained: c,
                detail: format!(
                    "r² = {c:.2} between ln(time since the hold began) and the residual about each hold's mean ({} holds, {} samples)",
                    hs.len(),
                    rr.len()
                ),
            });
    }
}

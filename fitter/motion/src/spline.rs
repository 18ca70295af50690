//! The generic principal-stretch material of seed 001 §4.2 (eqs. 18–20, after Xu et al. 2015).
//!
//! Ψ(F) = Σᵢ f(ςᵢ) + h(ς₁ς₂ς₃)                                   (eq. 18 with g ≡ 0)
//! ∂Ψ/∂ς₁ = f′(ς₁) + h′(ς₁ς₂ς₃) ς₂ς₃  (and cyclically)           (eq. 20)
//! P = U diag(∂Ψ/∂ςᵢ) Vᵀ with F = U diag(ς) Vᵀ.
//!
//! The two response functions are interpolating cubic Hermite splines whose control-point values
//! are the parameters; the control-point locations stay fixed (as in the paper):
//! - f′(x) = S_f(x) on stretch knots;
//! - h′(J) = S_h(J)/J on volume-ratio knots, i.e. the control values of S_h are J·h′(J) at the
//!   knots (h′ scaled by the fixed knot location).
//!
//! The tangents of each spline come from the three-point finite-difference formula, which on
//! uniform knots is the Catmull–Rom spline (Kochanek–Bartels with zero tension, continuity and
//! bias, the paper's choice); outside the knot range the splines continue linearly with their end
//! slopes. This tangent rule reproduces quadratics exactly, and the Neo-Hookean initialisation
//! (eq. 19, with the volumetric term of eq. 16) is f′(x) = μx and J h′(J) = −μ + λ(J² − 1)/2 —
//! both quadratics — so at initialisation the spline material *is* Neo-Hookean inside the knot
//! range, not an approximation of it (that is why h′ is carried as J h′(J)). Every spline value is
//! linear in the control values, so ∂P/∂c is the same formula as P with the basis weights in place
//! of the values (what the paper got from autodiff).
//!
//! The stress derivative uses the rotated-frame decomposition (Teran et al. 2005, as assembled in
//! Xu et al. 2015): with dF̂ = Uᵀ dF V, dP̂ᵢᵢ = Σⱼ Aᵢⱼ dF̂ⱼⱼ (A = ∂²Ψ/∂ς∂ς) and for i ≠ j the 2 × 2
//! block dP̂ᵢⱼ = aᵢⱼ dF̂ᵢⱼ + bᵢⱼ dF̂ⱼᵢ; the divided difference (ψᵢ − ψⱼ)/(ςᵢ − ςⱼ) is evaluated in
//! closed form (f′ divided difference minus S_h/(ςᵢςⱼ)), so repeated stretches — the rest state
//! — are not singular.

use super::MotionError;
use nalgebra::{Matrix3, Vector3};

/// A C¹ cubic Hermite spline through (knotₖ, valueₖ) with three-point tangents and linear
/// extrapolation.
#[derive(Debug, Clone, PartialEq)]
pub struct Spline {
    /// Strictly increasing control-point locations (fixed).
    pub knots: Vec<f64>,
    /// Control-point values (the parameters).
    pub values: Vec<f64>,
}

/// Basis weights of one evaluation: s(x) = Σₖ w\[k\]·c\[lo + k\], s′(x) = Σₖ dw\[k\]·c\[lo + k\].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Basis {
    /// First control index.
    pub lo: usize,
    /// Value weights.
    pub w: [f64; 4],
    /// Slope weights.
    pub dw: [f64; 4],
}

impl Basis {
    fn apply(&self, c: &[f64]) -> (f64, f64) {
        let mut s = 0.0;
        let mut d = 0.0;
        for k in 0..4 {
            s += self.w[k] * c[self.lo + k];
            d += self.dw[k] * c[self.lo + k];
        }
        (s, d)
    }
}

impl Spline {
    /// Knots `knots` with values `g(knot)`; needs ≥ 4 strictly increasing finite knots.
    pub fn from_fn(knots: Vec<f64>, g: impl Fn(f64) -> f64) -> Result<Self, MotionError> {
        if knots.len() < 4 {
            return Err(MotionError::Invalid(format!(
                "a response spline needs at least 4 control points, found {}",
                knots.len()
            )));
        }
        for (i, w) in knots.windows(2).enumerate() {
            if w[1] <= w[0] || !w[0].is_finite() || !w[1].is_finite() {
                return Err(MotionError::Invalid(format!(
                    "spline knots must be finite and strictly increasing: knot {} = {} then {}",
                    i, w[0], w[1]
                )));
            }
        }
        let values = knots.iter().map(|&x| g(x)).collect();
        Ok(Self { knots, values })
    }

    /// `n` uniform knots on [a, b].
    pub fn uniform_knots(a: f64, b: f64, n: usize) -> Vec<f64> {
        (0..n)
            .map(|i| a + (b - a) * i as f64 / (n.max(2) - 1) as f64)
            .collect()
    }

    /// Three-point tangent weights at knot `i`: (first index, weights of three values).
    fn tangent(&self, i: usize) -> (usize, [f64; 3]) {
        let x = &self.knots;
        let n = x.len();
        if i == 0 {
            let (h0, h1) = (x[1] - x[0], x[2] - x[1]);
            (
                0,
                [
                    -(2.0 * h0 + h1) / (h0 * (h0 + h1)),
                    (h0 + h1) / (h0 * h1),
                    -h0 / (h1 * (h0 + h1)),
                ],
            )
        } else if i == n - 1 {
            let (h0, h1) = (x[n - 2] - x[n - 3], x[n - 1] - x[n - 2]);
            (
                n - 3,
                [
                    h1 / (h0 * (h0 + h1)),
                    -(h0 + h1) / (h0 * h1),
                    (2.0 * h1 + h0) / (h1 * (h0 + h1)),
                ],
            )
        } else {
            let (h0, h1) = (x[i] - x[i - 1], x[i + 1] - x[i]);
            (
                i - 1,
                [
                    -h1 / (h0 * (h0 + h1)),
                    (h1 - h0) / (h0 * h1),
                    h0 / (h1 * (h0 + h1)),
                ],
            )
        }
    }

    /// Basis weights at `x`.
    pub fn basis(&self, x: f64) -> Basis {
        let k = &self.knots;
        let n = k.len();
        let seg = match k.partition_point(|&t| t <= x) {
            0 => None,
            p if p >= n => None,
            p => Some(p - 1),
        };
        let lo_of = |i: usize| i.saturating_sub(1).min(n - 4);
        let mut b = Basis {
            lo: 0,
            w: [0.0; 4],
            dw: [0.0; 4],
        };
        let add = |b: &mut Basis, idx: usize, w: f64, dw: f64| {
            b.w[idx - b.lo] += w;
            b.dw[idx - b.lo] += dw;
        };
        match seg {
            Some(i) => {
                b.lo = lo_of(i);
                let h = k[i + 1] - k[i];
                let t = (x - k[i]) / h;
                let (t2, t3) = (t * t, t * t * t);
                let h00 = 2.0 * t3 - 3.0 * t2 + 1.0;
                let h10 = t3 - 2.0 * t2 + t;
                let h01 = -2.0 * t3 + 3.0 * t2;
                let h11 = t3 - t2;
                let d00 = (6.0 * t2 - 6.0 * t) / h;
                let d10 = 3.0 * t2 - 4.0 * t + 1.0;
                let d01 = (-6.0 * t2 + 6.0 * t) / h;
                let d11 = 3.0 * t2 - 2.0 * t;
                add(&mut b, i, h00, d00);
                add(&mut b, i + 1, h01, d01);
                for (node, hv, dv) in [(i, h10, d10), (i + 1, h11, d11)] {
                    let (first, tw) = self.tangent(node);
                    for (j, w) in tw.iter().enumerate() {
                        add(&mut b, first + j, hv * h * w, dv * w);
                    }
                }
            }
            None => {
                // Linear continuation with the end slope (C¹ at the end knot).
                let end = if x < k[0] { 0 } else { n - 1 };
                b.lo = if end == 0 { 0 } else { n - 4 };
                let dx = x - k[end];
                add(&mut b, end, 1.0, 0.0);
                let (first, tw) = self.tangent(end);
                for (j, w) in tw.iter().enumerate() {
                    add(&mut b, first + j, dx * w, *w);
                }
            }
        }
        b
    }

    /// (s(x), s′(x)).
    pub fn eval(&self, x: f64) -> (f64, f64) {
        self.basis(x).apply(&self.values)
    }

    /// ∫ₐᵇ s(x)·wgt(x) dx by 8-point Gauss–Legendre on every knot interval (and on chunks of the
    /// extrapolated range no longer than the outermost intervals): exact for the cubic pieces
    /// times a polynomial weight of degree ≤ 12, and ~1e-15 relative for wgt = 1/x away from 0.
    pub fn integrate(&self, a: f64, b: f64, wgt: impl Fn(f64) -> f64) -> f64 {
        if a == b {
            return 0.0;
        }
        let (lo, hi, sign) = if a < b { (a, b, 1.0) } else { (b, a, -1.0) };
        let k = &self.knots;
        let step = (k[1] - k[0]).min(k[k.len() - 1] - k[k.len() - 2]);
        let (first, last) = (k[0], k[k.len() - 1]);
        let mut cuts = vec![lo, hi];
        cuts.extend(k.iter().copied().filter(|&t| t > lo && t < hi));
        let mut t = first - step;
        while t > lo {
            if t < hi {
                cuts.push(t);
            }
            t -= step;
        }
        let mut t = last + step;
        while t < hi {
            if t > lo {
                cuts.push(t);
            }
            t += step;
        }
        cuts.sort_by(f64::total_cmp);
        cuts.dedup();
        const GX: [f64; 4] = [
            0.183_434_642_495_649_8,
            0.525_532_409_916_329,
            0.796_666_477_413_626_7,
            0.960_289_856_497_536_3,
        ];
        const GW: [f64; 4] = [
            0.362_683_783_378_362,
            0.313_706_645_877_887_3,
            0.222_381_034_453_374_5,
            0.101_228_536_290_376_3,
        ];
        let mut sum = 0.0;
        for w in cuts.windows(2) {
            let (m, r) = (0.5 * (w[0] + w[1]), 0.5 * (w[1] - w[0]));
            for (x, wt) in GX.iter().zip(GW) {
                for s in [-1.0, 1.0] {
                    let p = m + s * r * x;
                    sum += wt * r * self.eval(p).0 * wgt(p);
                }
            }
        }
        sign * sum
    }

    /// Locations where the slope penalty samples the response: every knot and the midpoint of
    /// every knot interval.
    pub fn samples(&self) -> Vec<f64> {
        let mut v = Vec::with_capacity(2 * self.knots.len());
        for w in self.knots.windows(2) {
            v.push(w[0]);
            v.push(0.5 * (w[0] + w[1]));
        }
        v.push(self.knots[self.knots.len() - 1]);
        v
    }
}

/// Which response function a control value belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Response {
    /// f′ (uniaxial, on stretch knots).
    F,
    /// h′ (volumetric, on J knots; control values are J h′(J)).
    H,
}

/// The two response splines of eq. 18 (global: one material for every element, as in the paper).
#[derive(Debug, Clone, PartialEq)]
pub struct SplineMaterial {
    /// f′(x) = S_f(x).
    pub f: Spline,
    /// J h′(J) = S_h(J).
    pub h: Spline,
    /// Weight w of the negative-slope penalty added to the fit objective (§4.2); `None` =
    /// automatic (`optimize::auto_slope_weight`).
    pub slope_weight: Option<f64>,
}

/// Principal-stretch state of one element: F = U diag(ς) Vᵀ and the stress coefficients.
#[derive(Debug, Clone, Copy)]
pub struct StretchState {
    /// U (F = U Σ Vᵀ).
    pub u: Matrix3<f64>,
    /// V.
    pub v: Matrix3<f64>,
    /// Principal stretches ςᵢ.
    pub s: Vector3<f64>,
    /// J = ς₁ς₂ς₃.
    pub j: f64,
    /// ψᵢ = ∂Ψ/∂ςᵢ (eq. 20).
    pub psi: Vector3<f64>,
    fp: Vector3<f64>,
    fpp: Vector3<f64>,
    sh: f64,
    shp: f64,
    fb: [Basis; 3],
    hb: Basis,
}

impl SplineMaterial {
    /// The Neo-Hookean material of eq. 16 written as eq. 18 (eq. 19): f′(x) = μx and
    /// J h′(J) = −μ + λ(J² − 1)/2 at the given knots.
    pub fn neo_hookean(
        lambda: f64,
        mu: f64,
        stretch_knots: Vec<f64>,
        j_knots: Vec<f64>,
    ) -> Result<Self, MotionError> {
        Ok(Self {
            f: Spline::from_fn(stretch_knots, |x| mu * x)?,
            h: Spline::from_fn(j_knots, |j| -mu + 0.5 * lambda * (j * j - 1.0))?,
            slope_weight: None,
        })
    }

    /// Number of control values of `r`.
    pub fn len(&self, r: Response) -> usize {
        match r {
            Response::F => self.f.values.len(),
            Response::H => self.h.values.len(),
        }
    }

    /// Always false (a spline has ≥ 4 control points); for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Control value `i` of `r`.
    pub fn value(&self, r: Response, i: usize) -> f64 {
        match r {
            Response::F => self.f.values[i],
            Response::H => self.h.values[i],
        }
    }

    /// Sets control value `i` of `r`.
    pub fn set_value(&mut self, r: Response, i: usize, v: f64) {
        match r {
            Response::F => self.f.values[i] = v,
            Response::H => self.h.values[i] = v,
        }
    }

    /// Energy density Ψ (eq. 18) with f(1) = h(1) = 0; `None` when J ≤ 0.
    pub fn energy_density(&self, f: &Matrix3<f64>) -> Option<f64> {
        let j = f.determinant();
        if j.is_nan() || j <= 0.0 {
            return None;
        }
        let s = f.svd(false, false).singular_values;
        let uni: f64 = s.iter().map(|&x| self.f.integrate(1.0, x, |_| 1.0)).sum();
        Some(uni + self.h.integrate(1.0, j, |x| 1.0 / x))
    }

    /// SVD and stress coefficients of F; `None` when J ≤ 0 or the SVD fails.
    pub fn state(&self, f: &Matrix3<f64>) -> Option<StretchState> {
        let j = f.determinant();
        if j.is_nan() || j <= 0.0 {
            return None;
        }
        let svd = f.svd(true, true);
        let (u, vt) = (svd.u?, svd.v_t?);
        let s = svd.singular_values;
        if s.iter().any(|&x| x.is_nan() || x <= 0.0) {
            return None;
        }
        let j = s[0] * s[1] * s[2];
        let fb = [0, 1, 2].map(|i| self.f.basis(s[i]));
        let hb = self.h.basis(j);
        let mut fp = Vector3::zeros();
        let mut fpp = Vector3::zeros();
        for i in 0..3 {
            let (a, b) = fb[i].apply(&self.f.values);
            fp[i] = a;
            fpp[i] = b;
        }
        let (sh, shp) = hb.apply(&self.h.values);
        let psi = Vector3::from_fn(|i, _| fp[i] + sh / s[i]);
        Some(StretchState {
            u,
            v: vt.transpose(),
            s,
            j,
            psi,
            fp,
            fpp,
            sh,
            shp,
            fb,
            hb,
        })
    }

    /// First Piola–Kirchhoff stress P = U diag(ψ) Vᵀ.
    pub fn pk1(st: &StretchState) -> Matrix3<f64> {
        st.u * Matrix3::from_diagonal(&st.psi) * st.v.transpose()
    }

    /// f′ divided difference (f′(a) − f′(b))/(a − b), f″ at the midpoint when a ≈ b (error
    /// O((a − b)²·f⁗) ≤ 1e-12 relative at the switch-over).
    fn df_divided(&self, st: &StretchState, i: usize, k: usize) -> f64 {
        let (a, b) = (st.s[i], st.s[k]);
        if (a - b).abs() > 1e-6 * a.max(b) {
            (st.fp[i] - st.fp[k]) / (a - b)
        } else {
            self.f.eval(0.5 * (a + b)).1
        }
    }

    /// Directional derivative dP\[dF\] (rotated-frame form, see the module docs).
    pub fn dpk1(&self, st: &StretchState, df: &Matrix3<f64>) -> Matrix3<f64> {
        let s = &st.s;
        let dfh = st.u.transpose() * df * st.v;
        let mut dp = Matrix3::zeros();
        // A = ∂²Ψ/∂ς∂ς: Aᵢᵢ = f″(ςᵢ) + (S_h′ J − S_h)/ςᵢ², Aᵢⱼ = S_h′ J/(ςᵢςⱼ).
        for i in 0..3 {
            let mut acc = 0.0;
            for k in 0..3 {
                let a = if i == k {
                    st.fpp[i] + (st.shp * st.j - st.sh) / (s[i] * s[i])
                } else {
                    st.shp * st.j / (s[i] * s[k])
                };
                acc += a * dfh[(k, k)];
            }
            dp[(i, i)] = acc;
        }
        for i in 0..3 {
            for k in 0..3 {
                if i == k {
                    continue;
                }
                let diff = self.df_divided(st, i, k) - st.sh / (s[i] * s[k]);
                let sum = (st.psi[i] + st.psi[k]) / (s[i] + s[k]);
                let a = 0.5 * (diff + sum);
                let b = 0.5 * (diff - sum);
                dp[(i, k)] = a * dfh[(i, k)] + b * dfh[(k, i)];
            }
        }
        st.u * dp * st.v.transpose()
    }

    /// ∂P/∂c for every control value touching this element: calls `sink(response, index, ∂P/∂c)`.
    pub fn pk1_dcontrols(st: &StretchState, mut sink: impl FnMut(Response, usize, &Matrix3<f64>)) {
        let rot = |d: Vector3<f64>| st.u * Matrix3::from_diagonal(&d) * st.v.transpose();
        // f′(ςᵢ) enters ψᵢ only: collect per control index over the three stretches.
        let lo = st.fb.iter().map(|b| b.lo).min().unwrap_or(0);
        let hi = st.fb.iter().map(|b| b.lo + 4).max().unwrap_or(0);
        for c in lo..hi {
            let mut d = Vector3::zeros();
            for i in 0..3 {
                let b = &st.fb[i];
                if c >= b.lo && c < b.lo + 4 {
                    d[i] = b.w[c - b.lo];
                }
            }
            if d != Vector3::zeros() {
                sink(Response::F, c, &rot(d));
            }
        }
        // S_h(J)/ςᵢ enters every ψᵢ.
        for k in 0..4 {
            let w = st.hb.w[k];
            if w != 0.0 {
                let d = Vector3::from_fn(|i, _| w / st.s[i]);
                sink(Response::H, st.hb.lo + k, &rot(d));
            }
        }
    }

    /// Small-strain Lamé constants (λ_L, μ) of the rest tangent: μ = (f″(1) − h′(1))/2 and
    /// λ_L = h″(1) + h′(1) = S_h′(1) (exact for a stress-free rest state; Neo-Hookean gives back
    /// its λ and μ).
    pub fn lame_at_rest(&self) -> (f64, f64) {
        let (_, fpp) = self.f.eval(1.0);
        let (sh, shp) = self.h.eval(1.0);
        (shp, 0.5 * (fpp - sh))
    }

    /// Principal stress at F = I: ψ(1) = f′(1) + h′(1) (eq. 20). Neo-Hookean gives 0; a free fit
    /// can make it non-zero — the residual stress at rest the paper warns about (§4.2).
    pub fn rest_stress(&self) -> f64 {
        self.f.eval(1.0).0 + self.h.eval(1.0).0
    }

    /// Negative-slope penalty of §4.2: Σ over the sample points of both response functions of
    /// min(0, slope)², slopes being f″(x) and h″(J) = (S_h′(J) J − S_h(J))/J²; `grad` receives
    /// ∂/∂c (F controls first, then H controls).
    pub fn slope_penalty(&self, grad: &mut [f64]) -> f64 {
        let nf = self.f.values.len();
        let mut r = 0.0;
        for x in self.f.samples() {
            let b = self.f.basis(x);
            let (_, d) = b.apply(&self.f.values);
            if d < 0.0 {
                r += d * d;
                for k in 0..4 {
                    grad[b.lo + k] += 2.0 * d * b.dw[k];
                }
            }
        }
        for x in self.h.samples() {
            let b = self.h.basis(x);
            let (s, d) = b.apply(&self.h.values);
            let slope = (d * x - s) / (x * x);
            if slope < 0.0 {
                r += slope * slope;
                for k in 0..4 {
                    grad[nf + b.lo + k] += 2.0 * slope * (b.dw[k] * x - b.w[k]) / (x * x);
                }
            }
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Quadratics are reproduced exactly (the property the Neo-Hookean initialisation rests on),
    /// on non-uniform knots, inside and — linearly continued — at the ends.
    #[test]
    fn spline_reproduces_quadratics_and_slopes() {
        let knots = vec![0.4, 0.55, 0.8, 1.0, 1.3, 1.7, 2.2];
        let g = |x: f64| 3.0 - 2.0 * x + 1.5 * x * x;
        let s = Spline::from_fn(knots, g).unwrap();
        for i in 0..=100 {
            let x = 0.4 + 1.8 * i as f64 / 100.0;
            let (v, d) = s.eval(x);
            assert!((v - g(x)).abs() < 1e-13, "x {x}: {v} vs {}", g(x));
            assert!((d - (-2.0 + 3.0 * x)).abs() < 1e-12, "slope at {x}");
        }
        let (v, _) = s.eval(2.5);
        assert!((v - (g(2.2) + 0.3 * (-2.0 + 3.0 * 2.2))).abs() < 1e-12);
        // ∫ from 1 to 2 of the quadratic, and the integral over the extrapolated part.
        let exact = |a: f64, b: f64| {
            let p = |x: f64| 3.0 * x - x * x + 0.5 * x * x * x;
            p(b) - p(a)
        };
        assert!((s.integrate(1.0, 2.0, |_| 1.0) - exact(1.0, 2.0)).abs() < 1e-13);
        assert!((s.integrate(1.0, 0.45, |_| 1.0) - exact(1.0, 0.45)).abs() < 1e-13);
    }
}

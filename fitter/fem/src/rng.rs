//! The offline tools' seeded random generators, in one place: no dependency, the same numbers on
//! every machine, and every stream fixed by its seed (tests and committed results depend on them,
//! so the arithmetic here must not change).
//!
//! - [`SplitMix64`] with Box–Muller normals (one per pair of uniforms): synthetic static datasets
//!   (`palpate-static-fit`), specimens and the diagnosis noise studies (`palpate-specimen`, which
//!   seeds it with `seed ^ 0x5EED_0006_D1A6_0005`).
//! - [`XorShift64Star`] and [`Gauss`] (xorshift64* with Box–Muller normals that keep the spare
//!   sine sample): motion recordings (`palpate-motion`) and the link's fault injector.
//! - [`XorShift64`] (13/7/17 shifts): the curve-diagnosis tests' noise.
//!
//! The probe firmware keeps its own tiny `no_std` generator (`firmware/probe/src/sim.rs`).

use std::f64::consts::TAU;

/// 2⁵³, the number of distinct uniforms a 53-bit mantissa holds.
const TWO_53: f64 = (1u64 << 53) as f64;

/// SplitMix64 (Steele, Lea & Flood 2014): the state is the seed as given.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// Seeded generator (the state starts at `seed`).
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / TWO_53
    }
    /// Standard normal sample (Box–Muller, cosine branch; two uniforms per sample).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
    }
}

/// The study stream: [`SplitMix64`] seeded with `seed ^ 0x5EED_0006_D1A6_0005`, so it stays fixed
/// whatever other modules do with theirs. The specimens draw their noise from it and the
/// diagnosis its bootstrap resamples; committed results depend on both.
pub fn study_stream(seed: u64) -> SplitMix64 {
    SplitMix64::new(seed ^ 0x5EED_0006_D1A6_0005)
}

/// xorshift64* (Vigna 2016). The state must not be zero; callers pick how they avoid it.
#[derive(Debug, Clone)]
pub struct XorShift64Star(u64);

impl XorShift64Star {
    /// Generator with state `seed` (must be non-zero).
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / TWO_53
    }
    /// Uniform in (0, 1): the midpoint of one of 2⁵³ cells, never 0 (safe under `ln`).
    pub fn uniform_open(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / TWO_53
    }
}

/// Standard normals from xorshift64* by Box–Muller, both branches used (the sine sample is kept
/// for the next call).
#[derive(Debug, Clone)]
pub struct Gauss {
    rng: XorShift64Star,
    spare: Option<f64>,
}

impl Gauss {
    /// Seeds the generator (0 is replaced by a fixed constant).
    pub fn new(seed: u64) -> Self {
        Self {
            rng: XorShift64Star::new(if seed == 0 {
                0x9E37_79B9_7F4A_7C15
            } else {
                seed
            }),
            spare: None,
        }
    }
    /// Next N(0, 1) sample.
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> f64 {
        if let Some(s) = self.spare.take() {
            return s;
        }
        let (u, v) = (self.rng.uniform_open(), self.rng.uniform_open());
        let r = (-2.0 * u.ln()).sqrt();
        let th = 2.0 * std::f64::consts::PI * v;
        self.spare = Some(r * th.sin());
        r * th.cos()
    }
}

/// Marsaglia's xorshift64 (13, 7, 17) with open uniforms and cosine-branch Box–Muller normals.
#[derive(Debug, Clone)]
pub struct XorShift64(u64);

impl XorShift64 {
    /// Generator with state `seed` (must be non-zero).
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }
    /// Uniform in (0, 1) (cell midpoints, never 0).
    pub fn uniform_open(&mut self) -> f64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        ((self.0 >> 11) as f64 + 0.5) / TWO_53
    }
    /// Standard normal sample (two uniforms per sample).
    pub fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform_open(), self.uniform_open());
        (-2.0 * a.ln()).sqrt() * (TAU * b).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first outputs of SplitMix64 from state 0 (the reference implementation's values).
    #[test]
    fn splitmix_reference_values() {
        let mut r = SplitMix64::new(0);
        assert_eq!(r.next_u64(), 0xE220_A839_7B1D_CDAF);
        assert_eq!(r.next_u64(), 0x6E78_9E6A_A1B9_65F4);
    }

    #[test]
    fn uniforms_in_range() {
        let mut a = SplitMix64::new(7);
        let mut b = XorShift64Star::new(7);
        let mut c = XorShift64::new(7);
        for _ in 0..1000 {
            assert!((0.0..1.0).contains(&a.uniform()));
            assert!((0.0..1.0).contains(&b.uniform()));
            let u = c.uniform_open();
            assert!(u > 0.0 && u < 1.0);
        }
    }
}

//! Summary statistics of latencies and rates.

/// Order statistics of a sample of durations in µs.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Percentiles {
    /// Number of values.
    pub n: usize,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
    /// Mean.
    pub mean: f64,
}

impl Percentiles {
    /// Nearest-rank percentiles of `v` (sorted in place); all zeros when empty.
    pub fn of(v: &mut [f64]) -> Self {
        if v.is_empty() {
            return Self {
                n: 0,
                p50: 0.0,
                p99: 0.0,
                max: 0.0,
                mean: 0.0,
            };
        }
        v.sort_by(f64::total_cmp);
        let rank = |p: f64| v[((p * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Self {
            n: v.len(),
            p50: rank(0.50),
            p99: rank(0.99),
            max: v[v.len() - 1],
            mean: v.iter().sum::<f64>() / v.len() as f64,
        }
    }
}

/// CPU time (user + system) of the calling thread, in seconds, from `/proc/thread-self/stat`
/// (clock ticks of 10 ms); `None` where that file does not exist.
pub fn thread_cpu_seconds() -> Option<f64> {
    cpu_from_stat("/proc/thread-self/stat")
}

/// CPU time (user + system) of the whole process, in seconds.
pub fn process_cpu_seconds() -> Option<f64> {
    cpu_from_stat("/proc/self/stat")
}

fn cpu_from_stat(path: &str) -> Option<f64> {
    let s = std::fs::read_to_string(path).ok()?;
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let mut v: Vec<f64> = (1..=200).map(f64::from).collect();
        let p = Percentiles::of(&mut v);
        assert_eq!(
            (p.n, p.p50, p.p99, p.max, p.mean),
            (200, 100.0, 198.0, 200.0, 100.5)
        );
        assert!(process_cpu_seconds().is_some());
    }
}

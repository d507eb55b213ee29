//! Summaries of repeated timings.

use serde::Serialize;

/// Median, extremes and tail of a set of timings, in milliseconds.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Summary {
    /// Samples summarised.
    pub samples: usize,
    /// Median (nearest rank).
    pub median_ms: f64,
    /// 99th percentile (nearest rank; the maximum below 100 samples).
    pub p99_ms: f64,
    /// Smallest.
    pub min_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

impl Summary {
    /// Summarises `seconds`; `None` when empty.
    pub fn of_seconds(seconds: &[f64]) -> Option<Self> {
        let mut ms: Vec<f64> = seconds.iter().map(|s| s * 1e3).collect();
        ms.sort_by(f64::total_cmp);
        let (&min_ms, &max_ms) = (ms.first()?, ms.last()?);
        Some(Self {
            samples: ms.len(),
            median_ms: percentile(&ms, 0.5),
            p99_ms: percentile(&ms, 0.99),
            min_ms,
            max_ms,
        })
    }
}

/// Nearest-rank percentile of sorted, non-empty `sorted`.
fn percentile(sorted: &[f64], p: f64) -> f64 {
    let rank = (p * sorted.len() as f64).ceil() as usize;
    sorted[rank.clamp(1, sorted.len()) - 1]
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]
    use super::*;

    #[test]
    fn nearest_rank_percentiles() {
        let s = Summary::of_seconds(&[0.004, 0.001, 0.003, 0.002]).unwrap();
        assert_eq!(s.median_ms, 2.0);
        assert_eq!(s.p99_ms, 4.0);
        assert_eq!((s.min_ms, s.max_ms), (1.0, 4.0));
        assert!(Summary::of_seconds(&[]).is_none());
    }
}

//! A fixed-bucket latency histogram: log-spaced buckets, constant memory, O(1) record.

use std::time::Duration;

/// Buckets per decade: adjacent bucket bounds differ by 10^(1/20) ≈ 12.2 %, so a reported
/// percentile (the upper bound of its bucket) overstates the true value by at most 12.2 %.
pub const BUCKETS_PER_DECADE: usize = 20;
/// Smallest bucket bound, s (1 µs); faster samples fall in the first bucket.
pub const MIN_S: f64 = 1e-6;
/// Decades covered: 1 µs to 10 s; slower samples fall in the last bucket (the max is exact).
pub const DECADES: usize = 7;
const BUCKETS: usize = BUCKETS_PER_DECADE * DECADES;

/// Percentiles of a histogram, seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatencySummary {
    /// Samples recorded.
    pub count: u64,
    /// Median (bucket upper bound), s.
    pub p50_s: f64,
    /// 99th percentile (bucket upper bound), s.
    pub p99_s: f64,
    /// Exact maximum, s.
    pub max_s: f64,
}

impl LatencySummary {
    /// The summary of an empty histogram: NaN figures.
    pub const EMPTY: Self = Self {
        count: 0,
        p50_s: f64::NAN,
        p99_s: f64::NAN,
        max_s: f64::NAN,
    };
}

/// Log-spaced latency histogram.
#[derive(Debug, Clone)]
pub struct LatencyHistogram {
    counts: [u64; BUCKETS],
    count: u64,
    max_s: f64,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        Self {
            counts: [0; BUCKETS],
            count: 0,
            max_s: 0.0,
        }
    }
}

/// Upper bound of bucket `i`, s.
fn upper_bound_s(i: usize) -> f64 {
    MIN_S * 10f64.powf((i + 1) as f64 / BUCKETS_PER_DECADE as f64)
}

impl LatencyHistogram {
    /// Records one latency.
    pub fn record(&mut self, latency: Duration) {
        let s = latency.as_secs_f64();
        let i = if s <= MIN_S {
            0
        } else {
            // Bucket i holds (upper(i-1), upper(i)].
            let x = (s / MIN_S).log10() * BUCKETS_PER_DECADE as f64;
            (x.ceil() as usize).saturating_sub(1).min(BUCKETS - 1)
        };
        self.counts[i] += 1;
        self.count += 1;
        self.max_s = self.max_s.max(s);
    }

    /// Samples recorded.
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Upper bound of the bucket holding the `q`-quantile (q in (0, 1]), never above the max.
    pub fn quantile_s(&self, q: f64) -> f64 {
        if self.count == 0 {
            return f64::NAN;
        }
        let rank = ((q * self.count as f64).ceil() as u64).clamp(1, self.count);
        let mut seen = 0;
        for (i, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return upper_bound_s(i).min(self.max_s);
            }
        }
        self.max_s
    }

    /// p50, p99 and max.
    pub fn summary(&self) -> LatencySummary {
        if self.count == 0 {
            return LatencySummary::EMPTY;
        }
        LatencySummary {
            count: self.count,
            p50_s: self.quantile_s(0.50),
            p99_s: self.quantile_s(0.99),
            max_s: self.max_s,
        }
    }

    /// Forgets every sample.
    pub fn clear(&mut self) {
        *self = Self::default();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Relative width of one bucket: the resolution a reported quantile is accurate to.
    const RESOLUTION: f64 = 0.1221; // 10^(1/20) - 1

    fn exact_quantile(sorted: &[f64], q: f64) -> f64 {
        let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
        sorted[rank - 1]
    }

    #[test]
    fn empty_histogram_reports_nan() {
        let s = LatencyHistogram::default().summary();
        assert_eq!(s.count, 0);
        assert!(s.p50_s.is_nan() && s.p99_s.is_nan() && s.max_s.is_nan());
    }

    #[test]
    fn quantiles_are_within_one_bucket_above_the_exact_value() {
        // Log-uniform latencies from 20 µs to 20 ms, a deterministic sequence.
        let mut values: Vec<f64> = (0..10_000)
            .map(|i| 20e-6 * 1000f64.powf(((i * 7919) % 10_000) as f64 / 10_000.0))
            .collect();
        let mut h = LatencyHistogram::default();
        for v in &values {
            h.record(Duration::from_secs_f64(*v));
        }
        values.sort_by(f64::total_cmp);
        for q in [0.01, 0.5, 0.9, 0.99, 0.999] {
            let exact = exact_quantile(&values, q);
            let got = h.quantile_s(q);
            assert!(got >= exact * (1.0 - 1e-9), "q={q}: {got} < exact {exact}");
            assert!(
                got <= exact * (1.0 + RESOLUTION),
                "q={q}: {got} > exact {exact} + one bucket"
            );
        }
        let s = h.summary();
        assert_eq!(s.count, 10_000);
        assert!((s.max_s - values[values.len() - 1]).abs() < 1e-9);
    }

    #[test]
    fn constant_latency_reports_that_latency() {
        let mut h = LatencyHistogram::default();
        for _ in 0..100 {
            h.record(Duration::from_micros(500));
        }
        let s = h.summary();
        // Bounded by the exact max, so a constant is reported exactly.
        assert!((s.p50_s - 500e-6).abs() < 1e-12 && (s.p99_s - 500e-6).abs() < 1e-12);
    }

    #[test]
    fn extremes_land_in_the_end_buckets_and_max_stays_exact() {
        let mut h = LatencyHistogram::default();
        h.record(Duration::ZERO);
        h.record(Duration::from_secs(100));
        assert_eq!(h.count(), 2);
        assert!(h.quantile_s(0.5) <= MIN_S * 1.13);
        assert_eq!(h.summary().max_s, 100.0);
        h.clear();
        assert_eq!(h.count(), 0);
    }
}

//! The chi-square distribution, for Mahalanobis gates and consistency checks: the regularised
//! lower incomplete gamma function by its power series (exact to rounding for the small degrees
//! of freedom used here), and the quantile by bisection. Also the nearest-rank summary of
//! durations that the replay and the node report, and the RMS/median/p95 summary of errors that
//! every accuracy report uses.

/// Mean and nearest-rank quantiles of a set of durations [ns].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DurationSummary {
    /// How many durations.
    pub count: usize,
    /// Mean [ns].
    pub mean: f64,
    /// Median [ns].
    pub p50: f64,
    /// 99th percentile [ns].
    pub p99: f64,
    /// Largest [ns].
    pub max: f64,
    /// Sum [ns].
    pub total: f64,
}

impl DurationSummary {
    /// Summarises `durations` (sorting them in place); all zero when empty.
    pub fn of(durations: &mut [u64]) -> Self {
        durations.sort_unstable();
        let Some(&max) = durations.last() else {
            return Self::default();
        };
        let total: f64 = durations.iter().map(|d| *d as f64).sum();
        let rank = |q: f64| nearest_rank(durations, q).unwrap_or(0) as f64;
        Self {
            count: durations.len(),
            mean: total / durations.len() as f64,
            p50: rank(0.5),
            p99: rank(0.99),
            max: max as f64,
            total,
        }
    }
}

/// Durations [ns] in an HDR histogram, for runs of any length in constant memory: from 1 ns to
/// an hour, each quantile within 0.1 % of the sample's (three significant digits, the upper edge
/// of its bucket, nearest rank), a longer duration counted at an hour; the mean, total and
/// largest exact.
#[cfg(feature = "bag")]
#[derive(Debug, Clone)]
pub struct DurationHistogram {
    histogram: hdrhistogram::Histogram<u64>,
    total: f64,
    max: u64,
}

/// The longest duration told apart [ns]: an hour.
#[cfg(feature = "bag")]
const LONGEST_NS: u64 = 3_600_000_000_000;

#[cfg(feature = "bag")]
impl Default for DurationHistogram {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(feature = "bag")]
impl PartialEq for DurationHistogram {
    fn eq(&self, other: &Self) -> bool {
        self.histogram == other.histogram && self.total == other.total && self.max == other.max
    }
}

#[cfg(feature = "bag")]
impl DurationHistogram {
    /// An empty histogram (its buckets are allocated here, once).
    #[expect(
        clippy::expect_used,
        reason = "constant bounds hdrhistogram accepts: low 1 >= 1, high >= 2 low, 3 digits <= 5"
    )]
    pub fn new() -> Self {
        let histogram = hdrhistogram::Histogram::new_with_bounds(1, LONGEST_NS, 3)
            .expect("valid constant bounds");
        Self {
            histogram,
            total: 0.0,
            max: 0,
        }
    }

    /// Adds one duration [ns].
    pub fn record(&mut self, ns: u64) {
        self.histogram.saturating_record(ns);
        self.total += ns as f64;
        self.max = self.max.max(ns);
    }

    /// The nearest-rank quantile `q` in [0, 1] [ns] (0 when empty).
    pub fn quantile(&self, q: f64) -> f64 {
        if self.histogram.is_empty() {
            return 0.0;
        }
        self.histogram
            .value_at_quantile(q.clamp(0.0, 1.0))
            .min(self.max) as f64
    }

    /// Count, mean, median, 99th percentile, largest and total.
    pub fn summary(&self) -> DurationSummary {
        let count = self.histogram.len();
        if count == 0 {
            return DurationSummary::default();
        }
        DurationSummary {
            count: count as usize,
            mean: self.total / count as f64,
            p50: self.quantile(0.5),
            p99: self.quantile(0.99),
            max: self.max as f64,
            total: self.total,
        }
    }
}

/// Gamma(a) for a positive integer or half-integer `a`.
fn gamma_half_integer(a: f64) -> f64 {
    let (mut value, mut x) = if (a - a.floor()) > 0.25 {
        (std::f64::consts::PI.sqrt(), 0.5)
    } else {
        (1.0, 1.0)
    };
    while x < a - 0.25 {
        value *= x;
        x += 1.0;
    }
    value
}

/// P(X <= x) for X chi-square distributed with `dof` degrees of freedom (1 to 60).
pub fn chi_square_cdf(x: f64, dof: u32) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    if x <= 0.0 {
        return 0.0;
    }
    let a = 0.5 * f64::from(dof);
    let half_x = 0.5 * x;
    // P(a, y) = y^a e^-y / Gamma(a + 1) * sum_n y^n / ((a+1)...(a+n)).
    let mut term = 1.0;
    let mut sum = 1.0;
    let mut n = 1.0;
    while term > sum * 1e-17 && n < 10_000.0 {
        term *= half_x / (a + n);
        sum += term;
        n += 1.0;
    }
    let log_prefix = a * half_x.ln() - half_x - gamma_half_integer(a + 1.0).ln();
    (log_prefix.exp() * sum).min(1.0)
}

/// P(Z <= x) for a standard normal Z (from the chi-square distribution of Z^2 with 1 degree
/// of freedom; accurate to a few 1e-16 absolute, so tail probabilities to about 1e-12).
pub fn normal_cdf(x: f64) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    let tail = 0.5 * (1.0 - chi_square_cdf(x * x, 1));
    if x < 0.0 { tail } else { 1.0 - tail }
}

/// The `probability` quantile of the chi-square distribution with `dof` degrees of freedom.
pub fn chi_square_quantile(probability: f64, dof: u32) -> f64 {
    let p = probability.clamp(0.0, 1.0 - 1e-15);
    let (mut lo, mut hi) = (0.0, f64::from(dof).max(1.0));
    while chi_square_cdf(hi, dof) < p {
        hi *= 2.0;
    }
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if chi_square_cdf(mid, dof) < p {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-12 * hi {
            break;
        }
    }
    0.5 * (lo + hi)
}

/// The value at quantile `q` (0 to 1) of `sorted` by the nearest rank, round((n - 1) q); `None`
/// when it is empty.
pub fn nearest_rank<T: Copy>(sorted: &[T], q: f64) -> Option<T> {
    let last = sorted.len().checked_sub(1)?;
    sorted
        .get((last as f64 * q.clamp(0.0, 1.0)).round() as usize)
        .copied()
}

/// Root mean square, median and count of a set of errors.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct ErrorStats {
    /// Number of values.
    pub count: usize,
    /// Root mean square.
    pub rms: f64,
    /// Median of the absolute values.
    pub median: f64,
    /// 95th percentile of the absolute values.
    pub p95: f64,
}

impl ErrorStats {
    /// The statistics of `values` (absolute values for the median and percentile).
    pub fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        let mut sorted: Vec<f64> = values.iter().map(|v| v.abs()).collect();
        sorted.sort_by(f64::total_cmp);
        let at = |q: f64| nearest_rank(&sorted, q).unwrap_or(0.0);
        Self {
            count: values.len(),
            rms: (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt(),
            median: at(0.5),
            p95: at(0.95),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// Standard normal probabilities from tables: Phi(0) = 0.5, Phi(1) = 0.841345,
    /// Phi(-1.96) = 0.024998, Phi(-3) = 0.0013499.
    #[test]
    fn normal_cdf_matches_tables() {
        assert_relative_eq!(normal_cdf(0.0), 0.5, epsilon = 1e-12);
        assert_relative_eq!(normal_cdf(1.0), 0.841_344_746, epsilon = 1e-8);
        assert_relative_eq!(normal_cdf(-1.96), 0.024_997_895, epsilon = 1e-8);
        assert_relative_eq!(normal_cdf(-3.0), 0.001_349_898, epsilon = 1e-8);
        assert_relative_eq!(normal_cdf(2.5) + normal_cdf(-2.5), 1.0, epsilon = 1e-12);
    }

    /// The histogram's quantiles are the sorted sample's to 0.1 %, from nanoseconds to
    /// seconds; mean, total and maximum exact.
    #[cfg(feature = "bag")]
    #[test]
    fn duration_histogram_matches_the_sorted_sample() {
        // Log-uniform from 5 ns to 2 s, and one beyond what a fixed-bin histogram would keep.
        let mut sample: Vec<u64> = (0..20_000u64)
            .map(|i| (5.0 * (4e8f64).powf(((i * 7919) % 20_000) as f64 / 20_000.0)) as u64)
            .collect();
        sample.push(20_000_000);
        let mut histogram = DurationHistogram::new();
        for &ns in &sample {
            histogram.record(ns);
        }
        let exact = DurationSummary::of(&mut sample);
        let binned = histogram.summary();
        assert_eq!(binned.count, exact.count);
        assert_relative_eq!(binned.mean, exact.mean);
        assert_eq!(binned.max, exact.max);
        // Every percentile within 0.1 % of the sorted sample's (at the rank or its neighbour:
        // nearest-rank rules differ by one).
        for percent in 1..100 {
            let q = f64::from(percent) / 100.0;
            let rank = ((sample.len() - 1) as f64 * q).round() as usize;
            let low = sample[rank.saturating_sub(1)] as f64 * (1.0 - 1e-3);
            let high = sample[(rank + 1).min(sample.len() - 1)] as f64 * (1.0 + 1e-3) + 1.0;
            let value = histogram.quantile(q);
            assert!(
                (low..=high).contains(&value),
                "p{percent}: {value} not in {low}..{high}"
            );
        }
        let mut small = DurationHistogram::new();
        for ns in [100, 200, 300] {
            small.record(ns);
        }
        assert_eq!(small.quantile(0.5), 200.0);
        assert_eq!(
            DurationHistogram::new().summary(),
            DurationSummary::default()
        );
    }

    /// Reference quantiles from standard chi-square tables.
    #[test]
    fn quantiles_match_tables() {
        assert_relative_eq!(chi_square_quantile(0.95, 1), 3.841459, epsilon = 1e-5);
        assert_relative_eq!(chi_square_quantile(0.95, 3), 7.814728, epsilon = 1e-5);
        assert_relative_eq!(chi_square_quantile(0.99, 3), 11.344867, epsilon = 1e-5);
        assert_relative_eq!(chi_square_quantile(0.9973, 3), 14.1564, epsilon = 1e-3);
        assert_relative_eq!(chi_square_quantile(0.99, 6), 16.811894, epsilon = 1e-5);
        assert_relative_eq!(chi_square_quantile(0.5, 9), 8.342833, epsilon = 1e-5);
    }

    #[test]
    fn cdf_of_two_dof_is_exponential() {
        for x in [0.1, 1.0, 5.0, 20.0] {
            assert_relative_eq!(
                chi_square_cdf(x, 2),
                1.0 - (-x / 2.0_f64).exp(),
                epsilon = 1e-14
            );
        }
        assert_eq!(chi_square_cdf(-1.0, 3), 0.0);
    }
}

//! The chi-square distribution, for Mahalanobis gates and consistency checks: the regularised
//! lower incomplete gamma function by its power series (exact to rounding for the small degrees
//! of freedom used here), and the quantile by bisection. Also the nearest-rank summary of
//! durations that the replay and the node report.

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
        let rank = |q: f64| durations[((durations.len() - 1) as f64 * q).round() as usize] as f64;
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

/// Durations [ns] in fixed bins, for runs of any length in constant memory: 10 ns bins up to
/// 100 us, 1 us bins up to 10 ms, and the largest kept exactly. Quantiles are the upper edge of
/// their bin (nearest rank), so within 10 ns below 100 us; the mean and total are exact.
#[derive(Debug, Clone, PartialEq)]
pub struct DurationHistogram {
    fine: Vec<u64>,
    coarse: Vec<u64>,
    beyond: u64,
    count: u64,
    total: f64,
    max: u64,
}

const FINE_NS: u64 = 10;
const FINE_BINS: usize = 10_000;
const COARSE_NS: u64 = 1_000;
const COARSE_BINS: usize = 9_900;

impl Default for DurationHistogram {
    fn default() -> Self {
        Self::new()
    }
}

impl DurationHistogram {
    /// An empty histogram (its bins are allocated here, once).
    pub fn new() -> Self {
        Self {
            fine: vec![0; FINE_BINS],
            coarse: vec![0; COARSE_BINS],
            beyond: 0,
            count: 0,
            total: 0.0,
            max: 0,
        }
    }

    /// Adds one duration [ns].
    pub fn record(&mut self, ns: u64) {
        let fine_end = FINE_NS * FINE_BINS as u64;
        if ns < fine_end {
            self.fine[(ns / FINE_NS) as usize] += 1;
        } else if let Some(bin) = self.coarse.get_mut(((ns - fine_end) / COARSE_NS) as usize) {
            *bin += 1;
        } else {
            self.beyond += 1;
        }
        self.count += 1;
        self.total += ns as f64;
        self.max = self.max.max(ns);
    }

    /// The nearest-rank quantile `q` in [0, 1] [ns] (0 when empty).
    pub fn quantile(&self, q: f64) -> f64 {
        if self.count == 0 {
            return 0.0;
        }
        let rank = ((self.count - 1) as f64 * q.clamp(0.0, 1.0)).round() as u64;
        let mut seen = 0u64;
        let fine_end = FINE_NS * FINE_BINS as u64;
        let edges = (0..FINE_BINS)
            .map(|i| (self.fine[i], (i as u64 + 1) * FINE_NS))
            .chain(
                (0..COARSE_BINS).map(|i| (self.coarse[i], fine_end + (i as u64 + 1) * COARSE_NS)),
            );
        for (count, upper) in edges {
            seen += count;
            if seen > rank {
                return upper.min(self.max) as f64;
            }
        }
        self.max as f64
    }

    /// Count, mean, median, 99th percentile, largest and total.
    pub fn summary(&self) -> DurationSummary {
        if self.count == 0 {
            return DurationSummary::default();
        }
        DurationSummary {
            count: self.count as usize,
            mean: self.total / self.count as f64,
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

    /// The histogram's quantiles are the sorted sample's, to its 10 ns bins (1 us above 100 us);
    /// mean, total and maximum exact; beyond 10 ms only the maximum is kept.
    #[test]
    fn duration_histogram_matches_the_sorted_sample() {
        let mut histogram = DurationHistogram::new();
        let mut sample: Vec<u64> = (0..10_000u64).map(|i| (i * 7919) % 150_000 + 5).collect();
        sample.push(20_000_000);
        for &ns in &sample {
            histogram.record(ns);
        }
        let exact = DurationSummary::of(&mut sample);
        let binned = histogram.summary();
        assert_eq!(binned.count, exact.count);
        assert_relative_eq!(binned.mean, exact.mean);
        assert_eq!(binned.max, exact.max);
        assert!(
            (binned.p50 - exact.p50).abs() <= 1_000.0,
            "{binned:?} {exact:?}"
        );
        assert!(binned.p50 >= exact.p50 && binned.p99 >= exact.p99);
        assert!(
            (binned.p99 - exact.p99).abs() <= 1_000.0,
            "{binned:?} {exact:?}"
        );
        let mut small = DurationHistogram::new();
        for ns in [100, 200, 300] {
            small.record(ns);
        }
        assert_eq!(small.quantile(0.5), 210.0);
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

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

//! What an estimator learned ([`LearnedSummary`]), in words and as a configuration to start the
//! next one from: the physical parameters it learned over its tracks in place of the configured
//! ones (`aero.drag_scale`, `aero.magnus_scale`, `table.restitution`, `table.friction`), and
//! each camera's noise it learned in place of the source's configured sigmas (`sources.*`). A
//! node or replay started from it begins where this one ended, with the configured priors'
//! widths around the new values (the learning goes on from there; a new ball or table is still
//! learned as quickly).

use crate::config::Config;
#[cfg(feature = "interface")]
use crate::config::ConfigError;
use crate::online::ekf::ParamCovariance;
use crate::online::estimator::{PRIOR_WEIGHT, SourceNoiseEstimate};
use crate::physics::{PARAMS, ParamVector, PhysicsParams};

/// What the estimator has learned of one source's noise ([`Estimator::learned_noise`](crate::online::estimator::Estimator::learned_noise)).
#[derive(Debug, Clone, PartialEq)]
pub struct LearnedSourceNoise {
    /// The source's configuration key (`sources.*`).
    pub source: String,
    /// Its position sigma [m]: the configured one times the learned scale's square root.
    pub position_sigma: f64,
    /// The sigma of its stamps' timing [s].
    pub stamp_sigma: f64,
    /// The estimate behind them.
    pub estimate: SourceNoiseEstimate,
}

impl LearnedSourceNoise {
    /// Whether its detections have taught anything yet (beyond the configured prior's weight).
    pub fn has_learned(&self) -> bool {
        self.estimate.weight > PRIOR_WEIGHT
    }

    /// Whether its spins have taught anything yet.
    pub fn has_learned_spin(&self) -> bool {
        self.estimate.spin_weight > PRIOR_WEIGHT
    }
}

/// The physical parameters the estimator has learned ([`Estimator::learned_params`](crate::online::estimator::Estimator::learned_params)).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnedParams {
    /// The estimate (of the live track, else as the last track left it).
    pub params: PhysicsParams,
    /// Standard deviation of each parameter, in the order of [`PhysicsParams::NAMES`] [-].
    pub sigma: [f64; PARAMS],
    /// Tracks that have contributed, the live one included.
    pub tracks: u64,
    /// How much each parameter scatters from flight to flight about these [-] (the configured
    /// dispersion's standard deviation; zero for a single flight's own parameters).
    pub flight_sigma: [f64; PARAMS],
    /// The Reynolds exponents (a_D, a_M) [-] (`aero.reynolds_exponents`).
    pub reynolds_exponents: [f64; 2],
    /// Their standard deviations [-].
    pub reynolds_sigma: [f64; 2],
    /// Their prior standard deviations [-] (`adaptation.reynolds_sigma`; 0: not learned).
    pub reynolds_prior_sigma: [f64; 2],
}

/// The Reynolds exponents' names as reported, in the order of
/// [`LearnedParams::reynolds_exponents`].
pub const REYNOLDS_EXPONENT_NAMES: [&str; 2] = ["a_D", "a_M"];

/// An exponent is determined by the flights once its sigma is below this share of its prior's
/// (the flights' speeds have told it apart from the scale).
pub const DETERMINED_SHARE: f64 = 0.8;

/// Whether flights have determined an exponent of standard deviation `sigma` and prior standard
/// deviation `prior_sigma`: learned (a prior sigma above zero) and its sigma below
/// [`DETERMINED_SHARE`] of the prior's.
pub(crate) fn exponent_determined(sigma: f64, prior_sigma: f64) -> bool {
    prior_sigma > 0.0 && sigma < DETERMINED_SHARE * prior_sigma
}

impl LearnedParams {
    /// Parameters `theta` of covariance `covariance`, learned over `tracks` tracks, with a
    /// flight-to-flight dispersion of variances `dispersion`.
    pub(crate) fn new(
        theta: &ParamVector,
        covariance: &ParamCovariance,
        tracks: u64,
        dispersion: &ParamVector,
    ) -> Self {
        Self {
            params: PhysicsParams::from_vector(theta),
            sigma: std::array::from_fn(|i| covariance[(i, i)].max(0.0).sqrt()),
            tracks,
            flight_sigma: std::array::from_fn(|i| dispersion[i].max(0.0).sqrt()),
            reynolds_exponents: [0.0; 2],
            reynolds_sigma: [0.0; 2],
            reynolds_prior_sigma: [0.0; 2],
        }
    }

    /// The same with the Reynolds exponents `exponents`, of standard deviations `sigma` and
    /// prior standard deviations `prior_sigma`.
    pub(crate) fn with_reynolds(
        self,
        exponents: [f64; 2],
        (sigma, prior_sigma): ([f64; 2], [f64; 2]),
    ) -> Self {
        Self {
            reynolds_exponents: exponents,
            reynolds_sigma: sigma,
            reynolds_prior_sigma: prior_sigma,
            ..self
        }
    }

    /// Sets `config`'s ball and table parameters and Reynolds exponents to these.
    pub fn apply_to(&self, config: &mut Config) {
        self.params.apply_to(config);
        config.aero.reynolds_exponents = self.reynolds_exponents.to_vec();
    }

    /// Whether the flights have determined each Reynolds exponent (its sigma below
    /// [`DETERMINED_SHARE`] of its prior's); one not learned is not.
    pub fn reynolds_determined(&self) -> [bool; 2] {
        std::array::from_fn(|i| {
            exponent_determined(self.reynolds_sigma[i], self.reynolds_prior_sigma[i])
        })
    }
}

/// Everything an estimator has learned, as it stands.
#[derive(Debug, Clone, PartialEq)]
pub struct LearnedSummary {
    /// The ball's and table's physics.
    pub params: LearnedParams,
    /// Each camera source's noise, in the order of the configuration's sources.
    pub source_noise: Vec<LearnedSourceNoise>,
}

impl LearnedSummary {
    /// `base` with what was learned in place of the configured values (see the module doc). A
    /// source that has learned nothing beyond its prior keeps its configured noise.
    pub fn configuration(&self, base: &Config) -> Config {
        let mut config = base.clone();
        self.params.apply_to(&mut config);
        for learned in self.source_noise.iter().filter(|n| n.has_learned()) {
            let Some(source) = config.sources.by_name_mut(&learned.source) else {
                continue;
            };
            source.position_sigma = learned.position_sigma;
            source.stamp_sigma = learned.stamp_sigma;
            if learned.has_learned_spin() {
                source.spin_sigma *= learned.estimate.spin_scale.sqrt();
            }
        }
        config
    }

    /// What was learned, a line each: the physics, the cameras' noise (where learned).
    pub fn lines(&self) -> Vec<String> {
        let mut lines = vec![describe_params(&self.params)];
        lines.extend(describe_source_noise(&self.source_noise));
        lines
    }

    /// The learned configuration as a ROS 2 parameters file headed by comments (who wrote it,
    /// `written_by`, and [`Self::lines`]): the values of [`Self::configuration`] of `running`
    /// (the configuration the estimator ran with) that differ from `base` (the user's own: the
    /// one it was started with, without any learned file among its layers,
    /// [`crate::config::yaml::without_learned_files`], so that what an earlier run learned and
    /// this one did not move stays in the file). An error if what was learned is not a valid
    /// configuration.
    #[cfg(feature = "interface")]
    pub fn file_text(
        &self,
        base: &Config,
        running: &Config,
        written_by: &str,
    ) -> Result<String, ConfigError> {
        let learned = self.configuration(running);
        learned.validate()?;
        let mut text = format!(
            "{}{written_by}{}; pass it to --config (after\n\
             # your own files) to start the node or a replay from it.\n",
            crate::config::yaml::LEARNED_FILE_START,
            crate::config::yaml::LEARNED_FILE_MARK
        );
        for line in self.lines() {
            text.push_str("# ");
            text.push_str(&line);
            text.push('\n');
        }
        text.push_str(&crate::config::yaml::changed_params_yaml(base, &learned));
        Ok(text)
    }
}

/// The learned physics in one line: "learned physics over 40 tracks: drag_scale 0.927 +- 0.009
/// (each flight +- 0.030), ...".
pub fn describe_params(l: &LearnedParams) -> String {
    let values = l.params.to_vector();
    let parts: Vec<String> = PhysicsParams::NAMES
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let flights = if l.flight_sigma[i] > 0.0 {
                format!(" (each flight +- {:.3})", l.flight_sigma[i])
            } else {
                String::new()
            };
            format!("{name} {:.3} +- {:.3}{flights}", values[i], l.sigma[i])
        })
        .collect();
    let exponents: Vec<String> = REYNOLDS_EXPONENT_NAMES
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let value = l.reynolds_exponents[i];
            if l.reynolds_prior_sigma[i] <= 0.0 {
                format!("{name} {value:.3} (fixed)")
            } else if l.reynolds_determined()[i] {
                format!("{name} {value:.3} +- {:.3}", l.reynolds_sigma[i])
            } else {
                format!(
                    "{name} {value:.3}, kept at its prior (+- {:.3}, near the prior's {:.3}: \
                     these flights' speeds do not determine it)",
                    l.reynolds_sigma[i], l.reynolds_prior_sigma[i]
                )
            }
        })
        .collect();
    format!(
        "learned physics over {} tracks: {}; Reynolds exponents {}",
        l.tracks,
        parts.join(", "),
        exponents.join(", ")
    )
}

/// The noise learned of the sources that sent detections, in one line: "learned noise:
/// wide_150fps position sigma 3.0 mm (1.50x configured), stamps 0.3 ms; ...", or `None` when no
/// source has learned anything.
pub fn describe_source_noise(noise: &[LearnedSourceNoise]) -> Option<String> {
    let parts: Vec<String> = noise
        .iter()
        .filter(|n| n.has_learned())
        .map(|n| {
            format!(
                "{} position sigma {:.2} mm ({:.2}x configured), stamps {:.2} ms",
                n.source,
                n.position_sigma * 1e3,
                n.estimate.position_scale.sqrt(),
                n.stamp_sigma * 1e3
            )
        })
        .collect();
    (!parts.is_empty()).then(|| format!("learned noise: {}", parts.join("; ")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::online::estimator::{PRIOR_WEIGHT, SourceNoiseEstimate};

    fn source(name: &str, weight: f64, spin_weight: f64) -> LearnedSourceNoise {
        LearnedSourceNoise {
            source: name.to_owned(),
            position_sigma: 0.0007,
            stamp_sigma: 0.0004,
            estimate: SourceNoiseEstimate {
                position_scale: 0.1225,
                timing_variance: 1.6e-7,
                spin_scale: 4.0,
                weight,
                spin_weight,
            },
        }
    }

    fn lesson() -> LearnedSummary {
        LearnedSummary {
            params: LearnedParams {
                params: PhysicsParams {
                    drag_scale: 0.93,
                    magnus_scale: 0.56,
                    restitution: 0.965,
                    friction: 0.28,
                },
                sigma: [0.01; 4],
                tracks: 40,
                flight_sigma: [0.0; 4],
                reynolds_exponents: [0.0, -0.65],
                reynolds_sigma: [0.1, 0.3],
                reynolds_prior_sigma: [0.1, 0.3],
            },
            source_noise: vec![
                source("wide_150fps", 2000.0, PRIOR_WEIGHT),
                source("highspeed_900fps", PRIOR_WEIGHT, PRIOR_WEIGHT),
                source("not_a_source", 2000.0, 2000.0),
            ],
        }
    }

    /// The learned physics replace the configured, and a camera's noise is taken only where it
    /// learned something.
    #[test]
    fn what_was_learned_replaces_what_was_configured() {
        let base = Config::default();
        let learned = lesson();
        let c = learned.configuration(&base);
        assert_eq!(PhysicsParams::from_config(&c), learned.params.params);
        assert_eq!(c.ekf, base.ekf);
        let wide = &c.sources.wide_150fps;
        assert_eq!((wide.position_sigma, wide.stamp_sigma), (0.0007, 0.0004));
        // Its spin noise learned nothing beyond the prior.
        assert_eq!(wide.spin_sigma, base.sources.wide_150fps.spin_sigma);
        // The 900 fps camera learned nothing: as configured.
        assert_eq!(c.sources.highspeed_900fps, base.sources.highspeed_900fps);
        assert!(c.validate().is_ok());
        // Nothing learned, nothing changed.
        let nothing = LearnedSummary {
            params: LearnedParams {
                params: PhysicsParams::from_config(&base),
                reynolds_exponents: [
                    base.aero.reynolds_exponents[0],
                    base.aero.reynolds_exponents[1],
                ],
                ..learned.params
            },
            source_noise: Vec::new(),
        };
        assert_eq!(nothing.configuration(&base), base);
    }

    /// The file says who wrote it and what was learned, and loads back to the learned
    /// configuration; a lesson that is not a configuration is refused.
    #[test]
    #[cfg(feature = "interface")]
    fn the_file_loads_back_to_the_learned_configuration() {
        let base = Config::default();
        let learned = lesson();
        let text = learned.file_text(&base, &base, "a test").unwrap();
        assert!(text.starts_with("# Written by a test: "), "{text}");
        assert!(
            text.contains("# learned physics over 40 tracks: drag_scale 0.930 +- 0.010"),
            "{text}"
        );
        assert!(text.contains("# learned noise: wide_150fps position sigma 0.70 mm"));
        let loaded =
            crate::config::yaml::load_str::<&str>(&text, std::path::Path::new("l.yaml"), &[])
                .unwrap();
        assert_eq!(loaded, learned.configuration(&base));
        let mut wrong = learned;
        wrong.params.params.friction = -1.0;
        assert!(wrong.file_text(&base, &base, "a test").is_err());
    }
}

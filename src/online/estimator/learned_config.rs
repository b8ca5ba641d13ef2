//! What an estimator learned, as a configuration to start the next one from: the physical
//! parameters it learned over its tracks in place of the configured ones (`aero.drag_scale`,
//! `aero.magnus_scale`, `table.restitution`, `table.friction`), the model noise it learned folded
//! into the configured densities and scatters (`ekf.*`), and each camera's noise it learned in
//! place of the source's configured sigmas (`sources.*`). A node or replay started from it begins
//! where this one ended, with the configured priors' widths around the new values (the learning
//! goes on from there; a new ball or table is still learned as quickly).

use super::{LearnedModelNoise, LearnedParams, LearnedSourceNoise, noise};
use crate::config::Config;

/// `base` with what was learned in place of the configured values (see the module doc). A
/// source that has learned nothing beyond its prior keeps its configured noise.
pub fn learned_configuration(
    base: &Config,
    params: &LearnedParams,
    source_noise: &[LearnedSourceNoise],
    model_noise: &LearnedModelNoise,
) -> Config {
    let mut config = base.clone();
    params.params.apply_to(&mut config);
    let scales = &model_noise.scales;
    let ekf = &mut config.ekf;
    ekf.acceleration_noise_density *= scales.acceleration;
    ekf.spin_noise_density *= scales.spin;
    // The bounce's scale is on the scatter's variance.
    ekf.bounce_impulse_sigma *= scales.bounce.sqrt();
    ekf.bounce_restitution_sigma *= scales.bounce.sqrt();
    for learned in source_noise.iter().filter(|n| n.has_learned()) {
        let Some(source) = config.sources.by_name_mut(&learned.source) else {
            continue;
        };
        source.position_sigma = learned.position_sigma;
        source.stamp_sigma = learned.stamp_sigma;
        if learned.estimate.spin_weight > noise::PRIOR_WEIGHT {
            source.spin_sigma *= learned.estimate.spin_scale.sqrt();
        }
    }
    config
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::online::ekf::{NOISE_SCALES, NoiseScales};
    use crate::online::estimator::SourceNoiseEstimate;
    use crate::physics::PhysicsParams;

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

    /// The learned physics replace the configured, the model noise's scales are folded into
    /// the densities (the bounce's on its variance), and a camera's noise is taken only where
    /// it learned something.
    #[test]
    fn what_was_learned_replaces_what_was_configured() {
        let base = Config::default();
        let params = LearnedParams {
            params: PhysicsParams {
                drag_scale: 0.93,
                magnus_scale: 0.56,
                restitution: 0.965,
                friction: 0.28,
            },
            sigma: [0.01; 4],
            tracks: 40,
            flight_sigma: [0.0; 4],
        };
        let model = LearnedModelNoise {
            scales: NoiseScales {
                acceleration: 1.5,
                spin: 0.5,
                bounce: 4.0,
            },
            log_sigma: [0.1; NOISE_SCALES],
        };
        let noise = [
            source("wide_150fps", 2000.0, noise::PRIOR_WEIGHT),
            source("highspeed_900fps", noise::PRIOR_WEIGHT, noise::PRIOR_WEIGHT),
            source("not_a_source", 2000.0, 2000.0),
        ];
        let c = learned_configuration(&base, &params, &noise, &model);
        assert_eq!(PhysicsParams::from_config(&c), params.params);
        let (e, b) = (&c.ekf, &base.ekf);
        assert_eq!(
            e.acceleration_noise_density,
            1.5 * b.acceleration_noise_density
        );
        assert_eq!(e.spin_noise_density, 0.5 * b.spin_noise_density);
        assert_eq!(e.bounce_impulse_sigma, 2.0 * b.bounce_impulse_sigma);
        assert_eq!(e.bounce_restitution_sigma, 2.0 * b.bounce_restitution_sigma);
        let wide = &c.sources.wide_150fps;
        assert_eq!((wide.position_sigma, wide.stamp_sigma), (0.0007, 0.0004));
        // Its spin noise learned nothing beyond the prior.
        assert_eq!(wide.spin_sigma, base.sources.wide_150fps.spin_sigma);
        // The 900 fps camera learned nothing: as configured.
        assert_eq!(c.sources.highspeed_900fps, base.sources.highspeed_900fps);
        assert!(c.validate().is_ok());
        // Nothing learned, nothing changed.
        let none = LearnedModelNoise {
            scales: NoiseScales::default(),
            log_sigma: [0.5; NOISE_SCALES],
        };
        let unchanged = LearnedParams {
            params: PhysicsParams::from_config(&base),
            ..params
        };
        assert_eq!(learned_configuration(&base, &unchanged, &[], &none), base);
    }
}

//! The simulator's parameters, with the defaults of the seed setup (docs/models.md
//! "Cameras"): a 150 fps camera that sees the whole table (2 mm noise, 8 ms latency) and a
//! 900 fps camera that sees the robot's half and measures spin on 80 % of its frames (1 mm,
//! 12 rad/s, 3 ms); 2 % dropped frames and 0.5 % outliers each; shots 0.4-1.0 s apart, half of
//! them real rally balls; random launches at 3-14 m/s with up to 600 rad/s of spin.
//!
//! The estimator does not read these: it uses `Config::sources`. To evaluate it with noise
//! models that match the simulation, set the configuration from them with
//! [`SimParams::configure_estimator`] (the configuration's defaults are these same cameras:
//! 2 mm, 1 mm and 12 rad/s).

use crate::config::{Config, SourceParams};
use crate::model::detection::Source;

/// A closed interval [min, max] of a quantity (unit given where used).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// Lower end.
    pub min: f64,
    /// Upper end.
    pub max: f64,
}

impl Interval {
    /// The interval [min, max].
    pub const fn new(min: f64, max: f64) -> Self {
        Self { min, max }
    }

    /// True when `value` lies in [min, max].
    pub fn contains(&self, value: f64) -> bool {
        self.min <= value && value <= self.max
    }

    fn is_valid(&self) -> bool {
        self.min.is_finite() && self.max.is_finite() && self.min <= self.max
    }
}

/// The box of the table frame a camera sees [m].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldOfView {
    /// Range of x [m].
    pub x: Interval,
    /// Range of y [m].
    pub y: Interval,
    /// Range of z [m].
    pub z: Interval,
}

impl FieldOfView {
    /// True when the point [m] lies inside the box.
    pub fn contains(&self, p: &nalgebra::Vector3<f64>) -> bool {
        self.x.contains(p.x) && self.y.contains(p.y) && self.z.contains(p.z)
    }
}

/// One camera system: frame clock, view, noise, spin measurement, latency, failures.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraParams {
    /// The source written into its detections.
    pub source: Source,
    /// Frame rate [Hz]. The frame clock runs through the whole session with a random phase.
    pub frame_rate: f64,
    /// What it sees [m]: a frame yields a detection only when the true ball centre is inside, and
    /// a reported position outside it is cut (it would be off the image).
    pub view: FieldOfView,
    /// Standard deviation of the position noise, per axis, gaussian [m].
    pub position_sigma: f64,
    /// Probability that a frame also measures the spin [-]; 0 for a position-only camera.
    pub spin_probability: f64,
    /// Standard deviation of the spin noise, per axis, gaussian [rad/s].
    pub spin_sigma: f64,
    /// Mean latency from exposure (the stamp) to arrival [s].
    pub latency_mean: f64,
    /// Standard deviation of the gaussian latency jitter [s]; latencies are clipped at 0.
    pub latency_jitter: f64,
    /// Each frame interval is the period plus -1, 0 or +1 times this, each equally likely [s]
    /// (a free-running tracker: 7 ms +- 1 ms gives intervals of 6, 7 or 8 ms); 0: a regular
    /// clock.
    pub interval_jitter: f64,
    /// The stamps are rounded to a multiple of this [s] (0.001: millisecond stamps), the
    /// positions measured at the true exposure time; 0: exact stamps.
    pub stamp_resolution: f64,
    /// Probability that a frame with the ball in view yields no detection [-].
    pub dropout_probability: f64,
    /// Probability that a detection is an outlier [-]: displaced from the ball, flagged in truth.
    pub outlier_probability: f64,
    /// Distance of an outlier from the measured ball, uniform, in a direction uniform on the
    /// sphere [m].
    pub outlier_displacement: Interval,
    /// Confidence of a good detection [-].
    pub confidence: f32,
    /// Confidence of an outlier, uniform in this range [-].
    pub outlier_confidence: Interval,
}

impl CameraParams {
    /// The wide camera: 150 fps over the whole table volume, 2 mm, 8 ms +- 1.5 ms, position only.
    pub fn wide() -> Self {
        Self {
            source: Source::WIDE_150FPS,
            frame_rate: 150.0,
            view: FieldOfView {
                x: Interval::new(-1.9, 1.9),
                y: Interval::new(-1.2, 1.2),
                z: Interval::new(-0.1, 1.5),
            },
            position_sigma: 0.002,
            spin_probability: 0.0,
            spin_sigma: 0.0,
            latency_mean: 0.008,
            latency_jitter: 0.0015,
            interval_jitter: 0.0,
            stamp_resolution: 0.0,
            dropout_probability: 0.02,
            outlier_probability: 0.005,
            outlier_displacement: Interval::new(0.05, 0.30),
            confidence: 0.9,
            outlier_confidence: Interval::new(0.3, 0.6),
        }
    }

    /// The high-speed camera: 900 fps over the robot's half (x <= 0.05 m), 1 mm, spin on 80 % of
    /// the frames with 12 rad/s, 3 ms +- 0.5 ms.
    pub fn high_speed() -> Self {
        Self {
            source: Source::HIGHSPEED_900FPS,
            frame_rate: 900.0,
            view: FieldOfView {
                x: Interval::new(-1.9, 0.05),
                y: Interval::new(-1.2, 1.2),
                z: Interval::new(-0.1, 1.5),
            },
            position_sigma: 0.001,
            spin_probability: 0.8,
            spin_sigma: 12.0,
            latency_mean: 0.003,
            latency_jitter: 0.0005,
            ..Self::wide()
        }
    }

    /// The estimator's source parameters that match this camera: its sigmas and mean latency.
    pub fn source_params(&self) -> SourceParams {
        SourceParams {
            id: self.source.0,
            position_sigma: self.position_sigma,
            spin_sigma: if self.spin_probability > 0.0 {
                self.spin_sigma
            } else {
                0.0
            },
            latency: self.latency_mean,
            stamp_sigma: self.stamp_resolution / 12f64.sqrt(),
            frame_rate: self.frame_rate,
        }
    }

    fn validate(&self, camera: &'static str) -> Result<(), ParamError> {
        let check = |ok: bool, name: &'static str, value: f64| {
            if ok {
                Ok(())
            } else {
                Err(ParamError {
                    camera,
                    name,
                    value,
                })
            }
        };
        let probability = |p: f64| (0.0..=1.0).contains(&p);
        let non_negative = |v: f64| v.is_finite() && v >= 0.0;
        check(
            self.frame_rate.is_finite() && self.frame_rate > 0.0,
            "frame_rate",
            self.frame_rate,
        )?;
        for (name, interval) in [
            ("view.x", self.view.x),
            ("view.y", self.view.y),
            ("view.z", self.view.z),
            ("outlier_displacement", self.outlier_displacement),
            ("outlier_confidence", self.outlier_confidence),
        ] {
            check(interval.is_valid(), name, interval.min)?;
        }
        check(
            non_negative(self.position_sigma),
            "position_sigma",
            self.position_sigma,
        )?;
        check(non_negative(self.spin_sigma), "spin_sigma", self.spin_sigma)?;
        check(
            probability(self.spin_probability),
            "spin_probability",
            self.spin_probability,
        )?;
        check(
            non_negative(self.latency_mean),
            "latency_mean",
            self.latency_mean,
        )?;
        check(
            non_negative(self.latency_jitter),
            "latency_jitter",
            self.latency_jitter,
        )?;
        check(
            non_negative(self.interval_jitter) && self.interval_jitter * self.frame_rate < 0.5,
            "interval_jitter",
            self.interval_jitter,
        )?;
        check(
            non_negative(self.stamp_resolution),
            "stamp_resolution",
            self.stamp_resolution,
        )?;
        check(
            probability(self.dropout_probability),
            "dropout_probability",
            self.dropout_probability,
        )?;
        check(
            probability(self.outlier_probability),
            "outlier_probability",
            self.outlier_probability,
        )?;
        check(
            (0.0..=1.0).contains(&self.confidence),
            "confidence",
            f64::from(self.confidence),
        )
    }
}

/// Which camera systems deliver detections.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Cameras {
    /// The 150 fps wide camera alone.
    WideOnly,
    /// The 150 fps wide camera and the 900 fps high-speed camera.
    WideAndHighSpeed,
}

/// A log-normal distribution given by two of its quantiles (of a quantity in its own unit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    /// The median.
    pub median: f64,
    /// The 90th percentile (above the median).
    pub p90: f64,
}

impl Spread {
    /// sigma of the underlying normal: ln(p90 / median) / z_0.9.
    pub fn log_sigma(&self) -> f64 {
        (self.p90 / self.median).ln() / 1.281_551_565_5
    }

    fn is_valid(&self) -> bool {
        self.median.is_finite()
            && self.median > 0.0
            && self.p90.is_finite()
            && self.p90 > self.median
    }
}

/// The random launch generator: uniform draws in these ranges (or, with a spread, log-normal
/// draws cut to them), aimed at a uniform target on the robot's half by solving for the
/// elevation.
#[derive(Debug, Clone, PartialEq)]
pub struct RandomLaunchParams {
    /// Launch speed [m/s]. Default 3-14 m/s.
    pub speed: Interval,
    /// Spin magnitude [rad/s]. Default 30-600 rad/s.
    pub spin: Interval,
    /// Draw the speed log-normal with these quantiles, within `speed`, instead of uniform.
    pub speed_spread: Option<Spread>,
    /// Draw the spin log-normal with these quantiles, within `spin`, instead of uniform.
    pub spin_spread: Option<Spread>,
    /// Launch x, on the opponent's side [m]. Default 1.2-2.2 m.
    pub x: Interval,
    /// Launch y [m]. Default -0.6..0.6 m.
    pub y: Interval,
    /// Launch height above the table [m]. Default 0.1-0.5 m.
    pub z: Interval,
    /// x of the aimed bounce point on the robot's half [m]. Default -1.2..-0.2 m.
    pub target_x: Interval,
    /// y of the aimed bounce point [m]. Default -0.6..0.6 m.
    pub target_y: Interval,
    /// Elevations searched for the one that lands on the target [rad]. Default -30..40 degrees.
    pub elevation: Interval,
}

impl Default for RandomLaunchParams {
    fn default() -> Self {
        Self {
            speed: Interval::new(3.0, 14.0),
            spin: Interval::new(30.0, 600.0),
            speed_spread: None,
            spin_spread: None,
            x: Interval::new(1.2, 2.2),
            y: Interval::new(-0.6, 0.6),
            z: Interval::new(0.1, 0.5),
            target_x: Interval::new(-1.2, -0.2),
            target_y: Interval::new(-0.6, 0.6),
            elevation: Interval::new(-30f64.to_radians(), 40f64.to_radians()),
        }
    }
}

/// The sequence of shots.
#[derive(Debug, Clone, PartialEq)]
pub struct ShotParams {
    /// Fraction of shots launched from a real (GDM) state; the rest are random [-]. Default 0.5.
    pub real_fraction: f64,
    /// Fraction of shots played from the robot's end toward the opponent's (each a drawn shot
    /// turned half around the vertical through the net's centre: its bounce on the opponent's
    /// half, its plane crossing the opponent's); the rest come toward the robot [-]. Default 0.
    pub from_robot_fraction: f64,
    /// Time from the end of one shot to the launch of the next, uniform [s]. Default 0.4-1.0 s.
    pub gap: Interval,
    /// How long the ball is flown past the hitting plane, when the robot hits it [s]. Default
    /// 30 ms.
    pub follow_after_plane: f64,
    /// Lowest height of the ball centre where it crosses the hitting plane [m]. Default 0 (the
    /// table's surface): lower balls fall beside or past the table, out of the robot's reach.
    pub min_plane_height: f64,
    /// Longest flight the good-shot check looks at [s]. Default 3 s.
    pub horizon: f64,
    /// Largest number of launch states drawn for one shot before giving up [-]. Default 1000.
    pub max_tries: u32,
    /// The random launch generator.
    pub random: RandomLaunchParams,
}

impl Default for ShotParams {
    fn default() -> Self {
        Self {
            real_fraction: 0.5,
            from_robot_fraction: 0.0,
            gap: Interval::new(0.4, 1.0),
            follow_after_plane: 0.030,
            min_plane_height: 0.0,
            horizon: 3.0,
            max_tries: 1000,
            random: RandomLaunchParams::default(),
        }
    }
}

/// Everything the simulator needs besides the physics configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct SimParams {
    /// The 150 fps wide camera.
    pub wide: CameraParams,
    /// The 900 fps high-speed camera.
    pub high_speed: CameraParams,
    /// The shots.
    pub shots: ShotParams,
    /// Largest RK4 step of the true flight [s]. Default 0.25 ms: the truth is then independent
    /// of the step grid to about 1e-12 m, so the state at a stamp is the same however the flight
    /// was cut into steps.
    pub truth_step: f64,
    /// Largest RK4 step of the launcher's aim (which launches land where they are aimed, which
    /// make good shots) [s]. Default 10 ms. Its own, not the estimator's `prediction.step`, so
    /// that a session is the same whatever the estimator's settings.
    pub aim_step: f64,
}

impl Default for SimParams {
    fn default() -> Self {
        Self {
            wide: CameraParams::wide(),
            high_speed: CameraParams::high_speed(),
            shots: ShotParams::default(),
            truth_step: 0.000_25,
            aim_step: 0.01,
        }
    }
}

/// A simulator parameter out of its range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("simulator parameter {camera}{name} = {value} is out of range")]
pub struct ParamError {
    /// `wide.`, `high_speed.` or empty.
    pub camera: &'static str,
    /// The parameter.
    pub name: &'static str,
    /// Its value (the lower end of an interval).
    pub value: f64,
}

impl SimParams {
    /// Checks every range: rates and steps positive, sigmas non-negative, probabilities in
    /// [0, 1], intervals ordered.
    pub fn validate(&self) -> Result<(), ParamError> {
        self.wide.validate("wide.")?;
        self.high_speed.validate("high_speed.")?;
        let shots = &self.shots;
        let random = &shots.random;
        let check = |ok: bool, name: &'static str, value: f64| {
            if ok {
                Ok(())
            } else {
                Err(ParamError {
                    camera: "",
                    name,
                    value,
                })
            }
        };
        check(
            (0.0..=1.0).contains(&shots.real_fraction),
            "shots.real_fraction",
            shots.real_fraction,
        )?;
        check(
            (0.0..=1.0).contains(&shots.from_robot_fraction),
            "shots.from_robot_fraction",
            shots.from_robot_fraction,
        )?;
        check(
            shots.gap.is_valid() && shots.gap.min >= 0.0,
            "shots.gap",
            shots.gap.min,
        )?;
        check(
            shots.follow_after_plane.is_finite() && shots.follow_after_plane >= 0.0,
            "shots.follow_after_plane",
            shots.follow_after_plane,
        )?;
        check(
            shots.min_plane_height.is_finite(),
            "shots.min_plane_height",
            shots.min_plane_height,
        )?;
        check(
            shots.horizon.is_finite() && shots.horizon > 0.0,
            "shots.horizon",
            shots.horizon,
        )?;
        check(
            shots.max_tries > 0,
            "shots.max_tries",
            f64::from(shots.max_tries),
        )?;
        for (name, interval) in [
            ("shots.random.speed", random.speed),
            ("shots.random.spin", random.spin),
            ("shots.random.x", random.x),
            ("shots.random.y", random.y),
            ("shots.random.z", random.z),
            ("shots.random.target_x", random.target_x),
            ("shots.random.target_y", random.target_y),
            ("shots.random.elevation", random.elevation),
        ] {
            check(interval.is_valid(), name, interval.min)?;
        }
        check(
            random.speed.min > 0.0 && random.spin.min >= 0.0,
            "shots.random.speed",
            random.speed.min,
        )?;
        for (name, spread) in [
            ("shots.random.speed_spread", random.speed_spread),
            ("shots.random.spin_spread", random.spin_spread),
        ] {
            if let Some(spread) = spread {
                check(spread.is_valid(), name, spread.median)?;
            }
        }
        check(
            self.truth_step.is_finite() && self.truth_step > 0.0,
            "truth_step",
            self.truth_step,
        )?;
        check(
            self.aim_step.is_finite()
                && self.aim_step > 0.0
                && self.aim_step <= crate::config::MAX_STEP,
            "aim_step",
            self.aim_step,
        )
    }

    /// Sets the estimator's noise and latency of the two camera sources
    /// (`sources.wide_150fps`, `sources.highspeed_900fps`) to this simulation's.
    pub fn configure_estimator(&self, config: &mut Config) {
        config.sources.wide_150fps = self.wide.source_params();
        config.sources.highspeed_900fps = self.high_speed.source_params();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_the_documented_cameras_and_valid() {
        let p = SimParams::default();
        assert_eq!(p.validate(), Ok(()));
        assert_eq!(p.wide.frame_rate, 150.0);
        assert_eq!(p.high_speed.frame_rate, 900.0);
        assert_eq!(p.high_speed.view.x.max, 0.05);
        assert_eq!(p.wide.source, Source::WIDE_150FPS);
        assert_eq!(p.high_speed.source, Source::HIGHSPEED_900FPS);
    }

    #[test]
    fn validate_names_the_bad_parameter() {
        let mut p = SimParams::default();
        p.high_speed.dropout_probability = 1.5;
        let e = p.validate().err();
        assert_eq!(
            e.map(|e| e.to_string()),
            Some(
                "simulator parameter high_speed.dropout_probability = 1.5 is out of range"
                    .to_owned()
            )
        );
        let p = SimParams {
            truth_step: 0.0,
            ..SimParams::default()
        };
        assert_eq!(p.validate().map_err(|e| e.name), Err("truth_step"));
    }

    #[test]
    fn configure_estimator_copies_the_sigmas() {
        let p = SimParams::default();
        let mut config = Config::default();
        config.sources.wide_150fps.position_sigma = 0.01;
        config.sources.highspeed_900fps.spin_sigma = 40.0;
        p.configure_estimator(&mut config);
        assert_eq!(config.sources.wide_150fps.position_sigma, 0.002);
        assert_eq!(config.sources.wide_150fps.spin_sigma, 0.0);
        assert_eq!(config.sources.highspeed_900fps.position_sigma, 0.001);
        assert_eq!(config.sources.highspeed_900fps.spin_sigma, 12.0);
        assert_eq!(config.sources.highspeed_900fps.latency, 0.003);
        assert_eq!(config.validate(), Ok(()));
    }
}

//! How well the estimator predicts real flights: each flight's detections go through
//! [`Estimator::handle`] in time order, and at fixed leads before the measured crossing of a
//! hitting plane the latest interception prediction is compared with that crossing.
//!
//! **The plane.** The recordings end soon after the bounce (topspin flights 8 to 68 ms after it,
//! backspin 0.12 to 0.15 s, no-spin about 0.3 s; eight backspin and two topspin recordings end
//! before it, two more backspin ones within 16 ms) and the bounces spread over x_t = -0.55 m
//! (no spin) to -1.21 m (backspin), so a plane must be chosen per flight or the flights it suits
//! ([`Plane`]):
//! - [`Plane::AfterBounce`] (the default, 20 ms): each flight's plane is x_t where the ball is
//!   that long after its measured bounce (5 to 8 cm past the bounce point). Every scored flight
//!   is predicted through the same phases (flight, bounce, a short rise), so the leads mean the
//!   same for every kind. When the camera missed the frames there (three backspin flights lose
//!   40 to 55 ms at the bounce), the plane is where the ball is first seen again.
//! - [`Plane::Fixed`]: one x_t for all, like a robot's hitting plane; flights whose recording
//!   does not reach it after the bounce are not scored, and the stretch after the bounce differs
//!   by kind (no-spin balls bounce 0.6 m before x_t = -1.2 m, backspin balls 2 to 9 cm before).
//!
//! `intercept.plane_x` is set to the flight's plane for its estimator.
//!
//! **The measured crossing.** The bounce is found with [`detect_bounce`]; the crossing is from
//! the ballistic fit ([`fit_ballistic`]) of the samples after the bounce within
//! [`CROSSING_WINDOW`] of the crossing: its y and z at the crossing time. A flight is scored when
//! its recording has samples on both sides of the crossing, after the bounce.
//!
//! **Scoring.** At each lead L, the prediction is the latest [`InterceptEstimate`] stamped at or
//! before (crossing time - L). Its crossing point (y, z) and time are compared with the measured
//! ones; a flight without a track or with an invalid prediction at that time counts against the
//! valid fraction. The predicted bounce is compared with the measured one too, which separates
//! errors of the flight model (already in the bounce) from those of the bounce model.

use nalgebra::Vector3;

use super::mpi::{Flight, SpinKind, flight_detections};
use crate::config::Config;
use crate::model::detection::{Detection, Source, seconds_to_ns};
use crate::model::stats::ErrorStats;
use crate::offline::ballistic::{MeasuredBounce, detect_bounce, fit_ballistic};
use crate::offline::batch::fit_whole_flight;
use crate::online::estimator::{
    Counters, Estimator, InterceptEstimate, LearnedParams, LearnedPhysics, Rejection, Verdict,
};
use crate::online::intercept::NoIntercept;
use crate::physics::BallState;
use crate::physics::propagate::Propagator;

/// Samples within this time of the crossing [s] are fitted to measure it.
pub const CROSSING_WINDOW: f64 = 0.015;

/// The reasons of invalid predictions, in the order of [`LeadSummary::invalid`].
pub const INVALID_REASONS: [NoIntercept; 5] = [
    NoIntercept::NetHit,
    NoIntercept::MissesTable,
    NoIntercept::NoBounce,
    NoIntercept::TwoBounces,
    NoIntercept::NotWithinHorizon,
];

/// What to evaluate.
#[derive(Debug, Clone, PartialEq)]
pub struct RealEvalOptions {
    /// Leads before the measured crossing at which predictions are scored [s].
    pub leads: Vec<f64>,
    /// The hitting plane of each flight.
    pub plane: Plane,
    /// Stamp of every flight's t = 0 [ns] (each flight has its own estimator).
    pub epoch_ns: i64,
    /// Source of the detections (see [`flight_detections`]).
    pub source: Source,
    /// Each flight's estimator starts from what the previous flights' estimators learned of
    /// the physics (in the flights' order), as one estimator running through them would; else
    /// every flight starts from the configuration.
    pub carry_over: bool,
}

impl Default for RealEvalOptions {
    fn default() -> Self {
        Self {
            leads: vec![0.2, 0.1],
            plane: Plane::AfterBounce(0.02),
            epoch_ns: 1_700_000_000_000_000_000,
            source: Source::WIDE_150FPS,
            carry_over: true,
        }
    }
}

/// Where a flight's hitting plane is (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Plane {
    /// Where the flight is this long after its measured bounce [s].
    AfterBounce(f64),
    /// x_t = this for every flight [m].
    Fixed(f64),
}

impl Plane {
    /// A short description for tables.
    pub fn describe(&self) -> String {
        match self {
            Self::AfterBounce(s) => format!("{:.0} ms after each flight's bounce", s * 1e3),
            Self::Fixed(x) => format!("x_t = {x:.3} m"),
        }
    }
}

/// Why a flight is not scored.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Unscored {
    /// The recording shows no bounce (it ends before it).
    NoBounce,
    /// The recording ends this long after the bounce [s], before the plane.
    EndsTooSoon(f64),
    /// Fewer than two samples near the crossing (a gap).
    Gap,
    /// The ball is not moving toward the robot at the plane.
    NotTowardRobot,
    /// The bounce is beyond the fixed plane (seen from the net).
    BouncesBeyondPlane,
}

impl Unscored {
    /// A short explanation.
    pub fn describe(&self) -> String {
        match self {
            Self::NoBounce => "the recording ends before the bounce".to_owned(),
            Self::EndsTooSoon(s) => {
                format!("the recording ends {:.0} ms after the bounce", s * 1e3)
            }
            Self::Gap => "missed frames at the crossing".to_owned(),
            Self::NotTowardRobot => "the ball does not move toward the robot".to_owned(),
            Self::BouncesBeyondPlane => "the bounce is beyond the plane".to_owned(),
        }
    }
}

/// The crossing of a flight's plane, measured from its samples.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredCrossing {
    /// The measured bounce before it.
    pub bounce: MeasuredBounce,
    /// Crossing time, since the flight's first sample [s].
    pub time: f64,
    /// Ball centre at the crossing [m]; its x is the plane.
    pub position: Vector3<f64>,
    /// Velocity at the crossing [m/s].
    pub velocity: Vector3<f64>,
    /// Samples fitted [-].
    pub fitted: usize,
}

/// The crossing of a flight's plane (see the module doc); `gravity` [m/s^2] is used by the fits.
pub fn measured_crossing(
    flight: &Flight,
    plane: Plane,
    gravity: f64,
) -> Result<MeasuredCrossing, Unscored> {
    let bounce = detect_bounce(&flight.samples, gravity).ok_or(Unscored::NoBounce)?;
    let after = flight.samples.get(bounce.first_after..).unwrap_or(&[]);
    let last = after.last().map_or(bounce.time, |s| s.0);
    let ends_too_soon = Unscored::EndsTooSoon(last - bounce.time);
    let near = |time: f64| -> Vec<_> {
        after
            .iter()
            .copied()
            .filter(|(t, _)| (t - time).abs() <= CROSSING_WINDOW)
            .collect()
    };
    let (time, fit) = match plane {
        Plane::AfterBounce(delay) => {
            let nominal = bounce.time + delay;
            let &(next, _) = after
                .iter()
                .find(|(t, _)| *t >= nominal)
                .ok_or(ends_too_soon)?;
            // Fitted samples on both sides of the nominal time, or the first frames seen again.
            let (time, samples) = match near(nominal) {
                s if s.len() >= 2 && next <= nominal + CROSSING_WINDOW => (nominal, s),
                _ => (next, near(next)),
            };
            (time, fit_ballistic(&samples, time, gravity))
        }
        Plane::Fixed(x) => {
            if bounce.position.x <= x {
                return Err(Unscored::BouncesBeyondPlane);
            }
            let j = after
                .iter()
                .position(|(_, p)| p.x < x)
                .ok_or(ends_too_soon)?;
            // The frames on either side of the plane (the bounce itself before the first).
            let (t0, x0) = match j {
                0 => (bounce.time, bounce.position.x),
                _ => (after[j - 1].0, after[j - 1].1.x),
            };
            let (t1, x1) = (after[j].0, after[j].1.x);
            if t1 - t0 > CROSSING_WINDOW {
                return Err(Unscored::Gap);
            }
            let guess = t0 + (t1 - t0) * (x0 - x) / (x0 - x1);
            let fit = fit_ballistic(&near(guess), guess, gravity).ok_or(Unscored::Gap)?;
            if fit.velocity.x >= 0.0 {
                return Err(Unscored::NotTowardRobot);
            }
            // x has no gravity term: the fit's x is linear in time.
            let time = guess + (x - fit.position.x) / fit.velocity.x;
            (time, Some(fit))
        }
    };
    let fit = fit.ok_or(Unscored::Gap)?;
    if fit.velocity.x >= 0.0 {
        return Err(Unscored::NotTowardRobot);
    }
    Ok(MeasuredCrossing {
        bounce,
        time,
        position: fit.position_at(time),
        velocity: fit.velocity_at(time),
        fitted: fit.count,
    })
}

/// What the estimator predicted at one lead.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LeadOutcome {
    /// A valid prediction, minus the measurement.
    Predicted {
        /// Crossing point error in y [m].
        y_error: f64,
        /// Crossing point error in z [m].
        z_error: f64,
        /// Crossing time error [s].
        time_error: f64,
        /// The predicted standard deviations of the crossing's y, z [m] and time [s].
        sigma: [f64; 3],
        /// Velocity error at the crossing [m/s].
        velocity_error: Vector3<f64>,
        /// The crossing point's error normalised by its predicted covariance (y, z), per
        /// dimension [-]: about 1 when the covariance is honest (the measured crossing's own
        /// error, about a millimetre, is not in it); `None` when the covariance is singular.
        nees: Option<f64>,
        /// Predicted minus measured bounce point (x, y, z) [m] and time [s], when the bounce
        /// was still ahead.
        bounce_error: Option<(Vector3<f64>, f64)>,
    },
    /// No track yet at that time.
    NoTrack,
    /// The estimator predicted no valid crossing, for this reason.
    Invalid(NoIntercept),
}

/// One flight's evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightResult {
    /// The flight's number in its file [-].
    pub id: u32,
    /// Its spin kind.
    pub spin_kind: SpinKind,
    /// Its measured crossing, or why it is not scored.
    pub crossing: Result<MeasuredCrossing, Unscored>,
    /// The outcome at each lead of the options (empty when not scored).
    pub leads: Vec<LeadOutcome>,
    /// The estimated state the prediction at each lead was made from, when there was a track
    /// (empty when not scored).
    pub lead_states: Vec<Option<BallState>>,
    /// What the estimator did with all the flight's detections.
    pub counters: Counters,
    /// The estimated state just before the measured bounce (the last estimate of a track before
    /// it), or at the end of a recording that ends before the bounce.
    pub before_bounce: Option<BallState>,
    /// The batch fit's state at the same stamp ([`crate::offline::batch`]): the flight's
    /// detections up to that stamp fitted as a whole, flying the track's own physics then.
    pub batch_before_bounce: Option<BallState>,
    /// Detections gated within [`AFTER_BOUNCE_WINDOW`] after the measured bounce [-].
    pub gated_after_bounce: usize,
}

/// How long after a measured bounce a gated detection counts against the bounce's uncertainty
/// [s] (`FlightResult::gated_after_bounce`).
pub const AFTER_BOUNCE_WINDOW: f64 = 0.05;

impl FlightResult {
    /// The topspin component of the spin just before the bounce [rad/s]: the spin about the
    /// horizontal axis across the flight, z x v^ (positive topspin, negative backspin).
    pub fn topspin_before_bounce(&self) -> Option<f64> {
        topspin(&self.before_bounce?)
    }

    /// The spin perpendicular to the velocity just before the bounce, of the filter's estimate
    /// and of the batch fit at the same stamp [rad/s].
    pub fn spin_across_before_bounce(&self) -> Option<(Vector3<f64>, Vector3<f64>)> {
        let across = |s: &BallState| {
            let along = s.velocity.normalize();
            s.spin - along * s.spin.dot(&along)
        };
        Some((
            across(self.before_bounce.as_ref()?),
            across(self.batch_before_bounce.as_ref()?),
        ))
    }
}

/// The topspin component of a state's spin [rad/s]: about the horizontal axis across its flight,
/// z x v^ (positive topspin, negative backspin); `None` for a ball without horizontal velocity.
pub fn topspin(s: &BallState) -> Option<f64> {
    let horizontal = Vector3::new(s.velocity.x, s.velocity.y, 0.0);
    let norm = horizontal.norm();
    (norm > 0.0).then(|| s.spin.dot(&Vector3::z().cross(&(horizontal / norm))))
}

/// Accuracy at one lead over a group of flights.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LeadSummary {
    /// Time before the measured crossing [s].
    pub lead: f64,
    /// Flights scored [-].
    pub flights: usize,
    /// Of them, with a valid prediction [-].
    pub valid: usize,
    /// valid / flights [-].
    pub valid_fraction: f64,
    /// Flights without a track at that time [-].
    pub no_track: usize,
    /// Flights with an invalid prediction, by reason in the order of [`INVALID_REASONS`] [-].
    pub invalid: [usize; 5],
    /// Distance in the plane between predicted and measured crossing points [m].
    pub position_error: ErrorStats,
    /// Predicted minus measured crossing time [s].
    pub time_error: ErrorStats,
    /// Mean errors (biases) of the crossing: y [m], z [m], time [s].
    pub mean_error: [f64; 3],
    /// Mean velocity error (bias) at the crossing [m/s].
    pub mean_velocity_error: Vector3<f64>,
    /// Mean NEES per dimension of the crossing point (y, z) [-] (see
    /// [`LeadOutcome::Predicted`]); NaN with no valid prediction.
    pub crossing_nees: f64,
    /// Distance in the table plane (x, y) between predicted and measured bounce points [m].
    pub bounce_position_error: ErrorStats,
    /// Mean predicted minus measured bounce x [m] (positive: the prediction bounces short of
    /// the measured point, toward the net).
    pub bounce_x_bias: f64,
    /// Predicted minus measured bounce time [s].
    pub bounce_time_error: ErrorStats,
}

/// Accuracy over the flights of one spin kind, or all.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct GroupSummary {
    /// The kind; `None` for all flights.
    pub spin_kind: Option<SpinKind>,
    /// Flights in the group [-].
    pub flights: usize,
    /// Of them, scored (a measured crossing) [-].
    pub scored: usize,
    /// Accuracy at each lead of the options.
    pub leads: Vec<LeadSummary>,
}

/// The evaluation of a set of flights.
#[derive(Debug, Clone, PartialEq)]
pub struct RealReport {
    /// What was evaluated.
    pub options: RealEvalOptions,
    /// Every flight.
    pub flights: Vec<FlightResult>,
    /// Per spin kind present, in [`SpinKind::GROUPS`] order, then all flights.
    pub groups: Vec<GroupSummary>,
    /// What the last flight's estimator had learned of the physics at its end (with
    /// [`RealEvalOptions::carry_over`], over all the flights).
    pub learned: Option<LearnedParams>,
}

impl RealReport {
    /// The summary over all flights.
    pub fn overall(&self) -> Option<&GroupSummary> {
        self.groups.iter().find(|g| g.spin_kind.is_none())
    }

    /// The summary of one spin kind.
    pub fn group(&self, kind: SpinKind) -> Option<&GroupSummary> {
        self.groups.iter().find(|g| g.spin_kind == Some(kind))
    }

    /// The summaries as a Markdown table (mm and ms).
    pub fn to_markdown(&self) -> String {
        let mut s = String::from(
            "| flights | lead | scored | valid | crossing RMS / median [mm] | time RMS / median \
             [ms] | bias y / z [mm], t [ms] | bounce RMS [mm], x bias [mm], time RMS [ms] | \
             NEES/dim | not valid |\n\
             |---|---|---|---|---|---|---|---|---|---|\n",
        );
        for g in &self.groups {
            let name = g.spin_kind.map_or("all", SpinKind::name);
            for l in &g.leads {
                let bounce = if l.bounce_position_error.count == 0 {
                    "- (already bounced)".to_owned()
                } else {
                    format!(
                        "{:.1}, {:+.1}, {:.1}",
                        l.bounce_position_error.rms * 1e3,
                        l.bounce_x_bias * 1e3,
                        l.bounce_time_error.rms * 1e3
                    )
                };
                s.push_str(&format!(
                    "| {name} ({}) | {:.0} ms | {} | {:.0} % | {:.1} / {:.1} | {:.1} / {:.1} | \
                     {:+.1} / {:+.1}, {:+.1} | {} | {:.2} | {} |\n",
                    g.flights,
                    l.lead * 1e3,
                    l.flights,
                    l.valid_fraction * 100.0,
                    l.position_error.rms * 1e3,
                    l.position_error.median * 1e3,
                    l.time_error.rms * 1e3,
                    l.time_error.median * 1e3,
                    l.mean_error[0] * 1e3,
                    l.mean_error[1] * 1e3,
                    l.mean_error[2] * 1e3,
                    bounce,
                    l.crossing_nees,
                    not_valid(l),
                ));
            }
        }
        s
    }
}

/// Why the predictions at one lead were not valid, e.g. "2 no bounce, 1 no track".
fn not_valid(l: &LeadSummary) -> String {
    let mut parts: Vec<String> = INVALID_REASONS
        .iter()
        .zip(l.invalid)
        .filter(|(_, n)| *n > 0)
        .map(|(why, n)| {
            let name = match why {
                NoIntercept::NetHit => "net",
                NoIntercept::MissesTable => "misses table",
                NoIntercept::NoBounce => "no bounce",
                NoIntercept::TwoBounces => "two bounces",
                NoIntercept::NotWithinHorizon => "beyond horizon",
            };
            format!("{n} {name}")
        })
        .collect();
    if l.no_track > 0 {
        parts.push(format!("{} no track", l.no_track));
    }
    if parts.is_empty() {
        "-".to_owned()
    } else {
        parts.join(", ")
    }
}

/// The configuration as a drag-only model without spin: no Magnus force
/// (`aero.magnus_coefficients = [0]`), spin held at zero (`ekf.spin_prior_sigma` = 1e-6 rad/s,
/// `ekf.spin_noise_density` = 0). Drag, the bounce (of a ball without spin) and everything
/// else are unchanged.
pub fn drag_only(config: &Config) -> Config {
    let mut c = config.clone();
    c.aero.magnus_coefficients = vec![0.0];
    c.ekf.spin_prior_sigma = 1e-6;
    c.ekf.spin_noise_density = 0.0;
    c
}

/// Runs every flight through its own [`Estimator`] under `config` (with `intercept.plane_x`
/// set per flight; with [`RealEvalOptions::carry_over`], started from what the flights before
/// it taught) and scores it (see the module doc).
pub fn evaluate_flights(
    config: &Config,
    flights: &[Flight],
    options: &RealEvalOptions,
) -> RealReport {
    let mut learned: Option<LearnedPhysics> = None;
    let mut last = None;
    let results: Vec<FlightResult> = flights
        .iter()
        .map(|f| {
            let (result, after) = evaluate_flight(config, f, options, learned.as_ref());
            last = Some(after.params());
            if options.carry_over {
                learned = Some(after);
            }
            result
        })
        .collect();
    let mut groups: Vec<GroupSummary> = SpinKind::GROUPS
        .iter()
        .filter(|k| flights.iter().any(|f| f.spin_kind == **k))
        .map(|k| summarise(Some(*k), &results, options))
        .collect();
    groups.push(summarise(None, &results, options));
    RealReport {
        options: options.clone(),
        flights: results,
        groups,
        learned: last,
    }
}

/// One flight's result, and what its estimator learned of the physics over the whole flight.
fn evaluate_flight(
    config: &Config,
    flight: &Flight,
    options: &RealEvalOptions,
    learned: Option<&LearnedPhysics>,
) -> (FlightResult, LearnedPhysics) {
    let crossing = measured_crossing(flight, options.plane, config.gravity);
    let mut result = FlightResult {
        id: flight.id,
        spin_kind: flight.spin_kind,
        crossing,
        leads: Vec::new(),
        lead_states: Vec::new(),
        counters: Counters::default(),
        before_bounce: None,
        batch_before_bounce: None,
        gated_after_bounce: 0,
    };
    let bounce_time = detect_bounce(&flight.samples, config.gravity).map(|b| b.time);
    let mut flight_config = config.clone();
    if let Ok(measured) = crossing {
        flight_config.intercept.plane_x = measured.position.x;
    }
    let mut estimator = Estimator::new(&flight_config);
    if let Some(learned) = learned {
        estimator.adopt_learned_physics(learned);
    }
    let epoch = options.epoch_ns;
    let detections = flight_detections(flight, epoch, options.source);
    let before_bounce_ns = bounce_time.map(|t| epoch + seconds_to_ns(t));
    let mut before_bounce: Option<(i64, BallState, Option<LearnedParams>)> = None;
    let mut gated_after_bounce = 0;
    let window = seconds_to_ns(AFTER_BOUNCE_WINDOW);
    // Counts a gated detection after the measured bounce; the estimate before the measured
    // bounce and before the estimator's own (a millisecond early, its estimate would be of the
    // ball after it), if this is one.
    let mut note = |out: &crate::online::estimator::Output, stamp: i64| {
        if out.verdict == Verdict::Rejected(Rejection::Gated)
            && before_bounce_ns.is_some_and(|b| (b..=b + window).contains(&stamp))
        {
            gated_after_bounce += 1;
        }
        out.estimate
            .filter(|e| {
                before_bounce_ns.is_none_or(|b| stamp < b)
                    && e.status != crate::online::estimator::TrackStatus::Initializing
                    && e.bounces == 0
            })
            .map(|e| (e.stamp, e.state))
    };
    let Ok(measured) = crossing else {
        for d in &detections {
            let out = estimator.handle(d);
            if let Some((stamp, state)) = note(&out, d.stamp) {
                before_bounce = Some((stamp, state, estimator.track_params()));
            }
        }
        estimator.end_of_input();
        result.counters = estimator.counters();
        result.gated_after_bounce = gated_after_bounce;
        result.set_before_bounce(&flight_config, &detections, before_bounce);
        return (result, estimator.learned_physics());
    };
    let deadlines: Vec<i64> = options
        .leads
        .iter()
        .map(|lead| epoch + seconds_to_ns(measured.time - lead))
        .collect();
    let last_deadline = deadlines.iter().copied().max().unwrap_or(epoch);
    let mut latest: Vec<Option<(InterceptEstimate, Option<BallState>)>> =
        vec![None; deadlines.len()];
    for detection in &detections {
        let out = estimator.handle(detection);
        if let Some((stamp, state)) = note(&out, detection.stamp) {
            before_bounce = Some((stamp, state, estimator.track_params()));
        }
        if detection.stamp > last_deadline {
            // After the last lead: only learning.
            continue;
        }
        let Some(intercept) = out.intercept else {
            continue;
        };
        let state = out.estimate.map(|e| e.state);
        for (slot, deadline) in latest.iter_mut().zip(&deadlines) {
            if intercept.stamp <= *deadline {
                *slot = Some((intercept, state));
            }
        }
    }
    // The flight has ended: its track's lesson is learned (and counted) before it is carried.
    estimator.end_of_input();
    result.counters = estimator.counters();
    result.gated_after_bounce = gated_after_bounce;
    result.set_before_bounce(&flight_config, &detections, before_bounce);
    let learned_after = estimator.learned_physics();
    result.leads = latest
        .iter()
        .map(|p| match p {
            None => LeadOutcome::NoTrack,
            Some((p, _)) => outcome(p, &measured, epoch),
        })
        .collect();
    result.lead_states = latest.iter().map(|p| p.and_then(|(_, s)| s)).collect();
    (result, learned_after)
}

impl FlightResult {
    /// Records the filter's estimate before the bounce (`estimate`: its stamp, state and the
    /// track's own physics then) and fits `detections` up to that stamp as a whole, flying that
    /// physics on `config`, for the batch fit's state there.
    fn set_before_bounce(
        &mut self,
        config: &Config,
        detections: &[Detection],
        estimate: Option<(i64, BallState, Option<LearnedParams>)>,
    ) {
        let Some((stamp, state, params)) = estimate else {
            return;
        };
        self.before_bounce = Some(state);
        let mut physics = config.clone();
        if let Some(p) = params {
            p.params.apply_to(&mut physics);
        }
        let seen: Vec<Detection> = detections
            .iter()
            .filter(|d| d.stamp <= stamp)
            .copied()
            .collect();
        self.batch_before_bounce = fit_whole_flight(&physics, &seen).ok().and_then(|fit| {
            fit.state_at(&Propagator::new(&physics), stamp)
                .map(|(s, _)| s)
        });
    }
}

fn outcome(p: &InterceptEstimate, measured: &MeasuredCrossing, epoch: i64) -> LeadOutcome {
    let since_epoch = (p.stamp - epoch) as f64 * 1e-9;
    match p.intercept.crossing {
        Err(why) => LeadOutcome::Invalid(why),
        Ok(c) => LeadOutcome::Predicted {
            y_error: c.state.position.y - measured.position.y,
            z_error: c.state.position.z - measured.position.z,
            time_error: since_epoch + c.time - measured.time,
            sigma: [
                c.covariance[(1, 1)].max(0.0).sqrt(),
                c.covariance[(2, 2)].max(0.0).sqrt(),
                c.time_sigma,
            ],
            velocity_error: c.state.velocity - measured.velocity,
            nees: c.point_nees(&measured.position),
            bounce_error: p.intercept.bounce.map(|b| {
                (
                    b.position - measured.bounce.position,
                    since_epoch + b.time - measured.bounce.time,
                )
            }),
        },
    }
}

fn summarise(
    kind: Option<SpinKind>,
    results: &[FlightResult],
    options: &RealEvalOptions,
) -> GroupSummary {
    let members: Vec<&FlightResult> = results
        .iter()
        .filter(|r| kind.is_none_or(|k| r.spin_kind == k))
        .collect();
    let scored: Vec<&&FlightResult> = members.iter().filter(|r| r.crossing.is_ok()).collect();
    let leads = options
        .leads
        .iter()
        .enumerate()
        .map(|(slot, &lead)| {
            let mut position = Vec::new();
            let mut time = Vec::new();
            let mut sums = [0.0; 3];
            let mut velocity_sum = Vector3::zeros();
            let mut bounce_position = Vec::new();
            let mut bounce_x = Vec::new();
            let mut bounce_time = Vec::new();
            let mut nees = Vec::new();
            let mut no_track = 0;
            let mut invalid = [0; 5];
            for r in &scored {
                match r.leads.get(slot) {
                    Some(LeadOutcome::NoTrack) => no_track += 1,
                    Some(LeadOutcome::Invalid(why)) => {
                        if let Some(i) = INVALID_REASONS.iter().position(|w| w == why) {
                            invalid[i] += 1;
                        }
                    }
                    _ => {}
                }
                let Some(LeadOutcome::Predicted {
                    y_error,
                    z_error,
                    time_error,
                    velocity_error,
                    nees: crossing_nees,
                    bounce_error,
                    ..
                }) = r.leads.get(slot)
                else {
                    continue;
                };
                nees.extend(crossing_nees);
                velocity_sum += velocity_error;
                position.push(y_error.hypot(*z_error));
                time.push(*time_error);
                sums[0] += y_error;
                sums[1] += z_error;
                sums[2] += time_error;
                if let Some((p, t)) = bounce_error {
                    bounce_position.push(p.x.hypot(p.y));
                    bounce_x.push(p.x);
                    bounce_time.push(*t);
                }
            }
            let valid = position.len();
            let mean = |sum: f64, n: usize| if n > 0 { sum / n as f64 } else { f64::NAN };
            LeadSummary {
                lead,
                flights: scored.len(),
                valid,
                valid_fraction: if scored.is_empty() {
                    0.0
                } else {
                    valid as f64 / scored.len() as f64
                },
                no_track,
                invalid,
                position_error: ErrorStats::of(&position),
                time_error: ErrorStats::of(&time),
                mean_error: sums.map(|s| mean(s, valid)),
                mean_velocity_error: velocity_sum / valid.max(1) as f64,
                crossing_nees: mean(nees.iter().sum(), nees.len()),
                bounce_position_error: ErrorStats::of(&bounce_position),
                bounce_x_bias: mean(bounce_x.iter().sum(), bounce_x.len()),
                bounce_time_error: ErrorStats::of(&bounce_time),
            }
        })
        .collect();
    GroupSummary {
        spin_kind: kind,
        flights: members.len(),
        scored: scored.len(),
        leads,
    }
}

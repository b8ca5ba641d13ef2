//! The extended Kalman filter over the ball's 9-state (position, velocity, spin) in the `table`
//! frame, augmented with the 4 physical parameters it learns (drag and Magnus scale factors,
//! the table's restitution and friction: [`crate::physics::params`]).
//!
//! - Prediction: the physics core's propagation at the filter's own parameters (spin-parameter
//!   aero model, table bounce inside the step, with the state transition Phi, its contact-time
//!   sensitivity and the state's sensitivity S to the parameters) gives x and
//!   F = [[Phi, S], [0, I]]; P = F P F' + Q.
//! - Process noise Q: continuous white acceleration of density q_a [m^2/s^3] on the velocity, a
//!   spin random walk of density q_w [(rad/s)^2/s] and a random walk of each parameter,
//!   discretised over dt: Q_pp = q_a dt^3/3, Q_pv = q_a dt^2/2, Q_vv = q_a dt, Q_ww = q_w dt
//!   (each times I_3), Q_theta = q_theta dt.
//! - At a table bounce ([`BounceNoise`]): the bounce's own scatter, an uncertain tangential
//!   impulse (sigma_i per axis, per unit mass, which moves the velocity and, through the shell's
//!   inertia, the spin: 3/(2r) per m/s) and an uncertain restitution of that one bounce
//!   (sigma_e |v_z|); and the outcome's spread over the uncertainty of the state and the
//!   parameters beyond its linearisation: the bounce map on sigma points of (v, w, e_t, mu_t)
//!   (the unscented transform, which sees both the sliding and the rolling regime and the spin
//!   along every direction), its covariance less the linearised J C J' (and the mean's offset),
//!   the positive part. Both are carried to the end of the step by the flight after the bounce.
//!   The state keeps its correlation with the friction only in proportion to the probability
//!   that the bounce slid (from the margin that decides the regime, Gaussian with its
//!   propagated variance): a rolling bounce says nothing of it, and one read as sliding would
//!   teach it a value too low.
//! - Update: S = H P H' + R factored by Cholesky (a typed error when S is not positive definite),
//!   NIS = y' S^-1 y, the gain from the factor, and the Joseph form
//!   P = (I - K H) P (I - K H)' + K R K' (multiplied out), symmetrised; the parameters are kept
//!   inside their physical box ([`PARAM_BOUNDS`]). A partial update ([`Ekf::update_partially`])
//!   applies only a share of the gain to the spin along the flight (the partial-update
//!   Schmidt-Kalman filter, Brink 2017), the covariance the Joseph form's for the gain applied.
//!   Fixed-size matrices: no heap allocation.

use nalgebra::{SMatrix, SVector};

use crate::config::Config;
use crate::model::stats::normal_cdf;
pub use crate::physics::params::{AUGMENTED, AugmentedMatrix, ParamCovariance};
use crate::physics::params::{FRICTION, RESTITUTION, with_known_params};
use crate::physics::{
    Cursor, Event, EventKind, EventSensitivity, Flow, Observer, PARAMS, ParamVector, PhysicsParams,
    Propagator, StateMatrix, StateVector, Watch,
};

/// Dimensions of the bounce's unscented transform: velocity, spin, e_t and mu_t before it.
pub const BOUNCE_SIGMA_DIMENSIONS: usize = 8;

/// The box the parameters are kept in (k_D, k_M, e_t, mu_t): (lowest, highest).
pub const PARAM_BOUNDS: [(f64, f64); PARAMS] = [(0.3, 3.0), (0.05, 3.0), (0.5, 1.0), (0.02, 1.0)];

/// Why an update was not applied.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum UpdateError {
    /// The innovation covariance S is not positive definite.
    #[error("the innovation covariance is not positive definite")]
    NotPositiveDefinite,
    /// The measurement lies outside the Mahalanobis gate.
    #[error("normalised innovation squared {nis} beyond the gate {gate}")]
    Gated {
        /// Normalised innovation squared of the rejected measurement.
        nis: f64,
        /// The gate it exceeded.
        gate: f64,
    },
    /// The measurement or its covariance is not finite.
    #[error("the measurement is not finite")]
    NotFinite,
}

/// The process-noise densities.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProcessNoise {
    /// White-acceleration density q_a [m^2/s^3].
    pub acceleration_density: f64,
    /// Spin random-walk density q_w [(rad/s)^2/s].
    pub spin_density: f64,
    /// Random-walk density of each parameter [unit^2/s] (k_D, k_M, e_t, mu_t).
    pub param_density: ParamVector,
}

impl ProcessNoise {
    /// Q of the ball's state over a step of `dt` seconds (see the module doc).
    pub fn discretise(&self, dt: f64) -> StateMatrix {
        let (acceleration, spin) = self.discretise_parts(dt);
        acceleration + spin
    }

    /// Q over a step of `dt` seconds in its two parts: the white acceleration's (position and
    /// velocity) and the spin random walk's.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn discretise_parts(&self, dt: f64) -> (StateMatrix, StateMatrix) {
        let dt = dt.abs();
        let qa = self.acceleration_density;
        let (mut Q_a, mut Q_w) = (StateMatrix::zeros(), StateMatrix::zeros());
        for i in 0..3 {
            Q_a[(i, i)] = qa * dt * dt * dt / 3.0;
            Q_a[(i, i + 3)] = qa * dt * dt / 2.0;
            Q_a[(i + 3, i)] = qa * dt * dt / 2.0;
            Q_a[(i + 3, i + 3)] = qa * dt;
            Q_w[(i + 6, i + 6)] = self.spin_density * dt;
        }
        (Q_a, Q_w)
    }
}

/// The scatter of one table bounce (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BounceNoise {
    /// sigma_i: the tangential impulse per unit mass, per axis [m/s].
    pub impulse_sigma: f64,
    /// sigma_e: the restitution of one bounce about the table's [-].
    pub restitution_sigma: f64,
    /// Whether the bounce's outcome over the state's uncertainty is found by sigma points
    /// (its spread beyond the linearised one added).
    pub unscented: bool,
}

impl BounceNoise {
    /// The bounce scatter the configuration sets (`ekf.bounce_*`).
    pub fn from_config(config: &Config) -> Self {
        Self {
            impulse_sigma: config.ekf.bounce_impulse_sigma,
            restitution_sigma: config.ekf.bounce_restitution_sigma,
            unscented: config.ekf.bounce_unscented,
        }
    }

    /// This scatter with its variances times `scale` (the learned scale,
    /// [`NoiseScales::bounce`]).
    pub fn scaled(&self, scale: f64) -> Self {
        let sigma_scale = scale.max(0.0).sqrt();
        Self {
            impulse_sigma: self.impulse_sigma * sigma_scale,
            restitution_sigma: self.restitution_sigma * sigma_scale,
            unscented: self.unscented,
        }
    }
}

/// How many noise scales the estimator learns ([`NoiseScales`]).
pub const NOISE_SCALES: usize = 3;

/// Scale factors on the filter's noise, learned by the estimator from its innovations: the
/// configured white acceleration's density times `acceleration`, the spin random walk's times
/// `spin`, the bounce's scatter (its impulse and restitution variances) times `bounce`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseScales {
    /// The scale on the white acceleration's density [-].
    pub acceleration: f64,
    /// The scale on the spin random walk's density [-].
    pub spin: f64,
    /// The scale on the bounce's scatter [-].
    pub bounce: f64,
}

impl NoiseScales {
    /// The names of the scales, in the order of [`Self::to_array`].
    pub const NAMES: [&'static str; NOISE_SCALES] = ["acceleration", "spin", "bounce"];

    /// The scales in the order of [`Self::NAMES`].
    pub fn to_array(&self) -> [f64; NOISE_SCALES] {
        [self.acceleration, self.spin, self.bounce]
    }

    /// The scales from an array in the order of [`Self::NAMES`].
    pub fn from_array(a: [f64; NOISE_SCALES]) -> Self {
        Self {
            acceleration: a[0],
            spin: a[1],
            bounce: a[2],
        }
    }
}

impl Default for NoiseScales {
    fn default() -> Self {
        Self::from_array([1.0; NOISE_SCALES])
    }
}

/// How the covariance of the ball's state depends on each noise scale (in the order of
/// [`NoiseScales::NAMES`]): dP/ds, carried through every prediction (F D F' plus the scaled
/// noise's own part) and update ((I - K H) D (I - K H)', the derivative of the update at the
/// optimal gain).
pub type NoiseSensitivity = [StateMatrix; NOISE_SCALES];

/// The covariance's sensitivity to the noise scales as an update carries it along, and whether
/// the update also scores the scales by its innovation ([`NoiseScore`]): a filter that learns
/// the scales from predictions further ahead (`ekf.model_noise_horizon`) carries the
/// sensitivity through every update but scores none of them.
#[derive(Debug)]
pub struct NoiseCarry<'a> {
    /// dP/ds of each scale, updated in place.
    pub sensitivity: &'a mut NoiseSensitivity,
    /// Whether the update computes its [`NoiseScore`] (otherwise the default, zeros).
    pub scored: bool,
}

impl NoiseCarry<'_> {
    /// The same carry, borrowed again for one more update.
    pub fn reborrow(&mut self) -> NoiseCarry<'_> {
        NoiseCarry {
            sensitivity: self.sensitivity,
            scored: self.scored,
        }
    }
}

/// What one update tells of the noise scales: the derivative of the innovation's
/// log-likelihood, log N(y; 0, S), with respect to each scale (in the order of
/// [`NoiseScales::NAMES`]), and its Fisher information (see [`Ekf::update`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NoiseScore {
    /// d log L / ds.
    pub gradient: [f64; NOISE_SCALES],
    /// The Fisher information of each, 1/2 tr(S^-1 dS S^-1 dS).
    pub information: [f64; NOISE_SCALES],
    /// The share of the innovation's covariance each scale makes per unit of it,
    /// tr(S^-1 dS) / m: times the scale, the fraction of S that is the scale's doing (1 where it
    /// is all of it).
    pub share: [f64; NOISE_SCALES],
}

/// A fused measurement: its normalised innovation squared and what it tells of the noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fused {
    /// y' S^-1 y.
    pub nis: f64,
    /// The NIS of the whole measurement against the prediction, even where only part of it was
    /// fused (a spin that did not fit, see the estimator): what tells two hypotheses of one
    /// detection apart, compared over the same dimensions.
    pub whole_nis: f64,
    /// The score of the noise scales.
    pub score: NoiseScore,
}

/// Largest NIS per measured dimension a score counts at: an outlier just inside the gate moves
/// the noise scales no more than this.
const SCORE_NIS_LIMIT: f64 = 4.0;

/// What the filter's prediction adds to the physics: the process noise, the bounce's scatter,
/// and how the flight's coefficients see the spin's uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterNoise {
    /// The process noise.
    pub process: ProcessNoise,
    /// The bounce's scatter.
    pub bounce: BounceNoise,
    /// kappa: the flight's coefficients are evaluated at the spin parameter of
    /// sqrt(|w_perp|^2 + kappa^2 tr P_w_perp), the spin's magnitude across the flight with
    /// kappa times its spread ([`crate::physics::FlightModel::with_spin_variance`]); 0 at the
    /// estimate's own [-].
    pub spin_spread: f64,
}

/// What a prediction went through.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PredictReport {
    /// Table bounces during the step.
    pub bounces: u32,
    /// Table bounces during the step on the robot's half (x < 0).
    pub robot_half_bounces: u32,
    /// The state change of the step's last bounce (after - before).
    pub last_jump: Option<StateVector>,
}

impl Observer for PredictReport {
    fn on_event(&mut self, event: &Event) -> Flow {
        if matches!(event.kind, EventKind::TableBounce { .. }) {
            self.bounces += 1;
            self.last_jump = Some(event.after - event.before);
            if event.before[0] < 0.0 {
                self.robot_half_bounces += 1;
            }
        }
        Flow::Continue
    }
}

/// What a prediction about a nominal ([`Ekf::predict_about`]) writes and reads beyond the
/// estimate's.
struct Nominal<'a> {
    /// Where the transition of (state, parameters) is written.
    transition: &'a mut AugmentedMatrix,
    /// The covariance a bounce's spread is taken at, if not the estimate's.
    covariance: Option<&'a AugmentedMatrix>,
}

/// Counts the bounces of a prediction and adds up their scatter (in the state just after the
/// last one).
struct BounceWatch<'a> {
    report: PredictReport,
    propagator: &'a Propagator,
    noise: &'a BounceNoise,
    /// The covariance the prediction starts from (or its nominal's: [`Nominal`]), which the
    /// bounces' spread and sliding are taken at.
    start: &'a AugmentedMatrix,
    /// The scatter of the bounces so far at the configured sigmas (scaled in P).
    scatter: StateMatrix,
    /// The spread of the bounces' outcome beyond its linearisation so far.
    excess: StateMatrix,
    /// The probability that every bounce so far slid (the regime in which its outcome
    /// depends on the friction).
    sliding: f64,
}

impl Observer for BounceWatch<'_> {
    fn on_event(&mut self, event: &Event) -> Flow {
        self.report.on_event(event);
        if matches!(event.kind, EventKind::TableBounce { .. }) {
            let (scatter, excess, sliding) = self.bounce_scatter(event);
            self.scatter += scatter;
            self.excess += excess;
            self.sliding *= sliding;
        }
        Flow::Continue
    }
}

impl BounceWatch<'_> {
    /// The scatter of one bounce in the state just after it (at the configured sigmas), the
    /// spread of its outcome beyond the linearisation, and the probability that it slid.
    fn bounce_scatter(&self, event: &Event) -> (StateMatrix, StateMatrix, f64) {
        let bounce = self.propagator.bounce();
        let q = bounce_scatter(self.propagator, self.noise, &event.before);
        let Some(s) = event.sensitivity else {
            return (q, StateMatrix::zeros(), 1.0);
        };
        let at_bounce = covariance_at_event(&s, self.start);
        // The probability that it slid, from the margin that decides the regime (rolling when
        // positive; Gaussian, its variance g C g' over state and parameters).
        let (margin, gradient) = bounce.regime_margin(&event.before);
        let (e, mu) = bounce.table();
        let vz = event.before[5].abs();
        let mut g = SMatrix::<f64, 1, AUGMENTED>::zeros();
        g.fixed_columns_mut::<9>(0).copy_from(&gradient);
        g[9 + RESTITUTION] = mu * vz;
        g[9 + FRICTION] = (1.0 + e) * vz;
        let variance = (g * at_bounce * g.transpose())[(0, 0)];
        let p_sliding = if variance > 0.0 {
            normal_cdf(-margin / variance.sqrt())
        } else if margin < 0.0 {
            1.0
        } else {
            0.0
        };
        let excess = if self.noise.unscented {
            unscented_excess(
                self.propagator,
                &event.before,
                &event.after,
                &bounce_inputs_of(&at_bounce),
            )
        } else {
            StateMatrix::zeros()
        };
        (q, excess, p_sliding)
    }
}

/// The score of the noise scales for an innovation y of covariance S (its Cholesky factor `chol`
/// and NIS `nis`) of a measurement H x, given D = dP/ds of each scale: with A = H D H',
/// d log N(y; 0, S) / ds = -1/2 (tr(S^-1 A) - y' S^-1 A S^-1 y), information
/// 1/2 tr(S^-1 A S^-1 A) (Mehra 1970); y is cut to a NIS of `SCORE_NIS_LIMIT` per dimension.
#[expect(non_snake_case, reason = "matrix notation")]
fn noise_score<const M: usize>(
    y: &SVector<f64, M>,
    chol: &nalgebra::Cholesky<f64, nalgebra::Const<M>>,
    nis: f64,
    H: &SMatrix<f64, M, 9>,
    sensitivity: &NoiseSensitivity,
) -> NoiseScore {
    let limit = SCORE_NIS_LIMIT * M as f64;
    let w = chol.solve(y)
        * if nis > limit {
            (limit / nis).sqrt()
        } else {
            1.0
        };
    let mut score = NoiseScore::default();
    for (j, dp) in sensitivity.iter().enumerate() {
        let A = H * dp * H.transpose();
        let SiA = chol.solve(&A);
        score.gradient[j] = -0.5 * (SiA.trace() - w.dot(&(A * w)));
        score.information[j] = 0.5 * (SiA * SiA).trace();
        score.share[j] = SiA.trace() / M as f64;
    }
    score
}

/// The covariance of (state, parameters) at an event, from the covariance `start` of the
/// propagation's start and the event's sensitivities: [[T, S], [0, I]] P [.]'.
fn covariance_at_event(s: &EventSensitivity, start: &AugmentedMatrix) -> AugmentedMatrix {
    let mut a = SMatrix::<f64, AUGMENTED, AUGMENTED>::identity();
    a.fixed_view_mut::<9, 9>(0, 0).copy_from(&s.before);
    if let Some(p) = &s.params {
        a.fixed_view_mut::<9, PARAMS>(0, 9).copy_from(&p.before);
    }
    a * start * a.transpose()
}

/// The scatter of one bounce from state `before`, in the state just after it, at the
/// configured sigmas of `noise`: the tangential impulse's and the restitution's.
pub(crate) fn bounce_scatter(
    propagator: &Propagator,
    noise: &BounceNoise,
    before: &StateVector,
) -> StateMatrix {
    let r = propagator.flight().radius();
    let spin_gain = 1.5 / r;
    let mut q = StateMatrix::zeros();
    let si2 = noise.impulse_sigma * noise.impulse_sigma;
    if si2 > 0.0 {
        // An impulse error d along x moves v_x by -d and w_y by +3/(2r) d; along y, v_y by
        // -d and w_x by -3/(2r) d.
        for (v, w, sign) in [(3, 7, 1.0), (4, 6, -1.0)] {
            let mut column = StateVector::zeros();
            column[v] = -1.0;
            column[w] = sign * spin_gain;
            q += column * column.transpose() * si2;
        }
    }
    let se = noise.restitution_sigma * before[5];
    q[(5, 5)] += se * se;
    q
}

/// The covariance of what a bounce's outcome depends on, (v, w, e_t, mu_t): state indices 3..9
/// and the table's two parameters.
pub(crate) type BounceInputs = SMatrix<f64, BOUNCE_SIGMA_DIMENSIONS, BOUNCE_SIGMA_DIMENSIONS>;

/// The index in (state, parameters) of each of (v, w, e_t, mu_t).
fn bounce_input_index(k: usize) -> usize {
    if k < 6 {
        3 + k
    } else {
        9 + RESTITUTION + (k - 6)
    }
}

/// The bounce's inputs' covariance from that of (state, parameters) at the bounce.
fn bounce_inputs_of(at_bounce: &AugmentedMatrix) -> BounceInputs {
    BounceInputs::from_fn(|i, j| at_bounce[(bounce_input_index(i), bounce_input_index(j))])
}

/// The bounce's inputs' covariance at an event, from the covariance `start` of the
/// propagation's start and the event's sensitivities: the rows of [[T, S], [0, I]] P [.]' that
/// it needs (a quarter of the arithmetic of [`covariance_at_event`]).
pub(crate) fn bounce_inputs_at_event(
    s: &EventSensitivity,
    start: &AugmentedMatrix,
) -> BounceInputs {
    let mut a = SMatrix::<f64, BOUNCE_SIGMA_DIMENSIONS, AUGMENTED>::zeros();
    for k in 0..BOUNCE_SIGMA_DIMENSIONS {
        let i = bounce_input_index(k);
        if i < 9 {
            a.fixed_view_mut::<1, 9>(k, 0).copy_from(&s.before.row(i));
            if let Some(p) = &s.params {
                a.fixed_view_mut::<1, PARAMS>(k, 9)
                    .copy_from(&p.before.row(i));
            }
        } else {
            a[(k, i)] = 1.0;
        }
    }
    let a_start = a * start;
    a_start * a.transpose()
}

/// How much the bounce's outcome really spreads beyond its linearisation: the covariance
/// of (v, w) after the bounce over sigma points of (v, w, e_t, mu_t) before it (the
/// unscented transform, [`BOUNCE_SIGMA_DIMENSIONS`] dimensions, kappa = 1; `c` their
/// covariance), less the linearised J C J', its positive part. Both regimes, and the spin's
/// uncertainty along the directions the linearisation misses, are in it.
pub(crate) fn unscented_excess(
    propagator: &Propagator,
    before: &StateVector,
    after: &StateVector,
    c: &BounceInputs,
) -> StateMatrix {
    const N: usize = BOUNCE_SIGMA_DIMENSIONS;
    let c = *c;
    let jitter = SMatrix::<f64, N, N>::identity() * (1e-12 * c.diagonal().amax() + 1e-18);
    let Some(chol) = (c + jitter).cholesky() else {
        return StateMatrix::zeros();
    };
    let kappa = 1.0;
    let spread = (N as f64 + kappa).sqrt();
    let (w0, wi) = (kappa / (N as f64 + kappa), 0.5 / (N as f64 + kappa));
    let l = chol.l();
    let bounce = propagator.bounce();
    let (e, mu) = bounce.table();
    let outcome = |offset: &SVector<f64, N>| -> SVector<f64, 6> {
        let mut x = *before;
        for k in 0..6 {
            x[3 + k] += offset[k];
        }
        let table = bounce.with_table((e + offset[6]).clamp(0.05, 1.0), (mu + offset[7]).max(0.0));
        table.apply(&x).state.fixed_rows::<6>(3).into_owned()
    };
    let mut outcomes = [SVector::<f64, 6>::zeros(); 2 * N + 1];
    outcomes[0] = outcome(&SVector::zeros());
    for k in 0..N {
        let column = l.column(k) * spread;
        outcomes[1 + k] = outcome(&column.into_owned());
        outcomes[1 + N + k] = outcome(&(-column).into_owned());
    }
    let mean = outcomes[0] * w0 + outcomes[1..].iter().sum::<SVector<f64, 6>>() * wi;
    let mut spread_cov = SMatrix::<f64, 6, 6>::zeros();
    for (k, y) in outcomes.iter().enumerate() {
        let d = y - mean;
        spread_cov += d * d.transpose() * if k == 0 { w0 } else { wi };
    }
    // The linearised covariance of the same outcome: G C G' with G = d(v', w')/d(v, w, e,
    // mu) at the mean.
    let b = bounce.apply(before);
    let mut gm = SMatrix::<f64, 6, N>::zeros();
    gm.fixed_view_mut::<6, 6>(0, 0)
        .copy_from(&b.jacobian.fixed_view::<6, 6>(3, 3));
    gm.fixed_view_mut::<6, 2>(0, 6)
        .copy_from(&b.table_jacobian.fixed_view::<6, 2>(3, 0));
    let linear = gm * c * gm.transpose();
    // The mean's own offset from the linearised outcome counts too.
    let offset = mean - after.fixed_rows::<6>(3);
    let excess = spread_cov - linear + offset * offset.transpose();
    let eigen = nalgebra::SymmetricEigen::new((excess + excess.transpose()) * 0.5);
    let positive = eigen.eigenvectors
        * SMatrix::<f64, 6, 6>::from_diagonal(&eigen.eigenvalues.map(|v| v.max(0.0)))
        * eigen.eigenvectors.transpose();
    let mut q = StateMatrix::zeros();
    q.fixed_view_mut::<6, 6>(3, 3).copy_from(&positive);
    q
}

/// The slowest flight whose direction a partial update trusts [m/s].
const PARTIAL_UPDATE_MIN_SPEED: f64 = 0.5;

/// Takes the fraction `withheld` of the gain's rows of the spin along the flight (the direction
/// of the velocity in `x`) out of `K` (over the state, N = 9, or with the parameters too):
/// K_w <- (I - withheld u u') K_w.
#[expect(non_snake_case, reason = "matrix notation")]
fn withhold_along_flight<const N: usize, const M: usize>(
    K: &mut SMatrix<f64, N, M>,
    x: &StateVector,
    withheld: f64,
) {
    let velocity = x.fixed_rows::<3>(3);
    let speed = velocity.norm();
    if speed < PARTIAL_UPDATE_MIN_SPEED {
        return;
    }
    let u = velocity / speed;
    for j in 0..M {
        let along = u.dot(&K.fixed_view::<3, 1>(6, j)) * withheld;
        for a in 0..3 {
            K[(6 + a, j)] -= u[a] * along;
        }
    }
}

/// The filter's estimate: state, parameters and their joint covariance.
#[derive(Debug, Clone, Copy, PartialEq)]
#[expect(non_snake_case, reason = "matrix notation")]
pub struct Ekf {
    /// State (position [m], velocity [m/s], spin [rad/s]).
    pub x: StateVector,
    /// The physical parameters (k_D, k_M, e_t, mu_t) [-].
    pub theta: ParamVector,
    /// Covariance of (state, parameters).
    pub P: AugmentedMatrix,
}

impl Ekf {
    /// A filter at a given estimate of the state, with parameters `theta` of covariance
    /// `p_theta`, uncorrelated with the state.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn new(
        x: StateVector,
        P: StateMatrix,
        theta: ParamVector,
        p_theta: ParamCovariance,
    ) -> Self {
        let mut augmented = with_known_params(&P);
        augmented
            .fixed_view_mut::<PARAMS, PARAMS>(9, 9)
            .copy_from(&p_theta);
        Self {
            x,
            theta,
            P: augmented,
        }
    }

    /// A filter at a given estimate of the state with the parameters known exactly (those of
    /// `propagator`).
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn with_known_params(x: StateVector, P: StateMatrix, propagator: &Propagator) -> Self {
        Self::new(
            x,
            P,
            propagator.params().to_vector(),
            ParamCovariance::zeros(),
        )
    }

    /// The covariance of the ball's state.
    pub fn state_covariance(&self) -> StateMatrix {
        self.P.fixed_view::<9, 9>(0, 0).into_owned()
    }

    /// The variance of the spin across the flight [(rad/s)^2]: the trace of its covariance
    /// projected on the plane perpendicular to the velocity (all of it for a ball at rest).
    pub fn spin_variance_across_flight(&self) -> f64 {
        let p = self.P.fixed_view::<3, 3>(6, 6).into_owned();
        let v = self.x.fixed_rows::<3>(3).into_owned();
        let speed = v.norm();
        if speed < 1e-9 {
            return p.trace();
        }
        let u = v / speed;
        (p.trace() - u.dot(&(p * u))).max(0.0)
    }

    /// The covariance of the parameters.
    pub fn param_covariance(&self) -> ParamCovariance {
        self.P.fixed_view::<PARAMS, PARAMS>(9, 9).into_owned()
    }

    /// The parameters.
    pub fn params(&self) -> PhysicsParams {
        PhysicsParams::from_vector(&self.theta)
    }

    /// Propagates the estimate by `dt` seconds (dt >= 0) through flight and bounces, with the
    /// filter's parameters in `propagator`'s model and its `model` of what the physics leaves
    /// out, the noise times `scales`; `sensitivity`, the covariance's dependence on the scales,
    /// is carried along when given.
    pub fn predict(
        &mut self,
        propagator: &Propagator,
        model: &FilterNoise,
        scales: &NoiseScales,
        sensitivity: Option<&mut NoiseSensitivity>,
        dt: f64,
    ) -> PredictReport {
        self.propagate(propagator, model, scales, sensitivity, dt, None)
    }

    /// [`Self::predict`] linearised at a nominal `(x, theta)` rather than at the estimate (the
    /// forward pass of an iterated smoother, Bell 1994): the nominal is flown through the model,
    /// the estimate's deviation from it by the nominal's transition, `x' = f(x_n) + Phi (x -
    /// x_n) + S (theta - theta_n)`, and the covariance by the same `[Phi, S]`.
    ///
    /// A bounce's spread beyond its linearisation (`ekf.bounce_unscented`) is taken at
    /// `nominal_covariance` when given (a smoother's covariance of the nominal, what the whole
    /// flight knows of the state there), else at the estimate's own.
    ///
    /// Returns the report and the transition of (state, parameters), `[[Phi, S], [0, I]]`.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn predict_about(
        &mut self,
        nominal: (&StateVector, &ParamVector),
        nominal_covariance: Option<&AugmentedMatrix>,
        propagator: &Propagator,
        model: &FilterNoise,
        scales: &NoiseScales,
        dt: f64,
    ) -> (PredictReport, AugmentedMatrix) {
        let deviation = (self.x - nominal.0, self.theta - nominal.1);
        self.x = *nominal.0;
        self.theta = *nominal.1;
        let mut transition = AugmentedMatrix::identity();
        let report = self.propagate(
            propagator,
            model,
            scales,
            None,
            dt,
            Some(Nominal {
                transition: &mut transition,
                covariance: nominal_covariance,
            }),
        );
        self.theta += deviation.1;
        let (Phi, S) = (
            transition.fixed_view::<9, 9>(0, 0).into_owned(),
            transition.fixed_view::<9, PARAMS>(0, 9).into_owned(),
        );
        self.x += Phi * deviation.0 + S * deviation.1;
        (report, transition)
    }

    /// [`Self::predict`], writing the transition of (state, parameters) into the nominal's
    /// `transition` when given, and spreading a bounce's outcome by the nominal's covariance
    /// when it has one.
    #[expect(non_snake_case, reason = "matrix notation")]
    fn propagate(
        &mut self,
        propagator: &Propagator,
        model: &FilterNoise,
        scales: &NoiseScales,
        sensitivity: Option<&mut NoiseSensitivity>,
        dt: f64,
        nominal: Option<Nominal<'_>>,
    ) -> PredictReport {
        if dt <= 0.0 {
            return PredictReport::default();
        }
        let (noise, bounce_noise) = (&model.process, &model.bounce);
        let propagator = propagator.with_params(&self.params());
        let propagator = if model.spin_spread > 0.0 {
            propagator.with_spin_variance(
                model.spin_spread * model.spin_spread * self.spin_variance_across_flight(),
            )
        } else {
            propagator
        };
        let tracks_params = self.param_covariance() != ParamCovariance::zeros();
        let mut cursor = if tracks_params {
            Cursor::tracking_params(0.0, self.x)
        } else {
            Cursor::tracking(0.0, self.x)
        };
        let mut watch = BounceWatch {
            report: PredictReport::default(),
            propagator: &propagator,
            noise: bounce_noise,
            start: nominal
                .as_ref()
                .and_then(|n| n.covariance)
                .unwrap_or(&self.P),
            scatter: StateMatrix::zeros(),
            excess: StateMatrix::zeros(),
            sliding: 1.0,
        };
        propagator.advance(&mut cursor, dt, Watch::BOUNCES, &mut watch);
        let (report, scatter, excess, sliding) =
            (watch.report, watch.scatter, watch.excess, watch.sliding);
        let P_xx = self.state_covariance();
        let mut next = AugmentedMatrix::zeros();
        // Q: the white acceleration's and the spin random walk's at the configured densities
        // times their scales (each part at the configured density is dQ/ds).
        let (q_acceleration, q_spin) = noise.discretise_parts(dt);
        let mut P_xx_next = q_acceleration * scales.acceleration + q_spin * scales.spin;
        // The bounces' scatter (at the configured sigmas), carried by the flight since the last
        // one: in P times its scale, and dP/ds of that scale.
        let carried_scatter = match &cursor.tangent {
            Some(tangent) if report.bounces > 0 => tangent.carry_flight(&scatter),
            _ => scatter,
        };
        if let Some(d) = sensitivity {
            // dP/ds: carried like P, plus each scaled noise at its configured size.
            let [d_acceleration, d_spin, d_bounce] = d;
            let carry = |m: &StateMatrix| match &cursor.tangent {
                Some(tangent) => tangent.carry_covariance(m),
                None => *m,
            };
            *d_acceleration = symmetrise(&(carry(d_acceleration) + q_acceleration));
            *d_spin = symmetrise(&(carry(d_spin) + q_spin));
            *d_bounce = symmetrise(&(carry(d_bounce) + carried_scatter));
        }
        match cursor.tangent {
            Some(tangent) => {
                // Phi P_xx Phi' (in the flight's block structure before any event).
                P_xx_next += tangent.carry_covariance(&P_xx);
                if report.bounces > 0 {
                    P_xx_next += carried_scatter * scales.bounce + tangent.carry_flight(&excess);
                }
                if let Some(S) = tangent.params() {
                    let P_xt = self.P.fixed_view::<9, PARAMS>(0, 9).into_owned();
                    let P_tt = self.param_covariance();
                    // [[Phi, S], [0, I]] P [[Phi, S], [0, I]]'.
                    let B = tangent.transition() * P_xt;
                    let C = S * P_tt;
                    let cross = B + C;
                    P_xx_next += B * S.transpose() + S * B.transpose() + C * S.transpose();
                    next.fixed_view_mut::<9, PARAMS>(0, 9).copy_from(&cross);
                    next.fixed_view_mut::<PARAMS, 9>(9, 0)
                        .copy_from(&cross.transpose());
                }
            }
            None => P_xx_next += P_xx + carried_scatter * scales.bounce + excess,
        }
        next.fixed_view_mut::<9, 9>(0, 0).copy_from(&P_xx_next);
        let mut P_tt = self.param_covariance();
        if tracks_params {
            for i in 0..PARAMS {
                P_tt[(i, i)] += noise.param_density[i] * dt;
            }
        }
        next.fixed_view_mut::<PARAMS, PARAMS>(9, 9).copy_from(&P_tt);
        if sliding < 1.0 {
            // A bounce that may have rolled out or slid: its outcome depends on the friction
            // only if it slid. The state keeps its correlation with the friction in that
            // proportion (the outcome's covariance with mu_t over the two regimes, the
            // linearised one's times the probability of sliding); its uncertainty stays in the
            // state's covariance. A rolling bounce read as sliding would teach it a value too low.
            for i in 0..9 {
                next[(i, 9 + FRICTION)] *= sliding;
                next[(9 + FRICTION, i)] *= sliding;
            }
        }
        self.x = cursor.state;
        if let (
            Some(Nominal {
                transition: out, ..
            }),
            Some(tangent),
        ) = (nominal, &cursor.tangent)
        {
            out.fixed_view_mut::<9, 9>(0, 0)
                .copy_from(&tangent.transition());
            if let Some(S) = tangent.params() {
                out.fixed_view_mut::<9, PARAMS>(0, 9).copy_from(&S);
            }
        }
        self.P = symmetrise(&next);
        report
    }

    /// Fuses a measurement of the ball's state z = H x + noise(R) when its NIS is within `gate`;
    /// returns the NIS and, given the covariance's sensitivity to the noise scales (`noise`,
    /// which the update carries along), their score when it is asked for. The parameters move
    /// with their correlation to the state.
    ///
    /// The score: with A = H D H' for D = dP^-/ds of each noise scale ([`NoiseSensitivity`]),
    /// d log N(y; 0, S) = -1/2 (tr(S^-1 A) - y' S^-1 A S^-1 y), information 1/2 tr(S^-1 A S^-1 A)
    /// (the innovation's likelihood as a function of the noise, Mehra 1970); y is cut to a NIS
    /// of `SCORE_NIS_LIMIT` per dimension.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn update<const M: usize>(
        &mut self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
        gate: f64,
        noise: Option<NoiseCarry<'_>>,
    ) -> Result<Fused, UpdateError> {
        self.update_partially(z, H, R, gate, noise, 1.0)
    }

    /// [`Self::update`] with only the fraction `along_flight` in [0, 1] of the gain applied to
    /// the spin along the flight (the estimate's velocity direction): the partial-update
    /// Schmidt-Kalman filter (Brink 2017) on that one direction. The covariance is the Joseph
    /// form's for the gain applied, so it stays that of the estimate; 1 is the plain update.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn update_partially<const M: usize>(
        &mut self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
        gate: f64,
        noise: Option<NoiseCarry<'_>>,
        along_flight: f64,
    ) -> Result<Fused, UpdateError> {
        if !z.iter().chain(R.iter()).all(|v| v.is_finite()) {
            return Err(UpdateError::NotFinite);
        }
        let y = z - H * self.x;
        let PHt: SMatrix<f64, AUGMENTED, M> = self.P.fixed_columns::<9>(0) * H.transpose();
        let S = H * PHt.fixed_rows::<9>(0) + R;
        let chol = symmetrise(&S)
            .cholesky()
            .ok_or(UpdateError::NotPositiveDefinite)?;
        let nis = y.dot(&chol.solve(&y));
        if !nis.is_finite() {
            return Err(UpdateError::NotPositiveDefinite);
        }
        if nis > gate {
            return Err(UpdateError::Gated { nis, gate });
        }
        // The score of the noise scales, before the update moves D.
        let score = noise
            .as_ref()
            .filter(|carry| carry.scored)
            .map(|carry| noise_score(&y, &chol, nis, H, carry.sensitivity))
            .unwrap_or_default();
        // K = P H' S^-1 = (S^-1 H P)'.
        let mut K = chol.solve(&PHt.transpose()).transpose();
        if along_flight < 1.0 {
            withhold_along_flight(&mut K, &self.x, 1.0 - along_flight);
        }
        let dx = K * y;
        self.x += dx.fixed_rows::<9>(0);
        self.theta += dx.fixed_rows::<PARAMS>(9);
        for (i, (low, high)) in PARAM_BOUNDS.iter().enumerate() {
            self.theta[i] = self.theta[i].clamp(*low, *high);
        }
        // The Joseph form (I - K H) P (I - K H)' + K R K', multiplied out with S = H P H' + R:
        // P - K (P H')' - (P H') K' + K S K'. Equal to it for any gain, so a rounding error in K
        // still changes P to second order only.
        let K_PHt = K * PHt.transpose();
        self.P = symmetrise(&(self.P - K_PHt - K_PHt.transpose() + K * S * K.transpose()));
        let I_KH = StateMatrix::identity() - K.fixed_rows::<9>(0) * H;
        for d in noise
            .into_iter()
            .flat_map(|carry| carry.sensitivity.iter_mut())
        {
            *d = symmetrise(&(I_KH * *d * I_KH.transpose()));
        }
        Ok(Fused {
            nis,
            whole_nis: nis,
            score,
        })
    }

    /// Forgets what the filter learned about the spin: its covariance goes back to `variance`
    /// [(rad/s)^2] per axis, uncorrelated with the rest (the estimate itself is kept), and no
    /// longer depends on the noise scales (`sensitivity`, when given).
    pub fn reset_spin(&mut self, variance: f64, mut sensitivity: Option<&mut NoiseSensitivity>) {
        for i in 6..9 {
            for j in 0..AUGMENTED {
                self.P[(i, j)] = 0.0;
                self.P[(j, i)] = 0.0;
            }
            self.P[(i, i)] = variance;
            for d in sensitivity.iter_mut().flat_map(|d| d.iter_mut()) {
                for j in 0..9 {
                    d[(i, j)] = 0.0;
                    d[(j, i)] = 0.0;
                }
            }
        }
    }

    /// What a measurement z = H x + noise(R) says of the noise scales, without fusing it: its NIS
    /// and the score of the scales given the covariance's `sensitivity` to them (as
    /// [`Ekf::update`] computes it); None when its innovation's covariance is not positive
    /// definite or anything is not finite. For the innovation of a prediction further ahead than
    /// the next measurement (`ekf.model_noise_horizon`).
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn score<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
        sensitivity: &NoiseSensitivity,
    ) -> Option<Fused> {
        if !z.iter().chain(R.iter()).all(|v| v.is_finite()) {
            return None;
        }
        let (y, chol, nis) = self.innovation(z, H, R)?;
        nis.is_finite().then(|| Fused {
            nis,
            whole_nis: nis,
            score: noise_score(&y, &chol, nis, H, sensitivity),
        })
    }

    /// The NIS of a measurement and the log-determinant of its innovation's covariance, without
    /// fusing it: twice the negative log-likelihood of the measurement under the estimate, up
    /// to a constant, is their sum. None when S is not positive definite.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn nis_and_log_det<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
    ) -> Option<(f64, f64)> {
        let (_, chol, nis) = self.innovation(z, H, R)?;
        let log_det = 2.0
            * chol
                .l_dirty()
                .diagonal()
                .iter()
                .map(|v| v.ln())
                .sum::<f64>();
        (nis.is_finite() && log_det.is_finite()).then_some((nis, log_det))
    }

    /// The normalised innovation squared of a measurement, without fusing it.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn nis<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
    ) -> Option<f64> {
        self.innovation(z, H, R).map(|(_, _, nis)| nis)
    }

    /// The innovation y = z - H x of a measurement, the Cholesky factor of its covariance
    /// S = H P H' + R, and its NIS y' S^-1 y; None when S is not positive definite.
    #[expect(non_snake_case, reason = "matrix notation")]
    fn innovation<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
    ) -> Option<(
        SVector<f64, M>,
        nalgebra::Cholesky<f64, nalgebra::Const<M>>,
        f64,
    )> {
        let y = z - H * self.x;
        let S = H * self.state_covariance() * H.transpose() + R;
        let chol = symmetrise(&S).cholesky()?;
        let nis = y.dot(&chol.solve(&y));
        Some((y, chol, nis))
    }
}

/// (A + A') / 2.
pub fn symmetrise<const N: usize>(a: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    (a + a.transpose()) * 0.5
}

/// H of a position measurement: [I 0 0].
#[expect(non_snake_case, reason = "matrix notation")]
pub fn position_H() -> SMatrix<f64, 3, 9> {
    SMatrix::<f64, 3, 9>::from_fn(|i, j| if i == j { 1.0 } else { 0.0 })
}

/// H of a position + spin measurement: [[I 0 0], [0 0 I]].
#[expect(non_snake_case, reason = "matrix notation")]
pub fn position_spin_H() -> SMatrix<f64, 6, 9> {
    SMatrix::<f64, 6, 9>::from_fn(|i, j| {
        if (i < 3 && j == i) || (i >= 3 && j == i + 3) {
            1.0
        } else {
            0.0
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;
    use nalgebra::{Matrix3, Vector3};

    #[test]
    fn process_noise_matches_the_white_acceleration_model() {
        let q = ProcessNoise {
            acceleration_density: 2.0,
            spin_density: 5.0,
            param_density: ParamVector::zeros(),
        }
        .discretise(0.1);
        assert!((q[(0, 0)] - 2.0 * 1e-3 / 3.0).abs() < 1e-15);
        assert!((q[(0, 3)] - 2.0 * 1e-2 / 2.0).abs() < 1e-15);
        assert!((q[(3, 3)] - 0.2).abs() < 1e-15);
        assert!((q[(6, 6)] - 0.5).abs() < 1e-15);
        assert_eq!(q, q.transpose());
        assert!(q.cholesky().is_some(), "Q is positive definite");
    }

    /// A linear-Gaussian sanity check: one position update of a prior with P = I and R = I moves
    /// the estimate halfway and halves the variance.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn update_halves_variance_for_equal_prior_and_noise() {
        let mut ekf = Ekf::new(
            StateVector::zeros(),
            StateMatrix::identity(),
            ParamVector::repeat(0.5),
            ParamCovariance::zeros(),
        );
        let z = Vector3::new(1.0, -2.0, 0.5);
        let R = Matrix3::identity();
        let nis = ekf
            .update(&z, &position_H(), &R, 100.0, None)
            .expect("fused")
            .nis;
        assert!((nis - z.norm_squared() / 2.0).abs() < 1e-12);
        assert!((ekf.x[0] - 0.5).abs() < 1e-12 && (ekf.x[1] + 1.0).abs() < 1e-12);
        assert!((ekf.P[(0, 0)] - 0.5).abs() < 1e-12);
        assert_eq!(ekf.P[(3, 3)], 1.0);
        assert_eq!(ekf.theta, ParamVector::repeat(0.5));
        let far = Vector3::new(50.0, 0.0, 0.0);
        assert!(matches!(
            ekf.update(&far, &position_H(), &R, 10.0, None),
            Err(UpdateError::Gated { .. })
        ));
    }

    /// The likelihood terms of a measurement without fusing it: its NIS and ln det S, against
    /// S = H P H' + R and its determinant computed directly.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn the_nis_and_log_det_are_those_of_the_innovation() {
        let mut P = StateMatrix::identity() * 2e-4;
        P[(0, 1)] = 5e-5;
        P[(1, 0)] = 5e-5;
        let ekf = Ekf::new(
            StateVector::zeros(),
            P,
            ParamVector::repeat(1.0),
            ParamCovariance::zeros(),
        );
        let z = Vector3::new(0.01, -0.02, 0.005);
        let R = Matrix3::identity() * 4e-6;
        let (nis, log_det) = ekf
            .nis_and_log_det(&z, &position_H(), &R)
            .expect("S positive definite");
        let S = P.fixed_view::<3, 3>(0, 0) + R;
        let expected = z.dot(&(S.try_inverse().expect("invertible") * z));
        assert!((nis - expected).abs() < 1e-9 * expected, "{nis} {expected}");
        assert!((log_det - S.determinant().ln()).abs() < 1e-9, "{log_det}");
        assert_eq!(ekf.nis(&z, &position_H(), &R), Some(nis));
    }

    /// A state and a covariance with every component correlated.
    fn correlated_prior() -> (StateVector, StateMatrix) {
        let a = StateMatrix::from_fn(|i, j| ((i * 7 + j * 3) % 5) as f64 * 0.1 - 0.2);
        (
            StateVector::from_fn(|i, _| i as f64 * 0.3),
            a * a.transpose() + StateMatrix::identity() * 0.5,
        )
    }

    /// The multiplied-out covariance update equals the Joseph form written as products, for a
    /// correlated prior and a position + spin measurement.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn update_covariance_is_the_joseph_form() {
        let (x, P) = correlated_prior();
        let H = position_spin_H();
        let R = SMatrix::<f64, 6, 6>::from_diagonal_element(0.2);
        let z = H * x + SVector::<f64, 6>::from_fn(|i, _| 0.1 * i as f64 - 0.2);
        let mut ekf = Ekf::new(x, P, ParamVector::repeat(0.5), ParamCovariance::zeros());
        ekf.update(&z, &H, &R, 1e6, None).expect("fused");
        let S = H * P * H.transpose() + R;
        let K = P * H.transpose() * S.try_inverse().expect("S invertible");
        let I_KH = StateMatrix::identity() - K * H;
        let joseph = I_KH * P * I_KH.transpose() + K * R * K.transpose();
        let p9 = ekf.state_covariance();
        assert!(
            (p9 - joseph).amax() < 1e-13 * P.amax(),
            "{}",
            (p9 - joseph).amax()
        );
        assert!((ekf.x - (x + K * (z - H * x))).amax() < 1e-13);
        assert_eq!(ekf.P, ekf.P.transpose());
    }

    /// A position update that applies `keep` of its gain to the spin along the flight: the
    /// state moves by that gain, and the covariance is the Joseph form's for it (with the
    /// parameters uncorrelated, the 9-state one).
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn a_partial_update_moves_the_spin_along_the_flight_by_its_share_and_stays_honest() {
        let (x, P) = correlated_prior();
        let H = position_H();
        let R = SMatrix::<f64, 3, 3>::from_diagonal_element(0.2);
        let z = H * x + SVector::<f64, 3>::new(0.3, -0.2, 0.1);
        let u = x.fixed_rows::<3>(3).normalize();
        let S = H * P * H.transpose() + R;
        let K_plain = P * H.transpose() * S.try_inverse().expect("S invertible");
        let mut plain = Ekf::new(x, P, ParamVector::repeat(0.5), ParamCovariance::zeros());
        let mut same = plain;
        plain.update(&z, &H, &R, 1e6, None).expect("fused");
        same.update_partially(&z, &H, &R, 1e6, None, 1.0)
            .expect("fused");
        assert_eq!(plain, same, "a partial update of 1 is the plain update");
        for keep in [0.0, 0.5] {
            let mut ekf = Ekf::new(x, P, ParamVector::repeat(0.5), ParamCovariance::zeros());
            ekf.update_partially(&z, &H, &R, 1e6, None, keep)
                .expect("fused");
            // The gain applied: its share along the flight is checked on the state just below.
            let mut K = K_plain;
            withhold_along_flight(&mut K, &x, 1.0 - keep);
            let moved = |e: &Ekf| (e.x - x).fixed_rows::<3>(6).dot(&u);
            let plain_along = moved(&plain);
            assert!(plain_along.abs() > 1e-3, "{plain_along}");
            assert!((moved(&ekf) - keep * plain_along).abs() < 1e-12);
            // The spin across the flight moves as in the plain update.
            let across = |e: &Ekf| {
                let w = (e.x - x).fixed_rows::<3>(6).into_owned();
                w - u * w.dot(&u)
            };
            assert!((across(&ekf) - across(&plain)).amax() < 1e-12);
            let I_KH = StateMatrix::identity() - K * H;
            let joseph = I_KH * P * I_KH.transpose() + K * R * K.transpose();
            let p9 = ekf.state_covariance();
            assert!((p9 - joseph).amax() < 1e-13 * P.amax(), "keep {keep}");
            assert!((ekf.x - (x + K * (z - H * x))).amax() < 1e-13);
        }
    }

    #[test]
    fn predict_counts_bounces_and_grows_uncertainty() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let x = crate::physics::BallState::new(
            Vector3::new(-0.5, 0.0, 0.05),
            Vector3::new(-4.0, 0.0, -1.0),
            Vector3::zeros(),
        )
        .to_vector();
        let mut ekf = Ekf::with_known_params(x, StateMatrix::identity() * 1e-6, &propagator);
        let noise = ProcessNoise {
            acceleration_density: 1.0,
            spin_density: 1.0,
            param_density: ParamVector::zeros(),
        };
        let model = FilterNoise {
            process: noise,
            bounce: BounceNoise::default(),
            spin_spread: 0.0,
        };
        let report = ekf.predict(&propagator, &model, &NoiseScales::default(), None, 0.05);
        assert_eq!(report.bounces, 1);
        assert_eq!(report.robot_half_bounces, 1);
        assert!(ekf.x[5] > 0.0);
        assert!(ekf.P[(3, 3)] > 1e-6);
        assert_eq!(ekf.P, ekf.P.transpose());
    }

    /// A prediction linearised at a nominal: at the estimate itself it is the prediction; at a
    /// nominal off the estimate its mean is the nominal's flight plus the transition times the
    /// offset (first order: within a small fraction of the offset's effect of the prediction
    /// from the estimate), its covariance the prediction's at the nominal, and the parameters
    /// keep the estimate's.
    #[test]
    fn a_prediction_about_a_nominal_is_the_linearised_one() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let x = crate::physics::BallState::new(
            Vector3::new(0.6, 0.1, 0.25),
            Vector3::new(-6.0, 0.2, -1.0),
            Vector3::new(0.0, 300.0, 20.0),
        )
        .to_vector();
        let theta = propagator.params().to_vector();
        let ekf = Ekf::new(
            x,
            StateMatrix::identity() * 1e-4,
            theta,
            ParamCovariance::from_diagonal_element(1e-3),
        );
        let model = FilterNoise {
            process: ProcessNoise {
                acceleration_density: 1.0,
                spin_density: 1.0,
                param_density: ParamVector::zeros(),
            },
            bounce: BounceNoise::default(),
            spin_spread: 0.5,
        };
        let scales = NoiseScales::default();
        // Through a bounce.
        let dt = 0.3;
        let mut plain = ekf;
        plain.predict(&propagator, &model, &scales, None, dt);
        let mut about = ekf;
        about.predict_about((&x, &theta), None, &propagator, &model, &scales, dt);
        assert!((about.x - plain.x).amax() < 1e-12, "{}", about.x - plain.x);
        assert!((about.P - plain.P).amax() < 1e-12 * plain.P.amax());

        let mut offset = StateVector::zeros();
        offset[6] = 30.0;
        offset[4] = 0.05;
        let nominal = x + offset;
        let mut nominal_flight = ekf;
        nominal_flight.x = nominal;
        nominal_flight.predict(&propagator, &model, &scales, None, dt);
        let mut about = ekf;
        let (report, transition) =
            about.predict_about((&nominal, &theta), None, &propagator, &model, &scales, dt);
        assert_eq!(report.bounces, 1);
        let linear = nominal_flight.x - transition.fixed_view::<9, 9>(0, 0) * offset;
        assert!((about.x - linear).amax() < 1e-9, "{}", about.x - linear);
        assert!((about.P - nominal_flight.P).amax() < 1e-12 * plain.P.amax());
        assert_eq!(about.theta, theta);
        let effect = (nominal_flight.x - plain.x).fixed_rows::<3>(0).norm();
        let miss = (about.x - plain.x).fixed_rows::<3>(0).norm();
        assert!(
            effect > 5e-3 && miss < 0.05 * effect,
            "{miss} against {effect}"
        );
    }

    /// `Ekf::score` (a prediction further ahead, not fused) gives the NIS and the score of the
    /// noise scales that `Ekf::update` gives for the same measurement.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn a_prediction_is_scored_as_an_update_scores_it() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let start = crate::physics::BallState::new(
            Vector3::new(1.0, 0.1, 0.3),
            Vector3::new(-5.0, 0.3, 1.0),
            Vector3::new(10.0, 120.0, -20.0),
        )
        .to_vector();
        let mut ekf = Ekf::with_known_params(start, StateMatrix::identity() * 1e-4, &propagator);
        let mut d = [StateMatrix::zeros(); NOISE_SCALES];
        let model = FilterNoise {
            process: ProcessNoise {
                acceleration_density: config.ekf.acceleration_noise_density,
                spin_density: config.ekf.spin_noise_density,
                param_density: ParamVector::zeros(),
            },
            bounce: BounceNoise::from_config(&config),
            spin_spread: 0.0,
        };
        ekf.predict(
            &propagator,
            &model,
            &NoiseScales::default(),
            Some(&mut d),
            0.1,
        );
        let (H, R) = (position_H(), Matrix3::identity() * 4e-6);
        let z = ekf.x.fixed_rows::<3>(0) + Vector3::new(0.004, -0.002, 0.003);
        let scored = ekf.score(&z, &H, &R, &d).expect("scored");
        let (before, d_before) = (ekf, d);
        let fused = ekf
            .update(&z, &H, &R, 1e9, carry(&mut d, true))
            .expect("fused");
        // The same arithmetic: equal to the last bit.
        assert_eq!(scored, fused);
        assert!(scored.score.information[0] > 0.0, "{scored:?}");

        // An update asked for no score carries the sensitivity exactly as one that scores.
        let (mut quiet, mut quiet_d) = (before, d_before);
        let unscored = quiet
            .update(&z, &H, &R, 1e9, carry(&mut quiet_d, false))
            .expect("fused");
        assert_eq!(unscored.score, NoiseScore::default());
        assert_eq!(unscored.nis, fused.nis);
        assert_eq!((quiet.x, quiet.P), (ekf.x, ekf.P));
        assert_eq!(quiet_d, d);
        assert_ne!(d, d_before, "the update moved the sensitivity");
    }

    /// The sensitivity `d` carried through an update, scored or not.
    fn carry(d: &mut NoiseSensitivity, scored: bool) -> Option<NoiseCarry<'_>> {
        Some(NoiseCarry {
            sensitivity: d,
            scored,
        })
    }

    /// The filter's dP/ds of each noise scale, carried through flight, a bounce and updates,
    /// against central differences of the innovation covariance S = H P^- H' + R between two
    /// filters run with the scale moved up and down; and the score's gradient against the
    /// difference of the innovation's log-likelihood with the innovation held.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn the_noise_sensitivity_matches_finite_differences() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let start = crate::physics::BallState::new(
            Vector3::new(-0.3, 0.02, 0.045),
            Vector3::new(-4.0, 0.2, -1.5),
            Vector3::new(20.0, -150.0, 30.0),
        )
        .to_vector();
        let noise = ProcessNoise {
            acceleration_density: 0.05,
            spin_density: 200.0,
            param_density: ParamVector::zeros(),
        };
        let bounce_noise = BounceNoise {
            impulse_sigma: 0.1,
            restitution_sigma: 0.02,
            unscented: true,
        };
        let R = Matrix3::identity() * 1e-6;
        let H = position_H();
        // Six steps of 10 ms, the bounce in the second; the same measurements for every run.
        let truth = crate::physics::predict(
            &propagator,
            &crate::physics::BallState::from_vector(&start),
            &crate::physics::PredictOptions {
                horizon: 0.06,
                sample_interval: 0.01,
                plane_x: None,
                stop_at_plane: false,
            },
        );
        let run = |scales: &NoiseScales| {
            let mut ekf =
                Ekf::with_known_params(start, StateMatrix::identity() * 1e-4, &propagator);
            let mut d = [StateMatrix::zeros(); NOISE_SCALES];
            let mut last = None;
            for (k, sample) in truth.samples.iter().skip(1).enumerate() {
                let model = FilterNoise {
                    process: noise,
                    bounce: bounce_noise,
                    spin_spread: 0.0,
                };
                let report = ekf.predict(&propagator, &model, scales, Some(&mut d), 0.01);
                if k == 1 {
                    assert_eq!(report.bounces, 1, "the bounce is in the second step");
                }
                let z = sample.state.position + Vector3::new(0.001, -0.0005, 0.0008);
                let S = H * ekf.state_covariance() * H.transpose() + R;
                let sensitivity = d;
                let y = z - H * ekf.x;
                let fused = ekf
                    .update(&z, &H, &R, 1e9, carry(&mut d, true))
                    .expect("fused");
                last = Some((S, sensitivity, y, fused.score));
            }
            last.expect("steps")
        };
        let base = NoiseScales::from_array([0.7, 1.3, 0.9]);
        let (_, sensitivity, y, score) = run(&base);
        for j in 0..NOISE_SCALES {
            let h = 1e-4;
            let moved = |sign: f64| {
                let mut a = base.to_array();
                a[j] += sign * h;
                run(&NoiseScales::from_array(a)).0
            };
            let (up, down) = (moved(1.0), moved(-1.0));
            let numeric = (up - down) / (2.0 * h);
            let analytic = H * sensitivity[j] * H.transpose();
            assert!(analytic.amax() > 1e-9, "scale {j} matters: {analytic}");
            assert!(
                (numeric - analytic).amax() < 2e-3 * analytic.amax(),
                "scale {j}: {numeric} vs {analytic}"
            );
            // d/ds of log N(y; 0, S(s)) with y held.
            let log_likelihood = |S: &Matrix3<f64>| {
                let chol = S.cholesky().expect("S");
                -0.5 * (y.dot(&chol.solve(&y)) + chol.ln_determinant())
            };
            let numeric_gradient = (log_likelihood(&up) - log_likelihood(&down)) / (2.0 * h);
            assert!(
                (score.gradient[j] - numeric_gradient).abs()
                    < 2e-3 * numeric_gradient.abs().max(1e-3),
                "scale {j}: gradient {} vs {numeric_gradient}",
                score.gradient[j]
            );
            assert!(score.information[j] > 0.0);
        }
    }
}

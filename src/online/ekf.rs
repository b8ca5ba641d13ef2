//! The extended Kalman filter over the ball's 9-state (position, velocity, spin) in the `table`
//! frame, augmented with the 4 physical parameters it learns (drag and Magnus scale factors,
//! the table's restitution and friction: [`crate::physics::params`]).
//!
//! Each step is a pure function of the estimate that returns its parts, as the Kalman
//! literature writes them:
//!
//! - [`Ekf::predict`]: the physics core's propagation at the filter's own parameters
//!   (spin-parameter aero model, table bounce inside the step, with the state transition Phi,
//!   its contact-time sensitivity and the state's sensitivity S to the parameters) gives x and
//!   F = [[Phi, S], [0, I]]; P = F P F' + Q + Q_b. Q is the continuous white acceleration of
//!   density q_a [m^2/s^3] on the velocity, a spin random walk of density q_w [(rad/s)^2/s] and a
//!   random walk of each parameter, discretised over dt: Q_pp = q_a dt^3/3, Q_pv = q_a dt^2/2,
//!   Q_vv = q_a dt, Q_ww = q_w dt (each times I_3), Q_theta = q_theta dt. Q_b is a table bounce's
//!   scatter ([`BounceNoise`]): an uncertain tangential impulse (sigma_i per axis, per unit
//!   mass, which moves the velocity and, through the shell's inertia, the spin by 3/(2r) per
//!   m/s) and an uncertain restitution of that one bounce (sigma_e |v_z|), and the outcome's
//!   spread over the state's uncertainty beyond its linearisation
//!   ([`crate::online::bounce_spread`]), carried to the end of the step by the flight after the
//!   bounce. The state keeps its correlation with the friction
//!   only in proportion to the probability that the bounce slid (from the margin that decides
//!   the regime, Gaussian with its propagated variance): a rolling bounce says nothing of it.
//! - [`Ekf::update`]: y = z - H x, S = H P H' + R factored by Cholesky (a typed error when S is
//!   not positive definite), NIS = y' S^-1 y, K = P H' S^-1, and the Joseph form
//!   P = (I - K H) P (I - K H)' + K R K' (multiplied out), symmetrised; the parameters are kept
//!   inside their physical box ([`PARAM_BOUNDS`]). [`Ekf::update_partially`] applies only a
//!   share of the gain to the spin along the flight (the partial-update Schmidt-Kalman filter,
//!   Brink 2017), the covariance the Joseph form's for the gain applied.
//!
//! Fixed-size matrices throughout: no heap allocation.

use nalgebra::{SMatrix, SVector};

use crate::config::Config;
use crate::model::stats::normal_cdf;
use crate::online::bounce_spread::{bounce_inputs_at_event, bounce_spread};
pub use crate::physics::params::{AUGMENTED, AugmentedMatrix, ParamCovariance};
use crate::physics::params::{FRICTION, RESTITUTION, with_known_params};
use crate::physics::{
    Cursor, Event, EventKind, EventSensitivity, Flow, Observer, PARAMS, ParamVector, PhysicsParams,
    Propagator, StateMatrix, StateVector, Tangent, Watch,
};

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
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn discretise(&self, dt: f64) -> StateMatrix {
        let dt = dt.abs();
        let qa = self.acceleration_density;
        let mut Q = StateMatrix::zeros();
        for i in 0..3 {
            Q[(i, i)] = qa * dt * dt * dt / 3.0;
            Q[(i, i + 3)] = qa * dt * dt / 2.0;
            Q[(i + 3, i)] = qa * dt * dt / 2.0;
            Q[(i + 3, i + 3)] = qa * dt;
            Q[(i + 6, i + 6)] = self.spin_density * dt;
        }
        Q
    }
}

/// The scatter of one table bounce (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct BounceNoise {
    /// sigma_i: the tangential impulse per unit mass, per axis [m/s].
    pub impulse_sigma: f64,
    /// sigma_e: the restitution of one bounce about the table's [-].
    pub restitution_sigma: f64,
}

impl BounceNoise {
    /// The bounce scatter the configuration sets (`ekf.bounce_*`).
    pub fn from_config(config: &Config) -> Self {
        Self {
            impulse_sigma: config.ekf.bounce_impulse_sigma,
            restitution_sigma: config.ekf.bounce_restitution_sigma,
        }
    }
}

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

/// One prediction step and its parts.
#[derive(Debug, Clone, Copy, PartialEq)]
#[expect(non_snake_case, reason = "matrix notation")]
pub struct Prediction {
    /// The estimate at the end of the step.
    pub ekf: Ekf,
    /// F: the transition of (state, parameters) over the step, [[Phi, S], [0, I]].
    pub F: AugmentedMatrix,
    /// Q: the white acceleration's and the spin random walk's noise over the step.
    pub Q: StateMatrix,
    /// Q_b: the bounces' scatter and spread, in the state at the end of the step (zero without
    /// a bounce).
    pub Q_bounce: StateMatrix,
    /// What the step went through.
    pub report: PredictReport,
}

/// One update and its parts.
#[derive(Debug, Clone, Copy, PartialEq)]
#[expect(non_snake_case, reason = "matrix notation")]
pub struct Update<const M: usize> {
    /// The estimate after the update.
    pub ekf: Ekf,
    /// y: the innovation, z - H x of the prior.
    pub y: SVector<f64, M>,
    /// S: its covariance, H P H' + R of the prior.
    pub S: SMatrix<f64, M, M>,
    /// K: the gain applied, over (state, parameters).
    pub K: SMatrix<f64, AUGMENTED, M>,
    /// The normalised innovation squared y' S^-1 y.
    pub nis: f64,
}

/// Counts the bounces of a prediction and adds up their scatter (in the state just after the
/// last one).
struct BounceWatch<'a> {
    report: PredictReport,
    propagator: &'a Propagator,
    noise: &'a BounceNoise,
    /// The covariance the prediction starts from, at which a bounce's sliding and spread are
    /// judged.
    start: &'a AugmentedMatrix,
    /// The scatter and spread of the bounces so far.
    scatter: StateMatrix,
    /// The probability that every bounce so far slid (the regime in which its outcome depends
    /// on the friction).
    sliding: f64,
}

impl Observer for BounceWatch<'_> {
    fn on_event(&mut self, event: &Event) -> Flow {
        self.report.on_event(event);
        if matches!(event.kind, EventKind::TableBounce { .. }) {
            self.scatter += bounce_scatter(self.propagator, self.noise, &event.before);
            if let Some(s) = &event.sensitivity {
                self.sliding *= self.sliding_probability(event, s);
                let inputs = bounce_inputs_at_event(s, self.start);
                self.scatter +=
                    bounce_spread(self.propagator, &event.before, &event.after, &inputs);
            }
        }
        Flow::Continue
    }
}

impl BounceWatch<'_> {
    /// The probability that a bounce slid, from the margin that decides the regime (rolling
    /// when positive; Gaussian, its variance g C g' over state and parameters at the bounce).
    fn sliding_probability(&self, event: &Event, s: &EventSensitivity) -> f64 {
        let at_bounce = covariance_at_event(s, self.start);
        let bounce = self.propagator.bounce();
        let (margin, gradient) = bounce.regime_margin(&event.before);
        let (e, mu) = bounce.table();
        let vz = event.before[5].abs();
        let mut g = SMatrix::<f64, 1, AUGMENTED>::zeros();
        g.fixed_columns_mut::<9>(0).copy_from(&gradient);
        g[9 + RESTITUTION] = mu * vz;
        g[9 + FRICTION] = (1.0 + e) * vz;
        let variance = (g * at_bounce * g.transpose())[(0, 0)];
        if variance > 0.0 {
            normal_cdf(-margin / variance.sqrt())
        } else if margin < 0.0 {
            1.0
        } else {
            0.0
        }
    }
}

/// The covariance of (state, parameters) at an event, from the covariance `start` of the
/// propagation's start and the event's sensitivities: [[T, S], [0, I]] P [.]'.
fn covariance_at_event(s: &EventSensitivity, start: &AugmentedMatrix) -> AugmentedMatrix {
    let mut a = AugmentedMatrix::identity();
    a.fixed_view_mut::<9, 9>(0, 0).copy_from(&s.before);
    if let Some(p) = &s.params {
        a.fixed_view_mut::<9, PARAMS>(0, 9).copy_from(&p.before);
    }
    a * start * a.transpose()
}

/// The scatter of one bounce from state `before`, in the state just after it, at the sigmas of
/// `noise`: the tangential impulse's and the restitution's.
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

/// The slowest flight whose direction a partial update trusts [m/s].
const PARTIAL_UPDATE_MIN_SPEED: f64 = 0.5;

/// Takes the fraction `withheld` of the gain's rows of the spin along the flight (the direction
/// of the velocity in `x`) out of `K`: K_w <- (I - withheld u u') K_w.
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

    /// The estimate propagated by `dt` seconds (dt >= 0) through flight and bounces, with the
    /// filter's parameters in `propagator`'s model and `noise`, what the physics leaves out
    /// (see the module doc).
    pub fn predict(&self, propagator: &Propagator, noise: &FilterNoise, dt: f64) -> Prediction {
        self.propagate(propagator, noise, dt)
    }

    /// [`Self::predict`] linearised at a nominal `(x, theta)` rather than at the estimate (the
    /// forward pass of an iterated smoother, Bell 1994): the nominal is flown through the model,
    /// the estimate's deviation from it by the nominal's transition, `x' = f(x_n) + Phi (x -
    /// x_n) + S (theta - theta_n)`, and the covariance by the same F.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn predict_about(
        &self,
        nominal: (&StateVector, &ParamVector),
        propagator: &Propagator,
        noise: &FilterNoise,
        dt: f64,
    ) -> Prediction {
        let at_nominal = Self {
            x: *nominal.0,
            theta: *nominal.1,
            P: self.P,
        };
        let mut prediction = at_nominal.propagate(propagator, noise, dt);
        let deviation = (self.x - nominal.0, self.theta - nominal.1);
        let F = &prediction.F;
        let (Phi, S) = (
            F.fixed_view::<9, 9>(0, 0).into_owned(),
            F.fixed_view::<9, PARAMS>(0, 9).into_owned(),
        );
        prediction.ekf.x += Phi * deviation.0 + S * deviation.1;
        prediction.ekf.theta += deviation.1;
        prediction
    }

    /// The propagation of [`Self::predict`] (see the module doc).
    #[expect(non_snake_case, reason = "matrix notation")]
    fn propagate(&self, propagator: &Propagator, noise: &FilterNoise, dt: f64) -> Prediction {
        if dt <= 0.0 {
            return Prediction {
                ekf: *self,
                F: AugmentedMatrix::identity(),
                Q: StateMatrix::zeros(),
                Q_bounce: StateMatrix::zeros(),
                report: PredictReport::default(),
            };
        }
        let propagator = self.flight_model(propagator, noise.spin_spread);
        let tracks_params = self.param_covariance() != ParamCovariance::zeros();
        let mut cursor = if tracks_params {
            Cursor::tracking_params(0.0, self.x)
        } else {
            Cursor::tracking(0.0, self.x)
        };
        let mut watch = BounceWatch {
            report: PredictReport::default(),
            propagator: &propagator,
            noise: &noise.bounce,
            start: &self.P,
            scatter: StateMatrix::zeros(),
            sliding: 1.0,
        };
        propagator.advance(&mut cursor, dt, Watch::BOUNCES, &mut watch);
        let (report, sliding) = (watch.report, watch.sliding);
        let Q = noise.process.discretise(dt);
        // The bounces' scatter, carried by the flight since the last one.
        let Q_bounce = match &cursor.tangent {
            Some(tangent) if report.bounces > 0 => tangent.carry_flight(&watch.scatter),
            _ => watch.scatter,
        };
        let (F, P) = match &cursor.tangent {
            Some(tangent) => self.carried(tangent, &(Q + Q_bounce), noise, dt),
            // No tangent: a propagation that tracked nothing (not reached: `tracking` asks).
            None => (AugmentedMatrix::identity(), self.P),
        };
        let mut ekf = Self {
            x: cursor.state,
            theta: self.theta,
            P,
        };
        if sliding < 1.0 {
            // A bounce that may have rolled out or slid: its outcome depends on the friction
            // only if it slid. The state keeps its correlation with the friction in that
            // proportion; its uncertainty stays in the state's covariance.
            for i in 0..9 {
                ekf.P[(i, 9 + FRICTION)] *= sliding;
                ekf.P[(9 + FRICTION, i)] *= sliding;
            }
        }
        Prediction {
            ekf,
            F,
            Q,
            Q_bounce,
            report,
        }
    }

    /// The propagator at the filter's parameters, its coefficients seeing `kappa` times the
    /// spin's spread across the flight ([`FilterNoise::spin_spread`]).
    fn flight_model(&self, propagator: &Propagator, kappa: f64) -> Propagator {
        let propagator = propagator.with_params(&self.params());
        if kappa > 0.0 {
            propagator.with_spin_variance(kappa * kappa * self.spin_variance_across_flight())
        } else {
            propagator
        }
    }

    /// F of a propagation's `tangent` and the covariance F P F' + (`q` and the parameters'
    /// random walk over `dt`), symmetrised; the state's block carried in the flight's block
    /// structure where no event broke it.
    #[expect(non_snake_case, reason = "matrix notation")]
    fn carried(
        &self,
        tangent: &Tangent,
        q: &StateMatrix,
        noise: &FilterNoise,
        dt: f64,
    ) -> (AugmentedMatrix, AugmentedMatrix) {
        let Phi = tangent.transition();
        let mut F = AugmentedMatrix::identity();
        F.fixed_view_mut::<9, 9>(0, 0).copy_from(&Phi);
        let mut P = AugmentedMatrix::zeros();
        let mut P_xx = tangent.carry_covariance(&self.state_covariance()) + q;
        let mut P_tt = self.param_covariance();
        if let Some(S) = tangent.params() {
            F.fixed_view_mut::<9, PARAMS>(0, 9).copy_from(&S);
            let P_xt = self.P.fixed_view::<9, PARAMS>(0, 9).into_owned();
            // [[Phi, S], [0, I]] P [[Phi, S], [0, I]]'.
            let B = Phi * P_xt;
            let C = S * P_tt;
            let cross = B + C;
            P_xx += B * S.transpose() + S * B.transpose() + C * S.transpose();
            P.fixed_view_mut::<9, PARAMS>(0, 9).copy_from(&cross);
            P.fixed_view_mut::<PARAMS, 9>(9, 0)
                .copy_from(&cross.transpose());
            for i in 0..PARAMS {
                P_tt[(i, i)] += noise.process.param_density[i] * dt;
            }
        }
        P.fixed_view_mut::<9, 9>(0, 0).copy_from(&P_xx);
        P.fixed_view_mut::<PARAMS, PARAMS>(9, 9).copy_from(&P_tt);
        (F, symmetrise(&P))
    }

    /// Fuses a measurement of the ball's state z = H x + noise(R) when its NIS is within `gate`.
    /// The parameters move with their correlation to the state.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn update<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
        gate: f64,
    ) -> Result<Update<M>, UpdateError> {
        self.update_partially(z, H, R, gate, 1.0)
    }

    /// [`Self::update`] with only the fraction `along_flight` in [0, 1] of the gain applied to
    /// the spin along the flight (the estimate's velocity direction): the partial-update
    /// Schmidt-Kalman filter (Brink 2017) on that one direction. The covariance is the Joseph
    /// form's for the gain applied, so it stays that of the estimate; 1 is the plain update.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn update_partially<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
        gate: f64,
        along_flight: f64,
    ) -> Result<Update<M>, UpdateError> {
        if !z.iter().chain(R.iter()).all(|v| v.is_finite()) {
            return Err(UpdateError::NotFinite);
        }
        let y = z - H * self.x;
        let PHt: SMatrix<f64, AUGMENTED, M> = self.P.fixed_columns::<9>(0) * H.transpose();
        let S = symmetrise(&(H * PHt.fixed_rows::<9>(0) + R));
        let chol = S.cholesky().ok_or(UpdateError::NotPositiveDefinite)?;
        let nis = y.dot(&chol.solve(&y));
        if !nis.is_finite() {
            return Err(UpdateError::NotPositiveDefinite);
        }
        if nis > gate {
            return Err(UpdateError::Gated { nis, gate });
        }
        // K = P H' S^-1 = (S^-1 H P)'.
        let mut K = chol.solve(&PHt.transpose()).transpose();
        if along_flight < 1.0 {
            withhold_along_flight(&mut K, &self.x, 1.0 - along_flight);
        }
        let dx = K * y;
        let mut ekf = *self;
        ekf.x += dx.fixed_rows::<9>(0);
        ekf.theta += dx.fixed_rows::<PARAMS>(9);
        for (i, (low, high)) in PARAM_BOUNDS.iter().enumerate() {
            ekf.theta[i] = ekf.theta[i].clamp(*low, *high);
        }
        // The Joseph form (I - K H) P (I - K H)' + K R K', multiplied out with S = H P H' + R:
        // P - K (P H')' - (P H') K' + K S K'. Equal to it for any gain, so a rounding error in K
        // still changes P to second order only.
        let K_PHt = K * PHt.transpose();
        ekf.P = symmetrise(&(self.P - K_PHt - K_PHt.transpose() + K * S * K.transpose()));
        Ok(Update { ekf, y, S, K, nis })
    }

    /// The estimate with what it learned of the spin forgotten: the spin's covariance back to
    /// `variance` [(rad/s)^2] per axis, uncorrelated with the rest (the spin itself kept).
    pub fn with_spin_forgotten(&self, variance: f64) -> Self {
        let mut ekf = *self;
        for i in 6..9 {
            for j in 0..AUGMENTED {
                ekf.P[(i, j)] = 0.0;
                ekf.P[(j, i)] = 0.0;
            }
            ekf.P[(i, i)] = variance;
        }
        ekf
    }

    /// The normalised innovation squared of a measurement, without fusing it; None when its
    /// covariance is not positive definite.
    #[expect(non_snake_case, reason = "matrix notation")]
    pub fn nis<const M: usize>(
        &self,
        z: &SVector<f64, M>,
        H: &SMatrix<f64, M, 9>,
        R: &SMatrix<f64, M, M>,
    ) -> Option<f64> {
        let y = z - H * self.x;
        let S = H * self.state_covariance() * H.transpose() + R;
        let chol = symmetrise(&S).cholesky()?;
        Some(y.dot(&chol.solve(&y)))
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
    use nalgebra::{Matrix3, Vector3};

    fn noise(acceleration_density: f64, spin_density: f64, spin_spread: f64) -> FilterNoise {
        FilterNoise {
            process: ProcessNoise {
                acceleration_density,
                spin_density,
                param_density: ParamVector::zeros(),
            },
            bounce: BounceNoise::default(),
            spin_spread,
        }
    }

    #[test]
    fn process_noise_matches_the_white_acceleration_model() {
        let q = noise(2.0, 5.0, 0.0).process.discretise(0.1);
        assert!((q[(0, 0)] - 2.0 * 1e-3 / 3.0).abs() < 1e-15);
        assert!((q[(0, 3)] - 2.0 * 1e-2 / 2.0).abs() < 1e-15);
        assert!((q[(3, 3)] - 0.2).abs() < 1e-15);
        assert!((q[(6, 6)] - 0.5).abs() < 1e-15);
        assert_eq!(q, q.transpose());
        assert!(q.cholesky().is_some(), "Q is positive definite");
    }

    /// A linear-Gaussian sanity check: one position update of a prior with P = I and R = I moves
    /// the estimate halfway and halves the variance; its parts are the textbook ones.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn update_halves_variance_for_equal_prior_and_noise() {
        let ekf = Ekf::new(
            StateVector::zeros(),
            StateMatrix::identity(),
            ParamVector::repeat(0.5),
            ParamCovariance::zeros(),
        );
        let z = Vector3::new(1.0, -2.0, 0.5);
        let R = Matrix3::identity();
        let update = ekf.update(&z, &position_H(), &R, 100.0).expect("fused");
        assert!((update.nis - z.norm_squared() / 2.0).abs() < 1e-12);
        assert_eq!(update.y, z);
        assert_eq!(update.S, Matrix3::identity() * 2.0);
        assert!((update.K.fixed_view::<3, 3>(0, 0) - Matrix3::identity() * 0.5).amax() < 1e-15);
        let after = update.ekf;
        assert!((after.x[0] - 0.5).abs() < 1e-12 && (after.x[1] + 1.0).abs() < 1e-12);
        assert!((after.P[(0, 0)] - 0.5).abs() < 1e-12);
        assert_eq!(after.P[(3, 3)], 1.0);
        assert_eq!(after.theta, ParamVector::repeat(0.5));
        let far = Vector3::new(50.0, 0.0, 0.0);
        assert!(matches!(
            ekf.update(&far, &position_H(), &R, 10.0),
            Err(UpdateError::Gated { .. })
        ));
        let nis = ekf
            .nis(&far, &position_H(), &R)
            .expect("S positive definite");
        assert!((nis - far.norm_squared() / 2.0).abs() < 1e-9, "{nis}");
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
        let ekf = Ekf::new(x, P, ParamVector::repeat(0.5), ParamCovariance::zeros());
        let after = ekf.update(&z, &H, &R, 1e6).expect("fused").ekf;
        let S = H * P * H.transpose() + R;
        let K = P * H.transpose() * S.try_inverse().expect("S invertible");
        let I_KH = StateMatrix::identity() - K * H;
        let joseph = I_KH * P * I_KH.transpose() + K * R * K.transpose();
        let p9 = after.state_covariance();
        assert!(
            (p9 - joseph).amax() < 1e-13 * P.amax(),
            "{}",
            (p9 - joseph).amax()
        );
        assert!((after.x - (x + K * (z - H * x))).amax() < 1e-13);
        assert_eq!(after.P, after.P.transpose());
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
        let prior = Ekf::new(x, P, ParamVector::repeat(0.5), ParamCovariance::zeros());
        let plain = prior.update(&z, &H, &R, 1e6).expect("fused").ekf;
        let same = prior
            .update_partially(&z, &H, &R, 1e6, 1.0)
            .expect("fused")
            .ekf;
        assert_eq!(plain, same, "a partial update of 1 is the plain update");
        for keep in [0.0, 0.5] {
            let ekf = prior
                .update_partially(&z, &H, &R, 1e6, keep)
                .expect("fused")
                .ekf;
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

    /// A prediction through a bounce counts it, grows the uncertainty, and returns its parts:
    /// P = F P F' + Q + Q_b exactly, the bounce's scatter in Q_b.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn a_prediction_returns_its_parts() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let x = crate::physics::BallState::new(
            Vector3::new(-0.5, 0.0, 0.05),
            Vector3::new(-4.0, 0.0, -1.0),
            Vector3::new(0.0, 50.0, 0.0),
        )
        .to_vector();
        let ekf = Ekf::new(
            x,
            StateMatrix::identity() * 1e-6,
            propagator.params().to_vector(),
            ParamCovariance::from_diagonal_element(1e-4),
        );
        let mut model = noise(1.0, 1.0, 0.0);
        model.bounce = BounceNoise::from_config(&config);
        let prediction = ekf.predict(&propagator, &model, 0.05);
        assert_eq!(prediction.report.bounces, 1);
        assert_eq!(prediction.report.robot_half_bounces, 1);
        let after = prediction.ekf;
        assert!(after.x[5] > 0.0);
        assert!(after.P[(3, 3)] > 1e-6);
        assert_eq!(after.P, after.P.transpose());
        assert!(prediction.Q_bounce[(3, 3)] > 0.0);
        let F = prediction.F;
        let mut expected = F * ekf.P * F.transpose();
        let mut added = expected.fixed_view_mut::<9, 9>(0, 0);
        added += prediction.Q + prediction.Q_bounce;
        // The friction's correlation is kept in proportion to the chance that the bounce slid.
        for i in 0..AUGMENTED {
            if i != 9 + FRICTION {
                let scale = after.P[(i, 9 + FRICTION)] / expected[(i, 9 + FRICTION)];
                if expected[(i, 9 + FRICTION)].abs() > 1e-12 {
                    assert!((0.0..=1.0 + 1e-9).contains(&scale), "{scale}");
                }
                expected[(i, 9 + FRICTION)] = after.P[(i, 9 + FRICTION)];
                expected[(9 + FRICTION, i)] = after.P[(9 + FRICTION, i)];
            }
        }
        assert!(
            (after.P - expected).amax() < 1e-12 * after.P.amax(),
            "{}",
            (after.P - expected).amax()
        );
        // Without a step, nothing moves.
        let none = ekf.predict(&propagator, &model, 0.0);
        assert_eq!((none.ekf, none.F), (ekf, AugmentedMatrix::identity()));
    }

    /// F is the derivative of the prediction's mean with respect to the state, against central
    /// differences, through a bounce.
    #[test]
    fn the_transition_is_the_derivative_of_the_prediction() {
        let config = Config::default();
        let propagator = Propagator::new(&config);
        let x = crate::physics::BallState::new(
            Vector3::new(0.6, 0.1, 0.25),
            Vector3::new(-6.0, 0.2, -1.0),
            Vector3::new(0.0, 300.0, 20.0),
        )
        .to_vector();
        let ekf = Ekf::new(
            x,
            StateMatrix::identity() * 1e-4,
            propagator.params().to_vector(),
            ParamCovariance::from_diagonal_element(1e-3),
        );
        let model = noise(1.0, 1.0, 0.0);
        let dt = 0.3;
        let prediction = ekf.predict(&propagator, &model, dt);
        assert_eq!(prediction.report.bounces, 1);
        let steps = [1e-6, 1e-6, 1e-6, 1e-5, 1e-5, 1e-5, 1e-2, 1e-2, 1e-2];
        for (j, h) in steps.iter().enumerate() {
            let moved = |sign: f64| {
                let mut e = ekf;
                e.x[j] += sign * h;
                e.predict(&propagator, &model, dt).ekf.x
            };
            let numeric = (moved(1.0) - moved(-1.0)) / (2.0 * h);
            let analytic = prediction.F.fixed_view::<9, 1>(0, j).into_owned();
            assert!(
                (numeric - analytic).amax() < 1e-4 * analytic.amax().max(1.0),
                "column {j}: {numeric} vs {analytic}"
            );
        }
    }

    /// A prediction linearised at a nominal: at the estimate itself it is the prediction; at a
    /// nominal off the estimate its mean is the nominal's flight plus the transition times the
    /// offset, its covariance the prediction's at the nominal, and the parameters keep the
    /// estimate's.
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
        let model = noise(1.0, 1.0, 0.5);
        // Through a bounce.
        let dt = 0.3;
        let plain = ekf.predict(&propagator, &model, dt).ekf;
        let about = ekf.predict_about((&x, &theta), &propagator, &model, dt).ekf;
        assert!((about.x - plain.x).amax() < 1e-12, "{}", about.x - plain.x);
        assert!((about.P - plain.P).amax() < 1e-12 * plain.P.amax());

        let mut offset = StateVector::zeros();
        offset[6] = 30.0;
        offset[4] = 0.05;
        let nominal = x + offset;
        let mut at_nominal = ekf;
        at_nominal.x = nominal;
        let nominal_flight = at_nominal.predict(&propagator, &model, dt).ekf;
        let prediction = ekf.predict_about((&nominal, &theta), &propagator, &model, dt);
        assert_eq!(prediction.report.bounces, 1);
        let about = prediction.ekf;
        let linear = nominal_flight.x - prediction.F.fixed_view::<9, 9>(0, 0) * offset;
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

    /// Forgetting the spin resets its covariance block and its correlations, nothing else.
    #[test]
    #[expect(non_snake_case, reason = "matrix notation")]
    fn forgetting_the_spin_resets_its_covariance_only() {
        let (x, P) = correlated_prior();
        let ekf = Ekf::new(x, P, ParamVector::repeat(0.5), ParamCovariance::zeros());
        let forgotten = ekf.with_spin_forgotten(9e4);
        assert_eq!(forgotten.x, ekf.x);
        for i in 0..AUGMENTED {
            for j in 0..AUGMENTED {
                let expected = match ((6..9).contains(&i), (6..9).contains(&j)) {
                    (true, true) if i == j => 9e4,
                    (false, false) => ekf.P[(i, j)],
                    _ => 0.0,
                };
                assert_eq!(forgotten.P[(i, j)], expected, "({i}, {j})");
            }
        }
    }
}

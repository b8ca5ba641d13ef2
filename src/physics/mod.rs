//! The physics core: flight, table bounce and event-aware propagation of the ball state.
//! Pure functions of the state and the configuration: no I/O, no clock.
//!
//! - [`aero`]: the spin-parameter aerodynamic flight model and its Jacobian (Isomura et al. 2014).
//! - [`bounce`]: the table bounce with friction and its Jacobian (Nakashima et al., ACC 2010).
//! - [`propagate`]: RK4 with the state-transition matrix, and events (table, net, floor, a plane
//!   x = const) root-found inside a step, with the sensitivity of their time to the state.
//! - [`predict`]: a whole predicted flight with its events, the base of every later prediction.
//! - [`racket`]: the racket impact (Kawazoe & Suzuki; Kawazoe et al. 2010): reduced mass, restitution,
//!   rebound, spin from the rubber's friction, load on the grip.
//! - [`contact`]: contact time, force and deformation of that impact, and the plate's vibration
//!   loss.
//! - [`params`]: the physical parameters the estimator adapts (drag and Magnus scales, the
//!   table's restitution and friction), whose sensitivities the propagator carries.

pub mod aero;
pub mod bounce;
pub mod contact;
pub mod params;
pub mod predict;
pub mod propagate;
pub mod racket;
pub mod state;

pub use aero::{AeroForces, FlightJacobian, FlightMatrix, FlightModel};
pub use bounce::{Bounce, BounceRegime, TableBounce};
pub use contact::{Contact, ContactError, RestoringCharacteristic};
pub use params::{
    AUGMENTED, AugmentedMatrix, PARAMS, ParamCovariance, ParamMatrix, ParamRow, ParamVector,
    PhysicsParams,
};
pub use predict::{PredictOptions, Sample, Trajectory, TrajectoryEnd, predict};
pub use propagate::{
    Cursor, Event, EventKind, EventParamSensitivity, EventSensitivity, Flow, Observer, Outcome,
    Propagator, Tangent, Watch,
};
pub use racket::{Hit, ImpactError, NormalImpact, RacketModel, RacketState, WristLoad};
pub use state::{BallState, StateMatrix, StateRow, StateVector};

//! The physics core: flight, table bounce and event-aware propagation of the ball state.
//! Pure functions of the state and the configuration: no I/O, no clock.
//!
//! - [`aero`]: the spin-parameter aerodynamic flight model and its Jacobian (seed 004).
//! - [`bounce`]: the table bounce with friction and its Jacobian (Nakashima et al., ACC 2010).
//! - [`propagate`]: RK4 with the state-transition matrix, and events (table, net, floor, a plane
//!   x = const) root-found inside a step, with the sensitivity of their time to the state.
//! - [`predict`]: a whole predicted flight with its events, the base of every later prediction.

pub mod aero;
pub mod bounce;
pub mod predict;
pub mod propagate;
pub mod state;

pub use aero::{AeroForces, FlightJacobian, FlightModel};
pub use bounce::{Bounce, BounceRegime, TableBounce};
pub use predict::{PredictOptions, Sample, Trajectory, TrajectoryEnd, predict};
pub use propagate::{
    Cursor, Event, EventKind, Flow, Observer, Outcome, Propagator, Tangent, Watch,
};
pub use state::{BallState, StateMatrix, StateRow, StateVector};

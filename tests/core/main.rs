//! Tests of the pure core's lower layers (model, config, physics, online, eval): the physics
//! against its sources' values and its invariants, the estimator, the learned physics, the racket,
//! the simulator, the evaluation, the layer rule itself and the documentation's rules. One test
//! binary, so the crate is linked once for all of them.

mod adaptation;
mod docs;
mod estimator;
mod evaluation;
mod layers;
mod physics;
mod racket;
mod sim;

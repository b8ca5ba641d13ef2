//! Tests of the adapter layers (ros, bag, plot): the configuration file, the message contract,
//! the sample bags, the replay, bad input properties and the figures.

#[cfg(feature = "cli")]
#[path = "../common/mod.rs"]
mod common;

mod bags;
mod config_yaml;
#[cfg(feature = "live-view")]
mod live_view;
mod msgs_contract;
mod plot;
mod properties;
mod replay;
mod sqlite_bags;

//! Serde mirrors of the ROS 2 interfaces in `msgs/` (package `ttball_msgs`) and of the standard
//! types they use, for ros2-client and MCAP.
//!
//! Each struct has the fields of its `.msg` / `.srv` counterpart with the same names, in the same
//! order: ros2-client serialises messages with serde through the `cdr-encoding` crate, so field order
//! is wire order. Types map as uint8 -> `u8`, uint32 -> `u32`, int32 -> `i32`, float32 -> `f32`,
//! float64 -> `f64`, string -> `String`, `T[N]` -> `[T; N]` (a tuple on the wire: no length prefix)
//! and `T[]` -> `Vec<T>`. Modules follow ROS 2 naming (`ttball_msgs::msg::BallDetection`,
//! `ttball_msgs::srv::PredictTrajectoryRequest`). `tests/adapters/msgs_contract.rs` parses `msgs/` and checks
//! these mirrors against it, so change both together.

pub mod builtin_interfaces;
pub mod convert;
pub mod definitions;
pub mod diagnostic_msgs;
pub mod geometry_msgs;
pub mod nav_msgs;
pub mod rosgraph_msgs;
pub mod sensor_msgs;
pub mod std_msgs;
pub mod std_srvs;
pub mod tf2_msgs;
pub mod ttball_msgs;
pub mod type_names;
pub mod visualization_msgs;

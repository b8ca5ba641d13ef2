//! The ROS 2 seam: the interface types and the node's per-message step, with no transport.
//!
//! - [`msgs`]: serde mirrors of the ROS 2 interfaces in `msgs/` (package `ttball_msgs`) and of
//!   the standard ones ttball uses, in wire (field) order, their definitions for MCAP schemas,
//!   the conversions to and from the core's types, and every type name ([`msgs::type_names`]).
//! - [`pipeline`]: the node minus its transport: one message in, the messages to publish out;
//!   the ROS node and the MCAP replay both drive it.

pub mod msgs;
pub mod pipeline;

//! Mirror of the ROS 2 package `ttball_msgs` in `msgs/`: messages in [`msg`], services in [`srv`].

pub mod msg;
pub mod srv;

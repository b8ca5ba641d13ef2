//! The DDS side of the node, on ros2-client: the participant (domain, interfaces), names, QoS
//! profiles and type names as ROS 2 maps them onto DDS (`rt/` topics,
//! `pkg::msg::dds_::Type_` types, `rq/`/`rr/` service topics), so that ROS 2 nodes in C++ or
//! Python and plain DDS peers talk to ttball unchanged.

use std::net::{IpAddr, Ipv4Addr};

use ros2_client::dds::rustdds::Topic;
use ros2_client::{
    Context, MessageTypeName, Name, Node, NodeName, NodeOptions, QosProfile, ServiceMapping,
    ServiceTypeName,
    qos::{Durability, History, WhenFull},
};

use super::{DETECTION_TYPE, NodeError};
use crate::config::{self, Config};

/// A DDS failure as the node's error.
pub fn error(e: impl std::fmt::Display) -> NodeError {
    NodeError::Dds(e.to_string())
}

/// The DDS domain from `ROS_DOMAIN_ID` (unset or empty: 0), as ROS 2 reads it. ros2-client does
/// not read it itself.
pub fn domain_id(value: Option<&str>) -> Result<u16, NodeError> {
    let Some(text) = value.map(str::trim).filter(|t| !t.is_empty()) else {
        return Ok(0);
    };
    match text.parse::<u16>() {
        Ok(id) if id <= MAX_DOMAIN_ID => Ok(id),
        _ => Err(NodeError::DomainId(text.to_owned())),
    }
}

/// Largest domain id whose ports fit the RTPS port mapping (ROS 2 documents 0 to 232).
const MAX_DOMAIN_ID: u16 = 232;

/// The addresses of the interfaces DDS may use: loopback only when `node.localhost_only` or
/// ROS 2's environment says so (`ROS_LOCALHOST_ONLY=1`, `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`),
/// else `node.interface_address`, else all (`None`).
pub fn interfaces(
    node: &config::NodeParams,
    localhost_only_env: Option<&str>,
    discovery_range_env: Option<&str>,
) -> Option<Vec<IpAddr>> {
    let localhost = node.localhost_only
        || localhost_only_env.is_some_and(|v| v.trim() == "1")
        || discovery_range_env.is_some_and(|v| v.trim().eq_ignore_ascii_case("LOCALHOST"));
    if localhost {
        Some(vec![IpAddr::V4(Ipv4Addr::LOCALHOST)])
    } else {
        node.interface_address
            .parse::<IpAddr>()
            .ok()
            .map(|address| vec![address])
    }
}

/// A DDS participant (as ros2-client's context) on `domain`, limited to `interfaces`.
pub fn context(domain: u16, interfaces: Option<&[IpAddr]>) -> Result<Context, NodeError> {
    let mut builder = ros2_client::dds::rustdds::DomainParticipantBuilder::new(domain);
    if let Some(addresses) = interfaces {
        builder = builder.with_only_networks(addresses.iter().copied());
    }
    let participant = builder.build().map_err(error)?;
    Context::from_domain_participant(participant).map_err(error)
}

/// A ROS 2 node on `context`, publishing its log on `/rosout` when `rosout`.
pub fn node(context: &Context, name: NodeName, rosout: bool) -> Result<Node, NodeError> {
    context
        .new_node(
            name,
            // The node serves rcl_interfaces' parameter services itself, with its configured
            // framing (ros2-client's own use the enhanced one and know no descriptors).
            NodeOptions::new()
                .enable_rosout(rosout)
                .start_parameter_services(false),
        )
        .map_err(error)
}

/// Runs the node's ros2-client spinner (graph discovery, `ros_discovery_info`) on its own
/// thread; it stops when the node is dropped ([`Spinner::stop_with`]).
pub fn spawn_spinner(node: &mut Node) -> Result<Spinner, NodeError> {
    let spinner = node.spinner().map_err(error)?;
    std::thread::Builder::new()
        .name("ttball-spinner".to_owned())
        .spawn(move || {
            if let Err(e) = futures::executor::block_on(spinner.spin()) {
                tracing::warn!("ros2-client spinner stopped: {e}");
            }
        })
        .map(|thread| Spinner { thread })
        .map_err(|e| NodeError::Thread(e.to_string()))
}

/// The thread of a node's spinner.
pub struct Spinner {
    thread: std::thread::JoinHandle<()>,
}

impl Spinner {
    /// Drops `node`, which stops the spinner, and waits (up to a second) for the spinner to end:
    /// it owns DDS readers and writers (the node's parameter services), which must go before the
    /// participant does, or RustDDS logs an error for each.
    pub fn stop_with(self, node: Node) {
        drop(node);
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(1);
        while !self.thread.is_finished() && std::time::Instant::now() < deadline {
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
        if self.thread.is_finished() {
            let _ = self.thread.join();
        } else {
            tracing::warn!("the ros2-client spinner did not stop within a second");
        }
    }
}

/// The detections topic (`topics.detections`, sensor-data QoS), for the node and `ttball play`.
pub fn detections_topic(node: &mut Node, config: &Config) -> Result<Topic, NodeError> {
    node.create_topic(
        &name(&config.resolved_topics().detections)?,
        message_type(DETECTION_TYPE),
        &sensor_data(config.qos.detections_depth),
    )
    .map_err(error)
}

/// The node's name in its namespace (`/` when `node.namespace` is empty).
pub fn node_name(config: &Config) -> Result<NodeName, NodeError> {
    let namespace = if config.node.namespace.is_empty() {
        "/"
    } else {
        config.node.namespace.as_str()
    };
    NodeName::new(namespace, &config.node.name)
        .map_err(|e| NodeError::Name(format!("{namespace} {}: {e}", config.node.name)))
}

/// A topic or service name as ros2-client takes it.
pub fn name(full: &str) -> Result<Name, NodeError> {
    Name::parse(full).map_err(|e| NodeError::Name(format!("{full}: {e}")))
}

/// A private name (`~/base`): the base in the node's own namespace (`/ns/node/base`).
pub fn private_name(node: &NodeName, base: &str) -> Result<Name, NodeError> {
    Name::new(&node.fully_qualified_name(), base)
        .map_err(|e| NodeError::Name(format!("~/{base}: {e}")))
}

/// `pkg/msg/Type` as ros2-client's type name (DDS: `pkg::msg::dds_::Type_`).
pub fn message_type(ros_type: &str) -> MessageTypeName {
    let (package, ty) = split_type(ros_type);
    MessageTypeName::new(package, ty)
}

/// `pkg/srv/Type` as ros2-client's service type name.
pub fn service_type(ros_type: &str) -> ServiceTypeName {
    let (package, ty) = split_type(ros_type);
    ServiceTypeName::new(package, ty)
}

fn split_type(ros_type: &str) -> (&str, &str) {
    let mut parts = ros_type.split('/');
    let package = parts.next().unwrap_or(ros_type);
    let ty = parts.next_back().unwrap_or(ros_type);
    (package, ty)
}

/// REP 2003's sensor-data QoS for the detections: best effort, keep last `depth`, volatile.
pub fn sensor_data(depth: u32) -> QosProfile {
    QosProfile::subscription_default()
        .reliability_best_effort()
        .durability(Durability::Volatile)
        .history(History::KeepLast {
            depth: depth_usize(depth),
        })
}

/// The outputs' QoS (ROS 2's default for publishers): reliable, keep last `depth`, volatile.
pub fn reliable(depth: u32) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast {
            depth: depth_usize(depth),
        })
}

/// tf2's `/tf_static` QoS: reliable, transient local (a late subscriber gets the transforms),
/// keep last 100 (tf2_ros's StaticListenerQoS; its broadcaster keeps 1).
pub fn tf_static() -> QosProfile {
    QosProfile::subscription_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 100 })
}

/// rcl's `/rosout` QoS (`rcl_qos_profile_rosout_default`): reliable, transient local, keep last
/// 1000, records living 10 s, so that a late subscriber (`ros2 topic echo`, a recorder) gets the
/// node's recent log, its start included.
pub fn rosout() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::TransientLocal)
        .history(History::KeepLast { depth: 1000 })
        .lifespan(Some(std::time::Duration::from_secs(10)))
}

/// rclcpp's `ClockQoS` for `/clock`: best effort, keep last 1, volatile.
pub fn clock() -> QosProfile {
    sensor_data(1)
}

/// ROS 2's default QoS of services: reliable, keep last 10, volatile.
pub fn services() -> QosProfile {
    reliable(10)
}

fn depth_usize(depth: u32) -> usize {
    usize::try_from(depth).unwrap_or(usize::MAX)
}

/// The service framing of the configuration as ros2-client's.
pub fn service_mapping(mapping: config::ServiceMapping) -> ServiceMapping {
    match mapping {
        config::ServiceMapping::Enhanced => ServiceMapping::Enhanced,
        config::ServiceMapping::Cyclone => ServiceMapping::Cyclone,
        config::ServiceMapping::Basic => ServiceMapping::Basic,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn domain_id_as_ros2_reads_it() {
        assert_eq!(domain_id(None).unwrap(), 0);
        assert_eq!(domain_id(Some("")).unwrap(), 0);
        assert_eq!(domain_id(Some(" 42 ")).unwrap(), 42);
        assert_eq!(domain_id(Some("232")).unwrap(), 232);
        for bad in ["233", "-1", "x", "1.5"] {
            let err = domain_id(Some(bad)).unwrap_err().to_string();
            assert!(err.contains("ROS_DOMAIN_ID"), "{err}");
        }
    }

    #[test]
    fn interfaces_follow_config_and_ros_environment() {
        let mut node = config::NodeParams::default();
        assert_eq!(interfaces(&node, None, None), None);
        let lo = Some(vec![IpAddr::V4(Ipv4Addr::LOCALHOST)]);
        assert_eq!(interfaces(&node, Some("1"), None), lo);
        assert_eq!(interfaces(&node, Some("0"), None), None);
        assert_eq!(interfaces(&node, None, Some("localhost")), lo);
        assert_eq!(interfaces(&node, None, Some("SUBNET")), None);
        node.interface_address = "192.168.1.20".to_owned();
        assert_eq!(
            interfaces(&node, None, None),
            Some(vec!["192.168.1.20".parse().unwrap()])
        );
        node.localhost_only = true;
        assert_eq!(interfaces(&node, None, None), lo);
    }

    #[test]
    fn names_and_types_map_as_ros2_does() {
        let config = Config::default();
        let node = node_name(&config).unwrap();
        assert_eq!(node.fully_qualified_name(), "/ttball");
        let service = private_name(&node, "predict_trajectory").unwrap();
        assert_eq!(
            service.to_dds_name("rq", &node, "Request"),
            "rq/ttball/predict_trajectoryRequest"
        );
        let topic = name("/ball/detections").unwrap();
        assert_eq!(topic.to_dds_name("rt", &node, ""), "rt/ball/detections");
        assert_eq!(
            message_type("ttball_msgs/msg/BallDetection").dds_msg_type(),
            "ttball_msgs::msg::dds_::BallDetection_"
        );
        let service = service_type("ttball_msgs/srv/PredictTrajectory");
        assert_eq!(
            (service.package_name(), service.type_name()),
            ("ttball_msgs", "PredictTrajectory")
        );
        let mut config = Config::default();
        config.node.namespace = "/robot1".to_owned();
        let node = node_name(&config).unwrap();
        assert_eq!(
            private_name(&node, "predict_trajectory")
                .unwrap()
                .to_dds_name("rr", &node, "Reply"),
            "rr/robot1/ttball/predict_trajectoryReply"
        );
    }
}

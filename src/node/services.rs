//! The node's services, `~/predict_trajectory`, `~/predict_rebound` and `~/plan_return`, behind
//! one request and one reply type, so that one stream takes every request off DDS, one channel
//! carries it to the estimator thread (which answers it with the [`Pipeline`]) and one path sends
//! the reply back.

use futures::StreamExt;
use futures::stream::{self, FusedStream, LocalBoxStream};
use ros2_client::{Node, NodeName, RmwRequestId, Server};

use super::dds;
use super::{
    NodeError, PLAN_RETURN_SERVICE, PLAN_RETURN_TYPE, PREDICT_REBOUND_SERVICE,
    PREDICT_REBOUND_TYPE, PREDICT_TRAJECTORY_SERVICE, PREDICT_TRAJECTORY_TYPE,
};
use crate::config;
use crate::msgs::ttball_msgs::srv::{
    PlanReturnRequest, PlanReturnResponse, PredictReboundRequest, PredictReboundResponse,
    PredictTrajectoryRequest, PredictTrajectoryResponse,
};
use crate::pipeline::Pipeline;

impl ros2_client::Message for PredictTrajectoryRequest {}
impl ros2_client::Message for PredictTrajectoryResponse {}
impl ros2_client::Message for PredictReboundRequest {}
impl ros2_client::Message for PredictReboundResponse {}
impl ros2_client::Message for PlanReturnRequest {}
impl ros2_client::Message for PlanReturnResponse {}

/// One of the node's services.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Service {
    /// `~/predict_trajectory`.
    PredictTrajectory,
    /// `~/predict_rebound`.
    PredictRebound,
    /// `~/plan_return`.
    PlanReturn,
}

impl Service {
    /// Every service, in the order the node lists them.
    pub const ALL: [Self; 3] = [
        Self::PredictTrajectory,
        Self::PredictRebound,
        Self::PlanReturn,
    ];

    /// Base name, private to the node (`~/name`).
    pub fn name(self) -> &'static str {
        match self {
            Self::PredictTrajectory => PREDICT_TRAJECTORY_SERVICE,
            Self::PredictRebound => PREDICT_REBOUND_SERVICE,
            Self::PlanReturn => PLAN_RETURN_SERVICE,
        }
    }

    /// ROS 2 type, `pkg/srv/Type`.
    pub fn ros_type(self) -> &'static str {
        match self {
            Self::PredictTrajectory => PREDICT_TRAJECTORY_TYPE,
            Self::PredictRebound => PREDICT_REBOUND_TYPE,
            Self::PlanReturn => PLAN_RETURN_TYPE,
        }
    }
}

/// A request of any of the services.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    /// Of `~/predict_trajectory`.
    PredictTrajectory(PredictTrajectoryRequest),
    /// Of `~/predict_rebound`.
    PredictRebound(PredictReboundRequest),
    /// Of `~/plan_return`.
    PlanReturn(PlanReturnRequest),
}

/// A reply of any of the services.
#[derive(Debug, Clone, PartialEq)]
pub enum Reply {
    /// Of `~/predict_trajectory`.
    PredictTrajectory(PredictTrajectoryResponse),
    /// Of `~/predict_rebound`.
    PredictRebound(PredictReboundResponse),
    /// Of `~/plan_return`.
    PlanReturn(PlanReturnResponse),
}

impl Request {
    /// The service it is for.
    pub fn service(&self) -> Service {
        match self {
            Self::PredictTrajectory(_) => Service::PredictTrajectory,
            Self::PredictRebound(_) => Service::PredictRebound,
            Self::PlanReturn(_) => Service::PlanReturn,
        }
    }

    /// The pipeline's answer (on the estimator thread, so that it sees the live track).
    pub fn answer(&self, pipeline: &Pipeline) -> Reply {
        match self {
            Self::PredictTrajectory(r) => Reply::PredictTrajectory(pipeline.predict_trajectory(r)),
            Self::PredictRebound(r) => Reply::PredictRebound(pipeline.predict_rebound(r)),
            Self::PlanReturn(r) => Reply::PlanReturn(pipeline.plan_return(r)),
        }
    }
}

impl Reply {
    /// The service it is from.
    pub fn service(&self) -> Service {
        match self {
            Self::PredictTrajectory(_) => Service::PredictTrajectory,
            Self::PredictRebound(_) => Service::PredictRebound,
            Self::PlanReturn(_) => Service::PlanReturn,
        }
    }

    /// The reply of `service` that refuses a request: `success` false, `message`, every other
    /// field zero.
    pub fn refusal(service: Service, message: String) -> Self {
        match service {
            Service::PredictTrajectory => Self::PredictTrajectory(PredictTrajectoryResponse {
                success: false,
                message,
                ..PredictTrajectoryResponse::default()
            }),
            Service::PredictRebound => Self::PredictRebound(PredictReboundResponse {
                success: false,
                message,
                ..PredictReboundResponse::default()
            }),
            Service::PlanReturn => Self::PlanReturn(PlanReturnResponse {
                success: false,
                message,
                ..PlanReturnResponse::default()
            }),
        }
    }

    /// Its `success` and `message`.
    pub fn outcome(&self) -> (bool, &str) {
        match self {
            Self::PredictTrajectory(r) => (r.success, &r.message),
            Self::PredictRebound(r) => (r.success, &r.message),
            Self::PlanReturn(r) => (r.success, &r.message),
        }
    }
}

/// A request taken off DDS, or the service whose request did not decode and why.
pub type Incoming = Result<(RmwRequestId, Request), (Service, String)>;

/// The node's service servers.
pub struct Servers {
    predict_trajectory: Server<PredictTrajectoryRequest, PredictTrajectoryResponse>,
    predict_rebound: Server<PredictReboundRequest, PredictReboundResponse>,
    plan_return: Server<PlanReturnRequest, PlanReturnResponse>,
}

impl Servers {
    /// Creates every service of the node, private to it, with ROS 2's service QoS and the
    /// configured framing.
    pub fn new(
        node: &mut Node,
        node_name: &NodeName,
        mapping: config::ServiceMapping,
    ) -> Result<Self, NodeError> {
        let mapping = dds::service_mapping(mapping);
        Ok(Self {
            predict_trajectory: server(node, node_name, mapping, Service::PredictTrajectory)?,
            predict_rebound: server(node, node_name, mapping, Service::PredictRebound)?,
            plan_return: server(node, node_name, mapping, Service::PlanReturn)?,
        })
    }

    /// The requests of every service, in arrival order per service.
    pub fn requests(&self) -> impl FusedStream<Item = Incoming> + '_ {
        stream::select_all([
            incoming(
                &self.predict_trajectory,
                Service::PredictTrajectory,
                Request::PredictTrajectory,
            ),
            incoming(
                &self.predict_rebound,
                Service::PredictRebound,
                Request::PredictRebound,
            ),
            incoming(&self.plan_return, Service::PlanReturn, Request::PlanReturn),
        ])
    }

    /// Sends a reply to the request `id` on its service's server.
    pub fn send(&self, id: RmwRequestId, reply: Reply) -> Result<(), String> {
        match reply {
            Reply::PredictTrajectory(r) => self.predict_trajectory.send_response(id, r),
            Reply::PredictRebound(r) => self.predict_rebound.send_response(id, r),
            Reply::PlanReturn(r) => self.plan_return.send_response(id, r),
        }
        .map_err(|e| format!("{e:?}"))
    }
}

fn server<Q, S>(
    node: &mut Node,
    node_name: &NodeName,
    mapping: ros2_client::ServiceMapping,
    service: Service,
) -> Result<Server<Q, S>, NodeError>
where
    Q: ros2_client::Message + Clone + 'static,
    S: ros2_client::Message + 'static,
{
    node.create_server(
        mapping,
        &dds::private_name(node_name, service.name())?,
        &dds::service_type(service.ros_type()),
        dds::services(),
        dds::services(),
    )
    .map_err(dds::error)
}

/// The requests of one server as [`Incoming`].
fn incoming<Q, S>(
    server: &Server<Q, S>,
    service: Service,
    wrap: fn(Q) -> Request,
) -> LocalBoxStream<'_, Incoming>
where
    Q: ros2_client::Message + 'static,
    S: ros2_client::Message + 'static,
{
    server
        .receive_request_stream()
        .map(move |r| {
            r.map(|(id, request)| (id, wrap(request)))
                .map_err(|e| (service, format!("{e:?}")))
        })
        .boxed_local()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Config;

    #[test]
    fn every_request_is_answered_by_its_service_and_refused_in_its_type() {
        let pipeline = Pipeline::new(&Config::default());
        let requests = [
            Request::PredictTrajectory(PredictTrajectoryRequest {
                horizon: -1.0,
                ..PredictTrajectoryRequest::default()
            }),
            Request::PredictRebound(PredictReboundRequest::default()),
            Request::PlanReturn(PlanReturnRequest::default()),
        ];
        for (request, service) in requests.iter().zip(Service::ALL) {
            assert_eq!(request.service(), service);
            // Bad requests are refused, each by its own pipeline method.
            let reply = request.answer(&pipeline);
            let (success, message) = reply.outcome();
            assert!(!success && !message.is_empty(), "{service:?}: {reply:?}");
            let expected = match request {
                Request::PredictTrajectory(r) => {
                    Reply::PredictTrajectory(pipeline.predict_trajectory(r))
                }
                Request::PredictRebound(r) => Reply::PredictRebound(pipeline.predict_rebound(r)),
                Request::PlanReturn(r) => Reply::PlanReturn(pipeline.plan_return(r)),
            };
            assert_eq!(reply, expected);
            let busy = Reply::refusal(service, "busy".to_owned());
            assert_eq!(busy.outcome(), (false, "busy"));
            assert_eq!((reply.service(), busy.service()), (service, service));
        }
        let names: Vec<&str> = Service::ALL.iter().map(|s| s.name()).collect();
        assert_eq!(
            names,
            ["predict_trajectory", "predict_rebound", "plan_return"]
        );
        let types: Vec<&str> = Service::ALL.iter().map(|s| s.ros_type()).collect();
        assert_eq!(
            types,
            [
                "ttball_msgs/srv/PredictTrajectory",
                "ttball_msgs/srv/PredictRebound",
                "ttball_msgs/srv/PlanReturn"
            ]
        );
    }
}

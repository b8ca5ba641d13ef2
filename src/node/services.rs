//! The node's services, `~/predict_trajectory`, `~/predict_rebound`, `~/plan_return`, `~/reset`
//! and rcl_interfaces' six parameter services (`~/get_parameters`, ...), behind one request and
//! one reply type, so that one stream takes every request off DDS, one channel carries it to the
//! estimator thread (which answers it with the [`Pipeline`] and the node's [`Parameters`]) and
//! one path sends the reply back. Every one is served with the configured framing
//! (`node.service_mapping`), so a ROS 2 tool on any RMW can call them.

use futures::StreamExt;
use futures::stream::{self, FusedStream, LocalBoxStream};
use ros2_client::rcl_interfaces::{
    DescribeParametersRequest, DescribeParametersResponse, GetParameterTypesRequest,
    GetParameterTypesResponse, GetParametersRequest, GetParametersResponse, ListParametersRequest,
    ListParametersResponse, SetParametersAtomicallyResponse, SetParametersRequest,
    SetParametersResponse,
};
use ros2_client::{Node, NodeName, RmwRequestId, Server};

use super::dds;
use super::parameters::{Change, Parameters};
use super::{
    NodeError, PLAN_RETURN_SERVICE, PLAN_RETURN_TYPE, PREDICT_REBOUND_SERVICE,
    PREDICT_REBOUND_TYPE, PREDICT_TRAJECTORY_SERVICE, PREDICT_TRAJECTORY_TYPE,
};
use crate::config;
use crate::ros::msgs::std_srvs::{TriggerRequest, TriggerResponse};
use crate::ros::msgs::ttball_msgs::srv::{
    PlanReturnRequest, PlanReturnResponse, PredictReboundRequest, PredictReboundResponse,
    PredictTrajectoryRequest, PredictTrajectoryResponse,
};
use crate::ros::pipeline::Pipeline;

impl ros2_client::Message for PredictTrajectoryRequest {}
impl ros2_client::Message for PredictTrajectoryResponse {}
impl ros2_client::Message for PredictReboundRequest {}
impl ros2_client::Message for PredictReboundResponse {}
impl ros2_client::Message for PlanReturnRequest {}
impl ros2_client::Message for PlanReturnResponse {}
impl ros2_client::Message for TriggerRequest {}
impl ros2_client::Message for TriggerResponse {}

/// One of the node's services.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Service {
    /// `~/predict_trajectory`.
    PredictTrajectory,
    /// `~/predict_rebound`.
    PredictRebound,
    /// `~/plan_return`.
    PlanReturn,
    /// `~/reset` (std_srvs/srv/Trigger): drops the tracks and what was learned.
    Reset,
    /// `~/list_parameters`.
    ListParameters,
    /// `~/get_parameters`.
    GetParameters,
    /// `~/get_parameter_types`.
    GetParameterTypes,
    /// `~/describe_parameters`.
    DescribeParameters,
    /// `~/set_parameters`.
    SetParameters,
    /// `~/set_parameters_atomically`.
    SetParametersAtomically,
}

impl Service {
    /// Every service, in the order the node lists them.
    pub const ALL: [Self; 10] = [
        Self::PredictTrajectory,
        Self::PredictRebound,
        Self::PlanReturn,
        Self::Reset,
        Self::ListParameters,
        Self::GetParameters,
        Self::GetParameterTypes,
        Self::DescribeParameters,
        Self::SetParameters,
        Self::SetParametersAtomically,
    ];

    /// Base name, private to the node (`~/name`).
    pub fn name(self) -> &'static str {
        match self {
            Self::PredictTrajectory => PREDICT_TRAJECTORY_SERVICE,
            Self::PredictRebound => PREDICT_REBOUND_SERVICE,
            Self::PlanReturn => PLAN_RETURN_SERVICE,
            Self::Reset => "reset",
            Self::ListParameters => "list_parameters",
            Self::GetParameters => "get_parameters",
            Self::GetParameterTypes => "get_parameter_types",
            Self::DescribeParameters => "describe_parameters",
            Self::SetParameters => "set_parameters",
            Self::SetParametersAtomically => "set_parameters_atomically",
        }
    }

    /// ROS 2 type, `pkg/srv/Type`.
    pub fn ros_type(self) -> &'static str {
        match self {
            Self::PredictTrajectory => PREDICT_TRAJECTORY_TYPE,
            Self::PredictRebound => PREDICT_REBOUND_TYPE,
            Self::PlanReturn => PLAN_RETURN_TYPE,
            Self::Reset => "std_srvs/srv/Trigger",
            Self::ListParameters => "rcl_interfaces/srv/ListParameters",
            Self::GetParameters => "rcl_interfaces/srv/GetParameters",
            Self::GetParameterTypes => "rcl_interfaces/srv/GetParameterTypes",
            Self::DescribeParameters => "rcl_interfaces/srv/DescribeParameters",
            Self::SetParameters => "rcl_interfaces/srv/SetParameters",
            Self::SetParametersAtomically => "rcl_interfaces/srv/SetParametersAtomically",
        }
    }
}

/// A request of any of the services.
#[derive(Debug, Clone)]
pub enum Request {
    /// Of `~/predict_trajectory`.
    PredictTrajectory(PredictTrajectoryRequest),
    /// Of `~/predict_rebound`.
    PredictRebound(PredictReboundRequest),
    /// Of `~/plan_return`.
    PlanReturn(PlanReturnRequest),
    /// Of `~/reset` (its request has no fields).
    Reset,
    /// Of `~/list_parameters`.
    ListParameters(ListParametersRequest),
    /// Of `~/get_parameters`.
    GetParameters(GetParametersRequest),
    /// Of `~/get_parameter_types`.
    GetParameterTypes(GetParameterTypesRequest),
    /// Of `~/describe_parameters`.
    DescribeParameters(DescribeParametersRequest),
    /// Of `~/set_parameters`.
    SetParameters(SetParametersRequest),
    /// Of `~/set_parameters_atomically`.
    SetParametersAtomically(SetParametersRequest),
}

/// A reply of any of the services.
#[derive(Debug, Clone)]
pub enum Reply {
    /// Of `~/predict_trajectory`.
    PredictTrajectory(PredictTrajectoryResponse),
    /// Of `~/predict_rebound`.
    PredictRebound(PredictReboundResponse),
    /// Of `~/plan_return`.
    PlanReturn(PlanReturnResponse),
    /// Of `~/reset`.
    Reset(TriggerResponse),
    /// Of `~/list_parameters`.
    ListParameters(ListParametersResponse),
    /// Of `~/get_parameters`.
    GetParameters(GetParametersResponse),
    /// Of `~/get_parameter_types`.
    GetParameterTypes(GetParameterTypesResponse),
    /// Of `~/describe_parameters`.
    DescribeParameters(DescribeParametersResponse),
    /// Of `~/set_parameters`.
    SetParameters(SetParametersResponse),
    /// Of `~/set_parameters_atomically`.
    SetParametersAtomically(SetParametersAtomicallyResponse),
}

/// What answering a request did to the node beyond its reply.
#[derive(Debug, Clone)]
pub enum Effect {
    /// Nothing.
    None,
    /// Parameters changed: the pipeline takes the configuration [`Parameters::config`] (from
    /// `previous`), and `/parameter_events` reports it.
    Changed(Box<Change>),
}

impl Request {
    /// The service it is for.
    pub fn service(&self) -> Service {
        match self {
            Self::PredictTrajectory(_) => Service::PredictTrajectory,
            Self::PredictRebound(_) => Service::PredictRebound,
            Self::PlanReturn(_) => Service::PlanReturn,
            Self::Reset => Service::Reset,
            Self::ListParameters(_) => Service::ListParameters,
            Self::GetParameters(_) => Service::GetParameters,
            Self::GetParameterTypes(_) => Service::GetParameterTypes,
            Self::DescribeParameters(_) => Service::DescribeParameters,
            Self::SetParameters(_) => Service::SetParameters,
            Self::SetParametersAtomically(_) => Service::SetParametersAtomically,
        }
    }

    /// The answer (on the estimator thread, so that it sees the live track, and changes the
    /// pipeline only between detections): the pipeline answers its own services, the
    /// parameters theirs; `~/reset` resets the pipeline; a change of parameters is applied to it.
    pub fn answer(&self, pipeline: &mut Pipeline, parameters: &mut Parameters) -> (Reply, Effect) {
        let (reply, change) = match self {
            Self::PredictTrajectory(r) => (
                Reply::PredictTrajectory(pipeline.predict_trajectory(r)),
                None,
            ),
            Self::PredictRebound(r) => (Reply::PredictRebound(pipeline.predict_rebound(r)), None),
            Self::PlanReturn(r) => (Reply::PlanReturn(pipeline.plan_return(r)), None),
            Self::Reset => {
                pipeline.reset(parameters.config());
                let message = "tracks dropped; the physics, the cameras' noise and the model's \
                               noise learned so far forgotten (the configured values again)";
                (
                    Reply::Reset(TriggerResponse {
                        success: true,
                        message: message.to_owned(),
                    }),
                    None,
                )
            }
            Self::ListParameters(r) => (
                Reply::ListParameters(ListParametersResponse {
                    result: parameters.list(&r.prefixes, r.depth),
                }),
                None,
            ),
            Self::GetParameters(r) => (
                Reply::GetParameters(GetParametersResponse {
                    values: parameters.get(&r.names),
                }),
                None,
            ),
            Self::GetParameterTypes(r) => (
                Reply::GetParameterTypes(GetParameterTypesResponse {
                    values: parameters.get_types(&r.names),
                }),
                None,
            ),
            Self::DescribeParameters(r) => (
                Reply::DescribeParameters(DescribeParametersResponse {
                    values: parameters.describe(&r.names),
                }),
                None,
            ),
            Self::SetParameters(r) => {
                let (results, change) = parameters.set(&r.parameter);
                (
                    Reply::SetParameters(SetParametersResponse { results }),
                    change,
                )
            }
            Self::SetParametersAtomically(r) => {
                let (result, change) = parameters.set_atomically(&r.parameter);
                (
                    Reply::SetParametersAtomically(SetParametersAtomicallyResponse { result }),
                    change,
                )
            }
        };
        match change {
            Some(change) => {
                pipeline.reconfigure(&change.previous, parameters.config());
                (reply, Effect::Changed(Box::new(change)))
            }
            None => (reply, Effect::None),
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
            Self::Reset(_) => Service::Reset,
            Self::ListParameters(_) => Service::ListParameters,
            Self::GetParameters(_) => Service::GetParameters,
            Self::GetParameterTypes(_) => Service::GetParameterTypes,
            Self::DescribeParameters(_) => Service::DescribeParameters,
            Self::SetParameters(_) => Service::SetParameters,
            Self::SetParametersAtomically(_) => Service::SetParametersAtomically,
        }
    }

    /// The reply of `service` that refuses a request: `success` false, `message`, every other
    /// field zero (for the parameter services, which have no such fields: an empty answer, and
    /// for the sets each parameter refused with `message`).
    pub fn refusal(service: Service, message: String) -> Self {
        let refused = || ros2_client::parameters::raw::SetParametersResult {
            successful: false,
            reason: message.clone(),
        };
        match service {
            Service::Reset => Self::Reset(TriggerResponse {
                success: false,
                message,
            }),
            Service::ListParameters => Self::ListParameters(ListParametersResponse {
                result: ros2_client::rcl_interfaces::ListParametersResult {
                    names: Vec::new(),
                    prefixes: Vec::new(),
                },
            }),
            Service::GetParameters => {
                Self::GetParameters(GetParametersResponse { values: Vec::new() })
            }
            Service::GetParameterTypes => {
                Self::GetParameterTypes(GetParameterTypesResponse { values: Vec::new() })
            }
            Service::DescribeParameters => {
                Self::DescribeParameters(DescribeParametersResponse { values: Vec::new() })
            }
            Service::SetParameters => Self::SetParameters(SetParametersResponse {
                results: vec![refused()],
            }),
            Service::SetParametersAtomically => {
                Self::SetParametersAtomically(SetParametersAtomicallyResponse { result: refused() })
            }
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

    /// Its `success` and `message` (for a set of parameters: whether all were set, and the
    /// first refusal's reason; for the other parameter services: true, "").
    pub fn outcome(&self) -> (bool, &str) {
        match self {
            Self::PredictTrajectory(r) => (r.success, &r.message),
            Self::PredictRebound(r) => (r.success, &r.message),
            Self::PlanReturn(r) => (r.success, &r.message),
            Self::Reset(r) => (r.success, &r.message),
            Self::SetParameters(r) => r
                .results
                .iter()
                .find(|r| !r.successful)
                .map_or((true, ""), |r| (false, r.reason.as_str())),
            Self::SetParametersAtomically(r) => (r.result.successful, &r.result.reason),
            Self::ListParameters(_)
            | Self::GetParameters(_)
            | Self::GetParameterTypes(_)
            | Self::DescribeParameters(_) => (true, ""),
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
    reset: Server<TriggerRequest, TriggerResponse>,
    list_parameters: Server<ListParametersRequest, ListParametersResponse>,
    get_parameters: Server<GetParametersRequest, GetParametersResponse>,
    get_parameter_types: Server<GetParameterTypesRequest, GetParameterTypesResponse>,
    describe_parameters: Server<DescribeParametersRequest, DescribeParametersResponse>,
    set_parameters: Server<SetParametersRequest, SetParametersResponse>,
    set_parameters_atomically: Server<SetParametersRequest, SetParametersAtomicallyResponse>,
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
            reset: server(node, node_name, mapping, Service::Reset)?,
            list_parameters: server(node, node_name, mapping, Service::ListParameters)?,
            get_parameters: server(node, node_name, mapping, Service::GetParameters)?,
            get_parameter_types: server(node, node_name, mapping, Service::GetParameterTypes)?,
            describe_parameters: server(node, node_name, mapping, Service::DescribeParameters)?,
            set_parameters: server(node, node_name, mapping, Service::SetParameters)?,
            set_parameters_atomically: server(
                node,
                node_name,
                mapping,
                Service::SetParametersAtomically,
            )?,
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
            incoming(&self.reset, Service::Reset, |_: TriggerRequest| {
                Request::Reset
            }),
            incoming(
                &self.list_parameters,
                Service::ListParameters,
                Request::ListParameters,
            ),
            incoming(
                &self.get_parameters,
                Service::GetParameters,
                Request::GetParameters,
            ),
            incoming(
                &self.get_parameter_types,
                Service::GetParameterTypes,
                Request::GetParameterTypes,
            ),
            incoming(
                &self.describe_parameters,
                Service::DescribeParameters,
                Request::DescribeParameters,
            ),
            incoming(
                &self.set_parameters,
                Service::SetParameters,
                Request::SetParameters,
            ),
            incoming(
                &self.set_parameters_atomically,
                Service::SetParametersAtomically,
                Request::SetParametersAtomically,
            ),
        ])
    }

    /// Sends a reply to the request `id` on its service's server.
    pub fn send(&self, id: RmwRequestId, reply: Reply) -> Result<(), String> {
        match reply {
            Reply::PredictTrajectory(r) => self.predict_trajectory.send_response(id, r),
            Reply::PredictRebound(r) => self.predict_rebound.send_response(id, r),
            Reply::PlanReturn(r) => self.plan_return.send_response(id, r),
            Reply::Reset(r) => self.reset.send_response(id, r),
            Reply::ListParameters(r) => self.list_parameters.send_response(id, r),
            Reply::GetParameters(r) => self.get_parameters.send_response(id, r),
            Reply::GetParameterTypes(r) => self.get_parameter_types.send_response(id, r),
            Reply::DescribeParameters(r) => self.describe_parameters.send_response(id, r),
            Reply::SetParameters(r) => self.set_parameters.send_response(id, r),
            Reply::SetParametersAtomically(r) => {
                self.set_parameters_atomically.send_response(id, r)
            }
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
        let config = Config::default();
        let mut pipeline = Pipeline::new(&config);
        let mut parameters = Parameters::new(&config);
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
            let (reply, effect) = request.answer(&mut pipeline, &mut parameters);
            assert!(matches!(effect, Effect::None));
            let (success, message) = reply.outcome();
            assert!(!success && !message.is_empty(), "{service:?}: {reply:?}");
            let expected = match request {
                Request::PredictTrajectory(r) => {
                    Reply::PredictTrajectory(pipeline.predict_trajectory(r))
                }
                Request::PredictRebound(r) => Reply::PredictRebound(pipeline.predict_rebound(r)),
                Request::PlanReturn(r) => Reply::PlanReturn(pipeline.plan_return(r)),
                _ => unreachable!(),
            };
            assert_eq!(format!("{reply:?}"), format!("{expected:?}"));
        }
        for service in Service::ALL {
            let busy = Reply::refusal(service, "busy".to_owned());
            assert_eq!(busy.service(), service);
            let (success, message) = busy.outcome();
            let answers_outcome = !matches!(
                service,
                Service::ListParameters
                    | Service::GetParameters
                    | Service::GetParameterTypes
                    | Service::DescribeParameters
            );
            if answers_outcome {
                assert_eq!((success, message), (false, "busy"), "{service:?}");
            }
        }
        let names: Vec<&str> = Service::ALL.iter().map(|s| s.name()).collect();
        assert_eq!(
            names,
            [
                "predict_trajectory",
                "predict_rebound",
                "plan_return",
                "reset",
                "list_parameters",
                "get_parameters",
                "get_parameter_types",
                "describe_parameters",
                "set_parameters",
                "set_parameters_atomically"
            ]
        );
        let types: Vec<&str> = Service::ALL.iter().map(|s| s.ros_type()).collect();
        assert_eq!(
            types[..4],
            [
                "ttball_msgs/srv/PredictTrajectory",
                "ttball_msgs/srv/PredictRebound",
                "ttball_msgs/srv/PlanReturn",
                "std_srvs/srv/Trigger"
            ]
        );
    }

    #[test]
    fn a_parameter_set_reconfigures_the_pipeline_and_reset_keeps_it() {
        use ros2_client::parameters::raw::{Parameter, ParameterType, ParameterValue};
        let config = Config::default();
        let mut pipeline = Pipeline::new(&config);
        let mut parameters = Parameters::new(&config);
        let value = ParameterValue {
            double_value: -1.2,
            ..super::super::parameters::empty_value(ParameterType::DOUBLE)
        };
        let request = Request::SetParameters(SetParametersRequest {
            parameter: vec![Parameter {
                name: "intercept.plane_x".to_owned(),
                value,
            }],
        });
        let (reply, effect) = request.answer(&mut pipeline, &mut parameters);
        assert_eq!(reply.outcome(), (true, ""));
        let Effect::Changed(change) = effect else {
            panic!("no change: {effect:?}");
        };
        assert_eq!(change.changed[0].name, "intercept.plane_x");
        assert_eq!(parameters.config().intercept.plane_x, -1.2);
        let (reply, _) = Request::Reset.answer(&mut pipeline, &mut parameters);
        assert!(reply.outcome().0);
        // What the node runs with after the reset is the configuration as set.
        assert_eq!(parameters.config().intercept.plane_x, -1.2);
    }
}

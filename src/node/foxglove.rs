//! The Foxglove live view that acts: the app gets and sets the node's parameters and calls
//! `~/predict_trajectory`, `~/predict_rebound` and `~/plan_return`, through the Foxglove SDK's
//! parameter and service capabilities. The SDK's handlers hand each request to the estimator
//! thread over a bounded channel, as the DDS thread hands it a ROS request; the thread answers it
//! between detections with the same code ([`Request::answer`]), so the app meets the same
//! ranges, refusals and answers as a ROS client, and the SDK's responders carry the answers
//! back without any thread waiting. A full channel is answered at once as busy.
//!
//! Services take and give `cdr` payloads with the `ros2msg` schemas of the `.srv` halves, the
//! bytes a ROS client sends. Parameters keep their ROS types: a double stays a double (the
//! protocol's `float64` hint), a number the app sends for an integer parameter must be whole.
//! A refused set leaves the value as it was, which the answer shows, and the reason appears in
//! the app as a warning status.

use std::sync::Arc;

use crossbeam::channel::{Sender, TrySendError};
use foxglove::Schema;
use foxglove::bytes::Bytes;
use foxglove::websocket::service::{
    Handler, Request as ServiceRequest, Responder, Service as AppService, ServiceSchema,
};
use foxglove::websocket::{
    AnyClient, GetParametersResponder, Parameter as AppParameter, ParameterHandler,
    ParameterType as AppType, ParameterValue as AppValue, SetParametersResponder,
};
use ros2_client::parameters::raw::{Parameter, ParameterType, ParameterValue};
use ros2_client::rcl_interfaces::SetParametersRequest;

use super::parameters::Parameters;
use super::services::{Effect, Reply, Request, Service};
use crate::bag::live_view::Interaction;
use crate::bag::{decode, encode};
use crate::ros::msgs::definitions;
use crate::ros::pipeline::Pipeline;

/// The services the app may call.
const SERVICES: [Service; 3] = [
    Service::PredictTrajectory,
    Service::PredictRebound,
    Service::PlanReturn,
];

/// A request of the app's, waiting for the estimator thread.
pub enum AppRequest {
    /// Get the named parameters' values (every parameter's for no name).
    Get {
        /// The names.
        names: Vec<String>,
        /// Takes the values.
        responder: GetParametersResponder,
    },
    /// Set parameters, each on its own as `set_parameters` does.
    Set {
        /// The values asked for.
        parameters: Vec<AppParameter>,
        /// Takes the values after the set.
        responder: SetParametersResponder,
    },
    /// Call a service with a `cdr` request.
    Call {
        /// Which.
        service: Service,
        /// The request's CDR bytes.
        payload: Bytes,
        /// Takes the response's CDR bytes, or why there is none.
        responder: Responder,
    },
}

/// Hands the app's parameter requests to the estimator thread.
struct ParameterRequests(Sender<AppRequest>);

impl ParameterHandler for ParameterRequests {
    fn get(
        &self,
        _client: AnyClient,
        names: Vec<String>,
        _request_id: Option<String>,
        responder: GetParametersResponder,
    ) {
        if let Err(
            TrySendError::Full(AppRequest::Get { responder, .. })
            | TrySendError::Disconnected(AppRequest::Get { responder, .. }),
        ) = self.0.try_send(AppRequest::Get { names, responder })
        {
            responder.respond(Vec::new());
        }
    }

    fn set(
        &self,
        _client: AnyClient,
        parameters: Vec<AppParameter>,
        _request_id: Option<String>,
        responder: SetParametersResponder,
    ) {
        if let Err(
            TrySendError::Full(AppRequest::Set { responder, .. })
            | TrySendError::Disconnected(AppRequest::Set { responder, .. }),
        ) = self.0.try_send(AppRequest::Set {
            parameters,
            responder,
        }) {
            responder.respond(Vec::new());
        }
    }
}

/// Hands the app's calls of one service to the estimator thread.
struct ServiceCalls {
    service: Service,
    requests: Sender<AppRequest>,
}

impl Handler for ServiceCalls {
    fn call(&self, request: ServiceRequest, responder: Responder) {
        let call = AppRequest::Call {
            service: self.service,
            payload: request.into_payload(),
            responder,
        };
        match self.requests.try_send(call) {
            Ok(()) => {}
            Err(TrySendError::Full(AppRequest::Call { responder, .. })) => {
                responder.respond_err(super::busy_message());
            }
            Err(TrySendError::Disconnected(AppRequest::Call { responder, .. })) => {
                responder.respond_err("the node is stopping".to_owned());
            }
            Err(_) => {}
        }
    }
}

/// What the app may do, its requests sent to `requests`; the services under the node's
/// fully qualified name `node_fqn` (`/ttball/predict_trajectory`).
pub fn interaction(requests: &Sender<AppRequest>, node_fqn: &str) -> Interaction {
    let services = SERVICES
        .iter()
        .filter_map(|&service| {
            let ros_type = service.ros_type();
            let (request, response) = definitions::service_schemas(ros_type)?;
            let schema = |half: &str, text: String| {
                Schema::new(format!("{ros_type}_{half}"), "ros2msg", text.into_bytes())
            };
            let schema = ServiceSchema::new(ros_type)
                .with_request("cdr", schema("Request", request))
                .with_response("cdr", schema("Response", response));
            Some(
                AppService::builder(format!("{node_fqn}/{}", service.name()), schema).handler(
                    ServiceCalls {
                        service,
                        requests: requests.clone(),
                    },
                ),
            )
        })
        .collect();
    Interaction {
        parameters: Arc::new(ParameterRequests(requests.clone())),
        services,
    }
}

/// What answering an app request did: the effect on the node, and the reasons of refused
/// parameters (for the app's status line).
pub struct Answered {
    /// As a ROS request's.
    pub effect: Effect,
    /// `name: reason` of each parameter refused.
    pub refused: Vec<String>,
}

/// Answers one app request on the estimator thread, as [`Request::answer`] answers ROS's.
pub fn answer(
    request: AppRequest,
    pipeline: &mut Pipeline,
    parameters: &mut Parameters,
) -> Answered {
    let nothing = |refused| Answered {
        effect: Effect::None,
        refused,
    };
    match request {
        AppRequest::Get { names, responder } => {
            let names = if names.is_empty() {
                parameters.names().map(str::to_owned).collect()
            } else {
                names
            };
            responder.respond(values(parameters, &names));
            nothing(Vec::new())
        }
        AppRequest::Set {
            parameters: asked,
            responder,
        } => {
            let names: Vec<String> = asked.iter().map(|p| p.name.clone()).collect();
            let mut refused = Vec::new();
            let mut ros = Vec::new();
            for p in &asked {
                let declared = parameters.get_types(std::slice::from_ref(&p.name))[0];
                match to_ros(p, declared) {
                    Ok(value) => ros.push(value),
                    Err(why) => refused.push(format!("{}: {why}", p.name)),
                }
            }
            let request = Request::SetParameters(SetParametersRequest {
                parameter: ros.clone(),
            });
            let (reply, effect) = request.answer(pipeline, parameters);
            if let Reply::SetParameters(response) = reply {
                for (p, result) in ros.iter().zip(&response.results) {
                    if !result.successful {
                        refused.push(format!("{}: {}", p.name, result.reason));
                    }
                }
            }
            responder.respond(values(parameters, &names));
            Answered { effect, refused }
        }
        AppRequest::Call {
            service,
            payload,
            responder,
        } => {
            match call(service, &payload, pipeline, parameters) {
                Ok(bytes) => responder.respond_ok(bytes),
                Err(why) => responder.respond_err(why),
            }
            nothing(Vec::new())
        }
    }
}

/// A service's CDR response to a CDR request, or why there is none.
fn call(
    service: Service,
    payload: &[u8],
    pipeline: &mut Pipeline,
    parameters: &mut Parameters,
) -> Result<Vec<u8>, String> {
    let undecodable = |e: crate::bag::DecodeError| {
        format!(
            "the request is not a CDR {}_Request: {e}",
            service.ros_type()
        )
    };
    let request = match service {
        Service::PredictTrajectory => {
            Request::PredictTrajectory(decode(payload).map_err(undecodable)?)
        }
        Service::PredictRebound => Request::PredictRebound(decode(payload).map_err(undecodable)?),
        Service::PlanReturn => Request::PlanReturn(decode(payload).map_err(undecodable)?),
        _ => return Err(format!("{} is not offered to the app", service.name())),
    };
    let (reply, _) = request.answer(pipeline, parameters);
    let response = format!("{}_Response", service.ros_type());
    let encoded = match &reply {
        Reply::PredictTrajectory(r) => encode(&response, r),
        Reply::PredictRebound(r) => encode(&response, r),
        Reply::PlanReturn(r) => encode(&response, r),
        _ => return Err("no response".to_owned()),
    };
    encoded.map_err(|e| e.to_string())
}

/// The app's values of the named parameters (no value for a name not declared).
pub fn values(parameters: &Parameters, names: &[String]) -> Vec<AppParameter> {
    names
        .iter()
        .zip(parameters.get(names))
        .map(|(name, value)| to_app(name, &value))
        .collect()
}

/// A ROS parameter's value as the app's, its type kept by the protocol's hints.
pub fn to_app(name: &str, value: &ParameterValue) -> AppParameter {
    let floats = |v: &[f64]| AppValue::Array(v.iter().map(|&x| AppValue::Float64(x)).collect());
    let (r#type, value) = match value.ptype {
        ParameterType::BOOL => (None, Some(AppValue::Bool(value.boolean_value))),
        ParameterType::INTEGER => (None, Some(AppValue::Integer(value.int_value))),
        ParameterType::DOUBLE => (
            Some(AppType::Float64),
            Some(AppValue::Float64(value.double_value)),
        ),
        ParameterType::STRING => (None, Some(AppValue::String(value.string_value.clone()))),
        ParameterType::DOUBLE_ARRAY => (
            Some(AppType::Float64Array),
            Some(floats(&value.double_array)),
        ),
        ParameterType::INTEGER_ARRAY => (
            None,
            Some(AppValue::Array(
                value
                    .int_array
                    .iter()
                    .map(|&i| AppValue::Integer(i))
                    .collect(),
            )),
        ),
        ParameterType::STRING_ARRAY => (
            None,
            Some(AppValue::Array(
                value
                    .string_array
                    .iter()
                    .map(|s| AppValue::String(s.clone()))
                    .collect(),
            )),
        ),
        ParameterType::BOOL_ARRAY => (
            None,
            Some(AppValue::Array(
                value
                    .bool_array
                    .iter()
                    .map(|&b| AppValue::Bool(b))
                    .collect(),
            )),
        ),
        _ => (None, None),
    };
    AppParameter {
        name: name.to_owned(),
        r#type,
        value,
    }
}

/// The app's value as a ROS parameter of the declared type (`NOT_SET`: as the value's own
/// type, for the set to refuse by name), or why it cannot be one.
fn to_ros(p: &AppParameter, declared: u8) -> Result<Parameter, String> {
    let Some(value) = &p.value else {
        return Err("a parameter cannot be unset".to_owned());
    };
    let number = |v: &AppValue| match v {
        AppValue::Float64(x) => Some(*x),
        AppValue::Integer(i) => Some(*i as f64),
        _ => None,
    };
    let whole = |v: &AppValue| match v {
        AppValue::Integer(i) => Some(*i),
        AppValue::Float64(x) if x.fract() == 0.0 && x.abs() < 9.0e15 => Some(*x as i64),
        _ => None,
    };
    let ptype = match (declared, value) {
        (ParameterType::NOT_SET, AppValue::Bool(_)) => ParameterType::BOOL,
        (ParameterType::NOT_SET, AppValue::Integer(_)) => ParameterType::INTEGER,
        (ParameterType::NOT_SET, AppValue::Float64(_)) => ParameterType::DOUBLE,
        (ParameterType::NOT_SET, AppValue::String(_)) => ParameterType::STRING,
        (ParameterType::NOT_SET, _) => ParameterType::DOUBLE_ARRAY,
        (declared, _) => declared,
    };
    let mut out = super::parameters::empty_value(ptype);
    let wrong = || format!("a value of type {} is expected", type_name(ptype));
    match (ptype, value) {
        (ParameterType::BOOL, AppValue::Bool(b)) => out.boolean_value = *b,
        (ParameterType::INTEGER, v) => {
            out.int_value = whole(v).ok_or_else(|| "a whole number is expected".to_owned())?;
        }
        (ParameterType::DOUBLE, v) => out.double_value = number(v).ok_or_else(wrong)?,
        (ParameterType::STRING, AppValue::String(s)) => out.string_value = s.clone(),
        (ParameterType::DOUBLE_ARRAY, AppValue::Array(items)) => {
            out.double_array = items
                .iter()
                .map(number)
                .collect::<Option<_>>()
                .ok_or_else(wrong)?;
        }
        (ParameterType::INTEGER_ARRAY, AppValue::Array(items)) => {
            out.int_array = items
                .iter()
                .map(whole)
                .collect::<Option<_>>()
                .ok_or_else(wrong)?;
        }
        (ParameterType::STRING_ARRAY, AppValue::Array(items)) => {
            out.string_array = items
                .iter()
                .map(|v| match v {
                    AppValue::String(s) => Some(s.clone()),
                    _ => None,
                })
                .collect::<Option<_>>()
                .ok_or_else(wrong)?;
        }
        _ => return Err(wrong()),
    }
    Ok(Parameter {
        name: p.name.clone(),
        value: out,
    })
}

/// A ROS parameter type's name, for messages.
fn type_name(ptype: u8) -> &'static str {
    match ptype {
        ParameterType::BOOL => "bool",
        ParameterType::INTEGER => "integer",
        ParameterType::DOUBLE => "double",
        ParameterType::STRING => "string",
        ParameterType::DOUBLE_ARRAY => "double array",
        ParameterType::INTEGER_ARRAY => "integer array",
        ParameterType::STRING_ARRAY => "string array",
        ParameterType::BOOL_ARRAY => "bool array",
        _ => "unknown",
    }
}

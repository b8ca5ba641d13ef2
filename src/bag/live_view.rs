//! The live view without ROS: the node's topics (or a replay's, at recorded pace) served to the
//! Foxglove app over the Foxglove WebSocket protocol, through Foxglove's own SDK (the `foxglove`
//! crate's WebSocket server). Each topic is a channel with its message type's `ros2msg` schema
//! (every dependent definition embedded, as in ttball's bags) and `cdr` payloads, the same bytes
//! the DDS samples and bag messages carry; each message keeps its log time.
//!
//! The node's view also acts ([`Interaction`]): the app gets and sets its parameters and calls
//! its services through the SDK's parameter and service capabilities.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use foxglove::websocket::service::Service;
use foxglove::websocket::{Capability, Parameter, ParameterHandler, Status};
use foxglove::{ChannelBuilder, Context, PartialMetadata, RawChannel, Schema, WebSocketServer};

use crate::bag::{ChannelInfo, encode};

/// Why the live view could not start.
#[derive(Debug, thiserror::Error)]
pub enum LiveViewError {
    /// The address is not `HOST:PORT`.
    #[error(
        "--foxglove {0}: give HOST:PORT, e.g. 127.0.0.1:8765 (0.0.0.0:8765 for other machines)"
    )]
    Address(String),
    /// The server could not start (e.g. the port is taken).
    #[error("cannot serve the Foxglove live view on {address}: {reason}")]
    Start {
        /// The address asked for.
        address: String,
        /// What the server said.
        reason: String,
    },
}

/// A running Foxglove WebSocket server and its channels, one per topic.
pub struct LiveView {
    context: Arc<Context>,
    server: Option<foxglove::WebSocketServerHandle>,
    channels: HashMap<String, Arc<RawChannel>>,
    /// Replays at recorded pace: the wall time of the first message and its log time, and the
    /// speed-up (`None`: log at once, as the live node does).
    pace: Option<(f64, Option<(Instant, u64)>)>,
}

/// What the app may do beyond watching: get and set parameters through `parameters`, call
/// `services` (each with its request's and response's `ros2msg` schema, `cdr` encoded).
pub struct Interaction {
    /// Answers the app's parameter requests.
    pub parameters: Arc<dyn ParameterHandler>,
    /// The services the app may call.
    pub services: Vec<Service>,
}

impl LiveView {
    /// Serves on `address` (`HOST:PORT`; port 0 picks a free one, see [`Self::port`]), for
    /// watching only, with `channels` advertised from the start (see [`Self::start_with`]).
    pub fn start(address: &str, channels: &[ChannelInfo]) -> Result<Self, LiveViewError> {
        Self::start_with(address, channels, None)
    }

    /// Serves on `address`, with the parameters and services of `interaction` when given.
    /// `channels` (the topics known to come) are advertised to each app as it connects, before
    /// it can subscribe: a channel first advertised to an app already connected may be lost to
    /// it (the SDK sends the advertisement before it can take the app's subscription).
    pub fn start_with(
        address: &str,
        channels: &[ChannelInfo],
        interaction: Option<Interaction>,
    ) -> Result<Self, LiveViewError> {
        let (host, port) = address
            .rsplit_once(':')
            .and_then(|(h, p)| Some((h, p.parse::<u16>().ok()?)))
            .filter(|(h, _)| !h.is_empty())
            .ok_or_else(|| LiveViewError::Address(address.to_owned()))?;
        let context = Context::new();
        let mut view = Self {
            context: context.clone(),
            server: None,
            channels: HashMap::new(),
            pace: None,
        };
        for channel in channels {
            view.advertise(channel);
        }
        let mut server = WebSocketServer::new()
            .name("ttball")
            .bind(host, port)
            .context(&context);
        server = match interaction {
            Some(interaction) => server
                .capabilities([Capability::Time, Capability::Parameters])
                .parameter_handler(interaction.parameters)
                .services(interaction.services)
                .supported_encodings(["cdr"]),
            None => server.capabilities([Capability::Time]),
        };
        view.server = Some(server.start_blocking().map_err(|e| LiveViewError::Start {
            address: address.to_owned(),
            reason: e.to_string(),
        })?);
        Ok(view)
    }

    /// Logs messages at the pace of their log times, `rate` times as fast (replays).
    pub fn at_recorded_pace(mut self, rate: f64) -> Self {
        self.pace = Some((rate, None));
        self
    }

    /// The port served (the one picked, for port 0).
    pub fn port(&self) -> u16 {
        self.server
            .as_ref()
            .map_or(0, foxglove::WebSocketServerHandle::port)
    }

    /// How many Foxglove clients are connected.
    pub fn clients(&self) -> usize {
        self.server
            .as_ref()
            .map_or(0, foxglove::WebSocketServerHandle::client_count)
    }

    /// Tells the app's parameter subscribers the new values of `parameters`.
    pub fn publish_parameters(&self, parameters: Vec<Parameter>) {
        if let Some(server) = &self.server {
            server.publish_parameter_values(parameters);
        }
    }

    /// Shows `status` in the app (e.g. why a parameter set was refused).
    pub fn publish_status(&self, status: Status) {
        if let Some(server) = &self.server {
            server.publish_status(status);
        }
    }

    /// Waits until a client connects, at most `timeout`; whether one did.
    pub fn wait_for_client(&self, timeout: Duration) -> bool {
        let until = Instant::now() + timeout;
        while self.clients() == 0 && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(20));
        }
        self.clients() > 0
    }

    /// Sends one message (its CDR payload) on its channel's topic, the channel advertised on
    /// first use with its schema.
    pub fn log(&mut self, channel: &ChannelInfo, log_time: u64, payload: &[u8]) {
        self.send(&channel.topic, log_time, payload, || Some(channel.clone()));
    }

    /// Sends a message of one of ttball's known types (`pkg/msg/Type`) on `topic` (nothing for
    /// an empty topic, or a type without a definition).
    pub fn log_message<T: serde::Serialize>(
        &mut self,
        topic: &str,
        type_name: &str,
        log_time: u64,
        msg: &T,
    ) {
        if topic.is_empty() {
            return;
        }
        let Ok(payload) = encode(type_name, msg) else {
            return;
        };
        self.send(topic, log_time, &payload, || {
            ChannelInfo::ros2(topic, type_name)
        });
    }

    /// [`Self::log_message`] when there is a message.
    pub fn log_optional<T: serde::Serialize>(
        &mut self,
        topic: &str,
        type_name: &str,
        log_time: u64,
        msg: Option<&T>,
    ) {
        if let Some(msg) = msg {
            self.log_message(topic, type_name, log_time, msg);
        }
    }

    /// Advertises `channel` (once per topic). A topic the SDK refuses (it never has) is not
    /// shown; the rest goes on.
    fn advertise(&mut self, channel: &ChannelInfo) {
        if self.channels.contains_key(&channel.topic) {
            return;
        }
        let built = ChannelBuilder::new(channel.topic.clone())
            .context(&self.context)
            .message_encoding(channel.message_encoding.clone())
            .schema((!channel.schema_name.is_empty()).then(|| {
                Schema::new(
                    channel.schema_name.clone(),
                    channel.schema_encoding.clone(),
                    channel.schema_data.clone(),
                )
            }))
            .build_raw();
        if let Ok(raw) = built {
            self.channels.insert(channel.topic.clone(), raw);
        }
    }

    /// Sends `payload` on `topic`, whose channel `describe` gives the first time.
    fn send(
        &mut self,
        topic: &str,
        log_time: u64,
        payload: &[u8],
        describe: impl FnOnce() -> Option<ChannelInfo>,
    ) {
        if let Some((rate, start)) = &mut self.pace {
            let (wall, first) = *start.get_or_insert((Instant::now(), log_time));
            let due = Duration::from_secs_f64(log_time.saturating_sub(first) as f64 * 1e-9 / *rate);
            if let Some(wait) = (wall + due).checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
        }
        if !self.channels.contains_key(topic) {
            let Some(channel) = describe() else {
                return;
            };
            self.advertise(&channel);
        }
        if let Some(raw) = self.channels.get(topic) {
            raw.log_with_meta(
                payload,
                PartialMetadata {
                    log_time: Some(log_time),
                },
            );
        }
        if let Some(server) = &self.server {
            server.broadcast_time(log_time);
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        if let Some(server) = self.server.take() {
            drop(server.stop());
        }
    }
}

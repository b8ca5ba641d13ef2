//! The Foxglove live view as an app meets it on connecting, through a plain WebSocket client
//! speaking the Foxglove protocol.

use std::time::Duration;

use ttball::bag::live_view::LiveView;
use ttball::bag::replay::output_channels;
use ttball::config::Config;
use tungstenite::client::IntoClientRequest;
use tungstenite::{Message, stream::MaybeTlsStream};

/// Every channel known in advance (here ttball's outputs) is in the advertisements an app gets
/// on connecting, before anything is logged: an app never has to subscribe to a channel
/// advertised while it is connected, which the Foxglove SDK may refuse (it sends such an
/// advertisement before it can take the subscription to it).
#[test]
fn channels_known_in_advance_are_advertised_as_an_app_connects() {
    let channels: Vec<_> = output_channels(&Config::default().resolved_topics()).collect();
    assert!(channels.len() >= 4);
    let view = LiveView::start("127.0.0.1:0", &channels).unwrap();
    let mut request = format!("ws://127.0.0.1:{}", view.port())
        .into_client_request()
        .unwrap();
    request
        .headers_mut()
        .insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse().unwrap());
    let (mut socket, _) = tungstenite::connect(request).unwrap();
    if let MaybeTlsStream::Plain(stream) = socket.get_mut() {
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
    }
    let mut advertised = Vec::new();
    while advertised.len() < channels.len() {
        let Message::Text(text) = socket.read().expect("the advertisements, within 10 s") else {
            continue;
        };
        let message: serde_json::Value = serde_json::from_str(&text).unwrap();
        if message["op"] == "advertise" {
            for channel in message["channels"].as_array().unwrap() {
                assert_eq!(channel["encoding"], "cdr", "{channel}");
                assert_eq!(channel["schemaEncoding"], "ros2msg", "{channel}");
                advertised.push(channel["topic"].as_str().unwrap().to_owned());
            }
        }
    }
    advertised.sort();
    let mut expected: Vec<_> = channels.iter().map(|c| c.topic.clone()).collect();
    expected.sort();
    assert_eq!(advertised, expected);
}

//! `ttball dump`: every message of a bag as JSON lines, decoded by ttball (for inspection, and
//! for the interoperability check against the Python MCAP clients).

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use serde_json::{Value, json};
use ttball::bag::{DecodeError, damage_text, decode, read_bag_file};
use ttball::ros::msgs::nav_msgs::Odometry;
use ttball::ros::msgs::ttball_msgs::msg::{
    BallDetection, BallState, InterceptPrediction, PredictedTrajectory,
};
use ttball::ros::msgs::type_names::{
    DETECTION_TYPE, INTERCEPT_TYPE, MARKERS_TYPE, ODOMETRY_TYPE, STATE_TYPE, TRAJECTORY_TYPE,
};
use ttball::ros::msgs::visualization_msgs::MarkerArray;

/// Arguments of `ttball dump`.
#[derive(Debug, Args)]
pub struct DumpArgs {
    /// The bag.
    #[arg(value_name = "BAG.mcap")]
    pub bag: PathBuf,

    /// Only these topics (repeatable); all topics of known types by default.
    #[arg(long, value_name = "TOPIC")]
    pub topic: Vec<String>,
}

fn to_json<T: serde::de::DeserializeOwned + serde::Serialize>(
    data: &[u8],
) -> Result<Value, DecodeError> {
    let msg: T = decode(data)?;
    serde_json::to_value(&msg).map_err(|e| DecodeError::Cdr(e.to_string()))
}

/// The message as JSON, for the types ttball knows.
fn decode_json(schema: &str, data: &[u8]) -> Option<Result<Value, DecodeError>> {
    Some(match schema {
        DETECTION_TYPE => to_json::<BallDetection>(data),
        STATE_TYPE => to_json::<BallState>(data),
        INTERCEPT_TYPE => to_json::<InterceptPrediction>(data),
        TRAJECTORY_TYPE => to_json::<PredictedTrajectory>(data),
        MARKERS_TYPE => to_json::<MarkerArray>(data),
        ODOMETRY_TYPE => to_json::<Odometry>(data),
        _ => return None,
    })
}

impl DumpArgs {
    /// Prints the messages.
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let contents = read_bag_file(&self.bag)?;
        if let Some(damage) = damage_text(&contents.damage) {
            eprintln!("warning: {}: {damage}", self.bag.display());
        }
        let stdout = std::io::stdout();
        let mut out = std::io::BufWriter::new(stdout.lock());
        for m in &contents.messages {
            let channel = &contents.channels[m.channel];
            if !self.topic.is_empty() && !self.topic.contains(&channel.topic) {
                continue;
            }
            let Some(decoded) = decode_json(&channel.schema_name, &m.data) else {
                continue;
            };
            let message = decoded.with_context(|| {
                format!(
                    "{}: cannot decode a message on {} as {}",
                    self.bag.display(),
                    channel.topic,
                    channel.schema_name
                )
            })?;
            let line = json!({
                "topic": channel.topic,
                "type": channel.schema_name,
                "log_time": m.log_time,
                "publish_time": m.publish_time,
                "message": message,
            });
            match writeln!(out, "{line}") {
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                    return Ok(ExitCode::SUCCESS);
                }
                other => other?,
            }
        }
        match out.flush() {
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
            other => other?,
        }
        Ok(ExitCode::SUCCESS)
    }
}

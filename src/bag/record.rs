//! Bags written by ttball: [`write_detections`] (e.g. real flights imported from CSV), and
//! [`write_session`], simulated play (`ttball simulate`): the session's detections on `topics.detections`
//! in arrival order (log time = arrival, header stamp = exposure), the true state at each
//! detection's stamp on `topics.truth`, and each shot's true crossing of the hitting plane and
//! bounce on `topics.truth` + `/intercept`. The same session gives the same bytes.

use std::path::Path;

use crate::bag::replay::{DETECTION_TYPE, INTERCEPT_TYPE, STATE_TYPE, truth_intercept_topic};
use crate::bag::{BagError, BagWriter, OfferedQos, encode, mcap_time};
use crate::config::Config;
use crate::eval::sim::Session;
use crate::model::detection::Detection;
use crate::ros::msgs::convert::{detection_to_msg, truth_intercept_msg, truth_msg};

/// Writes a simulated session as a ROS 2 MCAP bag, with its truth or (`with_truth` false) the
/// detections alone, as a camera system records them; returns the number of messages written.
pub fn write_session(
    session: &Session,
    config: &Config,
    path: &Path,
    with_truth: bool,
) -> Result<u64, BagError> {
    let mut writer = BagWriter::create(path)?;
    let detections = writer.channel_with_qos(
        &config.resolved_topics().detections,
        DETECTION_TYPE,
        OfferedQos::SensorData,
    )?;
    // Without truth, no truth channels either: the bag is what a camera system records.
    let truth_channels = if with_truth {
        Some((
            writer.channel(&config.resolved_topics().truth, STATE_TYPE)?,
            writer.channel(
                &truth_intercept_topic(&config.resolved_topics().truth),
                INTERCEPT_TYPE,
            )?,
        ))
    } else {
        None
    };

    // (log time, order, channel, payload), written in log-time order.
    let mut records: Vec<(u64, usize, u16, Vec<u8>)> = Vec::new();
    if let Some((_, events)) = truth_channels {
        for (k, shot) in session.shots.iter().enumerate() {
            let id = u32::try_from(k + 1).unwrap_or(u32::MAX);
            let msg = truth_intercept_msg(id, shot);
            records.push((
                mcap_time(shot.launch_stamp),
                records.len(),
                events,
                encode(INTERCEPT_TYPE, &msg)?,
            ));
        }
    }
    for sim in &session.stream {
        let t = mcap_time(sim.arrival);
        let detection = encode(DETECTION_TYPE, &detection_to_msg(&sim.detection))?;
        records.push((t, records.len(), detections, detection));
        if let Some((truth, _)) = truth_channels {
            let id = u32::try_from(sim.shot + 1).unwrap_or(u32::MAX);
            let state = encode(STATE_TYPE, &truth_msg(sim.detection.stamp, id, &sim.truth))?;
            records.push((t, records.len(), truth, state));
        }
    }
    records.sort_by_key(|(t, order, _, _)| (*t, *order));
    for (t, _, channel, payload) in &records {
        writer.write_raw(*channel, *t, *t, payload)?;
    }
    writer.finish()?;
    Ok(records.len() as u64)
}

/// Writes detections on `topics.detections`, log time = stamp, in stamp order; returns the
/// number of messages written.
pub fn write_detections(
    detections: &[Detection],
    config: &Config,
    path: &Path,
) -> Result<u64, BagError> {
    let mut writer = BagWriter::create(path)?;
    let channel = writer.channel_with_qos(
        &config.resolved_topics().detections,
        DETECTION_TYPE,
        OfferedQos::SensorData,
    )?;
    let mut sorted: Vec<&Detection> = detections.iter().collect();
    sorted.sort_by_key(|d| d.stamp);
    for d in &sorted {
        let t = mcap_time(d.stamp);
        writer.write(channel, DETECTION_TYPE, t, &detection_to_msg(d))?;
    }
    writer.finish()?;
    Ok(sorted.len() as u64)
}

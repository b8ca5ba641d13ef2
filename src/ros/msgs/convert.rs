//! The boundary between ROS messages and the core: detections in, estimates, interceptions,
//! trajectories and RViz/Foxglove markers out; the racket services' requests in, rebounds and
//! racket commands out. Stamps become integer nanoseconds; an all-zero
//! covariance becomes "use the configured noise".

use nalgebra::{Matrix3, Vector3};

use super::builtin_interfaces::{Duration, Time};
use super::geometry_msgs::{Point, Pose, Quaternion, Vector3 as RosVector3};
use super::std_msgs::{ColorRGBA, Header};
use super::ttball_msgs::msg::{
    BallDetection, BallState, InterceptPrediction, PredictedTrajectory, RobotHit,
};
use super::ttball_msgs::srv::{PlanReturnResponse, PredictReboundRequest, PredictReboundResponse};
use super::visualization_msgs::{Marker, MarkerArray};
use crate::model::detection::{Detection, Source, seconds_to_ns};
use crate::online::estimator::{Estimate, InterceptEstimate, TrackStatus};
use crate::online::stroke::{Plan, Rebound, ReturnOutcome};
use crate::physics::{self, RacketState, StateMatrix, Trajectory};

/// The table frame's default name (`frames.table_frame`); the frame of the simulator's
/// messages.
pub const TABLE_FRAME: &str = "table";

/// A message that cannot become a core value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConvertError {
    /// The detection is not in the table frame, nor in a frame connected to it.
    #[error(
        "frame_id `{frame}` is not the table frame `{table}`, and no static transform on /tf_static connects it to `{table}`"
    )]
    UnknownFrame {
        /// The detection's frame.
        frame: String,
        /// The table frame's name.
        table: String,
    },
    /// A robot hit's racket normal is not a unit vector (or not finite).
    #[error(
        "racket_normal has length {length:.6}: give the unit normal of the hitting face, pointing toward the ball"
    )]
    NotUnitNormal {
        /// Its length.
        length: f64,
    },
}

fn point(v: &Vector3<f64>) -> Point {
    Point {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

fn vector(v: &Vector3<f64>) -> RosVector3 {
    RosVector3 {
        x: v.x,
        y: v.y,
        z: v.z,
    }
}

fn from_point(p: &Point) -> Vector3<f64> {
    Vector3::new(p.x, p.y, p.z)
}

fn from_vector(v: &RosVector3) -> Vector3<f64> {
    Vector3::new(v.x, v.y, v.z)
}

/// A row-major 3x3 covariance; all zero means "not given".
fn covariance3(values: &[f64; 9]) -> Option<Matrix3<f64>> {
    if values.iter().all(|v| *v == 0.0) {
        None
    } else {
        Some(Matrix3::from_row_slice(values))
    }
}

fn row_major3(m: &Option<Matrix3<f64>>) -> [f64; 9] {
    let mut out = [0.0; 9];
    if let Some(m) = m {
        for (i, slot) in out.iter_mut().enumerate() {
            *slot = m[(i / 3, i % 3)];
        }
    }
    out
}

fn row_major9(m: &StateMatrix) -> [f64; 81] {
    let mut out = [0.0; 81];
    for (i, slot) in out.iter_mut().enumerate() {
        *slot = m[(i / 9, i % 9)];
    }
    out
}

/// A header in `frame`; the default table frame's name is borrowed (no allocation per message).
fn header(stamp: i64, frame: &str) -> Header {
    Header {
        stamp: Time::from_nanos(stamp),
        frame_id: if frame == TABLE_FRAME {
            TABLE_FRAME.into()
        } else {
            frame.to_owned().into()
        },
    }
}

/// A `BallDetection` message in the table frame (`frames.fixed()`) or in any frame that
/// `frames` connects to it, brought into it (position, spin and their covariances).
pub fn detection_from_msg_in(
    msg: &BallDetection,
    frames: &crate::model::frames::Frames,
) -> Result<Detection, ConvertError> {
    if msg.header.frame_id == frames.fixed() {
        return Ok(detection_fields(msg));
    }
    let Some(t) = frames.to_fixed(&msg.header.frame_id) else {
        return Err(ConvertError::UnknownFrame {
            frame: msg.header.frame_id.to_string(),
            table: frames.fixed().to_owned(),
        });
    };
    let d = detection_fields(msg);
    Ok(Detection {
        position: t.point(&d.position),
        position_covariance: d.position_covariance.map(|c| t.covariance(&c)),
        spin: d.spin.map(|w| t.vector(&w)),
        spin_covariance: d.spin_covariance.map(|c| t.covariance(&c)),
        ..d
    })
}

/// A `RobotHit` message, brought into the table frame like a detection: the announced hit.
pub fn robot_hit_from_msg_in(
    msg: &RobotHit,
    frames: &crate::model::frames::Frames,
) -> Result<crate::online::estimator::RobotHit, ConvertError> {
    let (velocity, normal) = (
        from_vector(&msg.racket_velocity),
        from_vector(&msg.racket_normal),
    );
    let (velocity, normal) = if msg.header.frame_id == frames.fixed() {
        (velocity, normal)
    } else {
        let Some(t) = frames.to_fixed(&msg.header.frame_id) else {
            return Err(ConvertError::UnknownFrame {
                frame: msg.header.frame_id.to_string(),
                table: frames.fixed().to_owned(),
            });
        };
        (t.vector(&velocity), t.vector(&normal))
    };
    let length = normal.norm();
    let finite = velocity.iter().all(|v| v.is_finite()) && msg.impact_offset.is_finite();
    if !((length - 1.0).abs() <= physics::racket::NORMAL_TOLERANCE && finite) {
        return Err(ConvertError::NotUnitNormal { length });
    }
    Ok(crate::online::estimator::RobotHit {
        stamp: msg.header.stamp.to_nanos(),
        racket: RacketState {
            velocity,
            normal: normal / length,
            impact_offset: msg.impact_offset,
        },
    })
}

/// The static transforms of a `TFMessage` added to `frames`; the refused ones with why.
pub fn add_static_transforms(
    frames: &mut crate::model::frames::Frames,
    msg: &crate::ros::msgs::tf2_msgs::TFMessage,
) -> Vec<crate::model::frames::FrameError> {
    msg.transforms
        .iter()
        .filter_map(|t| {
            let (r, p) = (t.transform.rotation, t.transform.translation);
            frames
                .insert(
                    &t.header.frame_id,
                    &t.child_frame_id,
                    [r.x, r.y, r.z, r.w],
                    [p.x, p.y, p.z],
                )
                .err()
        })
        .collect()
}

fn detection_fields(msg: &BallDetection) -> Detection {
    Detection {
        stamp: msg.header.stamp.to_nanos(),
        source: Source(msg.source),
        position: from_point(&msg.position),
        position_covariance: covariance3(&msg.position_covariance),
        spin: msg.has_spin.then(|| from_vector(&msg.spin)),
        spin_covariance: covariance3(&msg.spin_covariance),
        confidence: msg.confidence,
    }
}

/// The core's detection as a `BallDetection` message.
pub fn detection_to_msg(d: &Detection) -> BallDetection {
    BallDetection {
        header: header(d.stamp, TABLE_FRAME),
        position: point(&d.position),
        position_covariance: row_major3(&d.position_covariance),
        has_spin: d.spin.is_some(),
        spin: vector(&d.spin.unwrap_or_else(Vector3::zeros)),
        spin_covariance: row_major3(&d.spin_covariance),
        source: d.source.0,
        confidence: d.confidence,
    }
}

/// The frame of an odometry message's twist: the ball, axes parallel to the table's.
pub const BALL_FRAME: &str = "ball";

/// An estimate as a `nav_msgs/Odometry` message: pose = position (orientation the identity, not
/// estimated: zero covariance), twist = velocity (linear) and spin (angular), each covariance
/// the matching blocks of the state's.
pub fn odometry_msg(e: &Estimate, frame: &str) -> crate::ros::msgs::nav_msgs::Odometry {
    use crate::ros::msgs::geometry_msgs::{PoseWithCovariance, Twist, TwistWithCovariance};
    let c = &e.covariance;
    let mut pose_covariance = [0.0; 36];
    let mut twist_covariance = [0.0; 36];
    for i in 0..3 {
        for j in 0..3 {
            pose_covariance[6 * i + j] = c[(i, j)];
        }
    }
    for i in 0..6 {
        for j in 0..6 {
            twist_covariance[6 * i + j] = c[(3 + i, 3 + j)];
        }
    }
    crate::ros::msgs::nav_msgs::Odometry {
        header: header(e.stamp, frame),
        child_frame_id: BALL_FRAME.into(),
        pose: PoseWithCovariance {
            pose: Pose {
                position: point(&e.state.position),
                orientation: Quaternion::default(),
            },
            covariance: pose_covariance,
        },
        twist: TwistWithCovariance {
            twist: Twist {
                linear: vector(&e.state.velocity),
                angular: vector(&e.state.spin),
            },
            covariance: twist_covariance,
        },
    }
}

/// An estimate as a `BallState` message.
pub fn state_msg(e: &Estimate, frame: &str) -> BallState {
    BallState {
        header: header(e.stamp, frame),
        track_id: e.track_id,
        status: e.status.code(),
        position: point(&e.state.position),
        velocity: vector(&e.state.velocity),
        spin: vector(&e.state.spin),
        covariance: row_major9(&e.covariance),
        bounces: e.bounces,
        nis: e.nis,
    }
}

/// A true state (from the simulator) as a `BallState` message: status TRACKING, zero
/// covariance, `track_id` = the shot's number (from 1).
pub fn truth_msg(stamp: i64, shot: u32, state: &physics::BallState) -> BallState {
    BallState {
        header: header(stamp, TABLE_FRAME),
        track_id: shot,
        status: TrackStatus::Tracking.code(),
        position: point(&state.position),
        velocity: vector(&state.velocity),
        spin: vector(&state.spin),
        covariance: [0.0; 81],
        bounces: 0,
        nis: 0.0,
    }
}

/// The stamp [ns], track id and state of a `BallState` message.
pub fn state_from_msg(msg: &BallState) -> (i64, u32, physics::BallState) {
    (
        msg.header.stamp.to_nanos(),
        msg.track_id,
        physics::BallState::new(
            from_point(&msg.position),
            from_vector(&msg.velocity),
            from_vector(&msg.spin),
        ),
    )
}

/// A simulated shot's true crossing of the hitting plane and bounce as an `InterceptPrediction`
/// message (`/ball/truth/intercept`): header stamp = launch, `track_id` = the shot's number;
/// `valid` false for a shot from the robot's end (the crossing is the opponent's plane's).
pub fn truth_intercept_msg(number: u32, shot: &crate::eval::sim::ShotTruth) -> InterceptPrediction {
    let crossing = &shot.intercept.before;
    InterceptPrediction {
        header: header(shot.launch_stamp, TABLE_FRAME),
        track_id: number,
        valid: !shot.from_robot,
        intercept_stamp: Time::from_nanos(shot.intercept.stamp),
        position: point(&crossing.position),
        velocity: vector(&crossing.velocity),
        spin: vector(&crossing.spin),
        bounce_valid: true,
        bounce_stamp: Time::from_nanos(shot.bounce.stamp),
        bounce_position: point(&shot.bounce.before.position),
        ..InterceptPrediction::default()
    }
}

/// The shot number and the truth the scores need (crossing stamp [ns], point and spin, bounce
/// stamp [ns]) of a `/ball/truth/intercept` message.
pub fn truth_intercept_from_msg(msg: &InterceptPrediction) -> (u32, crate::eval::ShotTruth) {
    (
        msg.track_id,
        crate::eval::ShotTruth {
            bounce_stamp: msg.bounce_stamp.to_nanos(),
            intercept_stamp: msg.intercept_stamp.to_nanos(),
            intercept_position: from_point(&msg.position),
            intercept_spin: from_vector(&msg.spin),
            toward_robot: msg.valid,
        },
    )
}

/// `stamp` [ns] plus `seconds`, as a message time: the stamp of a prediction made at `stamp`.
pub fn offset(stamp: i64, seconds: f64) -> Time {
    Time::from_nanos(stamp + seconds_to_ns(seconds))
}

/// `InterceptPrediction.reason` of why there is no interception.
pub fn reason_code(why: crate::online::intercept::NoIntercept) -> u8 {
    use crate::online::intercept::NoIntercept;
    match why {
        NoIntercept::NetHit => InterceptPrediction::REASON_NET,
        NoIntercept::MissesTable => InterceptPrediction::REASON_MISSES_TABLE,
        NoIntercept::NoBounce => InterceptPrediction::REASON_NO_BOUNCE,
        NoIntercept::TwoBounces => InterceptPrediction::REASON_TWO_BOUNCES,
        NoIntercept::NotWithinHorizon => InterceptPrediction::REASON_BEYOND_HORIZON,
    }
}

/// An interception prediction as an `InterceptPrediction` message.
pub fn intercept_msg(i: &InterceptEstimate, frame: &str) -> InterceptPrediction {
    let mut msg = InterceptPrediction {
        header: header(i.stamp, frame),
        track_id: i.track_id,
        ..InterceptPrediction::default()
    };
    match &i.intercept.crossing {
        Ok(c) => {
            msg.valid = true;
            msg.intercept_stamp = offset(i.stamp, c.time);
            msg.position = point(&c.state.position);
            msg.velocity = vector(&c.state.velocity);
            msg.spin = vector(&c.state.spin);
            msg.covariance = row_major9(&c.covariance);
            msg.time_variance = c.time_sigma * c.time_sigma;
        }
        Err(why) => msg.reason = reason_code(*why),
    }
    if let Some(b) = &i.intercept.bounce {
        msg.bounce_valid = true;
        msg.bounce_stamp = offset(i.stamp, b.time);
        msg.bounce_position = point(&b.position);
    }
    msg
}

/// A predicted trajectory (times relative to `stamp`) as a `PredictedTrajectory` message.
pub fn trajectory_msg(
    stamp: i64,
    track_id: u32,
    t: &Trajectory,
    frame: &str,
) -> PredictedTrajectory {
    PredictedTrajectory {
        header: header(stamp, frame),
        track_id,
        stamps: t.samples.iter().map(|s| offset(stamp, s.t)).collect(),
        positions: t.samples.iter().map(|s| point(&s.state.position)).collect(),
        velocities: t
            .samples
            .iter()
            .map(|s| vector(&s.state.velocity))
            .collect(),
        spins: t.samples.iter().map(|s| vector(&s.state.spin)).collect(),
    }
}

/// The ball and racket states of a `PredictRebound` request.
pub fn rebound_request(r: &PredictReboundRequest) -> (physics::BallState, RacketState) {
    (
        physics::BallState::new(
            from_point(&r.ball_position),
            from_vector(&r.ball_velocity),
            from_vector(&r.ball_spin),
        ),
        RacketState {
            velocity: from_vector(&r.racket_velocity),
            normal: from_vector(&r.racket_normal),
            impact_offset: r.impact_offset,
        },
    )
}

/// A rebound as a `PredictRebound` response (`success` true): the hit, and the landing when the
/// return lands on the opponent's half; otherwise `lands_on_table` false, the landing position
/// zero and `message` saying what the returned ball does.
pub fn rebound_response(rebound: &Rebound) -> PredictReboundResponse {
    let hit = &rebound.hit;
    let lands = rebound.flight.outcome == ReturnOutcome::Lands;
    let landing = rebound
        .flight
        .landing
        .filter(|_| lands)
        .map(|(_, state)| point(&state.position))
        .unwrap_or_default();
    PredictReboundResponse {
        success: true,
        message: if lands {
            String::new()
        } else {
            format!("the returned ball {}", rebound.flight.outcome.describe())
        },
        ball_velocity: vector(&hit.ball.velocity),
        ball_spin: vector(&hit.ball.spin),
        rebound_power_coefficient: hit.normal.rebound_power_coefficient,
        contact_time: hit.normal.contact.contact_time,
        mean_force: hit.normal.contact.mean_force,
        peak_force: hit.normal.contact.peak_force,
        reduced_mass: hit.normal.reduced_mass,
        wrist_force: hit.wrist.peak_force,
        lands_on_table: lands,
        landing_position: landing,
    }
}

/// A racket command as a `PlanReturn` response (`success` true), the impact at `impact_stamp`.
/// Landing, flight time and net clearance are those of the command's return through the real
/// table and net (zero when it has none); `landing_covariance` over (x, y, flight time), zero when
/// `None`.
pub fn plan_response(
    impact_stamp: Time,
    plan: &Plan,
    landing_covariance: &Option<Matrix3<f64>>,
) -> PlanReturnResponse {
    let hit = &plan.rebound.hit;
    let flight = &plan.rebound.flight;
    let (flight_time, landing) = flight
        .landing
        .map(|(t, state)| (t, point(&state.position)))
        .unwrap_or_default();
    PlanReturnResponse {
        success: true,
        message: String::new(),
        impact_stamp,
        impact_position: point(&hit.ball.position),
        racket_velocity: vector(&plan.racket.velocity),
        racket_normal: vector(&plan.racket.normal),
        ball_velocity: vector(&hit.ball.velocity),
        ball_spin: vector(&hit.ball.spin),
        landing_position: landing,
        flight_time,
        net_clearance: flight.net.map_or(0.0, |(_, clearance)| clearance),
        landing_error: plan.landing_error,
        landing_covariance: row_major3(landing_covariance),
        contact_time: hit.normal.contact.contact_time,
        peak_force: hit.normal.contact.peak_force,
        wrist_force: hit.wrist.peak_force,
    }
}

/// Marker ids in the `ttball` namespace.
const PATH: i32 = 0;
const BALL: i32 = 1;
const BOUNCE: i32 = 2;
const INTERCEPT: i32 = 3;
const LABEL: i32 = 4;
const TABLE: i32 = 5;
const NET: i32 = 6;

fn color(r: f32, g: f32, b: f32) -> ColorRGBA {
    ColorRGBA { r, g, b, a: 1.0 }
}

fn marker(header: &Header, id: i32, type_: i32) -> Marker {
    Marker {
        header: header.clone(),
        ns: "ttball".to_string(),
        id,
        type_,
        action: Marker::ADD,
        lifetime: Duration::default(),
        ..Marker::default()
    }
}

fn sphere(header: &Header, id: i32, at: &Vector3<f64>, diameter: f64, c: ColorRGBA) -> Marker {
    Marker {
        pose: Pose {
            position: point(at),
            orientation: Quaternion::default(),
        },
        scale: RosVector3 {
            x: diameter,
            y: diameter,
            z: diameter,
        },
        color: c,
        ..marker(header, id, Marker::SPHERE)
    }
}

fn delete(header: &Header, id: i32) -> Marker {
    Marker {
        action: Marker::DELETE,
        ..marker(header, id, Marker::SPHERE)
    }
}

/// A box of size `size` [m] centred at `centre`, axes along the table frame's.
fn cuboid(header: &Header, id: i32, centre: [f64; 3], size: [f64; 3], c: ColorRGBA) -> Marker {
    let [x, y, z] = centre;
    Marker {
        pose: Pose {
            position: Point { x, y, z },
            orientation: Quaternion::default(),
        },
        scale: RosVector3 {
            x: size[0],
            y: size[1],
            z: size[2],
        },
        color: c,
        ..marker(header, id, Marker::CUBE)
    }
}

/// Markers for RViz and Foxglove: the table (its playing surface, 3 cm thick, and the net, as
/// `table` configures them), the predicted path (green line), the ball (white), the predicted
/// bounce (orange) and interception point (red) with the time left until it.
pub fn markers(
    e: &Estimate,
    i: Option<&InterceptEstimate>,
    t: &Trajectory,
    table: &crate::config::TableParams,
    frame: &str,
) -> MarkerArray {
    let h = &header(e.stamp, frame);
    const THICKNESS: f64 = 0.03;
    let surface = cuboid(
        h,
        TABLE,
        [0.0, 0.0, -0.5 * THICKNESS],
        [table.length, table.width, THICKNESS],
        color(0.05, 0.2, 0.45),
    );
    let net_width = table.width + 2.0 * table.net_overhang;
    let net = cuboid(
        h,
        NET,
        [0.0, 0.0, 0.5 * table.net_height],
        [0.005, net_width, table.net_height],
        ColorRGBA {
            a: 0.6,
            ..color(0.9, 0.9, 0.9)
        },
    );
    let path = Marker {
        scale: RosVector3 {
            x: 0.006,
            y: 0.0,
            z: 0.0,
        },
        color: color(0.2, 0.9, 0.3),
        points: t.samples.iter().map(|s| point(&s.state.position)).collect(),
        ..marker(h, PATH, Marker::LINE_STRIP)
    };
    let mut markers = vec![
        surface,
        net,
        path,
        sphere(h, BALL, &e.state.position, 0.04, color(1.0, 1.0, 1.0)),
    ];
    let bounce = i.and_then(|i| i.intercept.bounce);
    markers.push(match bounce {
        Some(b) => sphere(h, BOUNCE, &b.position, 0.03, color(1.0, 0.6, 0.1)),
        None => delete(h, BOUNCE),
    });
    match i.and_then(|i| i.intercept.crossing.ok()) {
        Some(c) => {
            markers.push(sphere(
                h,
                INTERCEPT,
                &c.state.position,
                0.05,
                color(0.95, 0.1, 0.1),
            ));
            let mut above = c.state.position;
            above.z += 0.08;
            markers.push(Marker {
                pose: Pose {
                    position: point(&above),
                    orientation: Quaternion::default(),
                },
                scale: RosVector3 {
                    x: 0.0,
                    y: 0.0,
                    z: 0.05,
                },
                color: color(1.0, 1.0, 1.0),
                text: format!("{:.0} ms", c.time * 1e3),
                ..marker(h, LABEL, Marker::TEXT_VIEW_FACING)
            });
        }
        None => {
            markers.push(delete(h, INTERCEPT));
            markers.push(delete(h, LABEL));
        }
    }
    MarkerArray { markers }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn detections_round_trip_and_zero_covariance_means_default() {
        let d = Detection {
            stamp: 1_700_000_000_123_456_789,
            source: Source::HIGHSPEED_900FPS,
            position: Vector3::new(-0.5, 0.1, 0.2),
            position_covariance: None,
            spin: Some(Vector3::new(1.0, -150.0, 3.0)),
            spin_covariance: Some(Matrix3::from_diagonal_element(144.0)),
            confidence: 0.9,
        };
        let msg = detection_to_msg(&d);
        assert_eq!(msg.position_covariance, [0.0; 9]);
        assert_eq!(msg.spin_covariance[4], 144.0);
        let table = crate::model::frames::Frames::new(TABLE_FRAME);
        assert_eq!(detection_from_msg_in(&msg, &table), Ok(d));
        let mut other = msg;
        other.header.frame_id = "camera".into();
        assert_eq!(
            detection_from_msg_in(&other, &table),
            Err(ConvertError::UnknownFrame {
                frame: "camera".into(),
                table: "table".into()
            })
        );
    }

    #[test]
    fn every_reason_has_its_own_code() {
        use crate::online::intercept::NoIntercept;
        let all = [
            NoIntercept::NetHit,
            NoIntercept::MissesTable,
            NoIntercept::NoBounce,
            NoIntercept::TwoBounces,
            NoIntercept::NotWithinHorizon,
        ];
        let codes: Vec<u8> = all.iter().map(|w| reason_code(*w)).collect();
        assert_eq!(codes, [1, 2, 3, 4, 5]);
        assert_eq!(
            InterceptPrediction::default().reason,
            InterceptPrediction::REASON_VALID
        );
    }
}

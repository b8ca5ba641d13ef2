//! The MPI launcher flights: parsing their CSV files and the rigid transform into ttball's
//! `table` frame, worked out from the data.
//!
//! # The data
//!
//! "mn5008" trajectories of one three-wheeled launcher, recorded by the Intelligent Soft Robots
//! group (MPI for Intelligent Systems) at about 180 Hz: 15 backspin, 10 no-spin and 15 topspin
//! flights (wheel settings top-left / top-right / bottom: 350/350/2800, 1200/1200/1200,
//! 1800/1800/400). Spin is not measured; only its kind is known. Columns
//! `trajectory,t_s,x_m,y_m,z_m`, time from 0 in each trajectory. BSD 3-Clause License,
//! Copyright (c) 2023, Intelligent Soft Robots; the licence text goes with every copy of the
//! files.
//!
//! # Their frame and ours
//!
//! The launcher's frame has x along the table away from the launcher, z the absolute height (up)
//! and y lateral. ttball's `table` frame has its origin at the centre of the playing surface, x
//! toward the opponent (the launcher is the opponent: incoming balls move toward -x) and z up from
//! the surface. Both are right-handed with z up, so the transform is a rotation by 180 degrees
//! about z and an offset:
//!
//! ```text
//! x_t = c_x - x        y_t = c_y - y        z_t = z - z_surface
//! ```
//!
//! What the data say about the three constants ([`estimate_transform`] computes them; the numbers
//! are for the 40 flights, and `tests/offline/real_flights.rs` checks them):
//! - **z_surface.** At contact the ball centre is one radius above the surface. The contact
//!   height of each bounce is where ballistic fits of the frames before and after it meet
//!   ([`detect_bounce`]). 30 flights show a bounce (8 backspin and 2 topspin recordings end
//!   before it); the median contact height is 0.7596 m with a robust spread of 1 mm (no-spin and
//!   topspin contacts lie within 1.5 mm of it; backspin ones, three of them with 40 to 55 ms of
//!   missed frames at the bounce, up to 9 mm above). So z_surface = 0.7596 - 0.020 = 0.7396 m.
//!   The lowest single sample of all, 0.7602 m, is a frame next to a contact, as it must be. (The
//!   surface is 2 cm below the ITTF height of 0.76 m in their z: their floor or table differs;
//!   only the difference matters here.)
//! - **c_x.** Every bounce must be on the robot's half, x_t in (-1.37, 0): the bounces lie at
//!   x = 1.923 to 2.575 m, which admits c_x in (2.575 - 1.37, 1.923) = (1.205, 1.923). The
//!   tracks start at x = 0 and never before (lowest x of all: 0.001 m): 24 of the 40 flights
//!   have their first sample within one frame's travel of x = 0, spread evenly over it, and the
//!   others start later, after missed frames. A track that began at the launcher's mouth would
//!   start at the same x every time; an even spread over one frame is what cutting the tracks at
//!   a fixed plane x = 0 gives, and the natural plane to cut at is the launcher's end line of the
//!   table. So c_x = 1.37 m (half the table's length), inside the admissible range: the launch
//!   is over the far end line 0.32 m above the surface, the ball clears the net by more than
//!   0.15 m, the bounces fall at x_t = -0.553 to -1.205 m (at least 0.16 m inside the robot's end
//!   line), and the longest tracks end at x_t = -1.46 m, just behind it. Any c_x in the
//!   admissible range moves only the net and the table's ends relative to the flights, never the
//!   flights themselves.
//! - **c_y.** The launcher does not move between flights: every flight starts at y = -0.003 to
//!   +0.009 m (median 0.0046 m). With the launcher on the table's centre line, c_y is that median;
//!   the bounces then scatter over y_t = -0.06 to +0.09 m, a few centimetres either side of the
//!   centre line, far from the sidelines at +-0.76 m. The rotation assumes the launcher's frame is
//!   right-handed like ttball's; a mirrored frame would only flip the sign of y_t (no flight has
//!   side spin set).

use nalgebra::Vector3;

use super::noise::{NoiseEstimate, estimate_noise};
use crate::model::detection::{Detection, Source, seconds_to_ns};
use crate::offline::ballistic::{Sample, detect_bounce};

/// The kind of spin the launcher was set to, as a file's name states it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SpinKind {
    /// Wheels 350/350/2800 (bottom wheel fastest): backspin.
    Backspin,
    /// Wheels 1200/1200/1200: no spin.
    NoSpin,
    /// Wheels 1800/1800/400 (top wheels fastest): topspin.
    Topspin,
    /// Flights in a file whose name states no spin (other recordings in the same format).
    NotStated,
}

impl SpinKind {
    /// The launcher's settings, in the order of the data set's files.
    pub const ALL: [Self; 3] = [Self::Backspin, Self::NoSpin, Self::Topspin];

    /// Every kind a flight can have, in the order of the tables.
    pub const GROUPS: [Self; 4] = [Self::Backspin, Self::NoSpin, Self::Topspin, Self::NotStated];

    /// A short name for tables.
    pub fn name(self) -> &'static str {
        match self {
            Self::Backspin => "backspin",
            Self::NoSpin => "no spin",
            Self::Topspin => "topspin",
            Self::NotStated => "not stated",
        }
    }

    /// The data set's file name for a launcher setting, e.g. `mn5008_no_spin.csv`.
    pub fn file_name(self) -> Option<&'static str> {
        match self {
            Self::Backspin => Some("mn5008_backspin.csv"),
            Self::NoSpin => Some("mn5008_no_spin.csv"),
            Self::Topspin => Some("mn5008_topspin.csv"),
            Self::NotStated => None,
        }
    }

    /// The kind a file's name states (`backspin`, `no_spin` or `topspin` in it, in any case,
    /// as in `.../mn5008_topspin.csv`), else [`Self::NotStated`].
    pub fn of_file_name(name: &str) -> Self {
        let name = name.to_ascii_lowercase().replace('-', "_");
        [
            (Self::Backspin, "backspin"),
            (Self::NoSpin, "no_spin"),
            (Self::NoSpin, "nospin"),
            (Self::Topspin, "topspin"),
        ]
        .into_iter()
        .find(|(_, word)| name.contains(word))
        .map_or(Self::NotStated, |(kind, _)| kind)
    }
}

/// A flight in the launcher's frame, as recorded.
#[derive(Debug, Clone, PartialEq)]
pub struct RawFlight {
    /// The `trajectory` number in its file [-].
    pub id: u32,
    /// The spin its file's name states.
    pub spin_kind: SpinKind,
    /// (time since the first sample [s], ball centre in the launcher's frame [m]), in time order.
    pub samples: Vec<Sample>,
}

/// A flight in ttball's `table` frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Flight {
    /// The `trajectory` number in its file [-].
    pub id: u32,
    /// The spin its file's name states.
    pub spin_kind: SpinKind,
    /// (time since the first sample [s], ball centre in the `table` frame [m]), in time order.
    pub samples: Vec<Sample>,
}

/// Why a CSV file could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MpiError {
    /// The text has no header line.
    #[error("empty file: expected the header `trajectory,t_s,x_m,y_m,z_m`")]
    Empty,
    /// The header is not the expected one.
    #[error("line 1: expected the header `trajectory,t_s,x_m,y_m,z_m`, found `{found}`")]
    BadHeader {
        /// The header found.
        found: String,
    },
    /// A data line could not be read.
    #[error("line {line}: {reason}")]
    BadLine {
        /// Line number, from 1 [-].
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// Times within a trajectory do not increase.
    #[error("line {line}: trajectory {trajectory}: time {t} s does not increase")]
    TimeNotIncreasing {
        /// Line number, from 1 [-].
        line: usize,
        /// The trajectory.
        trajectory: u32,
        /// The time [s].
        t: f64,
    },
    /// No flight shows a bounce, so the surface height cannot be found.
    #[error("no flight shows a table bounce: the surface height cannot be estimated")]
    NoBounce,
}

const HEADER: [&str; 5] = ["trajectory", "t_s", "x_m", "y_m", "z_m"];

/// Parses one CSV file of the data set (its text) into flights in the launcher's frame, in the
/// order of their first line. Blank lines are skipped; every value must be finite.
pub fn parse_mpi_csv(text: &str, spin_kind: SpinKind) -> Result<Vec<RawFlight>, MpiError> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let (_, header) = lines.next().ok_or(MpiError::Empty)?;
    if !header.split(',').map(str::trim).eq(HEADER) {
        return Err(MpiError::BadHeader {
            found: header.to_owned(),
        });
    }
    let mut flights: Vec<RawFlight> = Vec::new();
    for (line, text) in lines {
        let bad = |reason: String| MpiError::BadLine { line, reason };
        let fields: Vec<&str> = text.split(',').map(str::trim).collect();
        if fields.len() != HEADER.len() {
            return Err(bad(format!(
                "expected {} fields, found {}",
                HEADER.len(),
                fields.len()
            )));
        }
        let id: u32 = fields[0]
            .parse()
            .map_err(|_| bad(format!("trajectory `{}` is not a number", fields[0])))?;
        let mut values = [0.0; 4];
        for (value, (field, name)) in values.iter_mut().zip(fields[1..].iter().zip(&HEADER[1..])) {
            *value = field
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| bad(format!("{name} `{field}` is not a finite number")))?;
        }
        let [t, x, y, z] = values;
        let index = match flights.iter().position(|f| f.id == id) {
            Some(i) => i,
            None => {
                flights.push(RawFlight {
                    id,
                    spin_kind,
                    samples: Vec::new(),
                });
                flights.len() - 1
            }
        };
        let flight = &mut flights[index];
        if flight.samples.last().is_some_and(|(last, _)| t <= *last) {
            return Err(MpiError::TimeNotIncreasing {
                line,
                trajectory: id,
                t,
            });
        }
        flight.samples.push((t, Vector3::new(x, y, z)));
    }
    Ok(flights)
}

/// The rigid transform from the launcher's frame into `table` (see the module doc):
/// `x_t = c_x - x`, `y_t = c_y - y`, `z_t = z - z_surface`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameTransform {
    /// The launcher frame's x of the table's centre (the net) [m].
    pub c_x: f64,
    /// The launcher frame's y of the table's centre line [m].
    pub c_y: f64,
    /// Height of the playing surface in the launcher frame's z [m].
    pub z_surface: f64,
}

impl FrameTransform {
    /// A launcher-frame point in the `table` frame [m].
    pub fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        Vector3::new(self.c_x - p.x, self.c_y - p.y, p.z - self.z_surface)
    }
}

impl RawFlight {
    /// The flight in the `table` frame.
    pub fn to_table(&self, transform: &FrameTransform) -> Flight {
        self.mapped(|p| transform.apply(p))
    }

    /// The flight, recorded in the `table` frame already, coming toward the robot: one that
    /// moves toward +x (from its first sample to its last) is turned half a turn about z, as the
    /// robot at the other end would see it.
    pub fn incoming(&self) -> Flight {
        let away = match (self.samples.first(), self.samples.last()) {
            (Some((_, first)), Some((_, last))) => last.x > first.x,
            _ => false,
        };
        self.mapped(|p| {
            if away {
                Vector3::new(-p.x, -p.y, p.z)
            } else {
                *p
            }
        })
    }

    fn mapped(&self, map: impl Fn(&Vector3<f64>) -> Vector3<f64>) -> Flight {
        Flight {
            id: self.id,
            spin_kind: self.spin_kind,
            samples: self.samples.iter().map(|(t, p)| (*t, map(p))).collect(),
        }
    }
}

/// Recorded flights ready for the estimator: in the `table` frame (by the transform worked out
/// from launcher flights, or as recorded), with their measured noise.
#[derive(Debug, Clone, PartialEq)]
pub struct LauncherFlights {
    /// The flights as recorded.
    pub raw: Vec<RawFlight>,
    /// The transform into the `table` frame and its evidence (none for flights recorded in it).
    pub estimate: Option<TransformEstimate>,
    /// The flights in the `table` frame.
    pub flights: Vec<Flight>,
    /// Their position noise.
    pub noise: NoiseEstimate,
}

impl LauncherFlights {
    /// Works out the transform (see [`estimate_transform`]) and the noise
    /// ([`estimate_noise`]) of recorded flights, for a ball of `ball_radius` [m] on a table of
    /// `table_length` [m] under `gravity` [m/s^2].
    pub fn new(
        raw: Vec<RawFlight>,
        ball_radius: f64,
        table_length: f64,
        gravity: f64,
    ) -> Result<Self, MpiError> {
        let estimate = estimate_transform(&raw, ball_radius, table_length, gravity)?;
        let flights = raw
            .iter()
            .map(|f| f.to_table(&estimate.transform))
            .collect();
        Ok(Self::with_flights(raw, Some(estimate), flights, gravity))
    }

    /// Flights recorded in the `table` frame, each coming toward the robot
    /// ([`RawFlight::incoming`]), and their noise under `gravity` [m/s^2].
    pub fn in_table_frame(raw: Vec<RawFlight>, gravity: f64) -> Self {
        let flights = raw.iter().map(RawFlight::incoming).collect();
        Self::with_flights(raw, None, flights, gravity)
    }

    fn with_flights(
        raw: Vec<RawFlight>,
        estimate: Option<TransformEstimate>,
        flights: Vec<Flight>,
        gravity: f64,
    ) -> Self {
        let noise = estimate_noise(
            flights.iter().map(|f: &Flight| f.samples.as_slice()),
            gravity,
        );
        Self {
            raw,
            estimate,
            flights,
            noise,
        }
    }

    /// The `sources.*.position_sigma` these detections need [m]: the noise's recommended
    /// sigma ([`NoiseEstimate::recommended_sigma`]) rounded up to 0.1 mm.
    pub fn position_sigma(&self) -> f64 {
        (self.noise.recommended_sigma() * 1e4).ceil() / 1e4
    }
}

/// The transform worked out from the data, with the evidence for it (launcher frame).
#[derive(Debug, Clone, PartialEq)]
pub struct TransformEstimate {
    /// The transform.
    pub transform: FrameTransform,
    /// Ball-centre height at contact of every recorded bounce [m].
    pub contact_heights: Vec<f64>,
    /// Robust spread of those heights: 1.4826 times their median absolute deviation [m].
    pub contact_height_sigma: f64,
    /// Lowest and highest x of the recorded bounces [m].
    pub bounce_x: (f64, f64),
    /// The range of c_x that puts every recorded bounce on the robot's half [m].
    pub c_x_admissible: (f64, f64),
    /// Lowest and highest y of the first samples [m].
    pub launch_y: (f64, f64),
    /// Flights whose first sample lies within one frame's travel of x = 0 [-].
    pub starts_at_zero: usize,
    /// Lowest x of any sample and highest x of any sample [m].
    pub x_extent: (f64, f64),
    /// Flights that show a bounce, of all flights [-].
    pub flights_with_bounce: (usize, usize),
}

fn median(values: &mut [f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    })
}

/// Works out the transform from raw flights (see the module doc): z_surface from the median
/// contact height minus `ball_radius` [m], c_y from the median launch y, and c_x = half of
/// `table_length` [m] (the launcher's end line), with the range the bounces admit. `gravity`
/// [m/s^2] is used by the bounce fits.
pub fn estimate_transform(
    flights: &[RawFlight],
    ball_radius: f64,
    table_length: f64,
    gravity: f64,
) -> Result<TransformEstimate, MpiError> {
    let bounces: Vec<_> = flights
        .iter()
        .filter_map(|f| detect_bounce(&f.samples, gravity))
        .collect();
    let mut heights: Vec<f64> = bounces.iter().map(|b| b.position.z).collect();
    let contact = median(&mut heights.clone()).ok_or(MpiError::NoBounce)?;
    let mut deviations: Vec<f64> = heights.iter().map(|h| (h - contact).abs()).collect();
    let contact_height_sigma = 1.4826 * median(&mut deviations).unwrap_or(0.0);
    heights.sort_by(f64::total_cmp);

    let fold = |init: (f64, f64), v: f64| (init.0.min(v), init.1.max(v));
    let empty = (f64::INFINITY, f64::NEG_INFINITY);
    let bounce_x = bounces.iter().map(|b| b.position.x).fold(empty, fold);
    let half = 0.5 * table_length;
    let mut launch: Vec<f64> = flights
        .iter()
        .filter_map(|f| f.samples.first().map(|s| s.1.y))
        .collect();
    let launch_y = launch.iter().copied().fold(empty, fold);
    let c_y = median(&mut launch).unwrap_or(0.0);
    let starts_at_zero = flights
        .iter()
        .filter(|f| match f.samples.as_slice() {
            [(t0, p0), (t1, p1), ..] => {
                let step = (p1.x - p0.x) / (t1 - t0) * median_interval(&f.samples);
                p0.x >= 0.0 && p0.x < step
            }
            _ => false,
        })
        .count();
    let x_extent = flights
        .iter()
        .flat_map(|f| f.samples.iter().map(|s| s.1.x))
        .fold(empty, fold);
    Ok(TransformEstimate {
        transform: FrameTransform {
            c_x: half,
            c_y,
            z_surface: contact - ball_radius,
        },
        contact_heights: heights,
        contact_height_sigma,
        bounce_x,
        c_x_admissible: (bounce_x.1 - half, bounce_x.0),
        launch_y,
        starts_at_zero,
        x_extent,
        flights_with_bounce: (bounces.len(), flights.len()),
    })
}

/// Median time between samples [s].
fn median_interval(samples: &[Sample]) -> f64 {
    let mut dts: Vec<f64> = samples.windows(2).map(|w| w[1].0 - w[0].0).collect();
    median(&mut dts).unwrap_or(0.0)
}

/// The flight as detections: stamp `epoch_ns` plus the sample time (rounded to the nanosecond),
/// the given source, no covariance (the estimator uses the source's configured noise), no spin,
/// confidence 1.
///
/// The recordings come from a camera system that sees the whole table and measures position
/// only, at about 180 Hz: [`Source::WIDE_150FPS`] describes it (set its
/// `sources.wide_150fps.position_sigma` to the noise of these flights, see
/// [`estimate_noise`]).
pub fn flight_detections(flight: &Flight, epoch_ns: i64, source: Source) -> Vec<Detection> {
    flight
        .samples
        .iter()
        .map(|(t, p)| Detection {
            stamp: epoch_ns + seconds_to_ns(*t),
            source,
            position: *p,
            position_covariance: None,
            spin: None,
            spin_covariance: None,
            confidence: 1.0,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_name_states_its_spin_or_none() {
        for kind in SpinKind::ALL {
            assert_eq!(SpinKind::of_file_name(kind.file_name().unwrap()), kind);
        }
        assert_eq!(SpinKind::of_file_name("Lab-No-Spin.csv"), SpinKind::NoSpin);
        assert_eq!(
            SpinKind::of_file_name("session_TOPSPIN_2.csv"),
            SpinKind::Topspin
        );
        assert_eq!(
            SpinKind::of_file_name("human_play.csv"),
            SpinKind::NotStated
        );
        assert_eq!(SpinKind::NotStated.file_name(), None);
    }

    #[test]
    fn parses_and_groups_by_trajectory() {
        let text = "trajectory,t_s,x_m,y_m,z_m\r\n0,0.0,0.1,0.2,1.0\n0,0.005,0.2,0.2,1.1\n\n\
                    1,0.0,0.0,0.0,1.0\n";
        let flights = parse_mpi_csv(text, SpinKind::Topspin).unwrap();
        assert_eq!(flights.len(), 2);
        assert_eq!(flights[0].samples.len(), 2);
        assert_eq!(flights[1].id, 1);
        assert_eq!(flights[1].spin_kind, SpinKind::Topspin);
    }

    #[test]
    fn says_what_is_wrong() {
        assert_eq!(parse_mpi_csv("", SpinKind::NoSpin), Err(MpiError::Empty));
        assert!(matches!(
            parse_mpi_csv("t,x,y,z\n", SpinKind::NoSpin),
            Err(MpiError::BadHeader { .. })
        ));
        let bad = "trajectory,t_s,x_m,y_m,z_m\n0,0.0,0.1,NaN,1.0\n";
        assert!(matches!(
            parse_mpi_csv(bad, SpinKind::NoSpin),
            Err(MpiError::BadLine { line: 2, .. })
        ));
        let back = "trajectory,t_s,x_m,y_m,z_m\n0,0.1,0,0,1\n0,0.1,0,0,1\n";
        assert!(matches!(
            parse_mpi_csv(back, SpinKind::NoSpin),
            Err(MpiError::TimeNotIncreasing { line: 3, .. })
        ));
    }

    #[test]
    fn the_transform_turns_the_launcher_frame_around() {
        let t = FrameTransform {
            c_x: 1.37,
            c_y: 0.005,
            z_surface: 0.74,
        };
        let p = t.apply(&Vector3::new(2.5, 0.025, 0.76));
        assert!((p - Vector3::new(-1.13, -0.02, 0.02)).norm() < 1e-12);
        let d = flight_detections(
            &Flight {
                id: 3,
                spin_kind: SpinKind::NoSpin,
                samples: vec![(0.0056, p)],
            },
            1_000,
            Source::WIDE_150FPS,
        );
        assert_eq!(d[0].stamp, 5_601_000);
        assert_eq!(d[0].position, p);
    }
}

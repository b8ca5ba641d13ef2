//! Static rigid transforms between coordinate frames, as tf2 keeps them from `/tf_static`
//! (REP 105 conventions: a transform with parent `header.frame_id` and `child_frame_id` is the
//! pose of the child frame in the parent, so a point maps as p_parent = R p_child + t), and
//! detections brought from their camera's frame into the estimator's `table` frame: position
//! p' = R p + t with covariance R Σ Rᵀ, spin (an axial vector, unchanged by a translation)
//! w' = R w with covariance R Σ_w Rᵀ. Pure: no I/O; the node feeds it `/tf_static`.

use nalgebra::{Matrix3, UnitQuaternion, Vector3};

/// A rigid transform: rotation, then translation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    /// Rotation from the child frame's axes to the parent's.
    pub rotation: UnitQuaternion<f64>,
    /// The child frame's origin in the parent frame [m].
    pub translation: Vector3<f64>,
}

impl Transform {
    /// The identity.
    pub fn identity() -> Self {
        Self {
            rotation: UnitQuaternion::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// `self`, then `outer`: maps a point of `self`'s child frame into `outer`'s parent frame.
    pub fn then(&self, outer: &Transform) -> Transform {
        Transform {
            rotation: outer.rotation * self.rotation,
            translation: outer.rotation * self.translation + outer.translation,
        }
    }

    /// The inverse transform (parent to child).
    pub fn inverse(&self) -> Transform {
        let rotation = self.rotation.inverse();
        Transform {
            rotation,
            translation: -(rotation * self.translation),
        }
    }

    /// A point of the child frame in the parent frame.
    pub fn point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * p + self.translation
    }

    /// A free vector (velocity, angular velocity) of the child frame in the parent frame.
    pub fn vector(&self, v: &Vector3<f64>) -> Vector3<f64> {
        self.rotation * v
    }

    /// A covariance of a point or vector of the child frame, in the parent frame: R Σ Rᵀ.
    pub fn covariance(&self, c: &Matrix3<f64>) -> Matrix3<f64> {
        let r = self.rotation.to_rotation_matrix();
        r.matrix() * c * r.matrix().transpose()
    }
}

/// Why a static transform is refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FrameError {
    /// Its rotation is not a rotation (a zero or non-finite quaternion) or its translation is
    /// not finite.
    #[error(
        "the transform {parent} -> {child} is not a rigid transform (non-finite values or a zero quaternion)"
    )]
    NotRigid {
        /// Parent frame.
        parent: String,
        /// Child frame.
        child: String,
    },
    /// A frame names itself as its parent, or a frame name is empty.
    #[error("the transform {parent} -> {child} does not link two named frames")]
    BadNames {
        /// Parent frame.
        parent: String,
        /// Child frame.
        child: String,
    },
}

/// The static transforms received, and every frame they connect to the fixed frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Frames {
    fixed: String,
    /// Each child frame with its parent and its pose there (a child has one parent, as in tf2).
    edges: Vec<(String, String, Transform)>,
    /// Every frame connected to the fixed one, with the transform into it (recomputed on
    /// each change, so that a lookup allocates nothing).
    to_fixed: Vec<(String, Transform)>,
}

impl Frames {
    /// No transforms yet; `fixed` is the frame everything is brought into.
    pub fn new(fixed: &str) -> Self {
        Self {
            fixed: fixed.to_owned(),
            edges: Vec::new(),
            to_fixed: Vec::new(),
        }
    }

    /// The fixed frame's name.
    pub fn fixed(&self) -> &str {
        &self.fixed
    }

    /// Adds (or replaces, for the same child) the static transform `parent` -> `child`, with
    /// the rotation as a quaternion (x, y, z, w; normalised here) and the translation [m].
    pub fn insert(
        &mut self,
        parent: &str,
        child: &str,
        quaternion: [f64; 4],
        translation: [f64; 3],
    ) -> Result<(), FrameError> {
        let names = || (parent.to_owned(), child.to_owned());
        let parent = parent.trim_start_matches('/');
        let child = child.trim_start_matches('/');
        if parent.is_empty() || child.is_empty() || parent == child {
            let (parent, child) = names();
            return Err(FrameError::BadNames { parent, child });
        }
        let [x, y, z, w] = quaternion;
        let q = nalgebra::Quaternion::new(w, x, y, z);
        let finite = quaternion.iter().chain(&translation).all(|v| v.is_finite());
        if !finite || q.norm() < 1e-9 {
            let (parent, child) = names();
            return Err(FrameError::NotRigid { parent, child });
        }
        let transform = Transform {
            rotation: UnitQuaternion::from_quaternion(q),
            translation: Vector3::from(translation),
        };
        self.edges.retain(|(_, c, _)| c != child);
        self.edges
            .push((parent.to_owned(), child.to_owned(), transform));
        self.connect();
        Ok(())
    }

    /// The transform from `frame` into the fixed frame, if the transforms connect them.
    pub fn to_fixed(&self, frame: &str) -> Option<Transform> {
        let frame = frame.trim_start_matches('/');
        if frame == self.fixed {
            return Some(Transform::identity());
        }
        self.to_fixed
            .iter()
            .find(|(name, _)| name == frame)
            .map(|(_, t)| *t)
    }

    /// Every frame connected to the fixed one (walking the edges either way).
    fn connect(&mut self) {
        let mut reached: Vec<(String, Transform)> =
            vec![(self.fixed.clone(), Transform::identity())];
        let mut next = 0;
        while next < reached.len() {
            let (frame, into_fixed) = reached[next].clone();
            next += 1;
            for (parent, child, t) in &self.edges {
                // A child of `frame`: child -> frame -> fixed.
                let step = if *parent == frame && !reached.iter().any(|(f, _)| f == child) {
                    Some((child.clone(), t.then(&into_fixed)))
                } else if *child == frame && !reached.iter().any(|(f, _)| f == parent) {
                    Some((parent.clone(), t.inverse().then(&into_fixed)))
                } else {
                    None
                };
                reached.extend(step);
            }
        }
        reached.remove(0);
        self.to_fixed = reached;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// A quarter turn about z.
    fn quarter_turn() -> [f64; 4] {
        let h = std::f64::consts::FRAC_1_SQRT_2;
        [0.0, 0.0, h, h]
    }

    #[test]
    fn points_vectors_and_covariances_follow_the_chain() {
        let mut frames = Frames::new("table");
        // world -> table: the table 1 m along world x; world -> camera_link: 2 m up, turned.
        frames
            .insert("world", "table", [0.0, 0.0, 0.0, 1.0], [1.0, 0.0, 0.0])
            .unwrap();
        frames
            .insert("/world", "camera_link", quarter_turn(), [0.0, 0.0, 2.0])
            .unwrap();
        assert!(frames.to_fixed("elsewhere").is_none());
        assert_eq!(frames.to_fixed("table"), Some(Transform::identity()));
        let t = frames.to_fixed("camera_link").unwrap();
        // The camera's x axis is world y; its origin is 2 m above world's origin.
        assert_relative_eq!(
            t.point(&Vector3::new(1.0, 0.0, 0.0)),
            Vector3::new(-1.0, 1.0, 2.0),
            epsilon = 1e-12
        );
        assert_relative_eq!(
            t.vector(&Vector3::new(0.0, 100.0, 0.0)),
            Vector3::new(-100.0, 0.0, 0.0),
            epsilon = 1e-12
        );
        let c = Matrix3::from_diagonal(&Vector3::new(4.0, 1.0, 9.0));
        assert_relative_eq!(
            t.covariance(&c),
            Matrix3::from_diagonal(&Vector3::new(1.0, 4.0, 9.0)),
            epsilon = 1e-12
        );
        // Round trip through world.
        let w = frames.to_fixed("world").unwrap();
        assert_relative_eq!(
            w.point(&Vector3::new(1.0, 0.0, 0.0)),
            Vector3::zeros(),
            epsilon = 1e-12
        );
        // A replaced transform replaces.
        frames
            .insert("world", "table", [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
            .unwrap();
        let w = frames.to_fixed("world").unwrap();
        assert_relative_eq!(
            w.point(&Vector3::new(1.0, 0.0, 0.0)),
            Vector3::new(1.0, 0.0, 0.0),
            epsilon = 1e-12
        );
    }

    #[test]
    fn bad_transforms_are_refused() {
        let mut frames = Frames::new("table");
        assert!(
            frames
                .insert("a", "a", [0.0, 0.0, 0.0, 1.0], [0.0; 3])
                .is_err()
        );
        assert!(
            frames
                .insert("", "b", [0.0, 0.0, 0.0, 1.0], [0.0; 3])
                .is_err()
        );
        assert!(frames.insert("a", "b", [0.0; 4], [0.0; 3]).is_err());
        assert!(
            frames
                .insert("a", "b", [0.0, 0.0, 0.0, 1.0], [f64::NAN, 0.0, 0.0])
                .is_err()
        );
        // An unnormalised quaternion is normalised.
        frames
            .insert("table", "b", [0.0, 0.0, 0.0, 2.0], [0.0; 3])
            .unwrap();
        assert_eq!(
            frames.to_fixed("b").unwrap().rotation,
            UnitQuaternion::identity()
        );
    }
}

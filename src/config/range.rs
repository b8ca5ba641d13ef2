//! A range of allowed values that both checks a value and says in words what it allows, so a
//! configuration rule is written once: [`Range::contains`] for the check, its `Display` for the
//! error message and the node's parameter descriptors (`"greater than 0 and at most 1
//! (metres)"`).

use std::fmt;

/// One end of a [`Range`].
#[derive(Debug, Clone, Copy, PartialEq)]
enum Bound {
    /// No limit on this side.
    Open,
    /// The limit itself is allowed.
    Inclusive(f64),
    /// The limit itself is not allowed.
    Exclusive(f64),
}

/// The finite numbers a configuration value may take, with what a user needs to read beside
/// them: a note on the lower limit (`"no air"`) and one on the whole (`"metres"`). NaN and
/// infinity are never inside.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Range {
    low: Bound,
    high: Bound,
    low_note: Option<&'static str>,
    note: Option<&'static str>,
    name: Option<&'static str>,
}

impl Range {
    /// Every finite number.
    pub const fn any() -> Self {
        Self {
            low: Bound::Open,
            high: Bound::Open,
            low_note: None,
            note: None,
            name: None,
        }
    }

    /// Greater than `low`.
    pub const fn greater_than(low: f64) -> Self {
        Self {
            low: Bound::Exclusive(low),
            ..Self::any()
        }
    }

    /// `low` or greater.
    pub const fn at_least(low: f64) -> Self {
        Self {
            low: Bound::Inclusive(low),
            ..Self::any()
        }
    }

    /// From `low` to `high`, both included.
    pub const fn between(low: f64, high: f64) -> Self {
        Self {
            low: Bound::Inclusive(low),
            high: Bound::Inclusive(high),
            ..Self::any()
        }
    }

    /// This range with `high` included as its upper limit.
    pub const fn at_most(self, high: f64) -> Self {
        Self {
            high: Bound::Inclusive(high),
            ..self
        }
    }

    /// This range with `high` excluded as its upper limit.
    pub const fn less_than(self, high: f64) -> Self {
        Self {
            high: Bound::Exclusive(high),
            ..self
        }
    }

    /// This range with a note on what its lower limit means (`between 0 (no air) and 10`).
    pub const fn low_meaning(self, note: &'static str) -> Self {
        Self {
            low_note: Some(note),
            ..self
        }
    }

    /// This range with a note after it: the unit, a typical value, why the limit is there.
    pub const fn note(self, note: &'static str) -> Self {
        Self {
            note: Some(note),
            ..self
        }
    }

    /// This range described by `name` instead of its limits (`"a non-zero quaternion"`).
    pub const fn named(self, name: &'static str) -> Self {
        Self {
            name: Some(name),
            ..self
        }
    }

    /// Both limits, when both are included: the range as ROS 2's `FloatingPointRange` can say
    /// it (a parameter descriptor's interval is closed).
    pub fn closed(&self) -> Option<(f64, f64)> {
        match (self.low, self.high) {
            (Bound::Inclusive(low), Bound::Inclusive(high)) => Some((low, high)),
            _ => None,
        }
    }

    /// Whether `value` is a finite number inside the range.
    pub fn contains(&self, value: f64) -> bool {
        let above = match self.low {
            Bound::Open => true,
            Bound::Inclusive(low) => value >= low,
            Bound::Exclusive(low) => value > low,
        };
        let below = match self.high {
            Bound::Open => true,
            Bound::Inclusive(high) => value <= high,
            Bound::Exclusive(high) => value < high,
        };
        value.is_finite() && above && below
    }
}

impl fmt::Display for Range {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(name) = self.name {
            return f.write_str(name);
        }
        let low_note = self.low_note.map(|n| format!(" ({n})")).unwrap_or_default();
        match (self.low, self.high) {
            (Bound::Open, Bound::Open) => f.write_str("a finite number")?,
            (Bound::Exclusive(a), Bound::Open) => write!(f, "greater than {a}{low_note}")?,
            (Bound::Inclusive(a), Bound::Open) => write!(f, "{a}{low_note} or greater")?,
            (Bound::Open, Bound::Inclusive(b)) => write!(f, "at most {b}")?,
            (Bound::Open, Bound::Exclusive(b)) => write!(f, "less than {b}")?,
            (Bound::Exclusive(a), Bound::Inclusive(b)) => {
                write!(f, "greater than {a}{low_note} and at most {b}")?;
            }
            (Bound::Exclusive(a), Bound::Exclusive(b)) => {
                write!(f, "greater than {a}{low_note} and less than {b}")?;
            }
            (Bound::Inclusive(a), Bound::Inclusive(b)) => {
                write!(f, "between {a}{low_note} and {b}")?;
            }
            (Bound::Inclusive(a), Bound::Exclusive(b)) => {
                write!(f, "at least {a}{low_note} and less than {b}")?;
            }
        }
        match self.note {
            Some(note) => write!(f, " ({note})"),
            None => Ok(()),
        }
    }
}

/// The whole numbers a count (detections, a queue's depth, an id) may take, said in words the
/// same way: [`CountRange::contains`] for the check, its `Display` for the message, and
/// [`CountRange::interval`] for the node's integer parameter descriptors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CountRange {
    min: u32,
    max: Option<u32>,
    note: Option<&'static str>,
}

impl CountRange {
    /// `min` or more.
    pub const fn at_least(min: u32) -> Self {
        Self {
            min,
            max: None,
            note: None,
        }
    }

    /// From `min` to `max`, both included.
    pub const fn between(min: u32, max: u32) -> Self {
        Self {
            min,
            max: Some(max),
            note: None,
        }
    }

    /// This range with a note after it: the unit, or why the limit is there.
    pub const fn note(self, note: &'static str) -> Self {
        Self {
            note: Some(note),
            ..self
        }
    }

    /// Whether `value` is inside.
    pub fn contains(&self, value: u64) -> bool {
        value >= u64::from(self.min) && self.max.is_none_or(|max| value <= u64::from(max))
    }

    /// `value` moved into the range.
    pub fn clamp(&self, value: u32) -> u32 {
        value.max(self.min).min(self.max.unwrap_or(u32::MAX))
    }

    /// The least and the greatest count allowed (a count is a `u32`).
    pub fn interval(&self) -> (u32, u32) {
        (self.min, self.max.unwrap_or(u32::MAX))
    }
}

impl fmt::Display for CountRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.max {
            Some(max) => write!(f, "between {} and {max}", self.min)?,
            None => write!(f, "at least {}", self.min)?,
        }
        match self.note {
            Some(note) => write!(f, " ({note})"),
            None => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{CountRange, Range};

    #[test]
    fn each_count_range_says_what_it_checks() {
        let at_least = CountRange::at_least(3).note("a third checks them");
        assert_eq!(at_least.to_string(), "at least 3 (a third checks them)");
        assert!(at_least.contains(3) && !at_least.contains(2) && at_least.contains(u64::MAX));
        assert_eq!(at_least.interval(), (3, u32::MAX));
        assert_eq!(at_least.clamp(0), 3);
        let between = CountRange::between(8, 4096).note("detections");
        assert_eq!(between.to_string(), "between 8 and 4096 (detections)");
        assert!(between.contains(8) && between.contains(4096));
        assert!(!between.contains(7) && !between.contains(4097));
        assert_eq!(between.interval(), (8, 4096));
        assert_eq!((between.clamp(5000), between.clamp(100)), (4096, 100));
        assert_eq!(CountRange::at_least(1).to_string(), "at least 1");
    }

    #[test]
    fn each_range_says_what_it_checks() {
        let cases = [
            (Range::any(), "a finite number", -1e300, f64::NAN),
            (Range::greater_than(0.0), "greater than 0", 1e-300, 0.0),
            (Range::at_least(0.0), "0 or greater", 0.0, -1e-300),
            (
                Range::greater_than(0.0).at_most(30.0).note("m/s^2"),
                "greater than 0 and at most 30 (m/s^2)",
                30.0,
                30.000_001,
            ),
            (
                Range::between(0.0, 10.0)
                    .low_meaning("no air")
                    .note("kg/m^3"),
                "between 0 (no air) and 10 (kg/m^3)",
                0.0,
                -0.1,
            ),
            (
                Range::greater_than(0.0).less_than(1.0),
                "greater than 0 and less than 1",
                0.999,
                1.0,
            ),
            (
                Range::at_least(-3.0).less_than(0.0),
                "at least -3 and less than 0",
                -3.0,
                0.0,
            ),
            (
                Range::between(0.0, 1e5),
                "between 0 and 100000",
                1e5,
                f64::INFINITY,
            ),
            (
                Range::greater_than(1e-12).named("a non-zero quaternion"),
                "a non-zero quaternion",
                1.0,
                0.0,
            ),
        ];
        for (range, words, inside, outside) in cases {
            assert_eq!(range.to_string(), words);
            assert_eq!(
                range.closed().is_some(),
                words.starts_with("between"),
                "{words}"
            );
            assert!(range.contains(inside), "{words}: {inside}");
            assert!(!range.contains(outside), "{words}: {outside}");
        }
    }
}

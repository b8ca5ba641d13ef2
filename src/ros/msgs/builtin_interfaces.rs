//! Mirror of the ROS 2 package `builtin_interfaces` (only `Time`).

use serde::{Deserialize, Serialize};

/// Nanoseconds in one second.
const NANOS_PER_SEC: i64 = 1_000_000_000;

/// `builtin_interfaces/msg/Time`: a point in time as seconds and nanoseconds since an epoch.
///
/// As in ROS 2, a negative time has `sec` rounded toward minus infinity and `nanosec` in
/// `[0, 1e9)`: -0.25 s is `{ sec: -1, nanosec: 750_000_000 }`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Whole seconds [s].
    pub sec: i32,
    /// Nanoseconds within the second [ns], in `[0, 1e9)`.
    pub nanosec: u32,
}

impl Time {
    /// The earliest representable time, `sec = i32::MIN`.
    pub const MIN: Time = Time {
        sec: i32::MIN,
        nanosec: 0,
    };
    /// The latest representable time, `sec = i32::MAX` and `nanosec = 999_999_999`.
    pub const MAX: Time = Time {
        sec: i32::MAX,
        nanosec: 999_999_999,
    };

    /// The time `nanos` nanoseconds after the epoch (negative: before it).
    ///
    /// `sec` is the floor of `nanos / 1e9` and `nanosec` the non-negative remainder. A time outside
    /// what `i32` seconds can hold (before 1901 or after 2038 for the Unix epoch) saturates to
    /// [`Time::MIN`] or [`Time::MAX`].
    pub fn from_nanos(nanos: i64) -> Time {
        let sec = nanos.div_euclid(NANOS_PER_SEC);
        let nanosec = nanos.rem_euclid(NANOS_PER_SEC);
        match (i32::try_from(sec), u32::try_from(nanosec)) {
            (Ok(sec), Ok(nanosec)) => Time { sec, nanosec },
            _ if sec < 0 => Time::MIN,
            _ => Time::MAX,
        }
    }

    /// Nanoseconds since the epoch, `sec * 1e9 + nanosec` [ns]. Exact for every `Time`, also
    /// for a malformed one with `nanosec >= 1e9`.
    pub fn to_nanos(self) -> i64 {
        i64::from(self.sec) * NANOS_PER_SEC + i64::from(self.nanosec)
    }
}

/// `builtin_interfaces/msg/Duration`: a time span [s, ns].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Duration {
    /// Whole seconds [s].
    pub sec: i32,
    /// Nanoseconds within the second [ns], in `[0, 1e9)`.
    pub nanosec: u32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn from_nanos_positive() {
        assert_eq!(
            Time::from_nanos(1_700_000_000_123_456_789),
            Time {
                sec: 1_700_000_000,
                nanosec: 123_456_789
            }
        );
        assert_eq!(Time::from_nanos(0), Time::default());
        assert_eq!(
            Time::from_nanos(999_999_999),
            Time {
                sec: 0,
                nanosec: 999_999_999
            }
        );
        assert_eq!(Time::from_nanos(1_000_000_000), Time { sec: 1, nanosec: 0 });
    }

    #[test]
    fn from_nanos_negative_floors_seconds() {
        assert_eq!(
            Time::from_nanos(-250_000_000),
            Time {
                sec: -1,
                nanosec: 750_000_000
            }
        );
        assert_eq!(
            Time::from_nanos(-1),
            Time {
                sec: -1,
                nanosec: 999_999_999
            }
        );
        assert_eq!(
            Time::from_nanos(-1_000_000_000),
            Time {
                sec: -1,
                nanosec: 0
            }
        );
        assert_eq!(
            Time::from_nanos(-1_000_000_001),
            Time {
                sec: -2,
                nanosec: 999_999_999
            }
        );
    }

    #[test]
    fn from_nanos_saturates_outside_i32_seconds() {
        assert_eq!(Time::from_nanos(i64::MAX), Time::MAX);
        assert_eq!(Time::from_nanos(i64::MIN), Time::MIN);
        let last = Time::MAX.to_nanos();
        assert_eq!(Time::from_nanos(last), Time::MAX);
        assert_eq!(Time::from_nanos(last + 1), Time::MAX);
        let first = Time::MIN.to_nanos();
        assert_eq!(Time::from_nanos(first), Time::MIN);
        assert_eq!(Time::from_nanos(first - 1), Time::MIN);
    }

    #[test]
    fn to_nanos_round_trips() {
        for nanos in [
            0,
            1,
            -1,
            999_999_999,
            -999_999_999,
            1_000_000_000,
            -1_000_000_000,
            1_700_000_000_123_456_789,
            -1_700_000_000_123_456_789,
            Time::MIN.to_nanos(),
            Time::MAX.to_nanos(),
        ] {
            let t = Time::from_nanos(nanos);
            assert!(t.nanosec < 1_000_000_000, "{t:?}");
            assert_eq!(t.to_nanos(), nanos, "{t:?}");
        }
        assert_eq!(
            Time {
                sec: -1,
                nanosec: 750_000_000
            }
            .to_nanos(),
            -250_000_000
        );
        assert_eq!(
            Time {
                sec: 1,
                nanosec: 1_500_000_000
            }
            .to_nanos(),
            2_500_000_000
        );
    }
}

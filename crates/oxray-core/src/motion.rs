//! Motion options and the timing of motion keys (guide §5.10.1): how many keys a traversable
//! has, the times of the first and last key, what happens outside that range, and which two
//! keys (and which fraction between them) a ray time selects.

use crate::error::BuildError;
use bitflags::bitflags;

bitflags! {
    /// What a traversable does at ray times outside its motion range (`OptixMotionFlags`,
    /// guide §5.10.1). Without a flag, time is clamped to the range: the traversable appears
    /// static and visible. Values match OptiX's.
    #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
    #[doc(alias = "OptixMotionFlags")]
    pub struct MotionFlags: u16 {
        /// Nothing under the traversable is hit at times before `time_begin`.
        const START_VANISH = 1 << 0;
        /// Nothing under the traversable is hit at times after `time_end`.
        const END_VANISH = 1 << 1;
    }
}

/// The motion options of an acceleration structure or a motion transform (`OptixMotionOptions`,
/// guide §5.10.1): `num_keys` keys evenly spaced from `time_begin` to `time_end`.
///
/// All zero (the default) is no motion: an acceleration structure with `num_keys` 0 or 1 is
/// static, and its times and flags are ignored. Times may be any finite range, not only
/// `[0, 1]`.
///
/// ```
/// use oxray_core::{MotionFlags, MotionOptions};
/// let m = MotionOptions::new(3, -1.0, 1.5);
/// assert!(m.has_motion());
/// // Keys at -1, 0.25 and 1.5: time 0.875 lies half-way between the last two.
/// assert_eq!(m.sample(0.875), Some(oxray_core::KeySample { key: 1, next: 2, fraction: 0.5 }));
/// // Outside the range, time is clamped ...
/// assert_eq!(m.sample(9.0).unwrap().key, 2);
/// // ... unless the traversable vanishes there.
/// let v = m.with_flags(MotionFlags::END_VANISH);
/// assert_eq!(v.sample(9.0), None);
/// ```
#[derive(Clone, Copy, Debug, Default)]
#[doc(alias = "OptixMotionOptions")]
pub struct MotionOptions {
    /// Motion keys (`numKeys`); 0 or 1 disables motion of an acceleration structure.
    pub num_keys: u16,
    /// Behaviour outside `[time_begin, time_end]`.
    pub flags: MotionFlags,
    /// Time of the first key.
    pub time_begin: f32,
    /// Time of the last key.
    pub time_end: f32,
}

impl PartialEq for MotionOptions {
    fn eq(&self, other: &Self) -> bool {
        // By bits, so that options can be keys of hash maps as build options are.
        self.num_keys == other.num_keys
            && self.flags == other.flags
            && self.time_begin.to_bits() == other.time_begin.to_bits()
            && self.time_end.to_bits() == other.time_end.to_bits()
    }
}

impl Eq for MotionOptions {}

impl std::hash::Hash for MotionOptions {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.num_keys.hash(state);
        self.flags.hash(state);
        self.time_begin.to_bits().hash(state);
        self.time_end.to_bits().hash(state);
    }
}

/// The two keys a time falls between and how far it is from the first: the data at that time
/// is `a + (b - a) * fraction`, `a` of key `key` and `b` of key `next` ([`lerp`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KeySample {
    /// The key at or before the time.
    pub key: usize,
    /// The key after it (equal to `key` at the last key and without motion).
    pub next: usize,
    /// In `[0, 1)`: 0 at `key`.
    pub fraction: f32,
}

impl KeySample {
    /// The sample of a structure without motion: key 0.
    pub const STATIC: KeySample = KeySample {
        key: 0,
        next: 0,
        fraction: 0.0,
    };
}

/// Linear interpolation as every motion key is interpolated: `a + (b - a) * f`, which gives `a`
/// exactly wherever `a == b` (a motionless key pair gives the static data, up to the sign of a
/// zero), and at `f = 0` for finite `b - a`.
#[inline(always)]
#[must_use]
pub fn lerp(a: f32, b: f32, f: f32) -> f32 {
    a + (b - a) * f
}

/// Why motion options were refused (guide §5.10.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MotionRule {
    /// A motion transform needs at least two keys.
    TransformKeys,
    /// A motion transform needs `time_begin < time_end`.
    TransformTimes,
    /// An acceleration structure with motion needs `time_begin <= time_end`.
    StructureTimes,
    /// Motion times must be finite.
    NonFiniteTime,
    /// Flags other than `START_VANISH` and `END_VANISH` are set.
    UnknownFlags,
}

impl std::fmt::Display for MotionRule {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MotionRule::TransformKeys => "a motion transform needs at least two motion keys",
            MotionRule::TransformTimes => {
                "a motion transform needs timeBegin strictly smaller than timeEnd"
            }
            MotionRule::StructureTimes => "timeBegin must not be greater than timeEnd",
            MotionRule::NonFiniteTime => "motion times must be finite",
            MotionRule::UnknownFlags => "only START_VANISH and END_VANISH are motion flags",
        })
    }
}

impl MotionOptions {
    /// No motion.
    pub const NONE: MotionOptions = MotionOptions {
        num_keys: 0,
        flags: MotionFlags::empty(),
        time_begin: 0.0,
        time_end: 0.0,
    };

    /// `num_keys` keys from `time_begin` to `time_end`, without flags.
    #[must_use]
    pub fn new(num_keys: u16, time_begin: f32, time_end: f32) -> Self {
        MotionOptions {
            num_keys,
            flags: MotionFlags::empty(),
            time_begin,
            time_end,
        }
    }

    /// The same options with `flags`.
    #[must_use]
    pub fn with_flags(mut self, flags: MotionFlags) -> Self {
        self.flags = flags;
        self
    }

    /// Whether these options give motion: more than one key.
    #[must_use]
    pub fn has_motion(&self) -> bool {
        self.num_keys > 1
    }

    /// Keys the data is given for: `num_keys`, or 1 without motion.
    #[must_use]
    pub fn key_count(&self) -> usize {
        (self.num_keys as usize).max(1)
    }

    /// The options of an acceleration structure (guide §5.10.1): with motion, finite times
    /// with `time_begin <= time_end` and known flags; without, anything (it is ignored).
    pub fn validate_for_structure(&self) -> Result<(), BuildError> {
        if !self.has_motion() {
            return Ok(());
        }
        self.check_common()?;
        if self.time_begin > self.time_end {
            return Err(BuildError::InvalidMotionOptions(MotionRule::StructureTimes));
        }
        Ok(())
    }

    /// The options of a motion transform (guide §5.10.1): at least two keys, finite times with
    /// `time_begin < time_end`, known flags.
    pub fn validate_for_transform(&self) -> Result<(), BuildError> {
        if self.num_keys < 2 {
            return Err(BuildError::InvalidMotionOptions(MotionRule::TransformKeys));
        }
        self.check_common()?;
        if self.time_begin >= self.time_end {
            return Err(BuildError::InvalidMotionOptions(MotionRule::TransformTimes));
        }
        Ok(())
    }

    fn check_common(&self) -> Result<(), BuildError> {
        if !(self.time_begin.is_finite() && self.time_end.is_finite()) {
            return Err(BuildError::InvalidMotionOptions(MotionRule::NonFiniteTime));
        }
        if !MotionFlags::all().contains(self.flags) {
            return Err(BuildError::InvalidMotionOptions(MotionRule::UnknownFlags));
        }
        Ok(())
    }

    /// Whether a traversable with these options vanishes at `time` (a vanish flag and a time
    /// outside the range); never without motion.
    #[inline]
    #[must_use]
    pub fn vanishes_at(&self, time: f32) -> bool {
        self.has_motion()
            && ((self.flags.contains(MotionFlags::START_VANISH) && time < self.time_begin)
                || (self.flags.contains(MotionFlags::END_VANISH) && time > self.time_end))
    }

    /// The keys `time` falls between (guide §5.10.1): keys are evenly spaced from `time_begin`
    /// to `time_end`, a time outside the range is clamped to it, and `None` where the
    /// traversable vanishes. A time that is not a number is taken as `time_begin`. Without
    /// motion, [`KeySample::STATIC`].
    #[inline]
    #[must_use]
    pub fn sample(&self, time: f32) -> Option<KeySample> {
        if !self.has_motion() {
            return Some(KeySample::STATIC);
        }
        if self.vanishes_at(time) {
            return None;
        }
        let last = self.num_keys as usize - 1;
        let span = self.time_end - self.time_begin;
        // A structure whose range is one instant shows its first key up to that instant and
        // its last key after it.
        if span <= 0.0 {
            let key = if time > self.time_end { last } else { 0 };
            return Some(KeySample {
                key,
                next: key,
                fraction: 0.0,
            });
        }
        let t = if time.is_nan() {
            self.time_begin
        } else {
            time.clamp(self.time_begin, self.time_end)
        };
        let pos = (t - self.time_begin) / span * last as f32;
        let key = (pos.floor().max(0.0) as usize).min(last);
        if key == last {
            return Some(KeySample {
                key,
                next: key,
                fraction: 0.0,
            });
        }
        Some(KeySample {
            key,
            next: key + 1,
            fraction: (pos - key as f32).clamp(0.0, 1.0),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn s5_10_1_keys_are_evenly_spaced_and_interpolated_between_neighbours() {
        let m = MotionOptions::new(5, 1.0, 3.0);
        // Keys at 1, 1.5, 2, 2.5, 3.
        for (k, t) in [1.0f32, 1.5, 2.0, 2.5].into_iter().enumerate() {
            let s = m.sample(t).unwrap();
            assert_eq!((s.key, s.next, s.fraction), (k, k + 1, 0.0));
        }
        let s = m.sample(3.0).unwrap();
        assert_eq!((s.key, s.next, s.fraction), (4, 4, 0.0));
        let s = m.sample(2.125).unwrap();
        assert_eq!((s.key, s.next, s.fraction), (2, 3, 0.25));
        assert_eq!(lerp(2.0, 6.0, 0.25), 3.0);
        assert_eq!(lerp(0.1, 0.1, 0.37), 0.1);
    }

    #[test]
    fn s5_10_1_time_outside_the_range_is_clamped_unless_the_traversable_vanishes() {
        let m = MotionOptions::new(2, 0.0, 1.0);
        assert_eq!(m.sample(-4.0), m.sample(0.0));
        assert_eq!(m.sample(7.0), m.sample(1.0));
        let start = m.with_flags(MotionFlags::START_VANISH);
        assert_eq!(start.sample(-0.001), None);
        assert_eq!(start.sample(7.0), m.sample(1.0));
        let end = m.with_flags(MotionFlags::END_VANISH);
        assert_eq!(end.sample(1.001), None);
        assert_eq!(end.sample(-1.0), m.sample(0.0));
        // The range's ends themselves are inside.
        let both = m.with_flags(MotionFlags::all());
        assert!(both.sample(0.0).is_some() && both.sample(1.0).is_some());
        // Without motion the flags and times are ignored.
        let none = MotionOptions::new(1, 0.0, 1.0).with_flags(MotionFlags::all());
        assert_eq!(none.sample(-5.0), Some(KeySample::STATIC));
    }

    #[test]
    fn s5_10_1_structures_and_transforms_validate_their_options() {
        // All zero disables motion of an acceleration structure, whatever else is set.
        MotionOptions::default().validate_for_structure().unwrap();
        MotionOptions::new(1, 5.0, -5.0)
            .validate_for_structure()
            .unwrap();
        MotionOptions::new(2, 1.0, 1.0)
            .validate_for_structure()
            .unwrap();
        let err = MotionOptions::new(2, 1.0, 0.0)
            .validate_for_structure()
            .unwrap_err();
        assert_eq!(
            err,
            BuildError::InvalidMotionOptions(MotionRule::StructureTimes)
        );
        assert_eq!(err.code(), crate::ErrorCode::InvalidValue);
        // Transforms: at least two keys, begin strictly before end.
        for (m, rule) in [
            (MotionOptions::new(1, 0.0, 1.0), MotionRule::TransformKeys),
            (MotionOptions::new(0, 0.0, 1.0), MotionRule::TransformKeys),
            (MotionOptions::new(2, 1.0, 1.0), MotionRule::TransformTimes),
            (
                MotionOptions::new(2, 0.0, f32::NAN),
                MotionRule::NonFiniteTime,
            ),
        ] {
            assert_eq!(
                m.validate_for_transform(),
                Err(BuildError::InvalidMotionOptions(rule))
            );
        }
        let mut bad = MotionOptions::new(2, 0.0, 1.0);
        bad.flags = MotionFlags::from_bits_retain(4);
        assert_eq!(
            bad.validate_for_transform(),
            Err(BuildError::InvalidMotionOptions(MotionRule::UnknownFlags))
        );
    }
}

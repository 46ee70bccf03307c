//! Alarms as events: the per-frame anomaly flags of a stream debounced into alarm start
//! and end events (k of n frames), so one anomaly is one alarm an operator can act on,
//! not a flickering run of flags.
//!
//! Rule ([`Debounce`]): an alarm **starts** at the frame where at least `k` of the last
//! `n` frames (that frame included) are flagged, and **ends** at the first frame after
//! which the last `n` frames hold no flag at all (`n` clear frames in a row). Between
//! the two, flags and gaps shorter than `n` belong to the same alarm. With `k = n = 1`
//! every run of flagged frames is its own alarm, starting at its first frame and ending
//! at the frame after its last.
//!
//! Pure and synchronous; used by the service's sessions, `vamos eval`'s plots and
//! anything that replays scores.

use serde::{Deserialize, Serialize};

/// The debouncing rule of alarms (`[alarm_events]` of a profile). Defaults: 3 of 5.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct Debounce {
    /// Flagged frames among the last `window` needed to start an alarm (1..=window).
    pub frames: usize,
    /// The window, frames; also the clear frames in a row that end an alarm (1..=64).
    pub window: usize,
}

impl Default for Debounce {
    fn default() -> Self {
        Self {
            frames: 3,
            window: 5,
        }
    }
}

/// A [`Debounce`] that cannot work.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("alarm debounce {frames} of {window} frames: need 1 <= frames <= window <= 64")]
pub struct BadDebounce {
    /// `frames` as given.
    pub frames: usize,
    /// `window` as given.
    pub window: usize,
}

impl Debounce {
    /// Checks `1 <= frames <= window <= 64`.
    pub fn check(&self) -> Result<(), BadDebounce> {
        if self.frames == 0 || self.frames > self.window || self.window > 64 {
            return Err(BadDebounce {
                frames: self.frames,
                window: self.window,
            });
        }
        Ok(())
    }
}

/// What one frame did to the alarm state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Edge {
    /// Nothing changed.
    None,
    /// An alarm starts at this frame.
    Start,
    /// The alarm ends at this frame (the `window`-th clear frame in a row).
    End,
}

/// The debouncer of one stream: feed it every scored frame's flag in order.
#[derive(Debug, Clone)]
pub struct Debouncer {
    rule: Debounce,
    /// The last `window` flags, bit 0 the newest.
    bits: u64,
    active: bool,
}

impl Default for Debouncer {
    /// The default rule (3 of 5 frames).
    fn default() -> Self {
        Self {
            rule: Debounce::default(),
            bits: 0,
            active: false,
        }
    }
}

impl Debouncer {
    /// A debouncer with `rule` (checked).
    pub fn new(rule: Debounce) -> Result<Self, BadDebounce> {
        rule.check()?;
        Ok(Self {
            rule,
            bits: 0,
            active: false,
        })
    }

    /// The rule.
    pub fn rule(&self) -> Debounce {
        self.rule
    }

    /// Whether an alarm is on.
    pub fn active(&self) -> bool {
        self.active
    }

    /// The next frame's flag.
    pub fn push(&mut self, flagged: bool) -> Edge {
        let mask = if self.rule.window == 64 {
            u64::MAX
        } else {
            (1u64 << self.rule.window) - 1
        };
        self.bits = ((self.bits << 1) | u64::from(flagged)) & mask;
        let count = self.bits.count_ones() as usize;
        if !self.active && count >= self.rule.frames {
            self.active = true;
            Edge::Start
        } else if self.active && count == 0 {
            self.active = false;
            Edge::End
        } else {
            Edge::None
        }
    }
}

/// The alarms of a finished stream of flags: `(start, end)` frame positions, `end`
/// `None` for an alarm still on at the last frame.
pub fn alarm_intervals(
    flags: impl IntoIterator<Item = bool>,
    rule: Debounce,
) -> Result<Vec<(usize, Option<usize>)>, BadDebounce> {
    let mut d = Debouncer::new(rule)?;
    let mut out: Vec<(usize, Option<usize>)> = Vec::new();
    for (i, f) in flags.into_iter().enumerate() {
        match d.push(f) {
            Edge::Start => out.push((i, None)),
            Edge::End => {
                if let Some(last) = out.last_mut() {
                    last.1 = Some(i);
                }
            }
            Edge::None => {}
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flags(s: &str) -> Vec<bool> {
        s.chars().map(|c| c == '1').collect()
    }

    #[test]
    fn three_of_five_starts_on_the_third_flag_and_ends_after_five_clear_frames() {
        let rule = Debounce::default();
        // Flags at 2, 4, 5: the third of them within a window of 5 is frame 5.
        let f = flags("0010110000000");
        assert_eq!(alarm_intervals(f, rule).unwrap(), vec![(5, Some(10))]);
    }

    #[test]
    fn isolated_flags_raise_no_alarm_and_gaps_shorter_than_the_window_keep_it_on() {
        let rule = Debounce::default();
        assert!(
            alarm_intervals(flags("1000010000100001"), rule)
                .unwrap()
                .is_empty()
        );
        // On at 2, a gap of 4 clear frames (< 5) does not end it, then 5 clear end it.
        let f = flags("111000011100000");
        assert_eq!(alarm_intervals(f, rule).unwrap(), vec![(2, Some(14))]);
        // Still on at the end.
        assert_eq!(
            alarm_intervals(flags("0001111"), rule).unwrap(),
            vec![(5, None)]
        );
    }

    #[test]
    fn one_of_one_is_every_run_of_flags() {
        let rule = Debounce {
            frames: 1,
            window: 1,
        };
        let f = flags("0110010");
        assert_eq!(
            alarm_intervals(f, rule).unwrap(),
            vec![(1, Some(3)), (5, Some(6))]
        );
    }

    #[test]
    fn the_widest_window_works_and_bad_rules_are_refused() {
        let rule = Debounce {
            frames: 64,
            window: 64,
        };
        let mut d = Debouncer::new(rule).unwrap();
        for _ in 0..63 {
            assert_eq!(d.push(true), Edge::None);
        }
        assert_eq!(d.push(true), Edge::Start);
        for _ in 0..63 {
            assert_eq!(d.push(false), Edge::None);
        }
        assert_eq!(d.push(false), Edge::End);
        for (frames, window) in [(0, 5), (6, 5), (3, 65)] {
            assert_eq!(
                Debouncer::new(Debounce { frames, window }).unwrap_err(),
                BadDebounce { frames, window }
            );
        }
    }
}

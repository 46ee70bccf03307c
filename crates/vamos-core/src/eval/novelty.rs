//! Kinematic novelty `e_k`: how far the robot's state lies from every state it passed
//! through in the nominal runs.
//!
//! A state is a vector built by the pipeline from the joint states (the joints' positions
//! and velocities, or its links' positions in metres), each value optionally divided by a
//! per-value scale fitted on the nominal runs (a joint's nominal range), so that the
//! distance between two states is in one unit. A repeated task passes through the same
//! states in every nominal run; a detour (knocking something over), a jam against an
//! obstacle, a push or a joint reading gone wrong leaves them, however the camera sees it.
//!
//! [`StateReference`] keeps the nominal states (consecutive states of an episode closer
//! than [`MIN_SPACING`] are kept once) and answers the distance to the nearest one
//! (exhaustive search: a few thousand states of a few hundred values take about a
//! millisecond). It is stored with the calibration as 16-bit codes per value (each
//! value's column quantised between its smallest and largest, steps of micrometres for a
//! robot of metres), base64: a third of the size of the same floats as JSON text, and the
//! states a scorer searches are the decoded codes whether the calibration was just fitted
//! or read back, so both score alike. Calibration needs the nominal distribution of `e_k`, which a state's
//! own episode would make zero: [`leave_one_episode_out`] gives each training frame its
//! distance to the other episodes' states.
//!
//! Pure maths on slices, like the rest of `eval`.

use base64::Engine;
use base64::engine::general_purpose::STANDARD as BASE64;
use serde::{Deserialize, Serialize};

/// Consecutive states of one episode closer than this (in the states' unit after scaling:
/// metres, or nominal ranges) are kept once: far below any motion worth an alarm, and a
/// robot standing still does not fill the reference.
pub const MIN_SPACING: f64 = 0.002;
/// At most this many states are kept (beyond it, every k-th state of each episode): the
/// reference is stored with the calibration and searched for every frame.
pub const MAX_STATES: usize = 20_000;

/// Largest number of values per state a stored reference may declare.
pub const MAX_DIMS: usize = 65_536;

/// The nominal states of a profile's training episodes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(try_from = "EncodedStates", into = "EncodedStates")]
pub struct StateReference {
    /// The stored form.
    encoded: EncodedStates,
    /// The decoded states, row-major, `dims` values each.
    states: Vec<f32>,
}

/// A [`StateReference`] as it is stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
struct EncodedStates {
    /// Values per state (the pipeline's state layout; a frame whose state has another
    /// length has no `e_k`).
    dims: usize,
    /// Number of states.
    count: usize,
    /// Per value of a state: the smallest over the states.
    offset: Vec<f64>,
    /// Per value of a state: the size of one code step (0 for a value that never changes).
    step: Vec<f64>,
    /// Per value of a state: what a query's value is divided by before it is compared (the
    /// stored states are divided already); absent: 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    scale: Option<Vec<f64>>,
    /// The codes, `count x dims` little-endian `u16`, row-major, base64.
    codes: String,
}

impl EncodedStates {
    /// Quantises `states` (row-major, `dims` each, finite, already scaled).
    fn encode(states: &[f32], dims: usize, scale: Option<Vec<f64>>) -> EncodedStates {
        let count = states.len() / dims;
        let mut offset = vec![f64::INFINITY; dims];
        let mut high = vec![f64::NEG_INFINITY; dims];
        for row in states.chunks_exact(dims) {
            for ((lo, hi), &v) in offset.iter_mut().zip(&mut high).zip(row) {
                *lo = lo.min(f64::from(v));
                *hi = hi.max(f64::from(v));
            }
        }
        let step: Vec<f64> = offset
            .iter()
            .zip(&high)
            .map(|(lo, hi)| (hi - lo) / f64::from(u16::MAX))
            .collect();
        let mut bytes = Vec::with_capacity(states.len() * 2);
        for row in states.chunks_exact(dims) {
            for ((&v, lo), st) in row.iter().zip(&offset).zip(&step) {
                let code = if *st > 0.0 {
                    ((f64::from(v) - lo) / st)
                        .round()
                        .clamp(0.0, f64::from(u16::MAX)) as u16
                } else {
                    0
                };
                bytes.extend_from_slice(&code.to_le_bytes());
            }
        }
        EncodedStates {
            dims,
            count,
            offset,
            step,
            scale,
            codes: BASE64.encode(bytes),
        }
    }

    /// The states the codes stand for.
    fn decode(&self) -> Result<Vec<f32>, String> {
        let EncodedStates {
            dims,
            count,
            offset,
            step,
            scale,
            codes,
        } = self;
        if *dims == 0 || *dims > MAX_DIMS || *count == 0 || *count > MAX_STATES {
            return Err(format!(
                "a state reference of {count} states of {dims} values (at most {MAX_STATES} \
                 states of 1..={MAX_DIMS} values)"
            ));
        }
        if offset.len() != *dims || step.len() != *dims {
            return Err(format!(
                "a state reference of {dims} values per state has {} offsets and {} steps",
                offset.len(),
                step.len()
            ));
        }
        if offset.iter().chain(step).any(|v| !v.is_finite()) || step.iter().any(|&v| v < 0.0) {
            return Err("a state reference's offsets and steps must be finite, steps >= 0".into());
        }
        if let Some(scale) = scale
            && (scale.len() != *dims || scale.iter().any(|v| !(v.is_finite() && *v > 0.0)))
        {
            return Err(format!(
                "a state reference's scale must be {dims} finite values > 0"
            ));
        }
        let expected = count * dims * 2;
        // The encoded length says the decoded one: refuse before decoding anything else.
        if codes.len() != expected.div_ceil(3) * 4 {
            return Err(format!(
                "a state reference of {count} x {dims} values needs {} base64 characters, \
                 it has {}",
                expected.div_ceil(3) * 4,
                codes.len()
            ));
        }
        let bytes = BASE64
            .decode(codes)
            .map_err(|e| format!("a state reference's codes: {e}"))?;
        if bytes.len() != expected {
            return Err(format!(
                "a state reference's codes hold {} bytes, not {expected}",
                bytes.len()
            ));
        }
        Ok(bytes
            .chunks_exact(2)
            .enumerate()
            .map(|(i, b)| {
                let d = i % dims;
                (offset[d] + f64::from(u16::from_le_bytes([b[0], b[1]])) * step[d]) as f32
            })
            .collect())
    }
}

impl TryFrom<EncodedStates> for StateReference {
    type Error = String;

    fn try_from(encoded: EncodedStates) -> Result<Self, String> {
        let states = encoded.decode()?;
        Ok(StateReference { encoded, states })
    }
}

impl From<StateReference> for EncodedStates {
    fn from(r: StateReference) -> Self {
        r.encoded
    }
}

impl StateReference {
    /// The reference of `episodes` (each a list of states of `dims` values; states of
    /// another length are skipped), each value divided by `scale` (`dims` finite values
    /// above 0; `None`: as they are). `None` when no state is left or `scale` does not fit.
    pub fn fit(
        episodes: &[Vec<Vec<f32>>],
        dims: usize,
        scale: Option<Vec<f64>>,
    ) -> Option<StateReference> {
        if dims == 0 {
            return None;
        }
        let scaled = scaled(episodes, dims, scale.as_deref())?;
        let kept: Vec<Vec<&[f32]>> = scaled.iter().map(|e| thin(e, dims)).collect();
        let total: usize = kept.iter().map(Vec::len).sum();
        let step = total.div_ceil(MAX_STATES).max(1);
        let mut states = Vec::with_capacity(total.min(MAX_STATES) * dims);
        for episode in &kept {
            for s in episode.iter().step_by(step) {
                states.extend_from_slice(s);
            }
        }
        if states.is_empty() {
            return None;
        }
        // What is searched is what is stored: the decoded codes.
        StateReference::try_from(EncodedStates::encode(&states, dims, scale)).ok()
    }

    /// This reference with the states of `episodes` (as the pipeline makes them: scaled
    /// here like the reference's own, thinned, capped) added: what a revision from
    /// episodes judged nominal learns. `None` when the result cannot be encoded.
    pub fn extended(&self, episodes: &[Vec<Vec<f32>>]) -> Option<StateReference> {
        let dims = self.dims();
        let scaled = scaled(episodes, dims, self.scale())?;
        let mut states = self.states.clone();
        for episode in &scaled {
            for s in thin(episode, dims) {
                states.extend_from_slice(s);
            }
        }
        let count = states.len() / dims;
        if count > MAX_STATES {
            let step = count.div_ceil(MAX_STATES);
            states = states
                .chunks_exact(dims)
                .step_by(step)
                .flatten()
                .copied()
                .collect();
        }
        StateReference::try_from(EncodedStates::encode(
            &states,
            dims,
            self.encoded.scale.clone(),
        ))
        .ok()
    }

    /// Values per state.
    pub fn dims(&self) -> usize {
        self.encoded.dims
    }

    /// Number of states.
    pub fn len(&self) -> usize {
        self.encoded.count
    }

    /// Whether it holds no state.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The scale a state's values are divided by (`None`: 1).
    pub fn scale(&self) -> Option<&[f64]> {
        self.encoded.scale.as_deref()
    }

    /// Distance from `state` (divided by the scale) to the nearest reference state;
    /// `None` when the lengths differ or the reference is empty, NaN when `state` is not
    /// finite.
    pub fn distance(&self, state: &[f32]) -> Option<f64> {
        let dims = self.dims();
        if state.len() != dims || self.is_empty() {
            return None;
        }
        if state.iter().any(|v| !v.is_finite()) {
            return Some(f64::NAN);
        }
        let scaled;
        let state = match self.scale() {
            Some(scale) => {
                scaled = scale_state(state, scale);
                scaled.as_slice()
            }
            None => state,
        };
        let best = self
            .states
            .chunks_exact(dims)
            .map(|r| squared_distance(r, state))
            .fold(f32::INFINITY, f32::min);
        Some(f64::from(best).sqrt())
    }
}

/// Each state's distance (values divided by `scale`, as [`StateReference::fit`]) to the
/// nearest state of the *other* episodes (NaN for a state of another length than `dims`
/// or when there is no other episode), episode by episode: the nominal distribution of
/// `e_k` that a frame of an unseen nominal run would have. All NaN when `scale` does not
/// fit.
pub fn leave_one_episode_out(
    episodes: &[Vec<Vec<f32>>],
    dims: usize,
    scale: Option<&[f64]>,
) -> Vec<Vec<f64>> {
    let Some(episodes) = scaled(episodes, dims, scale) else {
        return episodes.iter().map(|e| vec![f64::NAN; e.len()]).collect();
    };
    let kept: Vec<Vec<&[f32]>> = episodes.iter().map(|e| thin(e, dims)).collect();
    episodes
        .iter()
        .enumerate()
        .map(|(i, episode)| {
            episode
                .iter()
                .map(|s| {
                    if s.len() != dims || s.iter().any(|v| !v.is_finite()) {
                        return f64::NAN;
                    }
                    let best = kept
                        .iter()
                        .enumerate()
                        .filter(|&(j, _)| j != i)
                        .flat_map(|(_, other)| other.iter())
                        .map(|r| squared_distance(r, s))
                        .fold(f32::INFINITY, f32::min);
                    if best.is_finite() {
                        f64::from(best).sqrt()
                    } else {
                        f64::NAN
                    }
                })
                .collect()
        })
        .collect()
}

/// `episodes` with each state of `dims` values divided by `scale` (others kept as they
/// are, to be skipped later); `None` when `scale` is not `dims` finite values above 0.
fn scaled(
    episodes: &[Vec<Vec<f32>>],
    dims: usize,
    scale: Option<&[f64]>,
) -> Option<Vec<Vec<Vec<f32>>>> {
    let Some(scale) = scale else {
        return Some(episodes.to_vec());
    };
    if scale.len() != dims || scale.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return None;
    }
    Some(
        episodes
            .iter()
            .map(|e| {
                e.iter()
                    .map(|s| {
                        if s.len() == dims {
                            scale_state(s, scale)
                        } else {
                            s.clone()
                        }
                    })
                    .collect()
            })
            .collect(),
    )
}

fn scale_state(state: &[f32], scale: &[f64]) -> Vec<f32> {
    state
        .iter()
        .zip(scale)
        .map(|(&v, &k)| (f64::from(v) / k) as f32)
        .collect()
}

/// The states of one episode of length `dims` and finite, each kept only when it lies at
/// least [`MIN_SPACING`] from the last one kept.
fn thin(episode: &[Vec<f32>], dims: usize) -> Vec<&[f32]> {
    let min2 = (MIN_SPACING * MIN_SPACING) as f32;
    let mut kept: Vec<&[f32]> = Vec::new();
    for s in episode {
        if s.len() != dims || s.iter().any(|v| !v.is_finite()) {
            continue;
        }
        if kept
            .last()
            .is_none_or(|last| squared_distance(last, s) >= min2)
        {
            kept.push(s);
        }
    }
    kept
}

fn squared_distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn line(n: usize, y: f32) -> Vec<Vec<f32>> {
        (0..n).map(|i| vec![i as f32 * 0.01, y]).collect()
    }

    #[test]
    fn the_distance_is_to_the_nearest_nominal_state() {
        let r = StateReference::fit(&[line(11, 0.0), line(11, 0.1)], 2, None).unwrap();
        assert_eq!(r.len(), 22);
        // 3 cm above the upper line, between two of its states (codes are micrometres).
        let d = r.distance(&[0.055, 0.13]).unwrap();
        assert!(
            (d - (0.005f64.powi(2) + 0.03f64.powi(2)).sqrt()).abs() < 1e-5,
            "{d}"
        );
        assert!(r.distance(&[0.05, 0.0]).unwrap() < 1e-5);
        assert_eq!(r.distance(&[0.05]), None, "another layout has no distance");
        assert!(r.distance(&[f32::NAN, 0.0]).unwrap().is_nan());
    }

    #[test]
    fn a_robot_standing_still_is_kept_once() {
        let mut still = vec![vec![0.5f32, 0.5]; 50];
        still.push(vec![0.6, 0.5]);
        let r = StateReference::fit(&[still], 2, None).unwrap();
        assert_eq!(r.len(), 2);
        assert!(StateReference::fit(&[vec![vec![0.0; 3]]], 2, None).is_none());
    }

    #[test]
    fn leaving_an_episode_out_measures_it_against_the_others_only() {
        let episodes = [line(5, 0.0), line(5, 0.02), vec![vec![0.0, 0.5]]];
        let loo = leave_one_episode_out(&episodes, 2, None);
        assert_eq!(loo.len(), 3);
        assert!(
            loo[0].iter().all(|&d| (d - 0.02).abs() < 1e-6),
            "{:?}",
            loo[0]
        );
        assert!((loo[2][0] - 0.48).abs() < 1e-6);
        let alone = leave_one_episode_out(&[line(3, 0.0)], 2, None);
        assert!(alone[0].iter().all(|d| d.is_nan()));
    }

    #[test]
    fn a_scale_divides_each_value_before_it_is_compared() {
        // The second value varies ten times more in the nominal runs: a step of 0.1 in it
        // counts as a step of 0.01 in the first.
        let scale = vec![0.1, 1.0];
        let r = StateReference::fit(&[line(11, 0.0)], 2, Some(scale.clone())).unwrap();
        assert_eq!(r.scale(), Some(scale.as_slice()));
        let d = r.distance(&[0.05, 0.1]).unwrap();
        assert!((d - 0.1).abs() < 1e-5, "{d}");
        let d = r.distance(&[0.105, 0.0]).unwrap();
        assert!((d - 0.05).abs() < 1e-4, "{d}");
        let loo = leave_one_episode_out(&[line(3, 0.0), line(3, 0.5)], 2, Some(&scale));
        assert!(loo[0].iter().all(|&d| (d - 0.5).abs() < 1e-6), "{loo:?}");
        assert!(StateReference::fit(&[line(3, 0.0)], 2, Some(vec![0.0, 1.0])).is_none());
        let bad = leave_one_episode_out(&[line(3, 0.0), line(3, 0.5)], 2, Some(&[1.0]));
        assert!(bad.iter().flatten().all(|d| d.is_nan()));
    }

    #[test]
    fn an_extended_reference_knows_the_new_states_and_keeps_the_old() {
        let scale = vec![0.5, 1.0];
        let r = StateReference::fit(&[line(11, 0.0)], 2, Some(scale.clone())).unwrap();
        assert!(r.distance(&[0.05, 0.5]).unwrap() > 0.49);
        let wider = r.extended(&[line(11, 0.5)]).unwrap();
        assert_eq!(wider.len(), 22);
        assert_eq!(wider.scale(), Some(scale.as_slice()));
        assert!(wider.distance(&[0.05, 0.5]).unwrap() < 1e-4);
        assert!(wider.distance(&[0.05, 0.0]).unwrap() < 1e-4);
    }

    #[test]
    fn the_reference_is_capped() {
        let many: Vec<Vec<f32>> = (0..3 * MAX_STATES).map(|i| vec![i as f32]).collect();
        let r = StateReference::fit(&[many], 1, None).unwrap();
        assert!(
            r.len() <= MAX_STATES && r.len() >= MAX_STATES / 2,
            "{}",
            r.len()
        );
    }

    #[test]
    fn a_stored_reference_reads_back_as_the_same_states() {
        let episodes = [line(40, 0.0), line(40, 0.25), vec![vec![-1.5, 2.0]]];
        let r = StateReference::fit(&episodes, 2, None).unwrap();
        let json = serde_json::to_string(&r).unwrap();
        let back: StateReference = serde_json::from_str(&json).unwrap();
        assert_eq!(back, r);
        assert_eq!(back.distance(&[0.3, 0.1]), r.distance(&[0.3, 0.1]));
        // Quantised within a 16-bit step of each column's range.
        let step = 3.5 / f64::from(u16::MAX);
        assert!(
            r.distance(&[-1.5, 2.0]).unwrap() < step,
            "{:?}",
            r.distance(&[-1.5, 2.0])
        );
        // 81 states of two 2-byte codes in base64 (432 characters) plus the columns.
        assert!(json.len() < 600, "{} bytes: {json}", json.len());
    }

    #[test]
    fn a_damaged_stored_reference_is_refused() {
        let r = StateReference::fit(&[line(5, 0.0)], 2, Some(vec![1.0, 2.0])).unwrap();
        let good: serde_json::Value = serde_json::to_value(&r).unwrap();
        for (key, value) in [
            ("dims", serde_json::json!(3)),
            ("count", serde_json::json!(1_000_000_000u64)),
            ("codes", serde_json::json!("AAAA")),
            ("codes", serde_json::json!("!!!!!!!!!!!!!!!!!!!!!!!!!!!!")),
            ("step", serde_json::json!([-1.0, 0.0])),
            ("offset", serde_json::json!([0.0])),
            ("scale", serde_json::json!([1.0, 0.0])),
        ] {
            let mut bad = good.clone();
            bad[key] = value;
            let err = serde_json::from_value::<StateReference>(bad).unwrap_err();
            assert!(err.to_string().contains("state reference"), "{key}: {err}");
        }
    }
}

//! `e_k`, the kinematic novelty: the robot's state (joint positions, their velocities and
//! optionally efforts, or link points; [`crate::pipeline::novelty`]) against the nominal
//! states the calibration kept, as the distance to the nearest
//! ([`crate::eval::StateReference`]). Needs no image: it is defined on a stream's first
//! frame too.
//!
//! Calibration ([`fit`]): the training frames' states are the nominal states; each training
//! frame's `e_k` is its distance to the *other* episodes' states (its own would make it
//! zero). A revision adds the states of episodes judged nominal ([`revise`]).

use super::{FrameContext, FrameDetector};
use crate::eval::{Detector, StateReference, novelty};
use crate::pipeline::offline::EpisodeScores;
use crate::pipeline::profile::Calibration;
use crate::pipeline::scorer::{FrameScore, JointInput, RobotSetup, ScorerError, phase_s};
use crate::pipeline::{EffortWindow, KinematicsParams, PipelineConfig};
use std::collections::HashMap;

/// The kinematic-novelty detector.
pub struct Kinematics {
    params: KinematicsParams,
    /// The joints that move of their own (not fixed, not mimic) by name, with their place
    /// in a state's positions (for the efforts that follow them).
    own_joints: HashMap<String, usize>,
    /// The recent efforts (`effort = true`), smoothed.
    efforts: EffortWindow,
    /// The previous processed frame's stamp and the positions part of its state.
    previous: Option<(i64, Vec<f64>)>,
}

impl Kinematics {
    /// With the pipeline's kinematics settings, for `robot`'s joints.
    pub fn new(config: &PipelineConfig, robot: &RobotSetup) -> Kinematics {
        let own_joints = robot
            .robot
            .joints()
            .iter()
            .filter(|j| j.kind.is_moving() && j.mimic.is_none())
            .enumerate()
            .map(|(place, j)| (j.name.clone(), place))
            .collect();
        Kinematics {
            params: config.kinematics,
            own_joints,
            efforts: EffortWindow::default(),
            previous: None,
        }
    }

    /// The efforts of the joints that move of their own, in their order (0 for one the
    /// message lacks); `None` when the message carries no efforts (or not one per name).
    fn own_efforts(&self, joints: JointInput<'_>) -> Option<Vec<f64>> {
        if joints.efforts.is_empty() || joints.efforts.len() != joints.names.len() {
            return None;
        }
        let mut out = vec![0.0; self.own_joints.len()];
        for (name, &e) in joints.names.iter().zip(joints.efforts) {
            if let Some(&i) = self.own_joints.get(name.as_str()) {
                out[i] = e;
            }
        }
        Some(out)
    }
}

impl FrameDetector for Kinematics {
    fn detector(&self) -> Detector {
        Detector::Kinematics
    }

    /// Writes the frame's state (`kinematic_state`: what calibration keeps); the value
    /// needs a calibration's nominal states.
    fn measure(
        &mut self,
        frame: &FrameContext<'_>,
        out: &mut FrameScore,
    ) -> Result<Option<f64>, ScorerError> {
        let efforts = match (self.params.effort, frame.joints) {
            (true, Some(joints)) => {
                let efforts = self.own_efforts(joints);
                self.efforts.push(efforts, self.params.effort_window)
            }
            _ => None,
        };
        let positions = match (frame.pose, frame.positions) {
            (Some((links, _)), Some(q)) => Some(self.params.positions(q, links)),
            _ => None,
        };
        let previous = std::mem::replace(
            &mut self.previous,
            positions.clone().map(|p| (frame.stamp_ns, p)),
        );
        let state = positions.as_deref().and_then(|now| {
            self.params.state(
                now,
                previous
                    .as_ref()
                    .map(|(then, before)| (before.as_slice(), phase_s(*then, frame.stamp_ns))),
                efforts.as_deref(),
            )
        });
        let e_k = state.as_deref().and_then(|s| {
            frame
                .thresholds
                .kinematics
                .as_ref()
                .and_then(|r| r.distance(s))
        });
        out.kinematic_state = state;
        Ok(e_k)
    }

    fn reset(&mut self) {
        self.previous = None;
        self.efforts = EffortWindow::default();
    }
}

/// Each episode's frames' robot states (empty for a frame without one, which the state
/// reference skips).
fn robot_states(episodes: &[EpisodeScores]) -> Vec<Vec<Vec<f32>>> {
    episodes
        .iter()
        .map(|e| {
            e.frames
                .iter()
                .map(|f| f.kinematic_state.clone().unwrap_or_default())
                .collect()
        })
        .collect()
}

/// The nominal robot states of the training episodes (scaled as `params` says) and each
/// training frame's `e_k` against the other episodes' states (flattened like the
/// episodes' frames; `None` for a frame without a state). No reference, with a note, when
/// no frame has a state or no frame's distance can be measured (a single training
/// episode).
pub fn fit(
    train: &[EpisodeScores],
    params: &KinematicsParams,
    notes: &mut Vec<String>,
) -> (Option<StateReference>, Vec<Option<f64>>) {
    let frames = train.iter().map(|e| e.frames.len()).sum();
    let Some(dims) = train
        .iter()
        .flat_map(|e| &e.frames)
        .find_map(|f| f.kinematic_state.as_ref().map(Vec::len))
    else {
        if params.effort {
            notes.push(
                "no kinematic novelty (e_k): [pipeline.kinematics] effort = true, but no \
                 training frame's joint states carry one effort per joint"
                    .into(),
            );
        }
        return (None, vec![None; frames]);
    };
    let states = robot_states(train);
    let rows: Vec<&[f32]> = states.iter().flatten().map(Vec::as_slice).collect();
    let scale = params.scale(&rows, dims);
    let e_k: Vec<Option<f64>> = novelty::leave_one_episode_out(&states, dims, scale.as_deref())
        .into_iter()
        .flatten()
        .map(|d| d.is_finite().then_some(d))
        .collect();
    if e_k.iter().all(Option::is_none) {
        notes.push(
            "no kinematic novelty (e_k): it needs robot states from at least two training \
             episodes"
                .into(),
        );
        return (None, vec![None; frames]);
    }
    (StateReference::fit(&states, dims, scale), e_k)
}

/// The kinematic novelty's side of a revision: the nominal episodes' robot states join
/// the reference of `revised` (a robot doing what an operator judged nominal is then not
/// novel), and each episode's `e_k` is measured again against the old reference and the
/// *other* nominal episodes' states (as a held-out episode would be). Returns each
/// episode's frames' `e_k` (as scored when the calibration has no reference or the
/// frames no state).
pub fn revise(
    calibration: &Calibration,
    revised: &mut Calibration,
    nominal: &[EpisodeScores],
    notes: &mut Vec<String>,
) -> Vec<Vec<Option<f64>>> {
    let as_scored: Vec<Vec<Option<f64>>> = nominal
        .iter()
        .map(|e| {
            e.frames
                .iter()
                .map(|f| f.values[Detector::Kinematics])
                .collect()
        })
        .collect();
    let Some(reference) = calibration.thresholds.kinematics.as_ref() else {
        return as_scored;
    };
    let states = robot_states(nominal);
    let dims = reference.dims();
    if !states.iter().flatten().any(|s| s.len() == dims) {
        return as_scored;
    }
    let Some(learned) = reference.extended(&states) else {
        return as_scored;
    };
    let e_k = states
        .iter()
        .enumerate()
        .map(|(i, episode)| {
            let others: Vec<Vec<Vec<f32>>> = states
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != i)
                .map(|(_, e)| e.clone())
                .collect();
            let against = reference.extended(&others);
            episode
                .iter()
                .zip(&as_scored[i])
                .map(|(s, &scored)| match &against {
                    Some(r) if s.len() == dims => r.distance(s),
                    _ => scored,
                })
                .collect()
        })
        .collect();
    notes.push(format!(
        "the kinematic novelty's nominal states: {} -> {} (these episodes' robot states \
         join them)",
        reference.len(),
        learned.len()
    ));
    revised.thresholds.kinematics = Some(learned);
    e_k
}

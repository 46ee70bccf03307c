//! A session's joint-state buffer: samples grouped by their name lists (one group per
//! publisher), interpolated to image stamps as offline scoring does, trimmed as images
//! are released. Efforts are kept when a sample carries one finite effort per name; an
//! image has efforts when every group's samples around its stamp had them.

use super::state::FrameJoints;
use vamos_core::episode::{interpolate_optional, interpolate_rows};

/// Longest joint name accepted, bytes.
const MAX_JOINT_NAME: usize = 256;

/// Why a joint state does not go into the buffer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum JointRefused {
    /// Names and positions differ in number.
    #[error("joint state has {names} names and {positions} positions")]
    Lengths {
        /// Names given.
        names: usize,
        /// Positions given.
        positions: usize,
    },
    /// No joint at all.
    #[error("joint state without joints")]
    Empty,
    /// A NaN or infinite position.
    #[error("joint {joint:?} has a non-finite position")]
    NotFinite {
        /// The joint.
        joint: String,
    },
    /// A name over [`MAX_JOINT_NAME`] bytes.
    #[error("joint name of {bytes} bytes (at most {MAX_JOINT_NAME}): {start:?}...")]
    LongName {
        /// Its length, bytes.
        bytes: usize,
        /// Its first 32 characters.
        start: String,
    },
    /// More name lists than a session keeps.
    #[error("more than {MAX_GROUPS} distinct joint-name lists")]
    TooManyLists,
    /// A stamp not after the previous one of its list.
    #[error("joint state stamp {stamp_ns} ns is not after the previous one ({last_ns} ns)")]
    StampBack {
        /// The stamp, nanoseconds.
        stamp_ns: i64,
        /// The previous one, nanoseconds.
        last_ns: i64,
    },
}

/// Most distinct joint-name lists (publishers) a session keeps.
const MAX_GROUPS: usize = 16;

/// Joint samples of one set of names (one publisher), stamps ascending.
struct JointGroup {
    names: Vec<String>,
    stamps_ns: Vec<i64>,
    rows: Vec<f64>,
    /// Efforts, parallel to `rows` (zeros for a sample without).
    efforts: Vec<f64>,
    /// Whether each sample carried efforts.
    has_efforts: Vec<bool>,
}

/// Joint states of a session, grouped by their name lists.
#[derive(Default)]
pub struct JointBuffer {
    groups: Vec<JointGroup>,
}

impl JointBuffer {
    pub(crate) fn newest_ns(&self) -> Option<i64> {
        self.groups
            .iter()
            .filter_map(|g| g.stamps_ns.last().copied())
            .min()
    }

    /// Bytes of the samples and names held, for the session's cap and the server's
    /// budget (the vectors' spare capacity, at most as much again, is not counted).
    pub(crate) fn bytes(&self) -> u64 {
        self.groups
            .iter()
            .map(|g| {
                9 * g.stamps_ns.len()
                    + 8 * (g.rows.len() + g.efforts.len())
                    + g.names.iter().map(|n| n.len() + 24).sum::<usize>()
            })
            .sum::<usize>() as u64
    }

    /// Bytes a push of `names` would add at most (before any growth of capacity).
    pub(crate) fn push_cost(&self, names: &[String]) -> u64 {
        // Every sample keeps a row of efforts, zeros when it has none.
        let row = 16 * names.len() + 9;
        if self.groups.iter().any(|g| g.names == names) {
            row as u64
        } else {
            (row + names.iter().map(|n| n.len() + 24).sum::<usize>()) as u64
        }
    }

    /// Adds a sample; refuses (with the reason) a sample that does not fit the buffer.
    pub fn push(
        &mut self,
        stamp_ns: i64,
        names: Vec<String>,
        positions: Vec<f64>,
        efforts: Vec<f64>,
    ) -> Result<(), JointRefused> {
        if names.len() != positions.len() {
            return Err(JointRefused::Lengths {
                names: names.len(),
                positions: positions.len(),
            });
        }
        if names.is_empty() {
            return Err(JointRefused::Empty);
        }
        if let Some(bad) = names.iter().zip(&positions).find(|(_, p)| !p.is_finite()) {
            return Err(JointRefused::NotFinite {
                joint: bad.0.clone(),
            });
        }
        if let Some(long) = names.iter().find(|n| n.len() > MAX_JOINT_NAME) {
            return Err(JointRefused::LongName {
                bytes: long.len(),
                start: long.chars().take(32).collect(),
            });
        }
        let group = match self.groups.iter_mut().position(|g| g.names == names) {
            Some(i) => &mut self.groups[i],
            None => {
                if self.groups.len() >= MAX_GROUPS {
                    return Err(JointRefused::TooManyLists);
                }
                self.groups.push(JointGroup {
                    names,
                    stamps_ns: Vec::new(),
                    rows: Vec::new(),
                    efforts: Vec::new(),
                    has_efforts: Vec::new(),
                });
                let last = self.groups.len() - 1;
                &mut self.groups[last]
            }
        };
        if let Some(&last) = group.stamps_ns.last()
            && stamp_ns <= last
        {
            return Err(JointRefused::StampBack {
                stamp_ns,
                last_ns: last,
            });
        }
        let has = efforts.len() == positions.len() && efforts.iter().all(|e| e.is_finite());
        group.stamps_ns.push(stamp_ns);
        group.has_efforts.push(has);
        if has {
            group.efforts.extend(efforts);
        } else {
            group
                .efforts
                .extend(std::iter::repeat_n(0.0, positions.len()));
        }
        group.rows.extend(positions);
        Ok(())
    }

    /// The joint states at `stamp_ns`: each group interpolated (nearest outside its span),
    /// names concatenated.
    pub fn at(&self, stamp_ns: i64) -> Option<FrameJoints> {
        if self.groups.is_empty() {
            return None;
        }
        let mut names = Vec::new();
        let mut positions = Vec::new();
        let mut efforts = Vec::new();
        let mut all_efforts = true;
        for g in &self.groups {
            let n = g.names.len();
            let s = interpolate_rows(&g.stamps_ns, &g.rows, n, stamp_ns);
            names.extend(g.names.iter().cloned());
            positions.extend(s.positions);
            if all_efforts {
                let e = interpolate_optional(&g.stamps_ns, &g.efforts, &g.has_efforts, n, stamp_ns);
                all_efforts = !e.is_empty();
                efforts.extend(e);
            }
        }
        if !all_efforts {
            efforts.clear();
        }
        Some(FrameJoints {
            names,
            positions,
            efforts,
        })
    }

    /// Forgets samples that can no longer be the neighbours of an image at or after
    /// `stamp_ns` (keeps the last one before it).
    pub fn trim_before(&mut self, stamp_ns: i64) {
        for g in &mut self.groups {
            let keep_from = g
                .stamps_ns
                .partition_point(|&t| t < stamp_ns)
                .saturating_sub(1);
            if keep_from > 0 {
                let n = g.names.len();
                g.stamps_ns.drain(..keep_from);
                g.has_efforts.drain(..keep_from);
                g.rows.drain(..keep_from * n);
                g.efforts.drain(..keep_from * n);
                // A burst must not pin its capacity for the session's life.
                if g.stamps_ns.capacity() > 4 * g.stamps_ns.len().max(64) {
                    g.stamps_ns.shrink_to(2 * g.stamps_ns.len());
                    g.has_efforts.shrink_to(2 * g.has_efforts.len());
                    g.rows.shrink_to(2 * g.rows.len());
                    g.efforts.shrink_to(2 * g.efforts.len());
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn joint_buffer_interpolates_per_group_and_refuses_bad_samples() {
        let mut b = JointBuffer::default();
        let arm = vec!["a".to_string(), "b".to_string()];
        let head = vec!["h".to_string()];
        b.push(0, arm.clone(), vec![0.0, 10.0], vec![]).unwrap();
        b.push(100, arm.clone(), vec![1.0, 20.0], vec![]).unwrap();
        b.push(50, head.clone(), vec![5.0], vec![]).unwrap();
        assert_eq!(b.newest_ns(), Some(50));
        let j = b.at(25).unwrap();
        assert_eq!(j.names, vec!["a", "b", "h"]);
        assert_eq!(j.positions, vec![0.25, 12.5, 5.0]);
        assert!(j.efforts.is_empty());
        assert!(b.push(100, arm.clone(), vec![0.0, 0.0], vec![]).is_err());
        assert!(
            b.push(200, arm.clone(), vec![f64::NAN, 0.0], vec![])
                .is_err()
        );
        assert!(b.push(200, arm.clone(), vec![0.0], vec![]).is_err());
        b.push(200, arm.clone(), vec![2.0, 30.0], vec![]).unwrap();
        b.trim_before(150);
        // The sample before 150 (t = 100) stays as the left neighbour.
        assert_eq!(b.groups[0].stamps_ns, vec![100, 200]);
        assert_eq!(b.at(150).unwrap().positions[..2], [1.5, 25.0]);
    }

    #[test]
    fn efforts_are_interpolated_when_every_sample_used_has_them() {
        let mut b = JointBuffer::default();
        let arm = vec!["a".to_string(), "b".to_string()];
        let before = b.bytes();
        let cost = b.push_cost(&arm);
        b.push(0, arm.clone(), vec![0.0, 0.0], vec![2.0, -4.0])
            .unwrap();
        assert!(b.bytes() - before <= cost, "the charge covers the sample");
        b.push(100, arm.clone(), vec![1.0, 1.0], vec![4.0, -8.0])
            .unwrap();
        // One effort short, then a NaN: positions kept, efforts not.
        b.push(200, arm.clone(), vec![2.0, 2.0], vec![1.0]).unwrap();
        b.push(300, arm.clone(), vec![3.0, 3.0], vec![1.0, f64::NAN])
            .unwrap();
        assert_eq!(b.at(50).unwrap().efforts, vec![3.0, -6.0]);
        assert!(b.at(150).unwrap().efforts.is_empty());
        assert!(b.at(250).unwrap().efforts.is_empty());
        assert_eq!(b.at(250).unwrap().positions, vec![2.5, 2.5]);
        // A second publisher without efforts: no frame has a partial effort vector.
        b.push(0, vec!["h".to_string()], vec![0.5], vec![]).unwrap();
        assert!(b.at(50).unwrap().efforts.is_empty());
    }
}

//! Joint states recorded at their own rate, interpolated to image stamps.
//!
//! `joints.csv` (beside the images of a folder episode): a header `stamp_ns,NAME,NAME,...`
//! and one row of positions per stamp, stamps strictly increasing. [`JointTrack::at`]
//! interpolates linearly between the two samples around a stamp, takes the nearest sample
//! outside the recorded span, and reports how far the nearest sample is so callers can
//! flag gaps.

use super::folder::EpisodeError;
use std::path::Path;

/// A recorded joint-state stream.
#[derive(Debug, Clone, PartialEq)]
pub struct JointTrack {
    /// Joint names (column order).
    pub names: Vec<String>,
    stamps_ns: Vec<i64>,
    /// Row-major `[stamps, names]`.
    positions: Vec<f64>,
}

/// Joint positions at one stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct JointSample {
    /// Positions, in [`JointTrack::names`] order.
    pub positions: Vec<f64>,
    /// Distance to the nearest recorded sample, nanoseconds (0 on a sample).
    pub gap_ns: i64,
    /// Whether the stamp lies outside the recorded span (nearest sample used).
    pub extrapolated: bool,
}

impl JointTrack {
    /// Reads `joints.csv`.
    pub fn read_csv(path: &Path) -> Result<Self, EpisodeError> {
        let text = std::fs::read_to_string(path).map_err(|e| EpisodeError::Io {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Self::parse_csv(&text, &path.display().to_string())
    }

    /// Parses the CSV text (`label` names it in errors).
    pub fn parse_csv(text: &str, label: &str) -> Result<Self, EpisodeError> {
        let bad = |line: usize, reason: String| EpisodeError::BadIndex {
            path: label.to_string(),
            line,
            reason,
        };
        let mut lines = text.lines().enumerate();
        let header = lines.next().map(|(_, h)| h).unwrap_or_default();
        let mut cols = header.split(',').map(str::trim);
        if cols.next() != Some("stamp_ns") {
            return Err(bad(1, "the header must start with `stamp_ns`".into()));
        }
        let names: Vec<String> = cols.map(String::from).collect();
        if names.is_empty() || names.iter().any(String::is_empty) {
            return Err(bad(
                1,
                "the header needs joint names after `stamp_ns`".into(),
            ));
        }
        let mut stamps_ns = Vec::new();
        let mut positions = Vec::new();
        for (i, line) in lines {
            let line_no = i + 1;
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            if fields.len() != names.len() + 1 {
                return Err(bad(
                    line_no,
                    format!("{} fields, expected {}", fields.len(), names.len() + 1),
                ));
            }
            let stamp: i64 = fields[0]
                .parse()
                .map_err(|_| bad(line_no, format!("stamp {:?} is not an integer", fields[0])))?;
            if stamps_ns.last().is_some_and(|&p| stamp <= p) {
                return Err(bad(line_no, format!("stamp {stamp} does not increase")));
            }
            for (name, f) in names.iter().zip(&fields[1..]) {
                let v: f64 = f
                    .parse()
                    .map_err(|_| bad(line_no, format!("{name}: {f:?} is not a number")))?;
                if !v.is_finite() {
                    return Err(bad(line_no, format!("{name}: {v} is not finite")));
                }
                positions.push(v);
            }
            stamps_ns.push(stamp);
        }
        if stamps_ns.is_empty() {
            return Err(bad(2, "no samples".into()));
        }
        Ok(Self {
            names,
            stamps_ns,
            positions,
        })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.stamps_ns.len()
    }

    /// True when there are no samples (never, for a parsed track).
    pub fn is_empty(&self) -> bool {
        self.stamps_ns.is_empty()
    }

    /// The positions at `stamp_ns`.
    pub fn at(&self, stamp_ns: i64) -> JointSample {
        interpolate_rows(&self.stamps_ns, &self.positions, self.names.len(), stamp_ns)
    }
}

/// Interpolates row-major samples (`rows`: `stamps_ns.len()` rows of `n` values, stamps
/// ascending, at least one) to `stamp_ns`: linear between the two samples around it, the
/// nearest sample outside the span; `gap_ns` is the distance to the nearest sample.
pub fn interpolate_rows(stamps_ns: &[i64], rows: &[f64], n: usize, stamp_ns: i64) -> JointSample {
    let s = stamps_ns;
    let row = |i: usize| &rows[i * n..(i + 1) * n];
    if s.is_empty() {
        return JointSample {
            positions: Vec::new(),
            gap_ns: i64::MAX,
            extrapolated: true,
        };
    }
    let after = s.partition_point(|&t| t < stamp_ns);
    if after == 0 || after == s.len() {
        let i = if after == 0 { 0 } else { s.len() - 1 };
        return JointSample {
            positions: row(i).to_vec(),
            gap_ns: s[i].abs_diff(stamp_ns).min(i64::MAX as u64) as i64,
            extrapolated: s[i] != stamp_ns,
        };
    }
    let (t0, t1) = (s[after - 1], s[after]);
    if t1 == stamp_ns {
        // A sample at the stamp: its positions exactly (interpolating would round).
        return JointSample {
            positions: row(after).to_vec(),
            gap_ns: 0,
            extrapolated: false,
        };
    }
    let w = (stamp_ns - t0) as f64 / (t1 - t0) as f64;
    let positions = row(after - 1)
        .iter()
        .zip(row(after))
        .map(|(a, b)| a + w * (b - a))
        .collect();
    JointSample {
        positions,
        gap_ns: (stamp_ns - t0).min(t1 - stamp_ns),
        extrapolated: false,
    }
}

/// [`interpolate_rows`] of an optional field (velocities, efforts) that each sample
/// carries or not (`has`, one flag per stamp): the interpolated values when every sample
/// used (the two around `stamp_ns`, or the nearest outside the span) carries it, else
/// empty.
pub fn interpolate_optional(
    stamps_ns: &[i64],
    rows: &[f64],
    has: &[bool],
    n: usize,
    stamp_ns: i64,
) -> Vec<f64> {
    if stamps_ns.is_empty() {
        return Vec::new();
    }
    let after = stamps_ns.partition_point(|&t| t < stamp_ns);
    let used = [after.saturating_sub(1), after.min(stamps_ns.len() - 1)];
    if used.iter().all(|&i| has.get(i) == Some(&true)) {
        interpolate_rows(stamps_ns, rows, n, stamp_ns).positions
    } else {
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolates_inside_and_holds_outside() {
        let t = JointTrack::parse_csv("stamp_ns,a,b\n100,0.0,1.0\n200,1.0,3.0\n", "t").unwrap();
        let s = t.at(125);
        assert_eq!(s.positions, vec![0.25, 1.5]);
        assert_eq!((s.gap_ns, s.extrapolated), (25, false));
        let s = t.at(200);
        assert_eq!(
            (s.positions.clone(), s.gap_ns, s.extrapolated),
            (vec![1.0, 3.0], 0, false)
        );
        let s = t.at(50);
        assert_eq!(
            (s.positions.clone(), s.gap_ns, s.extrapolated),
            (vec![0.0, 1.0], 50, true)
        );
        let s = t.at(260);
        assert_eq!(
            (s.positions.clone(), s.gap_ns, s.extrapolated),
            (vec![1.0, 3.0], 60, true)
        );
    }

    #[test]
    fn malformed_csv_names_the_line() {
        for (text, line) in [
            ("time,a\n1,0\n", 1),
            ("stamp_ns\n1\n", 1),
            ("stamp_ns,a\n1,0\n1,1\n", 3),
            ("stamp_ns,a\n1,x\n", 2),
            ("stamp_ns,a\n1,NaN\n", 2),
            ("stamp_ns,a,b\n1,0\n", 2),
            ("stamp_ns,a\n", 2),
        ] {
            match JointTrack::parse_csv(text, "j") {
                Err(EpisodeError::BadIndex { line: l, .. }) => assert_eq!(l, line, "{text}"),
                other => panic!("{text}: {other:?}"),
            }
        }
    }
}

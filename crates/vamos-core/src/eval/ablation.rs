//! The paper's ablation table: flow variants (rows) x detector combinations (columns),
//! each cell an (AUC-ROC, AUC-PR) pair, written as markdown like REFERENCE.md's table.

use serde::{Deserialize, Serialize};

/// A column of the ablation table: which detectors feed the fused score.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FusionLevel {
    /// Optical-flow prediction error e_o alone.
    FlowOnly,
    /// e_o plus the body-motion detector e_b.
    FlowBody,
    /// e_o plus the body- and camera-motion detectors.
    FlowBodyCamera,
}

impl FusionLevel {
    /// All columns in table order.
    pub const ALL: [FusionLevel; 3] = [
        FusionLevel::FlowOnly,
        FusionLevel::FlowBody,
        FusionLevel::FlowBodyCamera,
    ];

    /// The column header, as in the paper.
    pub fn header(self) -> &'static str {
        match self {
            FusionLevel::FlowOnly => "OF only",
            FusionLevel::FlowBody => "OF + body",
            FusionLevel::FlowBodyCamera => "OF + body + camera",
        }
    }

    fn index(self) -> usize {
        match self {
            FusionLevel::FlowOnly => 0,
            FusionLevel::FlowBody => 1,
            FusionLevel::FlowBodyCamera => 2,
        }
    }
}

/// An (AUC-ROC, AUC-PR) pair; `None` where a class was absent.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct AucPair {
    /// Area under the ROC curve.
    pub auc_roc: Option<f64>,
    /// Average precision.
    pub auc_pr: Option<f64>,
}

impl AucPair {
    fn cell(&self) -> String {
        let f = |v: Option<f64>| v.map_or_else(|| "n/a".to_string(), |v| format!("{v:.3}"));
        format!("{} / {}", f(self.auc_roc), f(self.auc_pr))
    }
}

/// One row: a flow variant with its three cells and, optionally, the paper's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AblationRow {
    /// Flow variant label as shown in the table (e.g. "masked + registered").
    pub variant: String,
    /// Measured cells, by [`FusionLevel::ALL`] order; `None` = not run.
    pub cells: [Option<AucPair>; 3],
    /// The paper's cells for this variant, if known.
    pub paper: Option<[AucPair; 3]>,
    /// Why the row's cells were not measured (e.g. "no model"); shown in place of them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_run: Option<String>,
}

/// The ablation table, rows in insertion order.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AblationTable {
    /// The rows.
    pub rows: Vec<AblationRow>,
}

/// The paper's Table (REFERENCE.md), A = 5, B = 4, M = 10.
const PAPER: [(&str, [(f64, f64); 3]); 4] = [
    ("plain", [(0.740, 0.380), (0.741, 0.387), (0.792, 0.489)]),
    (
        "registered",
        [(0.716, 0.353), (0.716, 0.362), (0.773, 0.466)],
    ),
    ("masked", [(0.752, 0.467), (0.752, 0.464), (0.804, 0.549)]),
    (
        "masked + registered",
        [(0.727, 0.413), (0.727, 0.415), (0.779, 0.509)],
    ),
];

/// Lower-case letters and digits only: "Masked+Registered", "masked_registered" and
/// "masked + registered" all compare equal.
fn normalise(label: &str) -> String {
    label
        .chars()
        .filter(|c| c.is_ascii_alphanumeric())
        .map(|c| c.to_ascii_lowercase())
        .collect()
}

impl AblationTable {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// Record a cell, adding the variant's row on first use. Variant labels are matched
    /// ignoring case, spaces and punctuation.
    pub fn set(&mut self, variant: &str, level: FusionLevel, value: AucPair) {
        self.row_mut(variant).cells[level.index()] = Some(value);
    }

    /// Record that a variant's row was not run and why (`reason`, e.g. "no model"): the
    /// row is kept, its unmeasured cells say `reason`.
    pub fn set_not_run(&mut self, variant: &str, reason: &str) {
        self.row_mut(variant).not_run = Some(reason.to_string());
    }

    /// The variant's row, added on first use.
    fn row_mut(&mut self, variant: &str) -> &mut AblationRow {
        let key = normalise(variant);
        let i = match self.rows.iter().position(|r| normalise(&r.variant) == key) {
            Some(i) => i,
            None => {
                self.rows.push(AblationRow {
                    variant: variant.to_string(),
                    cells: [None; 3],
                    paper: None,
                    not_run: None,
                });
                self.rows.len() - 1
            }
        };
        &mut self.rows[i]
    }

    /// The measured cell, if recorded.
    pub fn get(&self, variant: &str, level: FusionLevel) -> Option<AucPair> {
        let key = normalise(variant);
        self.rows
            .iter()
            .find(|r| normalise(&r.variant) == key)
            .and_then(|r| r.cells[level.index()])
    }

    /// Attach the paper's figures to the rows whose variant the paper has (plain,
    /// registered, masked, masked + registered).
    pub fn with_paper_reference(mut self) -> Self {
        for row in &mut self.rows {
            let key = normalise(&row.variant);
            if let Some((_, cells)) = PAPER.iter().find(|(name, _)| normalise(name) == key) {
                row.paper = Some(cells.map(|(roc, pr)| AucPair {
                    auc_roc: Some(roc),
                    auc_pr: Some(pr),
                }));
            }
        }
        self
    }

    /// The table in markdown, laid out like REFERENCE.md's: one row per variant, cells
    /// "AUC-ROC / AUC-PR" to three decimals, "-" where not run (the row's reason, e.g.
    /// "no model", when it has one); where paper figures are attached, each cell adds them
    /// in parentheses.
    pub fn to_markdown(&self) -> String {
        let mut out = String::from("| input flow variant |");
        for level in FusionLevel::ALL {
            out.push_str(&format!(" {} |", level.header()));
        }
        out.push_str("\n|---|---|---|---|\n");
        for row in &self.rows {
            out.push_str(&format!("| {} |", row.variant));
            for (i, cell) in row.cells.iter().enumerate() {
                let ours = match (cell, &row.not_run) {
                    (Some(c), _) => c.cell(),
                    (None, Some(reason)) => reason.clone(),
                    (None, None) => "-".to_string(),
                };
                match &row.paper {
                    Some(paper) => out.push_str(&format!(" {ours} (paper {}) |", paper[i].cell())),
                    None => out.push_str(&format!(" {ours} |")),
                }
            }
            out.push('\n');
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_layout() {
        let mut t = AblationTable::new();
        let pair = |roc, pr| AucPair {
            auc_roc: Some(roc),
            auc_pr: Some(pr),
        };
        t.set("masked", FusionLevel::FlowOnly, pair(0.75, 0.4567));
        t.set("Masked", FusionLevel::FlowBodyCamera, pair(0.81, 0.55));
        t.set("mine", FusionLevel::FlowBody, AucPair::default());
        assert_eq!(t.rows.len(), 2);
        assert_eq!(
            t.get("MASKED", FusionLevel::FlowOnly),
            Some(pair(0.75, 0.4567))
        );
        assert_eq!(
            t.to_markdown(),
            "| input flow variant | OF only | OF + body | OF + body + camera |\n\
             |---|---|---|---|\n\
             | masked | 0.750 / 0.457 | - | 0.810 / 0.550 |\n\
             | mine | - | n/a / n/a | - |\n"
        );
        let md = t.with_paper_reference().to_markdown();
        assert!(
            md.contains(
                "| masked | 0.750 / 0.457 (paper 0.752 / 0.467) | - (paper 0.752 / 0.464) |"
            ),
            "{md}"
        );
        assert!(md.contains("| mine | - | n/a / n/a | - |"), "{md}");
    }

    #[test]
    fn a_variant_not_run_keeps_its_row_with_the_reason() {
        let mut t = AblationTable::new();
        t.set_not_run("registered", "no model");
        t.set(
            "masked",
            FusionLevel::FlowOnly,
            AucPair {
                auc_roc: Some(0.5),
                auc_pr: Some(0.25),
            },
        );
        assert_eq!(t.rows.len(), 2);
        assert_eq!(t.get("registered", FusionLevel::FlowOnly), None);
        let md = t.with_paper_reference().to_markdown();
        assert!(
            md.contains(
                "| registered | no model (paper 0.716 / 0.353) | no model (paper 0.716 / 0.362) \
                 | no model (paper 0.773 / 0.466) |"
            ),
            "{md}"
        );
        assert!(md.contains("| masked | 0.500 / 0.250 (paper"), "{md}");
    }

    #[test]
    fn paper_rows_match_reference_md() {
        let mut t = AblationTable::new();
        for (name, _) in PAPER {
            t.set(name, FusionLevel::FlowOnly, AucPair::default());
        }
        let t = t.with_paper_reference();
        let p = t.rows[3].paper.unwrap();
        assert_eq!(t.rows[3].variant, "masked + registered");
        assert_eq!((p[2].auc_roc, p[2].auc_pr), (Some(0.779), Some(0.509)));
        assert_eq!(t.rows[0].paper.unwrap()[0].auc_roc, Some(0.740));
    }
}

//! Profiles: what binds a stored robot, a camera, pipeline parameters, a stored model and
//! thresholds; their calibrations; resolution into a [`Profile`] ready to load.

use super::files::{check_name, now_unix_s, write_json};
use super::types::ProfileRecord;
use super::{
    CALIBRATION_FILE, MODEL, PROFILE, PROFILE_FILE, ProfileEntry, ProfileInfo, ProfileSpec, ROBOT,
    ResolvedModel, ResolvedProfile, State, Store, StoreError, ThresholdsPatch, files,
};
use vamos_core::pipeline::{Calibration, Profile, ProfileFile, ThresholdOverrides};
use vamos_vision::flow::FlowParams;

impl ProfileEntry {
    fn info(&self) -> ProfileInfo {
        let r = &self.record;
        let o = &r.spec.thresholds;
        let alarm = o.alarm_threshold(self.calibration.as_ref(), r.spec.alarm);
        ProfileInfo {
            name: r.name.clone(),
            spec: r.spec.clone(),
            calibration: self.calibration.clone(),
            thresholds: o.thresholds(self.calibration.as_ref()),
            alarm_threshold: alarm.is_finite().then_some(alarm),
            created_unix_s: r.created_unix_s,
            updated_unix_s: r.updated_unix_s,
            problem: self
                .calibration_problem
                .as_ref()
                .map(|p| format!("calibration: {p}")),
        }
    }
}

fn check_overrides(o: &ThresholdOverrides) -> Result<(), StoreError> {
    match o.non_finite() {
        Some((key, value)) => Err(StoreError::invalid(format!(
            "threshold {key} = {value} is not a finite number"
        ))),
        None => Ok(()),
    }
}

/// Refuses a calibration with a non-finite number where JSON could not keep it.
pub(super) fn check_calibration(c: &Calibration) -> Result<(), StoreError> {
    let mut values = vec![
        ("thresholds.e_c", c.thresholds.e_c),
        ("thresholds.e_b", c.thresholds.e_b),
        ("score_max", Some(c.score_max)),
    ];
    if let Some(k) = &c.conformal {
        values.push(("conformal.threshold", Some(k.threshold)));
        values.push(("conformal.order_statistic", Some(k.order_statistic)));
    }
    for (key, value) in values {
        if let Some(v) = value.filter(|v| !v.is_finite()) {
            return Err(StoreError::invalid(format!(
                "calibration {key} = {v} is not a finite number"
            )));
        }
    }
    Ok(())
}

impl State {
    /// Checks what a spec refers to exists and is servable, and its own values.
    fn check_spec(&self, spec: &ProfileSpec) -> Result<(), StoreError> {
        if let Some(robot) = &spec.robot {
            check_name(robot)?;
            Store::check_quarantine(self, ROBOT, robot)?;
            if !self.robots.contains_key(robot) {
                return Err(StoreError::NotFound {
                    kind: ROBOT,
                    name: robot.clone(),
                });
            }
            if spec.camera.is_none() {
                return Err(StoreError::invalid(
                    "a profile with a robot needs a camera (its URDF link and intrinsics)",
                ));
            }
        }
        if let Some(m) = &spec.model {
            check_name(&m.name)?;
            Store::check_quarantine(self, MODEL, &m.name)?;
            let entry = self
                .models
                .get(&m.name)
                .ok_or_else(|| StoreError::NotFound {
                    kind: MODEL,
                    name: m.name.clone(),
                })?;
            match m.version.or(entry.index.active) {
                Some(v) if entry.index.versions.iter().any(|s| s.version == v) => {}
                Some(v) => return Err(super::models::version_not_found(&m.name, v)),
                None => {
                    return Err(StoreError::invalid(format!(
                        "model {} has no active version to follow",
                        m.name
                    )));
                }
            }
        }
        if let Some(preset) = &spec.flow_preset {
            FlowParams::preset(preset).map_err(|e| StoreError::invalid(e.to_string()))?;
        }
        if let Some(pipeline) = &spec.pipeline {
            pipeline.check_limits().map_err(StoreError::invalid)?;
        }
        if let Some(d) = &spec.alarm_events {
            d.check().map_err(|e| StoreError::invalid(e.to_string()))?;
        }
        check_overrides(&spec.thresholds)
    }
}

impl Store {
    /// Creates or replaces profile `name` after checking that the robot, model and
    /// pinned version it names exist, that a robot comes with a camera, and that the
    /// flow preset and thresholds are valid. A replaced profile keeps its calibration.
    pub fn put_profile(&self, name: &str, spec: ProfileSpec) -> Result<ProfileInfo, StoreError> {
        self.check_writable()?;
        check_name(name)?;
        let mut st = self.lock();
        Self::check_quarantine(&st, PROFILE, name)?;
        st.check_spec(&spec)?;
        let now = now_unix_s();
        let old = st.profiles.get(name).cloned();
        let record = ProfileRecord {
            name: name.into(),
            created_unix_s: old.as_ref().map_or(now, |o| o.record.created_unix_s),
            updated_unix_s: now,
            spec,
        };
        let entry = self.write_record(old, record)?;
        let info = entry.info();
        st.profiles.insert(name.to_string(), entry);
        tracing::info!(profile = name, "profile stored");
        Ok(info)
    }

    /// Writes a profile's record: in place when it exists, else as a new folder.
    fn write_record(
        &self,
        old: Option<ProfileEntry>,
        record: ProfileRecord,
    ) -> Result<ProfileEntry, StoreError> {
        let tmp = self.tmp_dir();
        let dir = self.profile_dir(&record.name);
        match old {
            Some(mut entry) => {
                write_json(&tmp, &dir.join(PROFILE_FILE), &record)?;
                entry.record = record;
                Ok(entry)
            }
            None => {
                self.create_object_dir(&dir, |staging| {
                    write_json(&tmp, &staging.join(PROFILE_FILE), &record)
                })?;
                Ok(ProfileEntry {
                    record,
                    calibration: None,
                    calibration_problem: None,
                })
            }
        }
    }

    /// Every profile, by name.
    pub fn profiles(&self) -> Vec<ProfileInfo> {
        self.lock()
            .profiles
            .values()
            .map(ProfileEntry::info)
            .collect()
    }

    /// One profile.
    pub fn profile(&self, name: &str) -> Result<ProfileInfo, StoreError> {
        check_name(name)?;
        let st = self.lock();
        Self::check_quarantine(&st, PROFILE, name)?;
        st.profiles
            .get(name)
            .map(ProfileEntry::info)
            .ok_or_else(|| not_found(name))
    }

    /// Deletes profile `name` and its calibration.
    pub fn delete_profile(&self, name: &str) -> Result<(), StoreError> {
        self.check_writable()?;
        check_name(name)?;
        let mut st = self.lock();
        let key = (PROFILE, name.to_string());
        if !st.quarantined.contains_key(&key) && !st.profiles.contains_key(name) {
            return Err(not_found(name));
        }
        files::remove_dir_atomic(&self.tmp_dir(), &self.profile_dir(name))?;
        st.profiles.remove(name);
        st.quarantined.remove(&key);
        tracing::info!(profile = name, "profile deleted");
        Ok(())
    }

    /// Changes the threshold overrides of profile `name` (see [`ThresholdsPatch`]).
    pub fn patch_thresholds(
        &self,
        name: &str,
        patch: ThresholdsPatch,
    ) -> Result<ProfileInfo, StoreError> {
        self.check_writable()?;
        check_name(name)?;
        let mut st = self.lock();
        Self::check_quarantine(&st, PROFILE, name)?;
        let old = st
            .profiles
            .get(name)
            .cloned()
            .ok_or_else(|| not_found(name))?;
        let mut record = old.record.clone();
        record.spec.thresholds = patch.apply(record.spec.thresholds);
        check_overrides(&record.spec.thresholds)?;
        record.updated_unix_s = now_unix_s();
        let entry = self.write_record(Some(old), record)?;
        let info = entry.info();
        st.profiles.insert(name.to_string(), entry);
        tracing::info!(profile = name, "profile thresholds changed");
        Ok(info)
    }

    /// Saves (replaces) the calibration of profile `name`.
    pub fn save_calibration(
        &self,
        name: &str,
        calibration: Calibration,
    ) -> Result<ProfileInfo, StoreError> {
        self.check_writable()?;
        check_name(name)?;
        check_calibration(&calibration)?;
        let mut st = self.lock();
        Self::check_quarantine(&st, PROFILE, name)?;
        if !st.profiles.contains_key(name) {
            return Err(not_found(name));
        }
        write_json(
            &self.tmp_dir(),
            &self.profile_dir(name).join(CALIBRATION_FILE),
            &calibration,
        )?;
        let entry = st.profiles.get_mut(name).ok_or_else(|| not_found(name))?;
        entry.calibration = Some(calibration);
        entry.calibration_problem = None;
        tracing::info!(profile = name, "calibration saved");
        Ok(entry.info())
    }

    /// Profile `name` as a [`Profile`] for [`vamos_core::setup::Setup::from_profile`]: robot
    /// and model are the stored files (the model: the pinned version, else the active
    /// one now), the camera and calibration are filled in, and the threshold overrides
    /// are in `file.thresholds`, so [`Profile::thresholds`] and
    /// [`Profile::alarm_threshold`] give the values in force.
    pub fn resolve_profile(&self, name: &str) -> Result<ResolvedProfile, StoreError> {
        check_name(name)?;
        let st = self.lock();
        Self::check_quarantine(&st, PROFILE, name)?;
        let entry = st.profiles.get(name).ok_or_else(|| not_found(name))?;
        let dir = self.profile_dir(name);
        if let Some(reason) = &entry.calibration_problem {
            return Err(StoreError::Corrupt {
                path: dir.join(CALIBRATION_FILE),
                reason: reason.clone(),
            });
        }
        let spec = &entry.record.spec;
        let robot_path = match &spec.robot {
            Some(r) => {
                Self::check_quarantine(&st, ROBOT, r)?;
                let robot = st.robots.get(r).ok_or_else(|| StoreError::NotFound {
                    kind: ROBOT,
                    name: r.clone(),
                })?;
                let path = self.robot_dir(r).join(robot.meta.file_name());
                if let Some(reason) = &robot.problem {
                    return Err(StoreError::Corrupt {
                        path,
                        reason: reason.clone(),
                    });
                }
                Some(path)
            }
            None => None,
        };
        let model = match &spec.model {
            Some(m) => {
                Self::check_quarantine(&st, MODEL, &m.name)?;
                let me = st.models.get(&m.name).ok_or_else(|| StoreError::NotFound {
                    kind: MODEL,
                    name: m.name.clone(),
                })?;
                let v = self.servable_version(&m.name, me, m.version)?;
                let sha256 = me
                    .index
                    .versions
                    .iter()
                    .find(|s| s.version == v)
                    .map(|s| s.sha256.clone())
                    .unwrap_or_default();
                Some(ResolvedModel {
                    name: m.name.clone(),
                    version: v,
                    sha256,
                })
            }
            None => None,
        };
        let mut warnings = Vec::new();
        if let Some(c) = &entry.calibration {
            let resolved_sha = model.as_ref().map(|m| m.sha256.as_str());
            if c.model_sha256.as_deref() != resolved_sha {
                let made = c.model_sha256.as_deref().unwrap_or("no model");
                let now = model.as_ref().map_or("no model".to_string(), |m| {
                    format!("{}@{}", m.name, m.version)
                });
                warnings.push(format!(
                    "profile {name}: the calibration was made with {made}, the profile now \
                     uses {now}; recalibrate"
                ));
            }
        }
        let file = ProfileFile {
            name: name.into(),
            robot: robot_path,
            // A stored robot is sealed: it reads no package path.
            robot_packages: Vec::new(),
            camera: None,
            model: model.as_ref().map(|m| self.model_file(&m.name, m.version)),
            flow_preset: spec.flow_preset.clone(),
            alarm: spec.alarm,
            pipeline: spec.pipeline.clone(),
            topics: spec.topics.clone(),
            thresholds: spec.thresholds,
            alarm_events: spec.alarm_events,
        };
        Ok(ResolvedProfile {
            profile: Profile {
                path: dir.join(PROFILE_FILE),
                file,
                camera: spec.camera.clone(),
                calibration: entry.calibration.clone(),
                robot_stored: true,
            },
            model,
            robot: spec.robot.clone(),
            warnings,
        })
    }
}

fn not_found(name: &str) -> StoreError {
    StoreError::NotFound {
        kind: PROFILE,
        name: name.into(),
    }
}

//! The per-frame detectors by name, and [`PerDetector`]: one value per detector where
//! structs used to list five fields.
//!
//! [`Detector`] is the one place a detector's names live: its variant, the value's key
//! (`e_c`, the field and topic name every wire format uses), the detector's name
//! (`camera`, what JSON outputs, alarm records and the CLI say) and a plot label.
//! Code that has something for every detector holds a `PerDetector<T>` and iterates it,
//! so adding a detector adds a variant here and its module in `pipeline::detectors`.
//!
//! Serde: a `PerDetector<T>` is a JSON object keyed by [`Detector::key`], every detector
//! present (`PerDetector<Option<f64>>` writes `null` for a value not computed, as the
//! five fields did); reading takes any subset of the keys (absent: `T::default()`) and
//! refuses other keys. [`present`] writes only the `Some` entries of a
//! `PerDetector<Option<T>>` (for statistics that were absent when not fitted).

use serde::de::{MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use std::fmt;
use std::marker::PhantomData;
use std::ops::{Index, IndexMut};

/// The per-frame detectors.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Detector {
    /// Camera-motion error `e_c`: the camera motion expected from the kinematics against
    /// the registered image motion.
    Camera,
    /// Body-motion error `e_b`: the rendered robot's flow against the observed flow.
    Body,
    /// Flow-prediction error `e_o`: the flow predictor's expectation against the observed
    /// flow.
    Flow,
    /// Scene-motion residual `e_r`: the static scene's motion outside the robot.
    Scene,
    /// Kinematic novelty `e_k`: the robot's state against the nominal states.
    Kinematics,
}

impl Detector {
    /// Every detector, in the order [`PerDetector`] keeps them (the order of the
    /// five-field structs and of the wire formats: `e_c`, `e_b`, `e_o`, `e_r`, `e_k`).
    pub const ALL: [Detector; 5] = [
        Detector::Camera,
        Detector::Body,
        Detector::Flow,
        Detector::Scene,
        Detector::Kinematics,
    ];

    /// Number of detectors.
    pub const COUNT: usize = Self::ALL.len();

    /// Its place in [`Self::ALL`].
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The value's key: `e_c`, `e_b`, `e_o`, `e_r`, `e_k` (JSON fields, CSV columns,
    /// scored-bag topics `/vamos/<key>`, proto fields).
    pub const fn key(self) -> &'static str {
        match self {
            Detector::Camera => "e_c",
            Detector::Body => "e_b",
            Detector::Flow => "e_o",
            Detector::Scene => "e_r",
            Detector::Kinematics => "e_k",
        }
    }

    /// The value's topic in a scored bag: `/vamos/<key>`.
    pub const fn topic(self) -> &'static str {
        match self {
            Detector::Camera => "/vamos/e_c",
            Detector::Body => "/vamos/e_b",
            Detector::Flow => "/vamos/e_o",
            Detector::Scene => "/vamos/e_r",
            Detector::Kinematics => "/vamos/e_k",
        }
    }

    /// The detector's name: `camera`, `body`, `flow`, `scene`, `kinematics` (the
    /// `triggered` detector in JSON, alarm records, profile switches).
    pub const fn name(self) -> &'static str {
        match self {
            Detector::Camera => "camera",
            Detector::Body => "body",
            Detector::Flow => "flow",
            Detector::Scene => "scene",
            Detector::Kinematics => "kinematics",
        }
    }

    /// What the value measures and its unit, for plots and layouts.
    pub const fn label(self) -> &'static str {
        match self {
            Detector::Camera => "camera motion, px",
            Detector::Body => "body motion, px",
            Detector::Flow => "flow prediction error",
            Detector::Scene => "scene-motion residual",
            Detector::Kinematics => "kinematic novelty",
        }
    }

    /// The plot title: `e_c: camera motion, px`.
    pub fn title(self) -> String {
        format!("{}: {}", self.key(), self.label())
    }

    /// Whether the detector needs the robot's joint states (and so a robot).
    pub const fn needs_robot(self) -> bool {
        matches!(
            self,
            Detector::Camera | Detector::Body | Detector::Kinematics
        )
    }

    /// The detector of a value key (`e_c`) or a name (`camera`).
    pub fn parse(s: &str) -> Option<Detector> {
        Self::ALL
            .into_iter()
            .find(|d| d.key() == s || d.name() == s)
    }
}

impl fmt::Display for Detector {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One `T` per detector (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct PerDetector<T>([T; Detector::COUNT]);

/// A frame's detector values (`None`: not computed).
pub type DetectorValues = PerDetector<Option<f64>>;

impl<T> PerDetector<T> {
    /// Each detector's value from `f`.
    pub fn from_fn(mut f: impl FnMut(Detector) -> T) -> Self {
        PerDetector(Detector::ALL.map(&mut f))
    }

    /// The values in [`Detector::ALL`] order (the order of the wire formats' five
    /// fields).
    pub const fn from_array(values: [T; Detector::COUNT]) -> Self {
        PerDetector(values)
    }

    /// The values in [`Detector::ALL`] order.
    pub fn into_array(self) -> [T; Detector::COUNT] {
        self.0
    }

    /// `(detector, value)` in [`Detector::ALL`] order.
    pub fn iter(&self) -> impl Iterator<Item = (Detector, &T)> {
        Detector::ALL.into_iter().zip(&self.0)
    }

    /// `(detector, value)` in [`Detector::ALL`] order, mutable.
    pub fn iter_mut(&mut self) -> impl Iterator<Item = (Detector, &mut T)> {
        Detector::ALL.into_iter().zip(&mut self.0)
    }

    /// Each value mapped by `f`.
    pub fn map<U>(&self, mut f: impl FnMut(Detector, &T) -> U) -> PerDetector<U> {
        PerDetector::from_fn(|d| f(d, &self[d]))
    }

    /// Pairs with another map.
    pub fn zip<'a, U>(
        &'a self,
        other: &'a PerDetector<U>,
    ) -> impl Iterator<Item = (Detector, &'a T, &'a U)> {
        self.iter().map(move |(d, t)| (d, t, &other[d]))
    }
}

impl<T: Copy> PerDetector<Option<T>> {
    /// The given detectors' values, the others `None`.
    pub fn of(values: &[(Detector, T)]) -> Self {
        let mut out = PerDetector::from_fn(|_| None);
        for &(d, v) in values {
            out[d] = Some(v);
        }
        out
    }

    /// The detectors that have a value, with it.
    pub fn present(&self) -> impl Iterator<Item = (Detector, T)> + '_ {
        self.iter().filter_map(|(d, v)| v.map(|v| (d, v)))
    }
}

impl<T> Index<Detector> for PerDetector<T> {
    type Output = T;
    fn index(&self, d: Detector) -> &T {
        &self.0[d.index()]
    }
}

impl<T> IndexMut<Detector> for PerDetector<T> {
    fn index_mut(&mut self, d: Detector) -> &mut T {
        &mut self.0[d.index()]
    }
}

impl<T: Serialize> Serialize for PerDetector<T> {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(Detector::COUNT))?;
        for (d, v) in self.iter() {
            map.serialize_entry(d.key(), v)?;
        }
        map.end()
    }
}

impl<'de, T: Deserialize<'de> + Default> Deserialize<'de> for PerDetector<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Keys<T>(PhantomData<T>);
        impl<'de, T: Deserialize<'de> + Default> Visitor<'de> for Keys<T> {
            type Value = PerDetector<T>;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("an object keyed by e_c, e_b, e_o, e_r, e_k")
            }
            fn visit_map<A: MapAccess<'de>>(self, mut access: A) -> Result<Self::Value, A::Error> {
                let mut out = PerDetector::<T>::default();
                while let Some(key) = access.next_key::<String>()? {
                    let Some(d) = Detector::ALL.into_iter().find(|d| d.key() == key) else {
                        return Err(serde::de::Error::unknown_field(&key, &KEYS));
                    };
                    out[d] = access.next_value()?;
                }
                Ok(out)
            }
        }
        deserializer.deserialize_map(Keys(PhantomData))
    }
}

/// The value keys, in order (for serde's messages and schemas).
const KEYS: [&str; Detector::COUNT] = [
    Detector::Camera.key(),
    Detector::Body.key(),
    Detector::Flow.key(),
    Detector::Scene.key(),
    Detector::Kinematics.key(),
];

impl<T: schemars::JsonSchema> schemars::JsonSchema for PerDetector<T> {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        format!("PerDetector_{}", T::schema_name()).into()
    }

    fn json_schema(generator: &mut schemars::SchemaGenerator) -> schemars::Schema {
        let value = generator.subschema_for::<T>();
        let properties: serde_json::Map<String, serde_json::Value> = Detector::ALL
            .iter()
            .map(|d| (d.key().to_string(), value.clone().into()))
            .collect();
        schemars::json_schema!({
            "type": "object",
            "description": "One value per detector, keyed by e_c (camera), e_b (body), e_o (flow), e_r (scene), e_k (kinematics).",
            "properties": properties,
            "additionalProperties": false,
        })
    }
}

/// Serde for a `PerDetector<Option<T>>` that writes only the detectors with a value
/// (`#[serde(with = "present")]`); reading is the map's own.
pub mod present {
    use super::PerDetector;
    use serde::ser::SerializeMap;
    use serde::{Deserialize, Deserializer, Serialize, Serializer};

    /// Writes the `Some` entries.
    pub fn serialize<T: Serialize, S: Serializer>(
        values: &PerDetector<Option<T>>,
        serializer: S,
    ) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(None)?;
        for (d, v) in values.iter() {
            if let Some(v) = v {
                map.serialize_entry(d.key(), v)?;
            }
        }
        map.end()
    }

    /// Reads any subset of the keys.
    pub fn deserialize<'de, T: Deserialize<'de>, D: Deserializer<'de>>(
        deserializer: D,
    ) -> Result<PerDetector<Option<T>>, D::Error> {
        PerDetector::<Option<T>>::deserialize(deserializer)
    }

    /// The same for an optional map (`Option<PerDetector<Option<T>>>`).
    pub mod option {
        use super::PerDetector;
        use serde::{Deserialize, Deserializer, Serialize, Serializer};

        /// Writes `None` as `null`, a map with its `Some` entries.
        pub fn serialize<T: Serialize, S: Serializer>(
            values: &Option<PerDetector<Option<T>>>,
            serializer: S,
        ) -> Result<S::Ok, S::Error> {
            match values {
                Some(v) => super::serialize(v, serializer),
                None => serializer.serialize_none(),
            }
        }

        /// Reads `null` or a map.
        pub fn deserialize<'de, T: Deserialize<'de>, D: Deserializer<'de>>(
            deserializer: D,
        ) -> Result<Option<PerDetector<Option<T>>>, D::Error> {
            Option::<PerDetector<Option<T>>>::deserialize(deserializer)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_keys_and_order_are_one_table() {
        for (i, d) in Detector::ALL.into_iter().enumerate() {
            assert_eq!(d.index(), i);
            assert_eq!(Detector::parse(d.key()), Some(d));
            assert_eq!(Detector::parse(d.name()), Some(d));
            assert_eq!(d.topic(), format!("/vamos/{}", d.key()));
            // The serde name is the detector's name.
            assert_eq!(serde_json::to_value(d).unwrap(), d.name());
        }
        assert_eq!(KEYS, ["e_c", "e_b", "e_o", "e_r", "e_k"]);
        assert_eq!(Detector::parse("e_x"), None);
    }

    #[test]
    fn values_read_and_write_as_the_five_fields() {
        let mut v = DetectorValues::default();
        v[Detector::Camera] = Some(0.5);
        v[Detector::Kinematics] = Some(2.0);
        let json = serde_json::to_value(v).unwrap();
        assert_eq!(
            json,
            serde_json::json!({"e_c": 0.5, "e_b": null, "e_o": null, "e_r": null, "e_k": 2.0})
        );
        let back: DetectorValues = serde_json::from_value(json).unwrap();
        assert_eq!(back, v);
        // A subset reads; other keys are refused with the known ones named.
        let some: DetectorValues = serde_json::from_str(r#"{"e_r": 1.5}"#).unwrap();
        assert_eq!(some.present().collect::<Vec<_>>(), [(Detector::Scene, 1.5)]);
        let err = serde_json::from_str::<DetectorValues>(r#"{"e_q": 1}"#).unwrap_err();
        assert!(err.to_string().contains("e_q") && err.to_string().contains("e_k"));
    }

    #[test]
    fn present_writes_only_the_values_there() {
        #[derive(Serialize, Deserialize, PartialEq, Debug)]
        struct Holder {
            #[serde(with = "present")]
            v: DetectorValues,
        }
        let mut v = DetectorValues::default();
        v[Detector::Body] = Some(3.0);
        let json = serde_json::to_string(&Holder { v }).unwrap();
        assert_eq!(json, r#"{"v":{"e_b":3.0}}"#);
        assert_eq!(serde_json::from_str::<Holder>(&json).unwrap(), Holder { v });
    }
}

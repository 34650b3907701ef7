//! Anatomy parameters: what a gynecologist measures, in clinical units (mm, degrees), with parity
//! presets from `docs/anatomy.md` (values from references.md section 3).

use serde::{Deserialize, Serialize};

use super::error::AnatomyError;

/// Metres per millimetre (the parameters are in mm, the geometry in m).
pub(crate) const MM: f64 = 1e-3;

/// Parity preset: supplies every parameter not given in a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Parity {
    /// Never given birth: smaller corpus, fundal cavity width 27 mm.
    Nulliparous,
    /// Given birth: larger corpus, fundal cavity width 32 mm.
    Parous,
}

/// Which wall a lesion grows from. The cavity is a slit between the anterior and posterior walls;
/// its lateral edges and its fundal line are the lateral and fundal walls.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WallSide {
    /// Anterior wall (+y in the organ frame).
    Anterior,
    /// Posterior wall (-y).
    Posterior,
    /// The patient's left lateral wall (+x); myomas of FIGO type 3-4 only.
    Left,
    /// The patient's right lateral wall (-x); myomas of FIGO type 3-4 only.
    Right,
    /// The fundus, above the cavity's fundal line; myomas of FIGO type 3-4 only.
    Fundal,
    /// Any direction around the cavity axis given by `angle_deg` (0 anterior, 90 left, 180
    /// posterior, 270 right); myomas of FIGO type 3-4 only.
    Oblique,
}

impl WallSide {
    /// +1 for anterior, -1 for posterior (the sign of y inside that wall); `None` for the other
    /// walls, whose lesions do not protrude into the slit.
    pub fn sign(self) -> Option<f64> {
        match self {
            WallSide::Anterior => Some(1.0),
            WallSide::Posterior => Some(-1.0),
            _ => None,
        }
    }
}

/// A myoma (fibroid): an axis-aligned ellipsoid in or on a wall.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MyomaParams {
    /// Wall it grows in.
    pub wall: WallSide,
    /// Offset of its centre from the midline, mm (+ towards the patient's left); anterior,
    /// posterior and fundal walls (ignored for left, right and oblique: the wall fixes x).
    pub x_mm: f64,
    /// Distance of its centre below the fundal end of the cavity, mm (ignored for the fundal
    /// wall, whose myomas lie above the fundal line).
    pub from_fundus_mm: f64,
    /// Direction around the cavity axis for `wall = "oblique"`, degrees (0 anterior, 90 left,
    /// 180 posterior, 270 right).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle_deg: Option<f64>,
    /// Diameters: coronal width (x), antero-posterior thickness (y), longitudinal length (z), mm.
    pub diameters_mm: [f64; 3],
    /// FIGO type 0-4. If given without `depth_mm`, the placement is derived from it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub figo: Option<u8>,
    /// Depth of the centre below the endometrium, mm (negative: the centre lies in the cavity).
    /// If given without `figo`, the FIGO type is derived from it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_mm: Option<f64>,
}

/// Polyp attachment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PolypKind {
    /// Broad base on the endometrium.
    Sessile,
    /// Head on a narrow stalk.
    Pedunculated,
}

/// An endometrial polyp protruding into the cavity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolypParams {
    /// Wall it grows from.
    pub wall: WallSide,
    /// Offset of its base from the midline, mm (+ towards the patient's left).
    pub x_mm: f64,
    /// Distance of its base below the fundal end of the cavity, mm.
    pub from_fundus_mm: f64,
    /// Diameter of its head, mm.
    pub diameter_mm: f64,
    /// Sessile or pedunculated.
    pub kind: PolypKind,
}

/// Mesh resolution and post-processing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MeshParams {
    /// Number of tetrahedra aimed at; the lattice spacing is chosen from it (the result lies
    /// within about 15 % of it).
    pub target_tets: u32,
    /// Sweeps of quality-improving vertex smoothing after meshing (0 = off).
    pub smoothing_sweeps: u32,
}

impl Default for MeshParams {
    fn default() -> Self {
        MeshParams {
            target_tets: 35_000,
            smoothing_sweeps: 3,
        }
    }
}

/// All parameters of a parametric uterus. Lengths in mm, angles in degrees (clinical units; the
/// generator converts to metres).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnatomyParams {
    /// Preset that supplied the defaults.
    pub parity: Parity,
    /// External os to the top of the fundus (serosa), along the axis, mm.
    pub uterine_length_mm: f64,
    /// Largest left-right width of the corpus, mm.
    pub corpus_width_mm: f64,
    /// Largest antero-posterior depth of the corpus, mm.
    pub ap_depth_mm: f64,
    /// Fundal wall: cavity top to the serosa along the axis, mm.
    pub fundal_wall_mm: f64,
    /// Internal os to the fundal end of the cavity, mm.
    pub cavity_length_mm: f64,
    /// Cavity width between the cornua (coronal plane), mm.
    pub fundal_cavity_width_mm: f64,
    /// Angle at each cornu between the fundal line and the lateral cavity wall, degrees.
    pub cornual_angle_deg: f64,
    /// Cavity width at the internal os, mm.
    pub internal_os_width_mm: f64,
    /// Largest antero-posterior gap of the slit cavity at rest, mm.
    pub slit_gap_mm: f64,
    /// Cervix length, external os upwards, mm.
    pub cervix_length_mm: f64,
    /// Cervix outer diameter, mm.
    pub cervix_diameter_mm: f64,
    /// Cervical canal width (coronal) at the external os, mm; the canal is a collapsed slit.
    pub canal_diameter_mm: f64,
    /// Version: rotation of the whole uterus about the external os, degrees (+ anteverted).
    pub version_deg: f64,
    /// Flexion: bend of the corpus against the cervix at the isthmus, degrees (+ anteflexed).
    pub flexion_deg: f64,
    /// Mesh resolution.
    #[serde(default)]
    pub mesh: MeshParams,
    /// Myomas.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub myomas: Vec<MyomaParams>,
    /// Polyps.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub polyps: Vec<PolypParams>,
}

impl Default for AnatomyParams {
    fn default() -> Self {
        AnatomyParams::preset(Parity::Parous)
    }
}

impl AnatomyParams {
    /// Typical values for a parity (references.md section 3; see docs/anatomy.md for the sources
    /// of each number).
    pub fn preset(parity: Parity) -> Self {
        match parity {
            Parity::Nulliparous => AnatomyParams {
                parity,
                uterine_length_mm: 74.0,
                corpus_width_mm: 50.0,
                ap_depth_mm: 41.0,
                fundal_wall_mm: 12.0,
                cavity_length_mm: 33.0,
                fundal_cavity_width_mm: 27.0,
                cornual_angle_deg: 60.0,
                internal_os_width_mm: 5.0,
                slit_gap_mm: 1.5,
                cervix_length_mm: 26.0,
                cervix_diameter_mm: 25.0,
                canal_diameter_mm: 5.0,
                version_deg: 10.0,
                flexion_deg: 20.0,
                mesh: MeshParams::default(),
                myomas: Vec::new(),
                polyps: Vec::new(),
            },
            Parity::Parous => AnatomyParams {
                parity,
                uterine_length_mm: 80.0,
                corpus_width_mm: 52.0,
                ap_depth_mm: 42.0,
                fundal_wall_mm: 13.0,
                cavity_length_mm: 36.0,
                fundal_cavity_width_mm: 32.0,
                cornual_angle_deg: 60.0,
                internal_os_width_mm: 7.0,
                slit_gap_mm: 2.0,
                cervix_length_mm: 28.0,
                cervix_diameter_mm: 28.0,
                canal_diameter_mm: 7.0,
                version_deg: 10.0,
                flexion_deg: 20.0,
                mesh: MeshParams::default(),
                myomas: Vec::new(),
                polyps: Vec::new(),
            },
        }
    }

    /// Parses a TOML parameter file. Keys not given come from the `parity` preset (default
    /// `parous`); unknown keys and wrong types are errors naming the key.
    pub fn from_toml_str(text: &str) -> Result<Self, AnatomyError> {
        let user: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| AnatomyError::Parse(e.to_string()))?;
        let parity = match user.get("parity") {
            None => Parity::Parous,
            Some(toml::Value::String(s)) if s == "parous" => Parity::Parous,
            Some(toml::Value::String(s)) if s == "nulliparous" => Parity::Nulliparous,
            Some(v) => {
                return Err(AnatomyError::Parse(format!(
                    "key `parity` = {v}: expected \"nulliparous\" or \"parous\""
                )))
            }
        };
        let mut merged = toml::Table::try_from(AnatomyParams::preset(parity))
            .map_err(|e| AnatomyError::Parse(format!("internal: preset to TOML: {e}")))?;
        let known_tables = ["mesh", "myomas", "polyps"];
        for (key, value) in user {
            if !merged.contains_key(&key) && !known_tables.contains(&key.as_str()) {
                return Err(AnatomyError::Parse(format!(
                    "unknown key `{key}` (see `hydrometra anatomy --print-defaults` for the keys)"
                )));
            }
            if key == "mesh" {
                if let (Some(toml::Value::Table(base)), toml::Value::Table(over)) =
                    (merged.get_mut("mesh"), &value)
                {
                    for (k, v) in over {
                        base.insert(k.clone(), v.clone());
                    }
                    continue;
                }
            }
            merged.insert(key, value);
        }
        let params: AnatomyParams = merged
            .try_into()
            .map_err(|e: toml::de::Error| AnatomyError::Parse(e.to_string()))?;
        Ok(params)
    }

    /// These parameters as a TOML document (the format `from_toml_str` reads).
    pub fn to_toml_string(&self) -> Result<String, AnatomyError> {
        toml::to_string(self).map_err(|e| AnatomyError::Parse(format!("to TOML: {e}")))
    }

    /// Checks each parameter against its plausible range (wider than references.md's typical
    /// ranges, so that unusual anatomies stay possible). Combinations are checked by the
    /// geometry, which knows the mesh spacing.
    pub fn check_ranges(&self) -> Result<(), AnatomyError> {
        let ranges: [(&str, f64, f64, f64); 14] = [
            ("uterine_length_mm", self.uterine_length_mm, 45.0, 130.0),
            ("corpus_width_mm", self.corpus_width_mm, 30.0, 90.0),
            ("ap_depth_mm", self.ap_depth_mm, 25.0, 80.0),
            ("fundal_wall_mm", self.fundal_wall_mm, 5.0, 25.0),
            ("cavity_length_mm", self.cavity_length_mm, 15.0, 60.0),
            (
                "fundal_cavity_width_mm",
                self.fundal_cavity_width_mm,
                15.0,
                55.0,
            ),
            ("cornual_angle_deg", self.cornual_angle_deg, 30.0, 89.0),
            ("internal_os_width_mm", self.internal_os_width_mm, 3.0, 15.0),
            ("slit_gap_mm", self.slit_gap_mm, 0.3, 4.0),
            ("cervix_length_mm", self.cervix_length_mm, 15.0, 45.0),
            ("cervix_diameter_mm", self.cervix_diameter_mm, 15.0, 40.0),
            ("canal_diameter_mm", self.canal_diameter_mm, 2.0, 12.0),
            ("version_deg", self.version_deg, -90.0, 90.0),
            ("flexion_deg", self.flexion_deg, -90.0, 90.0),
        ];
        for (key, value, lo, hi) in ranges {
            if !(value.is_finite() && value >= lo && value <= hi) {
                return Err(AnatomyError::OutOfRange {
                    key: key.to_string(),
                    value,
                    expected: format!("{lo} ..= {hi}"),
                });
            }
        }
        let t = self.mesh.target_tets;
        if !(2_000..=2_000_000).contains(&t) {
            return Err(AnatomyError::OutOfRange {
                key: "mesh.target_tets".into(),
                value: t as f64,
                expected: "2000 ..= 2000000".into(),
            });
        }
        if self.mesh.smoothing_sweeps > 50 {
            return Err(AnatomyError::OutOfRange {
                key: "mesh.smoothing_sweeps".into(),
                value: self.mesh.smoothing_sweeps as f64,
                expected: "0 ..= 50".into(),
            });
        }
        for (i, m) in self.myomas.iter().enumerate() {
            for (k, d) in m.diameters_mm.iter().enumerate() {
                if !(d.is_finite() && *d >= 3.0 && *d <= 80.0) {
                    return Err(AnatomyError::OutOfRange {
                        key: format!("myomas[{i}].diameters_mm[{k}]"),
                        value: *d,
                        expected: "3 ..= 80".into(),
                    });
                }
            }
            if let Some(f) = m.figo {
                if f > 4 {
                    return Err(AnatomyError::OutOfRange {
                        key: format!("myomas[{i}].figo"),
                        value: f as f64,
                        expected: "0 ..= 4 (types 5-8 are subserosal/other: not modelled)".into(),
                    });
                }
            }
            if m.figo.is_none() && m.depth_mm.is_none() {
                return Err(AnatomyError::Parse(format!(
                    "myomas[{i}]: give `figo` or `depth_mm` (or both)"
                )));
            }
            for (k, v) in [("x_mm", m.x_mm), ("from_fundus_mm", m.from_fundus_mm)] {
                if !v.is_finite() {
                    return Err(AnatomyError::OutOfRange {
                        key: format!("myomas[{i}].{k}"),
                        value: v,
                        expected: "a finite number".into(),
                    });
                }
            }
        }
        for (i, p) in self.polyps.iter().enumerate() {
            if !(p.diameter_mm.is_finite() && p.diameter_mm >= 2.0 && p.diameter_mm <= 40.0) {
                return Err(AnatomyError::OutOfRange {
                    key: format!("polyps[{i}].diameter_mm"),
                    value: p.diameter_mm,
                    expected: "2 ..= 40".into(),
                });
            }
            for (k, v) in [("x_mm", p.x_mm), ("from_fundus_mm", p.from_fundus_mm)] {
                if !v.is_finite() {
                    return Err(AnatomyError::OutOfRange {
                        key: format!("polyps[{i}].{k}"),
                        value: v,
                        expected: "a finite number".into(),
                    });
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_round_trip_through_toml() {
        for parity in [Parity::Nulliparous, Parity::Parous] {
            let p = AnatomyParams::preset(parity);
            let text = p.to_toml_string().unwrap();
            assert_eq!(AnatomyParams::from_toml_str(&text).unwrap(), p);
        }
    }

    #[test]
    fn missing_keys_come_from_the_named_preset() {
        let p =
            AnatomyParams::from_toml_str("parity = \"nulliparous\"\nslit_gap_mm = 2.5\n").unwrap();
        assert_eq!(p.fundal_cavity_width_mm, 27.0);
        assert_eq!(p.slit_gap_mm, 2.5);
        let p = AnatomyParams::from_toml_str("[mesh]\ntarget_tets = 9000\n").unwrap();
        assert_eq!(p.fundal_cavity_width_mm, 32.0);
        assert_eq!(p.mesh.target_tets, 9000);
        assert_eq!(
            p.mesh.smoothing_sweeps,
            MeshParams::default().smoothing_sweeps
        );
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named() {
        let e = AnatomyParams::from_toml_str("uterine_lenght_mm = 70\n").unwrap_err();
        assert!(e.to_string().contains("uterine_lenght_mm"), "{e}");
        let e = AnatomyParams::from_toml_str("uterine_length_mm = \"long\"\n").unwrap_err();
        assert!(e.to_string().contains("uterine_length_mm"), "{e}");
        let p = AnatomyParams::from_toml_str("cornual_angle_deg = 120\n").unwrap();
        let e = p.check_ranges().unwrap_err();
        assert!(e.to_string().contains("cornual_angle_deg"), "{e}");
    }
}

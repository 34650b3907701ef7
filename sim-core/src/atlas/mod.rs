//! The deformation atlas: FEM equilibrium states of one mesh at increasing cavity pressures, with
//! `dx/dp` per level, replayed in real time by cubic Hermite interpolation in pressure.
//!
//! The binary layout is specified in `docs/atlas-format.md` and implemented in [`format`].
//!
//! ```
//! use hydrometra_sim::atlas::{Atlas, AtlasLevel};
//! let rest = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]];
//! let level = |p: f64| AtlasLevel {
//!     pressure_pa: p,
//!     cavity_volume_m3: 1.0 + p,
//!     positions_m: vec![[0.0, 0.0, 0.0], [1.0 + p, 0.0, 0.0]],
//!     dxdp_m_per_pa: vec![[0.0; 3], [1.0, 0.0, 0.0]],
//! };
//! let atlas = Atlas::new(0, serde_json::json!({}), rest, &[level(0.0), level(1.0)]).unwrap();
//! let bytes = atlas.to_bytes();
//! let back = Atlas::from_bytes(&bytes, "example").unwrap();
//! let mut out = vec![[0.0f32; 3]; 2];
//! back.positions_at(0.5, &mut out).unwrap();
//! assert!((out[1][0] - 1.5).abs() < 1e-6);
//! ```

pub mod format;

use crate::mesh::TetMesh;

/// Atlas errors: every one names what is wrong and where.
#[derive(Debug, thiserror::Error)]
pub enum AtlasError {
    /// File system error.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is shorter or longer than its header says.
    #[error("{origin}: size mismatch: {what}: expected {expected} bytes, found {found}")]
    Size {
        /// File name or origin.
        origin: String,
        /// Which part.
        what: String,
        /// Expected bytes.
        expected: usize,
        /// Found bytes.
        found: usize,
    },
    /// Not an atlas file.
    #[error("{origin}: bad magic {found:?}, expected {expected:?} (not a hydrometra atlas)")]
    Magic {
        /// File name or origin.
        origin: String,
        /// Found bytes.
        found: [u8; 8],
        /// Expected bytes.
        expected: [u8; 8],
    },
    /// A version this build cannot read.
    #[error("{origin}: unsupported atlas version {found}; this build reads version {supported}")]
    Version {
        /// File name or origin.
        origin: String,
        /// Found version.
        found: u32,
        /// Supported version.
        supported: u32,
    },
    /// Checksum mismatch (corruption).
    #[error("{origin}: CRC-32 mismatch: stored {stored:#010x}, computed {computed:#010x} (file corrupt)")]
    Checksum {
        /// File name or origin.
        origin: String,
        /// Stored value.
        stored: u32,
        /// Computed value.
        computed: u32,
    },
    /// Content that violates the format's rules.
    #[error("{origin}: {message}")]
    Invalid {
        /// File name or origin.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// A caller's buffer or argument does not fit the atlas.
    #[error("{0}")]
    Argument(String),
}

/// One equilibrium state.
#[derive(Debug, Clone, PartialEq)]
pub struct AtlasLevel {
    /// Cavity pressure in Pa.
    pub pressure_pa: f64,
    /// Cavity volume in m^3.
    pub cavity_volume_m3: f64,
    /// Vertex positions in m.
    pub positions_m: Vec<[f64; 3]>,
    /// `dx/dp` in m/Pa.
    pub dxdp_m_per_pa: Vec<[f64; 3]>,
}

/// A loaded (validated) deformation atlas.
#[derive(Debug, Clone, PartialEq)]
pub struct Atlas {
    /// Hash of the mesh the atlas belongs to ([`mesh_hash`]).
    pub mesh_hash: u64,
    /// Material, solver and provenance metadata (JSON object).
    pub metadata: serde_json::Value,
    /// Rest positions in m.
    pub rest_positions_m: Vec<[f64; 3]>,
    /// Pressure of each level in Pa, strictly increasing.
    pub pressure_pa: Vec<f64>,
    /// Cavity volume of each level in m^3.
    pub cavity_volume_m3: Vec<f64>,
    positions_m: Vec<[f32; 3]>,
    dxdp_m_per_pa: Vec<[f32; 3]>,
}

/// FNV-1a 64-bit hash of a mesh's geometry and topology (positions, tets, regions, labels,
/// cavity triangles, opening loop), to tie an atlas to its mesh.
pub fn mesh_hash(mesh: &TetMesh) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h ^= b as u64;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
    };
    eat(&(mesh.positions_m.len() as u64).to_le_bytes());
    for p in &mesh.positions_m {
        for c in p {
            eat(&c.to_le_bytes());
        }
    }
    eat(&(mesh.tets.len() as u64).to_le_bytes());
    for t in &mesh.tets {
        for i in t {
            eat(&i.to_le_bytes());
        }
    }
    for r in &mesh.tet_regions {
        eat(&[*r as u8]);
    }
    for l in &mesh.vertex_labels {
        eat(&[*l as u8]);
    }
    eat(&(mesh.cavity_triangles.len() as u64).to_le_bytes());
    for t in &mesh.cavity_triangles {
        for i in t {
            eat(&i.to_le_bytes());
        }
    }
    for i in &mesh.cavity_opening_loop {
        eat(&i.to_le_bytes());
    }
    h
}

impl Atlas {
    /// Builds an atlas from solved levels; checks sizes, finiteness and increasing pressures.
    pub fn new(
        mesh_hash: u64,
        metadata: serde_json::Value,
        rest_positions_m: Vec<[f64; 3]>,
        levels: &[AtlasLevel],
    ) -> Result<Self, AtlasError> {
        let n = rest_positions_m.len();
        let mut positions = Vec::with_capacity(n * levels.len());
        let mut dxdp = Vec::with_capacity(n * levels.len());
        for (k, l) in levels.iter().enumerate() {
            if l.positions_m.len() != n || l.dxdp_m_per_pa.len() != n {
                return Err(AtlasError::Argument(format!(
                    "level {k}: {} positions and {} dx/dp for {n} vertices",
                    l.positions_m.len(),
                    l.dxdp_m_per_pa.len()
                )));
            }
            positions.extend(l.positions_m.iter().map(|p| p.map(|v| v as f32)));
            dxdp.extend(l.dxdp_m_per_pa.iter().map(|p| p.map(|v| v as f32)));
        }
        let atlas = Self {
            mesh_hash,
            metadata,
            rest_positions_m,
            pressure_pa: levels.iter().map(|l| l.pressure_pa).collect(),
            cavity_volume_m3: levels.iter().map(|l| l.cavity_volume_m3).collect(),
            positions_m: positions,
            dxdp_m_per_pa: dxdp,
        };
        atlas.validate("new atlas")?;
        Ok(atlas)
    }

    /// Checks the invariants the replay relies on.
    pub(crate) fn validate(&self, origin: &str) -> Result<(), AtlasError> {
        let bad = |message: String| {
            Err(AtlasError::Invalid {
                origin: origin.to_string(),
                message,
            })
        };
        let n = self.rest_positions_m.len();
        let l = self.pressure_pa.len();
        if n == 0 {
            return bad("the atlas has no vertices".into());
        }
        if l < 2 {
            return bad(format!(
                "the atlas has {l} levels; at least 2 are needed to interpolate"
            ));
        }
        for (k, w) in self.pressure_pa.windows(2).enumerate() {
            if w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater) {
                return bad(format!(
                    "pressures must increase strictly: level {} has {} Pa after {} Pa at level {k}",
                    k + 1,
                    w[1],
                    w[0]
                ));
            }
        }
        if let Some(k) = self
            .pressure_pa
            .iter()
            .chain(&self.cavity_volume_m3)
            .position(|v| !v.is_finite())
        {
            return bad(format!("non-finite pressure or cavity volume (entry {k})"));
        }
        if self
            .rest_positions_m
            .iter()
            .flatten()
            .any(|v| !v.is_finite())
        {
            return bad("non-finite rest position".into());
        }
        if let Some(i) = self
            .positions_m
            .iter()
            .chain(&self.dxdp_m_per_pa)
            .position(|p| p.iter().any(|v| !v.is_finite()))
        {
            return bad(format!("non-finite position or dx/dp (vertex record {i})"));
        }
        Ok(())
    }

    /// Number of vertices.
    pub fn vertex_count(&self) -> usize {
        self.rest_positions_m.len()
    }

    /// Number of levels.
    pub fn level_count(&self) -> usize {
        self.pressure_pa.len()
    }

    /// Positions of level `k` (m, single precision).
    pub fn level_positions(&self, k: usize) -> &[[f32; 3]] {
        let n = self.vertex_count();
        &self.positions_m[k * n..(k + 1) * n]
    }

    /// `dx/dp` of level `k` (m/Pa, single precision).
    pub fn level_dxdp(&self, k: usize) -> &[[f32; 3]] {
        let n = self.vertex_count();
        &self.dxdp_m_per_pa[k * n..(k + 1) * n]
    }

    /// The level interval containing `pressure_pa` (clamped to the atlas range) and the local
    /// parameter `t` in [0, 1].
    fn segment(&self, pressure_pa: f64) -> (usize, f64) {
        let p = &self.pressure_pa;
        let last = p.len() - 1;
        let q = if pressure_pa.is_nan() {
            p[0]
        } else {
            pressure_pa.clamp(p[0], p[last])
        };
        let k = p.partition_point(|&v| v <= q).clamp(1, last) - 1;
        (k, ((q - p[k]) / (p[k + 1] - p[k])).clamp(0.0, 1.0))
    }

    /// Vertex positions at `pressure_pa` by cubic Hermite interpolation with the stored `dx/dp`
    /// (clamped to the atlas's pressure range) into `out` (one entry per vertex).
    pub fn positions_at(&self, pressure_pa: f64, out: &mut [[f32; 3]]) -> Result<(), AtlasError> {
        let n = self.vertex_count();
        if out.len() != n {
            return Err(AtlasError::Argument(format!(
                "positions_at: output has {} entries, the atlas has {n} vertices",
                out.len()
            )));
        }
        let (k, t) = self.segment(pressure_pa);
        let h = self.pressure_pa[k + 1] - self.pressure_pa[k];
        let t2 = t * t;
        let t3 = t2 * t;
        let c0 = (2.0 * t3 - 3.0 * t2 + 1.0) as f32;
        let d0 = ((t3 - 2.0 * t2 + t) * h) as f32;
        let c1 = (-2.0 * t3 + 3.0 * t2) as f32;
        let d1 = ((t3 - t2) * h) as f32;
        let (x0, x1) = (self.level_positions(k), self.level_positions(k + 1));
        let (g0, g1) = (self.level_dxdp(k), self.level_dxdp(k + 1));
        for i in 0..n {
            for c in 0..3 {
                out[i][c] = c0 * x0[i][c] + d0 * g0[i][c] + c1 * x1[i][c] + d1 * g1[i][c];
            }
        }
        Ok(())
    }

    /// Positions and `dx/dp` of the vertices `ids` at `pressure_pa`: the cubic Hermite of
    /// [`Self::positions_at`] and its derivative in pressure, clamped at the top level. Below the
    /// first level (suction) the positions continue along the first interval's secant, as the
    /// hydraulics' tabulated P-V curve continues its first segment (`TabulatedCompliance`), so the
    /// surface's volume follows the hydraulics' volume there too. `positions_out[n]` and
    /// `dxdp_out[n]` belong to vertex `ids[n]`.
    pub fn replay_subset(
        &self,
        pressure_pa: f64,
        ids: &[u32],
        positions_out: &mut [[f32; 3]],
        dxdp_out: &mut [[f32; 3]],
    ) -> Result<(), AtlasError> {
        if positions_out.len() != ids.len() || dxdp_out.len() != ids.len() {
            return Err(AtlasError::Argument(format!(
                "replay_subset: {} ids but {} positions and {} dx/dp outputs",
                ids.len(),
                positions_out.len(),
                dxdp_out.len()
            )));
        }
        self.check_ids("replay_subset", ids)?;
        self.replay_mapped(pressure_pa, |m| ids[m] as usize, positions_out, dxdp_out);
        Ok(())
    }

    /// [`Self::replay_subset`] of every vertex in order: the levels are read front to back (an
    /// atlas restricted to the vertices a caller replays, [`Self::subset`], is read contiguously).
    pub fn replay(
        &self,
        pressure_pa: f64,
        positions_out: &mut [[f32; 3]],
        dxdp_out: &mut [[f32; 3]],
    ) -> Result<(), AtlasError> {
        let n = self.vertex_count();
        if positions_out.len() != n || dxdp_out.len() != n {
            return Err(AtlasError::Argument(format!(
                "replay: {n} vertices but {} positions and {} dx/dp outputs",
                positions_out.len(),
                dxdp_out.len()
            )));
        }
        self.replay_mapped(pressure_pa, |m| m, positions_out, dxdp_out);
        Ok(())
    }

    /// An error naming `what` and the first of `ids` that is not a vertex of the atlas.
    fn check_ids(&self, what: &str, ids: &[u32]) -> Result<(), AtlasError> {
        let n = self.vertex_count();
        match ids.iter().find(|&&i| i as usize >= n) {
            Some(&bad) => Err(AtlasError::Argument(format!(
                "{what}: vertex {bad} is not in the atlas ({n} vertices)"
            ))),
            None => Ok(()),
        }
    }

    /// The atlas of the vertices `ids` alone (vertex `m` of the result is vertex `ids[m]`): the
    /// same levels, pressures and volumes, and the same stored values, so its replay equals
    /// [`Self::replay_subset`] of `ids` exactly.
    pub fn subset(&self, ids: &[u32]) -> Result<Atlas, AtlasError> {
        self.check_ids("subset", ids)?;
        let levels = 0..self.level_count();
        let gather =
            |level: &[[f32; 3]]| ids.iter().map(|&i| level[i as usize]).collect::<Vec<_>>();
        Ok(Atlas {
            mesh_hash: self.mesh_hash,
            metadata: self.metadata.clone(),
            rest_positions_m: ids
                .iter()
                .map(|&i| self.rest_positions_m[i as usize])
                .collect(),
            pressure_pa: self.pressure_pa.clone(),
            cavity_volume_m3: self.cavity_volume_m3.clone(),
            positions_m: levels
                .clone()
                .flat_map(|k| gather(self.level_positions(k)))
                .collect(),
            dxdp_m_per_pa: levels.flat_map(|k| gather(self.level_dxdp(k))).collect(),
        })
    }

    /// The replay of output `m` from vertex `vertex(m)` (checked by the callers).
    #[inline(always)]
    fn replay_mapped(
        &self,
        pressure_pa: f64,
        vertex: impl Fn(usize) -> usize,
        positions_out: &mut [[f32; 3]],
        dxdp_out: &mut [[f32; 3]],
    ) {
        let p0 = self.pressure_pa[0];
        if pressure_pa < p0 {
            let h = self.pressure_pa[1] - p0;
            let dp = (pressure_pa - p0) as f32;
            let (x0, x1) = (self.level_positions(0), self.level_positions(1));
            for (m, (pos, dxdp)) in positions_out
                .iter_mut()
                .zip(dxdp_out.iter_mut())
                .enumerate()
            {
                let i = vertex(m);
                for c in 0..3 {
                    let slope = ((x1[i][c] - x0[i][c]) as f64 / h) as f32;
                    pos[c] = x0[i][c] + dp * slope;
                    dxdp[c] = slope;
                }
            }
            return;
        }
        let (k, t) = self.segment(pressure_pa);
        let h = self.pressure_pa[k + 1] - self.pressure_pa[k];
        let (t2, t3) = (t * t, t * t * t);
        let c0 = (2.0 * t3 - 3.0 * t2 + 1.0) as f32;
        let d0 = ((t3 - 2.0 * t2 + t) * h) as f32;
        let c1 = (-2.0 * t3 + 3.0 * t2) as f32;
        let d1 = ((t3 - t2) * h) as f32;
        // d/dp = (1/h) d/dt.
        let e0 = ((6.0 * t2 - 6.0 * t) / h) as f32;
        let f0 = (3.0 * t2 - 4.0 * t + 1.0) as f32;
        let f1 = (3.0 * t2 - 2.0 * t) as f32;
        let (x0, x1) = (self.level_positions(k), self.level_positions(k + 1));
        let (g0, g1) = (self.level_dxdp(k), self.level_dxdp(k + 1));
        for (m, (pos, dxdp)) in positions_out
            .iter_mut()
            .zip(dxdp_out.iter_mut())
            .enumerate()
        {
            let i = vertex(m);
            for c in 0..3 {
                pos[c] = c0 * x0[i][c] + d0 * g0[i][c] + c1 * x1[i][c] + d1 * g1[i][c];
                dxdp[c] = e0 * (x0[i][c] - x1[i][c]) + f0 * g0[i][c] + f1 * g1[i][c];
            }
        }
    }

    /// Vertex positions at `pressure_pa` by linear interpolation (for comparison).
    pub fn positions_at_linear(
        &self,
        pressure_pa: f64,
        out: &mut [[f32; 3]],
    ) -> Result<(), AtlasError> {
        let n = self.vertex_count();
        if out.len() != n {
            return Err(AtlasError::Argument(format!(
                "positions_at_linear: output has {} entries, the atlas has {n} vertices",
                out.len()
            )));
        }
        let (k, t) = self.segment(pressure_pa);
        let (x0, x1) = (self.level_positions(k), self.level_positions(k + 1));
        let (a, b) = ((1.0 - t) as f32, t as f32);
        for i in 0..n {
            for c in 0..3 {
                out[i][c] = a * x0[i][c] + b * x1[i][c];
            }
        }
        Ok(())
    }

    /// Cavity volume at `pressure_pa` (m^3), piecewise linear between levels, clamped.
    pub fn cavity_volume_at(&self, pressure_pa: f64) -> f64 {
        let (k, t) = self.segment(pressure_pa);
        (1.0 - t) * self.cavity_volume_m3[k] + t * self.cavity_volume_m3[k + 1]
    }

    /// Pressure at cavity volume `volume_m3` (Pa), the inverse of [`Self::cavity_volume_at`]
    /// where the P-V curve is monotone; clamped to the atlas range.
    pub fn pressure_at_volume(&self, volume_m3: f64) -> f64 {
        let v = &self.cavity_volume_m3;
        let p = &self.pressure_pa;
        if volume_m3 <= v[0] {
            return p[0];
        }
        for k in 0..v.len() - 1 {
            if volume_m3 <= v[k + 1] && v[k + 1] > v[k] {
                let t = (volume_m3 - v[k]) / (v[k + 1] - v[k]);
                return p[k] + t * (p[k + 1] - p[k]);
            }
        }
        p[p.len() - 1]
    }
}

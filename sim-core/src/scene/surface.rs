//! The cavity surface the scene replays, voxelizes and publishes: the mesh's endometrium triangles,
//! closed over the external os by a fan from the opening loop's centroid, on its own compact
//! vertex numbering.

use crate::atlas::{Atlas, AtlasError};
use crate::mesh::TetMesh;

/// The closed cavity surface and its replayed state.
#[derive(Debug, Clone)]
pub struct CavitySurface {
    /// Atlas (mesh) vertex of each surface vertex but the last, which is the centroid of the
    /// opening loop.
    atlas_ids: Vec<u32>,
    /// Surface vertices of the opening loop, in order.
    loop_local: Vec<u32>,
    /// Triangles on the surface numbering (normals into the fluid): first the `cap_triangles`
    /// closing the opening, then the endometrium. (The voxelizer gives a band cell its
    /// lowest-index triangle, so a cell the cap touches is open even where the wall touches it.)
    triangles: Vec<[u32; 3]>,
    cap_triangles: usize,
    /// Replayed positions, m, and `dx/dp`, m/Pa, per surface vertex (the centroid last).
    positions_m: Vec<[f32; 3]>,
    dxdp_m_per_pa: Vec<[f32; 3]>,
    /// The pressure of the last replay, Pa.
    pressure_pa: f64,
}

impl CavitySurface {
    /// Extracts the closed surface of `mesh`.
    pub fn new(mesh: &TetMesh) -> Result<Self, AtlasError> {
        if mesh.cavity_triangles.is_empty() {
            return Err(AtlasError::Argument(
                "the mesh has no cavity triangles".into(),
            ));
        }
        let n = mesh.positions_m.len();
        let mut local = vec![u32::MAX; n];
        let mut atlas_ids = Vec::new();
        let mut map = |v: u32| -> Result<u32, AtlasError> {
            let slot = local.get_mut(v as usize).ok_or_else(|| {
                AtlasError::Argument(format!("cavity vertex {v} is not in the mesh ({n})"))
            })?;
            if *slot == u32::MAX {
                *slot = atlas_ids.len() as u32;
                atlas_ids.push(v);
            }
            Ok(*slot)
        };
        let mut triangles = Vec::with_capacity(mesh.cavity_triangles.len() + 64);
        for t in &mesh.cavity_triangles {
            triangles.push([map(t[0])?, map(t[1])?, map(t[2])?]);
        }
        let loop_local = mesh
            .cavity_opening_loop
            .iter()
            .map(|&v| map(v))
            .collect::<Result<Vec<u32>, _>>()?;
        let centroid = atlas_ids.len() as u32;
        // Close every boundary half-edge a -> b with (centroid, b, a): the orientation continues
        // (as in `mesh::cavity_volume_m3`).
        let mut half = std::collections::HashSet::with_capacity(triangles.len() * 3);
        for t in &triangles {
            for k in 0..3 {
                half.insert((t[k], t[(k + 1) % 3]));
            }
        }
        let mut cap: Vec<[u32; 3]> = half
            .iter()
            .filter(|&&(a, b)| !half.contains(&(b, a)))
            .map(|&(a, b)| [centroid, b, a])
            .collect();
        cap.sort_unstable();
        let cap_triangles = cap.len();
        cap.extend(triangles);
        let triangles = cap;
        let vertices = atlas_ids.len() + 1;
        Ok(Self {
            atlas_ids,
            loop_local,
            triangles,
            cap_triangles,
            positions_m: vec![[0.0; 3]; vertices],
            dxdp_m_per_pa: vec![[0.0; 3]; vertices],
            pressure_pa: f64::NAN,
        })
    }

    /// Vertices (the centroid of the opening last).
    pub fn vertex_count(&self) -> usize {
        self.positions_m.len()
    }
    /// Triangles, the cap first.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
    /// Number of cap triangles (the first ones).
    pub fn cap_triangles(&self) -> usize {
        self.cap_triangles
    }
    /// The mesh vertex of each surface vertex but the centroid.
    pub fn atlas_ids(&self) -> &[u32] {
        &self.atlas_ids
    }
    /// Replayed positions, m.
    pub fn positions_m(&self) -> &[[f32; 3]] {
        &self.positions_m
    }
    /// Replayed `dx/dp`, m/Pa.
    pub fn dxdp_m_per_pa(&self) -> &[[f32; 3]] {
        &self.dxdp_m_per_pa
    }
    /// The pressure of the last replay (NaN before the first).
    pub fn pressure_pa(&self) -> f64 {
        self.pressure_pa
    }

    /// Replays the surface at `pressure_pa` from the mesh's atlas.
    pub fn replay(&mut self, atlas: &Atlas, pressure_pa: f64) -> Result<(), AtlasError> {
        let m = self.atlas_ids.len();
        let (pos, dxdp) = (&mut self.positions_m[..m], &mut self.dxdp_m_per_pa[..m]);
        atlas.replay_subset(pressure_pa, &self.atlas_ids, pos, dxdp)?;
        self.close_the_opening(pressure_pa);
        Ok(())
    }

    /// The mesh's atlas restricted to this surface's vertices (the centroid aside), for
    /// [`Self::replay_compact`]: a fraction of the atlas, read front to back.
    pub fn compact_atlas(&self, atlas: &Atlas) -> Result<Atlas, AtlasError> {
        atlas.subset(&self.atlas_ids)
    }

    /// [`Self::replay`] from the [`Self::compact_atlas`] of the same atlas: the same positions
    /// and `dx/dp`, bit for bit, from contiguous memory (a replay right after a fluid step that
    /// evicted the caches reads a few hundred kB in order instead of gathering from the whole
    /// mesh's levels).
    pub fn replay_compact(&mut self, compact: &Atlas, pressure_pa: f64) -> Result<(), AtlasError> {
        let m = self.atlas_ids.len();
        let (pos, dxdp) = (&mut self.positions_m[..m], &mut self.dxdp_m_per_pa[..m]);
        compact.replay(pressure_pa, pos, dxdp)?;
        self.close_the_opening(pressure_pa);
        Ok(())
    }

    /// The centroid of the opening loop (the last vertex) from the replayed loop.
    fn close_the_opening(&mut self, pressure_pa: f64) {
        let m = self.atlas_ids.len();
        let (pos, centroid_pos) = self.positions_m.split_at_mut(m);
        let (dxdp, centroid_dxdp) = self.dxdp_m_per_pa.split_at_mut(m);
        let mut c = [0.0f32; 3];
        let mut d = [0.0f32; 3];
        for &v in &self.loop_local {
            for a in 0..3 {
                c[a] += pos[v as usize][a];
                d[a] += dxdp[v as usize][a];
            }
        }
        let n = self.loop_local.len().max(1) as f32;
        centroid_pos[0] = c.map(|x| x / n);
        centroid_dxdp[0] = d.map(|x| x / n);
        self.pressure_pa = pressure_pa;
    }

    /// Volume enclosed by the closed surface at its replayed positions, m^3.
    pub fn enclosed_volume_m3(&self) -> f64 {
        enclosed_volume_m3(&self.positions_m, &self.triangles)
    }
}

/// Volume enclosed by a closed surface whose normals point inwards (into the enclosed fluid), m^3.
pub fn enclosed_volume_m3(positions_m: &[[f32; 3]], triangles: &[[u32; 3]]) -> f64 {
    let p = |i: u32| positions_m[i as usize].map(f64::from);
    let mut six_v = 0.0;
    for t in triangles {
        let [a, b, c] = t.map(p);
        six_v += a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]);
    }
    -six_v / 6.0
}

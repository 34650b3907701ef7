//! Reconstructs the cavity mesh from `cavity/topology` and `cavity/positions` and prints the
//! volume it encloses, frame by frame (docs/ipc.md, "Cavity mesh"); beside it, for the frames
//! that published a flow field, the fluid volume of the field's fluid volume fractions,
//! `sum(fraction) h^3` (docs/ipc.md, "Flow field").
//!
//!     cargo run -p hydrometra-ipc --example cavity_volume -- [PREFIX] [FRAMES]

use core::time::Duration;

use hydrometra_ipc::field::fraction_from_u8;
use hydrometra_ipc::slice::{self, Flow, Positions, Topology};
use hydrometra_ipc::{events, ServiceNames};
use iceoryx2::prelude::*;

/// Volume enclosed by a closed surface whose normals point inward (into the cavity's fluid).
fn enclosed_volume_m3(triangles: &[u32], positions: &[f32]) -> f64 {
    let p = |i: u32| -> [f64; 3] { std::array::from_fn(|k| positions[3 * i as usize + k] as f64) };
    let mut six_v = 0.0;
    for t in triangles.chunks_exact(3) {
        let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
        six_v += a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
            + a[2] * (b[0] * c[1] - b[1] * c[0]);
    }
    -six_v / 6.0
}

fn main() -> Result<(), Box<dyn core::error::Error>> {
    set_log_level_from_env_or(LogLevel::Error);
    let mut args = std::env::args().skip(1);
    let prefix = args
        .next()
        .unwrap_or_else(|| hydrometra_ipc::DEFAULT_SERVICE_PREFIX.into());
    let frames: usize = args.next().map_or(Ok(0), |n| n.parse())?;
    let names = ServiceNames::new(&prefix)?;
    let node = NodeBuilder::new().create::<ipc::Service>()?;
    let hint = "is hydrometrad running with a scene, and is the scene ready (status scene_state)?";
    let topology = slice::open::<Topology, _>(&node, &names)
        .map_err(|e| {
            format!(
                "{}: {e}: {hint}",
                names.full(hydrometra_ipc::names::suffix::MESH_TOPOLOGY)
            )
        })?
        .subscriber_builder()
        .create()?;
    let positions = slice::open::<Positions, _>(&node, &names)
        .map_err(|e| {
            format!(
                "{}: {e}: {hint}",
                names.full(hydrometra_ipc::names::suffix::MESH_POSITIONS)
            )
        })?
        .subscriber_builder()
        .create()?;
    let flow = slice::open::<Flow, _>(&node, &names)
        .map_err(|e| {
            format!(
                "{}: {e}: {hint}",
                names.full(hydrometra_ipc::names::suffix::FLOW_FIELD)
            )
        })?
        .subscriber_builder()
        .create()?;
    let listener = events::open(&node, &names)?.listener_builder().create()?;
    // The enclosed volumes of the last frames, by scene frame: a flow field is published right
    // after its frame's positions (when the fluid stage ran), so it usually arrives a wake-up
    // later and is paired with its frame's volume here.
    let mut volumes = [(u64::MAX, 0.0f64); 8];
    let mut triangles: Vec<u32> = Vec::new();
    let mut revision = None;
    let mut printed = 0;
    while frames == 0 || printed < frames {
        listener.timed_wait(|_| {}, Duration::from_millis(100))?;
        while let Some(sample) = topology.receive()? {
            triangles.clear();
            triangles.extend_from_slice(sample.payload());
            revision = Some(sample.user_header().topology_revision);
        }
        let mut newest = None;
        while let Some(sample) = positions.receive()? {
            newest = Some(sample);
        }
        if let Some(sample) = newest {
            let h = *sample.user_header();
            // Positions of a topology not received yet are skipped.
            if Some(h.topology_revision) == revision {
                let volume = enclosed_volume_m3(&triangles, sample.payload());
                volumes[h.scene_frame as usize % volumes.len()] = (h.scene_frame, volume);
                println!(
                    "t={:.3} s  {:.1} mmHg  {} vertices, {} triangles  enclosed volume {:.3} ml",
                    h.sim_time_s,
                    h.cavity_pressure_pa / hydrometra_units::PA_PER_MMHG,
                    h.vertex_count,
                    triangles.len() / 3,
                    volume * 1e6
                );
                printed += 1;
            }
        }
        while let Some(sample) = flow.receive()? {
            let h = sample.user_header();
            // Absent fractions (offset 0): nothing to add up.
            let Some(fractions) = h.fractions(sample.payload()) else {
                continue;
            };
            let cells: f64 = fractions.iter().map(|&b| fraction_from_u8(b)).sum();
            let fluid_m3 = cells * h.spacing_m.powi(3);
            let (frame, volume) = volumes[h.scene_frame as usize % volumes.len()];
            if frame == h.scene_frame {
                println!(
                    "t={:.3} s  fluid {:.3} ml of the flow field's fractions ({:+.1} % of the \
                     enclosed volume)",
                    h.sim_time_s,
                    fluid_m3 * 1e6,
                    100.0 * (fluid_m3 / volume - 1.0)
                );
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_unit_cube_with_inward_normals_encloses_one() {
        let p: Vec<f32> = (0..8)
            .flat_map(|i| [(i & 1) as f32, ((i >> 1) & 1) as f32, ((i >> 2) & 1) as f32])
            .collect();
        // Outward counter-clockwise faces, then reversed (inward).
        let out = [
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ];
        let inward: Vec<u32> = out.iter().flat_map(|t| [t[0], t[2], t[1]]).collect();
        assert!((super::enclosed_volume_m3(&inward, &p) - 1.0).abs() < 1e-12);
    }
}

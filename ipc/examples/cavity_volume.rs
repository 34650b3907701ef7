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
    // The newest flow field's (scene frame, fluid volume m^3).
    let mut fluid: Option<(u64, Option<f64>)> = None;
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
        while let Some(sample) = flow.receive()? {
            let h = sample.user_header();
            // Absent fractions (offset 0) give no volume; the field is still this frame's.
            let cells = h
                .fractions(sample.payload())
                .map(|f| f.iter().map(|&b| fraction_from_u8(b)).sum::<f64>());
            fluid = Some((h.scene_frame, cells.map(|c| c * h.spacing_m.powi(3))));
        }
        let Some(sample) = newest else { continue };
        let h = *sample.user_header();
        if Some(h.topology_revision) != revision {
            continue; // positions of a topology not received yet
        }
        let volume = enclosed_volume_m3(&triangles, sample.payload());
        // The flow of the same frame is published right after its positions, so it is here
        // already unless the fluid stage skipped the frame (then the flow service is quiet).
        let fluid_text = match fluid {
            Some((frame, Some(v))) if frame == h.scene_frame => {
                format!(
                    "  fluid {:.3} ml ({:+.1} %)",
                    v * 1e6,
                    100.0 * (v / volume - 1.0)
                )
            }
            _ => String::new(),
        };
        println!(
            "t={:.3} s  {:.1} mmHg  {} vertices, {} triangles  enclosed volume {:.3} ml{fluid_text}",
            h.sim_time_s,
            h.cavity_pressure_pa / hydrometra_units::PA_PER_MMHG,
            h.vertex_count,
            triangles.len() / 3,
            volume * 1e6
        );
        printed += 1;
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

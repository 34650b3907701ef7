//! With cut cells the cavity's walls and its os move the fluid through the wall pieces inside the
//! cut cells (docs/scene.md, "Consistency of the fluxes"): on the coarse test scene, every fluid
//! step, the fluxes measured on the projected field balance (inflow - outflow - walls - os within
//! 1e-4 of the largest flow, and no mismatch removed from any closed region beyond 1e-4 of it, while
//! the fluid splits into several regions: each region with walls balances by itself and a pocket
//! without any takes no share of the losses), the ports carry the hydraulics' inflow and outflow, the os exactly its losses (never drawing
//! fluid in while they flow out), and the walls `dV/dt`.

mod scene_common;
use scene_common::{
    coarse, flux_balance_m3_per_s, inputs, largest_flow_m3_per_s, own, scope_in_cavity, DT,
};

use hydrometra_sim::scene::Scene;

#[test]
fn with_cut_cells_the_walls_and_the_os_carry_the_hydraulics_flows_every_fluid_step() {
    let (mut desc, assets) = coarse(1.2);
    desc.fluid.cut_cells = true;
    let mut scene = Scene::new(desc, assets).unwrap();
    let scope = scope_in_cavity(&scene);
    let (mut checked, mut worst, mut saw_losses) = (0, 0.0f64, false);
    let (mut split, mut worst_removed) = (0, 0.0f64);
    let (mut removed_m3, mut inflow_m3) = (0.0, 0.0);
    // Distend, rinse, a perforation (large losses), then drain.
    for f in 0..420 {
        let mut rig = match f {
            0..=149 => inputs(1.0, 0.0, 100.0, scope),
            150..=269 => inputs(1.0, 0.6, 100.0, scope),
            270..=329 => inputs(1.0, 0.3, 100.0, scope),
            _ => inputs(0.0, 1.0, 0.0, scope),
        };
        rig.hydraulic.perforation = (270..330).contains(&f);
        scene.step(&own(rig), DT).unwrap();
        let r = scene.report();
        let Some(stats) = r.fluid else { continue };
        assert!(stats.projection_converged, "frame {f}: {stats:?}");
        let fl = r.flux;
        let flow = scene.flow().unwrap();
        let solver = flow.solver();
        // Every fluid region is closed: no open cell takes up a mismatch.
        let (regions, closed) = solver.regions();
        assert_eq!(regions, closed, "frame {f}: an open region");
        split += usize::from(regions > 1);
        // The balance of the fluxes measured on the projected field.
        let balance = flux_balance_m3_per_s(&fl);
        let scale = largest_flow_m3_per_s(&fl).max(1e-12);
        let rel = balance.abs() / scale;
        worst = worst.max(rel);
        // Each region with wall pieces balances by itself (its walls take up its mismatch) and a
        // pocket without any gets no share of the losses: nothing is left for the projection to
        // remove.
        let removed = fl.closed_region_mismatch_m3_per_s;
        worst_removed = worst_removed.max(removed / scale);
        removed_m3 += removed * DT;
        inflow_m3 += fl.hydraulic_inflow_m3_per_s * DT;
        assert!(
            removed <= 1e-4 * scale,
            "frame {f}: the projection removed {removed:e} m^3/s of closed mismatch ({:e} of \
             {scale:e})",
            removed / scale
        );
        assert!(
            rel <= 1e-4,
            "frame {f}: in {:e} - out {:e} - walls {:e} - os {:e} = {balance:e} ({rel:e} of \
             {scale:e}); removed {:e}",
            fl.fluid_inflow_m3_per_s,
            fl.fluid_outflow_m3_per_s,
            fl.fluid_wall_m3_per_s,
            fl.fluid_open_m3_per_s,
            fl.closed_region_mismatch_m3_per_s
        );
        // The ports carry the hydraulics' flows (their whole cells' faces open as the cavity
        // makes them, not closed by the sheath's layer), to the solver's single precision.
        assert!(!fl.inflow_blocked && !fl.outflow_blocked, "frame {f}");
        for (what, fluid, hydraulic) in [
            (
                "inflow",
                fl.fluid_inflow_m3_per_s,
                fl.hydraulic_inflow_m3_per_s,
            ),
            (
                "outflow",
                fl.fluid_outflow_m3_per_s,
                fl.hydraulic_outflow_m3_per_s,
            ),
        ] {
            assert!(
                (fluid - hydraulic).abs() <= 1e-5 * scale,
                "frame {f}: {what} {fluid:e}, hydraulics {hydraulic:e}"
            );
        }
        // The os carries the losses with their sign; the walls dV/dt.
        let losses = fl.hydraulic_losses_m3_per_s;
        assert!(
            (fl.fluid_open_m3_per_s - losses).abs() <= 1e-9 * scale,
            "frame {f}: os {:e}, losses {losses:e}",
            fl.fluid_open_m3_per_s
        );
        assert!(!(losses > 0.0 && fl.fluid_open_m3_per_s < 0.0), "frame {f}");
        assert!(
            (fl.fluid_wall_m3_per_s - fl.hydraulic_dvdt_m3_per_s).abs() <= 1e-5 * scale,
            "frame {f}: walls {:e}, dV/dt {:e}",
            fl.fluid_wall_m3_per_s,
            fl.hydraulic_dvdt_m3_per_s
        );
        // What the walls' and the os's pieces push in is what the solver applies.
        let pieces_out = -solver.applied_boundary_flux_m3_per_s();
        let whole_walls = fl.fluid_wall_m3_per_s + fl.fluid_open_m3_per_s - pieces_out;
        assert!(
            whole_walls.abs() <= 1e-9 * scale,
            "frame {f}: whole wall cells carry {whole_walls:e}"
        );
        saw_losses |= losses > 1e-8;
        checked += 1;
    }
    println!(
        "{checked} fluid steps ({split} with the fluid in several regions): largest |in - out - \
         walls - os| / flow {worst:.2e}, largest mismatch removed / flow {worst_removed:.2e}"
    );
    println!("removed {removed_m3:.3e} m^3 of {inflow_m3:.3e} m^3 that entered over the run");
    assert!(checked > 300, "the fluid ran {checked} times");
    assert!(
        split > 0,
        "the fluid never split: the per-region rule is not exercised"
    );
    assert!(saw_losses, "the losses flowed");
}

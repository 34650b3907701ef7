//! Deterministic driver for instruction counts (callgrind) of the fluid, vortex and particle
//! stages on the benchmark cavity at 1.2 mm: `stage_costs <fluid|overlay|injected|particles> <steps>
//! [count]`.

use hydrometra_sim::fluid::cavity::uterine_cavity;
use hydrometra_sim::fluid::{CellLabel, FluidParams, FluidSolver};
use hydrometra_sim::scene::clarity::ViewSpec;
use hydrometra_sim::scene::particles::{
    kinds_from_labels, ParticleClass, ParticleKind, ParticleSystem,
};
use hydrometra_sim::scene::vortices::{VortexField, VortexMode, VortexSpec};

const DT: f64 = 1.0 / 60.0;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let what = args.get(1).map(String::as_str).unwrap_or("overlay");
    let steps: usize = args.get(2).map_or(Ok(60), |s| s.parse())?;
    let grid = uterine_cavity(1.2e-3, 1.0)?;
    let params = FluidParams {
        tolerance: 1e-5,
        ..Default::default()
    };
    let mut s = FluidSolver::new(grid, params)?;
    for _ in 0..30 {
        s.step(DT)?;
    }
    if what == "particles" {
        let count: usize = args.get(3).map_or(Ok(10_000), |s| s.parse())?;
        let kinds = kinds_from_labels(s.grid());
        let fluid: Vec<usize> = (0..kinds.len())
            .filter(|&n| s.grid().label_at(n) == CellLabel::Fluid)
            .collect();
        let [nx, ny, nz] = s.grid().dims();
        let h = s.grid().spacing_m();
        let o = s.grid().origin_m();
        let cone = ViewSpec::default().cone(
            [
                o[0] + 0.5 * nx as f64 * h,
                o[1] + 0.5 * ny as f64 * h,
                o[2] + 0.2 * nz as f64 * h,
            ],
            [0.0, 0.0, 1.0],
        );
        let mut sys = ParticleSystem::new(s.grid(), count, 8, [0.0, -1.0, 0.0]);
        let cls = sys
            .add_class(ParticleClass {
                kind: ParticleKind::Blood,
                settle_m_s: 3e-4,
                tau_s: 1e-4,
                shade_m2: 2e-7,
                diameter_m: 5e-5,
            })
            .ok_or("class")?;
        let mut rng = fastrand::Rng::with_seed(0);
        let mut clarity = 0.0;
        for _ in 0..steps {
            while sys.len() < count {
                let n = fluid[rng.usize(..fluid.len())];
                let c = s.grid().cell_centre_m(s.grid().coords(n));
                sys.emit(&kinds, cls, c);
            }
            clarity += sys.step(&s, &kinds, None, DT, Some(&cone)).unwrap_or(0.0);
        }
        println!("{:?} clarity sum {clarity}", sys.counts());
        return Ok(());
    }
    let mode = if what == "injected" {
        VortexMode::Injected
    } else {
        VortexMode::Overlay
    };
    let spec = VortexSpec {
        mode,
        ..VortexSpec::default()
    };
    let mut f = VortexField::new(spec, &s)?;
    let mut evaluated = 0;
    for _ in 0..steps {
        s.step(DT)?;
        if what != "fluid" {
            evaluated += f.step(&s, 100, DT).nodes_evaluated;
        }
        if mode == VortexMode::Injected {
            f.inject(&mut s);
        }
    }
    println!("nodes evaluated {evaluated}");
    Ok(())
}

//! Deterministic driver for instruction counts (callgrind) of the fluid, vortex and particle
//! stages on the benchmark cavity at 1.2 mm: `stage_costs <fluid|overlay|injected|particles> <steps>
//! [count]`.

use hydrometra_sim::harness::stage_bench::{self, DT_S as DT};
use hydrometra_sim::scene::vortices::{VortexField, VortexMode, VortexSpec};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let what = args.get(1).map(String::as_str).unwrap_or("overlay");
    let steps: usize = args.get(2).map_or(Ok(60), |s| s.parse())?;
    let mut s = stage_bench::cavity()?;
    if what == "particles" {
        let count: usize = args.get(3).map_or(Ok(10_000), |s| s.parse())?;
        let mut blood = stage_bench::Blood::new(&s, count).ok_or("class")?;
        let mut clarity = 0.0;
        let mut times = Vec::with_capacity(steps);
        for _ in 0..steps {
            let t = std::time::Instant::now();
            clarity += blood.step(&s).unwrap_or(0.0);
            times.push(t.elapsed().as_secs_f64() * 1e6);
        }
        times.sort_by(f64::total_cmp);
        let q = |f: f64| {
            times
                .get((f * steps as f64) as usize)
                .copied()
                .unwrap_or(0.0)
        };
        println!(
            "{:?} clarity sum {clarity}; wall us per step: p10 {:.1} median {:.1}",
            blood.system.counts(),
            q(0.1),
            q(0.5)
        );
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
    let start = std::time::Instant::now();
    for _ in 0..steps {
        s.step(DT)?;
        if what != "fluid" {
            evaluated += f.step(&s, 100, DT).nodes_evaluated;
        }
        if mode == VortexMode::Injected {
            f.inject(&mut s);
        }
    }
    // Wall time per step: compare only interleaved runs (A, B, A, B) on a loaded machine.
    let per_step_us = start.elapsed().as_secs_f64() * 1e6 / steps.max(1) as f64;
    println!("nodes evaluated {evaluated}, {per_step_us:.1} us per step");
    Ok(())
}

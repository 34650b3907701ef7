//! Hydraulic model step time at the daemon's 1 kHz tick, with its accuracy beside it.
//!
//! `cargo bench -p hydrometra-sim --bench hydraulics`

use criterion::{criterion_group, criterion_main, Criterion};
use hydrometra_sim::hydraulics::{HydraulicInputs, HydraulicModel, HydraulicParams};
use hydrometra_sim::units::{mmhg_to_pa, pa_to_mmhg};
use std::hint::black_box;

fn inputs(valve_in: f64, valve_out: f64, pump_mmhg: f64, perforation: bool) -> HydraulicInputs {
    HydraulicInputs {
        valve_in_opening: valve_in,
        valve_out_opening: valve_out,
        pump_set_pressure_pa: mmhg_to_pa(pump_mmhg),
        perforation,
    }
}

fn bench(c: &mut Criterion) {
    let mut group = c.benchmark_group("hydraulics");
    for (name, u) in [
        ("step_1ms_steady_open", inputs(1.0, 1.0, 100.0, false)),
        ("step_1ms_perforated", inputs(0.9, 0.3, 90.0, true)),
    ] {
        let mut model = HydraulicModel::new(HydraulicParams::default()).expect("defaults");
        for _ in 0..30_000 {
            model.step(&u, 1e-3);
        }
        let exact = model.steady_state_pressure_pa(&u).expect("unique");
        let s = model.state();
        eprintln!(
            "{name}: steady pressure error {:.2e} mmHg, balance error {:.2e} relative",
            pa_to_mmhg((s.cavity_pressure_pa - exact).abs()),
            (s.deficit_by_balance_m3() - s.deficit.deficit_m3).abs() / s.totals.inflow_m3
        );
        let before = *model.counters();
        group.bench_function(name, |b| {
            b.iter(|| black_box(model.step(black_box(&u), 1e-3).cavity_pressure_pa))
        });
        let c = model.counters();
        eprintln!(
            "{name}: mean {:.2} solver iterations per step, {:.2} bisections",
            (c.solver_iterations - before.solver_iterations) as f64
                / (c.steps - before.steps).max(1) as f64,
            (c.bisections - before.bisections) as f64 / (c.steps - before.steps).max(1) as f64
        );
    }
    // Valves and pump changing every tick: the worst case for the Newton start.
    let mut model = HydraulicModel::new(HydraulicParams::default()).expect("defaults");
    let mut k = 0u32;
    group.bench_function("step_1ms_inputs_change_every_tick", |b| {
        b.iter(|| {
            k = k.wrapping_add(1);
            let phase = f64::from(k % 997) / 997.0;
            let u = inputs(phase, 1.0 - phase, 150.0 * phase, false);
            black_box(model.step(&u, 1e-3).cavity_pressure_pa)
        })
    });
    let c = model.counters();
    eprintln!(
        "changing inputs: mean {:.2} / max {} solver iterations per step",
        c.solver_iterations as f64 / c.steps.max(1) as f64,
        c.max_solver_iterations
    );
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

//! Behaviour of the whole model: analytic steady states, mass balance, the pressure time constant,
//! stability for any input, port velocities, termination and restore.

use super::*;
use crate::units::{m3_per_s_to_ml_per_min, m3_to_ml, ml_to_m3, mmhg_to_pa, pa_to_mmhg};

/// The workspace's generator (fastrand, seeded) with the two draws these tests use.
struct Rng(fastrand::Rng);

impl Rng {
    fn new(seed: u64) -> Self {
        Self(fastrand::Rng::with_seed(seed))
    }
    fn next_u64(&mut self) -> u64 {
        self.0.u64(..)
    }
    fn uniform(&mut self) -> f64 {
        self.0.f64()
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
}

fn inputs(valve_in: f64, valve_out: f64, pump_mmhg: f64) -> HydraulicInputs {
    HydraulicInputs {
        valve_in_opening: valve_in,
        valve_out_opening: valve_out,
        pump_set_pressure_pa: mmhg_to_pa(pump_mmhg),
        perforation: false,
    }
}

fn run(model: &mut HydraulicModel, inputs: &HydraulicInputs, seconds: f64, dt: f64) {
    let steps = (seconds / dt).round() as usize;
    for _ in 0..steps {
        model.step(inputs, dt);
    }
}

/// Random but valid parameters: every conductance and pressure over a wide range.
fn random_params(rng: &mut Rng) -> HydraulicParams {
    let mut p = HydraulicParams::default();
    p.pump.max_flow_ml_per_min = rng.range(50.0, 800.0);
    p.inflow.tubing_conductance_ml_per_min_per_mmhg = rng.range(2.0, 50.0);
    p.inflow.valve_conductance_ml_per_min_per_mmhg = rng.range(2.0, 50.0);
    p.outflow.tubing_conductance_ml_per_min_per_mmhg = rng.range(2.0, 50.0);
    p.outflow.valve_conductance_ml_per_min_per_mmhg = rng.range(1.0, 30.0);
    p.outflow.suction_pressure_mmhg = rng.range(-200.0, 0.0);
    p.cervix.leak_conductance_ml_per_min_per_mmhg = rng.range(0.01, 2.0);
    p.cervix.leak_collected_fraction = rng.uniform();
    p.absorption.threshold_pressure_mmhg = rng.range(60.0, 110.0);
    p.absorption.conductance_ml_per_min_per_mmhg = rng.range(0.0, 5.0);
    p.perforation.conductance_ml_per_min_per_mmhg = rng.range(5.0, 100.0);
    p.inflow.valve_curve = [
        ValveCurve::Linear,
        ValveCurve::Quadratic,
        ValveCurve::EqualPercentage,
    ][(rng.next_u64() % 3) as usize];
    p
}

#[test]
fn steady_state_matches_the_closed_form_of_the_default_circuit() {
    // Defaults, valves fully open, pump 100 mmHg: the pump is below its flow limit and the cavity
    // pressure between 0 and the absorption threshold, so q(p) = 0 is linear:
    //   G_in (p_set - p) = G_out (p - p_suc) + G_leak p
    //   p = (G_in p_set + G_out p_suc) / (G_in + G_out + G_leak)
    let params = HydraulicParams::default();
    let g_in = params.inflow.line().conductance_m3_per_s_pa(1.0);
    let g_out = params.outflow.line().conductance_m3_per_s_pa(1.0);
    let g_leak = conductance_si(params.cervix.leak_conductance_ml_per_min_per_mmhg);
    let p_set = mmhg_to_pa(100.0);
    let p_suc = mmhg_to_pa(params.outflow.suction_pressure_mmhg);
    let expected = (g_in * p_set + g_out * p_suc) / (g_in + g_out + g_leak);

    let mut model = HydraulicModel::new(params).unwrap();
    let u = inputs(1.0, 1.0, 100.0);
    run(&mut model, &u, 30.0, 1e-3);
    let s = model.state();
    assert!(
        (s.cavity_pressure_pa - expected).abs() < 1e-6 * expected,
        "simulated {} mmHg, closed form {} mmHg",
        pa_to_mmhg(s.cavity_pressure_pa),
        pa_to_mmhg(expected)
    );
    assert!(expected > 0.0 && expected < mmhg_to_pa(80.0));
    let expected_inflow = g_in * (p_set - expected);
    assert!((s.flows.inflow_m3_per_s - expected_inflow).abs() < 1e-6 * expected_inflow);
    assert!(s.flows.net_m3_per_s().abs() < 1e-9 * expected_inflow);
    // The circuit's own piecewise solver agrees.
    let exact = model.steady_state_pressure_pa(&u).unwrap();
    assert!((exact - expected).abs() < 1e-9 * expected);
}

#[test]
fn steady_state_with_pump_at_its_flow_limit_and_absorption_matches_the_closed_form() {
    // Outflow shut, pump at 150 mmHg with a 100 ml/min limit and a perforation-free cavity: the pump
    // saturates and the pressure settles where leak plus absorption take Q_max:
    //   Q_max = G_leak p + G_abs (p - p_abs)  ->  p = (Q_max + G_abs p_abs) / (G_leak + G_abs)
    let mut params = HydraulicParams::default();
    params.pump.max_flow_ml_per_min = 100.0;
    params.cervix.leak_conductance_ml_per_min_per_mmhg = 0.5;
    params.absorption.conductance_ml_per_min_per_mmhg = 2.0;
    let q_max = crate::units::ml_per_min_to_m3_per_s(100.0);
    let g_leak = conductance_si(0.5);
    let g_abs = conductance_si(2.0);
    let p_abs = mmhg_to_pa(params.absorption.threshold_pressure_mmhg);
    let expected = (q_max + g_abs * p_abs) / (g_leak + g_abs);
    // (100 + 2*80) / 2.5 = 104 mmHg
    assert!((pa_to_mmhg(expected) - 104.0).abs() < 1e-9);

    let mut model = HydraulicModel::new(params).unwrap();
    let u = inputs(1.0, 0.0, 150.0);
    run(&mut model, &u, 30.0, 1e-3);
    let s = model.state();
    assert!(s.pump_flow_limited);
    assert!(
        (s.cavity_pressure_pa - expected).abs() < 1e-6 * expected,
        "{} vs {} mmHg",
        pa_to_mmhg(s.cavity_pressure_pa),
        pa_to_mmhg(expected)
    );
    assert!((s.flows.inflow_m3_per_s - q_max).abs() < 1e-15);
}

#[test]
fn steady_states_match_the_exact_piecewise_solution_for_random_circuits() {
    let mut rng = Rng::new(42);
    for case in 0..40 {
        let params = random_params(&mut rng);
        let u = HydraulicInputs {
            valve_in_opening: rng.range(0.05, 1.0),
            valve_out_opening: rng.range(0.0, 1.0),
            pump_set_pressure_pa: mmhg_to_pa(rng.range(15.0, 150.0)),
            perforation: rng.uniform() < 0.3,
        };
        let mut model = HydraulicModel::new(params).unwrap();
        let expected = model
            .steady_state_pressure_pa(&u)
            .expect("leak makes it unique");
        // Converge with large implicit steps (exact steady state is a fixed point of the scheme),
        // then check the 1 kHz scheme holds it.
        run(&mut model, &u, 200.0, 0.5);
        run(&mut model, &u, 1.0, 1e-3);
        let s = model.state();
        let scale = mmhg_to_pa(1.0);
        assert!(
            (s.cavity_pressure_pa - expected).abs() < 1e-6 * scale,
            "case {case}: {} vs {} mmHg",
            pa_to_mmhg(s.cavity_pressure_pa),
            pa_to_mmhg(expected)
        );
        // Flows balance at the steady state.
        let f = s.flows;
        assert!(
            f.net_m3_per_s().abs() <= 1e-9 * f.inflow_m3_per_s.max(1e-12),
            "case {case}"
        );
    }
}

#[test]
fn mass_balance_closes_over_long_random_valve_sequences() {
    for seed in 1..=4u64 {
        let mut rng = Rng::new(seed);
        let mut params = random_params(&mut rng);
        params.deficit.stop_pump_when_terminated = seed % 2 == 0;
        let mut model = HydraulicModel::new(params).unwrap();
        let dt = 1e-3;
        let mut u = inputs(0.0, 0.0, 0.0);
        let mut last_deficit = 0.0;
        let mut hold_steps = 0;
        for step in 0..300_000 {
            if hold_steps == 0 {
                u.valve_in_opening = rng.uniform();
                u.valve_out_opening = rng.uniform();
                u.pump_set_pressure_pa = mmhg_to_pa(rng.range(0.0, 150.0));
                // Slam a valve shut or open now and then.
                if rng.uniform() < 0.2 {
                    u.valve_in_opening = (rng.uniform() < 0.5) as u8 as f64;
                }
                u.perforation = step > 200_000 && rng.uniform() < 0.1;
                hold_steps = 1 + (rng.next_u64() % 500) as usize;
            }
            hold_steps -= 1;
            let s = model.step(&u, dt);
            assert!(
                s.deficit.deficit_m3 >= last_deficit,
                "deficit decreased at {step}"
            );
            last_deficit = s.deficit.deficit_m3;
        }
        let s = model.state();
        let throughput = s.totals.inflow_m3;
        assert!(
            m3_to_ml(throughput) > 100.0,
            "seed {seed}: too little flow to test"
        );
        let error = (s.deficit_by_balance_m3() - s.deficit.deficit_m3).abs();
        assert!(
            error <= 1e-9 * throughput,
            "seed {seed}: balance error {error:e} m^3 of {throughput:e} m^3 in"
        );
        // The booked volume stays on the compliance curve (the solver residual does not drift).
        let v_curve = model.compliance().volume_m3(s.cavity_pressure_pa);
        assert!((v_curve - s.cavity_volume_m3).abs() <= 1e-12 * v_curve.max(1e-6));
        let c = model.counters();
        assert_eq!(c.unconverged_steps, 0);
        assert!(c.max_solver_iterations < 60, "{c:?}");
    }
}

#[test]
fn pressure_time_constant_matches_c_over_g_exactly_for_a_linear_cavity() {
    // Constant compliance: p(t) = p_ss + (p0 - p_ss) e^{-t/tau}, tau = C / (G_in + G_out + G_leak).
    let params = HydraulicParams::default();
    let c = ml_to_m3(0.02) / mmhg_to_pa(1.0); // 0.02 ml/mmHg
    let compliance = LinearCompliance {
        volume_at_zero_m3: ml_to_m3(1.0),
        compliance_m3_per_pa: c,
    };
    let mut model = HydraulicModel::with_compliance(params.clone(), Box::new(compliance)).unwrap();
    let u = inputs(1.0, 1.0, 60.0);
    let g = params.inflow.line().conductance_m3_per_s_pa(1.0)
        + params.outflow.line().conductance_m3_per_s_pa(1.0)
        + conductance_si(params.cervix.leak_conductance_ml_per_min_per_mmhg);
    let tau = c / g;
    let p_ss = model.steady_state_pressure_pa(&u).unwrap();
    let p0 = model.state().cavity_pressure_pa;
    // A step too small to cross 0 Pa (the leak's kink): start at 0, settle above it.
    let dt = tau / 1000.0;
    for k in 1..=3000 {
        model.step(&u, dt);
        if k % 500 == 0 {
            let t = k as f64 * dt;
            let analytic = p_ss + (p0 - p_ss) * (-t / tau).exp();
            let err = (model.state().cavity_pressure_pa - analytic).abs() / (p_ss - p0).abs();
            // Backward Euler: relative error <= t dt / (2 tau^2) e^{-t/tau} < 1e-3.
            assert!(err < 1e-3, "t = {t}: err {err}");
        }
    }
    let measured = model.time_constant_s(&u).unwrap();
    assert!((measured - tau).abs() < 1e-12 * tau);
}

#[test]
fn pressure_time_constant_of_the_default_cavity_is_as_documented() {
    // docs/hydraulics.md: around the default operating point (valves open, pump 100 mmHg,
    // ~51 mmHg) tau = C(p)/G(p) is about 0.4 s. A small pump step (100 -> 102 mmHg) from the steady
    // state reaches 1 - 1/e of its change after tau within a few percent (the curve is nonlinear).
    let mut model = HydraulicModel::new(HydraulicParams::default()).unwrap();
    let u0 = inputs(1.0, 1.0, 100.0);
    run(&mut model, &u0, 30.0, 1e-3);
    let p0 = model.state().cavity_pressure_pa;
    let u1 = inputs(1.0, 1.0, 102.0);
    let tau = model.time_constant_s(&u1).unwrap();
    assert!((0.3..0.5).contains(&tau), "tau = {tau} s");
    let p_ss = model.steady_state_pressure_pa(&u1).unwrap();
    let dt = 1e-4;
    let mut t = 0.0;
    let target = p0 + (1.0 - (-1f64).exp()) * (p_ss - p0);
    while model.state().cavity_pressure_pa < target {
        model.step(&u1, dt);
        t += dt;
        assert!(t < 10.0 * tau);
    }
    assert!(
        (t - tau).abs() < 0.05 * tau,
        "63 % rise after {t} s, tau {tau} s"
    );
}

#[test]
fn random_and_extreme_inputs_never_give_nan_and_respect_the_pressure_bounds() {
    let bad = [
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        -1e300,
        1e300,
        0.0,
        1.0,
        -0.0,
        f64::MIN_POSITIVE,
    ];
    let dts = [
        1e-9,
        1e-6,
        1e-3,
        0.1,
        10.0,
        1e6,
        0.0,
        -1.0,
        f64::NAN,
        f64::INFINITY,
    ];
    let mut rng = Rng::new(7);
    for seed in 0..3 {
        let params = if seed == 0 {
            HydraulicParams::default()
        } else {
            random_params(&mut rng)
        };
        let p_min = mmhg_to_pa(params.outflow.suction_pressure_mmhg.min(0.0));
        let p_max = mmhg_to_pa(params.pump.max_pressure_mmhg);
        let mut model = HydraulicModel::new(params).unwrap();
        for i in 0..50_000 {
            let pick = |rng: &mut Rng| {
                if rng.uniform() < 0.3 {
                    bad[(rng.next_u64() % bad.len() as u64) as usize]
                } else {
                    rng.uniform()
                }
            };
            let u = HydraulicInputs {
                valve_in_opening: pick(&mut rng),
                valve_out_opening: pick(&mut rng),
                pump_set_pressure_pa: pick(&mut rng) * p_max * 1.5,
                perforation: i > 40_000,
            };
            let dt = if rng.uniform() < 0.1 {
                dts[(rng.next_u64() % dts.len() as u64) as usize]
            } else {
                1e-3
            };
            let s = *model.step(&u, dt);
            let all = [
                s.time_s,
                s.cavity_pressure_pa,
                s.cavity_volume_m3,
                s.flows.inflow_m3_per_s,
                s.flows.outflow_m3_per_s,
                s.flows.leak_m3_per_s,
                s.flows.absorption_m3_per_s,
                s.flows.perforation_m3_per_s,
                s.inflow_port_velocity_m_per_s,
                s.outflow_port_velocity_m_per_s,
                s.deficit.deficit_m3,
                s.deficit.rate_m3_per_s,
                s.totals.inflow_m3,
            ];
            assert!(all.iter().all(|v| v.is_finite()), "step {i}: {s:?}");
            // Maximum principle of the implicit scheme: the pressure stays between the lowest and
            // the highest source pressure.
            assert!(
                s.cavity_pressure_pa >= p_min - 1e-3 && s.cavity_pressure_pa <= p_max + 1e-3,
                "step {i}: {} mmHg",
                pa_to_mmhg(s.cavity_pressure_pa)
            );
        }
        assert!(model.counters().rejected_steps > 0 && model.counters().sanitized_inputs > 0);
        assert_eq!(model.counters().unconverged_steps, 0);
    }
}

#[test]
fn slamming_valves_and_pump_between_extremes_every_tick_stays_finite_and_balanced() {
    let mut model = HydraulicModel::new(HydraulicParams::default()).unwrap();
    for i in 0..100_000u32 {
        let on = |bit: u32| ((i >> bit) & 1) as f64;
        let u = inputs(on(0), on(1), 150.0 * on(2));
        let s = model.step(&u, 1e-3);
        assert!(s.cavity_pressure_pa.is_finite());
    }
    let s = model.state();
    let err = (s.deficit_by_balance_m3() - s.deficit.deficit_m3).abs();
    assert!(err <= 1e-9 * s.totals.inflow_m3);
}

#[test]
fn port_velocities_are_about_two_metres_per_second_at_fully_open_valves() {
    let params = HydraulicParams::default();
    let mut model = HydraulicModel::new(params.clone()).unwrap();
    run(&mut model, &inputs(1.0, 1.0, 100.0), 20.0, 1e-3);
    let s = model.state();
    let v_in = s.inflow_port_velocity_m_per_s;
    let v_out = s.outflow_port_velocity_m_per_s;
    assert!((v_in - s.flows.inflow_m3_per_s / (params.inflow.port_area_mm2 * 1e-6)).abs() < 1e-12);
    assert!((1.6..2.4).contains(&v_in), "inflow port {v_in} m/s");
    assert!((1.6..2.4).contains(&v_out), "outflow port {v_out} m/s");
    // Shut valves: no jet.
    run(&mut model, &inputs(0.0, 0.0, 100.0), 1.0, 1e-3);
    assert_eq!(model.state().inflow_port_velocity_m_per_s, 0.0);
    assert_eq!(model.state().outflow_port_velocity_m_per_s, 0.0);
}

#[test]
fn perforation_drives_the_deficit_to_termination_which_stops_the_pump_until_reset() {
    let mut params = HydraulicParams::default();
    params.deficit.limit = DeficitLimit::Custom;
    params.deficit.custom_limit_ml = 100.0;
    let mut model = HydraulicModel::new(params).unwrap();
    let mut u = inputs(1.0, 0.3, 100.0);
    run(&mut model, &u, 10.0, 1e-3);
    let before = *model.state();
    assert!(!before.deficit.rate_alarm && !before.deficit.terminated);
    let p_before = before.cavity_pressure_pa;

    u.perforation = true;
    let mut t = 0.0;
    let mut rate_alarm_at = None;
    loop {
        let last_deficit = model.state().deficit.deficit_m3;
        let s = *model.step(&u, 1e-3);
        t += 1e-3;
        if s.deficit.rate_alarm && rate_alarm_at.is_none() {
            rate_alarm_at = Some(t);
        }
        if t > 0.999 && t < 1.0005 {
            assert!(s.perforated);
            assert!(
                s.cavity_pressure_pa < 0.5 * p_before,
                "pressure collapses on perforation"
            );
            let rate = m3_per_s_to_ml_per_min(s.flows.perforation_m3_per_s);
            assert!(rate > 150.0, "perforation loses {rate} ml/min");
        }
        if s.deficit.terminated {
            // Fires on the step that crosses the limit, not before, not after.
            assert!(m3_to_ml(s.deficit.deficit_m3) >= 100.0);
            assert!(m3_to_ml(last_deficit) < 100.0);
            break;
        }
        assert!(t < 120.0, "never terminated");
    }
    let rate_alarm_at = rate_alarm_at.expect("rate alarm before termination");
    assert!(
        rate_alarm_at < t,
        "rate alarm at {rate_alarm_at} s, limit at {t} s"
    );
    // The pump stops and the latch holds while inputs keep asking for flow.
    run(&mut model, &u, 5.0, 1e-3);
    let s = *model.state();
    assert!(s.deficit.terminated && s.pump_stopped);
    assert_eq!(s.flows.inflow_m3_per_s, 0.0);
    // Only a new procedure clears it.
    model.start_new_procedure(ProcedureInfo {
        id: 2,
        started_unix_ms: 0,
    });
    let s = *model.state();
    assert_eq!(s.deficit.deficit_m3, 0.0);
    assert!(!s.deficit.terminated && !s.perforated);
    assert_eq!(s.totals, CumulativeVolumes::default());
    u.perforation = false;
    run(&mut model, &u, 5.0, 1e-3);
    assert!(model.state().flows.inflow_m3_per_s > 0.0);
    let s = model.state();
    assert!((s.deficit_by_balance_m3() - s.deficit.deficit_m3).abs() < 1e-15);
}

#[test]
fn a_restored_procedure_continues_exactly_as_if_never_interrupted() {
    let mut rng = Rng::new(99);
    let params = random_params(&mut rng);
    let mut a = HydraulicModel::new(params.clone()).unwrap();
    a.start_new_procedure(ProcedureInfo {
        id: 11,
        started_unix_ms: 123,
    });
    let mut seq = Vec::new();
    for i in 0..20_000 {
        if i % 700 == 0 {
            seq.push(HydraulicInputs {
                valve_in_opening: rng.uniform(),
                valve_out_opening: rng.uniform(),
                pump_set_pressure_pa: mmhg_to_pa(rng.range(20.0, 150.0)),
                perforation: i > 12_000,
            });
        }
    }
    let input_at = |i: usize| seq[i / 700];
    for i in 0..10_000 {
        a.step(&input_at(i), 1e-3);
    }
    // "Crash": persist as text, parse, restore into a fresh model.
    let text = a.record(1000).to_text();
    let record = ProcedureRecord::from_text(&text, std::path::Path::new("mem")).unwrap();
    let mut b = HydraulicModel::new(params).unwrap();
    b.restore(&record);
    assert_eq!(b.procedure(), a.procedure());
    assert_eq!(b.state().deficit, a.state().deficit);
    for i in 10_000..20_000 {
        let sa = *a.step(&input_at(i), 1e-3);
        let sb = *b.step(&input_at(i), 1e-3);
        assert_eq!(sa, sb, "diverged at step {i}");
    }
    assert!(a.state().perforated && a.state().deficit.deficit_m3 > 0.0);
}

/// A compliance swap mid-procedure (the daemon's hydraulics run on the parameters' curve until
/// the scene's atlas arrives, then on the atlas's) keeps the published pressure and the deficit
/// continuous, for any pair of curves: the new curve's resting volume may be larger than the
/// cavity's volume (which the atlas's maps to a negative pressure) or smaller.
#[test]
fn swapping_the_compliance_keeps_pressure_and_deficit_continuous_whatever_the_curves() {
    let mut rng = Rng::new(28);
    for case in 0..40 {
        let mut model = HydraulicModel::new(random_params(&mut rng)).unwrap();
        model.start_new_procedure(ProcedureInfo {
            id: 1,
            started_unix_ms: 1,
        });
        let pump = rng.range(20.0, 150.0);
        run(
            &mut model,
            &inputs(rng.uniform(), rng.uniform(), pump),
            rng.range(0.1, 5.0),
            1e-3,
        );
        let before = *model.state();
        // The new curve holds from a tenth to ten times the cavity's volume at its pressure now
        // (the old volume then maps to a pressure far above or below it, possibly negative).
        let compliance_m3_per_pa = ml_to_m3(rng.range(0.005, 0.2)) / mmhg_to_pa(1.0);
        let curve = LinearCompliance {
            volume_at_zero_m3: before.cavity_volume_m3 * 10f64.powf(rng.range(-1.0, 1.0))
                - compliance_m3_per_pa * before.cavity_pressure_pa,
            compliance_m3_per_pa,
        };
        model.set_compliance(Box::new(curve));
        let after = *model.state();
        assert_eq!(
            after.cavity_pressure_pa, before.cavity_pressure_pa,
            "case {case}"
        );
        assert_eq!(
            after.cavity_volume_m3,
            curve.volume_m3(before.cavity_pressure_pa)
        );
        assert_eq!(after.deficit.deficit_m3, before.deficit.deficit_m3);
        let tolerance = 1e-12 + 1e-9 * before.totals.inflow_m3;
        assert!(
            (after.deficit_by_balance_m3() - before.deficit_by_balance_m3()).abs() <= tolerance,
            "case {case}: the balance moved from {} to {}",
            before.deficit_by_balance_m3(),
            after.deficit_by_balance_m3()
        );
        // The next tick goes on from there: the pressure moves by what one tick can move it.
        model.step(&inputs(0.0, 0.0, 0.0), 1e-3);
        let next = model.state();
        assert!(
            (next.cavity_pressure_pa - after.cavity_pressure_pa).abs() < mmhg_to_pa(2.0),
            "case {case}: {} -> {} mmHg in one tick",
            pa_to_mmhg(after.cavity_pressure_pa),
            pa_to_mmhg(next.cavity_pressure_pa)
        );
        assert!(
            (next.deficit_by_balance_m3() - next.deficit.deficit_m3).abs()
                <= 1e-9 + 1e-6 * next.totals.inflow_m3,
            "case {case}: balance {} against accumulated {}",
            next.deficit_by_balance_m3(),
            next.deficit.deficit_m3
        );
    }
}

//! `hydrometra hydraulics ...`: run the hydraulic model offline on a scenario and tabulate it.

use std::fmt::Write as _;
use std::path::PathBuf;

use crate::scenario::load_scenario;
use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use hydrometra_sim::hydraulics::{
    HydraulicInputs, HydraulicModel, HydraulicParams, HydraulicState,
};
use hydrometra_sim::units::{m3_per_s_to_ml_per_min, m3_to_ml, mmhg_to_pa, pa_to_mmhg};

/// Hydraulic model tools.
#[derive(Subcommand, Debug)]
pub enum HydraulicsCommand {
    /// Drive the hydraulic model from a scenario's valve and pump keyframes (and its
    /// `[hydraulics]` case events) and write the trace as CSV, a markdown table and an SVG plot.
    Simulate(SimulateArgs),
    /// Print the default hydraulic parameters as TOML (the daemon's `[hydraulics]` keys).
    PrintDefaultParams,
}

/// One plotted sample: t, pressure mmHg, inflow, outflow, perforation ml/min, deficit ml.
type PlotPoint = (f64, f64, f64, f64, f64, f64);

/// Writes the three-panel SVG plot (pressure; flows; deficit with its limit) of a trace.
fn write_plot(
    path: &std::path::Path,
    title: &str,
    points: &[PlotPoint],
    limit_ml: f64,
) -> Result<()> {
    use plotters::prelude::*;
    let t_max = points.last().map_or(1.0, |p| p.0).max(1.0);
    let max_of = |f: fn(&PlotPoint) -> f64| points.iter().map(f).fold(1.0_f64, f64::max);
    let p_max = max_of(|p| p.1) * 1.1;
    let p_min = points.iter().map(|p| p.1).fold(0.0_f64, f64::min) * 1.1;
    // The perforation's first instant drains the distended cavity at several l/min; scale the
    // flow axis to the pump's flows so the sustained loss stays readable (the spike is clipped).
    let q_max = max_of(|p| p.2.max(p.3)) * 1.3;
    let d_max = max_of(|p| p.5).max(limit_ml) * 1.1;
    let root = SVGBackend::new(path, (1000, 900)).into_drawing_area();
    let draw = || -> std::result::Result<(), Box<dyn std::error::Error>> {
        root.fill(&WHITE)?;
        let panels = root.split_evenly((3, 1));
        let mut c = ChartBuilder::on(&panels[0])
            .caption(format!("{title}: cavity pressure"), ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(28)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..t_max, p_min..p_max)?;
        c.configure_mesh().x_desc("t (s)").y_desc("mmHg").draw()?;
        c.draw_series(LineSeries::new(points.iter().map(|p| (p.0, p.1)), &BLUE))?;

        let mut c = ChartBuilder::on(&panels[1])
            .caption("flows (perforation transient clipped)", ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(28)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..t_max, 0.0..q_max)?;
        c.configure_mesh().x_desc("t (s)").y_desc("ml/min").draw()?;
        for (series, color, label) in [
            (2usize, BLUE, "inflow"),
            (3, GREEN, "outflow"),
            (4, RED, "perforation"),
        ] {
            let pick = move |p: &PlotPoint| match series {
                2 => p.2,
                3 => p.3,
                _ => p.4,
            };
            c.draw_series(LineSeries::new(
                points.iter().map(|p| (p.0, pick(p))),
                &color,
            ))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;

        let mut c = ChartBuilder::on(&panels[2])
            .caption("fluid deficit", ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(28)
            .y_label_area_size(55)
            .build_cartesian_2d(0.0..t_max, 0.0..d_max)?;
        c.configure_mesh().x_desc("t (s)").y_desc("ml").draw()?;
        c.draw_series(LineSeries::new(points.iter().map(|p| (p.0, p.5)), &BLACK))?
            .label("deficit")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
        c.draw_series(LineSeries::new(
            vec![(0.0, limit_ml), (t_max, limit_ml)],
            &RED,
        ))?
        .label("limit")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
        root.present()?;
        Ok(())
    };
    draw().map_err(|e| anyhow::anyhow!("drawing {}: {e}", path.display()))
}

/// Arguments of `hydrometra hydraulics simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
    /// Scenario: a built-in name (`default`) or a scenario TOML file.
    #[arg(long, default_value = "default")]
    pub scenario: String,
    /// Hydraulic parameters (TOML); a scenario's `[hydraulics.params]` replaces them.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// Output directory for `hydraulics.csv`, `hydraulics.md` and `hydraulics.svg` (plot).
    #[arg(long, default_value = "hydraulics-out")]
    pub out: PathBuf,
    /// Simulated time, s (default: the scenario's length).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Model time step, ms (the daemon ticks at 1 ms).
    #[arg(long, default_value_t = 1.0)]
    pub dt_ms: f64,
    /// CSV row interval, s.
    #[arg(long, default_value_t = 0.1)]
    pub csv_every_s: f64,
    /// Markdown table row interval, s.
    #[arg(long, default_value_t = 5.0)]
    pub table_every_s: f64,
}

/// Runs a `hydraulics` subcommand.
pub fn run(command: HydraulicsCommand) -> Result<()> {
    match command {
        HydraulicsCommand::Simulate(args) => simulate(&args),
        HydraulicsCommand::PrintDefaultParams => {
            print!("{}", HydraulicParams::default_toml());
            Ok(())
        }
    }
}

fn check_positive(flag: &str, value: f64) -> Result<()> {
    if !(value.is_finite() && value > 0.0) {
        bail!("{flag} = {value}: expected a finite number > 0");
    }
    Ok(())
}

/// One traced row.
struct Row {
    t_s: f64,
    inputs: HydraulicInputs,
    state: HydraulicState,
}

fn csv_header() -> &'static str {
    "t_s,valve_in,valve_out,pump_mmhg,perforated,cavity_pressure_mmhg,cavity_volume_ml,\
     inflow_ml_per_min,outflow_ml_per_min,leak_ml_per_min,absorption_ml_per_min,\
     perforation_ml_per_min,inflow_port_m_per_s,outflow_port_m_per_s,total_in_ml,\
     total_collected_ml,deficit_ml,deficit_rate_ml_per_min,warning_stage,rate_alarm,terminated,\
     pump_stopped,overpressure"
}

fn csv_row(r: &Row) -> String {
    let s = &r.state;
    let f = &s.flows;
    format!(
        "{:.3},{:.3},{:.3},{:.2},{},{:.3},{:.4},{:.2},{:.2},{:.2},{:.2},{:.2},{:.3},{:.3},{:.3},{:.3},\
         {:.3},{:.2},{},{},{},{},{}",
        r.t_s,
        r.inputs.valve_in_opening,
        r.inputs.valve_out_opening,
        pa_to_mmhg(r.inputs.pump_set_pressure_pa),
        u8::from(s.perforated),
        pa_to_mmhg(s.cavity_pressure_pa),
        m3_to_ml(s.cavity_volume_m3),
        m3_per_s_to_ml_per_min(f.inflow_m3_per_s),
        m3_per_s_to_ml_per_min(f.outflow_m3_per_s),
        m3_per_s_to_ml_per_min(f.leak_m3_per_s),
        m3_per_s_to_ml_per_min(f.absorption_m3_per_s),
        m3_per_s_to_ml_per_min(f.perforation_m3_per_s),
        s.inflow_port_velocity_m_per_s,
        s.outflow_port_velocity_m_per_s,
        m3_to_ml(s.totals.inflow_m3),
        m3_to_ml(s.totals.collected_m3()),
        m3_to_ml(s.deficit.deficit_m3),
        m3_per_s_to_ml_per_min(s.deficit.rate_m3_per_s),
        s.deficit.warning_stage,
        u8::from(s.deficit.rate_alarm),
        u8::from(s.deficit.terminated),
        u8::from(s.pump_stopped),
        u8::from(s.deficit.overpressure),
    )
}

fn md_row(r: &Row) -> String {
    let s = &r.state;
    let f = &s.flows;
    let mut alarms = Vec::new();
    if s.deficit.warning_stage > 0 {
        alarms.push(format!("warn {}", s.deficit.warning_stage));
    }
    if s.deficit.rate_alarm {
        alarms.push("rate".into());
    }
    if s.deficit.terminated {
        alarms.push("TERMINATED".into());
    }
    if s.deficit.overpressure {
        alarms.push("overpressure".into());
    }
    format!(
        "| {:.0} | {:.2} / {:.2} | {:.0} | {} | {:.1} | {:.2} | {:.0} | {:.0} | {:.0} | {:.0} | {:.0} | {:.2} | {:.1} | {:.0} | {} |",
        r.t_s,
        r.inputs.valve_in_opening,
        r.inputs.valve_out_opening,
        pa_to_mmhg(r.inputs.pump_set_pressure_pa),
        if s.perforated { "yes" } else { "" },
        pa_to_mmhg(s.cavity_pressure_pa),
        m3_to_ml(s.cavity_volume_m3),
        m3_per_s_to_ml_per_min(f.inflow_m3_per_s),
        m3_per_s_to_ml_per_min(f.outflow_m3_per_s),
        m3_per_s_to_ml_per_min(f.leak_m3_per_s + f.absorption_m3_per_s),
        m3_per_s_to_ml_per_min(f.perforation_m3_per_s),
        m3_per_s_to_ml_per_min(s.deficit.rate_m3_per_s),
        s.inflow_port_velocity_m_per_s,
        m3_to_ml(s.deficit.deficit_m3),
        m3_to_ml(s.deficit.limit_m3),
        alarms.join(", "),
    )
}

fn simulate(args: &SimulateArgs) -> Result<()> {
    check_positive("--dt-ms", args.dt_ms)?;
    check_positive("--csv-every-s", args.csv_every_s)?;
    check_positive("--table-every-s", args.table_every_s)?;
    let (scenario, case) = load_scenario(&args.scenario)?;
    let params = match (&case.params, &args.params) {
        (Some(p), _) => p.clone(),
        (None, Some(path)) => HydraulicParams::load(path)?,
        (None, None) => HydraulicParams::default(),
    };
    let duration_s = args.duration_s.unwrap_or_else(|| scenario.duration_s());
    check_positive("--duration-s", duration_s)?;
    let dt = args.dt_ms * 1e-3;
    let steps = (duration_s / dt).round() as u64;
    if steps > 100_000_000 {
        bail!("--duration-s / --dt-ms = {steps} steps: expected at most 1e8");
    }
    let csv_every = ((args.csv_every_s / dt).round() as u64).max(1);
    let table_every = ((args.table_every_s / dt).round() as u64).max(1);

    let mut model = HydraulicModel::new(params.clone())?;
    let mut csv = String::from(csv_header());
    csv.push('\n');
    let mut table = Vec::new();
    let mut plot = Vec::new();
    let mut events = Vec::new();
    let mut last_stage = 0;
    let mut last_rate = false;
    let mut last_terminated = false;
    let mut last_perforated = false;
    for k in 0..=steps {
        let t_s = k as f64 * dt;
        let sample = scenario.sample_at(t_s);
        let loop_t = if scenario.looping && scenario.duration_s() > 0.0 {
            t_s.rem_euclid(scenario.duration_s())
        } else {
            t_s
        };
        let inputs = HydraulicInputs {
            valve_in_opening: sample.valve_in,
            valve_out_opening: sample.valve_out,
            pump_set_pressure_pa: mmhg_to_pa(sample.pump_mmhg),
            perforation: case.perforated_at(loop_t),
        };
        let state = if k == 0 {
            *model.state()
        } else {
            *model.step(&inputs, dt)
        };
        let d = &state.deficit;
        if state.perforated && !last_perforated {
            events.push(format!("{t_s:.1} s: perforation"));
        }
        if d.warning_stage > last_stage {
            events.push(format!(
                "{t_s:.1} s: warning stage {} ({:.0} ml = {:.0} % of the limit)",
                d.warning_stage,
                m3_to_ml(d.deficit_m3),
                100.0 * d.fraction_of_limit()
            ));
        }
        if d.rate_alarm != last_rate {
            events.push(format!(
                "{t_s:.1} s: deficit-rate alarm {} (averaged rate {:.0} ml/min)",
                if d.rate_alarm { "on" } else { "off" },
                m3_per_s_to_ml_per_min(d.rate_m3_per_s)
            ));
        }
        if d.terminated && !last_terminated {
            events.push(format!(
                "{t_s:.1} s: TERMINATED at {:.1} ml (limit {:.0} ml); pump stopped",
                m3_to_ml(d.deficit_m3),
                m3_to_ml(d.limit_m3)
            ));
        }
        last_stage = d.warning_stage;
        last_rate = d.rate_alarm;
        last_terminated = d.terminated;
        last_perforated = state.perforated;
        let row = Row { t_s, inputs, state };
        if k % csv_every == 0 {
            let s = &row.state;
            plot.push((
                t_s,
                pa_to_mmhg(s.cavity_pressure_pa),
                m3_per_s_to_ml_per_min(s.flows.inflow_m3_per_s),
                m3_per_s_to_ml_per_min(s.flows.outflow_m3_per_s),
                m3_per_s_to_ml_per_min(s.flows.perforation_m3_per_s),
                m3_to_ml(s.deficit.deficit_m3),
            ));
            csv.push_str(&csv_row(&row));
            csv.push('\n');
        }
        if k % table_every == 0 {
            table.push(md_row(&row));
        }
    }

    let s = model.state();
    let balance_error_ml = m3_to_ml((s.deficit_by_balance_m3() - s.deficit.deficit_m3).abs());
    let c = model.counters();
    let mut md = String::new();
    let _ = writeln!(
        md,
        "Hydraulic trace of scenario `{}` ({duration_s:.0} s, dt = {} ms), written by\n\
         `hydrometra hydraulics simulate --scenario {} --out {}`.\n",
        scenario.name,
        args.dt_ms,
        args.scenario,
        args.out.display()
    );
    let _ = writeln!(md, "Events:\n");
    for e in &events {
        let _ = writeln!(md, "- {e}");
    }
    let _ = writeln!(
        md,
        "\nEnd: in {:.1} ml, collected {:.1} ml, cavity change {:+.2} ml, deficit {:.2} ml \
         (by balance: in - collected - cavity change; difference {balance_error_ml:.1e} ml); \
         solver: {} steps, mean {:.2} / max {} iterations, {} unconverged.\n",
        m3_to_ml(s.totals.inflow_m3),
        m3_to_ml(s.totals.collected_m3()),
        m3_to_ml(s.cavity_volume_m3 - s.initial_cavity_volume_m3),
        m3_to_ml(s.deficit.deficit_m3),
        c.steps,
        c.solver_iterations as f64 / c.steps.max(1) as f64,
        c.max_solver_iterations,
        c.unconverged_steps,
    );
    let _ = writeln!(
        md,
        "| t s | valve in / out | pump mmHg | perforated | cavity mmHg | cavity ml | in ml/min | out ml/min | leak+abs ml/min | perf ml/min | deficit rate ml/min | port m/s | deficit ml | limit ml | alarms |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    );
    for r in &table {
        let _ = writeln!(md, "{r}");
    }

    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating output directory {}", args.out.display()))?;
    let csv_path = args.out.join("hydraulics.csv");
    let md_path = args.out.join("hydraulics.md");
    let svg_path = args.out.join("hydraulics.svg");
    write_plot(
        &svg_path,
        &format!("scenario {}", scenario.name),
        &plot,
        m3_to_ml(s.deficit.limit_m3),
    )?;
    std::fs::write(&csv_path, csv).with_context(|| format!("writing {}", csv_path.display()))?;
    std::fs::write(&md_path, &md).with_context(|| format!("writing {}", md_path.display()))?;
    for e in &events {
        println!("{e}");
    }
    println!(
        "deficit {:.1} ml of {:.0} ml; wrote {}, {} and {}",
        m3_to_ml(s.deficit.deficit_m3),
        m3_to_ml(s.deficit.limit_m3),
        csv_path.display(),
        md_path.display(),
        svg_path.display()
    );
    Ok(())
}

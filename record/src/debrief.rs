//! The debrief: fluid-handling metrics of a recorded procedure and the instructor's report.
//! Every metric is defined in `docs/debrief.md`; this module is the one implementation of them.

use std::fmt::Write as _;
use std::path::Path;

use hydrometra_ipc::{alarms, status::link_state, Status};
use hydrometra_sim::units::{m3_per_s_to_ml_per_min, m3_to_ml, pa_to_mmhg};
use serde::Serialize;

use super::reader::Recording;

/// Thresholds of the debrief (the defaults are in `docs/debrief.md`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DebriefSettings {
    /// Cavity pressure at or above which the cavity counts as distended, Pa.
    pub distended_pa: f64,
    /// A valve must move by more than this (opening, 0..1) to count as an adjustment.
    pub valve_band: f64,
    /// The pump setting must move by more than this to count as an adjustment, Pa.
    pub pump_band_pa: f64,
    /// A control is at rest again after changing by less than a fifth of its band for this long, s.
    pub settle_s: f64,
    /// The view is clear at or above this view clarity, obscured below (the particles stage's
    /// `view.clear_threshold`).
    pub clear_view_clarity: f64,
}

impl Default for DebriefSettings {
    fn default() -> Self {
        Self {
            distended_pa: hydrometra_sim::units::mmhg_to_pa(40.0),
            valve_band: 0.05,
            pump_band_pa: hydrometra_sim::units::mmhg_to_pa(5.0),
            settle_s: 0.5,
            clear_view_clarity: hydrometra_sim::scene::clarity::ViewSpec::default().clear_threshold,
        }
    }
}

/// One alarm raised or cleared.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AlarmEntry {
    /// Time since the recording's first status, s.
    pub t_s: f64,
    /// Alarm name (`docs/ipc.md`).
    pub name: String,
    /// True when raised, false when cleared.
    pub raised: bool,
}

/// Perforation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Perforation {
    /// The uterus was perforated during the recording.
    pub occurred: bool,
    /// When the perforated flag first showed, s.
    pub at_s: Option<f64>,
    /// Fluid lost through the perforation, ml.
    pub volume_ml: f64,
}

/// A metric that needs a status field this recording may not have.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ViewMetrics {
    /// Time from the first status to the first clear view, s.
    pub time_to_first_clear_view_s: Option<f64>,
    /// Fraction of the time with the view obscured.
    pub fraction_obscured: Option<f64>,
    /// Why they are missing, if they are.
    pub unavailable: Option<String>,
    /// The view counts as clear at or above this clarity.
    pub clear_view_clarity: f64,
}

/// The fluid-handling metrics of one recording (`metrics.json`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Metrics {
    /// The recording.
    pub file: String,
    /// Procedure id (`Status::procedure_id`).
    pub procedure_id: u64,
    /// From the first to the last recorded status, s.
    pub duration_s: f64,
    /// Statuses the metrics are computed from.
    pub statuses: usize,
    /// Fluid the pump delivered during the recording, ml.
    pub fluid_in_ml: f64,
    /// Fluid collected during the recording, ml.
    pub fluid_collected_ml: f64,
    /// Fluid deficit at the end (the procedure's, including any before the recording), ml.
    pub deficit_ml: f64,
    /// Deficit gained during the recording, ml.
    pub deficit_gained_ml: f64,
    /// The configured deficit limit, ml.
    pub deficit_limit_ml: f64,
    /// Highest averaged deficit rate, ml/min.
    pub peak_deficit_rate_ml_per_min: f64,
    /// When it occurred, s.
    pub peak_deficit_rate_at_s: f64,
    /// Highest cavity pressure, mmHg.
    pub max_cavity_pressure_mmhg: f64,
    /// Time with the `overpressure` alarm set, s.
    pub time_above_overpressure_s: f64,
    /// Time with the cavity pressure at or above `distended_mmhg`, s.
    pub time_distended_s: f64,
    /// The distension threshold used, mmHg.
    pub distended_mmhg: f64,
    /// Inflow valve adjustments.
    pub valve_in_adjustments: u32,
    /// Outflow valve adjustments.
    pub valve_out_adjustments: u32,
    /// Pump setting adjustments.
    pub pump_adjustments: u32,
    /// Alarms raised and cleared, in time order.
    pub alarms: Vec<AlarmEntry>,
    /// Perforation.
    pub perforation: Perforation,
    /// Scope tip path length while the pose was valid, m.
    pub scope_path_length_m: f64,
    /// Time on the safe inputs (rig lost or stale), s.
    pub time_in_safe_state_s: f64,
    /// View clarity metrics.
    pub view: ViewMetrics,
    /// The recording was not finished (daemon killed); metrics cover what was written.
    pub truncated: bool,
}

/// Counts adjustments of one control: an adjustment starts when the value leaves the band around
/// its resting value and ends once the value has changed by less than a fifth of the band for
/// `settle_s` (so a slow, continuous turn is one adjustment, however long it takes).
#[derive(Debug)]
struct AdjustmentCounter {
    band: f64,
    settle_s: f64,
    rest: Option<f64>,
    /// While moving: the value and time of the last change larger than `band / 5`.
    moving: Option<(f64, f64)>,
    count: u32,
}

impl AdjustmentCounter {
    fn new(band: f64, settle_s: f64) -> Self {
        Self {
            band,
            settle_s,
            rest: None,
            moving: None,
            count: 0,
        }
    }

    fn push(&mut self, t: f64, v: f64) {
        let Some(rest) = self.rest else {
            self.rest = Some(v);
            return;
        };
        match self.moving {
            None => {
                if (v - rest).abs() > self.band {
                    self.count += 1;
                    self.moving = Some((v, t));
                }
            }
            Some((anchor, since)) => {
                if (v - anchor).abs() > self.band / 5.0 {
                    self.moving = Some((v, t));
                } else if t - since >= self.settle_s {
                    self.rest = Some(v);
                    self.moving = None;
                }
            }
        }
    }
}

/// Computes the metrics of `rec`.
pub fn metrics(rec: &Recording, settings: &DebriefSettings) -> Result<Metrics, String> {
    let st = &rec.statuses;
    let (Some((t_first, first)), Some((t_last, last))) = (st.first(), st.last()) else {
        return Err(format!(
            "{}: no status in the recording: nothing to debrief",
            rec.path.display()
        ));
    };
    let secs = |t: u64| t.saturating_sub(*t_first) as f64 * 1e-9;
    let mut m = Metrics {
        file: rec.path.display().to_string(),
        procedure_id: last.procedure_id,
        duration_s: secs(*t_last),
        statuses: st.len(),
        fluid_in_ml: m3_to_ml(last.fluid_in_m3 - first.fluid_in_m3),
        fluid_collected_ml: m3_to_ml(last.fluid_collected_m3 - first.fluid_collected_m3),
        deficit_ml: m3_to_ml(last.deficit_m3),
        deficit_gained_ml: m3_to_ml(last.deficit_m3 - first.deficit_m3),
        deficit_limit_ml: m3_to_ml(last.deficit_limit_m3),
        peak_deficit_rate_ml_per_min: 0.0,
        peak_deficit_rate_at_s: 0.0,
        max_cavity_pressure_mmhg: f64::NEG_INFINITY,
        time_above_overpressure_s: 0.0,
        time_distended_s: 0.0,
        distended_mmhg: pa_to_mmhg(settings.distended_pa),
        valve_in_adjustments: 0,
        valve_out_adjustments: 0,
        pump_adjustments: 0,
        alarms: Vec::new(),
        perforation: Perforation {
            occurred: false,
            at_s: None,
            volume_ml: 0.0,
        },
        scope_path_length_m: 0.0,
        time_in_safe_state_s: 0.0,
        view: view_metrics(st, settings.clear_view_clarity),
        truncated: rec.truncated.is_some(),
    };
    let mut valve_in = AdjustmentCounter::new(settings.valve_band, settings.settle_s);
    let mut valve_out = AdjustmentCounter::new(settings.valve_band, settings.settle_s);
    let mut pump = AdjustmentCounter::new(settings.pump_band_pa, settings.settle_s);
    let mut peak_rate = f64::NEG_INFINITY;
    let mut prev: Option<(f64, &Status)> = None;
    for (t_ns, s) in st {
        let t = secs(*t_ns);
        m.max_cavity_pressure_mmhg = m
            .max_cavity_pressure_mmhg
            .max(pa_to_mmhg(s.cavity_pressure_pa));
        if s.deficit_rate_m3_per_s > peak_rate {
            peak_rate = s.deficit_rate_m3_per_s;
            m.peak_deficit_rate_at_s = t;
        }
        if s.link_state == link_state::CONNECTED {
            valve_in.push(t, s.rig_valve_in_opening);
            valve_out.push(t, s.rig_valve_out_opening);
            pump.push(t, s.rig_pump_set_pressure_pa);
        }
        let perforated = s.hydraulic_flags & (1 << 1) != 0;
        if perforated && m.perforation.at_s.is_none() {
            m.perforation.occurred = true;
            m.perforation.at_s = Some(t);
        }
        if let Some((tp, p)) = prev {
            // Each status holds over the interval to the next one (left Riemann sum).
            let dt = t - tp;
            if p.alarm_bits & alarms::OVERPRESSURE != 0 {
                m.time_above_overpressure_s += dt;
            }
            if p.cavity_pressure_pa >= settings.distended_pa {
                m.time_distended_s += dt;
            }
            if p.safe_state != 0 {
                m.time_in_safe_state_s += dt;
            }
            m.perforation.volume_ml += m3_to_ml(p.perforation_m3_per_s * dt);
            if p.scope_pose_valid != 0 && s.scope_pose_valid != 0 {
                let d: f64 = (0..3)
                    .map(|i| (s.scope_tip_position_m[i] - p.scope_tip_position_m[i]).powi(2))
                    .sum();
                m.scope_path_length_m += d.sqrt();
            }
            let (raised, cleared) = (s.alarm_bits & !p.alarm_bits, p.alarm_bits & !s.alarm_bits);
            for (bits, up) in [(raised, true), (cleared, false)] {
                for name in alarms::names(bits) {
                    m.alarms.push(AlarmEntry {
                        t_s: t,
                        name,
                        raised: up,
                    });
                }
            }
        } else {
            for name in alarms::names(s.alarm_bits) {
                m.alarms.push(AlarmEntry {
                    t_s: t,
                    name,
                    raised: true,
                });
            }
        }
        prev = Some((t, s));
    }
    m.peak_deficit_rate_ml_per_min = m3_per_s_to_ml_per_min(peak_rate.max(0.0));
    m.valve_in_adjustments = valve_in.count;
    m.valve_out_adjustments = valve_out.count;
    m.pump_adjustments = pump.count;
    Ok(m)
}

/// The view metrics from the statuses' `view_clarity` (NaN while no scene with a particle stage
/// runs): the time from the first status to the first clear one, and the fraction of the time with
/// a clarity figure during which the view was obscured (each status holds until the next).
fn view_metrics(st: &[(u64, Status)], clear: f64) -> ViewMetrics {
    let Some((t_first, _)) = st.first() else {
        return ViewMetrics {
            time_to_first_clear_view_s: None,
            fraction_obscured: None,
            unavailable: Some("no status".into()),
            clear_view_clarity: clear,
        };
    };
    let secs = |t: u64| t.saturating_sub(*t_first) as f64 * 1e-9;
    if !st.iter().any(|(_, s)| s.view_clarity.is_finite()) {
        return ViewMetrics {
            time_to_first_clear_view_s: None,
            fraction_obscured: None,
            unavailable: Some(
                "no status of this recording carries a view-clarity figure (the scene ran \
                 without a particle stage, or no scene ran)"
                    .into(),
            ),
            clear_view_clarity: clear,
        };
    }
    let first_clear = st
        .iter()
        .find(|(_, s)| s.view_clarity >= clear)
        .map(|(t, _)| secs(*t));
    let (mut with_figure_s, mut obscured_s) = (0.0, 0.0);
    for w in st.windows(2) {
        let ((ta, a), (tb, _)) = (&w[0], &w[1]);
        if a.view_clarity.is_finite() {
            let dt = secs(*tb) - secs(*ta);
            with_figure_s += dt;
            if a.view_clarity < clear {
                obscured_s += dt;
            }
        }
    }
    ViewMetrics {
        time_to_first_clear_view_s: first_clear,
        fraction_obscured: (with_figure_s > 0.0).then(|| obscured_s / with_figure_s),
        unavailable: None,
        clear_view_clarity: clear,
    }
}

/// Writes `metrics.json`, `report.md` and the SVG plots into `out`.
pub fn write_report(rec: &Recording, m: &Metrics, out: &Path) -> anyhow::Result<()> {
    use anyhow::Context;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let json = serde_json::to_string_pretty(m)?;
    std::fs::write(out.join("metrics.json"), json)
        .with_context(|| format!("cannot write {}", out.join("metrics.json").display()))?;
    plots::write_all(rec, m, out)?;
    let mut md = String::new();
    let _ = writeln!(md, "# Procedure debrief\n");
    let _ = writeln!(
        md,
        "Recording `{}`, procedure {}, {:.1} s ({} statuses){}.\n",
        m.file,
        m.procedure_id,
        m.duration_s,
        m.statuses,
        if m.truncated {
            "; the file was not finished (daemon stopped abruptly): metrics cover what was written"
        } else {
            ""
        }
    );
    let _ = writeln!(md, "Definitions: docs/debrief.md.\n");
    let _ = writeln!(md, "| metric | value |\n|---|---:|");
    let rows: Vec<(&str, String)> = vec![
        ("fluid in", format!("{:.0} ml", m.fluid_in_ml)),
        ("fluid collected", format!("{:.0} ml", m.fluid_collected_ml)),
        (
            "fluid deficit at the end (limit)",
            format!("{:.0} ml ({:.0} ml)", m.deficit_ml, m.deficit_limit_ml),
        ),
        (
            "deficit gained in this recording",
            format!("{:.0} ml", m.deficit_gained_ml),
        ),
        (
            "peak deficit rate",
            format!(
                "{:.0} ml/min at {:.1} s",
                m.peak_deficit_rate_ml_per_min, m.peak_deficit_rate_at_s
            ),
        ),
        (
            "highest cavity pressure",
            format!("{:.0} mmHg", m.max_cavity_pressure_mmhg),
        ),
        (
            "time above the overpressure threshold",
            format!("{:.1} s", m.time_above_overpressure_s),
        ),
        (
            "time distended",
            format!(
                "{:.1} s (>= {:.0} mmHg)",
                m.time_distended_s, m.distended_mmhg
            ),
        ),
        (
            "inflow valve adjustments",
            m.valve_in_adjustments.to_string(),
        ),
        (
            "outflow valve adjustments",
            m.valve_out_adjustments.to_string(),
        ),
        ("pump adjustments", m.pump_adjustments.to_string()),
        (
            "perforation",
            match m.perforation.at_s {
                Some(t) => format!(
                    "at {t:.1} s, {:.0} ml lost through it",
                    m.perforation.volume_ml
                ),
                None => "none".into(),
            },
        ),
        (
            "scope path length",
            format!("{:.2} m", m.scope_path_length_m),
        ),
        (
            "time on the safe inputs (rig lost)",
            format!("{:.1} s", m.time_in_safe_state_s),
        ),
        (
            "time to first clear view",
            match (m.view.time_to_first_clear_view_s, &m.view.unavailable) {
                (Some(t), _) => format!("{t:.1} s"),
                (None, None) => "never clear".into(),
                (None, Some(_)) => "unavailable".into(),
            },
        ),
        (
            "fraction of time with the view obscured",
            m.view
                .fraction_obscured
                .map(|f| format!("{:.0} %", f * 100.0))
                .unwrap_or_else(|| "unavailable".into()),
        ),
    ];
    for (k, v) in rows {
        let _ = writeln!(md, "| {k} | {v} |");
    }
    if let Some(why) = &m.view.unavailable {
        let _ = writeln!(
            md,
            "\nView metrics and the clarity plot are unavailable: {why}."
        );
    }
    let _ = writeln!(md, "\n## Alarms\n");
    if m.alarms.is_empty() {
        let _ = writeln!(md, "None.");
    } else {
        let _ = writeln!(md, "| t (s) | alarm | |\n|---:|---|---|");
        for a in &m.alarms {
            let _ = writeln!(
                md,
                "| {:.2} | {} | {} |",
                a.t_s,
                a.name,
                if a.raised { "raised" } else { "cleared" }
            );
        }
    }
    let _ = writeln!(md, "\n## Plots\n");
    for (file, caption) in plots::FILES {
        let _ = writeln!(md, "### {caption}\n\n![{caption}]({file})\n");
    }
    if m.view.unavailable.is_none() {
        let (file, caption) = plots::CLARITY;
        let _ = writeln!(md, "### {caption}\n\n![{caption}]({file})\n");
    }
    std::fs::write(out.join("report.md"), md)
        .with_context(|| format!("cannot write {}", out.join("report.md").display()))?;
    Ok(())
}

mod plots {
    use super::*;
    use plotters::prelude::*;

    /// The plots and their captions, in report order.
    pub const FILES: [(&str, &str); 4] = [
        ("pressure.svg", "Cavity pressure and pump setting"),
        ("flows.svg", "Flows"),
        ("deficit.svg", "Fluid deficit against its limits"),
        ("alarms.svg", "Alarm timeline"),
    ];
    /// Written when the recording has view-clarity figures.
    pub const CLARITY: (&str, &str) = ("clarity.svg", "View clarity");

    type Series = (&'static str, RGBColor, Vec<(f64, f64)>);

    fn chart(
        path: &Path,
        title: &str,
        y_desc: &str,
        t_max: f64,
        series: &[Series],
    ) -> anyhow::Result<()> {
        let y_max = series
            .iter()
            .flat_map(|s| s.2.iter().map(|p| p.1))
            .filter(|v| v.is_finite())
            .fold(1.0_f64, f64::max)
            * 1.1;
        let y_min = series
            .iter()
            .flat_map(|s| s.2.iter().map(|p| p.1))
            .filter(|v| v.is_finite())
            .fold(0.0_f64, f64::min)
            * 1.1;
        let root = SVGBackend::new(path, (900, 320)).into_drawing_area();
        let draw = || -> Result<(), Box<dyn std::error::Error>> {
            root.fill(&WHITE)?;
            let mut c = ChartBuilder::on(&root)
                .caption(title, ("sans-serif", 18))
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(60)
                .build_cartesian_2d(0.0..t_max.max(1e-3), y_min..y_max)?;
            c.configure_mesh().x_desc("t (s)").y_desc(y_desc).draw()?;
            for (label, color, pts) in series {
                let color = *color;
                c.draw_series(LineSeries::new(pts.iter().copied(), &color))?
                    .label(*label)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color));
            }
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

    pub fn write_all(rec: &Recording, m: &Metrics, out: &Path) -> anyhow::Result<()> {
        let st = &rec.statuses;
        let t0 = st.first().map_or(0, |s| s.0);
        let t = |ns: u64| ns.saturating_sub(t0) as f64 * 1e-9;
        let pick = |f: &dyn Fn(&Status) -> f64| -> Vec<(f64, f64)> {
            st.iter().map(|(ns, s)| (t(*ns), f(s))).collect()
        };
        let t_max = m.duration_s;
        let overpressure_mmhg = rec
            .metadata
            .get("config_toml")
            .and_then(|text| text.parse::<toml::Table>().ok())
            .and_then(|c| {
                c.get("hydraulics")?
                    .get("params")?
                    .get("deficit")?
                    .get("overpressure_mmhg")?
                    .as_float()
            });
        let mut pressure: Vec<Series> = vec![
            (
                "cavity pressure",
                BLUE,
                pick(&|s| pa_to_mmhg(s.cavity_pressure_pa)),
            ),
            (
                "pump setting",
                GREEN,
                pick(&|s| pa_to_mmhg(s.pump_set_pressure_pa)),
            ),
        ];
        if let Some(p) = overpressure_mmhg {
            pressure.push(("overpressure threshold", RED, vec![(0.0, p), (t_max, p)]));
        }
        chart(&out.join(FILES[0].0), FILES[0].1, "mmHg", t_max, &pressure)?;
        let q = |f: fn(&Status) -> f64| pick(&move |s| m3_per_s_to_ml_per_min(f(s)));
        chart(
            &out.join(FILES[1].0),
            FILES[1].1,
            "ml/min",
            t_max,
            &[
                ("inflow", BLUE, q(|s| s.inflow_m3_per_s)),
                ("outflow", GREEN, q(|s| s.outflow_m3_per_s)),
                ("cervical leak", MAGENTA, q(|s| s.leak_m3_per_s)),
                ("absorption", CYAN, q(|s| s.absorption_m3_per_s)),
                ("perforation", RED, q(|s| s.perforation_m3_per_s)),
            ],
        )?;
        let limit = m.deficit_limit_ml;
        chart(
            &out.join(FILES[2].0),
            FILES[2].1,
            "ml",
            t_max,
            &[
                ("deficit", BLACK, pick(&|s| m3_to_ml(s.deficit_m3))),
                (
                    "50 % of limit",
                    RGBColor(230, 160, 0),
                    vec![(0.0, 0.5 * limit), (t_max, 0.5 * limit)],
                ),
                (
                    "75 % of limit",
                    RGBColor(230, 100, 0),
                    vec![(0.0, 0.75 * limit), (t_max, 0.75 * limit)],
                ),
                ("limit", RED, vec![(0.0, limit), (t_max, limit)]),
            ],
        )?;
        if m.view.unavailable.is_none() {
            let clear = m.view.clear_view_clarity;
            let clarity: Vec<(f64, f64)> = pick(&|s| s.view_clarity)
                .into_iter()
                .filter(|p| p.1.is_finite())
                .collect();
            chart(
                &out.join(CLARITY.0),
                CLARITY.1,
                "clarity (1 = clear)",
                t_max,
                &[
                    ("view clarity", BLUE, clarity),
                    ("clear from", GREEN, vec![(0.0, clear), (t_max, clear)]),
                ],
            )?;
        }
        alarm_timeline(&out.join(FILES[3].0), rec, t_max)
    }

    /// One row per alarm that was ever set, a bar where it was set.
    fn alarm_timeline(path: &Path, rec: &Recording, t_max: f64) -> anyhow::Result<()> {
        let st = &rec.statuses;
        let t0 = st.first().map_or(0, |s| s.0);
        let ever = st.iter().fold(0u64, |acc, (_, s)| acc | s.alarm_bits);
        let rows: Vec<(u64, String)> = (0..64)
            .map(|i| 1u64 << i)
            .filter(|b| ever & b != 0)
            .map(|b| (b, alarms::names(b).join("")))
            .collect();
        let n = rows.len().max(1);
        let root = SVGBackend::new(path, (900, 80 + 28 * n as u32)).into_drawing_area();
        let draw = || -> Result<(), Box<dyn std::error::Error>> {
            root.fill(&WHITE)?;
            let mut c = ChartBuilder::on(&root)
                .caption("Alarm timeline", ("sans-serif", 18))
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(140)
                .build_cartesian_2d(0.0..t_max.max(1e-3), 0.0..n as f64)?;
            let labels: Vec<String> = rows.iter().map(|r| r.1.clone()).collect();
            c.configure_mesh()
                .x_desc("t (s)")
                .y_labels(n + 1)
                .y_label_formatter(&|y| {
                    let i = y.floor() as usize;
                    if (y - y.floor() - 0.0).abs() < 1e-9 && i < labels.len() {
                        labels[i].clone()
                    } else {
                        String::new()
                    }
                })
                .disable_y_mesh()
                .draw()?;
            for (row, (bit, _)) in rows.iter().enumerate() {
                let mut start: Option<f64> = None;
                let mut bars = Vec::new();
                for (ns, s) in st {
                    let t = ns.saturating_sub(t0) as f64 * 1e-9;
                    match (start, s.alarm_bits & bit != 0) {
                        (None, true) => start = Some(t),
                        (Some(a), false) => {
                            bars.push((a, t));
                            start = None;
                        }
                        _ => {}
                    }
                }
                if let Some(a) = start {
                    bars.push((a, t_max));
                }
                let y = row as f64;
                c.draw_series(bars.into_iter().map(|(a, b)| {
                    Rectangle::new(
                        [(a, y + 0.15), (b.max(a + t_max * 2e-3), y + 0.85)],
                        RED.filled(),
                    )
                }))?;
            }
            root.present()?;
            Ok(())
        };
        draw().map_err(|e| anyhow::anyhow!("drawing {}: {e}", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn adjustments_count_moves_not_samples() {
        let mut c = AdjustmentCounter::new(0.05, 0.5);
        // Rest at 0, one slow turn to 0.5 over 1 s, rest, a second turn back, then noise, then a
        // very slow turn (0.1 per second for 5 s): three adjustments.
        let mut t = 0.0;
        let mut push = |c: &mut AdjustmentCounter, v: f64| {
            c.push(t, v);
            t += 0.01;
        };
        for _ in 0..50 {
            push(&mut c, 0.0);
        }
        for i in 0..100 {
            push(&mut c, 0.005 * i as f64);
        }
        for _ in 0..100 {
            push(&mut c, 0.5);
        }
        for i in 0..50 {
            push(&mut c, 0.5 - 0.01 * i as f64);
        }
        for i in 0..200 {
            push(&mut c, 0.0 + 0.005 * ((i % 2) as f64));
        }
        for i in 0..500 {
            push(&mut c, 0.001 * i as f64);
        }
        assert_eq!(c.count, 3);
    }

    /// A clarity series whose answers follow by hand: no figure for the first second, then
    /// 0.5 (obscured), 0.95 (clear), 0.3, 0.95, 0.95 at one status per second.
    #[test]
    fn view_metrics_from_a_clarity_series_derived_by_hand() {
        let series = [f64::NAN, 0.5, 0.95, 0.3, 0.95, 0.95];
        let st: Vec<(u64, Status)> = series
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let s = Status {
                    view_clarity: c,
                    ..Status::default()
                };
                (5_000_000_000 + i as u64 * 1_000_000_000, s)
            })
            .collect();
        let v = view_metrics(&st, 0.9);
        assert_eq!(v.unavailable, None);
        // First clear status at t = 2 s; clarity figures from 1 to 5 s (4 s), obscured over
        // [1, 2) and [3, 4): half of it.
        assert!((v.time_to_first_clear_view_s.unwrap() - 2.0).abs() < 1e-12);
        assert!((v.fraction_obscured.unwrap() - 0.5).abs() < 1e-12);
        // Never clear: available, no time.
        let dark: Vec<(u64, Status)> = st
            .iter()
            .map(|(t, s)| {
                (
                    *t,
                    Status {
                        view_clarity: 0.2,
                        ..*s
                    },
                )
            })
            .collect();
        let v = view_metrics(&dark, 0.9);
        assert_eq!(v.time_to_first_clear_view_s, None);
        assert_eq!(v.fraction_obscured, Some(1.0));
        assert!(v.unavailable.is_none());
        // No figure at all (no particle stage): unavailable, with the reason.
        let none: Vec<(u64, Status)> = st
            .iter()
            .map(|(t, s)| {
                (
                    *t,
                    Status {
                        view_clarity: f64::NAN,
                        ..*s
                    },
                )
            })
            .collect();
        let v = view_metrics(&none, 0.9);
        assert!(v.unavailable.unwrap().contains("particle stage"));
    }
}

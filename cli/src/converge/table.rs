//! The accuracy table of `scene converge`: each size against the reference, and the observed
//! orders.

use std::fmt::Write as _;

use hydrometra_sim::harness::converge::{
    fitted_order, relative_error, successive_orders, window_mean, FUNDAL_FROM,
    JET_CONE_HALF_ANGLE_DEG, JET_PROBE_MM, JET_SEARCH_SPACING_M,
};
use serde::Serialize;

use super::args::{ConvergeArgs, RunRecord};

/// One size's figures (the reference's own row has no errors).
#[derive(Debug, Serialize)]
pub struct Row {
    pub voxel_mm: f64,
    pub grid_dims: [usize; 3],
    pub step_ms_mean: f64,
    pub wall_s: f64,
    /// Fluid volume against the surface's, %, over the frames with at least `min_fluid_cells`:
    /// the mean (signed) and the worst (largest magnitude, signed).
    pub volume_vs_surface_mean_pct: Option<f64>,
    pub volume_vs_surface_worst_pct: Option<f64>,
    /// Fluid volume against the reference's fluid volume, frame by frame, % (mean of the
    /// magnitudes, and the worst): the scope's cells are out of both.
    pub volume_vs_reference_mean_pct: Option<f64>,
    pub volume_vs_reference_worst_pct: Option<f64>,
    /// The jet probes' speeds averaged over the window, m/s, and their relative errors.
    pub jet_m_s: Vec<Option<f64>>,
    pub jet_error: Vec<Option<f64>>,
    /// The share of the window's frames in which each probe lay in a fluid cell.
    pub jet_in_fluid_share: Vec<f64>,
    pub fundal_m_s: Option<f64>,
    pub fundal_error: Option<f64>,
    pub time_to_clear_s: Option<f64>,
    /// |time to clear - the reference's|, s.
    pub time_to_clear_error_s: Option<f64>,
    pub min_clarity: Option<f64>,
}

/// The observed orders of one error column.
#[derive(Debug, Serialize)]
pub struct Orders {
    pub quantity: String,
    /// Between successive sizes.
    pub successive: Vec<Option<f64>>,
    /// Least-squares fit of `ln e` on `ln h` over every size with an error.
    pub fit: Option<f64>,
}

/// The whole table.
#[derive(Debug, Serialize)]
pub struct Table {
    pub scene: String,
    pub scenario: String,
    pub seconds: f64,
    pub rate_hz: f64,
    pub window_s: f64,
    pub cut_cells: bool,
    pub bleed_onset_s: Option<f64>,
    pub bleed_stop_s: Option<f64>,
    pub profile: String,
    pub rayon_threads: usize,
    pub reference: Row,
    pub rows: Vec<Row>,
    pub orders: Vec<Orders>,
}

impl Table {
    /// Each run of `runs` against `reference`.
    pub fn compare(a: &ConvergeArgs, reference: &RunRecord, runs: &[RunRecord]) -> Self {
        let reference_row = row(reference, None);
        let rows: Vec<Row> = runs.iter().map(|r| row(r, Some(reference))).collect();
        let h: Vec<f64> = rows.iter().map(|r| r.voxel_mm).collect();
        let mut columns: Vec<(String, Vec<Option<f64>>)> = vec![(
            "fluid volume vs the reference's (mean)".into(),
            rows.iter()
                .map(|r| r.volume_vs_reference_mean_pct)
                .collect(),
        )];
        for (i, d) in JET_PROBE_MM.iter().enumerate() {
            columns.push((
                format!("jet speed {d} mm ahead"),
                rows.iter().map(|r| r.jet_error[i]).collect(),
            ));
        }
        columns.push((
            "fundal third mean speed".into(),
            rows.iter().map(|r| r.fundal_error).collect(),
        ));
        columns.push((
            "time to clear".into(),
            rows.iter().map(|r| r.time_to_clear_error_s).collect(),
        ));
        let orders = columns
            .into_iter()
            .map(|(quantity, e)| Orders {
                quantity,
                successive: successive_orders(&h, &e),
                fit: fitted_order(&h, &e),
            })
            .collect();
        Self {
            scene: reference.key.scene.clone(),
            scenario: a.scenario.clone(),
            seconds: a.seconds,
            rate_hz: a.rate_hz,
            window_s: a.window_s,
            cut_cells: reference.key.cut_cells,
            bleed_onset_s: a.bleed_onset_s,
            bleed_stop_s: a.bleed_stop_s,
            profile: runs.first().unwrap_or(reference).profile.clone(),
            rayon_threads: runs.first().unwrap_or(reference).rayon_threads,
            reference: reference_row,
            rows,
            orders,
        }
    }

    /// The table as Markdown, its definitions first.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let bleed = match (self.bleed_onset_s, self.bleed_stop_s) {
            (None, None) => "the scene's".to_string(),
            (on, stop) => format!(
                "from {} to {} s",
                on.map_or("the scene's onset".into(), |t| t.to_string()),
                stop.map_or("the scene's end".into(), |t| t.to_string())
            ),
        };
        let _ = writeln!(
            s,
            "scene {}, scenario {}, {} s at {} Hz, cut cells {}, bleed {bleed}; reference {} mm; \
             {} profile, rayon threads {}.\n\
             step ms: mean wall time of a scene step over the whole run. vol vs surface: the \
             grid's fluid volume against the cavity surface's, mean / worst over the frames with \
             at least `min_fluid_cells` fluid cells. vol vs ref: |fluid volume / the reference's \
             - 1| at the same frames, mean / worst. jet: the peak speed |u| (the solver's \
             trilinear interpolation, sampled every {} mm) on the disk normal to the scope's \
             view direction {} mm ahead of its tip, of radius the inflow channel's plus the \
             distance times tan {} deg, averaged over every frame of the last {} s (the same \
             instants at every size); \
             fundal: the volume-weighted mean speed of the fluid cells above {:.3} of the cavity \
             surface's extent along z, same window; err: |value / the reference's - 1|. clear: \
             time from the bleed's stop to a clarity at or above the scene's threshold (the \
             scene's clarity tracker, at frame resolution); err: |difference| s.\n",
            self.scene,
            self.scenario,
            self.seconds,
            self.rate_hz,
            if self.cut_cells { "on" } else { "off" },
            self.reference.voxel_mm,
            self.profile,
            self.rayon_threads,
            JET_SEARCH_SPACING_M * 1e3,
            JET_PROBE_MM.map(|d| d.to_string()).join(", "),
            JET_CONE_HALF_ANGLE_DEG,
            self.window_s,
            FUNDAL_FROM,
        );
        let jet_heads: Vec<String> = JET_PROBE_MM
            .iter()
            .map(|d| format!("jet {d} mm m/s (err %)"))
            .collect();
        let _ = writeln!(
            s,
            "| voxel mm | grid | step ms | vol vs surface % mean / worst | vol vs ref % mean / worst | {} | fundal m/s (err %) | clear s (err s) |",
            jet_heads.join(" | ")
        );
        let _ = writeln!(
            s,
            "|---|---|---|---|---|{}---|---|",
            "---|".repeat(JET_PROBE_MM.len())
        );
        for r in self.rows.iter().chain(std::iter::once(&self.reference)) {
            let reference = std::ptr::eq(r, &self.reference);
            let jets: Vec<String> = (0..JET_PROBE_MM.len())
                .map(|i| with_error(r.jet_m_s[i], r.jet_error[i].map(|e| 100.0 * e), 4, 1))
                .collect();
            let _ = writeln!(
                s,
                "| {}{} | {}x{}x{} | {:.2} | {} / {} | {} / {} | {} | {} | {} |",
                r.voxel_mm,
                if reference { " (ref)" } else { "" },
                r.grid_dims[0],
                r.grid_dims[1],
                r.grid_dims[2],
                r.step_ms_mean,
                opt(r.volume_vs_surface_mean_pct, 2),
                opt(r.volume_vs_surface_worst_pct, 2),
                opt(r.volume_vs_reference_mean_pct, 2),
                opt(r.volume_vs_reference_worst_pct, 2),
                jets.join(" | "),
                with_error(r.fundal_m_s, r.fundal_error.map(|e| 100.0 * e), 4, 1),
                with_error(r.time_to_clear_s, r.time_to_clear_error_s, 2, 2),
            );
        }
        let pairs: Vec<String> = self
            .rows
            .windows(2)
            .map(|w| format!("{} -> {}", w[0].voxel_mm, w[1].voxel_mm))
            .collect();
        if pairs.is_empty() {
            let _ = writeln!(s, "\nOne size: no observed order.");
            return s + &self.probe_shares();
        }
        let _ = writeln!(
            s,
            "\nObserved order (ln of the error ratio over ln of the size ratio; fit: least squares of \
             ln e on ln h):\n\n| error of | {} | fit |",
            pairs.join(" | ")
        );
        let _ = writeln!(s, "|---|{}---|", "---|".repeat(pairs.len()));
        for o in &self.orders {
            let succ: Vec<String> = o.successive.iter().map(|p| opt(*p, 2)).collect();
            let _ = writeln!(
                s,
                "| {} | {} | {} |",
                o.quantity,
                succ.join(" | "),
                opt(o.fit, 2)
            );
        }
        s + &self.probe_shares()
    }

    /// The line on the jet probes' positions in the reference.
    fn probe_shares(&self) -> String {
        let shares: Vec<String> = JET_PROBE_MM
            .iter()
            .zip(&self.reference.jet_in_fluid_share)
            .map(|(d, f)| format!("{d} mm {:.0} %", 100.0 * f))
            .collect();
        format!(
            "\nJet probes in a fluid cell of the reference, share of the window's frames: {}.\n",
            shares.join(", ")
        )
    }
}

fn opt(x: Option<f64>, digits: usize) -> String {
    x.map_or("-".into(), |v| format!("{v:.digits$}"))
}

fn with_error(v: Option<f64>, e: Option<f64>, dv: usize, de: usize) -> String {
    match (v, e) {
        (Some(v), Some(e)) => format!("{v:.dv$} ({e:.de$})"),
        (Some(v), None) => format!("{v:.dv$}"),
        (None, _) => "-".into(),
    }
}

/// `run`'s row against `reference` (`None`: the reference's own row).
fn row(run: &RunRecord, reference: Option<&RunRecord>) -> Row {
    let enough = |r: &RunRecord, f: usize| {
        r.fluid_cells
            .get(f)
            .is_some_and(|&n| n >= r.min_fluid_cells)
    };
    let vs_surface: Vec<f64> = (0..run.frames.min(run.surface_ml.len()))
        .filter(|&f| enough(run, f) && run.surface_ml[f] > 0.0)
        .map(|f| 100.0 * (run.grid_fluid_ml[f] / run.surface_ml[f] - 1.0))
        .collect();
    let vs_reference: Vec<f64> = reference.map_or_else(Vec::new, |reference| {
        (0..run.grid_fluid_ml.len().min(reference.grid_fluid_ml.len()))
            .filter(|&f| enough(run, f) && enough(reference, f))
            .filter(|&f| reference.grid_fluid_ml[f] > 0.0)
            .map(|f| 100.0 * (run.grid_fluid_ml[f] / reference.grid_fluid_ml[f] - 1.0).abs())
            .collect()
    });
    let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
    let worst = |v: &[f64]| {
        v.iter()
            .copied()
            .reduce(|a, b| if b.abs() > a.abs() { b } else { a })
    };
    let series = |r: &RunRecord, v: &[Option<f64>]| -> Vec<(f64, f64)> {
        r.window_time_s
            .iter()
            .zip(v)
            .filter_map(|(&t, v)| v.map(|v| (t, v)))
            .collect()
    };
    let (from, to) = (f64::NEG_INFINITY, f64::INFINITY);
    let jet_m_s: Vec<Option<f64>> = run
        .jet_m_s
        .iter()
        .map(|v| window_mean(&series(run, v), from, to))
        .collect();
    let jet_error = (0..jet_m_s.len())
        .map(|i| {
            let r = reference?;
            let rv = window_mean(&series(r, r.jet_m_s.get(i)?), from, to);
            relative_error(jet_m_s[i], rv)
        })
        .collect();
    let fundal_m_s = window_mean(&series(run, &run.fundal_m_s), from, to);
    let fundal_error = reference
        .and_then(|r| relative_error(fundal_m_s, window_mean(&series(r, &r.fundal_m_s), from, to)));
    let time_to_clear_error_s =
        reference.and_then(|r| match (run.time_to_clear_s, r.time_to_clear_s) {
            (Some(a), Some(b)) => Some((a - b).abs()),
            _ => None,
        });
    Row {
        voxel_mm: run.key.voxel_mm,
        grid_dims: run.grid_dims,
        step_ms_mean: run.step_ms_mean,
        wall_s: run.wall_s,
        volume_vs_surface_mean_pct: mean(&vs_surface),
        volume_vs_surface_worst_pct: worst(&vs_surface),
        volume_vs_reference_mean_pct: mean(&vs_reference),
        volume_vs_reference_worst_pct: worst(&vs_reference),
        jet_in_fluid_share: run
            .jet_in_fluid
            .iter()
            .map(|v| v.iter().filter(|&&b| b).count() as f64 / v.len().max(1) as f64)
            .collect(),
        jet_m_s,
        jet_error,
        fundal_m_s,
        fundal_error,
        time_to_clear_s: run.time_to_clear_s,
        time_to_clear_error_s,
        min_clarity: run.min_clarity,
    }
}

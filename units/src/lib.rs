//! `hydrometra-units`: the one copy of the unit constants and conversions between SI (used inside
//! every crate) and the clinical units used at the edges (mmHg, ml, ml/min).
//!
//! A crate of its own because both `hydrometra-sim` (physics) and `hydrometra-drivers` (the rig
//! codec, which must build without `std` for firmware) need the same constants, and neither may
//! depend on the other. No dependencies, `no_std`.
//!
//! ```
//! use hydrometra_units::{mmhg_to_pa, PA_PER_MMHG};
//! assert_eq!(mmhg_to_pa(1.0), PA_PER_MMHG);
//! ```
#![no_std]
#![warn(missing_docs)]

/// Pascals per millimetre of mercury: 13.5951 g/cm³ × 9.80665 m/s² × 1 mm (the conventional
/// millimetre of mercury).
pub const PA_PER_MMHG: f64 = 133.322_387_415;
/// Cubic metres per millilitre.
pub const M3_PER_ML: f64 = 1e-6;
/// Seconds per minute.
pub const S_PER_MIN: f64 = 60.0;

/// mmHg -> Pa.
pub fn mmhg_to_pa(pressure_mmhg: f64) -> f64 {
    pressure_mmhg * PA_PER_MMHG
}

/// Pa -> mmHg.
pub fn pa_to_mmhg(pressure_pa: f64) -> f64 {
    pressure_pa / PA_PER_MMHG
}

/// ml -> m^3.
pub fn ml_to_m3(volume_ml: f64) -> f64 {
    volume_ml * M3_PER_ML
}

/// m^3 -> ml.
pub fn m3_to_ml(volume_m3: f64) -> f64 {
    volume_m3 / M3_PER_ML
}

/// ml/min -> m^3/s.
pub fn ml_per_min_to_m3_per_s(flow_ml_per_min: f64) -> f64 {
    flow_ml_per_min * M3_PER_ML / S_PER_MIN
}

/// m^3/s -> ml/min.
pub fn m3_per_s_to_ml_per_min(flow_m3_per_s: f64) -> f64 {
    flow_m3_per_s / M3_PER_ML * S_PER_MIN
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conversions_round_trip_and_match_the_definition() {
        // 1 mmHg = rho_Hg(0 °C) g h, with rho_Hg = 13595.1 kg/m³, g = 9.80665 m/s², h = 1 mm.
        assert!((PA_PER_MMHG - 13_595.1 * 9.806_65 * 1e-3).abs() < 1e-9);
        assert!((pa_to_mmhg(mmhg_to_pa(150.0)) - 150.0).abs() < 1e-12);
        // 760 mmHg is one standard atmosphere to within the definition's rounding (0.2 ppm).
        assert!((mmhg_to_pa(760.0) - 101_325.0).abs() < 0.02);
        assert!((m3_to_ml(ml_to_m3(1500.0)) - 1500.0).abs() < 1e-9);
        assert!((ml_per_min_to_m3_per_s(800.0) - 800e-6 / 60.0).abs() < 1e-18);
        assert!((m3_per_s_to_ml_per_min(ml_per_min_to_m3_per_s(50.0)) - 50.0).abs() < 1e-9);
    }
}

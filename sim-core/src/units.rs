//! Conversions between SI units (used inside) and clinical units (used at the edges).

/// Pascals per millimetre of mercury.
pub const PA_PER_MMHG: f64 = 133.322;
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
    fn conversions_round_trip() {
        assert!((pa_to_mmhg(mmhg_to_pa(150.0)) - 150.0).abs() < 1e-12);
        assert!((mmhg_to_pa(150.0) - 19998.3).abs() < 1e-6);
        assert!((m3_to_ml(ml_to_m3(1500.0)) - 1500.0).abs() < 1e-9);
        assert!((ml_per_min_to_m3_per_s(800.0) - 800e-6 / 60.0).abs() < 1e-18);
        assert!((m3_per_s_to_ml_per_min(ml_per_min_to_m3_per_s(50.0)) - 50.0).abs() < 1e-9);
    }
}

//! The slip of a particle relative to the fluid: a sphere's drag law and its terminal settling
//! or rise velocity along gravity, with the time its slip relaxes in.

use crate::fluid::FluidParams;

/// Gravity's magnitude, m/s^2.
pub const GRAVITY_M_S2: f64 = 9.81;

/// The fluid a particle slips in: the distension fluid the solver simulates (one set of fluid
/// properties for the flow and the particles).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SlipFluid {
    /// Density, kg/m^3.
    pub density_kg_m3: f64,
    /// Dynamic viscosity, Pa s.
    pub viscosity_pa_s: f64,
}

impl SlipFluid {
    /// The fluid of the solver's parameters: its density, and its kinematic viscosity times
    /// that density.
    pub fn of(params: &FluidParams) -> Self {
        Self {
            density_kg_m3: params.density_kg_m3,
            viscosity_pa_s: params.density_kg_m3 * params.viscosity_m2_s,
        }
    }

    /// [`terminal_slip`] of a sphere of diameter `d_m` and density `rho_p` in this fluid.
    pub fn terminal_slip(&self, d_m: f64, rho_p: f64) -> (f64, f64) {
        terminal_slip(d_m, rho_p, self.density_kg_m3, self.viscosity_pa_s)
    }
}

/// Drag coefficient of a sphere (Schiller-Naumann, 24/Re (1 + 0.15 Re^0.687) up to Re = 1000,
/// 0.44 above).
pub fn drag_coefficient(re: f64) -> f64 {
    if re >= 1000.0 {
        0.44
    } else {
        24.0 / re.max(1e-12) * (1.0 + 0.15 * re.powf(0.687))
    }
}

/// Terminal slip speed (m/s, positive along gravity: sinking) of a sphere of diameter `d_m` and
/// density `rho_p` in a fluid (`rho_f`, `mu`): the buoyancy-weight balance with
/// [`drag_coefficient`], solved by bisection on the speed. Also the relaxation time (s) of the
/// slip, `(rho_p + rho_f / 2) d^2 / (18 mu f(Re))` (added mass included, drag linearised at the
/// terminal Reynolds number).
pub fn terminal_slip(d_m: f64, rho_p: f64, rho_f: f64, mu: f64) -> (f64, f64) {
    let drho = rho_p - rho_f;
    let weight = drho.abs() * GRAVITY_M_S2 * std::f64::consts::PI / 6.0 * d_m.powi(3);
    let drag = |w: f64| {
        let re = rho_f * w * d_m / mu;
        0.5 * rho_f * drag_coefficient(re) * std::f64::consts::PI / 4.0 * d_m * d_m * w * w
    };
    let (mut lo, mut hi) = (0.0, 100.0);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if drag(mid) < weight {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let w = 0.5 * (lo + hi);
    let re = rho_f * w * d_m / mu;
    let f = if re > 0.0 {
        drag_coefficient(re) * re / 24.0
    } else {
        1.0
    };
    let tau = (rho_p + 0.5 * rho_f) * d_m * d_m / (18.0 * mu * f);
    (w * drho.signum(), tau)
}

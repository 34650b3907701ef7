//! Red-black Gauss-Seidel half-sweeps and the residual on one level, through the span kernels
//! (in place on one thread; into the residual vector and swapped on two).

use super::kernels::{run, SpanOp};
use super::level::Level;

impl Level {
    /// One colour's half-sweep of Gauss-Seidel on `x` (`colour` 0 = red, 1 = black). With `init`,
    /// `x` is taken as zero (it is written, not read: the first half-sweep of a V-cycle level).
    /// With `dot` (not with `init`), returns `sum b x` of the result, else 0.
    pub(crate) fn half_sweep(&mut self, colour: usize, init: bool, dot: bool) -> f64 {
        let mut x = std::mem::take(&mut self.x);
        let mut sum = 0.0;
        if init {
            run(
                self,
                SpanOp::Init {
                    x: &mut x,
                    b: &self.b,
                    inv: &self.inv[colour],
                },
            );
        } else {
            if self.any_periodic() {
                self.halo(&mut x);
            }
            if self.parallel {
                // Two threads cannot update `x` in place: the new values go to the residual vector
                // (free during smoothing), which then becomes `x`. Off the spans and the ghost
                // layers both hold zero, so the swap is exact.
                let mut t = std::mem::take(&mut self.r);
                sum = run(
                    self,
                    SpanOp::RelaxInto {
                        t: &mut t,
                        x: &x,
                        b: &self.b,
                        diag: &self.ddiag,
                        inv: &self.inv[colour],
                        dot,
                    },
                );
                self.r = std::mem::replace(&mut x, t);
                if self.any_periodic() {
                    // The old `x` kept its ghost copies; the restriction reads `r` on the ghost
                    // layer of a one-cell periodic axis, where it must be zero.
                    let mut r = std::mem::take(&mut self.r);
                    self.clear_halo(&mut r);
                    self.r = r;
                }
            } else {
                sum = run(
                    self,
                    SpanOp::Relax {
                        x: &mut x,
                        b: &self.b,
                        diag: &self.ddiag,
                        inv: &self.inv[colour],
                        dot,
                    },
                );
            }
        }
        self.x = x;
        sum
    }

    /// `r = b - A x` on the spans.
    pub(super) fn residual(&mut self) {
        let mut x = std::mem::take(&mut self.x);
        let mut r = std::mem::take(&mut self.r);
        if self.any_periodic() {
            self.halo(&mut x);
        }
        run(
            self,
            SpanOp::Stencil {
                y: &mut r,
                v: &x,
                b: Some(&self.b),
                diag: &self.ddiag,
                mask: &self.mask,
            },
        );
        self.x = x;
        self.r = r;
    }

    /// `y = A v` on the spans (zero on non-fluid cells of the spans); `v`'s periodic ghost layers
    /// must be filled.
    #[cfg(test)]
    pub fn apply(&self, v: &[f32], y: &mut [f32]) {
        run(
            self,
            SpanOp::Stencil {
                y,
                v,
                b: None,
                diag: &self.ddiag,
                mask: &self.mask,
            },
        );
    }
}

//! How often and how much of each kind of frame the page is sent.

use clap::Args;

/// Rates and sizes of the frames sent to the page.
#[derive(Args, Debug, Clone, Copy)]
pub struct Rates {
    /// Status frames per second, per rig.
    #[arg(long, value_name = "HZ", default_value_t = 30.0)]
    pub status_hz: f64,
    /// Cavity positions and particle frames per second, per rig (at most the scene's rate).
    #[arg(long, value_name = "HZ", default_value_t = 30.0)]
    pub scene_hz: f64,
    /// Flow frames per second, per rig.
    #[arg(long, value_name = "HZ", default_value_t = 10.0)]
    pub flow_hz: f64,
    /// Flow arrows at most (the field is averaged over blocks of cells to fit).
    #[arg(long, value_name = "N", default_value_t = 3000)]
    pub max_arrows: usize,
    /// Particles at most per frame (an evenly spaced subset of more).
    #[arg(long, value_name = "N", default_value_t = 4096)]
    pub max_particles: usize,
}

impl Default for Rates {
    fn default() -> Self {
        Self {
            status_hz: 30.0,
            scene_hz: 30.0,
            flow_hz: 10.0,
            max_arrows: 3000,
            max_particles: 4096,
        }
    }
}

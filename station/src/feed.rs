//! A rig's feed: samples of its services (from iceoryx2 or zenoh) become the page's frames in
//! the rig's slots: status, topology on change, positions and particles only while a browser
//! looks, the flow reduced to arrows.

use std::sync::atomic::Ordering;
use std::sync::Arc;

use hydrometra_ipc::field::FlowFieldHeader;
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::{Particle, ParticlesHeader};
use hydrometra_ipc::Status;
use hydrometra_remote::follow::Sink;

use crate::frame::{self, kind};
use crate::hub::Rig;
use crate::rates::Rates;

/// The feed of one rig.
pub struct RigFeed {
    /// The rig.
    pub rig: Arc<Rig>,
    /// Sizes of the frames (arrows, particles).
    pub rates: Rates,
}

impl Sink for RigFeed {
    fn status(&mut self, s: &Status, due: bool) {
        self.rig.status(s, due);
    }

    fn topology(&mut self, h: &MeshTopologyHeader, indices: &[u32]) {
        let f = frame::topology(self.rig.info.index, h, indices);
        self.rig.put(kind::TOPOLOGY, f);
    }

    fn positions(&mut self, h: &MeshPositionsHeader, xyz: &[f32]) {
        let f = frame::positions(self.rig.info.index, h, xyz);
        self.rig.put(kind::POSITIONS, f);
    }

    fn flow(&mut self, h: &FlowFieldHeader, bytes: &[u8]) {
        match crate::flow::arrows(h, bytes, self.rates.max_arrows) {
            Ok((ah, arrows)) => {
                let f = frame::flow(self.rig.info.index, &ah, &arrows);
                self.rig.put(kind::FLOW, f);
            }
            Err(e) => {
                self.rig
                    .counters
                    .decode_errors
                    .fetch_add(1, Ordering::Relaxed);
                tracing::debug!("{e}");
            }
        }
    }

    fn particles(&mut self, h: &ParticlesHeader, particles: &[Particle]) {
        let f = frame::particles(self.rig.info.index, h, particles, self.rates.max_particles);
        self.rig.put(kind::PARTICLES, f);
    }

    fn wants_scene(&self) -> bool {
        self.rig.wanted()
    }

    fn skipped(&mut self) {
        self.rig
            .counters
            .skipped_no_browser
            .fetch_add(1, Ordering::Relaxed);
    }

    fn connected(&mut self) {
        self.rig.counters.reconnects.fetch_add(1, Ordering::Relaxed);
    }
}

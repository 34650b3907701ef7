//! `hydrometrad`, the real-time service: the rig link, the 1 kHz simulation loop, the scene thread,
//! the publisher and the control plane. The binary (`src/bin/hydrometrad.rs`) only parses flags and
//! calls [`service::run`]; nothing else depends on this crate.

pub mod service;

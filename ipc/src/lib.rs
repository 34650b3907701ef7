//! `hydrometra-ipc`: the renderer contract. repr(C) payloads, service names and header layouts
//! published by `hydrometrad` over iceoryx2 shared memory. Renderers depend on this crate alone.
//!
//! The byte-level specification, for renderers in any language, is `docs/ipc.md`; a test keeps the
//! layout tables there in step with the structs here.
//!
//! ```no_run
//! use hydrometra_ipc::{ServiceNames, Status, status};
//! use iceoryx2::prelude::*;
//!
//! # fn main() -> Result<(), Box<dyn core::error::Error>> {
//! let node = NodeBuilder::new().create::<ipc::Service>()?;
//! let names = ServiceNames::default(); // "hydrometra/v1/..."
//! let service = status::open(&node, &names)?;
//! let subscriber = service.subscriber_builder().create()?;
//! while node.wait(core::time::Duration::from_millis(100)).is_ok() {
//!     while let Some(sample) = subscriber.receive()? {
//!         let s: &Status = &sample;
//!         println!("#{} t={:.3} s link={}", s.sequence, s.sim_time_s, s.link_state);
//!     }
//! }
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod alarms;
pub mod control;
pub mod events;
pub mod field;
pub mod hydraulic_flags;
pub mod mesh;
pub mod names;
pub mod particles;
pub mod slice;
pub mod status;

pub use names::{ServiceNames, DEFAULT_SERVICE_PREFIX};
pub use status::Status;

/// Major version of the renderer contract. Part of every payload type name (`hydrometra.v1.*`)
/// and of the default service prefix (`hydrometra/v1`); see "Versioning" in `docs/ipc.md`.
pub const SCHEMA_VERSION: u32 = 1;

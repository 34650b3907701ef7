//! `hydrometra-ipc`: the renderer contract. repr(C) payloads, service names and header layouts
//! published by `hydrometrad` over iceoryx2 shared memory. Renderers depend on this crate alone.
#![warn(missing_docs)]

//! The event service that wakes renderers: one event id per kind of new data.

use iceoryx2::node::Node;
use iceoryx2::port::event_id::EventId;
use iceoryx2::service::builder::event::{EventOpenError, EventOpenOrCreateError};
use iceoryx2::service::port_factory::event::PortFactory;
use iceoryx2::service::Service;

use crate::names::ServiceNames;

/// A new [`crate::Status`] was published.
pub const STATUS: EventId = EventId::new(1);
/// A new cavity topology was published.
pub const MESH_TOPOLOGY: EventId = EventId::new(2);
/// New cavity positions were published.
pub const MESH_POSITIONS: EventId = EventId::new(3);
/// A new flow field was published.
pub const FLOW_FIELD: EventId = EventId::new(4);
/// New particles were published.
pub const PARTICLES: EventId = EventId::new(5);
/// The daemon is shutting down cleanly.
pub const SHUTDOWN: EventId = EventId::new(15);

/// Largest event id; ids above it are rejected by the service.
pub const EVENT_ID_MAX: usize = 15;
/// Listeners the event service admits.
pub const MAX_LISTENERS: usize = 16;
/// Notifiers the event service admits (the daemon, plus tools).
pub const MAX_NOTIFIERS: usize = 4;
/// Nodes that may hold the service open at once.
pub const MAX_NODES: usize = 32;

/// The event service as the daemon creates it (or re-opens it after a restart).
pub fn create<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<PortFactory<S>, EventOpenOrCreateError> {
    node.service_builder(names.events())
        .event()
        .event_id_max_value(EVENT_ID_MAX)
        .max_listeners(MAX_LISTENERS)
        .max_notifiers(MAX_NOTIFIERS)
        .max_nodes(MAX_NODES)
        .open_or_create()
}

/// The event service as a renderer opens it.
pub fn open<S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<PortFactory<S>, EventOpenError> {
    node.service_builder(names.events()).event().open()
}

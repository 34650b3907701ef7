//! Cell labels of the MAC grid.

use serde::{Deserialize, Serialize};

/// What a grid cell is, as far as the fluid solver is concerned.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum CellLabel {
    /// Fluid: pressure is solved here.
    #[default]
    Fluid,
    /// A no-slip wall at rest.
    Solid,
    /// A solid moving with the cell's prescribed velocity: the flux through a face it shares with fluid
    /// is the velocity's normal component (an inflow or outflow port) and fluid beside it sees its
    /// tangential component (a moving wall).
    Velocity,
    /// An open boundary: pressure is zero and fluid may leave or enter freely.
    Outflow,
}

impl CellLabel {
    /// True for labels whose velocity is prescribed (walls and ports).
    pub fn is_wall(self) -> bool {
        matches!(self, CellLabel::Solid | CellLabel::Velocity)
    }

    /// The label's name as used in case files.
    pub fn name(self) -> &'static str {
        match self {
            CellLabel::Fluid => "fluid",
            CellLabel::Solid => "solid",
            CellLabel::Velocity => "velocity",
            CellLabel::Outflow => "outflow",
        }
    }
}

//! The records the scene's stages pass each other and report: the rig's inputs, the voxel kinds,
//! the flux balance, the step report and the published cavity. A leaf: it imports no stage, so
//! every stage (and [`super::Scene`]) can use it.

use super::counters::Counters;
use crate::fluid::StepStats;
use crate::hydraulics::{HydraulicInputs, HydraulicState};
use crate::vtk::{CellType, Document};

/// The scope pose in the organ frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScopePose {
    /// Tip position, m.
    pub tip_position_m: [f64; 3],
    /// View direction (need not be unit; a zero or non-finite one keeps the last).
    pub view_direction: [f64; 3],
    /// False when the pose is unknown (the scope is then left where it was).
    pub valid: bool,
}

impl Default for ScopePose {
    fn default() -> Self {
        Self {
            tip_position_m: [0.0; 3],
            view_direction: [0.0, 0.0, 1.0],
            valid: false,
        }
    }
}

/// What the rig says, in SI units. The valves, the pump and the case's perforation are the
/// hydraulic model's own input record ([`HydraulicInputs`], stepped on as is), the scope's pose is
/// the scene's: one record for both.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RigInputs {
    /// Valves, pump and the perforation event.
    pub hydraulic: HydraulicInputs,
    /// The scope.
    pub scope: ScopePose,
}

/// Where the hydraulic state comes from.
#[derive(Debug, Clone, Copy)]
pub enum HydraulicsInput<'a> {
    /// The scene steps its own model with the rig inputs (offline runner, tests).
    Own,
    /// Another loop steps the model; the scene follows this, its newest state.
    External(&'a HydraulicState),
}

/// The inputs of one step.
#[derive(Debug, Clone, Copy)]
pub struct SceneInputs<'a> {
    /// The rig.
    pub rig: RigInputs,
    /// The hydraulics.
    pub hydraulics: HydraulicsInput<'a>,
}

/// What a voxel is, as published (the daemon maps it to the renderer contract).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(u8)]
pub enum VoxelKind {
    /// Tissue or outside the cavity.
    #[default]
    Solid = 0,
    /// Fluid.
    Fluid = 1,
    /// The inflow port at the scope tip.
    Inflow = 2,
    /// The outflow holes of the sheath.
    Outflow = 3,
    /// The scope's sheath.
    Scope = 4,
    /// The cavity wall (a moving solid: its velocity is the wall's).
    Wall = 5,
    /// The open external os (fluid leaks out or in freely, pressure 0).
    Open = 6,
}

/// Volume fluxes over the last frame, m^3/s; positive into the cavity.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FluxBalance {
    /// The hydraulics' frame-mean inflow.
    pub hydraulic_inflow_m3_per_s: f64,
    /// The hydraulics' frame-mean outflow (positive out).
    pub hydraulic_outflow_m3_per_s: f64,
    /// The hydraulics' frame-mean losses: leak, absorption, perforation (positive out).
    pub hydraulic_losses_m3_per_s: f64,
    /// The hydraulics' cavity volume change over the frame, m^3/s.
    pub hydraulic_dvdt_m3_per_s: f64,
    /// Measured on the fluid's faces after the step: into the fluid through the inflow port.
    pub fluid_inflow_m3_per_s: f64,
    /// Measured: out of the fluid through the outflow holes (positive out).
    pub fluid_outflow_m3_per_s: f64,
    /// Out of the fluid into the moving walls (positive out; equals dV/dt): measured on the
    /// faces of the wall cells; with cut cells plus what the wall pieces inside the fluid cells
    /// carry out (the projection's boundary condition there, docs/scene.md "Cut cells").
    pub fluid_wall_m3_per_s: f64,
    /// Out through the external os (positive out; carries the losses): measured on the faces of
    /// the open os cells; with cut cells what the os's pieces carry out (there are no open
    /// cells then).
    pub fluid_open_m3_per_s: f64,
    /// Incompatible flux the projection removed from closed fluid regions, the sum of the
    /// regions' sizes (m^3/s): with cut cells (every region closed) and one region, what the
    /// balance `inflow - outflow - walls - os` misses by.
    pub closed_region_mismatch_m3_per_s: f64,
    /// The wall velocities from the atlas (`dx/dp dp/dt`) were scaled by this to carry dV/dt
    /// exactly over the staircase wall, or with cut cells over the wall pieces (1 when exact; 0
    /// when no wall moved).
    pub wall_flux_scale: f64,
    /// The inflow could not enter the fluid (tip in tissue, or not in the grid).
    pub inflow_blocked: bool,
    /// Fraction of the inflow channel's area that opens on fluid on the grid, in [0, 1]: 1 when
    /// the tip is clear of tissue (the port's area is the channel's, the jet leaves at
    /// `Q_in / channel area`), less when tissue covers part of the tip (the cervical canal: the
    /// jet leaves faster, at `Q_in / (fraction x channel area)`), 0 when nothing opens on fluid.
    /// Below [`MIN_INFLOW_OPEN_FRACTION`](super::MIN_INFLOW_OPEN_FRACTION) (0.1) the inflow is
    /// blocked.
    pub inflow_open_fraction: f64,
    /// The jet speed the inflow port imposes, m/s: `Q_in / (inflow_open_fraction x channel
    /// area)` (0 when blocked).
    pub inflow_jet_speed_m_per_s: f64,
    /// The outflow holes have no fluid around them.
    pub outflow_blocked: bool,
}

/// The report of one step.
#[derive(Debug, Clone, Default)]
pub struct StepReport {
    /// Steps so far.
    pub frame: u64,
    /// Scene time, s.
    pub time_s: f64,
    /// Cavity pressure the surface was replayed at, Pa.
    pub cavity_pressure_pa: f64,
    /// The hydraulics' cavity volume, m^3.
    pub cavity_volume_m3: f64,
    /// Volume enclosed by the replayed surface, m^3.
    pub surface_volume_m3: f64,
    /// Fluid cells now.
    pub fluid_cells: usize,
    /// The fluid volume the grid carries, m^3: with `[fluid] cut_cells` `sum V_i h^3` over its
    /// fluid cells (`FluidGrid::fluid_volume_m3`), else the whole fluid cells' volume (the
    /// conservative voxelization's).
    pub grid_fluid_volume_m3: f64,
    /// With `[fluid] cut_cells`: the fluid the renderer's picture holds, m^3: the volume the
    /// replayed surface encloses less the scope's sheath inside it (the sum of the exact cut-cell
    /// fractions of the two surfaces; exact for the polygonal surfaces except in the cells both
    /// cut). The reference for `grid_fluid_volume_m3`.
    pub cavity_less_sheath_volume_m3: Option<f64>,
    /// Whether the fluid stage idled for too few fluid cells.
    pub fluid_idle: bool,
    /// Cells whose label changed in this step.
    pub relabelled_cells: usize,
    /// The fluid step's own counters (when it ran).
    pub fluid: Option<StepStats>,
    /// The fluxes.
    pub flux: FluxBalance,
    /// Per-stage counters (cumulative).
    pub counters: Counters,
}

/// The cavity surface as published: closed (the first `cap_triangles` close the external os),
/// normals into the fluid.
#[derive(Debug, Clone, Copy)]
pub struct CavityView<'a> {
    /// Triangles (three vertex indices each).
    pub triangles: &'a [[u32; 3]],
    /// Vertex positions, m.
    pub positions_m: &'a [[f32; 3]],
    /// Changes when the triangles change.
    pub topology_revision: u64,
    /// The first `cap_triangles` close the external os.
    pub cap_triangles: usize,
    /// The pressure the positions belong to, Pa.
    pub pressure_pa: f64,
}

/// One port or wall cell and its faces on fluid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoundaryCell {
    /// Its linear index (x fastest).
    pub cell: u32,
    /// Its `(i, j, k)` (what the solver's setters take), kept to spare a division per use.
    pub at: [u32; 3],
    /// Bit f set: face f (0..6) borders fluid.
    pub faces: u8,
}

/// What [`super::Scene::relabel_whole_box`] changed: nothing (all zero, all false) when the row-
/// incremental compositions before it were complete.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WholeBoxCheck {
    /// Solver labels the whole-box pass changed.
    pub labels_changed: usize,
    /// Published kinds it changed.
    pub kinds_changed: usize,
    /// Whether it changed the port or wall cell lists, their fluid faces or the inflow rim.
    pub lists_changed: bool,
    /// Whether it changed the count of fluid cells.
    pub fluid_cells_changed: bool,
}

impl WholeBoxCheck {
    /// Nothing changed.
    pub fn is_clean(&self) -> bool {
        *self == Self::default()
    }
}

impl CavityView<'_> {
    /// The closed surface as a VTU of triangles (positions in metres), cell data `cap`: 1 on the
    /// triangles that close the external os.
    pub fn vtu_string(&self) -> String {
        let mut doc = Document::unstructured_grid(self.positions_m.len(), self.triangles.len());
        doc.cell_data("cap", None);
        doc.array(
            "cap",
            (0..self.triangles.len()).map(|t| [u8::from(t < self.cap_triangles)]),
        );
        doc.points(self.positions_m.iter().copied());
        doc.cells(self.triangles.iter().copied(), CellType::Triangle);
        doc.finish()
    }
}

/// The hydraulics' flows over the last frame (frame means from the cumulative totals): what the
/// fluid's ports and moving walls must carry.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FrameFlows {
    /// Inflow through the scope's channel, m^3/s.
    pub inflow_m3_per_s: f64,
    /// Outflow through the sheath's holes (positive out), m^3/s.
    pub outflow_m3_per_s: f64,
    /// Leak, absorption and perforation (positive out), m^3/s.
    pub losses_m3_per_s: f64,
    /// The cavity volume's change, m^3/s.
    pub dvdt_m3_per_s: f64,
    /// The cavity pressure's change, Pa/s (the wall velocity is `dx/dp` times it).
    pub dpdt_pa_per_s: f64,
    /// The cavity volume at the frame's end, m^3.
    pub volume_m3: f64,
}

/// A box of cubic cells: cell `(i, j, k)` spans `origin + h [i, i+1) x [j, j+1) x [k, k+1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelBox {
    /// Cells per axis.
    pub dims: [usize; 3],
    /// Lower corner of cell (0, 0, 0), m.
    pub origin_m: [f64; 3],
    /// Cell edge, m.
    pub spacing_m: f64,
}

impl VoxelBox {
    /// Number of cells.
    pub fn cell_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    /// Linear index, x fastest.
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        i + self.dims[0] * (j + self.dims[1] * k)
    }
    /// Centre of a cell, m.
    pub fn centre_m(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        let c = [i, j, k];
        std::array::from_fn(|a| self.origin_m[a] + (c[a] as f64 + 0.5) * self.spacing_m)
    }
    /// Centre of the cell with linear index `n`, m.
    pub fn centre_m_of(&self, n: u32) -> [f64; 3] {
        let n = n as usize;
        let [nx, ny, _] = self.dims;
        self.centre_m(n % nx, (n / nx) % ny, n / (nx * ny))
    }
}

/// The inflow port as the particles see it: its cells and their faces on fluid, on the grid
/// `cells`, with the scope's view direction (`None` before a pose) and the channel's area.
#[derive(Debug, Clone, Copy)]
pub struct InflowPort<'a> {
    /// The port's cells, by cell index.
    pub cells: &'a [BoundaryCell],
    /// The grid they lie on.
    pub grid: VoxelBox,
    /// The scope's unit view direction, if it was ever placed.
    pub direction: Option<[f64; 3]>,
    /// The inflow channel's area, m^2.
    pub channel_area_m2: f64,
}

/// How much of its configured work the scene does: the daemon lowers it in steps under overload
/// (docs/daemon.md, "Overload") and restores it when frames fit again.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneQuality {
    /// At most this many fluid substeps per step (`None`: the configured bound).
    pub max_fluid_substeps: Option<usize>,
    /// The share of the particle budget in use, `[0, 1]` (at least one particle).
    pub particle_budget_share: f64,
}

impl Default for SceneQuality {
    /// The full quality: everything as configured.
    fn default() -> Self {
        Self {
            max_fluid_substeps: None,
            particle_budget_share: 1.0,
        }
    }
}

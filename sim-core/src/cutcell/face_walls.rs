//! The wall distances of the viscous stencil's arms, per MAC face: the record the cutcell module
//! computes (`crossings.rs`) and the fluid solver reads (`fluid/cut.rs`), with no imports of its
//! own so both can depend on it.

/// A stencil arm without a boundary within one cell.
pub const NO_WALL: f32 = f32::INFINITY;

/// Per MAC face (the box layout of `CutCells::face_fractions`) with a boundary within one cell
/// of its centre along some axis: the distance from the centre to the boundary in cells, per arm
/// `-x, +x, -y, +y, -z, +z` ([`NO_WALL`]: none within one cell). A face whose centre lies in the
/// solid reads 0 on every arm. Sorted by face index, one entry per face.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FaceWalls {
    /// Per face component (the axis the faces are normal to).
    pub faces: [Vec<(u32, [f32; 6])>; 3],
}

//! VTK XML documents in ASCII for ParaView and meshio: unstructured grids (`.vtu`), vertex poly
//! data (`.vtp`) and the collections (`.pvd`) that make a time series of them. The one writer
//! behind the anatomy's mesh, the atlas's levels, the scene's series and the particles.
//!
//! ```
//! use hydrometra_sim::vtk::{CellType, Document};
//! let mut doc = Document::unstructured_grid(3, 1);
//! doc.cell_data("region", None);
//! doc.array("region", [[2u8]]);
//! doc.points([[0.0f64, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
//! doc.cells([[0usize, 1, 2]], CellType::Triangle);
//! let vtu = doc.finish();
//! assert!(vtu.contains("NumberOfCells=\"1\""));
//! ```

use std::fmt::Write as _;

/// A number a data array holds, and how it is written.
pub trait Value: Copy {
    /// The VTK type name (`UInt8`, `Float32`, ...).
    const TYPE: &'static str;
    /// Appends the value (floating point: the shortest form that reads back to the same value).
    fn write(self, out: &mut String);
}

impl Value for u8 {
    const TYPE: &'static str = "UInt8";
    fn write(self, out: &mut String) {
        let _ = write!(out, "{self}");
    }
}

impl Value for f32 {
    const TYPE: &'static str = "Float32";
    fn write(self, out: &mut String) {
        let _ = write!(out, "{self:e}");
    }
}

impl Value for f64 {
    const TYPE: &'static str = "Float64";
    fn write(self, out: &mut String) {
        let _ = write!(out, "{self:e}");
    }
}

/// An `f32` written with `D` digits after the point (`{:.De}`): smaller files where the full
/// precision is not wanted.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Digits<const D: usize>(pub f32);

impl<const D: usize> Value for Digits<D> {
    const TYPE: &'static str = "Float32";
    fn write(self, out: &mut String) {
        let _ = write!(out, "{:.*e}", D, self.0);
    }
}

/// The cell types written here (VTK's numbers).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum CellType {
    /// One point.
    Vertex = 1,
    /// Three points.
    Triangle = 5,
    /// Four points.
    Tetra = 10,
    /// Eight points, x fastest, then y, then z.
    Voxel = 11,
    /// Eight points, the bottom face's four counter-clockwise, then the top's.
    Hexahedron = 12,
}

/// Which dataset a [`Document`] holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Dataset {
    UnstructuredGrid,
    PolyData,
}

impl Dataset {
    fn root(self) -> &'static str {
        match self {
            Dataset::UnstructuredGrid => "UnstructuredGrid",
            Dataset::PolyData => "PolyData",
        }
    }
    fn cells_tag(self) -> &'static str {
        match self {
            Dataset::UnstructuredGrid => "Cells",
            Dataset::PolyData => "Verts",
        }
    }
}

/// One VTK XML dataset being written, in the order the format wants: point data, cell data (each
/// opened with its active arrays, then its arrays), the points, the cells.
#[derive(Debug)]
pub struct Document {
    out: String,
    dataset: Dataset,
    /// The data section open (`PointData`, `CellData`), closed by the next section.
    open: Option<&'static str>,
}

impl Document {
    fn start(dataset: Dataset, piece: std::fmt::Arguments<'_>, capacity: usize) -> Self {
        let mut out = String::with_capacity(capacity + 512);
        let root = dataset.root();
        let _ = writeln!(
            out,
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"{root}\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<{root}>"
        );
        let _ = writeln!(out, "<Piece {piece}>");
        Self {
            out,
            dataset,
            open: None,
        }
    }

    /// An unstructured grid (`.vtu`) of `points` points and `cells` cells.
    pub fn unstructured_grid(points: usize, cells: usize) -> Self {
        Self::start(
            Dataset::UnstructuredGrid,
            format_args!("NumberOfPoints=\"{points}\" NumberOfCells=\"{cells}\""),
            48 * (points + cells),
        )
    }

    /// Poly data (`.vtp`) of `points` points, one vertex cell each.
    pub fn poly_vertices(points: usize) -> Self {
        Self::start(
            Dataset::PolyData,
            format_args!(
                "NumberOfPoints=\"{points}\" NumberOfVerts=\"{points}\" NumberOfLines=\"0\" NumberOfStrips=\"0\" NumberOfPolys=\"0\""
            ),
            48 * points,
        )
    }

    fn close_section(&mut self) {
        if let Some(tag) = self.open.take() {
            let _ = writeln!(self.out, "</{tag}>");
        }
    }

    fn open_section(&mut self, tag: &'static str, scalars: &str, vectors: Option<&str>) {
        self.close_section();
        let _ = write!(self.out, "<{tag} Scalars=\"{scalars}\"");
        if let Some(v) = vectors {
            let _ = write!(self.out, " Vectors=\"{v}\"");
        }
        self.out.push_str(">\n");
        self.open = Some(tag);
    }

    /// Opens the point data, naming its active scalars (and vectors); the arrays follow.
    pub fn point_data(&mut self, scalars: &str, vectors: Option<&str>) {
        self.open_section("PointData", scalars, vectors);
    }

    /// Opens the cell data, naming its active scalars (and vectors); the arrays follow.
    pub fn cell_data(&mut self, scalars: &str, vectors: Option<&str>) {
        self.open_section("CellData", scalars, vectors);
    }

    /// The tuples as a data array (one per line, `N` components each).
    fn data_array<T: Value, const N: usize>(
        &mut self,
        name: Option<&str>,
        tuples: impl IntoIterator<Item = [T; N]>,
    ) {
        let _ = write!(self.out, "<DataArray type=\"{}\"", T::TYPE);
        if let Some(name) = name {
            let _ = write!(self.out, " Name=\"{name}\"");
        }
        if N > 1 {
            let _ = write!(self.out, " NumberOfComponents=\"{N}\"");
        }
        self.out.push_str(" format=\"ascii\">\n");
        for tuple in tuples {
            for (c, v) in tuple.into_iter().enumerate() {
                if c > 0 {
                    self.out.push(' ');
                }
                v.write(&mut self.out);
            }
            self.out.push('\n');
        }
        self.out.push_str("</DataArray>\n");
    }

    /// A named array of the open point or cell data: one tuple of `N` components per point or
    /// cell.
    pub fn array<T: Value, const N: usize>(
        &mut self,
        name: &str,
        tuples: impl IntoIterator<Item = [T; N]>,
    ) {
        self.data_array(Some(name), tuples);
    }

    /// The points' positions (closes the open data section).
    pub fn points<T: Value>(&mut self, positions: impl IntoIterator<Item = [T; 3]>) {
        self.close_section();
        self.out.push_str("<Points>\n");
        self.data_array(None, positions);
        self.out.push_str("</Points>\n");
    }

    /// The cells, each `N` point indices, all of `cell_type` (a poly data's vertices: one index
    /// each, of [`CellType::Vertex`]).
    pub fn cells<I: Copy + std::fmt::Display, const N: usize>(
        &mut self,
        connectivity: impl IntoIterator<Item = [I; N]>,
        cell_type: CellType,
    ) {
        self.close_section();
        let tag = self.dataset.cells_tag();
        let _ = writeln!(
            self.out,
            "<{tag}>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">"
        );
        let mut count = 0;
        for cell in connectivity {
            for (c, v) in cell.iter().enumerate() {
                if c > 0 {
                    self.out.push(' ');
                }
                let _ = write!(self.out, "{v}");
            }
            self.out.push('\n');
            count += 1;
        }
        self.out.push_str(
            "</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n",
        );
        for i in 0..count {
            let _ = writeln!(self.out, "{}", N * (i + 1));
        }
        self.out.push_str("</DataArray>\n");
        if self.dataset == Dataset::UnstructuredGrid {
            self.out
                .push_str("<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
            let line = format!("{}\n", cell_type as u8);
            for _ in 0..count {
                self.out.push_str(&line);
            }
            self.out.push_str("</DataArray>\n");
        }
        let _ = writeln!(self.out, "</{tag}>");
    }

    /// The document.
    pub fn finish(mut self) -> String {
        self.close_section();
        let root = self.dataset.root();
        let _ = writeln!(self.out, "</Piece>\n</{root}>\n</VTKFile>");
        self.out
    }
}

/// A ParaView collection (`.pvd`): the files of a time series, each at its time step and part.
#[derive(Debug)]
pub struct Collection {
    out: String,
}

impl Default for Collection {
    fn default() -> Self {
        Self::new()
    }
}

impl Collection {
    /// An empty collection.
    pub fn new() -> Self {
        Self {
            out: String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n<Collection>\n"),
        }
    }

    /// Adds `file` (relative to the collection) as part `part` at `timestep`.
    pub fn dataset(&mut self, timestep: f64, part: usize, file: &str) {
        let _ = writeln!(
            self.out,
            "<DataSet timestep=\"{timestep:.4}\" group=\"\" part=\"{part}\" file=\"{file}\"/>"
        );
    }

    /// The document.
    pub fn finish(mut self) -> String {
        self.out.push_str("</Collection>\n</VTKFile>\n");
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The text of the data array named `name` (the points' when `None`), its attributes and its
    /// numbers, read back from `doc`.
    fn read_array(doc: &str, name: Option<&str>) -> (String, Vec<f64>) {
        let start = match name {
            Some(n) => doc
                .find(&format!("Name=\"{n}\""))
                .and_then(|at| doc[..at].rfind("<DataArray"))
                .expect("the array is in the document"),
            None => doc.find("<Points>").expect("points") + "<Points>\n".len(),
        };
        let open_end = start + doc[start..].find('>').expect("tag end") + 1;
        let close = open_end + doc[open_end..].find("</DataArray>").expect("array end");
        let values = doc[open_end..close]
            .split_whitespace()
            .map(|v| v.parse::<f64>().expect("a number"))
            .collect();
        (doc[start..open_end].to_string(), values)
    }

    /// Every array, the points and the cells read back to the values written, in an unstructured
    /// grid with point and cell data and in vertex poly data, and the document's structure is
    /// what VTK's readers expect (one piece, sections in order, counts and offsets).
    #[test]
    fn documents_read_back_to_the_values_written() {
        let points = [
            [0.0f64, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.1, 0.2, 1.0 / 3.0],
        ];
        let mut doc = Document::unstructured_grid(points.len(), 2);
        doc.point_data("label", Some("velocity"));
        doc.array("label", [[3u8], [0], [255], [7]]);
        let velocity = [
            [1.5f32, -2.0, 1e-7],
            [0.0; 3],
            [3.25, 1.0 / 3.0, -0.0],
            [1e30, 2.0, 3.0],
        ];
        doc.array("velocity", velocity);
        doc.cell_data("region", None);
        doc.array("region", [[1u8], [2]]);
        doc.array("speed", [[Digits::<5>(1.0 / 3.0)], [Digits::<5>(2.0)]]);
        doc.points(points);
        doc.cells([[0u32, 1, 2, 3], [3, 2, 1, 0]], CellType::Tetra);
        let vtu = doc.finish();

        assert!(vtu.starts_with("<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\""));
        assert!(vtu.ends_with("</Piece>\n</UnstructuredGrid>\n</VTKFile>\n"));
        let order = [
            "<PointData Scalars=\"label\" Vectors=\"velocity\">",
            "</PointData>",
            "<CellData Scalars=\"region\">",
            "</CellData>",
            "<Points>",
            "</Points>",
            "<Cells>",
            "</Cells>",
        ];
        let at: Vec<usize> = order.iter().map(|t| vtu.find(t).expect(t)).collect();
        assert!(
            at.windows(2).all(|w| w[0] < w[1]),
            "sections out of order: {at:?}"
        );
        assert!(vtu.contains("<Piece NumberOfPoints=\"4\" NumberOfCells=\"2\">"));

        let (tag, label) = read_array(&vtu, Some("label"));
        assert_eq!(
            tag,
            "<DataArray type=\"UInt8\" Name=\"label\" format=\"ascii\">"
        );
        assert_eq!(label, [3.0, 0.0, 255.0, 7.0]);
        let (tag, v) = read_array(&vtu, Some("velocity"));
        assert!(tag.contains("type=\"Float32\"") && tag.contains("NumberOfComponents=\"3\""));
        let written: Vec<f32> = velocity.iter().flatten().copied().collect();
        let read: Vec<f32> = v.iter().map(|&x| x as f32).collect();
        assert_eq!(read, written, "f32 values read back exactly");
        assert_eq!(read_array(&vtu, Some("region")).1, [1.0, 2.0]);
        let (tag, speed) = read_array(&vtu, Some("speed"));
        assert!(tag.contains("type=\"Float32\""));
        assert_eq!(speed, [3.33333e-1, 2.0], "five digits after the point");
        let (tag, p) = read_array(&vtu, None);
        assert!(tag.contains("type=\"Float64\"") && tag.contains("NumberOfComponents=\"3\""));
        let written: Vec<f64> = points.iter().flatten().copied().collect();
        assert_eq!(p, written, "f64 positions read back exactly");
        assert_eq!(
            read_array(&vtu, Some("connectivity")).1,
            [0., 1., 2., 3., 3., 2., 1., 0.]
        );
        assert_eq!(read_array(&vtu, Some("offsets")).1, [4.0, 8.0]);
        assert_eq!(read_array(&vtu, Some("types")).1, [10.0, 10.0]);

        // Vertex poly data: no types array, `Verts` for the cells.
        let mut doc = Document::poly_vertices(2);
        doc.point_data("kind", None);
        doc.array("kind", [[1u8], [2]]);
        doc.points([[0.5f32, 0.25, 0.125], [1.0, 2.0, 4.0]]);
        doc.cells([[0usize], [1]], CellType::Vertex);
        let vtp = doc.finish();
        assert!(vtp.contains("<Piece NumberOfPoints=\"2\" NumberOfVerts=\"2\" NumberOfLines=\"0\""));
        assert!(vtp.contains("<Verts>") && !vtp.contains("Name=\"types\""));
        assert!(vtp.ends_with("</Verts>\n</Piece>\n</PolyData>\n</VTKFile>\n"));
        assert_eq!(read_array(&vtp, None).1, [0.5, 0.25, 0.125, 1.0, 2.0, 4.0]);
        assert_eq!(read_array(&vtp, Some("offsets")).1, [1.0, 2.0]);

        // An empty document is still a valid one.
        let mut doc = Document::unstructured_grid(0, 0);
        doc.points(std::iter::empty::<[f32; 3]>());
        doc.cells(std::iter::empty::<[u32; 3]>(), CellType::Triangle);
        let empty = doc.finish();
        assert!(read_array(&empty, None).1.is_empty());
        assert!(read_array(&empty, Some("types")).1.is_empty());

        let mut pvd = Collection::new();
        pvd.dataset(2.0, 0, "vtu/a.vtu");
        pvd.dataset(1.0 / 3.0, 1, "vtu/b.vtu");
        let pvd = pvd.finish();
        assert!(pvd
            .contains("<DataSet timestep=\"0.3333\" group=\"\" part=\"1\" file=\"vtu/b.vtu\"/>\n"));
        assert!(pvd.ends_with("</Collection>\n</VTKFile>\n"));
    }

    /// meshio, an independent reader, reads the documents (points, cells, point and cell data).
    #[test]
    fn meshio_reads_the_documents() {
        let mut doc = Document::unstructured_grid(4, 1);
        doc.point_data("label", None);
        doc.array("label", [[1u8], [2], [3], [4]]);
        doc.cell_data("region", Some("velocity"));
        doc.array("region", [[9u8]]);
        doc.array(
            "velocity",
            [[Digits::<5>(0.5), Digits::<5>(-1.0), Digits::<5>(2.0)]],
        );
        doc.points([
            [0.0f64, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
        ]);
        doc.cells([[0u32, 1, 2, 3]], CellType::Tetra);
        let dir = std::env::temp_dir().join(format!("hydrometra-vtk-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("a temporary directory");
        let path = dir.join("tet.vtu");
        std::fs::write(&path, doc.finish()).expect("written");
        let script = r#"
import sys, meshio
m = meshio.read(sys.argv[1])
print(len(m.points), m.cells_dict["tetra"].tolist(), m.point_data["label"].tolist(),
      m.cell_data_dict["region"]["tetra"].tolist(), m.cell_data_dict["velocity"]["tetra"].tolist(),
      m.points[:, 2].sum())
"#;
        let out = std::process::Command::new("python3")
            .arg("-c")
            .arg(script)
            .arg(&path)
            .output()
            .expect("python3 with meshio (.ci/requirements.txt)");
        let _ = std::fs::remove_dir_all(&dir);
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "meshio could not read the document: {stdout} {}",
            String::from_utf8_lossy(&out.stderr)
        );
        assert_eq!(
            stdout.trim(),
            "4 [[0, 1, 2, 3]] [1, 2, 3, 4] [9] [[0.5, -1.0, 2.0]] 1.0"
        );
    }
}

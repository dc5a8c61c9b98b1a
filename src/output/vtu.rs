//! ParaView output: one VTU file per body and frame, the contact points of each frame as a point
//! set, and a `.pvd` time series per body and for the contact points.
//!
//! Points are at their current positions (no "Warp By Vector" needed); point data:
//! `displacement`, `velocity`; cell data: `von_mises`, `cauchy_stress` (9 components, row-major),
//! `J`. Contact points carry `gap`, `normal` (master to slave), `normal_reaction`,
//! `tangential_reaction` (vector) and `status` (0 open, 1 stick, 2 slip).

use super::OutputError;
use crate::element::CellFields;
use crate::mesh::ElementKind;
use crate::precision::Real;
use crate::solver::Simulation;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use vtkio::model::{Attribute, Attributes, ByteOrder, CellType, Cells, DataArray, DataSet, ElementType, IOBuffer, UnstructuredGridPiece, Version, VertexNumbers, Vtk};

/// Name of the contact-point series (a body of this name would share its files).
pub const CONTACT_SERIES: &str = "contact_points";

/// Writes the frames of one run into a directory.
pub struct VtuSeries {
    dir: PathBuf,
    /// One series per body, then the contact points when the scene has contact.
    series: Vec<String>,
    /// Simulated time of each frame written so far.
    times: Vec<Real>,
}

fn cell_type(kind: ElementKind) -> CellType {
    match kind {
        ElementKind::Tri3 => CellType::Triangle,
        ElementKind::Quad4 => CellType::Quad,
        ElementKind::Tet4 => CellType::Tetra,
        ElementKind::Hex8 => CellType::Hexahedron,
    }
}

fn array<T>(name: &str, elem: ElementType, data: Vec<T>) -> Attribute
where
    Vec<T>: Into<IOBuffer>,
{
    Attribute::DataArray(DataArray { name: name.into(), elem, data: data.into() })
}

fn scalars(name: &str, data: Vec<Real>) -> Attribute {
    array(name, ElementType::Scalars { num_comp: 1, lookup_table: None }, data)
}

/// A dof vector (2 or 3 components per node) padded to 3 components.
fn padded(values: &[Real], dim: usize) -> Vec<Real> {
    values.chunks(dim).flat_map(|c| [c[0], c[1], if dim == 3 { c[2] } else { 0.0 }]).collect()
}

fn grid(points: Vec<Real>, cells: Cells, data: Attributes) -> Vtk {
    Vtk { version: Version::Auto, title: String::new(), byte_order: ByteOrder::LittleEndian, data: DataSet::inline(UnstructuredGridPiece { points: points.into(), cells, data }), file_path: None }
}

impl VtuSeries {
    /// Creates (or reuses) `dir` for the bodies (and contact points) of `sim`.
    pub fn create(dir: &Path, sim: &Simulation) -> Result<Self, OutputError> {
        std::fs::create_dir_all(dir).map_err(|source| OutputError::Create { path: dir.into(), source })?;
        let mut series: Vec<String> = sim.bodies().iter().map(|b| b.name().to_string()).collect();
        if sim.contact().is_some() {
            series.push(CONTACT_SERIES.into());
        }
        Ok(Self { dir: dir.into(), series, times: Vec::new() })
    }

    fn frame_path(&self, series: &str, frame: usize) -> PathBuf {
        self.dir.join(series).join(format!("{series}_{frame:06}.vtu"))
    }

    fn export(&self, vtk: Vtk, path: &Path) -> Result<(), OutputError> {
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(|source| OutputError::Create { path: parent.into(), source })?;
        }
        let mut xml = Vec::new();
        vtk.write_xml(&mut xml).map_err(|e| OutputError::Write { path: path.into(), message: e.to_string() })?;
        std::fs::write(path, empty_piece_counts(xml)).map_err(|source| OutputError::Create { path: path.into(), source })
    }

    /// Writes the committed state of `sim` as the next frame; `fields` are each body's cell
    /// fields. The `.pvd` files are rewritten so that they list every frame written so far.
    pub fn write_frame(&mut self, sim: &Simulation, fields: &[Vec<CellFields>]) -> Result<(), OutputError> {
        let frame = self.times.len();
        let dim = sim.dim();
        for (b, f) in sim.bodies().iter().zip(fields) {
            let points: Vec<Real> = (0..b.mesh().nodes.len()).flat_map(|n| b.position(n)).collect();
            let nen = b.mesh().kind.nodes() as u64;
            let count = b.mesh().element_count();
            let cells = Cells { cell_verts: VertexNumbers::XML { connectivity: b.mesh().connectivity.iter().map(|&n| n as u64).collect(), offsets: (1..=count as u64).map(|e| e * nen).collect() }, types: vec![cell_type(b.mesh().kind); count] };
            let data = Attributes {
                point: vec![array("displacement", ElementType::Vectors, padded(&b.state().u, dim)), array("velocity", ElementType::Vectors, padded(&b.state().v, dim))],
                cell: vec![scalars("von_mises", f.iter().map(|c| c.von_mises).collect()), array("cauchy_stress", ElementType::Generic(9), f.iter().flat_map(|c| c.cauchy).collect()), scalars("J", f.iter().map(|c| c.jacobian).collect())],
            };
            self.export(grid(points, cells, data), &self.frame_path(b.name(), frame))?;
        }
        if sim.contact().is_some() {
            let c = sim.contact_points();
            let points: Vec<Real> = c.iter().flat_map(|p| sim.bodies()[p.slave_body as usize].position(p.slave_node as usize)).collect();
            let cells = Cells { cell_verts: VertexNumbers::XML { connectivity: (0..c.len() as u64).collect(), offsets: (1..=c.len() as u64).collect() }, types: vec![CellType::Vertex; c.len()] };
            let data = Attributes {
                point: vec![
                    scalars("gap", c.iter().map(|p| p.gap).collect()),
                    array("normal", ElementType::Vectors, c.iter().flat_map(|p| p.frame[0]).collect()),
                    scalars("normal_reaction", c.iter().map(|p| p.r[0]).collect()),
                    array("tangential_reaction", ElementType::Vectors, c.iter().flat_map(|p| p.to_global(&[0.0, p.r[1], p.r[2]])).collect()),
                    array("status", ElementType::Scalars { num_comp: 1, lookup_table: None }, c.iter().map(|p| p.status.code() as i32).collect::<Vec<i32>>()),
                ],
                cell: vec![],
            };
            self.export(grid(points, cells, data), &self.frame_path(CONTACT_SERIES, frame))?;
        }
        self.times.push(sim.t());
        for s in &self.series {
            self.write_pvd(s)?;
        }
        Ok(())
    }

    fn write_pvd(&self, series: &str) -> Result<(), OutputError> {
        let mut xml = String::from("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n");
        for (frame, t) in self.times.iter().enumerate() {
            let file = self.frame_path(series, frame);
            let relative = file.strip_prefix(&self.dir).expect("inside the directory");
            let file = relative.display().to_string().replace('&', "&amp;").replace('"', "&quot;").replace('<', "&lt;");
            writeln!(xml, "    <DataSet timestep=\"{t:e}\" part=\"0\" file=\"{file}\"/>").expect("writes to a string");
        }
        xml.push_str("  </Collection>\n</VTKFile>\n");
        let path = self.dir.join(format!("{series}.pvd"));
        std::fs::write(&path, xml).map_err(|source| OutputError::Create { path, source })
    }
}

/// vtkio leaves out `NumberOfPoints` and `NumberOfCells` when they are zero (a contact frame
/// with no contact point), and readers such as meshio then reject the file: write the zeros.
fn empty_piece_counts(xml: Vec<u8>) -> Vec<u8> {
    const EMPTY: &[u8] = b"<Piece>";
    match xml.windows(EMPTY.len()).position(|w| w == EMPTY) {
        Some(at) => [&xml[..at], b"<Piece NumberOfPoints=\"0\" NumberOfCells=\"0\">", &xml[at + EMPTY.len()..]].concat(),
        None => xml,
    }
}

//! The static measurement dataset (seed 000 §4.3: measured marker positions x̄_i and probe forces
//! f̄_i): in-memory types here; reading, writing and marker embedding in the submodules.
//! The on-disk format is documented in `docs/dataset.md`.

pub mod embed;
pub mod mesh_error;
pub mod read;
pub mod refine;
pub mod write;

use crate::mesh::Mesh;

/// A static contact-measurement dataset, validated and ready to fit.
#[derive(Debug, Clone)]
pub struct StaticDataset {
    /// Short name (from `dataset.toml`).
    pub name: String,
    /// Free-text description.
    pub description: String,
    /// The tetrahedral mesh (rest configuration, metres).
    pub mesh: Mesh,
    /// Name of the fixed (Dirichlet) physical group.
    pub fixed_group: String,
    /// Fixed node indices (sorted).
    pub fixed_nodes: Vec<usize>,
    /// Boundary triangles of the mesh, wound outward (node indices).
    pub surface: Vec<[usize; 3]>,
    /// Default probe radius (m) for contacts that do not give their own.
    pub probe_radius: f64,
    /// Declared marker noise σ (m), if the dataset states one.
    pub marker_noise: Option<f64>,
    /// Gravity vector (m/s²), if the dataset declares that the measurements were taken under it.
    pub gravity: Option<[f64; 3]>,
    /// Markers, embedded in the surface.
    pub markers: Vec<Marker>,
    /// Measurements in file order.
    pub measurements: Vec<Measurement>,
}

/// A surface marker: rest position and its embedding in a boundary triangle.
#[derive(Debug, Clone, PartialEq)]
pub struct Marker {
    /// Marker id as written in `markers.csv`.
    pub id: String,
    /// Rest position (m).
    pub rest: [f64; 3],
    /// Node indices of the boundary triangle the marker is embedded in.
    pub triangle: [usize; 3],
    /// Barycentric coordinates of the closest point on that triangle (sum to 1).
    pub barycentric: [f64; 3],
    /// Distance from the rest position to the surface (m).
    pub distance: f64,
}

impl Marker {
    /// Position of the marker for node positions `x` (interpolated on its triangle).
    pub fn interpolate(&self, x: impl Fn(usize) -> [f64; 3]) -> [f64; 3] {
        let mut p = [0.0; 3];
        for (k, &n) in self.triangle.iter().enumerate() {
            let xn = x(n);
            for d in 0..3 {
                p[d] += self.barycentric[k] * xn[d];
            }
        }
        p
    }
}

/// One measured contact interaction (x̄_i, f̄_i).
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    /// Measurement id as written in the CSV files.
    pub id: String,
    /// Probe contact point on the rest surface (m).
    pub contact: [f64; 3],
    /// Probe force vector (N), spread with the runtime's contact rule.
    pub force: [f64; 3],
    /// Probe radius for this contact (m).
    pub radius: f64,
    /// Observed markers: (index into `StaticDataset::markers`, deformed position in m). A marker
    /// missing here was occluded.
    pub observed: Vec<(usize, [f64; 3])>,
}

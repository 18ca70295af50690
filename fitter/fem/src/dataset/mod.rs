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
    /// Declared height of the markers' stand-offs (m): markers may sit up to this far off the
    /// surface (posts, rigid mounts), carried rigidly by their surface patch.
    pub marker_standoff: Option<f64>,
    /// Markers, embedded in the surface.
    pub markers: Vec<Marker>,
    /// Measurements in file order.
    pub measurements: Vec<Measurement>,
}

/// A marker: a material point of the surface, or of a rigid stand-off on it. It is embedded at the
/// closest point of a boundary triangle (barycentric coordinates); the offset from that point to
/// its rest position — a facet lying a fraction of a millimetre inside a curved object's scanned
/// surface, or a post a few millimetres high — moves rigidly with the triangle.
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
    /// The offset rest − (closest surface point), in the triangle's rest frame
    /// ([`triangle_frame`]: first edge, in-plane normal to it, normal).
    pub offset_local: [f64; 3],
}

impl Marker {
    /// The marker at `rest` embedded by `e` on the triangle of `nodes` it names.
    pub fn embedded(id: String, rest: [f64; 3], e: &embed::Embedding, nodes: &[[f64; 3]]) -> Self {
        let frame = triangle_frame(e.triangle.map(|n| nodes[n]));
        let o = [0, 1, 2].map(|d| rest[d] - e.point[d]);
        Self {
            id,
            rest,
            triangle: e.triangle,
            barycentric: e.barycentric,
            distance: e.distance,
            offset_local: frame.map(|axis| (0..3).map(|d| axis[d] * o[d]).sum()),
        }
    }

    /// The marker's surface point for node positions `x` (interpolated on its triangle, without
    /// the offset).
    pub fn surface_point(&self, x: impl Fn(usize) -> [f64; 3]) -> [f64; 3] {
        let mut p = [0.0; 3];
        for (k, &n) in self.triangle.iter().enumerate() {
            let xn = x(n);
            for d in 0..3 {
                p[d] += self.barycentric[k] * xn[d];
            }
        }
        p
    }

    /// Position of the marker for node positions `x`: the surface point interpolated on its
    /// triangle, plus its offset turned with the triangle ([`triangle_frame`] of the deformed
    /// triangle).
    pub fn interpolate(&self, x: impl Fn(usize) -> [f64; 3]) -> [f64; 3] {
        self.interpolate_on(self.triangle, self.barycentric, x)
    }

    /// [`Marker::interpolate`] with the marker's surface point moved to `barycentric` on
    /// `triangle` (a re-located embedding), the offset carried by that triangle.
    pub fn interpolate_on(
        &self,
        triangle: [usize; 3],
        barycentric: [f64; 3],
        x: impl Fn(usize) -> [f64; 3],
    ) -> [f64; 3] {
        let corners = triangle.map(&x);
        let mut p = [0.0; 3];
        for (k, xn) in corners.iter().enumerate() {
            for d in 0..3 {
                p[d] += barycentric[k] * xn[d];
            }
        }
        if self.offset_local != [0.0; 3] {
            let frame = triangle_frame(corners);
            for (axis, o) in frame.iter().zip(self.offset_local) {
                for d in 0..3 {
                    p[d] += o * axis[d];
                }
            }
        }
        p
    }
}

/// An orthonormal frame of a triangle (a, b, c): t₁ along b − a, t₂ in the plane normal to it,
/// n = t₁ × t₂ (the normal, on the side the winding gives). A degenerate triangle gives the
/// identity frame.
pub fn triangle_frame([a, b, c]: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    use nalgebra::Vector3;
    let (a, b, c) = (Vector3::from(a), Vector3::from(b), Vector3::from(c));
    let n = (b - a).cross(&(c - a));
    let (e, nn) = ((b - a).norm(), n.norm());
    if !(e > 0.0 && nn > 0.0) {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let t1 = (b - a) / e;
    let n = n / nn;
    let t2 = n.cross(&t1);
    [t1.into(), t2.into(), n.into()]
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

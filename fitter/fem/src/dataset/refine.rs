//! A static dataset carried over to its mesh refined once (every tetrahedron into eight,
//! [`crate::mesh::refine`]): the same object, fixed face, markers and measurements, on elements of
//! half the size. The diagnosis solves on it when the dataset mesh's own discretisation error is
//! a large part of the residual ([`crate::dataset::mesh_error`]), and the mesh-error estimate is
//! the simplest model solved on it.
//!
//! Refinement keeps the geometry exactly (faces split in their planes), so every marker's surface
//! point lies on one of the four children of its triangle: it is re-located there with the same
//! rest position and offset, and its prediction on the refined mesh differs from the coarse one
//! only by what the finer elements solve differently.

use std::collections::HashSet;

use super::embed::embed_point;
use super::{Marker, StaticDataset};
use crate::mesh::refine::refine_with_midpoints;

/// Why a dataset could not be refined.
#[derive(Debug, thiserror::Error)]
pub enum RefineError {
    /// A marker's surface point is on no refined boundary triangle (cannot happen for a valid
    /// dataset: the refined surface covers the coarse one).
    #[error("marker {marker:?}: its surface point {point:?} is on no triangle of the refined surface (nearest at {distance:e} m)")]
    Marker {
        /// Marker id.
        marker: String,
        /// Its surface point (m).
        point: [f64; 3],
        /// Distance to the nearest refined triangle (m).
        distance: f64,
    },
}

/// The dataset on its mesh refined once. Node indices of the coarse mesh are kept; a midpoint is
/// fixed when both ends of its edge are.
pub fn refine_dataset(ds: &StaticDataset) -> Result<StaticDataset, RefineError> {
    let (mesh, mid) = refine_with_midpoints(&ds.mesh);
    let fixed: HashSet<usize> = ds.fixed_nodes.iter().copied().collect();
    let mut fixed_nodes = ds.fixed_nodes.clone();
    fixed_nodes.extend(
        mid.iter()
            .filter(|((a, b), _)| fixed.contains(a) && fixed.contains(b))
            .map(|(_, &m)| m),
    );
    fixed_nodes.sort_unstable();
    let surface = mesh.boundary_triangles();
    // The re-located point must be the same point: allow round-off of the coordinates only.
    let (lo, hi) = ds.mesh.bounds();
    let tol = 1e-9
        * (0..3)
            .map(|d| hi[d] - lo[d])
            .fold(0.0, f64::max)
            .max(1e-300);
    let markers = ds
        .markers
        .iter()
        .map(|m| {
            let point = m.surface_point(|n| ds.mesh.nodes[n]);
            match embed_point(&mesh, &surface, point) {
                // The same surface point and the same offset to the rest position, on a
                // refined triangle (coplanar with the coarse one).
                Some(e) if e.distance <= tol => Ok(Marker {
                    distance: m.distance,
                    ..Marker::embedded(m.id.clone(), m.rest, &e, &mesh.nodes)
                }),
                other => Err(RefineError::Marker {
                    marker: m.id.clone(),
                    point,
                    distance: other.map_or(f64::INFINITY, |e| e.distance),
                }),
            }
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(StaticDataset {
        marker_standoff: ds.marker_standoff,
        name: ds.name.clone(),
        description: ds.description.clone(),
        mesh,
        fixed_group: ds.fixed_group.clone(),
        fixed_nodes,
        surface,
        probe_radius: ds.probe_radius,
        marker_noise: ds.marker_noise,
        gravity: ds.gravity,
        markers,
        measurements: ds.measurements.clone(),
    })
}

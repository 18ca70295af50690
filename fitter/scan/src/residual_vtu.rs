//! A scan fit's residual for ParaView (or meshio): two VTK XML unstructured grids (ASCII, so any
//! reader takes them).
//!
//! - `<name>-points.vtu`: every scanned point as a vertex cell, with its signed distance to the
//!   fitted surface `signed_distance_m` (positive outside; NaN where no surface was within the
//!   search radius), the distance over its noise `scaled_residual`, its noise `sigma_m` and its
//!   robust weight `weight` (0 for a point the fit ignored).
//! - `<name>-surface.vtu`: the fitted, deformed surface as triangles, with each surface node's
//!   `mean_residual_m` — the mean signed distance of the points whose closest point lies on a
//!   triangle at that node, each counted by its barycentric coordinate there (NaN where no point
//!   lands) — `points_near` (the sum of those coordinates) and `displacement` (m) from rest.
//!
//! Colouring the surface by `mean_residual_m` shows where the model and the scan part: a
//! systematic sign over a region is a misfit of the model, scatter about zero is noise.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::fit::{PointResidual, ScanFit, ScanPoints};
use crate::ScanError;

/// VTK cell types.
const VTK_VERTEX: u8 = 1;
const VTK_TRIANGLE: u8 = 5;

/// Per surface node of `surface`: the barycentric-weighted mean signed distance of the points
/// whose closest point lies on a triangle at that node, and the weight summed (the mean is NaN
/// where the weight is 0). Indices are `nodes`' (the mesh's), one entry per node.
pub fn node_mean_residual(nodes: usize, residuals: &[PointResidual]) -> (Vec<f64>, Vec<f64>) {
    let mut sum = vec![0.0; nodes];
    let mut weight = vec![0.0; nodes];
    for r in residuals {
        let c = &r.correspondence;
        for (n, b) in c.triangle.iter().zip(c.barycentric) {
            sum[*n] += b * c.distance;
            weight[*n] += b;
        }
    }
    let mean = sum
        .iter()
        .zip(&weight)
        .map(|(s, w)| if *w > 0.0 { s / w } else { f64::NAN })
        .collect();
    (mean, weight)
}

/// Writes the two files of `fit` against `scan` into `dir` as `<name>-points.vtu` and
/// `<name>-surface.vtu`; returns their paths.
pub fn write_fit_residual(
    dir: &Path,
    name: &str,
    scan: &ScanPoints,
    fit: &ScanFit,
) -> Result<Vec<PathBuf>, ScanError> {
    std::fs::create_dir_all(dir).map_err(|e| ScanError::io(dir, e))?;
    let n = scan.points.len();
    let (mut d, mut scaled, mut weight) = (vec![f64::NAN; n], vec![f64::NAN; n], vec![0.0; n]);
    for r in &fit.at_fit.residuals {
        let i = r.correspondence.point;
        d[i] = r.correspondence.distance;
        scaled[i] = r.scaled();
        weight[i] = r.weight;
    }
    let points: Vec<[f64; 3]> = scan.points.iter().map(|p| [p.x, p.y, p.z]).collect();
    let cells: Vec<Vec<usize>> = (0..n).map(|i| vec![i]).collect();
    let points_file = dir.join(format!("{name}-points.vtu"));
    write_grid(
        &points_file,
        &points,
        &cells,
        VTK_VERTEX,
        &[
            ("signed_distance_m", Data::Scalar(&d)),
            ("scaled_residual", Data::Scalar(&scaled)),
            ("sigma_m", Data::Scalar(&scan.sigma)),
            ("weight", Data::Scalar(&weight)),
        ],
    )?;

    let eq = &fit.at_fit.equilibrium;
    let (mean, near) = node_mean_residual(eq.positions.len(), &fit.at_fit.residuals);
    // Only the surface's nodes, renumbered, so that the file holds no interior point.
    let mut index = vec![usize::MAX; eq.positions.len()];
    let mut kept = Vec::new();
    for t in &eq.surface {
        for &v in t {
            if index[v] == usize::MAX {
                index[v] = kept.len();
                kept.push(v);
            }
        }
    }
    let pick = |v: &[f64]| kept.iter().map(|&k| v[k]).collect::<Vec<f64>>();
    let displacement: Vec<[f64; 3]> = kept
        .iter()
        .map(|&k| [0, 1, 2].map(|a| eq.positions[k][a] - eq.rest[k][a]))
        .collect();
    let surface_points: Vec<[f64; 3]> = kept.iter().map(|&k| eq.positions[k]).collect();
    let triangles: Vec<Vec<usize>> = eq
        .surface
        .iter()
        .map(|t| t.iter().map(|&v| index[v]).collect())
        .collect();
    let surface_file = dir.join(format!("{name}-surface.vtu"));
    write_grid(
        &surface_file,
        &surface_points,
        &triangles,
        VTK_TRIANGLE,
        &[
            ("mean_residual_m", Data::Scalar(&pick(&mean))),
            ("points_near", Data::Scalar(&pick(&near))),
            ("displacement", Data::Vector(&displacement)),
        ],
    )?;
    Ok(vec![points_file, surface_file])
}

enum Data<'a> {
    Scalar(&'a [f64]),
    Vector(&'a [[f64; 3]]),
}

/// Writes one unstructured grid of cells of one type, ASCII VTK XML 1.0, atomically.
fn write_grid(
    path: &Path,
    points: &[[f64; 3]],
    cells: &[Vec<usize>],
    cell_type: u8,
    point_data: &[(&str, Data)],
) -> Result<(), ScanError> {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">",
        points.len(),
        cells.len()
    );
    s.push_str("<PointData>\n");
    for (name, data) in point_data {
        match data {
            Data::Scalar(v) => {
                let _ = writeln!(
                    s,
                    "<DataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"1\" format=\"ascii\">"
                );
                for x in *v {
                    let _ = write!(s, "{} ", number(*x));
                }
            }
            Data::Vector(v) => {
                let _ = writeln!(
                    s,
                    "<DataArray type=\"Float64\" Name=\"{name}\" NumberOfComponents=\"3\" format=\"ascii\">"
                );
                for x in v.iter().flatten() {
                    let _ = write!(s, "{} ", number(*x));
                }
            }
        }
        s.push_str("\n</DataArray>\n");
    }
    s.push_str("</PointData>\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for x in points.iter().flatten() {
        let _ = write!(s, "{} ", number(*x));
    }
    s.push_str("\n</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n");
    for c in cells {
        for v in c {
            let _ = write!(s, "{v} ");
        }
    }
    s.push_str("\n</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n");
    let mut offset = 0;
    for c in cells {
        offset += c.len();
        let _ = write!(s, "{offset} ");
    }
    s.push_str("\n</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for _ in cells {
        let _ = write!(s, "{cell_type} ");
    }
    s.push_str("\n</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    palpate_fem::io::atomic::write_atomic(path, s.as_bytes())
        .map_err(|e| ScanError::Invalid(format!("{}: {e}", path.display())))
}

/// A value as VTK's ASCII reader takes it: shortest round-trip form, NaN as "nan".
fn number(x: f64) -> String {
    if x.is_nan() {
        "nan".into()
    } else {
        format!("{x:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::surface::Correspondence;
    use nalgebra::Vector3;

    fn residual(point: usize, triangle: [usize; 3], b: [f64; 3], d: f64) -> PointResidual {
        PointResidual {
            correspondence: Correspondence {
                point,
                triangle,
                barycentric: b,
                normal: Vector3::z(),
                distance: d,
            },
            sigma: 1e-3,
            weight: 1.0,
        }
    }

    /// Two points on triangle (0, 1, 2): one at node 0 (b = 1, 0, 0) 2 mm out, one at the
    /// centroid 1 mm in. By hand: node 0 gets (1·2 + ⅓·(−1))/(1 + ⅓) = 1.25 mm, nodes 1 and 2
    /// only the centroid's −1 mm, node 3 nothing (NaN).
    #[test]
    fn each_node_gets_the_barycentric_mean_of_its_points() {
        let t = 1.0 / 3.0;
        let r = [
            residual(0, [0, 1, 2], [1.0, 0.0, 0.0], 2e-3),
            residual(1, [0, 1, 2], [t, t, t], -1e-3),
        ];
        let (mean, near) = node_mean_residual(4, &r);
        assert!((mean[0] - 1.25e-3).abs() < 1e-15, "{mean:?}");
        assert!((mean[1] + 1e-3).abs() < 1e-15 && (mean[2] + 1e-3).abs() < 1e-15);
        assert!(mean[3].is_nan() && near[3] == 0.0);
        assert!((near[0] - 4.0 / 3.0).abs() < 1e-15);
    }
}

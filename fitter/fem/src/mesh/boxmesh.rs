//! A built-in structured box mesher (six Kuhn tetrahedra per cell) for tests and benchmarks.

use super::Mesh;
use std::collections::BTreeMap;

/// Meshes the box [0, size] with `cells` cells per axis, six tetrahedra per cell (Kuhn
/// subdivision along the main diagonal, conforming across cells). Node groups: `bottom` (z = 0),
/// `top`, `left` (x = 0), `right`, `front` (y = 0), `back`.
pub fn box_mesh(size: [f64; 3], cells: [usize; 3]) -> Mesh {
    let grid = |k: usize| {
        (0..=cells[k])
            .map(|i| size[k] * i as f64 / cells[k] as f64)
            .collect::<Vec<_>>()
    };
    box_mesh_graded([&grid(0), &grid(1), &grid(2)])
}

/// Like [`box_mesh`], on arbitrary increasing grid coordinates per axis (graded meshes for
/// contact problems: fine under the probe, coarse far away).
pub fn box_mesh_graded(grid: [&[f64]; 3]) -> Mesh {
    let [nx, ny, nz] = [grid[0].len() - 1, grid[1].len() - 1, grid[2].len() - 1];
    let size = [
        grid[0][nx] - grid[0][0],
        grid[1][ny] - grid[1][0],
        grid[2][nz] - grid[2][0],
    ];
    let origin = [grid[0][0], grid[1][0], grid[2][0]];
    let id = |i: usize, j: usize, k: usize| (k * (ny + 1) + j) * (nx + 1) + i;
    let mut nodes = Vec::with_capacity((nx + 1) * (ny + 1) * (nz + 1));
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([grid[0][i], grid[1][j], grid[2][k]]);
            }
        }
    }
    const PERMS: [[usize; 3]; 6] = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::with_capacity(6 * nx * ny * nz);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for p in PERMS {
                    let mut c = [i, j, k];
                    let mut t = [id(c[0], c[1], c[2]); 4];
                    for (s, axis) in p.iter().enumerate() {
                        c[*axis] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    if signed_volume(&nodes, &t) < 0.0 {
                        t.swap(2, 3);
                    }
                    tets.push(t);
                }
            }
        }
    }
    let mut groups: BTreeMap<String, Vec<usize>> = BTreeMap::new();
    for (n, p) in nodes.iter().enumerate() {
        let tol = 1e-12 * (size[0] + size[1] + size[2]);
        let mut put = |name: &str, on: bool| {
            if on {
                groups.entry(name.to_string()).or_default().push(n);
            }
        };
        put("left", (p[0] - origin[0]).abs() < tol);
        put("right", (p[0] - origin[0] - size[0]).abs() < tol);
        put("front", (p[1] - origin[1]).abs() < tol);
        put("back", (p[1] - origin[1] - size[1]).abs() < tol);
        put("bottom", (p[2] - origin[2]).abs() < tol);
        put("top", (p[2] - origin[2] - size[2]).abs() < tol);
    }
    let node_tags = (1..=nodes.len() as u64).collect();
    Mesh {
        nodes,
        node_tags,
        tets,
        node_groups: groups,
    }
}

/// Grid coordinates on [lo, hi] with spacing `fine` inside [fine_lo, fine_hi] and cells growing
/// by `ratio` per cell outside it (capped at `coarse`).
pub fn graded_axis(
    lo: f64,
    hi: f64,
    fine_lo: f64,
    fine_hi: f64,
    fine: f64,
    ratio: f64,
    coarse: f64,
) -> Vec<f64> {
    let n_fine = ((fine_hi - fine_lo) / fine).round().max(1.0) as usize;
    let mut pts: Vec<f64> = (0..=n_fine)
        .map(|i| fine_lo + (fine_hi - fine_lo) * i as f64 / n_fine as f64)
        .collect();
    let grow = |from: f64, to: f64| {
        let mut out = Vec::new();
        let dir = (to - from).signum();
        let mut h = fine;
        let mut x = from;
        while (to - x) * dir > 1e-12 {
            h = (h * ratio).min(coarse);
            x += dir * h;
            if (to - x) * dir < 0.5 * h {
                x = to;
            }
            out.push(x);
        }
        out
    };
    let mut left = grow(fine_lo, lo);
    left.reverse();
    let right = grow(fine_hi, hi);
    left.append(&mut pts);
    left.extend(right);
    left
}

/// Cells per axis for a box of `size` with about `target_tets` tetrahedra and near-cubic cells.
pub fn cells_for_target(size: [f64; 3], target_tets: usize) -> [usize; 3] {
    let vol = size[0] * size[1] * size[2];
    let h = (vol * 6.0 / target_tets.max(6) as f64).cbrt();
    [
        ((size[0] / h).round() as usize).max(1),
        ((size[1] / h).round() as usize).max(1),
        ((size[2] / h).round() as usize).max(1),
    ]
}

fn signed_volume(nodes: &[[f64; 3]], t: &[usize; 4]) -> f64 {
    super::signed_volume(t.map(|n| nodes[n]))
}

/// A solid circular cylinder of `radius` along y from 0 to `length`, meshed as a box of
/// `cells = [across, along]` cells whose square cross-section is mapped onto the disc
/// (elliptical grid mapping u √(1 − w²/2), w √(1 − u²/2): every node of the square's boundary
/// lands on the circle, interior cells stay convex). Node groups `front` (y = 0, the clamp of a
/// cantilever) and `back` (y = length); the box's side groups are dropped (they are no longer
/// planar faces).
pub fn cylinder_mesh(radius: f64, length: f64, cells: [usize; 2]) -> Mesh {
    let [across, along] = cells;
    let mut mesh = box_mesh(
        [2.0 * radius, length, 2.0 * radius],
        [across, along, across],
    );
    for p in mesh.nodes.iter_mut() {
        let (u, w) = (p[0] / radius - 1.0, p[2] / radius - 1.0);
        p[0] = radius * u * (1.0 - 0.5 * w * w).sqrt();
        p[2] = radius * w * (1.0 - 0.5 * u * u).sqrt();
    }
    mesh.node_groups
        .retain(|name, _| name == "front" || name == "back");
    mesh
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_mesh_volumes_sum_and_surface_is_closed() {
        let m = box_mesh([0.1, 0.1, 0.05], [4, 4, 2]);
        assert_eq!(m.tets.len(), 6 * 32);
        let v: f64 = m.tets.iter().map(|t| signed_volume(&m.nodes, t)).sum();
        assert!((v - 0.1 * 0.1 * 0.05).abs() < 1e-15);
        assert!(m.tets.iter().all(|t| signed_volume(&m.nodes, t) > 0.0));
        // Closed surface of a box: 2 triangles per boundary cell face.
        let tris = m.boundary_triangles();
        assert_eq!(tris.len(), 2 * (2 * 16 + 2 * 8 + 2 * 8));
        assert_eq!(m.group("bottom").unwrap().len(), 25);
    }
}

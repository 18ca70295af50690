//! The quasi-static Neo-Hookean problem of [`super::statics`] on quadratic (10-node) tetrahedra:
//! the same [`StaticProblem`] (mesh, material, fixed nodes, nodal forces, gravity) solved on
//! [`QuadraticMesh::from_linear`] of its linear mesh. Linear tetrahedra lock in bending as
//! Poisson's ratio nears ½ (docs/results/discretisation); quadratic ones do not.
//!
//! - Corner nodes keep the linear mesh's indices, so fixed nodes, nodal forces and markers named
//!   on the linear mesh mean the same here; an edge node is fixed when both its corners are
//!   ([`QuadraticMesh::lift_flags`]) and moves with their mean (a straight edge stays straight).
//! - Nodal forces act on the corner nodes as given; gravity is the consistent load ∫ ρ g N_a dV.
//! - Energy, forces and tangent are integrated with the 4-point rule (degree 2, exact for the
//!   small-strain stiffness of straight-sided elements), with the kernel of
//!   [`super::hyperelastic`] at each quadrature point's deformation gradient
//!   F = Σ_a x_a ∇N_aᵀ.
//! - The load-increment Newton loop and the sensitivities are [`super::statics`]' own.

use super::hyperelastic::{self as he, FParts, HyperParams, RestTet};
use super::sparse::Pattern;
use super::static_newton::{check_problem, Discretised, Dofs, Prepared};
use super::statics::{StaticProblem, StaticSensitivity, StaticSolution};
use super::viscosity::Moduli;
use super::MotionError;
use nalgebra::{Matrix3, Vector3};
use palpate_fem::mesh::quadratic::{QuadraticMesh, QUADRATIC_EDGES};
use std::borrow::Cow;
use std::cell::RefCell;
use std::rc::Rc;

/// The 4-point rule on a tetrahedron (degree 2): barycentric coordinates (a, b, b, b) and its
/// permutations, weight ¼ of the volume each.
const QUADRATURE_A: f64 = 0.585_410_196_624_968_5;
const QUADRATURE_B: f64 = 0.138_196_601_125_010_5;

/// The quadrature points' barycentric coordinates.
pub(crate) fn quadrature_points() -> [[f64; 4]; 4] {
    std::array::from_fn(|q| {
        std::array::from_fn(|a| if a == q { QUADRATURE_A } else { QUADRATURE_B })
    })
}

/// The ten quadratic shape functions at barycentric coordinates `l` (corners, then the edge
/// nodes in [`QUADRATIC_EDGES`] order): N_a = L_a (2 L_a − 1), N_ab = 4 L_a L_b.
pub fn shape_functions(l: &[f64; 4]) -> [f64; 10] {
    std::array::from_fn(|k| {
        if k < 4 {
            l[k] * (2.0 * l[k] - 1.0)
        } else {
            let [a, b] = QUADRATIC_EDGES[k - 4];
            4.0 * l[a] * l[b]
        }
    })
}

/// Gradients of the ten shape functions at `l`, from the linear element's constant ∇L_a:
/// ∇N_a = (4 L_a − 1) ∇L_a, ∇N_ab = 4 (L_b ∇L_a + L_a ∇L_b).
pub(crate) fn shape_gradients(grad: &[Vector3<f64>; 4], l: &[f64; 4]) -> [Vector3<f64>; 10] {
    std::array::from_fn(|k| {
        if k < 4 {
            grad[k] * (4.0 * l[k] - 1.0)
        } else {
            let [a, b] = QUADRATIC_EDGES[k - 4];
            (grad[a] * l[b] + grad[b] * l[a]) * 4.0
        }
    })
}

/// The element's 10 × 10 node pairs split into ten 4-node blocks, so that the linear element's
/// closed-form tangent ([`he::element_tangent`], which holds for any four gradient vectors) and
/// the 4-node sparsity [`Pattern`] serve the 10-node element: the nodes are paired
/// {0,1}, {2,3}, …, {8,9} and block (g, h) holds pairs g and h. A pair of nodes from different
/// groups lies in exactly one block; a pair within one group lies in four, so its entries are
/// added at a quarter ([`BLOCK_SHARE`]).
pub(crate) const BLOCKS: [[usize; 4]; 10] = {
    let mut out = [[0; 4]; 10];
    let mut k = 0;
    let mut g = 0;
    while g < 5 {
        let mut h = g + 1;
        while h < 5 {
            out[k] = [2 * g, 2 * g + 1, 2 * h, 2 * h + 1];
            k += 1;
            h += 1;
        }
        g += 1;
    }
    out
};

/// The share of a block's local entry (r, c): ¼ when both dofs' nodes are in one group.
pub(crate) fn block_share(r: usize, c: usize) -> f64 {
    if r / 6 == c / 6 {
        0.25
    } else {
        1.0
    }
}

/// One quadrature point of one element: shape-function gradients and weight (volume share).
#[derive(Debug, Clone, Copy)]
pub(crate) struct QuadPoint {
    pub(crate) grad: [Vector3<f64>; 10],
    pub(crate) weight: f64,
}

/// Every element's four quadrature points, from its linear rest geometry.
pub(crate) fn element_points(rest: &[RestTet]) -> Vec<[QuadPoint; 4]> {
    let bary = quadrature_points();
    rest.iter()
        .map(|r| {
            bary.map(|l| QuadPoint {
                grad: shape_gradients(&r.grad, &l),
                weight: r.volume / 4.0,
            })
        })
        .collect()
}

/// The ten 4-node blocks of every element ([`BLOCKS`]), as the tetrahedra of the tangent's
/// [`Pattern`]; block b of element e is entry 10e + b.
pub(crate) fn block_tets(q: &QuadraticMesh) -> Vec<[usize; 4]> {
    q.tets
        .iter()
        .flat_map(|t| BLOCKS.map(|b| b.map(|a| t[a])))
        .collect()
}

/// Scales a block's entries by their share ([`block_share`]).
pub(crate) fn share(m: &mut [[f64; 12]; 12]) {
    for (r, row) in m.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v *= block_share(r, c);
        }
    }
}

/// For each of the ten blocks ([`BLOCKS`]) and each local entry 12 r + c of a block, the entry
/// 30 R + C of the element's 30 × 30 matrix it holds.
const BLOCK_ENTRIES: [[u16; 144]; 10] = {
    let mut out = [[0; 144]; 10];
    let mut b = 0;
    while b < 10 {
        let mut local = 0;
        while local < 144 {
            let (lr, lc) = (local / 12, local % 12);
            let r = 3 * BLOCKS[b][lr / 3] + lr % 3;
            let c = 3 * BLOCKS[b][lc / 3] + lc % 3;
            out[b][local] = (30 * r + c) as u16;
            local += 1;
        }
        b += 1;
    }
    out
};

/// Where each element's symmetric 30 × 30 matrix goes in a [`Pattern`] built on its ten blocks
/// ([`block_tets`]): per element, each stored entry it touches once, with the entry 30 R + C of
/// its node-block upper triangle that fills it. The blocks hold a pair of nodes of one group
/// four times at a quarter ([`block_share`]); summed here, each pair is one read and one add
/// instead of up to four scaled ones, and K and D go in one pass ([`Self::add_pair`]).
#[derive(Debug, Clone)]
pub(crate) struct ElementScatter {
    ptr: Vec<usize>,
    entries: Vec<(u16, u32)>,
}

impl ElementScatter {
    /// The scatter of `elements` elements from `pattern`'s block lists (element e's blocks are
    /// its entries 10e … 10e + 9). Sorted by stored entry, so the adds walk the values forward.
    pub(crate) fn new(pattern: &Pattern, elements: usize) -> Self {
        let mut ptr = Vec::with_capacity(elements + 1);
        let mut entries = Vec::new();
        ptr.push(0);
        let mut merged: Vec<(u32, u16, f64)> = Vec::new();
        for e in 0..elements {
            merged.clear();
            for (b, block) in BLOCK_ENTRIES.iter().enumerate() {
                for &(local, idx) in pattern.element_entries(BLOCKS.len() * e + b) {
                    let local = usize::from(local);
                    merged.push((idx, block[local], block_share(local / 12, local % 12)));
                }
            }
            merged.sort_unstable_by_key(|&(idx, entry, _)| (idx, entry));
            let mut k = 0;
            while k < merged.len() {
                let (idx, entry, mut share) = merged[k];
                k += 1;
                while k < merged.len() && (merged[k].0, merged[k].1) == (idx, entry) {
                    share += merged[k].2;
                    k += 1;
                }
                // Every pair of nodes is held by blocks whose shares sum to one.
                debug_assert!((share - 1.0).abs() < 1e-12, "share {share}");
                entries.push((entry, idx));
            }
            ptr.push(entries.len());
        }
        Self { ptr, entries }
    }

    /// Adds element `e`'s `ke` (its node-block upper triangle read) into `values`.
    pub(crate) fn add(&self, e: usize, ke: &[[f64; 30]; 30], values: &mut [f64]) {
        let flat = ke.as_flattened();
        for &(entry, idx) in &self.entries[self.ptr[e]..self.ptr[e + 1]] {
            values[idx as usize] += flat[usize::from(entry)];
        }
    }

    /// [`Self::add`] of two matrices of element `e` into two value arrays in one pass.
    pub(crate) fn add_pair(
        &self,
        e: usize,
        (ke, kvalues): (&[[f64; 30]; 30], &mut [f64]),
        (de, dvalues): (&[[f64; 30]; 30], &mut [f64]),
    ) {
        let (kf, df) = (ke.as_flattened(), de.as_flattened());
        for &(entry, idx) in &self.entries[self.ptr[e]..self.ptr[e + 1]] {
            kvalues[idx as usize] += kf[usize::from(entry)];
            dvalues[idx as usize] += df[usize::from(entry)];
        }
    }
}

/// Adds the tangent of the moduli `a` at one quadrature point ([`Moduli`], the point's volume
/// in them), Σ_kl ∇φ_a,k A\[3i+k\]\[3j+l\] ∇φ_b,l, to `k`\[3a+i\]\[3b+j\] where b ≥ a (the
/// node-block upper triangle [`ElementScatter`] reads; `a` has A\[r\]\[c\] = A\[c\]\[r\]).
/// First W\[3i+k\] = A\[3i+k\] ∇φ (nine 30-vectors), then each row a sum of three of them
/// from column 3a on: the loops run over contiguous columns in SIMD lanes.
pub(crate) fn add_moduli_rows(grad: &[Vector3<f64>; 10], a: &Moduli, k: &mut [[f64; 30]; 30]) {
    let w: [[f64; 30]; 9] = std::array::from_fn(|r| {
        let m = &a[r];
        std::array::from_fn(|col| {
            let (g, j) = (&grad[col / 3], 3 * (col % 3));
            m[j] * g.x + m[j + 1] * g.y + m[j + 2] * g.z
        })
    });
    for (na, g) in grad.iter().enumerate() {
        for i in 0..3 {
            let (w0, w1, w2) = (&w[3 * i], &w[3 * i + 1], &w[3 * i + 2]);
            let row = &mut k[3 * na + i];
            for col in 3 * na..30 {
                row[col] += g.x * w0[col] + g.y * w1[col] + g.z * w2[col];
            }
        }
    }
}

/// Adds V (∇φ_a · C ∇φ_b) δ_ij at one quadrature point (gradients `grad`, volume `volume`) to
/// `k`\[3a+i\]\[3b+j\] where b ≥ a: a stress-like term whose force is F C ∇φ_a (the creep
/// branch's, [`crate::relaxation::StepBranch::tangent`]), for a symmetric C.
pub(crate) fn add_symmetric_rows(
    grad: &[Vector3<f64>; 10],
    volume: f64,
    c: &Matrix3<f64>,
    k: &mut [[f64; 30]; 30],
) {
    for (na, ga) in grad.iter().enumerate() {
        let ca = c * ga * volume;
        for (nb, gb) in grad.iter().enumerate().skip(na) {
            let w = ca.dot(gb);
            for i in 0..3 {
                k[3 * na + i][3 * nb + i] += w;
            }
        }
    }
}

/// The equilibrium found on quadratic tetrahedra.
#[derive(Debug, Clone)]
pub struct QuadraticSolution {
    /// The quadratic mesh solved on.
    pub mesh: QuadraticMesh,
    /// Positions of every node of [`Self::mesh`] (the linear mesh's corners first), Newton
    /// iterations and residual.
    pub solution: StaticSolution,
}

impl QuadraticSolution {
    /// The deformed position of the point at barycentric coordinates `l` in linear element `e`
    /// (the same element index as the linear mesh's), through the quadratic shape functions.
    pub fn position_at(&self, e: usize, l: &[f64; 4]) -> [f64; 3] {
        value_at(&self.mesh, &self.solution.positions, e, l)
    }
}

/// A nodal field of `mesh` (positions, sensitivities) at barycentric coordinates `l` of linear
/// element `e`, through the quadratic shape functions.
pub fn value_at(mesh: &QuadraticMesh, values: &[[f64; 3]], e: usize, l: &[f64; 4]) -> [f64; 3] {
    interpolate(&mesh.tets[e], &shape_functions(l), values)
}

/// Σ_a N_a v_a over an element's ten nodes.
fn interpolate(t: &[usize; 10], n: &[f64; 10], v: &[[f64; 3]]) -> [f64; 3] {
    let mut p = [0.0; 3];
    for (a, &node) in t.iter().enumerate() {
        for d in 0..3 {
            p[d] += n[a] * v[node][d];
        }
    }
    p
}

struct Ctx<'a> {
    p: &'a StaticProblem<'a>,
    q: &'a QuadraticMesh,
    points: &'a [[QuadPoint; 4]],
    /// Where the element tangents go in the lift's pattern, the one [`Discretised::forces`] is
    /// handed.
    scatter: &'a ElementScatter,
}

impl Ctx<'_> {
    fn mat(&self, e: usize) -> &HyperParams {
        self.p.material_of(e)
    }
    fn deformation_gradient(&self, e: usize, qp: &QuadPoint, x: &[f64]) -> Matrix3<f64> {
        let mut f = Matrix3::zeros();
        for (a, &n) in self.q.tets[e].iter().enumerate() {
            f += Vector3::new(x[3 * n], x[3 * n + 1], x[3 * n + 2]) * qp.grad[a].transpose();
        }
        f
    }
    /// Adds −w P ∇N_a at every node of element `e` into `f`.
    fn add_stress(&self, e: usize, qp: &QuadPoint, p: &Matrix3<f64>, f: &mut [f64]) {
        for (a, &n) in self.q.tets[e].iter().enumerate() {
            let fa = p * qp.grad[a] * (-qp.weight);
            for i in 0..3 {
                f[3 * n + i] += fa[i];
            }
        }
    }
}

impl Discretised for Ctx<'_> {
    fn energy(&self, x: &[f64]) -> Option<f64> {
        let mut total = 0.0;
        for (e, pts) in self.points.iter().enumerate() {
            for qp in pts {
                let f = self.deformation_gradient(e, qp, x);
                total += qp.weight * he::energy_density(&f, self.mat(e))?;
            }
        }
        Some(total)
    }

    fn forces(&self, x: &[f64], mut k: Option<(&Pattern, &mut [f64])>) -> Option<Vec<f64>> {
        let mut f = vec![0.0; x.len()];
        if let Some((_, k)) = k.as_mut() {
            k.iter_mut().for_each(|v| *v = 0.0);
        }
        // The element's 30 × 30 tangent, its node-block upper triangle summed over the
        // quadrature points in SIMD rows and scattered once, each stored entry it touches once
        // ([`ElementScatter`]): the ten 12 × 12 blocks of every point were entries one at a
        // time and four times the scatters.
        let mut ke = [[0.0; 30]; 30];
        let want_k = k.is_some();
        for (e, pts) in self.points.iter().enumerate() {
            if want_k {
                ke = [[0.0; 30]; 30];
            }
            for qp in pts {
                let s = FParts::new(self.deformation_gradient(e, qp, x))?;
                self.add_stress(e, qp, &he::pk1(&s, self.mat(e)), &mut f);
                if want_k {
                    he::quadratic_point_tangent(&qp.grad, qp.weight, &s, self.mat(e), &mut ke);
                }
            }
            if let Some((_, k)) = k.as_mut() {
                self.scatter.add(e, &ke, k);
            }
        }
        Some(f)
    }

    fn parameter_forces(&self, x: &[f64]) -> Option<[Vec<f64>; 2]> {
        let mut out = [vec![0.0; x.len()], vec![0.0; x.len()]];
        for (e, pts) in self.points.iter().enumerate() {
            for qp in pts {
                let s = FParts::new(self.deformation_gradient(e, qp, x))?;
                for (o, dp) in out.iter_mut().zip([he::pk1_dlambda(&s), he::pk1_dmu(&s)]) {
                    self.add_stress(e, qp, &dp, o);
                }
            }
        }
        Some(out)
    }
}

/// What a problem's quadratic lift needs beside its material and loads: the lift of its linear
/// mesh, the quadrature data of its rest geometry and the tangent's pattern on the dofs its
/// fixed nodes leave free (with the fill-reducing order and symbolic factorisation). A fit
/// solves one problem hundreds of times at other moduli; building these at every solve and
/// every sensitivity was a tenth of a scan diagnosis, so a thread keeps the last few
/// ([`lift_of`]).
struct Lift {
    /// The linear mesh's nodes, elements and fixed flags it was built for.
    nodes: Vec<[f64; 3]>,
    tets: Vec<[usize; 4]>,
    fixed: Vec<bool>,
    q: QuadraticMesh,
    points: Vec<[QuadPoint; 4]>,
    dofs: Dofs,
    scatter: ElementScatter,
}

/// How many lifts a thread keeps, the most recently used: a scan diagnosis alternates between
/// two states' fixed nodes on the dataset's mesh and on the mesh refined once. Each holds its
/// tangent's pattern and scatter (up to 9 MB for a 768-tet lift) until the thread ends or newer
/// lifts push it out.
const KEPT_LIFTS: usize = 4;

thread_local! {
    static LIFTS: RefCell<Vec<Rc<Lift>>> = const { RefCell::new(Vec::new()) };
}

/// The lift of `p`'s mesh with the fixed flags `is_fixed` ([`check_problem`]'s): one kept from a
/// solve of the same nodes, elements and fixed nodes (compared in full, not by a hash), or built
/// and kept.
fn lift_of(p: &StaticProblem<'_>, is_fixed: &[bool]) -> Result<Rc<Lift>, MotionError> {
    let same = |l: &Lift| l.fixed == is_fixed && l.tets == p.mesh.tets && l.nodes == p.mesh.nodes;
    let kept = LIFTS.with_borrow_mut(|kept| {
        let i = kept.iter().position(|l| same(l))?;
        let l = kept.remove(i);
        kept.insert(0, Rc::clone(&l));
        Some(l)
    });
    if let Some(l) = kept {
        return Ok(l);
    }
    let q = QuadraticMesh::from_linear(p.mesh);
    let points = element_points(&RestTet::of_mesh(p.mesh)?);
    let dofs = Dofs::new(&q.lift_flags(is_fixed), &block_tets(&q))?;
    let scatter = ElementScatter::new(&dofs.pattern, q.tets.len());
    let l = Rc::new(Lift {
        nodes: p.mesh.nodes.clone(),
        tets: p.mesh.tets.clone(),
        fixed: is_fixed.to_vec(),
        q,
        points,
        dofs,
        scatter,
    });
    LIFTS.with_borrow_mut(|kept| {
        kept.insert(0, Rc::clone(&l));
        kept.truncate(KEPT_LIFTS);
    });
    Ok(l)
}

/// `p`'s lift and its loading on it, with forces on any node of the quadratic mesh (`extra`)
/// beside `p`'s corner forces.
fn setup(
    p: &StaticProblem<'_>,
    extra: &[(usize, [f64; 3])],
) -> Result<(Rc<Lift>, Loading), MotionError> {
    let is_fixed = check_problem(p)?;
    let lift = lift_of(p, &is_fixed)?;
    let loading = loading(p, &lift, &is_fixed, extra)?;
    Ok((lift, loading))
}

/// A problem's loads on its lift: the full external load, the rest positions and each moving
/// fixed dof's final displacement ([`Prepared`] without the dofs).
struct Loading {
    fext: Vec<f64>,
    rest: Vec<f64>,
    moved: Vec<(usize, f64)>,
}

impl Loading {
    /// Ready to solve on `lift`'s dofs.
    fn on(self, lift: &Lift) -> Prepared<'_> {
        Prepared {
            dofs: Cow::Borrowed(&lift.dofs),
            fext: self.fext,
            rest: self.rest,
            moved: self.moved,
        }
    }
}

/// [`Loading`] of `p` on `lift`.
fn loading(
    p: &StaticProblem<'_>,
    lift: &Lift,
    is_fixed: &[bool],
    extra: &[(usize, [f64; 3])],
) -> Result<Loading, MotionError> {
    let (q, points) = (&lift.q, &lift.points);
    let bary = quadrature_points();
    let mut fext = vec![0.0; 3 * q.nodes.len()];
    for &(n, f) in p.forces.iter().chain(extra) {
        if n >= q.nodes.len() {
            return Err(MotionError::Invalid(format!(
                "a force on node {n} of a quadratic mesh of {} nodes",
                q.nodes.len()
            )));
        }
        for i in 0..3 {
            fext[3 * n + i] += f[i];
        }
    }
    // Consistent gravity ∫ ρ g N_a dV: the rule is exact for the quadratic N_a.
    let n_at: [[f64; 10]; 4] = bary.map(|l| shape_functions(&l));
    for (t, pts) in q.tets.iter().zip(points) {
        for (qp, n) in pts.iter().zip(&n_at) {
            for (a, &node) in t.iter().enumerate() {
                for i in 0..3 {
                    fext[3 * node + i] += p.density * qp.weight * n[a] * p.gravity[i];
                }
            }
        }
    }
    // Each fixed corner's final displacement; an edge node between two fixed corners moves with
    // their mean.
    let mut corner = vec![[0.0; 3]; q.vertex_count];
    for (&n, u) in p.fixed.iter().zip(&p.fixed_displacement) {
        corner[n] = *u;
    }
    let flags = q.lift_flags(is_fixed);
    let moved = (0..q.nodes.len())
        .filter(|&n| flags[n] && !p.fixed_displacement.is_empty())
        .flat_map(|n| {
            let u = if n < q.vertex_count {
                corner[n]
            } else {
                let [a, b] = q.edges[n - q.vertex_count];
                [0, 1, 2].map(|d| 0.5 * (corner[a][d] + corner[b][d]))
            };
            (0..3).map(move |d| (3 * n + d, u[d]))
        })
        .collect();
    Ok(Loading {
        fext,
        rest: q.nodes.iter().flatten().copied().collect(),
        moved,
    })
}

/// Solves `p` on the quadratic lift of its mesh.
pub fn solve_static_quadratic(p: &StaticProblem<'_>) -> Result<QuadraticSolution, MotionError> {
    solve_static_quadratic_loaded(p, &[])
}

/// [`solve_static_quadratic`] with `extra` forces (N) on nodes of the quadratic lift (corner or
/// edge nodes, by their index in [`QuadraticMesh::from_linear`]) beside `p`'s corner forces:
/// a surface traction's consistent load ([`consistent_traction_load`]).
pub fn solve_static_quadratic_loaded(
    p: &StaticProblem<'_>,
    extra: &[(usize, [f64; 3])],
) -> Result<QuadraticSolution, MotionError> {
    let (lift, loading) = setup(p, extra)?;
    let ctx = Ctx {
        p,
        q: &lift.q,
        points: &lift.points,
        scatter: &lift.scatter,
    };
    let solution = loading.on(&lift).solve(&ctx, p)?;
    Ok(QuadraticSolution {
        mesh: lift.q.clone(),
        solution,
    })
}

/// The consistent load on the quadratic lift of `mesh` of the traction that a set of lumped
/// nodal forces on its boundary stands for: `force` (3 per linear node) is read as the traction
/// t_i = f_i / A_i at each boundary node (A_i a third of the area of its boundary triangles, the
/// lumping of the runtime's contact rule), linear over each triangle of `surface`, and
/// integrated against the six quadratic shape functions of the triangle:
///
///   ∫ N_a L_a dA = A/30, ∫ N_a L_b dA = −A/60 (b ≠ a), ∫ N_ab L_a dA = 2A/15, ∫ N_ab L_c dA = A/15
///
/// (∫ L_a^i L_b^j L_c^k dA = 2A i! j! k! / (i + j + k + 2)!). Its total is Σ f_i, and lumped back
/// onto the corners it is `force` again. Loaded on the corners only, a quadratic mesh sees point
/// loads, whose displacement grows without bound as the mesh is refined; this load is the
/// traction itself. Nodal forces off the boundary are kept on their corner as they are.
/// Returns (quadratic node index, N).
pub fn consistent_traction_load(
    mesh: &palpate_fem::mesh::Mesh,
    surface: &[[usize; 3]],
    force: &[f64],
) -> Vec<(usize, [f64; 3])> {
    let q = QuadraticMesh::from_linear(mesh);
    let n = mesh.nodes.len();
    let v = |i: usize| Vector3::from(mesh.nodes[i]);
    let area = |t: &[usize; 3]| 0.5 * (v(t[1]) - v(t[0])).cross(&(v(t[2]) - v(t[0]))).norm();
    let mut lumped = vec![0.0; n];
    for t in surface {
        let a = area(t);
        t.iter().for_each(|&i| lumped[i] += a / 3.0);
    }
    let f = |i: usize| Vector3::new(force[3 * i], force[3 * i + 1], force[3 * i + 2]);
    let traction = |i: usize| {
        if lumped[i] > 0.0 {
            f(i) / lumped[i]
        } else {
            Vector3::zeros()
        }
    };
    let mut out = vec![Vector3::zeros(); q.nodes.len()];
    for (i, o) in out.iter_mut().enumerate().take(n) {
        if lumped[i] == 0.0 {
            *o += f(i);
        }
    }
    for (t, l) in surface.iter().zip(q.lift_triangles(surface)) {
        let a = area(t);
        let tr = t.map(traction);
        for k in 0..3 {
            let (b, c) = ((k + 1) % 3, (k + 2) % 3);
            out[l[k]] += a * (tr[k] / 30.0 - (tr[b] + tr[c]) / 60.0);
            // Edge node k of the lifted triangle joins corners k and k + 1.
            out[l[3 + k]] += a * ((tr[k] + tr[b]) * (2.0 / 15.0) + tr[c] / 15.0);
        }
    }
    out.into_iter()
        .enumerate()
        .filter(|(_, f)| f.iter().any(|c| *c != 0.0))
        .map(|(i, f)| (i, [f.x, f.y, f.z]))
        .collect()
}

/// The sensitivities of an equilibrium found by [`solve_static_quadratic`] to the (uniform)
/// material's λ and μ, per node of the quadratic mesh.
pub fn quadratic_sensitivity(
    p: &StaticProblem<'_>,
    solution: &QuadraticSolution,
) -> Result<StaticSensitivity, MotionError> {
    let (lift, loading) = setup(p, &[])?;
    let ctx = Ctx {
        p,
        q: &lift.q,
        points: &lift.points,
        scatter: &lift.scatter,
    };
    loading
        .on(&lift)
        .sensitivity(&ctx, p, &solution.solution.positions)
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::mesh::Mesh;

    /// One quadratic element on the sample tetrahedron, nothing fixed, deformed by a smooth
    /// non-affine field of about 20 % strain (so that F differs between quadrature points).
    fn one_element() -> (Mesh, Vec<f64>) {
        let (_, corners) = RestTet::sample();
        let mesh = Mesh {
            nodes: corners.map(|c| [c.x, c.y, c.z]).to_vec(),
            tets: vec![[0, 1, 2, 3]],
            ..Default::default()
        };
        let q = QuadraticMesh::from_linear(&mesh);
        let x = q
            .nodes
            .iter()
            .flat_map(|&[a, b, c]| {
                [
                    a + 0.15 * b + 8.0 * a * c,
                    b - 0.1 * c + 6.0 * a * b,
                    c + 0.2 * a - 5.0 * b * b,
                ]
            })
            .collect();
        (mesh, x)
    }

    /// A uniform traction on the top face of a block, lumped onto its corners as the contact
    /// rule lumps a press: its consistent quadratic load is the textbook one of a constant
    /// traction on 6-node triangles, nothing on any corner (each triangle gives its corners 0
    /// and its edge nodes A/3 each), the total unchanged.
    #[test]
    fn a_uniform_traction_loads_the_edge_nodes_and_no_inner_corner() {
        let mesh = palpate_fem::mesh::boxmesh::box_mesh([0.03, 0.02, 0.01], [3, 2, 1]);
        let top = 0.01 - 1e-12;
        let surface: Vec<[usize; 3]> = mesh
            .boundary_triangles()
            .into_iter()
            .filter(|t| t.iter().all(|&i| mesh.nodes[i][2] > top))
            .collect();
        let t = [0.5, -1.0, -30.0];
        let mut lumped = vec![0.0; 3 * mesh.nodes.len()];
        for tri in &surface {
            let p = tri.map(|i| Vector3::from(mesh.nodes[i]));
            let a = 0.5 * (p[1] - p[0]).cross(&(p[2] - p[0])).norm();
            for &i in tri {
                for d in 0..3 {
                    lumped[3 * i + d] += a / 3.0 * t[d];
                }
            }
        }
        let load = consistent_traction_load(&mesh, &surface, &lumped);
        let q = QuadraticMesh::from_linear(&mesh);
        for d in 0..3 {
            let total: f64 = load.iter().map(|(_, f)| f[d]).sum();
            let want = 0.03 * 0.02 * t[d];
            assert!(
                (total - want).abs() < 1e-12 * want.abs().max(1.0),
                "{total} {want}"
            );
        }
        // A constant traction gives every corner of the face 0, inside it and on its rim (to
        // round-off: 30 N/m² on triangles of 10⁻⁴ m²).
        for (i, f) in load.iter().filter(|(i, _)| *i < q.vertex_count) {
            assert!(f.iter().all(|c| c.abs() < 1e-15), "corner {i}: {f:?}");
        }
    }

    fn material() -> HyperParams {
        HyperParams {
            lambda: 2.4e5,
            mu: 1.6e4,
            stiffening: 0.0,
        }
    }

    /// [`material`], and the same with the stiffening term at `stiffening` (Pa).
    fn with_and_without_stiffening(stiffening: f64) -> [HyperParams; 2] {
        [
            material(),
            HyperParams {
                stiffening,
                ..material()
            },
        ]
    }

    /// Forces are minus the energy's gradient and the tangent minus the forces' Jacobian, by
    /// central differences (h = 1e-8 m on a 1 cm element: ~1e-7 relative, asserted 1e-5), with
    /// and without the stiffening term.
    #[test]
    fn element_forces_and_tangent_match_finite_differences() {
        for m in with_and_without_stiffening(5e3) {
            forces_and_tangent_match_finite_differences(m);
        }
    }

    fn forces_and_tangent_match_finite_differences(m: HyperParams) {
        let (mesh, x) = one_element();
        let p = StaticProblem::new(&mesh, m, Vec::new());
        let (lift, loading) = setup(&p, &[]).unwrap();
        let prepared = loading.on(&lift);
        let ctx = Ctx {
            p: &p,
            q: &lift.q,
            points: &lift.points,
            scatter: &lift.scatter,
        };
        let pattern = &prepared.dofs.pattern;
        let mut k = vec![0.0; pattern.nnz()];
        let f = ctx.forces(&x, Some((pattern, &mut k))).unwrap();
        let fmax = f.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let h = 1e-8;
        let mut kcol = vec![0.0; 30];
        for c in 0..30 {
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[c] += h;
            xm[c] -= h;
            let fd_e = (ctx.energy(&xp).unwrap() - ctx.energy(&xm).unwrap()) / (2.0 * h);
            assert!(
                (f[c] + fd_e).abs() < 1e-5 * fmax,
                "force {c}: {} vs {}",
                f[c],
                -fd_e
            );
            let (fp, fm) = (
                ctx.forces(&xp, None).unwrap(),
                ctx.forces(&xm, None).unwrap(),
            );
            // Column c of K (every dof is free, free index = dof).
            let mut unit = vec![0.0; 30];
            unit[c] = 1.0;
            kcol.iter_mut().for_each(|v| *v = 0.0);
            pattern.mul_add(&k, &unit, &mut kcol);
            let kmax = kcol.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for r in 0..30 {
                let fd = -(fp[r] - fm[r]) / (2.0 * h);
                assert!(
                    (kcol[r] - fd).abs() < 1e-5 * kmax,
                    "K[{r}][{c}] {} vs {fd}",
                    kcol[r]
                );
            }
        }
    }

    /// The element matrix summed over its quadrature points and scattered once, each stored
    /// entry it touches once ([`ElementScatter`]), equals the ten 4-node blocks of every point
    /// scattered one by one ([`he::element_tangent`] on each block, at its share), to round-off,
    /// on a mesh of many elements with fixed nodes, with and without the stiffening term.
    #[test]
    fn the_summed_element_tangent_is_the_blocks_of_its_points() {
        for m in with_and_without_stiffening(4e3) {
            summed_tangent_is_the_blocks_of_its_points(m);
        }
    }

    fn summed_tangent_is_the_blocks_of_its_points(m: HyperParams) {
        let mesh = palpate_fem::mesh::boxmesh::box_mesh([0.03, 0.02, 0.01], [3, 2, 1]);
        let fixed: Vec<usize> = (0..mesh.nodes.len())
            .filter(|&n| mesh.nodes[n][0] < 1e-9)
            .collect();
        let p = StaticProblem {
            fixed,
            ..StaticProblem::new(&mesh, m, Vec::new())
        };
        let q = QuadraticMesh::from_linear(&mesh);
        let (lift, loading) = setup(&p, &[]).unwrap();
        let prepared = loading.on(&lift);
        let x: Vec<f64> = q
            .nodes
            .iter()
            .flat_map(|&[a, b, c]| [a + 0.1 * b * b * 40.0, b - 0.05 * a, c + 3.0 * a * a])
            .collect();
        let ctx = Ctx {
            p: &p,
            q: &q,
            points: &lift.points,
            scatter: &lift.scatter,
        };
        let pattern = &prepared.dofs.pattern;
        let mut k = vec![0.0; pattern.nnz()];
        ctx.forces(&x, Some((pattern, &mut k))).unwrap();
        let mut blocks = vec![0.0; pattern.nnz()];
        for (e, pts) in ctx.points.iter().enumerate() {
            for qp in pts {
                let s = FParts::new(ctx.deformation_gradient(e, qp, &x)).unwrap();
                for (b, nodes) in BLOCKS.iter().enumerate() {
                    let block = RestTet {
                        grad: nodes.map(|a| qp.grad[a]),
                        volume: qp.weight,
                    };
                    let mut kb = he::element_tangent(&block, &s, &m);
                    share(&mut kb);
                    pattern.add_element(BLOCKS.len() * e + b, &kb, 1.0, &mut blocks);
                }
            }
        }
        let kmax = blocks.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        assert!(kmax > 0.0);
        for (i, (a, b)) in k.iter().zip(&blocks).enumerate() {
            assert!((a - b).abs() <= 1e-12 * kmax, "entry {i}: {a} vs {b}");
        }
    }

    /// A kept lift serves only its own mesh and fixed nodes: the same topology with other node
    /// positions, or other fixed nodes, solves as it would in a thread that kept nothing, and a
    /// solve repeated from a kept lift is the first one to the bit.
    #[test]
    fn a_kept_lift_serves_only_its_own_mesh_and_fixed_nodes() {
        let a = palpate_fem::mesh::boxmesh::box_mesh([0.04, 0.01, 0.01], [4, 1, 1]);
        let mut b = a.clone();
        b.nodes.iter_mut().for_each(|n| n[2] *= 1.5);
        let left = |m: &Mesh| -> Vec<usize> {
            (0..m.nodes.len())
                .filter(|&n| m.nodes[n][0] < 1e-9)
                .collect()
        };
        let right: Vec<usize> = (0..a.nodes.len())
            .filter(|&n| a.nodes[n][0] > 0.04 - 1e-9)
            .collect();
        let problem = |m: &'static Mesh, fixed: Vec<usize>| StaticProblem {
            gravity: [0.0, 0.0, -9.81],
            density: 1000.0,
            ..StaticProblem::new(m, material(), fixed)
        };
        let (a, b): (&'static Mesh, &'static Mesh) =
            (Box::leak(Box::new(a)), Box::leak(Box::new(b)));
        let solve = |p: &StaticProblem<'_>| solve_static_quadratic(p).unwrap().solution.positions;
        let fresh = std::thread::spawn(move || {
            [
                solve(&problem(b, left(b))),
                solve(&problem(a, right.clone())),
            ]
        })
        .join()
        .unwrap();
        let first = solve(&problem(a, left(a)));
        assert_eq!(solve(&problem(b, left(b))), fresh[0]);
        let right: Vec<usize> = (0..a.nodes.len())
            .filter(|&n| a.nodes[n][0] > 0.04 - 1e-9)
            .collect();
        assert_eq!(solve(&problem(a, right)), fresh[1]);
        assert_eq!(solve(&problem(a, left(a))), first);
        assert_ne!(first, fresh[0]);
    }

    /// The shape functions are a partition of unity with N_a(corner b) = δ_ab, and the blocks
    /// hold every pair of the ten nodes (a pair in one group four times, otherwise once).
    #[test]
    fn shape_functions_and_blocks() {
        for l in quadrature_points() {
            assert!((shape_functions(&l).iter().sum::<f64>() - 1.0).abs() < 1e-14);
        }
        for b in 0..4 {
            let l: [f64; 4] = std::array::from_fn(|a| if a == b { 1.0 } else { 0.0 });
            let n = shape_functions(&l);
            for (k, v) in n.iter().enumerate() {
                assert_eq!(*v, if k == b { 1.0 } else { 0.0 });
            }
        }
        let mut count = [[0; 10]; 10];
        for blk in BLOCKS {
            for a in blk {
                for b in blk {
                    count[a][b] += 1;
                }
            }
        }
        for a in 0..10 {
            for b in 0..10 {
                assert_eq!(
                    count[a][b],
                    if a / 2 == b / 2 { 4 } else { 1 },
                    "({a}, {b})"
                );
            }
        }
    }
}

//! Test support: owned storage for model records, small meshes with their C_e/D_e, and an
//! independent container writer (from the spec in `MODEL-FORMAT.md`, not from the crate).
#![allow(dead_code)]

use palpate_protocol::model::{ModelRecord, ParameterLayout};

pub fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

pub fn u32_bytes(v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

pub fn set_f32(bytes: &mut [u8], i: usize, v: f32) {
    bytes[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
}

pub fn set_u32(bytes: &mut [u8], i: usize, v: u32) {
    bytes[4 * i..4 * i + 4].copy_from_slice(&v.to_le_bytes());
}

/// The models the tests build and corrupt are kept in the crate's owned storage; its `record`
/// only borrows the arrays, so nothing of what is checked (encoder, decoder, validation) is
/// shared with the test data beyond that mapping.
pub use palpate_protocol::model::{OwnedBlend, OwnedModel};

/// The tests' two ways of encoding an [`OwnedModel`].
pub trait Encoded {
    /// Encodes with the crate's encoder into a fresh buffer of exactly `encoded_len` bytes.
    fn encode(&self) -> Vec<u8>;
    /// Encodes WITHOUT validation (postcard payload + independent container), for
    /// corrupt-content tests: the bytes are a well-formed container with a correct CRC.
    fn encode_unchecked(&self) -> Vec<u8>;
}

impl Encoded for OwnedModel {
    fn encode(&self) -> Vec<u8> {
        let r = self.record();
        let mut out = vec![0u8; palpate_protocol::model::encoded_len(&r).unwrap()];
        let n = palpate_protocol::model::encode(&r, &mut out).unwrap();
        assert_eq!(n, out.len());
        out
    }

    fn encode_unchecked(&self) -> Vec<u8> {
        wrap(&payload_of(&self.record()))
    }
}

/// The postcard payload of `record` (the serde derive, no validation).
pub fn payload_of(record: &ModelRecord) -> Vec<u8> {
    let size =
        postcard::serialize_with_flavor(record, postcard::ser_flavors::Size::default()).unwrap();
    let mut buf = vec![0u8; size];
    let n = postcard::to_slice(record, &mut buf).unwrap().len();
    assert_eq!(n, size);
    buf
}

/// CRC-32/ISCSI (reflected Castagnoli, init and xorout 0xFFFFFFFF), as the spec says.
pub fn crc32c(bytes: &[u8]) -> u32 {
    crc::Crc::<u32>::new(&crc::CRC_32_ISCSI).checksum(bytes)
}

/// A model container around `payload`, written from the spec (not from the crate).
pub fn wrap(payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(payload.len() + 16);
    out.extend_from_slice(b"PALP");
    out.extend_from_slice(&1u16.to_le_bytes());
    out.extend_from_slice(&1u16.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    let crc = crc32c(&out);
    out.extend_from_slice(&crc.to_le_bytes());
    out
}

/// Recomputes the trailing CRC of a container in place (after a deliberate edit).
pub fn reseal(bytes: &mut [u8]) {
    let end = bytes.len() - 4;
    let crc = crc32c(&bytes[..end]);
    bytes[end..].copy_from_slice(&crc.to_le_bytes());
}

// ---------------------------------------------------------------------------------------------
// Meshes and element matrices (an f64 re-implementation for test data only; the runtime's
// `element.rs` is the one used for simulation).

pub type P3 = [f64; 3];

fn sub(a: P3, b: P3) -> P3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn det3(a: P3, b: P3, c: P3) -> f64 {
    a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
        + a[2] * (b[0] * c[1] - b[1] * c[0])
}

/// Packed C_e = V Bᵀ F B and D_e = V Bᵀ G B (seed 000 eqs. 3.33–3.34, 3.63) of one tetrahedron.
pub fn element_cd(x: [P3; 4]) -> ([f32; 78], [f32; 78]) {
    let (a, b, c) = (sub(x[1], x[0]), sub(x[2], x[0]), sub(x[3], x[0]));
    let det = det3(a, b, c);
    let v = det / 6.0;
    // Rows of D_m⁻¹ (D_m = [a b c] as columns) are the gradients of φ_1..φ_3: inv = adj / det.
    let cross = |p: P3, q: P3| {
        [
            p[1] * q[2] - p[2] * q[1],
            p[2] * q[0] - p[0] * q[2],
            p[0] * q[1] - p[1] * q[0],
        ]
    };
    let g1 = cross(b, c).map(|e| e / det);
    let g2 = cross(c, a).map(|e| e / det);
    let g3 = cross(a, b).map(|e| e / det);
    let g0 = [
        -(g1[0] + g2[0] + g3[0]),
        -(g1[1] + g2[1] + g3[1]),
        -(g1[2] + g2[2] + g3[2]),
    ];
    let grads = [g0, g1, g2, g3];
    let mut bm = [[0.0f64; 12]; 6];
    for (n, g) in grads.iter().enumerate() {
        let k = 3 * n;
        bm[0][k] = g[0];
        bm[1][k + 1] = g[1];
        bm[2][k + 2] = g[2];
        bm[3][k] = g[1];
        bm[3][k + 1] = g[0];
        bm[4][k + 1] = g[2];
        bm[4][k + 2] = g[1];
        bm[5][k] = g[2];
        bm[5][k + 2] = g[0];
    }
    let f_diag = [1.0, 1.0, 1.0, 0.5, 0.5, 0.5];
    let gm = |r: usize, s: usize| -> f64 {
        if r < 3 && s < 3 {
            if r == s {
                -1.0
            } else {
                1.0
            }
        } else if r == s {
            -1.0
        } else {
            0.0
        }
    };
    let mut cp = [0f32; 78];
    let mut dp = [0f32; 78];
    let mut k = 0;
    for i in 0..12 {
        for j in i..12 {
            let mut cij = 0.0;
            let mut dij = 0.0;
            for r in 0..6 {
                cij += bm[r][i] * f_diag[r] * bm[r][j];
                for s in 0..6 {
                    dij += bm[r][i] * gm(r, s) * bm[s][j];
                }
            }
            cp[k] = (v * cij) as f32;
            dp[k] = (v * dij) as f32;
            k += 1;
        }
    }
    (cp, dp)
}

/// A mesh: rest positions, positively oriented tets, outward boundary triangles.
pub struct Mesh {
    pub nodes: Vec<P3>,
    pub tets: Vec<[u32; 4]>,
    pub triangles: Vec<[u32; 3]>,
}

/// An nx × ny × nz grid of cubes of edge `h`, each split into the 6 Kuhn tetrahedra (a conforming
/// triangulation), with its boundary triangles wound outward.
pub fn grid_mesh(nx: usize, ny: usize, nz: usize, h: f64) -> Mesh {
    let id = |i: usize, j: usize, k: usize| (i + (nx + 1) * (j + (ny + 1) * k)) as u32;
    let mut nodes = Vec::new();
    for k in 0..=nz {
        for j in 0..=ny {
            for i in 0..=nx {
                nodes.push([i as f64 * h, j as f64 * h, k as f64 * h]);
            }
        }
    }
    let perms = [
        [0, 1, 2],
        [0, 2, 1],
        [1, 0, 2],
        [1, 2, 0],
        [2, 0, 1],
        [2, 1, 0],
    ];
    let mut tets = Vec::new();
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                for p in perms {
                    let mut c = [i, j, k];
                    let mut t = [id(c[0], c[1], c[2]); 4];
                    for (s, axis) in p.iter().enumerate() {
                        c[*axis] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    let x = t.map(|n| nodes[n as usize]);
                    if det3(sub(x[1], x[0]), sub(x[2], x[0]), sub(x[3], x[0])) < 0.0 {
                        t.swap(2, 3);
                    }
                    tets.push(t);
                }
            }
        }
    }
    let triangles = boundary(&nodes, &tets);
    Mesh {
        nodes,
        tets,
        triangles,
    }
}

/// Faces used by exactly one tet, wound so their normal points away from the tet's fourth node.
fn boundary(nodes: &[P3], tets: &[[u32; 4]]) -> Vec<[u32; 3]> {
    use std::collections::HashMap;
    let mut faces: HashMap<[u32; 3], (usize, [u32; 3], u32)> = HashMap::new();
    for t in tets {
        for skip in 0..4 {
            let f: Vec<u32> = (0..4).filter(|&i| i != skip).map(|i| t[i]).collect();
            let face = [f[0], f[1], f[2]];
            let mut key = face;
            key.sort();
            faces
                .entry(key)
                .and_modify(|e| e.0 += 1)
                .or_insert((1, face, t[skip]));
        }
    }
    let mut out: Vec<[u32; 3]> = faces
        .into_values()
        .filter(|e| e.0 == 1)
        .map(|(_, mut f, opposite)| {
            let x = f.map(|n| nodes[n as usize]);
            let o = nodes[opposite as usize];
            // Normal (x1−x0)×(x2−x0) must point away from the opposite node.
            if det3(sub(x[1], x[0]), sub(x[2], x[0]), sub(o, x[0])) > 0.0 {
                f.swap(1, 2);
            }
            f
        })
        .collect();
    out.sort();
    out
}

/// Which parameter layout and blend a test model uses.
#[derive(Clone, Copy, Debug)]
pub enum BlendKind {
    None,
    Deformation,
    Strain,
}

/// A valid model on `mesh` with the bottom (z = 0) nodes fixed, `sets` parameter sets (forced to
/// 1 for BlendKind::None) and the given layout. Values vary per set/element so that a field
/// mix-up cannot round-trip by accident.
pub fn model_on(mesh: &Mesh, layout: ParameterLayout, blend: BlendKind, sets: u32) -> OwnedModel {
    let n = mesh.nodes.len();
    let t = mesh.tets.len();
    let sets = if matches!(blend, BlendKind::None) {
        1
    } else {
        sets
    };
    let rest: Vec<f32> = mesh
        .nodes
        .iter()
        .flat_map(|p| p.map(|v| v as f32))
        .collect();
    let tags: Vec<u32> = (0..n as u32).map(|i| 1000 + 7 * i).collect();
    let tets: Vec<u32> = mesh.tets.iter().flatten().copied().collect();
    let fixed: Vec<u32> = (0..n as u32)
        .filter(|&i| mesh.nodes[i as usize][2] == 0.0)
        .collect();
    let tris: Vec<u32> = mesh.triangles.iter().flatten().copied().collect();
    let mut c = Vec::new();
    let mut d = Vec::new();
    for tet in &mesh.tets {
        // Round-trip the positions through f32 first, as a fitter would.
        let x = tet.map(|i| mesh.nodes[i as usize].map(|v| v as f32 as f64));
        let (cp, dp) = element_cd(x);
        c.extend_from_slice(&cp);
        d.extend_from_slice(&dp);
    }
    let per = match layout {
        ParameterLayout::Global => 1,
        ParameterLayout::PerElement => t,
    };
    let mut lambda = Vec::new();
    let mut alpha = Vec::new();
    for s in 0..sets as usize {
        for e in 0..per {
            let l = 20_000.0 + 1_000.0 * s as f32 + 10.0 * e as f32;
            lambda.push(l);
            alpha.push(l * (0.25 + 0.01 * (e % 5) as f32));
        }
    }
    let blend = match blend {
        BlendKind::None => OwnedBlend::None,
        BlendKind::Deformation => {
            let centres: Vec<f32> = (0..sets as usize)
                .flat_map(|s| {
                    rest.iter()
                        .enumerate()
                        .map(move |(i, v)| v + 1e-3 * (s * 3 + i % 3) as f32)
                })
                .collect();
            OwnedBlend::Deformation {
                centres: f32_bytes(&centres),
                weights_lambda: f32_bytes(&(0..sets).map(|s| 1.5 - s as f32).collect::<Vec<_>>()),
                weights_alpha: f32_bytes(&(0..sets).map(|s| -0.25 * s as f32).collect::<Vec<_>>()),
            }
        }
        BlendKind::Strain => {
            let k = 2.min(t as u32);
            let index: Vec<u32> = (0..t as u32)
                .flat_map(|e| (0..k).map(move |j| (e + j) % t as u32))
                .collect();
            let weight: Vec<f32> = (0..t * k as usize)
                .map(|i| if i % k as usize == 0 { 1.0 } else { 0.5 })
                .collect();
            let centres: Vec<f32> = (0..sets as usize * t * 6)
                .map(|i| 1e-3 * (i % 11) as f32 - 5e-3)
                .collect();
            let wl: Vec<f32> = (0..t * sets as usize)
                .map(|i| 3.0 - 0.5 * i as f32)
                .collect();
            let wa: Vec<f32> = (0..t * sets as usize).map(|i| 0.125 * i as f32).collect();
            OwnedBlend::Strain {
                decay: 400.0,
                neighbours: k,
                neighbour_index: u32_bytes(&index),
                neighbour_weight: f32_bytes(&weight),
                centres: f32_bytes(&centres),
                weights_lambda: f32_bytes(&wl),
                weights_alpha: f32_bytes(&wa),
            }
        }
    };
    OwnedModel {
        tool: "palpate-test 0.1.0 fit --material sponge".into(),
        created: "2026-11-22T04:00:00Z".into(),
        source: "protocol/tests (synthetic)".into(),
        notes: "grid mesh, Kuhn tets; ünïcödé ok".into(),
        node_count: n as u32,
        element_count: t as u32,
        rest_positions: f32_bytes(&rest),
        node_tags: u32_bytes(&tags),
        tets: u32_bytes(&tets),
        fixed_nodes: u32_bytes(&fixed),
        surface_triangles: u32_bytes(&tris),
        c_packed: f32_bytes(&c),
        d_packed: f32_bytes(&d),
        layout,
        count: sets,
        lambda: f32_bytes(&lambda),
        alpha: f32_bytes(&alpha),
        blend,
    }
}

/// The tiny model of `MODEL-FORMAT.md`: the unit corner tetrahedron, bottom face fixed,
/// one global (λ, α) = (20 kPa, 6 kPa) (E ≈ 10.4 kPa, ν = 0.3), no blending.
pub fn tiny_model() -> OwnedModel {
    let x: [P3; 4] = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
    ];
    let (c, d) = element_cd(x);
    let rest: Vec<f32> = x.iter().flat_map(|p| p.map(|v| v as f32)).collect();
    OwnedModel {
        tool: "palpate".into(),
        created: "2026-11-22".into(),
        source: "unit tet".into(),
        notes: String::new(),
        node_count: 4,
        element_count: 1,
        rest_positions: f32_bytes(&rest),
        node_tags: u32_bytes(&[1, 2, 3, 4]),
        tets: u32_bytes(&[0, 1, 2, 3]),
        fixed_nodes: u32_bytes(&[0, 1, 2]),
        // The four faces wound outward.
        surface_triangles: u32_bytes(&[0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]),
        c_packed: f32_bytes(&c),
        d_packed: f32_bytes(&d),
        layout: ParameterLayout::Global,
        count: 1,
        lambda: f32_bytes(&[20_000.0]),
        alpha: f32_bytes(&[6_000.0]),
        blend: OwnedBlend::None,
    }
}

//! Every file reader against mutated inputs: valid example files with bytes flipped, lines
//! dropped, duplicated or truncated, and numbers replaced by extreme values (1e308, −1e308, NaN,
//! inf, 18446744073709551615, −0, 1e-320). Each reader must answer Ok or a located error — never
//! panic, never abort, never try to allocate without bound (the allocator below refuses any single
//! allocation over 1 GiB, which aborts the test binary instead of swapping the machine).
//!
//! Bounded for CI: a fixed number of cases per reader (`PROPTEST_CASES` raises it).

use proptest::prelude::*;
use std::alloc::{GlobalAlloc, Layout, System};
use std::path::{Path, PathBuf};

struct Capped;

const CAP: usize = 1 << 30;

#[allow(unsafe_code)]
unsafe impl GlobalAlloc for Capped {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > CAP {
            return std::ptr::null_mut();
        }
        // SAFETY: forwards to the system allocator with the caller's layout.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: ptr was allocated by System.alloc with this layout.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > CAP {
            return std::ptr::null_mut();
        }
        // SAFETY: forwards to the system allocator.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Capped = Capped;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

const EXTREMES: [&str; 9] = [
    "1e308",
    "-1e308",
    "NaN",
    "inf",
    "18446744073709551615",
    "-0",
    "1e-320",
    "2000000000000000000",
    "",
];

/// One structured mutation of a text file.
#[derive(Debug, Clone)]
enum Mutation {
    /// Replace the `k`-th number-like field by an extreme value.
    Number(usize, usize),
    /// Drop line `k`.
    DropLine(usize),
    /// Duplicate line `k`.
    DupLine(usize),
    /// Cut the file at a fraction of its length.
    Truncate(f64),
    /// XOR one byte.
    Flip(usize, u8),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        (any::<usize>(), 0..EXTREMES.len()).prop_map(|(k, e)| Mutation::Number(k, e)),
        any::<usize>().prop_map(Mutation::DropLine),
        any::<usize>().prop_map(Mutation::DupLine),
        (0.0f64..1.0).prop_map(Mutation::Truncate),
        (any::<usize>(), 1u8..=255).prop_map(|(k, b)| Mutation::Flip(k, b)),
    ]
}

fn apply(text: &[u8], m: &Mutation) -> Vec<u8> {
    match *m {
        Mutation::Number(k, e) => {
            let s = String::from_utf8_lossy(text);
            let fields: Vec<(usize, usize)> = s
                .char_indices()
                .filter(|(i, c)| {
                    c.is_ascii_digit()
                        && (*i == 0
                            || matches!(s.as_bytes()[i - 1], b',' | b' ' | b'=' | b'\n' | b'['))
                })
                .map(|(i, _)| {
                    let end = s[i..]
                        .find(|c: char| {
                            !(c.is_ascii_alphanumeric() || c == '.' || c == '-' || c == '+')
                        })
                        .map_or(s.len(), |j| i + j);
                    (i, end)
                })
                .collect();
            if fields.is_empty() {
                return text.to_vec();
            }
            let (a, b) = fields[k % fields.len()];
            let mut out = s[..a].to_string();
            out.push_str(EXTREMES[e]);
            out.push_str(&s[b..]);
            out.into_bytes()
        }
        Mutation::DropLine(k) | Mutation::DupLine(k) => {
            let s = String::from_utf8_lossy(text);
            let mut lines: Vec<&str> = s.lines().collect();
            if lines.is_empty() {
                return text.to_vec();
            }
            let k = k % lines.len();
            if matches!(m, Mutation::DropLine(_)) {
                lines.remove(k);
            } else {
                lines.insert(k, lines[k]);
            }
            (lines.join("\n") + "\n").into_bytes()
        }
        Mutation::Truncate(f) => text[..(f * text.len() as f64) as usize].to_vec(),
        Mutation::Flip(k, b) => {
            let mut v = text.to_vec();
            if !v.is_empty() {
                let k = k % v.len();
                v[k] ^= b;
            }
            v
        }
    }
}

/// Copies `src` (a folder) to a temporary folder with `file` mutated; returns the folder.
fn mutated_copy(src: &Path, file: &str, muts: &[Mutation]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        if e.path().is_file() {
            std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
        }
    }
    let mut text = std::fs::read(src.join(file)).unwrap();
    for m in muts {
        text = apply(&text, m);
    }
    std::fs::write(dir.path().join(file), text).unwrap();
    dir
}

/// The error and its sources, as one text.
fn chain(e: &dyn std::error::Error) -> String {
    let mut s = e.to_string();
    let mut next = e.source();
    while let Some(c) = next {
        s.push_str(": ");
        s.push_str(&c.to_string());
        next = c.source();
    }
    s
}

/// A located error names the file it found the fault in: one of the input's files (a fault in
/// one file may surface in another that refers to it, e.g. a moved mesh node under a marker) or
/// the input's own path.
fn assert_located(r: Result<(), String>, files: &[&str], path: &Path) {
    if let Err(e) = r {
        let shown = path.display().to_string();
        assert!(
            files.iter().any(|f| e.contains(f)) || e.contains(&shown),
            "an error that names no file of {files:?} nor {shown}: {e}"
        );
    }
}

const MOTION_FILES: [&str; 5] = [
    "dataset.toml",
    "markers.csv",
    "trajectories.csv",
    "clamps.csv",
    "mesh.msh",
];
const STATIC_FILES: [&str; 5] = [
    "markers.csv",
    "measurements.csv",
    "contacts.csv",
    "dataset.toml",
    "mesh.msh",
];

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]

    /// Motion datasets (dataset.toml, markers, trajectories, clamps and the mesh).
    #[test]
    fn motion_dataset_reader_survives_mutations(
        file in prop::sample::select(vec!["dataset.toml", "markers.csv", "trajectories.csv", "clamps.csv", "mesh.msh"]),
        muts in prop::collection::vec(mutation(), 1..4),
    ) {
        let dir = mutated_copy(&repo().join("models/motion-example"), file, &muts);
        let r = palpate_motion::dataset::load(dir.path()).map(|_| ()).map_err(|e| chain(&e));
        assert_located(r, &MOTION_FILES, dir.path());
    }

    /// Static datasets (with the small cube mesh copied beside them so each case is quick).
    #[test]
    fn static_dataset_reader_survives_mutations(
        file in prop::sample::select(vec!["dataset.toml", "markers.csv", "measurements.csv", "contacts.csv", "mesh.msh"]),
        muts in prop::collection::vec(mutation(), 1..4),
    ) {
        let src = tempfile::tempdir().unwrap();
        for f in STATIC_FILES {
            std::fs::copy(repo().join("models/sponge-specimen").join(f), src.path().join(f)).unwrap();
        }
        let dir = mutated_copy(src.path(), file, &muts);
        let r = palpate_fem::dataset::StaticDataset::read(dir.path())
            .map(|_| ())
            .map_err(|e| chain(&e));
        assert_located(r, &STATIC_FILES, dir.path());
    }

    /// Gmsh 4.1 ASCII meshes.
    #[test]
    fn gmsh_reader_survives_mutations(muts in prop::collection::vec(mutation(), 1..4)) {
        let src = repo().join("fitter/fem/src/mesh/gmsh/testdata");
        let dir = mutated_copy(&src, "cube-ascii.msh", &muts);
        let r = palpate_fem::mesh::gmsh::read_msh(dir.path().join("cube-ascii.msh"))
            .map(|_| ())
            .map_err(|e| chain(&e));
        assert_located(r, &["cube-ascii.msh"], dir.path());
    }

    /// Measured curves (the silicone tension test format).
    #[test]
    fn curve_reader_survives_mutations(muts in prop::collection::vec(mutation(), 1..4)) {
        let mut s = String::from("time_s,true_strain,true_stress_MPa,engineering_strain,engineering_stress_MPa\n");
        for k in 1..60 {
            let e = 0.02 * k as f64;
            s.push_str(&format!("{},{},{},{},{}\n", 0.1 * k as f64, e, 0.1 * e, e, 0.1 * e));
        }
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("c.csv"), apply(s.as_bytes(), &muts[0])).unwrap();
        for m in &muts[1..] {
            let t = std::fs::read(dir.path().join("c.csv")).unwrap();
            std::fs::write(dir.path().join("c.csv"), apply(&t, m)).unwrap();
        }
        let r = palpate_diagnose::curve::read::read_path(dir.path(), false, false)
            .map(|_| ())
            .map_err(|e| chain(&e));
        assert_located(r, &["c.csv"], dir.path());
    }
}

/// Step counts that would size buffers of many gigabytes (the whole u64 range, 2·10¹⁸, 4·10⁹
/// steps) are refused with the file and field before anything is allocated for them: the
/// allocator of this binary refuses any single allocation over 1 GiB, which aborts the test.
#[test]
fn huge_step_counts_are_refused_under_a_capped_allocator() {
    let src = repo().join("models/motion-example");
    let dt = "dt = 0.005555555555555556";
    for steps in ["18446744073709551615", "2000000000000000000", "4000000000"] {
        let dir = tempfile::tempdir().unwrap();
        for e in std::fs::read_dir(&src).unwrap() {
            let e = e.unwrap();
            if e.path().is_file() {
                std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
            }
        }
        let toml = std::fs::read_to_string(src.join("dataset.toml")).unwrap();
        assert!(toml.contains(dt), "the example's dt changed");
        let edited = toml.replacen(dt, &format!("{dt}\nsteps = {steps}"), 1);
        std::fs::write(dir.path().join("dataset.toml"), edited).unwrap();
        let e = match palpate_motion::dataset::load(dir.path()) {
            Ok(_) => panic!("steps = {steps} accepted"),
            Err(e) => chain(&e),
        };
        assert!(
            e.contains("dataset.toml") && e.contains("steps"),
            "steps = {steps}: {e}"
        );
    }
}

/// The unmutated inputs read: the mutations above start from files that reach every stage of
/// their readers, not from files rejected at the first line.
#[test]
fn unmutated_inputs_read() {
    palpate_motion::dataset::load(&repo().join("models/motion-example")).unwrap();
    palpate_fem::dataset::StaticDataset::read(repo().join("models/sponge-specimen")).unwrap();
    palpate_fem::mesh::gmsh::read_msh(
        repo().join("fitter/fem/src/mesh/gmsh/testdata/cube-ascii.msh"),
    )
    .unwrap();
}

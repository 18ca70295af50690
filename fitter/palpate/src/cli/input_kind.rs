//! What kind of input a path is — static or motion dataset, `.palp` model, `fit.json`, C3D
//! capture, STL or Gmsh mesh — recognised from its content before any reader sees it, so a
//! command given the wrong kind says what the input is and which command takes it, instead of a
//! reader's complaint about a field it did not expect.

use std::fmt;
use std::io::Read as _;
use std::path::Path;

/// The kinds of input the commands take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A static contact dataset folder (`dataset.toml` without `dt`).
    StaticDataset,
    /// A motion dataset folder (`dataset.toml` with `dt`).
    MotionDataset,
    /// A runtime model (`.palp`, magic `PALP`).
    Palp,
    /// A fitted motion model (`fit.json` of `fit-motion` or `diagnose`).
    FitJson,
    /// A C3D motion capture.
    C3d,
    /// An STL surface mesh.
    Stl,
    /// A Gmsh mesh (`.msh`).
    Gmsh,
}

impl Kind {
    /// The commands that take this kind, as advice.
    fn commands(self) -> &'static str {
        match self {
            Kind::StaticDataset => "`palpate fit`, `palpate diagnose` or `palpate info`",
            Kind::MotionDataset => {
                "`palpate fit-motion`, `palpate validate`, `palpate diagnose` or \
                 `palpate info`"
            }
            Kind::Palp => "`palpate simulate --model`, `palpate haptic --model` or `palpate info`",
            Kind::FitJson => {
                "`palpate validate --model`, `palpate export --model`, `palpate simulate \
                 --model`, `palpate haptic --model` or `palpate info`"
            }
            Kind::C3d => "`palpate import c3d` or `palpate info`",
            Kind::Stl => {
                "`python3 models/mesh_stl.py` first (palpate reads tetrahedral Gmsh meshes, not \
                 surfaces)"
            }
            Kind::Gmsh => {
                "`palpate import c3d --mesh`, `palpate export --mesh`, a dataset's `mesh` key, or \
                 `palpate info`"
            }
        }
    }
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Kind::StaticDataset => "a static contact dataset",
            Kind::MotionDataset => "a motion dataset",
            Kind::Palp => "a palpate runtime model (.palp)",
            Kind::FitJson => "a fitted motion model (fit.json)",
            Kind::C3d => "a C3D motion capture",
            Kind::Stl => "an STL surface mesh",
            Kind::Gmsh => "a Gmsh mesh",
        })
    }
}

/// Recognises `path` from its content; `None` if it does not exist, cannot be read or is none
/// of the kinds (the reader of the expected kind then says what is wrong with it).
pub fn recognise(path: &Path) -> Option<Kind> {
    if path.is_dir() {
        let text = std::fs::read_to_string(path.join("dataset.toml")).ok()?;
        // The motion format's one required key that the static one lacks.
        let table = text.parse::<toml::Table>().ok()?;
        return Some(if table.contains_key("dt") {
            Kind::MotionDataset
        } else {
            Kind::StaticDataset
        });
    }
    let mut head = Vec::with_capacity(4096);
    std::fs::File::open(path)
        .ok()?
        .take(4096)
        .read_to_end(&mut head)
        .ok()?;
    let len = std::fs::metadata(path).ok()?.len();
    let text = String::from_utf8_lossy(&head);
    let trimmed = text.trim_start_matches('\u{feff}').trim_start();
    if head.starts_with(b"PALP") {
        Some(Kind::Palp)
    } else if trimmed.starts_with("$MeshFormat") {
        Some(Kind::Gmsh)
    } else if trimmed.starts_with('{') {
        // fit.json names its format, or carries the fitted moduli.
        let fitted = ["palpate-motion-fit", "shear_modulus_pa", "\"mu\""]
            .iter()
            .any(|k| trimmed.contains(k));
        fitted.then_some(Kind::FitJson)
    } else if trimmed.starts_with("solid") || is_binary_stl(&head, len) {
        Some(Kind::Stl)
    } else if len >= 512 && head.get(1) == Some(&0x50) {
        Some(Kind::C3d)
    } else {
        None
    }
}

/// A binary STL: an 80-byte header, a triangle count, 50 bytes per triangle.
fn is_binary_stl(head: &[u8], len: u64) -> bool {
    head.len() >= 84 && {
        let n = u32::from_le_bytes([head[80], head[81], head[82], head[83]]);
        len == 84 + 50 * u64::from(n)
    }
}

/// Refuses `path` if it is recognisably another kind than one of `want`, naming what it is and
/// which command takes it. `command` is the command (and flag) being run, e.g. `fit` or
/// `simulate --model`.
pub fn expect_one_of(path: &Path, want: &[Kind], command: &str) -> anyhow::Result<()> {
    match recognise(path) {
        Some(k) if !want.contains(&k) => anyhow::bail!(
            "{} is {k}, but `palpate {command}` takes {}; {k} goes to {}",
            path.display(),
            want.iter()
                .map(|w| w.to_string())
                .collect::<Vec<_>>()
                .join(" or "),
            k.commands()
        ),
        _ => Ok(()),
    }
}

/// [`expect_one_of`] with one kind.
pub fn expect(path: &Path, want: Kind, command: &str) -> anyhow::Result<()> {
    expect_one_of(path, &[want], command)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn repo(p: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(p)
    }

    #[test]
    fn the_shipped_inputs_are_recognised() {
        for (p, k) in [
            ("models/sponge-specimen", Kind::StaticDataset),
            ("models/motion-example", Kind::MotionDataset),
            ("models/silicone-beam/fit.json", Kind::FitJson),
            ("models/silicone-beam/beam_gravity_V2_a.c3d", Kind::C3d),
            ("models/silicone-beam/beam.stl", Kind::Stl),
            ("models/silicone-beam/beam.msh", Kind::Gmsh),
        ] {
            assert_eq!(recognise(&repo(p)), Some(k), "{p}");
        }
        assert_eq!(recognise(&repo("models/nothere")), None);
    }

    #[test]
    fn the_wrong_kind_names_what_it_is_and_where_it_goes() {
        let e = expect(&repo("models/motion-example"), Kind::StaticDataset, "fit")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("is a motion dataset") && e.contains("`palpate fit-motion`"),
            "{e}"
        );
        assert!(expect(&repo("models/sponge-specimen"), Kind::StaticDataset, "fit").is_ok());
    }
}

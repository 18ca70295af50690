//! The motion dataset reader on the bundled example and on broken copies of it.

use crate::support::{copy_example, example};
use palpate_motion::dataset::load;
use std::path::Path;

#[test]
fn example_dataset_loads_with_all_observations() {
    let ds = load(&example()).unwrap();
    assert_eq!(ds.model.tets.len(), 24);
    assert_eq!(ds.model.steps, 45);
    assert_eq!(ds.model.markers.len(), 9);
    assert!(ds
        .obs
        .markers
        .iter()
        .all(|row| row.iter().all(|m| m.is_some())));
    // The clamp pose at t = 0.1 s is the two-sinusoid motion (written with 9 decimals).
    let p = ds.model.clamps[0].poses[18].t;
    let t: f64 = 18.0 / 180.0;
    let want = 0.015 * (1.0 - (6.0 * std::f64::consts::PI * t).cos());
    assert!((p[0] - want).abs() < 1e-9);
}

fn broken(change: impl Fn(&Path)) -> String {
    let dir = tempfile::tempdir().unwrap();
    copy_example(dir.path());
    change(dir.path());
    load(dir.path()).unwrap_err().to_string()
}

/// Rewrites `file` in the folder `d` by `f`.
fn edit(d: &Path, file: &str, f: impl FnOnce(String) -> String) {
    let t = std::fs::read_to_string(d.join(file)).unwrap();
    std::fs::write(d.join(file), f(t)).unwrap();
}

#[test]
fn errors_name_file_line_and_field() {
    let e = broken(|d| {
        edit(d, "trajectories.csv", |t| {
            let mut lines: Vec<String> = t.lines().map(String::from).collect();
            lines[3] = lines[3].replacen(",m", ",nosuch", 1);
            lines.join("\n")
        })
    });
    assert!(
        e.contains("trajectories.csv:4") && e.contains("marker") && e.contains("nosuch"),
        "{e}"
    );
    let e = broken(|d| {
        edit(d, "clamps.csv", |t| {
            t.replacen("0.005556,front,", "0.005556,front,abc", 1)
        })
    });
    assert!(e.contains("clamps.csv:3") && e.contains("field ux"), "{e}");
    let e = broken(|d| {
        edit(d, "trajectories.csv", |t| {
            t.replacen("0.005556,", "0.0071,", 1)
        })
    });
    assert!(e.contains("not on the step grid"), "{e}");
    let e = broken(|d| {
        edit(d, "dataset.toml", |t| {
            t.replace("clamps = [\"front\"]", "clamps = [\"base\"]")
        })
    });
    assert!(e.contains("dataset.toml") && e.contains("base"), "{e}");
}

/// Appends `row` to `file` in a copy of the example and returns the loader's error.
fn with_row(file: &'static str, row: &'static str) -> String {
    broken(move |d| edit(d, file, |t| t + row))
}

/// Replaces `from` by `to` in the example's dataset.toml and returns the loader's error.
fn with_toml(from: &'static str, to: &'static str) -> String {
    broken(move |d| {
        edit(d, "dataset.toml", |t| {
            assert!(t.contains(from));
            t.replacen(from, to, 1)
        })
    })
}

/// Step counts are bounded before anything is allocated: times and `steps` that once overflowed a
/// capacity or asked for 24 GB are refused with the line and field. That nothing is allocated
/// for them first is checked under a capped allocator in `readers_fuzz.rs`
/// (`huge_step_counts_are_refused_under_a_capped_allocator`), not by a clock here.
#[test]
fn step_counts_are_bounded_before_allocation() {
    for t in ["1e20", "1e12", "5555.0"] {
        let row: &'static str = Box::leak(format!("{t},m0,0,0.0267,0.01\n").into_boxed_str());
        let e = with_row("trajectories.csv", row);
        assert!(
            e.contains("trajectories.csv:") && e.contains("field t") && e.contains("at most"),
            "t = {t}: {e}"
        );
    }
    for steps in ["18446744073709551615", "2000000000000000000", "4000000000"] {
        let to: &'static str =
            Box::leak(format!("dt = 0.005555555555555556\nsteps = {steps}").into_boxed_str());
        let e = with_toml("dt = 0.005555555555555556", to);
        assert!(
            e.contains("dataset.toml") && e.contains("steps"),
            "steps = {steps}: {e}"
        );
    }
    // Tiny dt: the existing rows now sit on huge step numbers.
    let e = with_toml("dt = 0.005555555555555556", "dt = 1e-9");
    assert!(e.contains("field t") || e.contains("steps"), "{e}");
    // Steps far past the data: no information, refused with what would be accepted.
    let e = with_toml(
        "dt = 0.005555555555555556",
        "dt = 0.005555555555555556\nsteps = 1000",
    );
    assert!(
        e.contains("last observation is step 45") && e.contains("≤ 90"),
        "{e}"
    );
    let e = with_toml("dt = 0.005555555555555556", "dt = inf");
    assert!(e.contains("field dt"), "{e}");
}

/// A trajectory row given twice is an error naming both lines, not silently overwritten.
#[test]
fn duplicate_rows_are_refused() {
    let e = with_row(
        "trajectories.csv",
        "0.005556,m0,0.0001344,0.0265321,0.0098414\n",
    );
    assert!(
        e.contains("given twice") && e.contains("first at line 2") && e.contains("m0"),
        "{e}"
    );
}

/// A marker metres outside a centimetre bar (wrong units or frame) is refused with its name,
/// its distance and what is allowed.
#[test]
fn markers_far_outside_the_body_are_refused() {
    let e = with_row("markers.csv", "far,5.0,0.02,0.01\n");
    assert!(
        e.contains("markers.csv:") && e.contains("\"far\"") && e.contains("outside the mesh"),
        "{e}"
    );
}

/// A trajectory in millimetres beside rest places in metres (the marker 28 m from where it
/// rests on a 8 cm bar) is refused naming the row, the marker and the units, instead of being
/// fitted as motion.
#[test]
fn trajectories_in_other_units_are_refused() {
    let e = broken(|d| {
        edit(d, "trajectories.csv", |t| {
            let mut out = String::new();
            for (i, line) in t.lines().enumerate() {
                let f: Vec<&str> = line.split(',').collect();
                if i == 0 {
                    out.push_str(line);
                } else {
                    let mm: Vec<String> = f[2..]
                        .iter()
                        .map(|v| format!("{}", v.parse::<f64>().unwrap() * 1000.0))
                        .collect();
                    out.push_str(&format!("{},{},{}", f[0], f[1], mm.join(",")));
                }
                out.push('\n');
            }
            out
        })
    });
    assert!(
        e.contains("trajectories.csv:2:")
            && e.contains("\"m0\"")
            && e.contains("from its rest place")
            && e.contains("units"),
        "{e}"
    );
}

/// A missing or misspelt key of dataset.toml is named on its line, in one sentence (was
/// `dataset.toml:0:` and the parser's rendered excerpt).
#[test]
fn toml_keys_missing_or_unknown_are_named_on_their_line() {
    let e = with_toml("dt = 0.005555555555555556\n", "");
    assert!(e.contains("dataset.toml:1: missing field `dt`"), "{e}");
    let e = with_toml("density = 47.0", "densty = 47.0");
    assert!(
        e.contains("dataset.toml:5: unknown field `densty`") && !e.contains(":0:"),
        "{e}"
    );
}

/// `viscosity_form` sets the law a fit starts from (the rest-gradient one without it); an
/// unknown name is refused with the field and the names it takes.
#[test]
fn viscosity_form_key_sets_the_law_a_fit_starts_from() {
    use palpate_motion::viscosity::Form;
    let dir = tempfile::tempdir().unwrap();
    copy_example(dir.path());
    edit(dir.path(), "dataset.toml", |t| {
        format!("viscosity_form = \"objective\"\n{t}")
    });
    assert_eq!(
        load(dir.path()).unwrap().model.viscous_form,
        Form::Objective
    );
    assert_eq!(
        load(&example()).unwrap().model.viscous_form,
        Form::RestGradient
    );
    let e = broken(|d| {
        edit(d, "dataset.toml", |t| {
            format!("viscosity_form = \"spatial\"\n{t}")
        })
    });
    assert!(
        e.contains("dataset.toml")
            && e.contains("field viscosity_form")
            && e.contains("\"spatial\"")
            && e.contains("\"objective\""),
        "{e}"
    );
}

/// `scheme` picks the integrator, and the substeps chosen from the capture follow its rule; a
/// dataset without the key is read under the midpoint rule; an unknown name is refused with the
/// field and the names it takes.
#[test]
fn scheme_key_selects_the_integrator() {
    use palpate_motion::timestep::Scheme;
    let example_scheme = "scheme = \"bdf2\"\n";
    assert_eq!(load(&example()).unwrap().model.scheme, Scheme::Bdf2);
    let dir = tempfile::tempdir().unwrap();
    copy_example(dir.path());
    edit(dir.path(), "dataset.toml", |t| {
        assert!(t.contains(example_scheme));
        t.replace(example_scheme, "scheme = \"midpoint\"\n")
    });
    let ds = load(dir.path()).unwrap();
    assert_eq!(ds.model.scheme, Scheme::Midpoint);
    assert_eq!(ds.timestep.scheme, Scheme::Midpoint);
    edit(dir.path(), "dataset.toml", |t| {
        t.replace("scheme = \"midpoint\"\n", "")
    });
    let ds = load(dir.path()).unwrap();
    assert_eq!(ds.model.scheme, Scheme::Midpoint);
    assert_eq!(palpate_motion::timestep::DATASET_DEFAULT, Scheme::Midpoint);
    let e = broken(|d| {
        edit(d, "dataset.toml", |t| {
            t.replace(example_scheme, "scheme = \"rk4\"\n")
        })
    });
    assert!(
        e.contains("dataset.toml") && e.contains("field scheme") && e.contains("\"rk4\""),
        "{e}"
    );
}

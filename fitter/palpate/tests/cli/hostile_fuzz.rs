//! Mutated inputs through every reader of the command line — C3D captures (bytes flipped, the
//! file cut short), motion and static datasets (a key or a cell replaced by a hostile number),
//! `fit.json` (a field replaced) and numeric flags — with the cases users reported as seeds
//! (`.palp` models are fuzzed where they are decoded, in the protocol crate). The property: `palpate` ends within a bound with exit status
//! 0, 1 or 2 (never a signal: no abort), never panics, and an exit 1 says why on stderr.

use crate::common;

use common::{copy_dir, palpate, repo, run_within, text};
use proptest::prelude::*;

/// Numbers a hostile or careless user writes: non-finite, huge, zero, negative, units off.
const HOSTILE: &[&str] = &[
    "nan", "inf", "-inf", "1e308", "-1e308", "1e300", "-1", "0", "-0.0", "1e-308", "9810", "1000",
    "-47",
];

/// Runs `palpate args…` and checks the property; the seconds bound makes a hang a failure.
fn check(args: &[&std::ffi::OsStr], secs: u64) {
    let mut cmd = palpate();
    cmd.arg("-q").args(args);
    let o = run_within(cmd, secs);
    let err = text(&o.stderr);
    let code = o.status.code();
    assert!(
        matches!(code, Some(0..=2)),
        "palpate {args:?}: status {:?} (a signal is an abort): {err}",
        o.status
    );
    assert!(!err.contains("panicked"), "palpate {args:?}: {err}");
    if code == Some(1) {
        assert!(
            err.contains("error"),
            "palpate {args:?}: exit 1, silent: {err}"
        );
    }
}

fn os<S: AsRef<std::ffi::OsStr> + ?Sized>(s: &S) -> &std::ffi::OsStr {
    s.as_ref()
}

fn c3d_bytes() -> Vec<u8> {
    std::fs::read(repo().join("models/silicone-beam/beam_gravity_V2_a.c3d")).unwrap()
}

/// `info` and `import c3d` on the beam capture with `flips` written over it, cut at `cut`.
fn c3d_case(flips: &[(usize, u8)], cut: Option<usize>) {
    let tmp = tempfile::tempdir().unwrap();
    let mut b = c3d_bytes();
    for &(i, v) in flips {
        let i = i % b.len();
        b[i] = v;
    }
    if let Some(c) = cut {
        b.truncate(c % (b.len() + 1));
    }
    let f = tmp.path().join("x.c3d");
    std::fs::write(&f, &b).unwrap();
    check(&[os("info"), os(&f)], 60);
    let beam = repo().join("models/silicone-beam");
    check(
        &[
            os("import"),
            os("c3d"),
            os(&f),
            os("--mesh"),
            os(&beam.join("beam-coarse.msh")),
            os("--places"),
            os(&beam.join("marker-places.csv")),
            os("--clamps"),
            os("clamp"),
            os("--gravity=-9.81,0,0"),
            os("-o"),
            os(&tmp.path().join("D")),
        ],
        120,
    );
}

/// Keys of the motion example's `dataset.toml` and the ones it may carry.
const MOTION_KEYS: &[&str] = &[
    "dt",
    "density",
    "gravity",
    "marker_weight",
    "force_weight",
    "marker_noise",
    "steps",
    "substeps",
    "initial.lambda",
    "initial.mu",
    "initial.viscosity",
    "initial.h",
];

/// The motion example with `key = value` set (in `[initial]` for `initial.*`), read by `info`.
fn motion_case(key: &str, value: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("m");
    copy_dir(&repo().join("models/motion-example"), &d);
    let toml = std::fs::read_to_string(d.join("dataset.toml")).unwrap();
    let mut top = Vec::new();
    let mut initial = Vec::new();
    let mut in_initial = false;
    for line in toml.lines() {
        if line.trim() == "[initial]" {
            in_initial = true;
            continue;
        }
        let k = line.split('=').next().unwrap_or("").trim();
        let target = if in_initial { &mut initial } else { &mut top };
        if !(key == k || key == format!("initial.{k}")) {
            target.push(line.to_string());
        }
    }
    let v = if key == "gravity" {
        format!("[0.0, {value}, 0.0]")
    } else {
        value.to_string()
    };
    match key.strip_prefix("initial.") {
        Some(k) => initial.push(format!("{k} = {v}")),
        None => top.push(format!("{key} = {v}")),
    }
    let text = format!("{}\n[initial]\n{}\n", top.join("\n"), initial.join("\n"));
    std::fs::write(d.join("dataset.toml"), text).unwrap();
    check(&[os("info"), os(&d)], 60);
}

/// The static specimen with cell (`row`, `col`) of `file` replaced by `value`, read by `info`.
fn static_case(file: &str, row: usize, col: usize, value: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path().join("s");
    copy_dir(&repo().join("models/sponge-specimen"), &d);
    let t = std::fs::read_to_string(d.join(file)).unwrap();
    let lines: Vec<&str> = t.lines().collect();
    let r = 1 + row % (lines.len() - 1);
    let mut out: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
    let mut f: Vec<String> = lines[r].split(',').map(String::from).collect();
    let c = col % f.len();
    f[c] = value.to_string();
    out[r] = f.join(",");
    std::fs::write(d.join(file), out.join("\n") + "\n").unwrap();
    check(&[os("info"), os(&d)], 60);
}

/// The beam's `fit.json` with `field` replaced by `[value]` (or a bare value), read by `info`.
fn fit_json_case(field: &str, value: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let t = std::fs::read_to_string(repo().join("models/silicone-beam/fit.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&t).unwrap();
    // JSON has no NaN or infinity: those become the strings a hand edit would leave.
    let n: serde_json::Value = value
        .parse::<f64>()
        .ok()
        .and_then(|x| serde_json::Number::from_f64(x).map(serde_json::Value::Number))
        .unwrap_or_else(|| serde_json::Value::String(value.into()));
    v[field] = if v[field].is_array() {
        serde_json::json!([n])
    } else {
        n
    };
    let f = tmp.path().join("fit.json");
    std::fs::write(&f, serde_json::to_string(&v).unwrap()).unwrap();
    check(&[os("info"), os(&f)], 60);
}

const FIT_FIELDS: &[&str] = &[
    "nodes",
    "tets",
    "lame_lambda_pa",
    "shear_modulus_pa",
    "viscosity_pa_s_h",
    "power_law_index",
    "density_kg_m3",
    "stiffening_pa",
    "rms_marker_m",
];

/// A numeric flag of a command that refuses before work (or does little), set to `value`.
fn flag_case(which: usize, value: &str) {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let beam = repo().join("models/silicone-beam");
    let import = |flag: String| -> Vec<std::ffi::OsString> {
        vec![
            "import".into(),
            "c3d".into(),
            beam.join("beam_gravity_V2_a.c3d").into(),
            "--mesh".into(),
            beam.join("beam-coarse.msh").into(),
            "--places".into(),
            beam.join("marker-places.csv").into(),
            "--clamps".into(),
            "clamp".into(),
            flag.into(),
            "-o".into(),
            out.clone().into(),
        ]
    };
    let args: Vec<std::ffi::OsString> = match which % 6 {
        0 => vec![
            "haptic".into(),
            format!("--block-tets={value}").into(),
            "--port".into(),
            "/dev/ttyNOSUCH0".into(),
        ],
        1 => {
            let mut a = import(format!("--density={value}"));
            a.push("--gravity=-9.81,0,0".into());
            a
        }
        2 => {
            let mut a = import(format!("--release-threshold={value}"));
            a.push("--gravity=-9.81,0,0".into());
            a
        }
        3 => import(format!("--gravity={value},0,0")),
        4 => vec![
            "specimen".into(),
            format!("--noise={value}").into(),
            "--measurements=1".into(),
            "-o".into(),
            out.clone().into(),
        ],
        _ => vec![
            "specimen".into(),
            "--effect=inclusion".into(),
            format!("--magnitude={value}").into(),
            "--measurements=1".into(),
            "-o".into(),
            out.clone().into(),
        ],
    };
    let refs: Vec<&std::ffi::OsStr> = args.iter().map(|a| a.as_os_str()).collect();
    check(&refs, 180);
}

/// The reported cases, each through the same property.
#[test]
fn the_reported_cases_hold_the_property() {
    c3d_case(&[(0, 0)], None);
    c3d_case(&[(16, 0), (17, 0)], None);
    c3d_case(&[], Some(600));
    motion_case("marker_weight", "-1.0");
    motion_case("marker_weight", "0.0");
    motion_case("density", "0.0");
    motion_case("gravity", "-9810");
    static_case("measurements.csv", 3, 3, "1e308");
    static_case("contacts.csv", 1, 7, "1e308");
    fit_json_case("density_kg_m3", "-47");
    flag_case(0, "100000000000");
    flag_case(1, "-1");
    flag_case(2, "0");
    flag_case(2, "-1");
    flag_case(3, "1e308");
    flag_case(4, "10");
    flag_case(5, "1e300");
}

fn hostile() -> impl Strategy<Value = &'static str> {
    proptest::sample::select(HOSTILE)
}

proptest! {
    // Each case runs the program once or twice (tens of milliseconds to a second): a few dozen
    // cases keep the file well under a minute in release.
    #![proptest_config(ProptestConfig {
        cases: 8,
        failure_persistence: None,
        ..ProptestConfig::default()
    })]

    #[test]
    fn mutated_c3d(
        flips in proptest::collection::vec((0usize..600, any::<u8>()), 1..4),
        cut in proptest::option::of(0usize..200_000),
    ) {
        c3d_case(&flips, cut);
    }

    #[test]
    fn mutated_motion_dataset(key in proptest::sample::select(MOTION_KEYS), v in hostile()) {
        motion_case(key, v);
    }

    #[test]
    fn mutated_static_dataset(
        file in proptest::sample::select(&["markers.csv", "contacts.csv", "measurements.csv"][..]),
        row in 0usize..64,
        col in 1usize..8,
        v in hostile(),
    ) {
        static_case(file, row, col, v);
    }

    #[test]
    fn mutated_fit_json(field in proptest::sample::select(FIT_FIELDS), v in hostile()) {
        fit_json_case(field, v);
    }

    #[test]
    fn hostile_numeric_flags(which in 0usize..6, v in hostile()) {
        flag_case(which, v);
    }
}

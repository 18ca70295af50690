//! One name per thing on the command line and in files: the clamped face is `clamps`, a flag whose
//! unit is not SI says its unit, help texts cite documents a user can open. Old spellings are still
//! read, with a warning that names the new one.

mod common;

use common::{assert_exit_and_stderr, assert_succeeded, palpate, repo, text};

/// `simulate --mesh … --clamps GROUP`, or the older `--fixed GROUP` with a warning.
#[test]
fn simulate_reads_clamps_and_the_older_fixed_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let run = |flag: &str| {
        palpate()
            .arg("simulate")
            .arg("--mesh")
            .arg(repo().join("models/motion-example/mesh.msh"))
            .args(["--young", "50000", "--poisson", "0.3", flag, "bottom"])
            .args(["--contact", "0.01,0.04,0.02", "--force", "0,0,-0.1"])
            .arg("-o")
            .arg(dir.path().join(flag.trim_start_matches('-')))
            .env_remove("RUST_LOG")
            .output()
            .unwrap()
    };
    let new = run("--clamps");
    assert_succeeded(&new);
    assert!(
        !text(&new.stderr).contains("older name"),
        "{}",
        text(&new.stderr)
    );
    let old = run("--fixed");
    assert_succeeded(&old);
    let err = text(&old.stderr);
    assert!(
        err.contains("warning: --fixed is the older name of --clamps"),
        "{err}"
    );
}

/// A static dataset's `fixed_group = "…"` is read as `clamps = ["…"]`, with a warning naming the
/// file and line.
#[test]
fn a_static_dataset_with_fixed_group_is_read_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let src = repo().join("models/dataset-example");
    for e in std::fs::read_dir(&src).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.path().join(e.file_name())).unwrap();
    }
    let toml = dir.path().join("dataset.toml");
    let t = std::fs::read_to_string(&toml).unwrap();
    assert!(t.contains("clamps = [\"bottom\"]"), "{t}");
    let mesh = src.join("../sponge/sponge.msh");
    let t = t
        .replace("clamps = [\"bottom\"]", "fixed_group = \"bottom\"")
        .replace(
            "\"../sponge/sponge.msh\"",
            &format!("{:?}", mesh.display().to_string()),
        );
    std::fs::write(&toml, t).unwrap();
    let o = palpate()
        .arg("info")
        .arg(dir.path())
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert_succeeded(&o);
    let err = text(&o.stderr);
    assert!(
        err.contains("dataset.toml:7: `fixed_group` is the older name of `clamps = [\"bottom\"]`"),
        "{err}"
    );
}

/// `--gauge-length-mm` says its unit; `--gauge-length` is still read, with a warning, and a bad
/// value is refused in the unit of the flag.
#[test]
fn gauge_length_says_millimetres() {
    let o = palpate()
        .arg("diagnose")
        .arg(repo().join("models/motion-example"))
        .args(["--gauge-length", "0"])
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert_exit_and_stderr(
        &o,
        1,
        "--gauge-length-mm 0: expected a finite length > 0 mm",
    );
    assert!(
        text(&o.stderr).contains("--gauge-length is the older name of --gauge-length-mm"),
        "{}",
        text(&o.stderr)
    );
}

/// probe-sim's dither is in ADC counts, and its flag says so; `--noise` is still read.
#[test]
fn probe_sim_dither_says_counts() {
    let help = palpate().args(["probe-sim", "--help"]).output().unwrap();
    let h = text(&help.stdout);
    assert!(h.contains("--adc-dither-counts"), "{h}");
    assert!(
        !h.lines().any(|l| l.trim_start().starts_with("--noise")),
        "{h}"
    );
    let o = palpate()
        .args(["probe-sim", "--noise", "2", "--profile", "bogus:1"])
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    assert_exit_and_stderr(&o, 1, "unknown kind \"bogus\"");
    assert!(
        text(&o.stderr).contains("--noise is the older name of --adc-dither-counts"),
        "{}",
        text(&o.stderr)
    );
}

/// Help texts cite documents a user can open (docs/method.md), not sections of the papers.
#[test]
fn help_cites_no_paper_sections() {
    let top = text(&palpate().arg("--help").output().unwrap().stdout);
    let commands: Vec<String> = top
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.split_whitespace().next().map(String::from))
        .filter(|c| c != "help")
        .collect();
    assert!(commands.len() > 10, "{top}");
    for c in std::iter::once(String::new()).chain(commands) {
        let o = palpate().args([c.as_str(), "--help"]).output().unwrap();
        let h = text(&o.stdout);
        for bad in ["§", "seed 00", "thesis"] {
            assert!(!h.contains(bad), "`palpate {c} --help` cites {bad:?}:\n{h}");
        }
    }
}

/// `-o` means one thing everywhere: `-o, --output` (also `--out`), what the command writes, with
/// its default shown or, for a command whose result is printed, the words that nothing is written
/// without it.
#[test]
fn every_output_flag_is_o_output_with_its_default_or_none() {
    let top = text(&palpate().arg("--help").output().unwrap().stdout);
    assert!(top.contains("-o/--output"), "{top}");
    let mut seen = 0;
    for c in [
        "demo",
        "fit",
        "simulate",
        "specimen",
        "diagnose",
        "fit-motion",
        "validate",
        "calibrate-fsr",
    ] {
        let h = text(&palpate().args([c, "--help"]).output().unwrap().stdout);
        let at = h
            .find("-o, --output <")
            .unwrap_or_else(|| panic!("`palpate {c} --help` has no `-o, --output`:\n{h}"));
        // The flag's entry: up to the next flag.
        let entry = &h[at..];
        let entry = &entry[..entry[3..].find("\n  -").map_or(entry.len(), |e| e + 3)];
        assert!(entry.contains("Output: "), "{c}: {entry}");
        assert!(
            entry.contains("aliases: --out") || entry.contains("alias: --out"),
            "{c}: {entry}"
        );
        assert!(
            entry.contains("[default: ") || entry.contains("nothing is written without it"),
            "{c}: {entry}"
        );
        seen += 1;
    }
    assert_eq!(seen, 8);
}

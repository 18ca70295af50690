//! `palpate diagnose` on measured curves (fitter/diagnose/src/curve): synthetic curves written as
//! CSV files in the real-data column formats, each with (or without) an effect the simplest
//! model lacks. The generators are independent of the fitted models (fine-step integration,
//! closed forms written here), so the tests check the library, not a copy of itself.

use palpate_diagnose::curve::lm::{fd_jacobian, levenberg_marquardt, linear_lsq};
use palpate_diagnose::curve::model::{elastic, Family, Law, Model, Scale};
use palpate_diagnose::curve::read::{parse, Group};
use palpate_diagnose::curve::{diagnose_path, CurveDiagnosis, CurveError, CurveOptions};
use std::fmt::Write as _;
use std::path::Path;

/// Deterministic Gaussian noise (xorshift + Box–Muller, `palpate_fem::rng`).
use palpate_fem::rng::XorShift64 as Noise;

fn tension_csv(t: &[f64], x: &[f64], f: &[f64]) -> String {
    let mut s = String::from("time_s,displacement_mm,force_N\n");
    for i in 0..t.len() {
        let _ = writeln!(s, "{:.4},{:.4},{:.6}", t[i], x[i], f[i]);
    }
    s
}

/// Writes the tension test `(t, x, f)` to `path`.
fn write_tension(path: &Path, t: &[f64], x: &[f64], f: &[f64]) {
    std::fs::write(path, tension_csv(t, x, f)).unwrap();
}

fn run(dir: &Path) -> CurveDiagnosis {
    let mut v = diagnose_path(dir, &CurveOptions::default(), &mut |m| eprintln!("{m}")).unwrap();
    assert_eq!(v.len(), 1, "one dataset expected");
    v.remove(0)
}

/// A triangle ramp 0 → x_max → 0 at `rate` (mm/s), sampled at `hz`.
fn triangle(x_max: f64, rate: f64, hz: f64) -> (Vec<f64>, Vec<f64>) {
    let t_end = 2.0 * x_max / rate;
    let n = (t_end * hz).round() as usize;
    let t: Vec<f64> = (0..=n).map(|i| i as f64 / hz).collect();
    let x = t
        .iter()
        .map(|&t| {
            if t <= t_end / 2.0 {
                rate * t
            } else {
                rate * (t_end - t)
            }
        })
        .collect();
    (t, x)
}

#[test]
fn neo_hookean_tension_adopts_hyperelastic_nonlinearity() {
    // μ_eff = 0.5 N, L0 = 50 mm (not given to diagnose), three files to stretch 2, 3 and 4,
    // σ = 5 mN. Loading only, slow: no rate effect in the data.
    let dir = tempfile::tempdir().unwrap();
    let (mu, l0, sigma) = (0.5, 50.0, 0.005);
    let mut noise = Noise::new(0x9e37_79b9_7f4a_7c15);
    for (k, lam_max) in [2.0, 3.0, 4.0].into_iter().enumerate() {
        let n = 300;
        let x: Vec<f64> = (0..=n)
            .map(|i| (lam_max - 1.0) * l0 * i as f64 / n as f64)
            .collect();
        let t: Vec<f64> = (0..=n).map(|i| i as f64 * 0.1).collect();
        let f: Vec<f64> = x
            .iter()
            .map(|&d| {
                let lam = 1.0 + d / l0;
                mu * (lam - lam.powi(-2)) + sigma * noise.normal()
            })
            .collect();
        write_tension(&dir.path().join(format!("pull{k}.csv")), &t, &x, &f);
    }
    let d = run(dir.path());
    assert!(
        d.adopted
            .first()
            .is_some_and(|a| a.starts_with("hyperelastic")),
        "adopted {:?}",
        d.adopted
    );
    // Before: a straight line through a Neo-Hookean curve to λ = 4 is off by far more than the
    // noise; after: held-out (whole files left out) within 1.5 σ (the noise floor, allowing for
    // the extrapolation to the λ = 4 file from the other two).
    assert!(d.before.heldout_rms > 5.0 * sigma, "before {:?}", d.before);
    assert!(d.after.heldout_rms < 1.5 * sigma, "after {:?}", d.after);
    // Recovered μ within 3 % (its σ is ~0.3 %; L0 is fitted too, and μ trades against it).
    assert_eq!(d.adopted, ["hyperelastic-neo-hookean"]);
    let p = d.final_params.iter().find(|p| p.name == "mu").unwrap();
    assert!((p.value - mu).abs() < 0.03 * mu, "mu {p:?}");
    // diagnosis.json carries its schema version.
    let json: serde_json::Value =
        serde_json::from_str(&palpate_diagnose::curve::report::json_text(&d).unwrap()).unwrap();
    assert_eq!(
        (json["schema_version"].as_u64(), json["kind"].as_str()),
        (Some(1), Some("curve-diagnosis"))
    );
}

/// Linear elastic spring k plus one Maxwell branch (β, τ) in Fung form, integrated with forward
/// Euler on a 20× finer step than recorded (independent of the exact exponential update the
/// model uses).
fn sls_force(t: &[f64], x: &[f64], k: f64, beta: f64, tau: f64) -> Vec<f64> {
    let mut f = vec![0.0; t.len()];
    let mut h = 0.0;
    for i in 1..t.len() {
        let sub = 20;
        let dt = (t[i] - t[i - 1]) / sub as f64;
        let dpe = k * (x[i] - x[i - 1]) / sub as f64;
        for _ in 0..sub {
            h += -h / tau * dt + beta * dpe;
        }
        f[i] = k * x[i] + h;
    }
    f
}

/// Triangles to 20 mm at 0.5, 1.5 and 4 mm/s on the SLS `(k, β, τ)`, written as
/// `{name}0.csv` … `{name}2.csv`: the force as `measured` makes it of the model's, plus σ noise.
fn sls_at_three_rates(
    dir: &Path,
    name: &str,
    (k, beta, tau): (f64, f64, f64),
    sigma: f64,
    seed: u64,
    measured: impl Fn(f64) -> f64,
) {
    let mut noise = Noise::new(seed);
    for (i, rate) in [0.5, 1.5, 4.0].into_iter().enumerate() {
        let (t, x) = triangle(20.0, rate, 20.0);
        let f: Vec<f64> = sls_force(&t, &x, k, beta, tau)
            .into_iter()
            .map(|v| measured(v) + sigma * noise.normal())
            .collect();
        write_tension(&dir.join(format!("{name}{i}.csv")), &t, &x, &f);
    }
}

#[test]
fn standard_linear_solid_at_three_rates_adopts_viscosity() {
    // k = 0.05 N/mm, β = 1, τ = 4 s; triangles to 20 mm at 0.5, 1.5 and 4 mm/s, σ = 5 mN.
    let dir = tempfile::tempdir().unwrap();
    let (k, beta, tau, sigma) = (0.05, 1.0, 4.0, 0.005);
    sls_at_three_rates(dir.path(), "rate", (k, beta, tau), sigma, 42, |v| v);
    let d = run(dir.path());
    assert_eq!(
        d.adopted.first().map(String::as_str),
        Some("viscosity"),
        "adopted {:?}",
        d.adopted
    );
    // Hysteresis of ±β k x(1 − e^{−t/τ}) ≫ σ before; after, held-out (one rate left out) within
    // 1.5 σ: Euler at 1/20 of the 50 ms step has a truncation error ≲ 1e-4 N ≪ σ.
    assert!(d.before.heldout_rms > 5.0 * sigma, "before {:?}", d.before);
    assert!(d.after.heldout_rms < 1.5 * sigma, "after {:?}", d.after);
    let get = |n: &str| d.final_params.iter().find(|p| p.name == n).unwrap().value;
    assert_eq!(d.adopted, ["viscosity"]);
    // The one branch matches the generator within 5 % (1σ ≈ 1 %).
    assert!((get("k") - k).abs() < 0.05 * k, "k {}", get("k"));
    assert!(
        (get("beta1") - beta).abs() < 0.05 * beta,
        "beta {}",
        get("beta1")
    );
    assert!(
        (get("tau1") - tau).abs() < 0.05 * tau,
        "tau {}",
        get("tau1")
    );
}

/// Three tension files `{name}0.csv` … `{name}2.csv` of a linear spring: F = 0.08 N/mm · Δ plus
/// σ = 5 mN noise from `noise`, triangles to 10, 20 and 30 mm at 1 mm/s.
fn linear_files(dir: &Path, name: &str, noise: &mut Noise) {
    for (i, xm) in [10.0, 20.0, 30.0].into_iter().enumerate() {
        let (t, x) = triangle(xm, 1.0, 10.0);
        let f: Vec<f64> = x
            .iter()
            .map(|&d| 0.08 * d + 0.005 * noise.normal())
            .collect();
        write_tension(&dir.join(format!("{name}{i}.csv")), &t, &x, &f);
    }
}

#[test]
fn linear_data_with_noise_comes_back_clean() {
    // Tension: three files, F = 0.08 N/mm · Δ + noise (σ = 5 mN), loading and unloading.
    let dir = tempfile::tempdir().unwrap();
    let mut noise = Noise::new(7);
    linear_files(dir.path(), "lin", &mut noise);
    let d = run(dir.path());
    assert!(d.adopted.is_empty(), "adopted {:?}", d.adopted);
    // The simplest model is right: fitted RMS ≈ σ (within 15 %, n ≈ 1,200).
    assert!(
        (d.after.fitted_rms / 0.005 - 1.0).abs() < 0.15,
        "{:?}",
        d.after
    );

    // Stress–strain, one file: held out by contiguous blocks (incl. the extrapolated top).
    let dir = tempfile::tempdir().unwrap();
    let mut s = String::from(
        "time_s,true_strain,true_stress_MPa,engineering_strain,engineering_stress_MPa\n",
    );
    for i in 0..=400 {
        let e = 2.0 * i as f64 / 400.0;
        let p = 0.3 * e + 0.004 * noise.normal();
        let _ = writeln!(
            s,
            "{},{},{},{},{}",
            0.1 * i as f64,
            (1.0 + e).ln(),
            p * (1.0 + e),
            e,
            p
        );
    }
    std::fs::write(dir.path().join("linear.csv"), s).unwrap();
    let d = run(&dir.path().join("linear.csv"));
    assert!(d.adopted.is_empty(), "adopted {:?}", d.adopted);
}

#[test]
fn fsr_power_law_sensor_adopts_nonlinear_response() {
    // Four balance runs of a divider (10 bit) with conductance ∝ F^0.6 (a typical FSR), counts
    // rounded and σ = 8 counts. The linear-conductance model bends the wrong way.
    let dir = tempfile::tempdir().unwrap();
    let mut noise = Noise::new(11);
    let mut s = String::from("run,adc_counts,reference_mass_g\n");
    for run in 1..=4 {
        for m in (0..=1000).step_by(50) {
            let f = m as f64 * 9.81e-3;
            let u = 0.8 * f.powf(0.6);
            let c = (1023.0 * u / (1.0 + u) + 8.0 * noise.normal())
                .round()
                .clamp(0.0, 1023.0);
            let _ = writeln!(s, "{run},{c},{m}");
        }
    }
    std::fs::write(dir.path().join("fsr.csv"), s).unwrap();
    let d = run(&dir.path().join("fsr.csv"));
    assert_eq!(
        d.adopted.first().map(String::as_str),
        Some("power-law-response"),
        "{:?}",
        d.adopted
    );
    // Held out (one run out) within 1.5 × the 8-count noise after.
    assert!(d.after.heldout_rms < 12.0, "{:?}", d.after);
    let b = d.final_params.iter().find(|p| p.name == "b").unwrap();
    assert!((b.value - 0.6).abs() < 0.05, "b {b:?}");
}

#[test]
fn malformed_csv_gives_a_located_error() {
    let text = "time_s,displacement_mm,force_N\n0,0,0\n0.1,0.5,0.01\n0.2,abc,0.02\n";
    match parse(text, "bad.csv") {
        Err(CurveError::Format {
            file,
            line,
            message,
        }) => {
            assert_eq!((file.as_str(), line), ("bad.csv", 4));
            assert!(
                message.contains("displacement_mm") && message.contains("abc"),
                "{message}"
            );
        }
        other => panic!("expected a located format error, got {other:?}"),
    }
    let e = parse("a,b\n1,2\n", "x.csv").unwrap_err().to_string();
    assert!(
        e.starts_with("x.csv:1:") && e.contains("time_s,displacement_mm,force_N"),
        "{e}"
    );
    let e = parse("time_s,displacement_mm,force_N\n0,0,0\n1,1\n", "short.csv")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("short.csv:3:") && e.contains("force_n"),
        "{e}"
    );
    let e = parse(
        "time_s,displacement_mm,force_N\n0,0,0\n1,1,1\n0.5,2,2\n",
        "t.csv",
    )
    .unwrap_err()
    .to_string();
    assert!(e.starts_with("t.csv:4:") && e.contains("backwards"), "{e}");
}

#[test]
fn jacobian_and_lm_against_analytic_references() {
    // Forward-difference Jacobian of a Mooney–Rivlin stress–strain model vs the analytic one:
    // ∂P/∂C10 = 2(λ − λ⁻²), ∂P/∂C01 = 2(λ − λ⁻²)/λ. FD step 1e-6 → error ~1e-6 relative.
    let e: Vec<f64> = (0..50).map(|i| 0.05 * i as f64).collect();
    let g = Group {
        name: "g".into(),
        order: 0.0,
        t: (0..50).map(|i| i as f64).collect(),
        x: e.clone(),
        y: e.iter()
            .map(|&e| elastic(Law::MooneyRivlin, &[0.1, 0.05], [2.0, 0.0], 1.0 + e))
            .collect(),
        line: (2..52).collect(),
    };
    let scale = Scale {
        x_max: 2.45,
        duration: 49.0,
        order_mean: 0.0,
    };
    let m = Model {
        law: Law::MooneyRivlin,
        ..Model::simplest(Family::StressStrain, scale)
    };
    let f = |th: &[f64]| m.predict(th, &g);
    let th = [0.3, -0.02];
    let r0 = f(&th).unwrap();
    let j = fd_jacobian(&f, &th, &r0);
    for (i, &e) in e.iter().enumerate() {
        let lam = 1.0 + e;
        let d = 2.0 * (lam - lam.powi(-2));
        assert!((j[(i, 0)] - d).abs() < 1e-6 * (1.0 + d.abs()), "row {i}");
        assert!(
            (j[(i, 1)] - d / lam).abs() < 1e-6 * (1.0 + d.abs()),
            "row {i}"
        );
    }
    // LM on the noise-free data recovers the generating moduli; the model is linear in them, so
    // the independent reference is the normal-equation solution (agreement to 1e-9).
    let res = |th: &[f64]| {
        Some(
            m.predict(th, &g)?
                .iter()
                .zip(&g.y)
                .map(|(p, y)| p - y)
                .collect(),
        )
    };
    let fit = levenberg_marquardt(&res, &[1.0, 1.0], 50).unwrap();
    let cols: Vec<Vec<f64>> = vec![
        e.iter()
            .map(|&e| 2.0 * ((1.0 + e) - (1.0 + e).powi(-2)))
            .collect(),
        e.iter()
            .map(|&e| 2.0 * ((1.0 + e) - (1.0 + e).powi(-2)) / (1.0 + e))
            .collect(),
    ];
    let reference = linear_lsq(&cols, &g.y).unwrap();
    for k in 0..2 {
        assert!(
            (fit.theta[k] - reference[k]).abs() < 1e-9,
            "{:?} vs {reference:?}",
            fit.theta
        );
    }
    assert!((reference[0] - 0.1).abs() < 1e-9 && (reference[1] - 0.05).abs() < 1e-9);
}

#[test]
fn inputs_are_detected_by_header_and_broken_stress_strain_time_is_repaired() {
    use palpate_diagnose::curve::read::{is_curve_input, read_path, Format};
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("a.csv"),
        "force_N,resistance_ohm\n1,6000\n10,1000\n100,250\n",
    )
    .unwrap();
    // A stress–strain file whose time column restarts (as in a spreadsheet export): kept, with
    // time rebuilt from the sample index and a warning naming the line.
    std::fs::write(
        dir.path().join("b.csv"),
        "engineering_strain,engineering_stress_MPa,time_s\n0,0,0.8\n0.1,0.01,0.9\n0.2,0.02,0.10\n0.3,0.03,0.11\n",
    )
    .unwrap();
    // A CSV of another kind in the same directory is skipped, with a warning naming it.
    std::fs::write(dir.path().join("c.csv"), "note,value\nx,1\n").unwrap();
    assert!(is_curve_input(dir.path()));
    let sets = read_path(dir.path(), false, false).unwrap();
    assert!(
        sets[0].warnings.iter().any(|w| w.contains("c.csv:1:")),
        "{:?}",
        sets[0].warnings
    );
    let formats: Vec<Format> = sets.iter().map(|d| d.format).collect();
    assert_eq!(formats, [Format::FsrDatasheet, Format::StressStrain]);
    let ss = &sets[1];
    assert!(ss.warnings[0].contains("b.csv:4:"), "{:?}", ss.warnings);
    let t = &ss.groups[0].t;
    assert!(
        t.windows(2).all(|w| (w[1] - w[0] - 0.1).abs() < 1e-12),
        "{t:?}"
    );
    // A static dataset directory is not a curve input.
    std::fs::write(dir.path().join("dataset.toml"), "").unwrap();
    assert!(!is_curve_input(dir.path()));
}

#[test]
fn viscous_strip_that_buckles_on_unloading_adopts_slack() {
    // The SLS of the viscosity test with a strong, slow branch (β = 2, τ = 10 s): on fast
    // unloading the model force turns compressive, but a strip buckles, so the "measured" force
    // is max(F, 0) + noise — the effect the real VHB membrane showed.
    let dir = tempfile::tempdir().unwrap();
    let (k, beta, tau, sigma) = (0.05, 2.0, 10.0, 0.005);
    sls_at_three_rates(dir.path(), "strip", (k, beta, tau), sigma, 5, |v| {
        v.max(0.0)
    });
    let d = run(dir.path());
    assert!(
        d.adopted.iter().any(|a| a == "slack") && d.adopted.iter().any(|a| a == "viscosity"),
        "adopted {:?}",
        d.adopted
    );
    // With both effects the model is the generator's: held-out within 1.5 σ.
    assert!(d.after.heldout_rms < 1.5 * sigma, "after {:?}", d.after);
}

/// A data folder with one subdirectory per instrument (as `../shared/data` is laid out) is
/// diagnosed one subdirectory at a time, each into its own report folder; a folder with nothing
/// diagnosable anywhere is an error that says what was looked for.
#[test]
fn a_folder_of_instrument_folders_is_diagnosed_one_by_one() {
    let root = tempfile::tempdir().unwrap();
    let mut noise = Noise::new(11);
    for name in ["strip-a", "strip-b"] {
        let sub = root.path().join(name);
        std::fs::create_dir(&sub).unwrap();
        linear_files(&sub, "run", &mut noise);
    }
    std::fs::create_dir(root.path().join("notes")).unwrap();
    let out = tempfile::tempdir().unwrap();
    let args = |dataset: &Path, output: &Path| palpate_diagnose::run::Request {
        dataset: dataset.to_path_buf(),
        output: output.to_path_buf(),
        candidates: Vec::new(),
        max_effects: Some(3),
        mesh: palpate_diagnose::MeshChoice::Auto,
        gauge_length: None,
        more_runs: Vec::new(),
        held_out: Vec::new(),
        poisson: None,
        design: None,
        motion_convergence: false,
        full_search: false,
    };
    palpate_diagnose::run::run(&args(root.path(), out.path())).unwrap();
    for name in ["strip-a", "strip-b"] {
        let reports: Vec<_> = walk(&out.path().join(name))
            .into_iter()
            .filter(|p| p.ends_with("diagnosis.md"))
            .collect();
        assert_eq!(reports.len(), 1, "{name}: {reports:?}");
    }
    assert!(!out.path().join("notes").exists());
    let empty = tempfile::tempdir().unwrap();
    std::fs::create_dir(empty.path().join("sub")).unwrap();
    let e = palpate_diagnose::run::run(&args(empty.path(), out.path()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("no subdirectory is any of these"), "{e}");
}

/// Every file below `dir`.
fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// Curves that no model can be fitted to honestly are refused with the file's line, never
/// reported as "clean" with an infinite RMS or explained by a hyperelastic law: a stress of 1e300
/// (its square overflows) and a tension test whose force is negative throughout.
#[test]
fn implausible_curves_are_refused_not_called_clean() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = String::from(
        "time_s,true_strain,true_stress_MPa,engineering_strain,engineering_stress_MPa\n",
    );
    for k in 1..40 {
        let e = 0.05 * k as f64;
        let stress = if k == 20 { 1e300 } else { 0.1 * e };
        s.push_str(&format!(
            "{},{},{},{},{}\n",
            0.1 * k as f64,
            e,
            stress,
            e,
            stress
        ));
    }
    std::fs::write(dir.path().join("huge.csv"), s).unwrap();
    let e = diagnose_path(dir.path(), &CurveOptions::default(), &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("line 21") && e.contains("1e300"), "{e}");

    let dir = tempfile::tempdir().unwrap();
    let (t, x) = triangle(20.0, 1.0, 10.0);
    let f: Vec<f64> = x.iter().map(|x| -0.08 * x - 0.001).collect();
    std::fs::write(dir.path().join("negative.csv"), tension_csv(&t, &x, &f)).unwrap();
    let e = diagnose_path(dir.path(), &CurveOptions::default(), &mut |_| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("negative in all") && e.contains("flip the sign"),
        "{e}"
    );
}

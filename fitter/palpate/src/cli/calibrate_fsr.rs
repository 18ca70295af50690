//! `palpate calibrate-fsr <csv> [-o calibration.json]`: fit an FSR's response (thesis §4.2,
//! Fig. 4.4) and write the calibration the probe's config frame carries.

use anyhow::Context;
use palpate_fem::io::atomic::write_atomic;
use palpate_link::fsr::data::{self, Rig};
use palpate_link::fsr::{calibrate, CurveChoice, FitOptions};
use palpate_protocol::link::{Divider, ForceCurve};
use std::path::PathBuf;

/// `--curve`: the library's names (listed in `--help`), parsed by its `FromStr`.
fn curve_parser() -> impl clap::builder::TypedValueParser<Value = CurveChoice> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(CurveChoice::ALL.map(CurveChoice::name))
        .try_map(|s| s.parse::<CurveChoice>())
}

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Calibration table: `run,adc_counts,reference_mass_g` (balance) or
    /// `force_N,resistance_ohm,divider_output_V` (published points).
    pub csv: PathBuf,
    /// Output: the calibration (and the full fit report) written as JSON; the result is printed,
    /// and nothing is written without it.
    #[arg(
        short = 'o',
        long = "output",
        visible_alias = "out",
        value_name = "FILE"
    )]
    pub output: Option<PathBuf>,
    /// Curve written into the calibration.
    #[arg(long, default_value = "power", value_parser = curve_parser())]
    pub curve: CurveChoice,
    /// ADC resolution of the rig that recorded counts.
    #[arg(long, default_value_t = 10)]
    pub rig_bits: u32,
    /// Divider supply of the rig, V.
    #[arg(long, default_value_t = 5.0)]
    pub rig_supply_v: f64,
    /// Pull-down of the rig's divider, Ω.
    #[arg(long, default_value_t = 10_000.0)]
    pub rig_pulldown_ohm: f64,
    /// Divider supply of the probe the calibration is for, V (nRF52840 board: 3.3).
    #[arg(long, default_value_t = 3.3)]
    pub probe_supply_v: f32,
    /// Pull-down of the probe's divider, Ω.
    #[arg(long, default_value_t = 10_000.0)]
    pub probe_pulldown_ohm: f32,
    /// Outlier threshold, robust standard deviations of the log residual.
    #[arg(long, default_value_t = 3.5)]
    pub outlier_sigmas: f64,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        (2..=24).contains(&args.rig_bits),
        "--rig-bits {} must be 2 ..= 24",
        args.rig_bits
    );
    let rig = Rig {
        adc_bits: args.rig_bits,
        v_supply_v: args.rig_supply_v,
        r_pulldown_ohm: args.rig_pulldown_ohm,
    };
    let (format, points) = data::read_csv(&args.csv, &rig)?;
    let opts = FitOptions {
        rig,
        target: Divider {
            r_pulldown_ohm: args.probe_pulldown_ohm,
            v_supply_v: args.probe_supply_v,
        },
        curve: args.curve,
        outlier_sigmas: args.outlier_sigmas,
    };
    let name = args.csv.display().to_string();
    let fit = calibrate(&name, format, points, &opts)?;

    println!(
        "FSR calibration of {name} ({format:?}, {} points)",
        fit.points
    );
    match format {
        data::Format::BalanceCounts => println!(
            "  rig: {}-bit ADC, {} V, {} Ω pull-down; force = mass · 9.81 m/s²; G = V / (R_pd (V_s − V)) in µS",
            rig.adc_bits, rig.v_supply_v, rig.r_pulldown_ohm
        ),
        data::Format::ForceResistance => println!("  conductance G = 1 / R in µS"),
    }
    let (a, b) = fit.power_law;
    let pr = fit.power_law_residuals;
    let mr = fit.monotone_residuals;
    println!(
        "  {:<34} {:>10} {:>10} {:>8}",
        "curve", "rms [N]", "max [N]", "rms rel"
    );
    println!(
        "  {:<34} {:>10.3} {:>10.3} {:>7.1}%",
        format!("power law F = {a:.4e} · G^{b:.3}"),
        pr.rms_n,
        pr.max_abs_n,
        100.0 * pr.rms_relative
    );
    println!(
        "  {:<34} {:>10.3} {:>10.3} {:>7.1}%",
        format!("monotone ({} knots)", fit.monotone_knots.len()),
        mr.rms_n,
        mr.max_abs_n,
        100.0 * mr.rms_relative
    );
    println!(
        "  usable range: {:.3} … {:.3} N ({:.0} … {:.0} g)",
        fit.usable_range_n.0,
        fit.usable_range_n.1,
        fit.usable_range_n.0 / 9.81e-3,
        fit.usable_range_n.1 / 9.81e-3
    );
    println!(
        "  fitted {} points; rejected {}:",
        fit.fitted.len(),
        fit.rejected.len()
    );
    for r in &fit.rejected {
        let what = match (r.point.run, r.point.counts) {
            (Some(run), Some(c)) => format!("run {run}, {c} counts, {:.3} N", r.point.force_n),
            _ => format!("{:.3} N", r.point.force_n),
        };
        println!("    line {:>3} ({what}): {}", r.point.line, r.reason);
    }
    for (line, stated, computed) in &fit.divider_disagreements {
        println!(
            "  line {line}: stated divider output {stated} V, resistance gives {computed:.2} V"
        );
    }
    match fit.calibration.curve {
        ForceCurve::PowerLaw { gain, exponent } => {
            println!("  calibration: power law gain {gain:e}, exponent {exponent}")
        }
        ForceCurve::Monotone { len, .. } => println!("  calibration: monotone table, {len} knots"),
    }
    if let Some(out) = &args.output {
        let json = serde_json::to_string_pretty(&fit).context("serialising the fit")?;
        write_atomic(out, json.as_bytes())?;
        log::info!("wrote {}", out.display());
    }
    println!(
        "{}",
        serde_json::json!({
            "schema_version": 1, "kind": "fsr-calibration", "source": name, "power_law": {"gain": a, "exponent": b}, "power_rms_n": pr.rms_n,
            "power_rms_relative": pr.rms_relative, "monotone_rms_n": mr.rms_n,
            "usable_range_n": [fit.usable_range_n.0, fit.usable_range_n.1],
            "fitted": fit.fitted.len(), "rejected": fit.rejected.len(),
        })
    );
    Ok(())
}

//! `palpate probe-sim --port <dev> --profile <…>`: the probe firmware library on the host behind a
//! simulated ADS1015, pressed by a scripted force profile, streaming real frames to a serial
//! device — a stand-in probe for demos and tests. `--pty` makes its own pseudo-terminal and
//! prints the path to give to `palpate probe --port` or `palpate haptic --port`.

use anyhow::Context;
use palpate_link::faults::{FaultPlan, FaultyWriter};
use palpate_link::fsr::read_calibration_json;
use palpate_link::sender::{run_sender, Pacing, SenderOptions};
use palpate_probe::sim::{default_config, Profile, SimProbe};
use serialport::SerialPort;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Serial device to write frames to (e.g. one end of a `socat` pty pair).
    #[arg(long, conflicts_with = "pty")]
    pub port: Option<String>,
    /// Create a pseudo-terminal pair and print the path of the end to read from.
    #[arg(long)]
    pub pty: bool,
    /// Force script: `const:F`, `sine:MEAN,AMPLITUDE,HZ` or `press:PEAK,PERIOD_S` (N, Hz, s).
    #[arg(long, default_value = "press:8,2")]
    pub profile: String,
    /// Seconds to run.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Sample rate, Hz.
    #[arg(long, default_value_t = 1000)]
    pub rate: u16,
    /// Low-pass cut-off, Hz (0 = off).
    #[arg(long, default_value_t = 100.0)]
    pub cutoff: f32,
    /// Calibration written by `palpate calibrate-fsr -o` (default: the FSR 402 fit on a 3.3 V / 10 kΩ divider).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// ADC dither in counts (±), added to every simulated reading (`--noise` is its older name).
    #[arg(long = "adc-dither-counts", alias = "noise", default_value_t = 2)]
    pub adc_dither_counts: i16,
    /// Probability of corrupting each byte on the wire (fault demo).
    #[arg(long, default_value_t = 0.0)]
    pub corrupt: f64,
    /// Serial baud rate (ignored by ptys).
    #[arg(long, default_value_t = 1_000_000)]
    pub baud: u32,
}

/// Parses a profile spec.
pub fn parse_profile(s: &str) -> anyhow::Result<Profile> {
    let (kind, rest) = s
        .split_once(':')
        .with_context(|| format!("profile {s:?}: expected KIND:VALUES"))?;
    let v: Vec<f32> = rest
        .split(',')
        .map(|x| {
            x.trim()
                .parse::<f32>()
                .with_context(|| format!("profile {s:?}: {x:?} is not a number"))
        })
        .collect::<Result<_, _>>()?;
    let need = |n: usize| -> anyhow::Result<()> {
        anyhow::ensure!(
            v.len() == n,
            "profile {s:?}: {kind} takes {n} values, found {}",
            v.len()
        );
        Ok(())
    };
    let p = match kind {
        "const" => {
            need(1)?;
            Profile::Constant(v[0])
        }
        "sine" => {
            need(3)?;
            Profile::Sine {
                mean: v[0],
                amplitude: v[1],
                hz: v[2],
            }
        }
        "press" => {
            need(2)?;
            anyhow::ensure!(v[1] > 0.0, "profile {s:?}: period must be > 0");
            Profile::Press {
                peak: v[0],
                period_s: v[1],
            }
        }
        k => anyhow::bail!("profile {s:?}: unknown kind {k:?} (const, sine, press)"),
    };
    anyhow::ensure!(
        v.iter().all(|x| x.is_finite()),
        "profile {s:?}: values must be finite"
    );
    Ok(p)
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    super::renamed::warn_if_used("--noise", "--adc-dither-counts");
    let profile = parse_profile(&args.profile)?;
    let mut config = default_config();
    config.rate_hz = args.rate;
    config.filter_cutoff_hz = args.cutoff;
    if let Some(p) = &args.calibration {
        config.calibration = read_calibration_json(p)?;
    }
    let sim = SimProbe::new(config, profile, args.adc_dither_counts)
        .map_err(|e| anyhow::anyhow!("starting the simulated probe: {e}"))?;
    let opts = SenderOptions::clean(args.seconds, Pacing::RealTime);
    let plan = FaultPlan {
        corrupt: args.corrupt,
        ..Default::default()
    };
    let stop = AtomicBool::new(false);
    let (mut port, _keep) = if args.pty {
        let (master, slave) =
            serialport::TTYPort::pair().context("creating a pseudo-terminal pair")?;
        println!(
            "probe-sim: read the probe at {}",
            slave.name().unwrap_or_default()
        );
        (master, Some(slave))
    } else {
        let path = args.port.as_deref().context("give --port <dev> or --pty")?;
        (
            palpate_link::port::open(path, args.baud, Duration::from_millis(500))?,
            None,
        )
    };
    port.set_timeout(Duration::from_millis(500))?;
    log::info!(
        "probe-sim: {} at {} Hz for {} s",
        describe(&profile),
        args.rate,
        args.seconds
    );
    let t0 = Instant::now();
    let (rep, sink) = run_sender(
        FaultyWriter::new(port, plan, 1),
        sim,
        &opts,
        Instant::now(),
        &stop,
    );
    let wall = t0.elapsed().as_secs_f64();
    println!(
        "probe-sim: {} samples, {} frames written, {} write errors, {:.0} frames/s, faults {:?}",
        rep.samples.len(),
        rep.frames_written,
        rep.write_errors,
        rep.frames_written as f64 / wall,
        sink.counts()
    );
    Ok(())
}

/// The profile in words (its Rust form is no message for a user).
fn describe(p: &Profile) -> String {
    match *p {
        Profile::Constant(f) => format!("a constant {f} N"),
        Profile::Sine {
            mean,
            amplitude,
            hz,
        } => format!("a sine of {mean} ± {amplitude} N at {hz} Hz"),
        Profile::Press { peak, period_s } => {
            format!("presses up to {peak} N every {period_s} s")
        }
    }
}

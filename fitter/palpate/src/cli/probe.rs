//! `palpate probe --port <dev> [--csv out.csv]`: read the probe's stream, show the force live,
//! record every sample to CSV, and report the link's counters.

use palpate_fem::io::atomic::write_atomic_with;
use palpate_link::fsr::read_calibration_json;
use palpate_link::port::{open, FrameReader, StdWrite};
use palpate_link::LinkHostError;
use palpate_probe::tx::FrameWriter;
use palpate_protocol::link::{Config, Frame};
use std::io::Write;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// Arguments.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Serial device of the probe.
    #[arg(long)]
    pub port: String,
    /// Record every sample here.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Seconds to read.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// Send this calibration (from `palpate calibrate-fsr -o`) to the probe first.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Sample rate to request with `--calibration`, Hz.
    #[arg(long, default_value_t = 1000)]
    pub rate: u16,
    /// Baud rate.
    #[arg(long, default_value_t = 1_000_000)]
    pub baud: u32,
}

/// Runs the command.
pub fn run(args: Args) -> anyhow::Result<()> {
    // The recording's place is checked before the seconds of recording, not after.
    if let Some(path) = &args.csv {
        super::output::check_writable(path)?;
    }
    if !(args.seconds.is_finite() && args.seconds > 0.0) {
        anyhow::bail!(
            "--seconds {}: expected a finite duration > 0 s",
            args.seconds
        );
    }
    let port = open(&args.port, args.baud, Duration::from_millis(50))?;
    if let Some(p) = &args.calibration {
        let cfg = Config {
            rate_hz: args.rate,
            filter_cutoff_hz: 100.0,
            calibration: read_calibration_json(p)?,
        };
        let mut w = FrameWriter::new(StdWrite(port.try_clone_native()?));
        w.send(&Frame::Config(cfg))
            .map_err(|e| anyhow::anyhow!("sending config to {}: {e:?}", args.port))?;
    }
    let mut reader = FrameReader::new(port);
    let mut rows = Vec::new();
    let t0 = Instant::now();
    let mut last_print = t0;
    let mut stderr = std::io::stderr();
    // The live line is progress: -q hides it.
    let live = super::logging::progress_shown();
    let mut drawn = false;
    while t0.elapsed().as_secs_f64() < args.seconds {
        reader
            .poll(|f, at| match f {
                Frame::Sample(s) => rows.push((s, at.duration_since(t0).as_micros() as u64)),
                Frame::Hello(h) => log::info!(
                    "probe: device {:#010x}, firmware {:#06x}, protocol {}, {} Hz",
                    h.device_id,
                    h.firmware_version,
                    h.protocol_version,
                    h.rate_hz
                ),
                Frame::Config(c) => log::info!(
                    "probe config: {} Hz, cut-off {} Hz, {:?}",
                    c.rate_hz,
                    c.filter_cutoff_hz,
                    c.calibration.curve
                ),
                Frame::Error(e) => log::warn!("probe error: {:?} ({})", e.code, e.detail),
            })
            .map_err(|source| LinkHostError::Io {
                what: "reading",
                path: args.port.clone(),
                source,
            })?;
        if last_print.elapsed() > Duration::from_millis(100) {
            last_print = Instant::now();
            if let Some((s, _)) = rows.last().filter(|_| live) {
                drawn = true;
                let st = reader.stats();
                let _ = write!(stderr, "\rseq {:>8}  force {:>8.3} N  raw {:>6}  status {:#04x}  missing {}  rejected {}   ", s.seq, s.force_n, s.raw_counts, s.status, st.missing_samples, st.rejected());
            }
        }
        if rows.is_empty() && t0.elapsed() > Duration::from_secs(2) {
            if let Some(e) = reader.version_mismatch(&args.port) {
                return Err(e.into());
            }
        }
    }
    if drawn {
        eprintln!();
    }
    let st = *reader.stats();
    if rows.is_empty() {
        anyhow::bail!(
            "no force sample received from {} in {:.1} s ({} frames rejected, {} bytes \
             discarded, {} bytes read): check the port, the baud rate and that the probe is streaming",
            args.port,
            args.seconds,
            st.rejected(),
            st.bytes_discarded,
            st.bytes
        );
    }
    println!(
        "{} samples in {:.1} s; link: {:?}",
        rows.len(),
        args.seconds,
        st
    );
    if let Some(path) = &args.csv {
        write_atomic_with(path, |w| {
            writeln!(
                w,
                "seq,timestamp_us,raw_counts,force_n,status,host_arrival_us"
            )?;
            for (s, at) in &rows {
                writeln!(
                    w,
                    "{},{},{},{},{},{}",
                    s.seq, s.timestamp_us, s.raw_counts, s.force_n, s.status, at
                )?;
            }
            Ok(())
        })?;
        log::info!("wrote {} rows to {}", rows.len(), path.display());
    }
    Ok(())
}

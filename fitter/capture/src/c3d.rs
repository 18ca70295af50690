//! C3D marker trajectories (via `c3dio`), in metres, with missing samples kept as missing.

use super::c3d_parameters;
use std::path::{Path, PathBuf};

/// Errors of the capture import: each names the file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CaptureError {
    /// The file could not be read.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// The header is not a C3D header, or promises more data than the file holds.
    #[error("{path}: not a readable C3D file: {what}")]
    Header {
        /// The file.
        path: PathBuf,
        /// What is wrong, with the numbers.
        what: String,
    },
    /// The C3D parser refused the file.
    #[error("{path}: C3D parser: {what}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The parser's message.
        what: String,
    },
    /// `POINT:UNITS` is not a length unit palpate knows.
    #[error("{path}: POINT:UNITS is {found:?}, expected m, cm or mm (or the unit's name)")]
    Units {
        /// The file.
        path: PathBuf,
        /// What the file says.
        found: String,
    },
    /// A label asked for is not in the file.
    #[error("{path}: no marker labelled {label:?}; the file has {known:?}")]
    Label {
        /// The file.
        path: PathBuf,
        /// The label asked for.
        label: String,
        /// The file's labels.
        known: Vec<String>,
    },
}

/// Marker trajectories of one capture.
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    /// The file read.
    pub source: PathBuf,
    /// Marker labels, trimmed, in the file's order.
    pub labels: Vec<String>,
    /// Frames per second.
    pub rate_hz: f64,
    /// Number of the first frame in the capture software's numbering.
    pub first_frame: usize,
    /// `positions[frame][marker]` in metres; `None` where the sample is missing (the camera
    /// system lost the marker: a negative residual in C3D).
    pub positions: Vec<Vec<Option<[f64; 3]>>>,
}

/// A gap (the cameras lost the marker). C3D marks it by a negative fourth word — written as −1
/// (all bits set) by capture software — and usually zero coordinates. `c3dio` splits that word
/// into seven camera flags and a signed residual byte and drops the sign bit, so a gap reads as
/// every camera set with residual −1 (times the scale); a valid residual byte above 127 also reads
/// negative, which is why the sign alone is not the test.
fn is_gap(m: &c3dio::data::MarkerPoint, scale: f32) -> bool {
    let unit = if scale != 0.0 { scale.abs() } else { 1.0 };
    let all_cameras = m.cameras.iter().all(|c| *c);
    (all_cameras && (m.residual / unit).round() == -1.0) || m.point == [0.0; 3]
}

/// Bytes of one point sample in the data section: four values (x, y, z, residual/cameras).
const POINT_BYTES_FLOAT: usize = 16;
const POINT_BYTES_INTEGER: usize = 8;

/// Reads a C3D file's marker trajectories.
pub fn read_c3d(path: &Path) -> Result<Capture, CaptureError> {
    let bytes = std::fs::read(path).map_err(|source| CaptureError::Io {
        path: path.into(),
        source,
    })?;
    check_header(path, &bytes)?;
    // Empty parameters (a zero dimension), which `c3dio` refuses, left out of the section; where
    // the walk finds the section broken, the parser still decides, and the walk says where.
    let (bytes, walk) = match c3d_parameters::without_empty(&bytes) {
        Ok(Some((kept, _dropped))) => (kept, None),
        Ok(None) => (bytes, None),
        Err(where_) => (bytes, Some(where_)),
    };
    let located = |what: String| CaptureError::Parse {
        path: path.into(),
        what: match &walk {
            Some(w) => format!("{what}; the parameter section: {w}"),
            None => what,
        },
    };
    // The parser is a third-party crate: a file that passes the header check but trips it must
    // still be an error, not a crash of the whole program.
    let parsed =
        std::panic::catch_unwind(|| c3dio::C3d::from_bytes(&bytes).map_err(|e| format!("{e:?}")))
            .map_err(|_| {
            located("the parser failed on this file (malformed parameter or data section)".into())
        })?;
    let c3d = parsed.map_err(located)?;
    let p = &c3d.points;
    let units: String = p.units.iter().collect::<String>().trim().to_lowercase();
    let Some(scale) = metres_per_unit(&units) else {
        return Err(CaptureError::Units {
            path: path.into(),
            found: units,
        });
    };
    let (frames, markers) = p.points.size();
    let labels: Vec<String> = (0..markers)
        .map(|k| {
            p.labels
                .get(k)
                .map_or_else(|| format!("marker {}", k + 1), |s| s.trim().to_string())
        })
        .collect();
    let mut positions = Vec::with_capacity(frames);
    for f in 0..frames {
        let mut row = Vec::with_capacity(markers);
        for k in 0..markers {
            let m = &p.points[(f, k)];
            let ok = !is_gap(m, p.scale_factor) && m.point.iter().all(|v| v.is_finite());
            row.push(ok.then(|| m.point.map(|v| f64::from(v) * scale)));
        }
        positions.push(row);
    }
    if !(p.frame_rate.is_finite() && p.frame_rate > 0.0) {
        return Err(CaptureError::Header {
            path: path.into(),
            what: format!("point frame rate {} is not a positive number", p.frame_rate),
        });
    }
    Ok(Capture {
        source: path.into(),
        labels,
        rate_hz: f64::from(p.frame_rate),
        first_frame: usize::from(p.first_frame),
        positions,
    })
}

/// Metres per unit of `POINT:UNITS` (trimmed, lower case): the standard's abbreviations, the
/// words some exporters write instead, and millimetres where the parameter is empty (the
/// standard's default).
fn metres_per_unit(units: &str) -> Option<f64> {
    Some(match units {
        "m" | "meter" | "meters" | "metre" | "metres" => 1.0,
        "cm" | "centimeter" | "centimeters" | "centimetre" | "centimetres" => 1e-2,
        "mm" | "millimeter" | "millimeters" | "millimetre" | "millimetres" | "" => 1e-3,
        _ => return None,
    })
}

/// The header promises `frames × markers` samples; the data section must be able to hold them,
/// so a corrupt or truncated file is refused before the parser sizes anything from it.
fn check_header(path: &Path, b: &[u8]) -> Result<(), CaptureError> {
    let bad = |what: String| CaptureError::Header {
        path: path.into(),
        what,
    };
    if b.len() < 512 {
        return Err(bad(format!(
            "{} bytes, shorter than the 512-byte header",
            b.len()
        )));
    }
    if b[1] != 0x50 {
        return Err(bad(format!(
            "byte 2 is {:#04x}, expected the C3D key 0x50",
            b[1]
        )));
    }
    // Block 1 is this header, so the parameter section starts at block 2 or later; `c3dio`
    // indexes `512 * (block - 1)` without checking, and a zero here wraps below zero.
    let param_block = usize::from(b[0]);
    let blocks = b.len().div_ceil(512);
    if param_block < 2 || param_block > blocks {
        return Err(bad(format!(
            "byte 1 (parameter section start) is block {param_block}, expected 2..={blocks} \
             (block 1 is the header; the file has {blocks} blocks)"
        )));
    }
    let param = (param_block - 1) * 512;
    // Processor type (parameter block byte 4): 84 Intel, 85 DEC (both little-endian u16), 86 MIPS.
    let processor = b.get(param + 3).copied().unwrap_or(0);
    if !(84..=86).contains(&processor) {
        return Err(bad(format!(
            "parameter block byte 4 (processor type) is {processor}, expected 84 (Intel), \
             85 (DEC) or 86 (MIPS)"
        )));
    }
    let big_endian = processor == 86;
    let u16_at = |i: usize| {
        let w = [b[i], b[i + 1]];
        if big_endian {
            u16::from_be_bytes(w)
        } else {
            u16::from_le_bytes(w)
        }
    };
    let (markers, first, last) = (u16_at(2), u16_at(6), u16_at(8));
    // The data section follows the parameter section; the parser slices the parameters as
    // blocks 2..data_start and the points from data_start on, without checking either.
    let data_block = usize::from(u16_at(16));
    if data_block <= param_block || data_block > blocks {
        return Err(bad(format!(
            "bytes 17-18 (data section start) say block {data_block}, expected {}..={blocks} \
             (after the parameter section at block {param_block}; the file has {blocks} blocks)",
            param_block + 1
        )));
    }
    if last < first {
        return Err(bad(format!("last frame {last} before first frame {first}")));
    }
    let frames = usize::from(last - first) + 1;
    let per_point = if float_points([b[12], b[13], b[14], b[15]], processor) {
        POINT_BYTES_FLOAT
    } else {
        POINT_BYTES_INTEGER
    };
    let need = frames * usize::from(markers) * per_point;
    if need > b.len() - (data_block - 1) * 512 {
        return Err(bad(format!(
            "the header promises {frames} frames of {markers} markers ({need} bytes of points), \
             but the file has {} bytes (truncated?)",
            b.len()
        )));
    }
    Ok(())
}

/// Whether the header's point scale (bytes 13–16), in the file's processor format, is zero or
/// negative: the points are then stored as floats, otherwise as scaled integers. Intel writes an
/// IEEE float little-endian, MIPS big-endian, DEC its F-float: two little-endian 16-bit halves,
/// the first holding the sign (its bit 15) and the exponent (bits 14–7; 0 is zero), so the sign
/// is in the second byte, where an IEEE little-endian read finds a fraction bit.
fn float_points(w: [u8; 4], processor: u8) -> bool {
    match processor {
        85 => w[1] & 0x80 != 0 || (u16::from(w[1] & 0x7f) << 1 | u16::from(w[0] >> 7)) == 0,
        86 => f32::from_be_bytes(w) <= 0.0,
        _ => f32::from_le_bytes(w) <= 0.0,
    }
}

impl Capture {
    /// The index of marker `label`.
    ///
    /// A label the file does not hold is also found under one subject's prefix: Vicon Nexus
    /// labels each marker `Subject:Marker`, and a places file written for the object says
    /// `Marker`. Only a single such match counts; two subjects with the marker are an error.
    pub fn marker(&self, label: &str) -> Result<usize, CaptureError> {
        if let Some(k) = self.labels.iter().position(|l| l == label) {
            return Ok(k);
        }
        let mut prefixed = self
            .labels
            .iter()
            .enumerate()
            .filter(|(_, l)| l.rsplit_once(':').is_some_and(|(_, m)| m == label));
        match (prefixed.next(), prefixed.next()) {
            (Some((k, _)), None) => Ok(k),
            _ => Err(CaptureError::Label {
                path: self.source.clone(),
                label: label.into(),
                known: self.labels.clone(),
            }),
        }
    }

    /// Seconds from the first frame to frame `f`.
    pub fn time(&self, f: usize) -> f64 {
        f as f64 / self.rate_hz
    }

    /// The first frame at which `markers`, averaged, have moved more than `threshold` (m) from
    /// where each was first seen (the release of a held object); `None` if nothing moves that
    /// far. At each frame the average is over the markers seen there: a marker the cameras lost
    /// in frame 0, or in every frame, leaves the others to tell the release.
    pub fn release_frame(&self, markers: &[usize], threshold: f64) -> Option<usize> {
        let first_seen: Vec<Option<[f64; 3]>> = markers
            .iter()
            .map(|&k| {
                self.positions
                    .iter()
                    .find_map(|row| row.get(k).copied().flatten())
            })
            .collect();
        // The mean position of the markers seen at frame f, and the mean of where those same
        // markers were first seen.
        let means = |f: usize| -> Option<([f64; 3], [f64; 3])> {
            let row = self.positions.get(f)?;
            let seen: Vec<([f64; 3], [f64; 3])> = markers
                .iter()
                .zip(&first_seen)
                .filter_map(|(&k, start)| Some(((*row.get(k)?)?, (*start)?)))
                .collect();
            if seen.is_empty() {
                return None;
            }
            let n = seen.len() as f64;
            let (mut now, mut start) = ([0.0; 3], [0.0; 3]);
            for (p, q) in &seen {
                for d in 0..3 {
                    now[d] += p[d] / n;
                    start[d] += q[d] / n;
                }
            }
            Some((now, start))
        };
        (1..self.positions.len()).find(|&f| {
            means(f).is_some_and(|(p, q)| {
                ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
                    > threshold
            })
        })
    }

    /// The first frame up to `before` in which every one of `markers` is seen: where a
    /// registration can use them all.
    pub fn first_frame_seeing_all(&self, markers: &[usize], before: usize) -> Option<usize> {
        (0..=before.min(self.positions.len().saturating_sub(1))).find(|&f| {
            markers
                .iter()
                .all(|&k| self.positions[f].get(k).is_some_and(Option::is_some))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn beam_with(patch: &[(usize, u8)]) -> Vec<u8> {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../models/silicone-beam/beam_gravity_V2_a.c3d");
        let mut b = std::fs::read(path).unwrap();
        for &(i, v) in patch {
            b[i] = v;
        }
        b
    }

    fn header_error(b: &[u8]) -> String {
        match check_header(Path::new("x.c3d"), b) {
            Err(CaptureError::Header { what, .. }) => what,
            other => panic!("expected a header error, got {other:?}"),
        }
    }

    /// Byte 1 = 0 made the parser index 512 × (0 − 1), a wrapped index and a panic.
    #[test]
    fn parameter_block_zero_is_a_header_error() {
        assert!(check_header(Path::new("x.c3d"), &beam_with(&[])).is_ok());
        let what = header_error(&beam_with(&[(0, 0)]));
        assert!(what.contains("parameter section start"), "{what}");
        let what = header_error(&beam_with(&[(0, 255)]));
        assert!(what.contains("block 255"), "{what}");
    }

    /// A zero data-start word made the parser slice the parameters up to 512 × (0 − 1).
    #[test]
    fn data_block_zero_or_past_the_end_is_a_header_error() {
        let what = header_error(&beam_with(&[(16, 0), (17, 0)]));
        assert!(what.contains("data section start"), "{what}");
        let what = header_error(&beam_with(&[(16, 0xff), (17, 0xff)]));
        assert!(what.contains("block 65535"), "{what}");
    }

    /// A DEC file's scale is a DEC F-float: its sign is in byte 14, not byte 16. An integer
    /// file (8 bytes a point) whose scale's byte 16 has its top bit set was read as a float
    /// file needing twice its data, and refused as truncated.
    #[test]
    fn a_dec_files_scale_is_read_as_dec_writes_it() {
        let b = beam_with(&[]);
        let data = (usize::from(u16::from_le_bytes([b[16], b[17]])) - 1) * 512;
        let points = usize::from(u16::from_le_bytes([b[2], b[3]]))
            * (usize::from(u16::from_le_bytes([b[8], b[9]]))
                - usize::from(u16::from_le_bytes([b[6], b[7]]))
                + 1);
        // DEC, scale +0.0025 as DEC writes it ([0x23, 0x3c, 0x0a, 0xd7]: exponent 120, positive),
        // the data section just long enough for 8-byte points.
        let mut dec = beam_with(&[
            (512 + 3, 85),
            (12, 0x23),
            (13, 0x3c),
            (14, 0x0a),
            (15, 0xd7),
        ]);
        dec.truncate(data + points * POINT_BYTES_INTEGER);
        assert!(!float_points([0x23, 0x3c, 0x0a, 0xd7], 85));
        assert!(
            float_points([0x23, 0x3c, 0x0a, 0xd7], 84),
            "read as IEEE: negative"
        );
        check_header(Path::new("x.c3d"), &dec).unwrap();
        // The same scale negative (float points, 16 bytes each) does not fit: truncated.
        dec[13] |= 0x80;
        let what = header_error(&dec);
        assert!(what.contains("truncated"), "{what}");
        assert!(float_points([0, 0, 0, 0], 85), "DEC zero");
    }

    #[test]
    fn point_units_are_read_as_abbreviations_or_words() {
        assert_eq!(metres_per_unit("mm"), Some(1e-3));
        assert_eq!(metres_per_unit("millimetres"), Some(1e-3));
        assert_eq!(metres_per_unit(""), Some(1e-3));
        assert_eq!(metres_per_unit("meters"), Some(1.0));
        assert_eq!(metres_per_unit("cm"), Some(1e-2));
        assert_eq!(metres_per_unit("in"), None);
    }

    #[test]
    fn unknown_processor_is_a_header_error() {
        let what = header_error(&beam_with(&[(512 + 3, 0)]));
        assert!(what.contains("processor type"), "{what}");
    }
}

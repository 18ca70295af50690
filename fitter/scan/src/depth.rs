//! Depth images: one depth (m) per pixel, row by row from the top left, 0 where the sensor saw
//! nothing. On disk a 16-bit greyscale PNG, or a 16-bit binary PGM (Netpbm P5, what OpenNI and
//! Kinect tools save), whose integer unit is the sensor's (1 mm for a RealSense or an Azure
//! Kinect by default, 0.1 mm or finer for a structured-light scanner), declared by the caller:
//! the file itself does not say it.

use std::path::Path;

use crate::ScanError;

/// A depth image.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Depth per pixel (m), row-major; 0 where there is none.
    pub depth: Vec<f64>,
}

/// A depth unit must be a positive number of metres.
fn check_unit(path: &Path, metres_per_unit: f64) -> Result<(), ScanError> {
    if metres_per_unit.is_finite() && metres_per_unit > 0.0 {
        Ok(())
    } else {
        Err(ScanError::Invalid(format!(
            "{}: the depth unit must be a positive number of metres, found {metres_per_unit}",
            path.display()
        )))
    }
}

impl DepthImage {
    /// An image of `width` × `height` pixels with no depth anywhere.
    pub fn empty(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            depth: vec![0.0; width * height],
        }
    }

    /// Pixels with a depth.
    pub fn valid(&self) -> usize {
        self.depth.iter().filter(|z| **z > 0.0).count()
    }

    /// Reads a 16-bit depth image, PNG or binary PGM by its first bytes, whose integer unit is
    /// `metres_per_unit` (0.001 for millimetres); 0 stays "no depth".
    pub fn read(path: &Path, metres_per_unit: f64) -> Result<Self, ScanError> {
        let mut head = [0u8; 2];
        let n = std::fs::File::open(path)
            .and_then(|mut f| std::io::Read::read(&mut f, &mut head))
            .map_err(|e| ScanError::io(path, e))?;
        if head[..n] == *b"P5" {
            Self::read_pgm(path, metres_per_unit)
        } else {
            Self::read_png(path, metres_per_unit)
        }
    }

    /// Reads a 16-bit binary PGM (Netpbm P5: a text header "P5 width height maxval", `#`
    /// comments allowed, then one big-endian 16-bit sample a pixel) whose integer unit is
    /// `metres_per_unit`; 0 stays "no depth". A maxval below 256 (one byte a sample) is a grey
    /// picture, not a depth image, and is refused as an 8-bit PNG is.
    pub fn read_pgm(path: &Path, metres_per_unit: f64) -> Result<Self, ScanError> {
        check_unit(path, metres_per_unit)?;
        let bytes = std::fs::read(path).map_err(|e| ScanError::io(path, e))?;
        let bad = |what: String| ScanError::format(path, format!("not a readable PGM: {what}"));
        // The header: the magic and three numbers, separated by whitespace and comments, then
        // one whitespace byte before the samples.
        let mut at = 0;
        let mut fields = Vec::with_capacity(4);
        while fields.len() < 4 {
            while at < bytes.len() && (bytes[at].is_ascii_whitespace() || bytes[at] == b'#') {
                if bytes[at] == b'#' {
                    while at < bytes.len() && bytes[at] != b'\n' {
                        at += 1;
                    }
                } else {
                    at += 1;
                }
            }
            let start = at;
            while at < bytes.len() && !bytes[at].is_ascii_whitespace() {
                at += 1;
            }
            if start == at {
                return Err(bad(
                    "the header ends before its width, height and maxval".into()
                ));
            }
            fields.push(String::from_utf8_lossy(&bytes[start..at]).into_owned());
        }
        at += 1;
        if fields[0] != "P5" {
            return Err(bad(format!(
                "magic {:?}, expected P5 (binary greymap)",
                fields[0]
            )));
        }
        let number = |i: usize, what: &str| -> Result<usize, ScanError> {
            fields[i]
                .parse::<usize>()
                .map_err(|_| bad(format!("{what} {:?} is not a whole number", fields[i])))
        };
        let (width, height, maxval) = (
            number(1, "width")?,
            number(2, "height")?,
            number(3, "maxval")?,
        );
        if !(256..=65_535).contains(&maxval) {
            return Err(ScanError::format(
                path,
                format!(
                    "a depth image must be 16-bit greyscale, found a PGM with maxval {maxval} \
                     (256..=65535 is 16-bit)"
                ),
            ));
        }
        let need = width
            .checked_mul(height)
            .and_then(|p| p.checked_mul(2))
            .ok_or_else(|| bad(format!("{width} × {height} pixels overflow")))?;
        let data = bytes.get(at..).unwrap_or(&[]);
        if data.len() < need {
            return Err(bad(format!(
                "{width} × {height} pixels of 2 bytes need {need} bytes after the header, the file \
                 has {}",
                data.len()
            )));
        }
        let depth = data[..need]
            .chunks_exact(2)
            .map(|b| f64::from(u16::from_be_bytes([b[0], b[1]])) * metres_per_unit)
            .collect();
        Ok(Self {
            width,
            height,
            depth,
        })
    }

    /// Reads a 16-bit greyscale PNG whose integer unit is `metres_per_unit` (0.001 for
    /// millimetres); 0 stays "no depth".
    pub fn read_png(path: &Path, metres_per_unit: f64) -> Result<Self, ScanError> {
        check_unit(path, metres_per_unit)?;
        let file = std::fs::File::open(path).map_err(|e| ScanError::io(path, e))?;
        let decoder = png::Decoder::new(std::io::BufReader::new(file));
        let mut reader = decoder
            .read_info()
            .map_err(|e| ScanError::format(path, format!("not a readable PNG: {e}")))?;
        let info = reader.info();
        let (width, height) = (info.width as usize, info.height as usize);
        if info.color_type != png::ColorType::Grayscale || info.bit_depth != png::BitDepth::Sixteen
        {
            return Err(ScanError::format(
                path,
                format!(
                    "a depth image must be 16-bit greyscale, found {:?} at {} bits",
                    info.color_type, info.bit_depth as u8
                ),
            ));
        }
        let mut buf = vec![0; reader.output_buffer_size()];
        let frame = reader
            .next_frame(&mut buf)
            .map_err(|e| ScanError::format(path, format!("PNG data: {e}")))?;
        let bytes = &buf[..frame.buffer_size()];
        // PNG stores 16-bit samples big-endian.
        let depth = bytes
            .chunks_exact(2)
            .map(|b| f64::from(u16::from_be_bytes([b[0], b[1]])) * metres_per_unit)
            .collect::<Vec<_>>();
        if depth.len() != width * height {
            return Err(ScanError::format(
                path,
                format!(
                    "{width} × {height} pixels declared, {} samples found",
                    depth.len()
                ),
            ));
        }
        Ok(Self {
            width,
            height,
            depth,
        })
    }

    /// Writes the image as a 16-bit greyscale PNG in units of `metres_per_unit`, each depth
    /// rounded to the nearest unit; a depth beyond 65,535 units is refused, not clipped.
    pub fn write_png(&self, path: &Path, metres_per_unit: f64) -> Result<(), ScanError> {
        let mut data = Vec::with_capacity(2 * self.depth.len());
        for (i, z) in self.depth.iter().enumerate() {
            let units = if *z > 0.0 {
                (z / metres_per_unit).round()
            } else {
                0.0
            };
            if !(0.0..=f64::from(u16::MAX)).contains(&units) {
                return Err(ScanError::Invalid(format!(
                    "{}: pixel ({}, {}) has depth {z} m, beyond 16 bits of {metres_per_unit} m",
                    path.display(),
                    i % self.width,
                    i / self.width
                )));
            }
            data.extend_from_slice(&(units as u16).to_be_bytes());
        }
        let file = std::fs::File::create(path).map_err(|e| ScanError::io(path, e))?;
        let mut enc = png::Encoder::new(
            std::io::BufWriter::new(file),
            self.width as u32,
            self.height as u32,
        );
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let fail = |e: png::EncodingError| ScanError::format(path, format!("writing PNG: {e}"));
        let mut w = enc.write_header().map_err(fail)?;
        w.write_image_data(&data).map_err(fail)?;
        w.finish().map_err(fail)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Written and read back at 0.1 mm: every depth within half a unit, "no depth" kept.
    #[test]
    fn a_depth_image_survives_its_png() {
        let mut img = DepthImage::empty(7, 5);
        for (i, z) in img.depth.iter_mut().enumerate() {
            *z = if i % 4 == 0 {
                0.0
            } else {
                0.3 + 1e-3 * i as f64 + 1.7e-5
            };
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("d.png");
        img.write_png(&p, 1e-4).unwrap();
        let back = DepthImage::read_png(&p, 1e-4).unwrap();
        assert_eq!((back.width, back.height), (7, 5));
        for (a, b) in img.depth.iter().zip(&back.depth) {
            assert!((a - b).abs() <= 0.5e-4 + 1e-12, "{a} {b}");
            assert_eq!(*a == 0.0, *b == 0.0);
        }
    }

    /// A 16-bit binary PGM as OpenNI tools write it (a comment in the header), read by its first
    /// bytes, the same depths as the PNG of the same samples; an 8-bit PGM and a truncated one
    /// are refused by name.
    #[test]
    fn a_sixteen_bit_pgm_reads_as_its_png() {
        let samples: [u16; 6] = [0, 1000, 65_535, 2, 300, 0];
        let dir = tempfile::tempdir().unwrap();
        let mut pgm = b"P5\n# depth in 0.1 mm\n3 2\n65535\n".to_vec();
        for s in samples {
            pgm.extend(s.to_be_bytes());
        }
        let p = dir.path().join("d.pgm");
        std::fs::write(&p, &pgm).unwrap();
        let img = DepthImage::read(&p, 1e-4).unwrap();
        assert_eq!((img.width, img.height), (3, 2));
        let want: Vec<f64> = samples.iter().map(|&s| f64::from(s) * 1e-4).collect();
        assert_eq!(img.depth, want);
        let png = dir.path().join("d.png");
        img.write_png(&png, 1e-4).unwrap();
        assert_eq!(DepthImage::read(&png, 1e-4).unwrap(), img);
        let cut = dir.path().join("cut.pgm");
        std::fs::write(&cut, &pgm[..pgm.len() - 1]).unwrap();
        let e = DepthImage::read(&cut, 1e-4).unwrap_err().to_string();
        assert!(e.contains("cut.pgm") && e.contains("12 bytes"), "{e}");
        let grey = dir.path().join("grey.pgm");
        std::fs::write(&grey, b"P5 3 2 255\n\0\0\0\0\0\0").unwrap();
        let e = DepthImage::read(&grey, 1e-4).unwrap_err().to_string();
        assert!(
            e.contains("16-bit greyscale") && e.contains("maxval 255"),
            "{e}"
        );
    }

    /// An 8-bit image is a colour picture, not a depth image: refused by name.
    #[test]
    fn an_eight_bit_png_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("rgb.png");
        let f = std::fs::File::create(&p).unwrap();
        let mut enc = png::Encoder::new(f, 2, 2);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .unwrap()
            .write_image_data(&[0; 12])
            .unwrap();
        let e = DepthImage::read_png(&p, 1e-3).unwrap_err().to_string();
        assert!(
            e.contains("rgb.png") && e.contains("16-bit greyscale"),
            "{e}"
        );
    }
}

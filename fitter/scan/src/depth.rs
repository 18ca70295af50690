//! Depth images: one depth (m) per pixel, row by row from the top left, 0 where the sensor saw
//! nothing. On disk a 16-bit greyscale PNG whose integer unit is the sensor's (1 mm for a
//! RealSense or an Azure Kinect by default, 0.1 mm or finer for a structured-light scanner),
//! declared by the caller: the file itself does not say it.

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

    /// Reads a 16-bit greyscale PNG whose integer unit is `metres_per_unit` (0.001 for
    /// millimetres); 0 stays "no depth".
    pub fn read_png(path: &Path, metres_per_unit: f64) -> Result<Self, ScanError> {
        if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
            return Err(ScanError::Invalid(format!(
                "{}: the depth unit must be a positive number of metres, found {metres_per_unit}",
                path.display()
            )));
        }
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

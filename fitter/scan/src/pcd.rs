//! Point clouds in PCL's PCD format (Point Cloud Library, "The PCD (Point Cloud Data) file
//! format", v0.7), what ROS and PCL tools save from a depth camera: a text header (`FIELDS`,
//! `SIZE`, `TYPE`, `COUNT`, `WIDTH`, `HEIGHT`, `POINTS`, `DATA`), then the points as ASCII lines
//! or as packed little-endian records. The `x`, `y`, `z` fields are read and any others
//! skipped; a point whose coordinates are not finite (an organised cloud's pixel with no depth,
//! written as NaN) is no point. `binary_compressed` (LZF) is refused with the command that
//! re-saves the file.

use nalgebra::Vector3;
use std::path::Path;

use crate::cloud::Scalar;
use crate::ScanError;

/// One field of a PCD record: its name, size in bytes, type letter (I, U, F) and element count.
#[derive(Debug, Clone, PartialEq)]
struct Field {
    name: String,
    size: usize,
    kind: char,
    count: usize,
}

/// The points of a PCD file; errors name the file and the header line or point.
pub(crate) fn read_pcd(path: &Path, bytes: &[u8]) -> Result<Vec<Vector3<f64>>, ScanError> {
    let bad = |what: String| ScanError::format(path, what);
    let mut at = 0;
    let mut line_no = 0;
    let mut keys: Vec<(String, Vec<String>)> = Vec::new();
    let data = loop {
        let Some(len) = bytes[at..].iter().position(|&b| b == b'\n') else {
            return Err(bad("the PCD header has no DATA line".into()));
        };
        line_no += 1;
        let line = String::from_utf8_lossy(&bytes[at..at + len])
            .trim()
            .to_string();
        at += len + 1;
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut words = line.split_whitespace().map(str::to_string);
        let key = words.next().unwrap_or_default().to_ascii_uppercase();
        let values: Vec<String> = words.collect();
        if key == "DATA" {
            break values.first().cloned().unwrap_or_default();
        }
        keys.push((key, values));
    };
    let get = |key: &str| -> Result<&Vec<String>, ScanError> {
        keys.iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v)
            .ok_or_else(|| bad(format!("the PCD header has no {key} line")))
    };
    let numbers = |key: &str| -> Result<Vec<usize>, ScanError> {
        get(key)?
            .iter()
            .map(|v| {
                v.parse()
                    .map_err(|_| bad(format!("PCD {key}: {v:?} is not a whole number")))
            })
            .collect()
    };
    let names = get("FIELDS")?.clone();
    let sizes = numbers("SIZE")?;
    let kinds: Vec<char> = get("TYPE")?
        .iter()
        .map(|t| t.chars().next().unwrap_or(' ').to_ascii_uppercase())
        .collect();
    // COUNT may be absent: one element per field.
    let counts = match keys.iter().any(|(k, _)| k == "COUNT") {
        true => numbers("COUNT")?,
        false => vec![1; names.len()],
    };
    if sizes.len() != names.len() || kinds.len() != names.len() || counts.len() != names.len() {
        return Err(bad(format!(
            "PCD header: {} FIELDS, {} SIZE, {} TYPE and {} COUNT values; they must match",
            names.len(),
            sizes.len(),
            kinds.len(),
            counts.len()
        )));
    }
    let fields: Vec<Field> = (0..names.len())
        .map(|i| Field {
            name: names[i].clone(),
            size: sizes[i],
            kind: kinds[i],
            count: counts[i],
        })
        .collect();
    let points = match keys.iter().any(|(k, _)| k == "POINTS") {
        true => numbers("POINTS")?.first().copied().unwrap_or(0),
        false => {
            let (w, h) = (numbers("WIDTH")?, numbers("HEIGHT")?);
            w.first().copied().unwrap_or(0) * h.first().copied().unwrap_or(1)
        }
    };
    // Where x, y and z sit: their field, and their element's index among all elements.
    let mut place = Vec::with_capacity(3);
    for axis in ["x", "y", "z"] {
        let Some(i) = fields.iter().position(|f| f.name == axis) else {
            return Err(bad(format!(
                "the PCD fields {names:?} have no {axis:?}: a point cloud needs x, y and z"
            )));
        };
        let before: usize = fields[..i].iter().map(|f| f.count).sum();
        let offset: usize = fields[..i].iter().map(|f| f.size * f.count).sum();
        place.push((i, before, offset));
    }
    let finite = |p: [f64; 3]| p.iter().all(|v| v.is_finite());
    let mut out = Vec::with_capacity(points.min(1 << 20));
    match data.as_str() {
        "ascii" => {
            let text = String::from_utf8_lossy(&bytes[at..]);
            let elements: usize = fields.iter().map(|f| f.count).sum();
            let mut read = 0;
            for (k, line) in text.lines().enumerate() {
                let words: Vec<&str> = line.split_whitespace().collect();
                if words.is_empty() {
                    continue;
                }
                if words.len() != elements {
                    return Err(bad(format!(
                        "PCD line {}: {} values, the fields hold {elements}",
                        line_no + k + 1,
                        words.len()
                    )));
                }
                let mut p = [0.0; 3];
                for (d, &(_, before, _)) in place.iter().enumerate() {
                    p[d] = words[before].parse().map_err(|_| {
                        bad(format!(
                            "PCD line {}: {:?} is not a number",
                            line_no + k + 1,
                            words[before]
                        ))
                    })?;
                }
                if finite(p) {
                    out.push(Vector3::from(p));
                }
                read += 1;
            }
            if read != points {
                return Err(bad(format!(
                    "the PCD header promises {points} points, the file holds {read}"
                )));
            }
        }
        "binary" => {
            let record: usize = fields.iter().map(|f| f.size * f.count).sum();
            let need = points.saturating_mul(record);
            let body = &bytes[at..];
            if body.len() < need {
                return Err(bad(format!(
                    "the PCD header promises {points} points of {record} bytes ({need} bytes), \
                     the file holds {} after its header (truncated?)",
                    body.len()
                )));
            }
            for r in body[..need].chunks_exact(record.max(1)) {
                let mut p = [0.0; 3];
                for (d, &(i, _, offset)) in place.iter().enumerate() {
                    let f = &fields[i];
                    let scalar = Scalar::of_pcd(f.kind, f.size).ok_or_else(|| {
                        bad(format!(
                            "PCD field {:?}: type {}{} is not a number type PCD defines",
                            f.name, f.kind, f.size
                        ))
                    })?;
                    // PCD's binary records are little-endian.
                    p[d] = scalar.decode(&r[offset..offset + f.size], true);
                }
                if finite(p) {
                    out.push(Vector3::from(p));
                }
            }
        }
        "binary_compressed" => {
            return Err(bad(
                "PCD DATA binary_compressed (LZF) is not read; re-save it as binary or ascii \
                 (`pcl_convert_pcd_ascii_binary in.pcd out.pcd 1`)"
                    .into(),
            ))
        }
        other => {
            return Err(bad(format!(
                "PCD DATA {other:?}, expected ascii, binary or binary_compressed"
            )))
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEAD: &str =
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\n\
                        SIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 3\nHEIGHT 1\n\
                        VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\n";

    #[test]
    fn ascii_and_binary_read_the_same_points_and_skip_nan() {
        let ascii = format!("{HEAD}DATA ascii\n1 2 3 4278190080\nnan nan nan 0\n-0.5 0.25 7 1\n");
        let p = Path::new("t.pcd");
        let a = read_pcd(p, ascii.as_bytes()).unwrap();
        assert_eq!(
            a,
            [Vector3::new(1.0, 2.0, 3.0), Vector3::new(-0.5, 0.25, 7.0)]
        );
        let mut binary = format!("{HEAD}DATA binary\n").into_bytes();
        for (x, y, z, rgb) in [
            (1f32, 2f32, 3f32, 7u32),
            (f32::NAN, f32::NAN, f32::NAN, 0),
            (-0.5, 0.25, 7.0, 1),
        ] {
            for v in [x, y, z] {
                binary.extend(v.to_le_bytes());
            }
            binary.extend(rgb.to_le_bytes());
        }
        assert_eq!(read_pcd(p, &binary).unwrap(), a);
        let e = read_pcd(p, &binary[..binary.len() - 1])
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.pcd") && e.contains("truncated"), "{e}");
    }

    #[test]
    fn what_cannot_be_read_is_named() {
        let p = Path::new("t.pcd");
        let e = read_pcd(p, format!("{HEAD}DATA binary_compressed\n").as_bytes())
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("binary_compressed") && e.contains("re-save"),
            "{e}"
        );
        let no_z = HEAD.replace("FIELDS x y z rgb", "FIELDS x y w rgb");
        let e = read_pcd(p, format!("{no_z}DATA ascii\n").as_bytes())
            .unwrap_err()
            .to_string();
        assert!(e.contains("no \"z\""), "{e}");
        let e = read_pcd(p, format!("{HEAD}DATA ascii\n1 2 3\n").as_bytes())
            .unwrap_err()
            .to_string();
        assert!(e.contains("3 values, the fields hold 4"), "{e}");
    }
}

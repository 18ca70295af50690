//! Point clouds from scanners: PLY (ASCII, binary little- and big-endian; the `vertex`
//! element's `x`, `y`, `z`, any other properties and elements skipped), PCL's PCD (`pcd`) and
//! XYZ/CSV text (three numbers per line, separated by commas or white space, a header line
//! allowed). Points are in metres in the frame the file declares; bringing them into the mesh's
//! frame is the caller's.

use std::path::Path;

use nalgebra::Vector3;

use crate::ScanError;

/// Reads the points of a PLY, PCD, XYZ, CSV or TXT file, chosen by its extension.
pub fn read_points(path: &Path) -> Result<Vec<Vector3<f64>>, ScanError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let bytes = std::fs::read(path).map_err(|e| ScanError::io(path, e))?;
    match ext.as_str() {
        "ply" => Ok(read_ply(path, &bytes, None)?.0),
        "pcd" => crate::pcd::read_pcd(path, &bytes),
        "xyz" | "csv" | "txt" => read_text(path, &bytes),
        _ => Err(ScanError::format(
            path,
            format!("a point cloud is .ply, .pcd, .xyz, .csv or .txt, found extension \"{ext}\""),
        )),
    }
}

/// A number type of a PLY property or a PCD field, and its size in bytes. The 64-bit integers
/// are PCD's only (`TYPE I`/`U`, `SIZE 8`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    /// A PCD field's type: its `TYPE` letter (I, U, F) and `SIZE` in bytes.
    pub(crate) fn of_pcd(kind: char, size: usize) -> Option<Self> {
        Some(match (kind, size) {
            ('I', 1) => Self::I8,
            ('U', 1) => Self::U8,
            ('I', 2) => Self::I16,
            ('U', 2) => Self::U16,
            ('I', 4) => Self::I32,
            ('U', 4) => Self::U32,
            ('I', 8) => Self::I64,
            ('U', 8) => Self::U64,
            ('F', 4) => Self::F32,
            ('F', 8) => Self::F64,
            _ => return None,
        })
    }

    pub(crate) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 | Self::U64 | Self::F64 => 8,
        }
    }

    /// The value of `b` (exactly `size()` bytes).
    pub(crate) fn decode(self, b: &[u8], little: bool) -> f64 {
        macro_rules! num {
            ($t:ty) => {{
                let a = b.try_into().expect("sized by the caller");
                (if little {
                    <$t>::from_le_bytes(a)
                } else {
                    <$t>::from_be_bytes(a)
                }) as f64
            }};
        }
        match self {
            Self::I8 => num!(i8),
            Self::U8 => num!(u8),
            Self::I16 => num!(i16),
            Self::U16 => num!(u16),
            Self::I32 => num!(i32),
            Self::U32 => num!(u32),
            Self::I64 => num!(i64),
            Self::U64 => num!(u64),
            Self::F32 => num!(f32),
            Self::F64 => num!(f64),
        }
    }
}

/// A property: a scalar, or a list with its count's type and its items' type.
#[derive(Debug, Clone, PartialEq)]
struct Property {
    name: String,
    count: Option<Scalar>,
    item: Scalar,
}

#[derive(Debug, Clone, PartialEq)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Binary { little: bool },
}

/// Adds `p` to the element the header declared last (a property belongs to the element line
/// above it); an error when no element came before it.
fn add_property(elements: &mut [Element], p: Property) -> Result<(), String> {
    elements
        .last_mut()
        .ok_or_else(|| "a property before any element".to_string())?
        .properties
        .push(p);
    Ok(())
}

/// The header: encoding, elements, and the byte offset where the data start.
fn ply_header(path: &Path, bytes: &[u8]) -> Result<(Encoding, Vec<Element>, usize), ScanError> {
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut at = 0;
    let mut line_no = 0;
    loop {
        let Some(len) = bytes[at..].iter().position(|b| *b == b'\n') else {
            return Err(ScanError::format(
                path,
                "the PLY header has no end_header line",
            ));
        };
        line_no += 1;
        let line = std::str::from_utf8(&bytes[at..at + len])
            .map_err(|_| ScanError::format(path, format!("line {line_no}: header is not text")))?
            .trim_end_matches('\r')
            .trim();
        at += len + 1;
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = |what: String| ScanError::format(path, format!("line {line_no}: {what}"));
        match words.as_slice() {
            ["ply"] if line_no == 1 => {}
            _ if line_no == 1 => {
                return Err(bad(format!(
                    "a PLY file starts with \"ply\", found \"{line}\""
                )))
            }
            ["format", f, "1.0"] => {
                encoding = Some(match *f {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Binary { little: true },
                    "binary_big_endian" => Encoding::Binary { little: false },
                    other => return Err(bad(format!("unknown PLY format \"{other}\""))),
                })
            }
            ["comment", ..] | ["obj_info", ..] | [] => {}
            ["element", name, n] => elements.push(Element {
                name: (*name).into(),
                count: n
                    .parse()
                    .map_err(|_| bad(format!("element {name}: count \"{n}\" is not a number")))?,
                properties: Vec::new(),
            }),
            ["property", "list", c, i, name] => {
                let (Some(count), Some(item)) = (Scalar::parse(c), Scalar::parse(i)) else {
                    return Err(bad(format!(
                        "property list {name}: unknown types \"{c} {i}\""
                    )));
                };
                let p = Property {
                    name: (*name).into(),
                    count: Some(count),
                    item,
                };
                add_property(&mut elements, p).map_err(bad)?;
            }
            ["property", t, name] => {
                let item = Scalar::parse(t)
                    .ok_or_else(|| bad(format!("property {name}: unknown type \"{t}\"")))?;
                let p = Property {
                    name: (*name).into(),
                    count: None,
                    item,
                };
                add_property(&mut elements, p).map_err(bad)?;
            }
            ["end_header"] => break,
            _ => return Err(bad(format!("not a PLY header line: \"{line}\""))),
        }
    }
    let encoding =
        encoding.ok_or_else(|| ScanError::format(path, "the PLY header has no format line"))?;
    Ok((encoding, elements, at))
}

/// Reads a PLY's points and the vertex property `property` (one value per point), as
/// [`write_ply`] writes them with `sigma`.
pub fn read_ply_with(
    path: &Path,
    property: &str,
) -> Result<(Vec<Vector3<f64>>, Vec<f64>), ScanError> {
    let bytes = std::fs::read(path).map_err(|e| ScanError::io(path, e))?;
    read_ply(path, &bytes, Some(property))
}

/// Writes `points` (m) and each one's `sigma` (m) as an ASCII PLY, atomically.
pub fn write_ply(path: &Path, points: &[Vector3<f64>], sigma: &[f64]) -> Result<(), ScanError> {
    use std::fmt::Write as _;
    if points.len() != sigma.len() {
        return Err(ScanError::Invalid(format!(
            "{}: {} points but {} sigma values",
            path.display(),
            points.len(),
            sigma.len()
        )));
    }
    let mut text = format!(
        "ply\nformat ascii 1.0\ncomment palpate scan: metres in the mesh's frame; sigma: the point's noise (m)\n\
         element vertex {}\nproperty double x\nproperty double y\nproperty double z\nproperty double sigma\nend_header\n",
        points.len()
    );
    for (p, s) in points.iter().zip(sigma) {
        // 17 significant digits: the f64 read back is the one written.
        let _ = writeln!(text, "{:.17e} {:.17e} {:.17e} {:.17e}", p.x, p.y, p.z, s);
    }
    palpate_fem::io::atomic::write_atomic(path, text.as_bytes())
        .map_err(|e| ScanError::Invalid(format!("{}: {e}", path.display())))
}

/// Points and the values of the vertex property `extra` if asked for.
type PlyPoints = (Vec<Vector3<f64>>, Vec<f64>);

fn read_ply(path: &Path, bytes: &[u8], extra: Option<&str>) -> Result<PlyPoints, ScanError> {
    let (encoding, elements, start) = ply_header(path, bytes)?;
    let vertex = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| ScanError::format(path, "the PLY header declares no vertex element"))?;
    let slot = |axis: &str| -> Result<usize, ScanError> {
        elements[vertex]
            .properties
            .iter()
            .position(|p| p.name == axis && p.count.is_none())
            .ok_or_else(|| {
                ScanError::format(
                    path,
                    format!("the vertex element has no scalar property {axis}"),
                )
            })
    };
    let xyz = [slot("x")?, slot("y")?, slot("z")?];
    let extra_slot = extra.map(slot).transpose()?;
    let mut extras = Vec::new();
    // The header's count is not trusted to size memory: every point takes at least a byte.
    let mut points = Vec::with_capacity(elements[vertex].count.min(bytes.len()));
    match encoding {
        Encoding::Ascii => {
            let text = std::str::from_utf8(&bytes[start..])
                .map_err(|_| ScanError::format(path, "ASCII PLY data that are not text"))?;
            let header_lines = bytes[..start].iter().filter(|b| **b == b'\n').count();
            let mut lines = text
                .lines()
                .enumerate()
                .map(|(i, l)| (header_lines + i + 1, l))
                .filter(|(_, l)| !l.trim().is_empty());
            for (e, el) in elements.iter().enumerate().take(vertex + 1) {
                for k in 0..el.count {
                    let Some((line_no, line)) = lines.next() else {
                        return Err(ScanError::format(
                            path,
                            format!("element {} ends at instance {k} of {}", el.name, el.count),
                        ));
                    };
                    if e != vertex {
                        continue;
                    }
                    let values = ascii_values(path, line_no, line, &el.properties)?;
                    points.push(Vector3::new(values[xyz[0]], values[xyz[1]], values[xyz[2]]));
                    if let Some(k) = extra_slot {
                        extras.push(values[k]);
                    }
                }
            }
        }
        Encoding::Binary { little } => {
            let mut at = start;
            for (e, el) in elements.iter().enumerate().take(vertex + 1) {
                for k in 0..el.count {
                    let mut values = Vec::with_capacity(el.properties.len());
                    for p in &el.properties {
                        let take = |at: &mut usize, s: Scalar| -> Result<f64, ScanError> {
                            let b = bytes.get(*at..*at + s.size()).ok_or_else(|| {
                                ScanError::format(
                                    path,
                                    format!(
                                        "the data end inside element {} instance {k} of {} (byte {})",
                                        el.name, el.count, *at
                                    ),
                                )
                            })?;
                            *at += s.size();
                            Ok(s.decode(b, little))
                        };
                        match p.count {
                            None => values.push(take(&mut at, p.item)?),
                            Some(c) => {
                                let n = take(&mut at, c)?;
                                if n.is_nan() || n < 0.0 {
                                    return Err(ScanError::format(
                                        path,
                                        format!(
                                            "element {} instance {k}: list {} has count {n}",
                                            el.name, p.name
                                        ),
                                    ));
                                }
                                for _ in 0..n as usize {
                                    take(&mut at, p.item)?;
                                }
                                values.push(f64::NAN);
                            }
                        }
                    }
                    if e == vertex {
                        points.push(Vector3::new(values[xyz[0]], values[xyz[1]], values[xyz[2]]));
                        if let Some(k) = extra_slot {
                            extras.push(values[k]);
                        }
                    }
                }
            }
        }
    }
    check_finite(path, &points)?;
    Ok((points, extras))
}

/// The scalar values of one ASCII instance (lists read past, NaN in their slot).
fn ascii_values(
    path: &Path,
    line_no: usize,
    line: &str,
    properties: &[Property],
) -> Result<Vec<f64>, ScanError> {
    let mut words = line.split_whitespace();
    let mut values = Vec::with_capacity(properties.len());
    let mut next = |name: &str| -> Result<f64, ScanError> {
        let w = words.next().ok_or_else(|| {
            ScanError::format(path, format!("line {line_no}: property {name} is missing"))
        })?;
        w.parse::<f64>().map_err(|_| {
            ScanError::format(
                path,
                format!("line {line_no}: property {name}: \"{w}\" is not a number"),
            )
        })
    };
    for p in properties {
        match p.count {
            None => values.push(next(&p.name)?),
            Some(_) => {
                let n = next(&p.name)?;
                for _ in 0..n.max(0.0) as usize {
                    next(&p.name)?;
                }
                values.push(f64::NAN);
            }
        }
    }
    Ok(values)
}

fn read_text(path: &Path, bytes: &[u8]) -> Result<Vec<Vector3<f64>>, ScanError> {
    let text = std::str::from_utf8(bytes)
        .map_err(|_| ScanError::format(path, "a point list must be text"))?;
    let mut points = Vec::new();
    let mut first = true;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let fields: Vec<&str> = line
            .split(|c: char| c == ',' || c == ';' || c.is_whitespace())
            .filter(|f| !f.is_empty())
            .collect();
        let numbers: Vec<Option<f64>> = fields.iter().take(3).map(|f| f.parse().ok()).collect();
        let header = first && numbers.iter().any(Option::is_none);
        first = false;
        if header {
            continue;
        }
        if numbers.len() < 3 {
            return Err(ScanError::format(
                path,
                format!(
                    "line {}: three coordinates expected, found {} field(s)",
                    i + 1,
                    fields.len()
                ),
            ));
        }
        let mut p = [0.0; 3];
        for (k, n) in numbers.iter().enumerate() {
            p[k] = n.ok_or_else(|| {
                ScanError::format(
                    path,
                    format!(
                        "line {}: field {}: \"{}\" is not a number",
                        i + 1,
                        k + 1,
                        fields[k]
                    ),
                )
            })?;
        }
        points.push(Vector3::from(p));
    }
    check_finite(path, &points)?;
    Ok(points)
}

fn check_finite(path: &Path, points: &[Vector3<f64>]) -> Result<(), ScanError> {
    match points.iter().position(|p| !p.iter().all(|v| v.is_finite())) {
        Some(i) => Err(ScanError::format(
            path,
            format!("point {i} is not finite: {:?}", points[i]),
        )),
        None if points.is_empty() => Err(ScanError::format(path, "no points")),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    const EXPECTED: [[f64; 3]; 2] = [[0.5, -1.25, 2.0], [3.0, 4.5, -0.125]];

    /// The same two points as a scanner writes them: a face element before the vertices, colours
    /// between the coordinates, in ASCII and both binary byte orders (bytes laid out here by
    /// hand, not by palpate).
    #[test]
    fn ply_in_every_encoding() {
        let dir = tempfile::tempdir().unwrap();
        let head = |fmt: &str| {
            format!(
                "ply\nformat {fmt} 1.0\ncomment made by hand\nelement face 1\nproperty list uchar int vertex_indices\n\
                 element vertex 2\nproperty float x\nproperty uchar red\nproperty double y\nproperty float z\nend_header\n"
            )
        };
        let ascii = format!(
            "{}3 0 1 1\n0.5 255 -1.25 2\n3 0 4.5 -0.125\n",
            head("ascii")
        );
        let mut le = head("binary_little_endian").into_bytes();
        let mut be = head("binary_big_endian").into_bytes();
        for (out, little) in [(&mut le, true), (&mut be, false)] {
            out.push(3);
            for i in [0i32, 1, 1] {
                out.extend(if little {
                    i.to_le_bytes()
                } else {
                    i.to_be_bytes()
                });
            }
            for p in EXPECTED {
                let x = p[0] as f32;
                out.extend(if little {
                    x.to_le_bytes()
                } else {
                    x.to_be_bytes()
                });
                out.push(7);
                out.extend(if little {
                    p[1].to_le_bytes()
                } else {
                    p[1].to_be_bytes()
                });
                let z = p[2] as f32;
                out.extend(if little {
                    z.to_le_bytes()
                } else {
                    z.to_be_bytes()
                });
            }
        }
        for (name, bytes) in [
            ("a.ply", ascii.into_bytes()),
            ("le.ply", le),
            ("be.ply", be),
        ] {
            let pts = read_points(&write(dir.path(), name, &bytes)).unwrap();
            assert_eq!(pts.len(), 2, "{name}");
            for (p, e) in pts.iter().zip(EXPECTED) {
                assert_eq!([p.x, p.y, p.z], e, "{name}");
            }
        }
    }

    #[test]
    fn csv_with_a_header_and_errors_that_name_the_line() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(
            dir.path(),
            "p.csv",
            b"x,y,z\n0.5,-1.25,2\n\n3, 4.5, -0.125\n",
        );
        let pts = read_points(&p).unwrap();
        assert_eq!(pts.len(), 2);
        assert_eq!([pts[1].x, pts[1].y, pts[1].z], EXPECTED[1]);
        let p = write(dir.path(), "q.xyz", b"0 0 0\n1 2 oops\n");
        let e = read_points(&p).unwrap_err().to_string();
        assert!(
            e.contains("q.xyz") && e.contains("line 2") && e.contains("oops"),
            "{e}"
        );
        let p = write(dir.path(), "t.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n1 1 1\n");
        let e = read_points(&p).unwrap_err().to_string();
        assert!(e.contains("instance 2 of 3"), "{e}");
        let p = write(
            dir.path(),
            "u.ply",
            b"ply\nformat ascii 1.0\nproperty float x\nelement vertex 1\nend_header\n0\n",
        );
        let e = read_points(&p).unwrap_err().to_string();
        assert!(
            e.contains("u.ply") && e.contains("line 3") && e.contains("before any element"),
            "{e}"
        );
    }
}

//! MSH 2.x binary (Gmsh with `Mesh.MshFileVersion = 2.2` and `Mesh.Binary = 1`), rewritten as
//! the MSH 2.2 ASCII it stands for and read by `ascii22`, so that both flavours build one mesh
//! through one parser (its merging of repeated elements, its checks).
//!
//! The binary file keeps the ASCII section markers and count lines. After the `$MeshFormat` line
//! (`2.2 1 8`) comes the integer 1 in the file's byte order, which says that order. Each node is
//! an int tag and three doubles. Elements come in blocks, each headed by three ints: the type,
//! the number of elements that follow, and their number of tags. Each element is then its tag,
//! its tags and its nodes, all ints (Gmsh reference manual, "MSH file format version 2 (Legacy)").
//! Sections palpate does not read are skipped to their end marker.

use super::ascii22::element_dim_and_nodes;
use super::MeshError;
use std::fmt::Write as _;
use std::path::Path;

/// Reads the bytes of a binary MSH 2.x file forward, knowing its byte order.
struct Cursor<'a> {
    file: &'a Path,
    bytes: &'a [u8],
    at: usize,
    little: bool,
}

impl<'a> Cursor<'a> {
    fn error(&self, at: usize, message: String) -> MeshError {
        MeshError::Binary {
            file: self.file.to_path_buf(),
            offset: at,
            line: 1 + self.bytes[..at.min(self.bytes.len())]
                .iter()
                .filter(|&&b| b == b'\n')
                .count(),
            message,
        }
    }

    /// The next text line, without its line end; `None` at the end of the file.
    fn line(&mut self) -> Option<&'a str> {
        if self.at >= self.bytes.len() {
            return None;
        }
        let rest = &self.bytes[self.at..];
        let len = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.at += (len + 1).min(rest.len());
        Some(
            std::str::from_utf8(&rest[..len])
                .unwrap_or("")
                .trim_end_matches('\r'),
        )
    }

    /// The next line that is not blank (the binary data end with a line break of their own).
    fn text(&mut self, what: &str) -> Result<&'a str, MeshError> {
        loop {
            let at = self.at;
            match self.line() {
                Some(l) if l.trim().is_empty() => {}
                Some(l) => return Ok(l.trim()),
                None => return Err(self.error(at, format!("end of file before {what}"))),
            }
        }
    }

    fn expect(&mut self, marker: &str) -> Result<(), MeshError> {
        let at = self.at;
        let l = self.text(marker)?;
        if l == marker {
            Ok(())
        } else {
            Err(self.error(at, format!("expected {marker}, found {l:?}")))
        }
    }

    fn count(&mut self, what: &str) -> Result<usize, MeshError> {
        let at = self.at;
        let l = self.text(what)?;
        l.parse()
            .map_err(|_| self.error(at, format!("expected the {what}, found {l:?}")))
    }

    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8], MeshError> {
        if self.bytes.len() - self.at < n {
            return Err(self.error(
                self.at,
                format!(
                    "{what}: {n} bytes needed, {} left",
                    self.bytes.len() - self.at
                ),
            ));
        }
        let s = &self.bytes[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }

    /// The next `N` bytes as a number in the file's byte order (`from`: little-, big-endian).
    fn number<const N: usize, T>(
        &mut self,
        what: &str,
        from: [fn([u8; N]) -> T; 2],
    ) -> Result<T, MeshError> {
        let b: [u8; N] = self.take(N, what)?.try_into().expect("N bytes");
        Ok(if self.little { from[0](b) } else { from[1](b) })
    }

    fn int(&mut self, what: &str) -> Result<i32, MeshError> {
        self.number(what, [i32::from_le_bytes, i32::from_be_bytes])
    }

    fn double(&mut self, what: &str) -> Result<f64, MeshError> {
        self.number(what, [f64::from_le_bytes, f64::from_be_bytes])
    }
}

/// The MSH 2.2 ASCII text of the binary MSH 2.x file `bytes`; errors name the byte offset.
pub(super) fn to_ascii(file: &Path, bytes: &[u8]) -> Result<String, MeshError> {
    let mut c = Cursor {
        file,
        bytes,
        at: 0,
        little: true,
    };
    c.expect("$MeshFormat")?;
    let at = c.at;
    let format = c.text("the format line")?;
    let size = format.split_whitespace().nth(2);
    if size != Some("8") {
        return Err(c.error(
            at,
            format!("data size {size:?} on the format line {format:?}, expected 8 (doubles)"),
        ));
    }
    let one = c.take(4, "the byte-order integer")?;
    c.little = match (
        i32::from_le_bytes(one.try_into().expect("four bytes")),
        i32::from_be_bytes(one.try_into().expect("four bytes")),
    ) {
        (1, _) => true,
        (_, 1) => false,
        _ => return Err(c.error(at, "the byte-order integer is not 1 in either order".into())),
    };
    c.expect("$EndMeshFormat")?;
    let mut out = String::from("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n");
    while let Ok(section) = c.text("a section") {
        match section {
            "$PhysicalNames" => {
                out.push_str("$PhysicalNames\n");
                loop {
                    let l = c.text("$EndPhysicalNames")?;
                    out.push_str(l);
                    out.push('\n');
                    if l == "$EndPhysicalNames" {
                        break;
                    }
                }
            }
            "$Nodes" => {
                let n = c.count("number of nodes")?;
                let _ = writeln!(out, "$Nodes\n{n}");
                for _ in 0..n {
                    let tag = c.int("a node's tag")?;
                    let (x, y, z) = (
                        c.double("a node's x")?,
                        c.double("a node's y")?,
                        c.double("a node's z")?,
                    );
                    // `{:?}` prints the shortest text that reads back to the same double.
                    let _ = writeln!(out, "{tag} {x:?} {y:?} {z:?}");
                }
                c.expect("$EndNodes")?;
                out.push_str("$EndNodes\n");
            }
            "$Elements" => {
                let n = c.count("number of elements")?;
                let _ = writeln!(out, "$Elements\n{n}");
                let mut read = 0usize;
                while read < n {
                    let at = c.at;
                    let (kind, follow, tags) = (
                        c.int("an element block's type")?,
                        c.int("an element block's count")?,
                        c.int("an element block's number of tags")?,
                    );
                    let Some((_, nodes)) = element_dim_and_nodes(kind) else {
                        return Err(
                            c.error(at, format!("element type {kind} is not an MSH 2 type"))
                        );
                    };
                    let (Ok(follow), Ok(tags)) = (usize::try_from(follow), usize::try_from(tags))
                    else {
                        return Err(c.error(
                            at,
                            format!("an element block of {follow} elements with {tags} tags"),
                        ));
                    };
                    if follow == 0 || follow > n - read {
                        return Err(c.error(
                            at,
                            format!(
                                "an element block of {follow} elements where {} of the {n} \
                                 counted are left",
                                n - read
                            ),
                        ));
                    }
                    for _ in 0..follow {
                        let tag = c.int("an element's tag")?;
                        let _ = write!(out, "{tag} {kind} {tags}");
                        for _ in 0..tags + nodes {
                            let _ = write!(out, " {}", c.int("an element's tags and nodes")?);
                        }
                        out.push('\n');
                    }
                    read += follow;
                }
                c.expect("$EndElements")?;
                out.push_str("$EndElements\n");
            }
            s if s.starts_with('$') && !s.starts_with("$End") => {
                // A section palpate does not read ($NodeData, $Periodic, …): to its end marker.
                let end = format!("\n$End{}", &s[1..]);
                let from = c.at;
                let Some(k) = bytes[from..]
                    .windows(end.len())
                    .position(|w| w == end.as_bytes())
                else {
                    return Err(c.error(from, format!("no {} after {s}", &end[1..])));
                };
                c.at = from + k + end.len();
            }
            other => {
                let at = c.at;
                return Err(c.error(
                    at,
                    format!("expected a section like \"$Nodes\", found {other:?}"),
                ));
            }
        }
    }
    Ok(out)
}

//! The MSH 4.1 ASCII parser: a token reader that knows the line of every token.

use super::{MeshError, RawElements, RawMsh};
use std::path::Path;

/// Which parser reads a file: decided by the version and the file type on its `$MeshFormat` line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum MshFormat {
    /// MSH 4.1 ASCII, read by [`parse`].
    V41Ascii,
    /// MSH 4.1 binary, read through mshio.
    V41Binary,
    /// MSH 2.0, 2.1 or 2.2 ASCII, read by `ascii22::parse`.
    V2Ascii,
    /// MSH 2.0, 2.1 or 2.2 binary, rewritten as ASCII by `binary22::to_ascii`.
    V2Binary,
}

/// Reads the `$MeshFormat` header and says which parser reads the file. Rejects non-MSH files
/// and versions other than 4.1 and 2.0–2.2.
pub(super) fn mesh_format(file: &Path, bytes: &[u8]) -> Result<MshFormat, MeshError> {
    // The header is ASCII in both flavours; look only at its first lines.
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(256)]);
    let mut lines = head.lines().map(str::trim);
    let syntax = |line: usize, expected: &str, found: &str| MeshError::Syntax {
        file: file.to_path_buf(),
        line,
        expected: expected.to_string(),
        found: quote(found),
    };
    let first = lines.next().unwrap_or("");
    if first != "$MeshFormat" {
        return Err(syntax(1, "\"$MeshFormat\" (a Gmsh .msh file)", first));
    }
    let fmt = lines.next().unwrap_or("");
    let mut parts = fmt.split_whitespace();
    let version = parts.next().unwrap_or("");
    let msh2 = match version {
        "4.1" => false,
        // 2.0 and 2.1 differ from 2.2 only in sections and tags palpate does not read.
        "2.2" | "2.1" | "2.0" => true,
        _ => {
            return Err(syntax(
                2,
                "MSH format version 4.1 or 2.2, 2.1, 2.0 (ASCII or binary) \
                 (save with Mesh.MshFileVersion = 4.1)",
                version,
            ))
        }
    };
    match (parts.next(), msh2) {
        (Some("0"), false) => Ok(MshFormat::V41Ascii),
        // mshio reads a binary file's size_t at the width this field gives and has no reader
        // for widths other than its few (a corrupted "7" made it panic): Gmsh writes
        // sizeof(size_t), 8 on a 64-bit machine and 4 on a 32-bit one.
        (Some("1"), false) => match parts.next() {
            Some("8" | "4") => Ok(MshFormat::V41Binary),
            other => Err(syntax(
                2,
                "data size 8 or 4 (the bytes of a size_t, as Gmsh writes it)",
                other.unwrap_or(""),
            )),
        },
        (Some("0"), true) => Ok(MshFormat::V2Ascii),
        (Some("1"), true) => Ok(MshFormat::V2Binary),
        (other, _) => Err(syntax(
            2,
            "file type 0 (ASCII) or 1 (binary)",
            other.unwrap_or(""),
        )),
    }
}

/// Counts come from the file: never pre-allocate more than a file of this kind could hold, so a
/// corrupt count fails with "end of file" instead of exhausting memory.
pub(super) fn prealloc(count: usize) -> usize {
    count.min(1 << 16)
}

fn quote(s: &str) -> String {
    if s.is_empty() {
        "end of line".to_string()
    } else {
        format!("{s:?}")
    }
}

/// A cursor over whitespace-separated tokens that remembers lines.
pub(super) struct Tokens<'a> {
    file: &'a Path,
    lines: Vec<&'a str>,
    /// Current line index (0-based) and byte column in it.
    pub(super) line: usize,
    col: usize,
}

impl<'a> Tokens<'a> {
    pub(super) fn new(file: &'a Path, text: &'a str) -> Self {
        Tokens {
            file,
            lines: text.lines().collect(),
            line: 0,
            col: 0,
        }
    }

    pub(super) fn err(&self, line: usize, expected: impl Into<String>, found: &str) -> MeshError {
        MeshError::Syntax {
            file: self.file.to_path_buf(),
            line: line + 1,
            expected: expected.into(),
            found: quote(found),
        }
    }

    /// Next token on the current line, if any.
    pub(super) fn on_line(&mut self) -> Option<(usize, &'a str)> {
        let l = *self.lines.get(self.line)?;
        let rest = &l[self.col..];
        let start = rest.len() - rest.trim_start().len();
        let rest = &rest[start..];
        if rest.is_empty() {
            return None;
        }
        let len = rest.find(char::is_whitespace).unwrap_or(rest.len());
        self.col += start + len;
        Some((self.line, &rest[..len]))
    }

    /// Next token, moving across line ends. `what` names it in the end-of-file error.
    pub(super) fn next(&mut self, what: &str) -> Result<(usize, &'a str), MeshError> {
        loop {
            if let Some(t) = self.on_line() {
                return Ok(t);
            }
            if self.line + 1 >= self.lines.len() {
                return Err(MeshError::Syntax {
                    file: self.file.to_path_buf(),
                    line: self.lines.len(),
                    expected: what.to_string(),
                    found: "end of file".to_string(),
                });
            }
            self.line += 1;
            self.col = 0;
        }
    }

    /// Moves to the start of the next line that holds a token.
    fn next_line(&mut self) {
        self.line += 1;
        self.col = 0;
    }

    fn parse<T: std::str::FromStr>(&mut self, what: &str, kind: &str) -> Result<T, MeshError> {
        let (line, tok) = self.next(what)?;
        tok.parse()
            .map_err(|_| self.err(line, format!("{what} ({kind})"), tok))
    }
    fn uint(&mut self, what: &str) -> Result<u64, MeshError> {
        self.parse(what, "an unsigned integer")
    }
    fn int(&mut self, what: &str) -> Result<i32, MeshError> {
        self.parse(what, "an integer")
    }
    pub(super) fn count(&mut self, what: &str) -> Result<usize, MeshError> {
        self.parse(what, "a count")
    }
    fn float(&mut self, what: &str) -> Result<f64, MeshError> {
        self.parse(what, "a number")
    }

    fn expect(&mut self, word: &str) -> Result<(), MeshError> {
        let (line, tok) = self.next(&format!("{word:?}"))?;
        if tok == word {
            Ok(())
        } else {
            Err(self.err(line, format!("{word:?}"), tok))
        }
    }
}

/// The file as text; invalid UTF-8 is an error naming the line it is on.
pub(super) fn utf8_text<'a>(file: &Path, bytes: &'a [u8]) -> Result<&'a str, MeshError> {
    std::str::from_utf8(bytes).map_err(|e| {
        let line = bytes[..e.valid_up_to()]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1;
        MeshError::Syntax {
            file: file.to_path_buf(),
            line,
            expected: "UTF-8 text (an ASCII .msh file)".into(),
            found: "invalid UTF-8 bytes".into(),
        }
    })
}

/// Parses an ASCII MSH 4.1 file.
pub(super) fn parse(file: &Path, bytes: &[u8]) -> Result<RawMsh, MeshError> {
    let text = utf8_text(file, bytes)?;
    let mut t = Tokens::new(file, text);
    let mut raw = RawMsh::default();
    // `next` fails only at the end of the file, which is where reading stops between sections.
    while let Ok((line, section)) = t.next("a section") {
        match section {
            "$MeshFormat" => {
                // Checked by `mesh_format`; skip its content.
                skip_to(&mut t, "$EndMeshFormat")?;
            }
            "$PhysicalNames" => physical_names(&mut t, &mut raw)?,
            "$Entities" => entities(&mut t, &mut raw)?,
            "$Nodes" => nodes(&mut t, &mut raw)?,
            "$Elements" => elements(&mut t, &mut raw)?,
            s if s.starts_with('$') && !s.starts_with("$End") => {
                // Sections palpate does not use ($NodeData, $Periodic, comments, …).
                let end = format!("$End{}", &s[1..]);
                skip_to(&mut t, &end)?;
            }
            other => return Err(t.err(line, "a section header like \"$Nodes\"", other)),
        }
    }
    Ok(raw)
}

pub(super) fn skip_to(t: &mut Tokens, end: &str) -> Result<(), MeshError> {
    loop {
        let (_, tok) = t.next(&format!("{end:?}"))?;
        if tok == end {
            return Ok(());
        }
    }
}

pub(super) fn physical_names(t: &mut Tokens, raw: &mut RawMsh) -> Result<(), MeshError> {
    let n = t.count("number of physical names")?;
    for _ in 0..n {
        let dim = t.int("physical group dimension")?;
        let tag = t.int("physical group tag")?;
        // The name is quoted and may hold spaces: take the rest of the line.
        let line = t.line;
        let rest = t.lines[line][t.col..].trim();
        let name = rest
            .strip_prefix('"')
            .and_then(|r| r.strip_suffix('"'))
            .ok_or_else(|| t.err(line, "a quoted physical group name", rest))?;
        raw.physical_names.push((dim, tag, name.to_string()));
        t.next_line();
    }
    t.expect("$EndPhysicalNames")
}

fn entities(t: &mut Tokens, raw: &mut RawMsh) -> Result<(), MeshError> {
    let counts = [
        t.count("number of points")?,
        t.count("number of curves")?,
        t.count("number of surfaces")?,
        t.count("number of volumes")?,
    ];
    for (dim, &n) in counts.iter().enumerate() {
        for _ in 0..n {
            let tag = t.int("entity tag")?;
            let coords = if dim == 0 { 3 } else { 6 };
            for _ in 0..coords {
                t.float("entity coordinate")?;
            }
            let np = t.count("number of physical tags")?;
            let mut phys = Vec::with_capacity(prealloc(np));
            for _ in 0..np {
                phys.push(t.int("physical tag")?);
            }
            if dim > 0 {
                let nb = t.count("number of bounding entities")?;
                for _ in 0..nb {
                    t.int("bounding entity tag")?;
                }
            }
            raw.entity_physicals.push(((dim as i32, tag), phys));
        }
    }
    t.expect("$EndEntities")
}

/// The line that opens `$Nodes` and `$Elements`: the number of entity blocks, then the total
/// number of `kind`s and their minimum and maximum tags (read for their syntax, unused: the blocks
/// say it again). Returns the number of blocks.
fn block_count(t: &mut Tokens, kind: &str) -> Result<usize, MeshError> {
    let blocks = t.count(&format!("number of {kind} entity blocks"))?;
    t.uint(&format!("number of {kind}s"))?;
    t.uint(&format!("minimum {kind} tag"))?;
    t.uint(&format!("maximum {kind} tag"))?;
    Ok(blocks)
}

fn nodes(t: &mut Tokens, raw: &mut RawMsh) -> Result<(), MeshError> {
    let blocks = block_count(t, "node")?;
    for _ in 0..blocks {
        let dim = t.int("entity dimension")?;
        let entity = t.int("entity tag")?;
        let (line, tok) = t.next("parametric flag (0 or 1)")?;
        let parametric = match tok {
            "0" => false,
            "1" => true,
            _ => return Err(t.err(line, "parametric flag (0 or 1)", tok)),
        };
        let n = t.count("number of nodes in block")?;
        let mut tags = Vec::with_capacity(prealloc(n));
        for _ in 0..n {
            tags.push(t.uint("node tag")?);
        }
        let mut block = Vec::with_capacity(prealloc(n));
        for tag in tags {
            let x = [t.float("node x")?, t.float("node y")?, t.float("node z")?];
            if parametric {
                // Parametric coordinates u (curves), u v (surfaces), u v w (volumes): unused.
                for _ in 0..dim.clamp(0, 3) {
                    t.float("parametric coordinate")?;
                }
            }
            block.push((tag, x));
        }
        raw.node_blocks.push((dim, entity, block));
    }
    t.expect("$EndNodes")
}

fn elements(t: &mut Tokens, raw: &mut RawMsh) -> Result<(), MeshError> {
    let blocks = block_count(t, "element")?;
    for _ in 0..blocks {
        let dim = t.int("entity dimension")?;
        let entity = t.int("entity tag")?;
        let type_id = t.int("element type")?;
        let n = t.count("number of elements in block")?;
        let expected_nodes = match type_id {
            15 => Some(1),
            1 => Some(2),
            2 => Some(3),
            3 | 4 => Some(4),
            11 => Some(10),
            _ => None,
        };
        let mut elements = Vec::with_capacity(prealloc(n));
        for _ in 0..n {
            // One element per line: its tag, then its node tags.
            t.next_line_if_done();
            let tag = t.uint("element tag")?;
            let line = t.line;
            let mut nodes = Vec::with_capacity(expected_nodes.unwrap_or(4));
            while let Some((l, tok)) = t.on_line() {
                nodes.push(
                    tok.parse::<u64>()
                        .map_err(|_| t.err(l, "node tag (an unsigned integer)", tok))?,
                );
            }
            if let Some(k) = expected_nodes {
                if nodes.len() != k {
                    return Err(t.err(
                        line,
                        format!("{k} node tags for element {tag} of type {type_id}"),
                        &format!("{} node tags", nodes.len()),
                    ));
                }
            }
            elements.push((tag, nodes));
        }
        raw.element_blocks.push(RawElements {
            dim,
            entity,
            type_id,
            elements,
        });
    }
    t.next_line_if_done();
    t.expect("$EndElements")
}

impl Tokens<'_> {
    /// Moves to the next line if the current one has no tokens left (element rows are per line).
    fn next_line_if_done(&mut self) {
        if let Some(l) = self.lines.get(self.line) {
            if l[self.col..].trim().is_empty() {
                self.next_line();
            }
        }
    }
}

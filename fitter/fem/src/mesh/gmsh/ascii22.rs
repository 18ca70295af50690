//! The MSH 2.2 ASCII parser (also 2.0 and 2.1, whose ASCII grammar is the same in the sections
//! read here), into the same [`RawMsh`] as the 4.1 parsers so that `assemble` builds the mesh.
//!
//! MSH 2 has no `$Entities` section: every element row carries its own tags, the first its
//! physical tag (0 = none) and the second its elementary (geometric entity) tag. The physical tag
//! belongs to the element, not to the entity, so the parser makes one synthetic entity per
//! (dimension, elementary tag, set of physical tags) and records that set in
//! `entity_physicals`; a group then holds exactly the nodes of its elements, as in the 4.1 path.
//!
//! Gmsh writes an element that belongs to several physical groups once per group, each time with
//! a new element tag. Such a repeat (same type, elementary tag and node list, another physical
//! tag) is merged into the first row: it adds its physical tag instead of a second element,
//! which would otherwise read as a tetrahedron overlapping itself.
//!
//! Rows are read line by line (Gmsh and meshio write one node or element per line), so a short
//! or long row is reported on its own line rather than where the next row's tokens run out.

use super::ascii::{physical_names, prealloc, skip_to, utf8_text, Tokens};
use super::{MeshError, RawElements, RawMsh};
use std::collections::HashMap;
use std::path::Path;

/// The (dimension, entity) of the one node block: MSH 2 does not classify nodes on entities, and
/// no entity has dimension −1, so `assemble` adds these nodes to groups only through elements.
const UNCLASSIFIED: (i32, i32) = (-1, -1);

/// Parses an ASCII MSH 2.x file.
pub(super) fn parse(file: &Path, bytes: &[u8]) -> Result<RawMsh, MeshError> {
    let text = utf8_text(file, bytes)?;
    let mut t = Tokens::new(file, text);
    let mut raw = RawMsh::default();
    let mut rows = ElementRows::default();
    // `next` fails only at the end of the file, which is where reading stops between sections.
    while let Ok((line, section)) = t.next("a section") {
        match section {
            "$MeshFormat" => {
                // Checked by `mesh_format`; skip its content.
                skip_to(&mut t, "$EndMeshFormat")?;
            }
            "$PhysicalNames" => physical_names(&mut t, &mut raw)?,
            "$Nodes" => nodes(&mut t, &mut raw)?,
            "$Elements" => elements(&mut t, &mut rows)?,
            s if s.starts_with('$') && !s.starts_with("$End") => {
                // Sections palpate does not use ($NodeData, $Periodic, $Comments, …).
                let end = format!("$End{}", &s[1..]);
                skip_to(&mut t, &end)?;
            }
            other => return Err(t.err(line, "a section header like \"$Nodes\"", other)),
        }
    }
    rows.into_blocks(&mut raw);
    Ok(raw)
}

/// Gmsh element type → (dimension, number of nodes), for every type MSH 2.2 defines (checked
/// against `gmsh.model.mesh.getElementProperties` of Gmsh 4.15.2). An MSH 2 row does not say how
/// many nodes it lists, so a type outside this table cannot be read.
pub(super) fn element_dim_and_nodes(type_id: i32) -> Option<(i32, usize)> {
    Some(match type_id {
        15 => (0, 1),
        1 => (1, 2),
        8 => (1, 3),
        26 => (1, 4),
        27 => (1, 5),
        28 => (1, 6),
        2 => (2, 3),
        3 => (2, 4),
        9 => (2, 6),
        10 => (2, 9),
        16 => (2, 8),
        20 => (2, 9),
        21 => (2, 10),
        22 => (2, 12),
        23 | 24 => (2, 15),
        25 => (2, 21),
        4 => (3, 4),
        5 => (3, 8),
        6 => (3, 6),
        7 => (3, 5),
        11 => (3, 10),
        12 => (3, 27),
        13 => (3, 18),
        14 => (3, 14),
        17 => (3, 20),
        18 => (3, 15),
        19 => (3, 13),
        29 => (3, 20),
        30 => (3, 35),
        31 => (3, 56),
        92 => (3, 64),
        93 => (3, 125),
        _ => return None,
    })
}

/// The section's count line: one count alone on its line. Returns the count and its 0-based line.
fn section_count(t: &mut Tokens, what: &str) -> Result<(usize, usize), MeshError> {
    let n = t.count(what)?;
    let line = t.line;
    row_end(t, &format!("the end of the line after the {what}"))?;
    Ok((n, line))
}

/// The first token of row `k` (0-based) of the `n` counted on `count_line`. A section end or the
/// end of the file here means the count promised more rows than the section holds.
fn row_start<'a>(
    t: &mut Tokens<'a>,
    kind: &str,
    k: usize,
    n: usize,
    count_line: usize,
) -> Result<(usize, &'a str), MeshError> {
    let expected = format!(
        "{kind} {} of {n} (counted on line {})",
        k + 1,
        count_line + 1
    );
    let (line, tok) = t.next(&expected)?;
    if tok.starts_with('$') {
        return Err(t.err(line, expected, tok));
    }
    Ok((line, tok))
}

/// Parses `tok`, found on 0-based `line`, as `what` (`kind` says the expected form).
fn parse_token<T: std::str::FromStr>(
    t: &Tokens,
    (line, tok): (usize, &str),
    what: &str,
    kind: &str,
) -> Result<T, MeshError> {
    tok.parse()
        .map_err(|_| t.err(line, format!("{what} ({kind})"), tok))
}

/// The next token of the current row, which must be on the row's line.
fn field<'a>(t: &mut Tokens<'a>, what: &str, kind: &str) -> Result<(usize, &'a str), MeshError> {
    let line = t.line;
    t.on_line()
        .ok_or_else(|| t.err(line, format!("{what} ({kind})"), ""))
}

fn parse_field<T: std::str::FromStr>(
    t: &mut Tokens,
    what: &str,
    kind: &str,
) -> Result<T, MeshError> {
    let token = field(t, what, kind)?;
    parse_token(t, token, what, kind)
}

/// The current row must hold nothing more.
fn row_end(t: &mut Tokens, expected: &str) -> Result<(), MeshError> {
    match t.on_line() {
        Some((line, tok)) => Err(t.err(line, expected, tok)),
        None => Ok(()),
    }
}

/// The section's end marker, right after its `n` rows.
fn section_end(
    t: &mut Tokens,
    end: &str,
    n: usize,
    kind: &str,
    count_line: usize,
) -> Result<(), MeshError> {
    let expected = format!(
        "{end:?} after the {n} {kind}s counted on line {}",
        count_line + 1
    );
    let (line, tok) = t.next(&expected)?;
    if tok == end {
        Ok(())
    } else {
        Err(t.err(line, expected, tok))
    }
}

/// `$Nodes`: the count, then one `tag x y z` row per node.
fn nodes(t: &mut Tokens, raw: &mut RawMsh) -> Result<(), MeshError> {
    let (n, count_line) = section_count(t, "number of nodes")?;
    let mut block = Vec::with_capacity(prealloc(n));
    for k in 0..n {
        let first = row_start(t, "node", k, n, count_line)?;
        let tag: u64 = parse_token(t, first, "node tag", "an unsigned integer")?;
        let x: [f64; 3] = [
            parse_field(t, "node x", "a number")?,
            parse_field(t, "node y", "a number")?,
            parse_field(t, "node z", "a number")?,
        ];
        row_end(t, "the end of the node row (tag x y z)")?;
        block.push((tag, x));
    }
    raw.node_blocks
        .push((UNCLASSIFIED.0, UNCLASSIFIED.1, block));
    section_end(t, "$EndNodes", n, "node", count_line)
}

/// One element as read, before its entity is known (that needs all its physical tags).
struct ElementRow {
    tag: u64,
    type_id: i32,
    dim: i32,
    elementary: i32,
    /// Physical tags of this element and of its repeats, 0 (none) included.
    physicals: Vec<i32>,
    nodes: Vec<u64>,
}

/// The elements of the file in file order, repeats merged.
#[derive(Default)]
struct ElementRows {
    rows: Vec<ElementRow>,
    /// (type, elementary tag, node tags) → index in `rows`: finds Gmsh's per-group repeats.
    first_row: HashMap<(i32, i32, Vec<u64>), usize>,
}

/// `$Elements`: the count, then one `tag type ntags tag… node…` row per element.
fn elements(t: &mut Tokens, rows: &mut ElementRows) -> Result<(), MeshError> {
    let (n, count_line) = section_count(t, "number of elements")?;
    rows.rows.reserve(prealloc(n));
    for k in 0..n {
        let first = row_start(t, "element", k, n, count_line)?;
        let tag: u64 = parse_token(t, first, "element tag", "an unsigned integer")?;
        let type_what = format!("type of element {tag}");
        let type_token = field(t, &type_what, "an integer")?;
        let type_id: i32 = parse_token(t, type_token, &type_what, "an integer")?;
        let (dim, node_count) = element_dim_and_nodes(type_id).ok_or_else(|| {
            t.err(
                type_token.0,
                format!("{type_what} (a Gmsh element type 1–31, 92 or 93)"),
                type_token.1,
            )
        })?;
        let ntags: usize = parse_field(t, &format!("number of tags of element {tag}"), "a count")?;
        let mut tags = Vec::with_capacity(ntags.min(8));
        for i in 0..ntags {
            let what = format!("tag {} of {ntags} of element {tag}", i + 1);
            tags.push(parse_field::<i32>(t, &what, "an integer")?);
        }
        // Tags past the second (partitions, ghost cells) say nothing about groups.
        let physical = tags.first().copied().unwrap_or(0);
        let elementary = tags.get(1).copied().unwrap_or(0);
        let line = t.line;
        let mut nodes = Vec::with_capacity(node_count);
        while let Some((l, tok)) = t.on_line() {
            nodes.push(parse_token(
                t,
                (l, tok),
                &format!("node tag of element {tag}"),
                "an unsigned integer",
            )?);
        }
        if nodes.len() != node_count {
            return Err(t.err(
                line,
                format!("{node_count} node tags for element {tag} of type {type_id}"),
                &format!("{} node tags", nodes.len()),
            ));
        }
        rows.push(ElementRow {
            tag,
            type_id,
            dim,
            elementary,
            physicals: vec![physical],
            nodes,
        });
    }
    section_end(t, "$EndElements", n, "element", count_line)
}

impl ElementRows {
    fn push(&mut self, row: ElementRow) {
        let key = (row.type_id, row.elementary, row.nodes.clone());
        let physical = row.physicals[0];
        match self.first_row.get(&key) {
            // A repeat for another physical group. A repeat with a physical tag already seen is
            // a genuinely duplicated element and stays, for `assemble` to reject as in 4.1.
            Some(&i) if !self.rows[i].physicals.contains(&physical) => {
                self.rows[i].physicals.push(physical);
            }
            _ => {
                self.first_row.entry(key).or_insert(self.rows.len());
                self.rows.push(row);
            }
        }
    }

    /// Element blocks (consecutive rows of one (dimension, entity, type), so file order is kept)
    /// and the physical tags of every synthetic entity.
    fn into_blocks(self, raw: &mut RawMsh) {
        let mut entity_of: HashMap<(i32, i32, Vec<i32>), i32> = HashMap::new();
        for row in self.rows {
            let mut physicals: Vec<i32> = row.physicals.into_iter().filter(|&p| p != 0).collect();
            physicals.sort_unstable();
            let next_entity = entity_of.len() as i32 + 1;
            let entity = *entity_of
                .entry((row.dim, row.elementary, physicals.clone()))
                .or_insert_with(|| {
                    raw.entity_physicals
                        .push(((row.dim, next_entity), physicals));
                    next_entity
                });
            match raw.element_blocks.last_mut() {
                Some(b) if (b.dim, b.entity, b.type_id) == (row.dim, entity, row.type_id) => {
                    b.elements.push((row.tag, row.nodes));
                }
                _ => raw.element_blocks.push(RawElements {
                    dim: row.dim,
                    entity,
                    type_id: row.type_id,
                    elements: vec![(row.tag, row.nodes)],
                }),
            }
        }
    }
}

//! Binary MSH 4.1 through mshio, converted to the shared raw form.

use super::{MeshError, RawElements, RawMsh};
use std::path::Path;

/// Parses a binary MSH 4.1 file with mshio. `$PhysicalNames` (plain text even in binary files,
/// and not read by mshio) is read from the text before the first binary section.
///
/// mshio has inputs it panics on (`unimplemented!` for a size_t width it has no reader for,
/// `expect` on digits that are not UTF-8); the header's fields are checked before it is called
/// (`ascii::mesh_format`), and a panic left in it is caught and reported as this file's error.
pub(super) fn parse(file: &Path, bytes: &[u8]) -> Result<RawMsh, MeshError> {
    let parsed = std::panic::catch_unwind(|| mshio::parse_msh_bytes(bytes)).map_err(|panic| {
        let why = panic
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| panic.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        MeshError::Binary {
            file: file.to_path_buf(),
            offset: 0,
            line: 0,
            message: format!("the MSH 4.1 binary reader (mshio) failed on this file: {why}"),
        }
    })?;
    let msh = parsed.map_err(|e| {
        // mshio's error holds the unparsed rest of the input: its length gives the offset.
        let offset = e
            .backtrace
            .first()
            .map(|(rest, _)| bytes.len() - rest.len())
            .unwrap_or(0);
        let line = bytes[..offset].iter().filter(|&&b| b == b'\n').count() + 1;
        let message = e
            .backtrace
            .iter()
            .map(|(_, kind)| kind.to_string())
            .collect::<Vec<_>>()
            .join(": ");
        MeshError::Binary {
            file: file.to_path_buf(),
            offset,
            line,
            message,
        }
    })?;
    let mut raw = RawMsh {
        physical_names: physical_names(file, bytes)?,
        ..RawMsh::default()
    };
    let bad = |what: &str| MeshError::Binary {
        file: file.to_path_buf(),
        offset: 0,
        line: 0,
        message: format!("value out of range in {what}"),
    };
    if let Some(ent) = &msh.data.entities {
        // ((dimension, tag), physical tags) of every entity, points to volumes (four types).
        raw.entity_physicals.extend(
            ent.points
                .iter()
                .map(|p| ((0, p.tag), p.physical_tags.clone()))
                .chain(
                    ent.curves
                        .iter()
                        .map(|c| ((1, c.tag), c.physical_tags.clone())),
                )
                .chain(
                    ent.surfaces
                        .iter()
                        .map(|s| ((2, s.tag), s.physical_tags.clone())),
                )
                .chain(
                    ent.volumes
                        .iter()
                        .map(|v| ((3, v.tag), v.physical_tags.clone())),
                ),
        );
    }
    if let Some(nodes) = &msh.data.nodes {
        // Dense tags are not kept by mshio: rebuild them as min_tag + running position.
        let mut next = nodes.min_node_tag;
        for b in &nodes.node_blocks {
            let mut tag_of = vec![0u64; b.nodes.len()];
            match &b.node_tags {
                Some(map) => {
                    for (&tag, &i) in map {
                        *tag_of.get_mut(i).ok_or_else(|| bad("node tags"))? = tag;
                    }
                }
                None => {
                    for t in tag_of.iter_mut() {
                        *t = next;
                        next += 1;
                    }
                }
            }
            let block = b
                .nodes
                .iter()
                .zip(tag_of)
                .map(|(n, tag)| (tag, [n.x, n.y, n.z]))
                .collect();
            raw.node_blocks.push((b.entity_dim, b.entity_tag, block));
        }
    }
    if let Some(elements) = &msh.data.elements {
        for b in &elements.element_blocks {
            let type_id = b.element_type as i32;
            let elements = b
                .elements
                .iter()
                .map(|e| (e.element_tag, e.nodes.clone()))
                .collect();
            raw.element_blocks.push(RawElements {
                dim: b.entity_dim,
                entity: b.entity_tag,
                type_id,
                elements,
            });
        }
    }
    Ok(raw)
}

/// `$PhysicalNames` from the text part of a binary file.
fn physical_names(file: &Path, bytes: &[u8]) -> Result<Vec<(i32, i32, String)>, MeshError> {
    let Some(start) = find(bytes, b"$PhysicalNames") else {
        return Ok(Vec::new());
    };
    let Some(len) = find(&bytes[start..], b"$EndPhysicalNames") else {
        return Err(MeshError::Binary {
            file: file.to_path_buf(),
            offset: start,
            line: 0,
            message: "$PhysicalNames without $EndPhysicalNames".into(),
        });
    };
    let first_line = bytes[..start].iter().filter(|&&b| b == b'\n').count();
    let section = String::from_utf8_lossy(&bytes[start..start + len]);
    let mut out = Vec::new();
    for (k, line) in section.lines().enumerate().skip(2) {
        let line_no = first_line + k + 1;
        let syntax = |expected: &str| MeshError::Syntax {
            file: file.to_path_buf(),
            line: line_no,
            expected: expected.to_string(),
            found: format!("{line:?}"),
        };
        let mut parts = line.trim().splitn(3, ' ');
        let dim = parts
            .next()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| syntax("a dimension"))?;
        let tag = parts
            .next()
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| syntax("a physical tag"))?;
        let name = parts
            .next()
            .map(str::trim)
            .and_then(|s| s.strip_prefix('"'))
            .and_then(|s| s.strip_suffix('"'))
            .ok_or_else(|| syntax("a quoted name"))?;
        out.push((dim, tag, name.to_string()));
    }
    Ok(out)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

//! The C3D parameter section walked record by record (C3D.org, *The C3D File Format User Guide*,
//! "The parameter section"): to hand `c3dio` a section it can parse, and to say where one is
//! broken.
//!
//! The section is a chain of records after a 4-byte header. Each record starts with the length of
//! its name (i8, negative when locked) and a group id (i8: negative for a group, the owning group's
//! id for a parameter; 0 ends the chain), the name, and a 16-bit offset from that offset field to
//! the next record (0: the last record). A group then holds its description; a parameter its type
//! (−1 char, 1 byte, 2 int16, 4 float), the number of dimensions, the dimensions, the data
//! (their product times the type's size) and its description.
//!
//! A dimension of 0 is an empty array, which the standard allows and capture software writes:
//! Vicon Nexus leaves `EVENT:LABELS` (32 × 0), `ANALYSIS:VALUES` (0), `FORCE_PLATFORM:CORNERS`
//! (3 × 4 × 0) and more empty when a trial has no events, analyses or plates. `c3dio` drops the
//! zero dimensions before sizing the data, reads data that are not there, and refuses the whole
//! file (`InvalidParameterData`). Those parameters hold nothing, so [`without_empty`] leaves them
//! out of a copy of the section, and every other byte of the file stays as it was.

/// One record of the parameter section, by its offsets in the file.
#[derive(Debug, Clone, PartialEq)]
struct Record {
    /// File offset of its first byte.
    start: usize,
    /// File offset just past its description.
    end: usize,
    /// File offset of its 16-bit offset to the next record.
    link: usize,
    /// `GROUP` or `GROUP:NAME`.
    name: String,
    /// A parameter with a zero dimension: no data.
    empty: bool,
}

/// Where the parameter section lies in the file and how its 16-bit words are ordered: from the
/// header, which [`super::c3d`] has checked (the section starts at block 2 or later and ends
/// where the data section begins).
fn section(b: &[u8]) -> Option<(usize, usize, bool)> {
    let start = (usize::from(*b.first()?).checked_sub(1)?) * 512;
    let big_endian = *b.get(start + 3)? == 86;
    let word = [*b.get(16)?, *b.get(17)?];
    let data = if big_endian {
        u16::from_be_bytes(word)
    } else {
        u16::from_le_bytes(word)
    };
    let end = (usize::from(data).checked_sub(1)? * 512).min(b.len());
    (start + 4 <= end).then_some((start, end, big_endian))
}

/// The records of the parameter section in chain order; `Err` says which record is broken and
/// where (file offsets).
fn records(b: &[u8]) -> Result<Vec<Record>, String> {
    let (start, end, big_endian) =
        section(b).ok_or("the header does not place a parameter section before the data")?;
    let byte = |i: usize| -> Result<u8, String> {
        if i < end {
            Ok(b[i])
        } else {
            Err(format!(
                "a record at byte {i} runs past the section's end (byte {end})"
            ))
        }
    };
    let mut groups: Vec<(i8, String)> = Vec::new();
    let mut out = Vec::new();
    let mut i = start + 4;
    while i + 1 < end {
        let name_len = usize::from((b[i] as i8).unsigned_abs());
        let id = b[i + 1] as i8;
        if id == 0 || name_len == 0 {
            break;
        }
        let link = i + 2 + name_len;
        let raw_name: String = (i + 2..link)
            .map(|k| byte(k).map(char::from))
            .collect::<Result<_, _>>()?;
        let raw_name = raw_name.trim().to_ascii_uppercase();
        let word = [byte(link)?, byte(link + 1)?];
        let offset = usize::from(if big_endian {
            u16::from_be_bytes(word)
        } else {
            u16::from_le_bytes(word)
        });
        let (name, rec_end, empty) = if id < 0 {
            groups.push((-id, raw_name.clone()));
            let description = usize::from(byte(link + 2)?);
            (raw_name, link + 3 + description, false)
        } else {
            let group = groups
                .iter()
                .find(|(g, _)| *g == id)
                .map_or_else(|| format!("group {id}"), |(_, g)| g.clone());
            let name = format!("{group}:{raw_name}");
            let size = match byte(link + 2)? as i8 {
                -1 | 1 => 1,
                2 => 2,
                4 => 4,
                t => {
                    return Err(format!(
                        "parameter {name} (byte {i}) has data type {t}, expected −1 (char), \
                         1 (byte), 2 (int16) or 4 (float)"
                    ))
                }
            };
            let dimensions = usize::from(byte(link + 3)?);
            let dims: Vec<usize> = (0..dimensions)
                .map(|k| byte(link + 4 + k).map(usize::from))
                .collect::<Result<_, _>>()?;
            let data = link + 4 + dimensions;
            let data_end = data + size * dims.iter().product::<usize>();
            if data_end >= end {
                return Err(format!(
                    "parameter {name} (byte {i}): its data (dimensions {dims:?}) run to byte \
                     {data_end}, past the section's end (byte {end})"
                ));
            }
            let description = usize::from(b[data_end]);
            (name, data_end + 1 + description, dims.contains(&0))
        };
        if rec_end > end {
            return Err(format!(
                "{name} (byte {i}): its description runs to byte {rec_end}, past the section's \
                 end (byte {end})"
            ));
        }
        out.push(Record {
            start: i,
            end: rec_end,
            link,
            name,
            empty,
        });
        if offset == 0 {
            break;
        }
        let next = link + offset;
        if next < rec_end {
            return Err(format!(
                "{} (byte {i}): the next record is said to start at byte {next}, inside this one \
                 (it ends at byte {rec_end})",
                out.last().map_or("a record", |r| r.name.as_str())
            ));
        }
        i = next;
    }
    Ok(out)
}

/// The file with the parameters whose data are empty (a zero dimension) left out of its
/// parameter section, and their names (`GROUP:NAME`); `Ok(None)` when there are none. The
/// records kept are copied as they are, one after the other, each linked to the next; the last
/// is followed by zeros to the section's end, which is where it was, so the data section does
/// not move. `Err`: the walk's located complaint ([`records`]).
pub(crate) fn without_empty(b: &[u8]) -> Result<Option<(Vec<u8>, Vec<String>)>, String> {
    let recs = records(b)?;
    if !recs.iter().any(|r| r.empty) {
        return Ok(None);
    }
    let (start, end, big_endian) = section(b).ok_or("no parameter section")?;
    let mut out = b.to_vec();
    out[start + 4..end].iter_mut().for_each(|z| *z = 0);
    let mut at = start + 4;
    let mut dropped = Vec::new();
    for r in &recs {
        if r.empty {
            dropped.push(r.name.clone());
            continue;
        }
        let len = r.end - r.start;
        out[at..at + len].copy_from_slice(&b[r.start..r.end]);
        // From this record's offset field to the next record, which follows it directly: zeros
        // after the last one end the chain.
        let link = at + (r.link - r.start);
        let offset = u16::try_from(at + len - link)
            .map_err(|_| format!("{} is longer than a 16-bit offset can span", r.name))?;
        let word = if big_endian {
            offset.to_be_bytes()
        } else {
            offset.to_le_bytes()
        };
        out[link..link + 2].copy_from_slice(&word);
        at += len;
    }
    Ok(Some((out, dropped)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A section built here: group POINT (id 1) with USED = 3 (int16) and an empty char
    /// parameter MOVIE_ID (32 × 0) between them, then an empty float TIMES (2 × 0), chained as
    /// a writer chains them; `big` writes the 16-bit words big-endian (MIPS).
    fn file(big: bool) -> Vec<u8> {
        let w = |v: u16| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let mut b = vec![0u8; 3 * 512];
        b[0] = 2;
        b[1] = 0x50;
        b[16..18].copy_from_slice(&w(3));
        let mut s = vec![0u8, 0x50, 1, if big { 86 } else { 84 }];
        let push = |s: &mut Vec<u8>, name: &str, id: i8, body: &[u8]| {
            s.push(name.len() as u8);
            s.push(id as u8);
            s.extend(name.as_bytes());
            s.extend(w(2 + body.len() as u16));
            s.extend(body);
        };
        push(&mut s, "POINT", -1, &[0]);
        push(&mut s, "MOVIE_ID", 1, &[0xff, 2, 32, 0, 0]);
        let mut used = vec![2u8, 0];
        used.extend(w(3));
        used.push(0);
        push(&mut s, "USED", 1, &used);
        push(&mut s, "TIMES", 1, &[4, 2, 2, 0, 1, b'T']);
        b[512..512 + s.len()].copy_from_slice(&s);
        b
    }

    #[test]
    fn empty_parameters_are_left_out_and_the_rest_kept() {
        for big in [false, true] {
            let b = file(big);
            let names: Vec<String> = records(&b).unwrap().into_iter().map(|r| r.name).collect();
            assert_eq!(
                names,
                ["POINT", "POINT:MOVIE_ID", "POINT:USED", "POINT:TIMES"]
            );
            let (out, dropped) = without_empty(&b).unwrap().unwrap();
            assert_eq!(dropped, ["POINT:MOVIE_ID", "POINT:TIMES"]);
            assert_eq!(out.len(), b.len());
            assert_eq!(
                out[..516],
                b[..516],
                "header and section header as they were"
            );
            let kept = records(&out).unwrap();
            let names: Vec<&str> = kept.iter().map(|r| r.name.as_str()).collect();
            assert_eq!(names, ["POINT", "POINT:USED"]);
            let used = &kept[1];
            let value = [out[used.link + 4], out[used.link + 5]];
            let value = if big {
                u16::from_be_bytes(value)
            } else {
                u16::from_le_bytes(value)
            };
            assert_eq!(value, 3, "the parameter's data copied as they were");
            assert!(out[used.end..1024].iter().all(|&z| z == 0));
            assert!(
                without_empty(&out).unwrap().is_none(),
                "nothing left to drop"
            );
        }
    }

    #[test]
    fn a_broken_section_is_a_located_error() {
        let mut b = file(false);
        // TIMES said to hold 2 × 200 floats: past the section's end.
        let times = records(&b).unwrap()[3].clone();
        b[times.link + 5] = 200;
        let e = records(&b).unwrap_err();
        assert!(
            e.contains("POINT:TIMES") && e.contains("past the section"),
            "{e}"
        );
        let mut b = file(false);
        b[times.link + 2] = 3;
        let e = records(&b).unwrap_err();
        assert!(e.contains("data type 3"), "{e}");
    }
}

//! The `diagnosis.json` documents: every one carries `schema_version` and names its fields with
//! their units (`fitted_rms_m`, `force_rms_n`, `run_time_s`; pairs as `<name>_<x unit>_<y unit>`),
//! and states the elastic constants as Lamé's λ, μ and E, ν (`docs/json-outputs.md`).
//!
//! The report structs keep the names the algorithms use; the JSON layer renames them here, path
//! by path, so that a field added to a report appears (under its own name) without touching this
//! file, and the algorithms' files need no serde attributes.

use std::path::{Path, PathBuf};

use palpate_fem::io::atomic::write_atomic;
use palpate_fem::names::Elastic;
use serde_json::{Map, Value};

/// The `schema_version` of every `diagnosis.json` (static, motion, runs, curves).
pub const SCHEMA_VERSION: u32 = 1;

/// Renames keys in every object reached by `path` (keys separated by `.`, `key[]` = every element
/// of the array `key`, a bare `[]` = every element of the array reached so far; `""` = the
/// document itself). A key that is absent is left alone.
pub(crate) fn rename(v: &mut Value, path: &str, renames: &[(&str, &str)]) {
    each_object(v, path, &mut |obj: &mut Map<String, Value>| {
        // Rebuilt in order: a renamed field stays where it was.
        *obj = std::mem::take(obj)
            .into_iter()
            .map(|(k, x)| match renames.iter().find(|(from, _)| *from == k) {
                Some((_, to)) => ((*to).to_string(), x),
                None => (k, x),
            })
            .collect();
    });
}

/// Calls `f` on every object reached by `path` (as in [`rename`]).
pub(crate) fn each_object(v: &mut Value, path: &str, f: &mut dyn FnMut(&mut Map<String, Value>)) {
    let mut parts = path.split('.').filter(|p| !p.is_empty());
    reach(v, &mut parts, f);
}

fn reach<'a>(
    v: &mut Value,
    parts: &mut (dyn Iterator<Item = &'a str> + 'a),
    f: &mut dyn FnMut(&mut Map<String, Value>),
) {
    match parts.next() {
        None => {
            if let Value::Object(o) = v {
                f(o);
            }
        }
        Some(part) => {
            let rest: Vec<&'a str> = parts.collect();
            let (key, each) = match part.strip_suffix("[]") {
                Some(k) => (k, true),
                None => (part, false),
            };
            // A bare `[]` walks the elements of the array reached so far (arrays of arrays).
            let child = if key.is_empty() {
                Some(v)
            } else {
                v.as_object_mut().and_then(|o| o.get_mut(key))
            };
            let Some(child) = child else {
                return;
            };
            if each {
                if let Value::Array(items) = child {
                    for item in items {
                        reach(item, &mut rest.iter().copied(), f);
                    }
                }
            } else {
                reach(child, &mut rest.iter().copied(), f);
            }
        }
    }
}

/// Lamé's λ, μ, E and ν as a JSON object.
pub(crate) fn elastic(e: &Elastic) -> Value {
    serde_json::to_value(e).unwrap_or(Value::Null)
}

/// `doc` with `schema_version` (and `kind`) first, as pretty JSON text.
pub(crate) fn finish(kind: &str, doc: Value) -> Result<String, serde_json::Error> {
    let mut out = Map::new();
    out.insert("schema_version".into(), SCHEMA_VERSION.into());
    out.insert("kind".into(), kind.into());
    if let Value::Object(o) = doc {
        out.extend(o);
    }
    serde_json::to_string_pretty(&Value::Object(out))
}

/// Creates `dir` and writes `diagnosis.md`, then `diagnosis.json` (made by `json` once the
/// markdown is written), into it; returns their paths. The motion and runs reports begin so, and
/// word the errors alike (the folder named, the rest as the error says).
pub(crate) fn write_md_and_json(
    dir: &Path,
    md: &str,
    json: impl FnOnce() -> Result<String, serde_json::Error>,
) -> Result<Vec<PathBuf>, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut out = Vec::new();
    let p = dir.join("diagnosis.md");
    write_atomic(&p, md.as_bytes()).map_err(|e| e.to_string())?;
    out.push(p);
    let p = dir.join("diagnosis.json");
    let json = json().map_err(|e| e.to_string())?;
    write_atomic(&p, json.as_bytes()).map_err(|e| e.to_string())?;
    out.push(p);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renames_follow_the_path() {
        let mut v = serde_json::json!({
            "rms": 1.0,
            "steps": [{"before": {"rms": 2.0}}, {"before": {"rms": 3.0}, "rms": 4.0}],
        });
        rename(&mut v, "steps[].before", &[("rms", "rms_m")]);
        let mut pairs = serde_json::json!({"runs": [[{"chi2": 1.0}], [{"chi2": 2.0}]]});
        rename(&mut pairs, "runs[].[]", &[("chi2", "chi2_m2")]);
        assert_eq!(pairs["runs"][1][0]["chi2_m2"], 2.0);
        rename(&mut v, "", &[("rms", "total_rms_m"), ("absent", "x")]);
        assert_eq!(
            v,
            serde_json::json!({
                "total_rms_m": 1.0,
                "steps": [{"before": {"rms_m": 2.0}}, {"before": {"rms_m": 3.0}, "rms": 4.0}],
            })
        );
        let text = finish("static", v).unwrap();
        assert!(text.starts_with("{\n  \"schema_version\": 1,\n  \"kind\": \"static\""));
    }
}

//! JSON documents palpate writes: each carries `schema_version` (first) so that a reader can tell
//! which layout it holds, and names its fields with their units (`rms_m`, `young_modulus_pa`).
//! The documents and their versions are listed in `docs/json-outputs.md`.

use serde::{Serialize, Serializer};

/// `document` with `"schema_version": version` as its first field (the document must serialise
/// as a JSON object).
#[derive(Debug, Clone, Copy)]
pub struct Versioned<'a, T: ?Sized> {
    /// The version of the document's layout.
    pub version: u32,
    /// The document.
    pub document: &'a T,
}

impl<'a, T: Serialize + ?Sized> Versioned<'a, T> {
    /// Wraps `document`.
    pub fn new(version: u32, document: &'a T) -> Self {
        Self { version, document }
    }
}

impl<T: Serialize + ?Sized> Serialize for Versioned<'_, T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        #[derive(Serialize)]
        struct Doc<'a, T: ?Sized> {
            schema_version: u32,
            #[serde(flatten)]
            document: &'a T,
        }
        Doc {
            schema_version: self.version,
            document: self.document,
        }
        .serialize(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Serialize)]
    struct Doc {
        rms_m: f64,
    }

    #[test]
    fn the_version_comes_first() {
        let text = serde_json::to_string(&Versioned::new(3, &Doc { rms_m: 0.5 })).unwrap();
        assert_eq!(text, r#"{"schema_version":3,"rms_m":0.5}"#);
    }
}

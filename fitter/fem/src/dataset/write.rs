//! Writing a static dataset folder (format: `docs/dataset.md`), e.g. synthetic data from the
//! specimen generator. Each file is written atomically; `dataset.toml` is written last, so a
//! folder whose `dataset.toml` is new holds a complete new dataset.

use super::read::{DatasetError, CONTACTS_CSV, DATASET_TOML, MARKERS_CSV, MEASUREMENTS_CSV};
use super::StaticDataset;
use crate::io::atomic::write_atomic;
use crate::mesh::gmsh::write_msh;
use serde::Serialize;
use std::fmt::Write as _;
use std::path::Path;

/// Name of the mesh file [`StaticDataset::write`] writes.
pub const MESH_MSH: &str = "mesh.msh";

#[derive(Serialize)]
struct DatasetTomlOut<'a> {
    name: &'a str,
    description: &'a str,
    units: &'a str,
    mesh: &'a str,
    clamps: [&'a str; 1],
    probe_radius: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    marker_noise: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    gravity: Option<[f64; 3]>,
    #[serde(skip_serializing_if = "Option::is_none")]
    marker_standoff: Option<f64>,
}

impl StaticDataset {
    /// Writes the dataset to the folder `dir` (created if needed): `dataset.toml`, `mesh.msh`,
    /// `markers.csv`, `measurements.csv` (one row per observed marker) and `contacts.csv` (always
    /// with the `radius` column). Numbers are printed so that they read back bit for bit.
    pub fn write(&self, dir: impl AsRef<Path>) -> Result<(), DatasetError> {
        let dir = dir.as_ref();
        let put = |name: &str, text: String| {
            let file = dir.join(name);
            write_atomic(&file, text.as_bytes()).map_err(|e| DatasetError::Write {
                file,
                message: format!("{e:#}"),
            })
        };
        // Ids go into comma-separated files without quoting: refuse those that would not read back.
        let ids = self.markers.iter().map(|m| (MARKERS_CSV, "marker", &m.id));
        let ids = ids.chain(
            self.measurements
                .iter()
                .map(|m| (CONTACTS_CSV, "measurement", &m.id)),
        );
        for (name, field, id) in ids {
            if id.is_empty()
                || id.starts_with('#')
                || id.contains([',', '\n', '\r'])
                || id.trim() != id
            {
                return Err(DatasetError::Write {
                    file: dir.join(name),
                    message: format!("{field} id {id:?} is empty, starts with '#', or holds a comma, newline or edge space"),
                });
            }
        }
        write_msh(&self.mesh, dir.join(MESH_MSH))?;

        let mut s = String::from("marker,x,y,z\n");
        for m in &self.markers {
            let _ = writeln!(
                s,
                "{},{:?},{:?},{:?}",
                m.id, m.rest[0], m.rest[1], m.rest[2]
            );
        }
        put(MARKERS_CSV, s)?;

        let mut s = String::from("measurement,marker,x,y,z\n");
        for m in &self.measurements {
            for (k, x) in &m.observed {
                let _ = writeln!(
                    s,
                    "{},{},{:?},{:?},{:?}",
                    m.id, self.markers[*k].id, x[0], x[1], x[2]
                );
            }
        }
        put(MEASUREMENTS_CSV, s)?;

        let mut s = String::from("measurement,x,y,z,fx,fy,fz,radius\n");
        for m in &self.measurements {
            let (c, f) = (m.contact, m.force);
            let _ = writeln!(
                s,
                "{},{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
                m.id, c[0], c[1], c[2], f[0], f[1], f[2], m.radius
            );
        }
        put(CONTACTS_CSV, s)?;

        let meta = DatasetTomlOut {
            name: &self.name,
            description: &self.description,
            units: "SI",
            mesh: MESH_MSH,
            clamps: [&self.fixed_group],
            probe_radius: self.probe_radius,
            marker_noise: self.marker_noise,
            gravity: self.gravity,
            marker_standoff: self.marker_standoff,
        };
        let text = toml::to_string(&meta).map_err(|e| DatasetError::Write {
            file: dir.join(DATASET_TOML),
            message: e.to_string(),
        })?;
        put(DATASET_TOML, text)
    }
}

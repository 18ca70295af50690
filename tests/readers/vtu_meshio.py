"""Every kind of VTU palpate writes, read by meshio — a reader palpate did not write.

Run by .ci/run after the tests (it needs target/release/palpate):
    python3 tests/readers/vtu_meshio.py target/release/palpate OUT_DIR
It makes `palpate simulate`'s deformed.vtu and `palpate fit`'s fit.vtu, reads both with meshio and
checks the point and cell counts against the mesh and one value in each: the displacement of the
node under the probe against displacements.csv, and the fitted Young's modulus against report.json.
Exits non-zero, naming the file and the check, on the first mismatch.
"""
import csv
import re
import subprocess
import sys
from pathlib import Path

import meshio


def fail(what):
    print(f"vtu_meshio: FAILED: {what}")
    sys.exit(1)


palpate, out = sys.argv[1], Path(sys.argv[2])
out.mkdir(parents=True, exist_ok=True)
mesh = meshio.read("models/sponge/sponge.msh")
n_points = len(mesh.points)
n_tets = sum(len(c.data) for c in mesh.cells if c.type == "tetra")

# 1. simulate: rest points + displacement + young_modulus_pa.
sim = out / "simulate"
subprocess.run([palpate, "simulate", "--mesh", "models/sponge/sponge.msh", "--young", "2e4",
                "--poisson", "0.3", "--fixed", "bottom", "--contact", "0.05,0.05,0.05",
                "--force", "0,0,-0.5", "-o", str(sim)], check=True, stdout=subprocess.DEVNULL)
m = meshio.read(sim / "deformed.vtu")
tets = sum(len(c.data) for c in m.cells if c.type == "tetra")
if (len(m.points), tets) != (n_points, n_tets):
    fail(f"deformed.vtu: {len(m.points)} points / {tets} tets, the mesh has {n_points} / {n_tets}")
if abs(m.points - mesh.points).max() > 1e-6:
    fail("deformed.vtu: points are not the rest positions")
u = m.point_data["displacement"]
rows = list(csv.reader(open(sim / "displacements.csv")))
tags = list(m.point_data["node_tag"].astype(int))
moved = max(rows[1:], key=lambda r: abs(float(r[3])))
i = tags.index(int(float(moved[0])))
if abs(u[i][2] - float(moved[3])) > 1e-9 + 1e-6 * abs(float(moved[3])):
    fail(f"deformed.vtu: displacement {u[i][2]} at node {moved[0]}, displacements.csv says {moved[3]}")
e = m.cell_data["young_modulus_pa"][0].ravel()
if abs(e.min() - 2e4) > 1 or abs(e.max() - 2e4) > 1:
    fail(f"deformed.vtu: young_modulus_pa {e.min()}–{e.max()}, expected 2e4")
print(f"vtu_meshio: {sim / 'deformed.vtu'}: {len(m.points)} points, {tets} tets, u_z = {u[i][2]:.4e} m at node {moved[0]} ✓")

# 2. fit: the report's fit.vtu.
fit = out / "fit" / "model.palp"
subprocess.run([palpate, "fit", "models/sponge/dataset", "--material", "linear-homogeneous",
                "-o", str(fit)], check=True, stdout=subprocess.DEVNULL)
report = out / "fit" / "model.report"
m = meshio.read(report / "fit.vtu")
tets = sum(len(c.data) for c in m.cells if c.type == "tetra")
ds_mesh = meshio.read("models/sponge/dataset/mesh.msh")
if len(m.points) != len(ds_mesh.points):
    fail(f"fit.vtu: {len(m.points)} points, the dataset mesh has {len(ds_mesh.points)}")
e = m.cell_data["young_modulus_pa"][0].ravel()
nu = m.cell_data["poisson_ratio"][0].ravel()
if tets != len(e):
    fail(f"fit.vtu: {tets} tets but {len(e)} young_modulus_pa values")
if not (0 < nu.min() and nu.max() < 0.5):
    fail(f"fit.vtu: poisson_ratio {nu.min()}–{nu.max()}")
# The homogeneous fit's E, as report.json states it.
# (schema 1 names it young_modulus_pa; files written before it, young)
young = [float(v) for v in re.findall(r'"young(?:_modulus_pa)?": *([0-9.eE+-]+)', (report / "report.json").read_text())]
if not young or abs(e[0] - young[0]) > 1e-6 * young[0]:
    fail(f"fit.vtu: young_modulus_pa {e[0]}, report.json says {young[:1]}")
if "marker_error_m" not in m.point_data:
    fail("fit.vtu: no marker_error_m point array")
print(f"vtu_meshio: {report / 'fit.vtu'}: {len(m.points)} points, {tets} tets, E = {e[0]:.4e} Pa, ν = {nu[0]:.3f} ✓")

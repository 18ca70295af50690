"""Mesh a closed STL surface into linear tetrahedra for palpate (Gmsh MSH 4.1 ASCII), with named
physical groups for the faces a dataset refers to (clamps, probed faces).

Run (Gmsh 4.15.2 from PyPI, `pip install gmsh==4.15.2`):

    python3 models/mesh_stl.py OBJECT.stl OUT.msh --scale 0.001 --size 5 \
        --group clamp:z=100 --group free_end:z=0

- `--scale`: factor from STL units to metres (0.001 for an STL in millimetres).
- `--size`: target element size, in STL units.
- `--group NAME:AXIS=VALUE`: the boundary faces lying in the plane AXIS = VALUE (STL units, within
  `--tol`) become the surface physical group NAME; repeat for several groups. The volume is the
  physical group `body`.

The STL must be closed (watertight). Faces are recovered from the triangulation by Gmsh's
classification at `--angle` degrees (sharp edges of a box at 90° are kept). The run is
deterministic (`Mesh.RandomSeed` fixed), so the same command gives the same mesh.
"""
import argparse
import math

import gmsh

ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
ap.add_argument("stl")
ap.add_argument("out")
ap.add_argument("--scale", type=float, default=1.0)
ap.add_argument("--size", type=float, required=True)
ap.add_argument("--group", action="append", default=[])
ap.add_argument("--angle", type=float, default=40.0)
ap.add_argument("--tol", type=float, default=1e-6)
args = ap.parse_args()

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("body")
gmsh.merge(args.stl)
gmsh.model.mesh.classifySurfaces(math.radians(args.angle), True, True, math.pi)
gmsh.model.mesh.createGeometry()
surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
loop = gmsh.model.geo.addSurfaceLoop(surfaces)
volume = gmsh.model.geo.addVolume([loop])
gmsh.model.geo.synchronize()

for spec in args.group:
    name, plane = spec.split(":", 1)
    axis, value = plane.split("=", 1)
    k = "xyz".index(axis.strip())
    value = float(value)
    tags = []
    for dim, tag in gmsh.model.getEntities(2):
        box = gmsh.model.getBoundingBox(dim, tag)
        lo, hi = box[k], box[k + 3]
        if abs(lo - value) <= args.tol * max(1.0, abs(value)) + 1e-9 and abs(hi - value) <= args.tol * max(1.0, abs(value)) + 1e-9:
            tags.append(tag)
    if not tags:
        raise SystemExit(f"--group {spec}: no boundary face lies in the plane {axis} = {value}")
    gmsh.model.addPhysicalGroup(2, tags, name=name)
gmsh.model.addPhysicalGroup(3, [volume], name="body")

gmsh.option.setNumber("Mesh.MeshSizeMin", args.size)
gmsh.option.setNumber("Mesh.MeshSizeMax", args.size)
gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
gmsh.option.setNumber("Mesh.ElementOrder", 1)
gmsh.option.setNumber("Mesh.RandomSeed", 1)
gmsh.model.mesh.generate(3)
gmsh.option.setNumber("Mesh.ScalingFactor", args.scale)
gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
gmsh.option.setNumber("Mesh.Binary", 0)
gmsh.option.setNumber("Mesh.SaveAll", 0)
gmsh.write(args.out)
tets, _ = gmsh.model.mesh.getElementsByType(4)
nodes, _, _ = gmsh.model.mesh.getNodes()
print(f"{args.out}: {len(nodes)} nodes, {len(tets)} tetrahedra, groups {[g.split(':')[0] for g in args.group] + ['body']}")
gmsh.finalize()

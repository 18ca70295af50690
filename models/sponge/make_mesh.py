"""The bundled default object: a sponge-like block 10 x 10 x 5 cm (thesis, seed 000 ch. 7), bottom fixed.

Run (Gmsh 4.15.2 from PyPI, `pip install gmsh==4.15.2`):

    python3 make_mesh.py            # writes sponge.msh beside this script

Units are metres. Physical groups (surfaces):
    "bottom"  z = 0        (the fixed, Dirichlet face)
    "top"     z = 0.05     (the probed face)
    "sides"   x = 0, x = 0.1, y = 0, y = 0.1
and the volume "sponge". The mesh is linear tetrahedra (Gmsh's default Delaunay 3D algorithm),
written as MSH 4.1 ASCII; the target element size H gives about 4,000-5,000 tetrahedra.
"""
import os
import sys

import gmsh

LX, LY, LZ = 0.10, 0.10, 0.05
H = 0.0085  # target element size (m)

here = os.path.dirname(os.path.abspath(__file__))
out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "sponge.msh")

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("sponge")
box = gmsh.model.occ.addBox(0, 0, 0, LX, LY, LZ)
gmsh.model.occ.synchronize()

bottom, top, sides = [], [], []
for dim, tag in gmsh.model.getEntities(2):
    x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(dim, tag)
    if abs(z1) < 1e-6:
        bottom.append(tag)
    elif abs(z0 - LZ) < 1e-6:
        top.append(tag)
    else:
        sides.append(tag)
assert len(bottom) == 1 and len(top) == 1 and len(sides) == 4, (bottom, top, sides)
gmsh.model.addPhysicalGroup(2, bottom, name="bottom")
gmsh.model.addPhysicalGroup(2, top, name="top")
gmsh.model.addPhysicalGroup(2, sides, name="sides")
gmsh.model.addPhysicalGroup(3, [box], name="sponge")

gmsh.option.setNumber("Mesh.MeshSizeMin", H)
gmsh.option.setNumber("Mesh.MeshSizeMax", H)
gmsh.option.setNumber("Mesh.ElementOrder", 1)
gmsh.option.setNumber("Mesh.RandomSeed", 1)  # same mesh on every run
gmsh.model.mesh.generate(3)
gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
gmsh.option.setNumber("Mesh.Binary", 0)
gmsh.write(out)

tets, _ = gmsh.model.mesh.getElementsByType(4)
nodes, _, _ = gmsh.model.mesh.getNodes()
print(f"{out}: {len(nodes)} nodes, {len(tets)} tetrahedra")
gmsh.finalize()

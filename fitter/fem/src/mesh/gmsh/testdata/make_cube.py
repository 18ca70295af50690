"""Test fixtures for the Gmsh reader: a unit cube, ~100 tetrahedra, written as MSH 4.1 ASCII and binary.

    python3 make_cube.py cube-ascii.msh 0
    python3 make_cube.py cube-binary.msh 1

Physical groups: "bottom" (surface z = 0), "body" (the volume) and an unnamed point group
(tag 3) on the corner (0, 0, 1). Gmsh 4.15.2 (PyPI `gmsh`) printed: bottom 12 nodes, body 45
nodes, 100 tetrahedra.
"""
import sys

import gmsh

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("cube")
gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
gmsh.model.occ.synchronize()
gmsh.model.addPhysicalGroup(2, [5], name="bottom")
gmsh.model.addPhysicalGroup(3, [1], name="body")
gmsh.model.addPhysicalGroup(0, [1])
gmsh.model.mesh.setSize(gmsh.model.getEntities(0), 0.6)
gmsh.model.mesh.generate(3)
gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
gmsh.option.setNumber("Mesh.Binary", int(sys.argv[2]))
gmsh.write(sys.argv[1])
n, _ = gmsh.model.mesh.getNodesForPhysicalGroup(2, 1)
print("bottom nodes", len(n))
n, _ = gmsh.model.mesh.getNodesForPhysicalGroup(3, 2)
print("body nodes", len(n))
t, _ = gmsh.model.mesh.getElementsByType(4)
print("tets", len(t))
gmsh.finalize()

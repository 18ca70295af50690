"""Test fixtures for reading 10-node tetrahedra: one small cylinder mesh (radius 1 cm, length 4 cm,
a curved boundary) written by Gmsh's own writer at order 1, then raised to order 2 and written again:

    cyl-order1.msh          MSH 4.1 ASCII, 4-node tetrahedra
    cyl-order2.msh          MSH 4.1 ASCII, the same mesh raised to 10-node tetrahedra
    cyl-order2-binary.msh   the same, MSH 4.1 binary
    cyl-order2-22.msh       the same, MSH 2.2 ASCII

Raising the order keeps the corner nodes and their tags and adds a node on each edge; on the curved
surface Gmsh moves the edge node onto the cylinder, off the straight edge's midpoint (the script
prints the largest such offset over the edge's length). Physical groups: "clamp" (the face z = 0)
and "body" (the volume). Made with gmsh 4.15.2 (PyPI):

    cd fitter/fem/src/mesh/gmsh/testdata && python3 make_order2.py
"""
import gmsh
import numpy as np

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("cyl")
gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, 0.04, 0.01)
gmsh.model.occ.synchronize()
faces = gmsh.model.getEntities(2)
clamp = [t for d, t in faces if abs(gmsh.model.occ.getCenterOfMass(d, t)[2]) < 1e-9]
gmsh.model.addPhysicalGroup(2, clamp, name="clamp")
gmsh.model.addPhysicalGroup(3, [1], name="body")
gmsh.model.mesh.setSize(gmsh.model.getEntities(0), 0.012)
gmsh.model.mesh.generate(3)
gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
gmsh.option.setNumber("Mesh.Binary", 0)
gmsh.write("cyl-order1.msh")
tags1, _ = gmsh.model.mesh.getElementsByType(4)
gmsh.model.mesh.setOrder(2)
gmsh.write("cyl-order2.msh")
gmsh.option.setNumber("Mesh.Binary", 1)
gmsh.write("cyl-order2-binary.msh")
gmsh.option.setNumber("Mesh.Binary", 0)
gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
gmsh.write("cyl-order2-22.msh")
tags2, nodes2 = gmsh.model.mesh.getElementsByType(11)
ntags, coords, _ = gmsh.model.mesh.getNodes()
xyz = dict(zip(ntags, coords.reshape(-1, 3)))
edges = [(0, 1), (1, 2), (2, 0), (0, 3), (2, 3), (1, 3)]
bow = 0.0
for e in np.asarray(nodes2).reshape(-1, 10):
    for k, (a, b) in enumerate(edges):
        pa, pb, m = xyz[e[a]], xyz[e[b]], xyz[e[4 + k]]
        bow = max(bow, np.linalg.norm(m - 0.5 * (pa + pb)) / np.linalg.norm(pa - pb))
print("tets", len(tags1), len(tags2), "nodes", len(ntags), "largest edge bow", bow)
gmsh.finalize()

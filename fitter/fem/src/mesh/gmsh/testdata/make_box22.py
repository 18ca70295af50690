"""Test fixtures for MSH 2.2 reading: one small box mesh (42 tetrahedra), written four times by
tools palpate does not contain:

    box-41.msh         MSH 4.1 ASCII, Gmsh's writer
    box-22-gmsh.msh    MSH 2.2 ASCII, Gmsh's writer (Mesh.MshFileVersion = 2.2)
    box-22-meshio.msh  MSH 2.2 ASCII, meshio's writer (file_format="gmsh22"), from box-41.msh
    box-22-binary.msh  MSH 2.2 binary, Gmsh's writer (Mesh.Binary = 1)

Made with Python 3.11.7, gmsh 4.15.2 and meshio 5.3.5 (PyPI):

    python3 -m venv /tmp/venv-msh && /tmp/venv-msh/bin/pip install gmsh==4.15.2 meshio==5.3.5
    cd fitter/fem/src/mesh/gmsh/testdata && /tmp/venv-msh/bin/python make_box22.py

Box 0.1 x 0.06 x 0.04 m. Physical groups: "fixed" (surface z = 0), "top" (surface z = 0.04),
"body" and "silicone" (both the volume: Gmsh's MSH 2.2 writer then lists every tetrahedron twice,
once per group) and an unnamed point group (tag 5) on the corner (0, 0, 0.04). meshio keeps one
physical tag per element, so in its file the tetrahedra are in "body" only and "silicone" is
empty. This script prints the counts the test checks.
"""
import gmsh
import meshio

gmsh.initialize()
gmsh.option.setNumber("General.Terminal", 0)
gmsh.model.add("box")
gmsh.model.occ.addBox(0, 0, 0, 0.1, 0.06, 0.04)
gmsh.model.occ.synchronize()
gmsh.model.addPhysicalGroup(2, [5], name="fixed")
gmsh.model.addPhysicalGroup(2, [6], name="top")
gmsh.model.addPhysicalGroup(3, [1], name="body")
gmsh.model.addPhysicalGroup(3, [1], name="silicone")
gmsh.model.addPhysicalGroup(0, [1])
gmsh.model.mesh.setSize(gmsh.model.getEntities(0), 0.05)
gmsh.model.mesh.generate(3)
gmsh.option.setNumber("Mesh.Binary", 0)
for version, name in [(4.1, "box-41.msh"), (2.2, "box-22-gmsh.msh")]:
    gmsh.option.setNumber("Mesh.MshFileVersion", version)
    gmsh.write(name)
gmsh.option.setNumber("Mesh.Binary", 1)
gmsh.write("box-22-binary.msh")
gmsh.option.setNumber("Mesh.Binary", 0)
for dim, tag in gmsh.model.getPhysicalGroups():
    nodes, _ = gmsh.model.mesh.getNodesForPhysicalGroup(dim, tag)
    print(dim, tag, repr(gmsh.model.getPhysicalName(dim, tag)), "nodes", len(nodes))
tets, _ = gmsh.model.mesh.getElementsByType(4)
print("tets", len(tets))
gmsh.finalize()

meshio.write("box-22-meshio.msh", meshio.read("box-41.msh"), file_format="gmsh22", binary=False)

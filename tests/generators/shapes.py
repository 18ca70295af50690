"""Shapes for the independent generator, meshed with Gmsh's Python API (gmsh==4.15.2).

Every shape stands on z = 0 (the fixed face, physical group "bottom"); the probed and marked faces are
"top" (the flat top, or the spherical cap of the dome) and "sides". Units: metres.

Two meshes of one shape are made by two independent Gmsh runs:
- the *truth* mesh: fine, graded towards the probed surfaces (Distance + Threshold fields),
  Gmsh's Delaunay 3-D algorithm, its own random seed;
- the *dataset* mesh: uniform, coarse (~1-3k tets), Gmsh's HXT 3-D algorithm and another 2-D
  algorithm, another seed. On curved faces its facets are chords of the true surface (inside it).
"""
from __future__ import annotations

import math
import os
import tempfile

import gmsh
import numpy as np


def classify_flat(dim, tag, height):
    """Names a face of a flat-bottomed, flat-topped solid of this height by its centre of mass:
    "bottom" at z = 0, "top" at z = height, "sides" otherwise (Block and Cylinder share it)."""
    z = gmsh.model.occ.getCenterOfMass(dim, tag)[2]
    if z < 1e-7:
        return "bottom"
    if z > height - 1e-7:
        return "top"
    return "sides"


class Shape:
    kind: str

    def build(self):  # adds the OCC volume; returns the volume tag
        raise NotImplementedError

    def classify(self, dim, tag):  # "bottom", "top" or "sides"
        raise NotImplementedError

    def probed_groups(self):
        return ["top"]

    def volume(self):
        raise NotImplementedError

    def extent(self):
        """(xmin, ymin, zmin, xmax, ymax, zmax)."""
        raise NotImplementedError

    def top_z(self, x, y):
        """Height of the top surface above (x, y) (vectorised)."""
        raise NotImplementedError

    def dist_inside(self, p):
        """Distance from interior points p (n,3) to the surface (>0 inside)."""
        raise NotImplementedError

    def sample_probe(self, rng, margin):
        """A random contact point on a probed face at least `margin` from its edges, and the outward normal."""
        raise NotImplementedError

    def params(self):
        return {k: v for k, v in self.__dict__.items() if not k.startswith("_")}


class Block(Shape):
    kind = "block"

    def __init__(self, L, W, H):
        self.L, self.W, self.H = L, W, H

    def build(self):
        return gmsh.model.occ.addBox(0, 0, 0, self.L, self.W, self.H)

    def classify(self, dim, tag):
        return classify_flat(dim, tag, self.H)

    def volume(self):
        return self.L * self.W * self.H

    def extent(self):
        return (0, 0, 0, self.L, self.W, self.H)

    def top_z(self, x, y):
        return np.full_like(np.asarray(x, float), self.H)

    def dist_inside(self, p):
        return np.min(np.stack([p[:, 0], self.L - p[:, 0], p[:, 1], self.W - p[:, 1], p[:, 2], self.H - p[:, 2]]), axis=0)

    def sample_probe(self, rng, margin):
        x = rng.uniform(margin, self.L - margin)
        y = rng.uniform(margin, self.W - margin)
        return np.array([x, y, self.H]), np.array([0.0, 0.0, 1.0])


class Dome(Shape):
    """A block L x W x Hb whose top is a spherical cap: the cap rises hc above the block's top at
    the centre and meets the side walls delta above it at the corners."""

    kind = "dome"

    def __init__(self, L, W, Hb, hc):
        self.L, self.W, self.Hb, self.hc = L, W, Hb, hc
        d = 0.5 * math.hypot(L, W)
        self.delta = 0.35 * hc
        h = hc - self.delta
        self.R = (d * d + h * h) / (2 * h)
        self.zc = Hb + hc - self.R
        self.cx, self.cy = L / 2, W / 2

    def build(self):
        occ = gmsh.model.occ
        box = occ.addBox(0, 0, 0, self.L, self.W, self.Hb + self.hc)
        ball = occ.addSphere(self.cx, self.cy, self.zc, self.R)
        low = occ.addBox(0, 0, 0, self.L, self.W, self.Hb)
        fused, _ = occ.fuse([(3, ball)], [(3, low)])
        out, _ = occ.intersect([(3, box)], fused)
        assert len(out) == 1, out
        return out[0][1]

    def classify(self, dim, tag):
        z = gmsh.model.occ.getCenterOfMass(dim, tag)[2]
        if z < 1e-7:
            return "bottom"
        if gmsh.model.getType(dim, tag) == "Sphere":
            return "top"
        return "sides"

    def volume(self):
        # numerical: block + cap over the footprint
        n = 200
        xs = (np.arange(n) + 0.5) / n * self.L
        ys = (np.arange(n) + 0.5) / n * self.W
        Xg, Yg = np.meshgrid(xs, ys)
        return float(np.mean(self.top_z(Xg, Yg)) * self.L * self.W)

    def extent(self):
        return (0, 0, 0, self.L, self.W, self.Hb + self.hc)

    def top_z(self, x, y):
        r2 = (np.asarray(x) - self.cx) ** 2 + (np.asarray(y) - self.cy) ** 2
        return self.zc + np.sqrt(np.maximum(self.R**2 - r2, 0.0))

    def dist_inside(self, p):
        c = np.array([self.cx, self.cy, self.zc])
        ds = self.R - np.linalg.norm(p - c, axis=1)
        return np.min(np.stack([p[:, 0], self.L - p[:, 0], p[:, 1], self.W - p[:, 1], p[:, 2], ds]), axis=0)

    def sample_probe(self, rng, margin):
        x = rng.uniform(margin, self.L - margin)
        y = rng.uniform(margin, self.W - margin)
        z = float(self.top_z(x, y))
        p = np.array([x, y, z])
        n = p - np.array([self.cx, self.cy, self.zc])
        return p, n / np.linalg.norm(n)


class Cylinder(Shape):
    """A standing cylinder of radius R and height H, axis along z through (R, R)."""

    kind = "cylinder"

    def __init__(self, R, H):
        self.R, self.H = R, H
        self.cx = self.cy = R

    def build(self):
        return gmsh.model.occ.addCylinder(self.cx, self.cy, 0, 0, 0, self.H, self.R)

    def classify(self, dim, tag):
        return classify_flat(dim, tag, self.H)

    def probed_groups(self):
        return ["top", "sides"]

    def volume(self):
        return math.pi * self.R**2 * self.H

    def extent(self):
        return (0, 0, 0, 2 * self.R, 2 * self.R, self.H)

    def top_z(self, x, y):
        return np.full_like(np.asarray(x, float), self.H)

    def dist_inside(self, p):
        rho = np.hypot(p[:, 0] - self.cx, p[:, 1] - self.cy)
        return np.min(np.stack([self.R - rho, p[:, 2], self.H - p[:, 2]]), axis=0)

    def sample_probe(self, rng, margin):
        top_area = math.pi * max(self.R - margin, 0) ** 2
        side_area = 2 * math.pi * self.R * max(self.H - 2 * margin - 0.01, 0)
        if rng.uniform() < top_area / (top_area + side_area):
            r = (self.R - margin) * math.sqrt(rng.uniform())
            t = rng.uniform(0, 2 * math.pi)
            return np.array([self.cx + r * math.cos(t), self.cy + r * math.sin(t), self.H]), np.array([0, 0, 1.0])
        t = rng.uniform(0, 2 * math.pi)
        z = rng.uniform(margin + 0.01, self.H - margin)
        n = np.array([math.cos(t), math.sin(t), 0.0])
        return np.array([self.cx + self.R * n[0], self.cy + self.R * n[1], z]), n


def draw_shape(rng, kind):
    """Random dimensions (m) within the ranges written here."""
    if kind == "block":
        return Block(L=rng.uniform(0.06, 0.12), W=rng.uniform(0.06, 0.12), H=rng.uniform(0.03, 0.06))
    if kind == "dome":
        return Dome(L=rng.uniform(0.06, 0.11), W=rng.uniform(0.06, 0.11), Hb=rng.uniform(0.025, 0.045), hc=rng.uniform(0.01, 0.025))
    if kind == "cylinder":
        return Cylinder(R=rng.uniform(0.025, 0.045), H=rng.uniform(0.04, 0.08))
    raise ValueError(f"unknown shape {kind!r}")


class MeshData:
    """Nodes X (n,3), node tags (n,), tets T (ne,4) 0-based, boundary triangles per group (0-based)."""

    def __init__(self, X, tags, T, faces):
        self.X, self.tags, self.T, self.faces = X, tags, T, faces


def _extract():
    tags, coords, _ = gmsh.model.mesh.getNodes()
    X = coords.reshape(-1, 3)
    index = {int(t): i for i, t in enumerate(tags)}
    lut = np.vectorize(index.__getitem__)
    et, en = gmsh.model.mesh.getElementsByType(4)
    T = lut(en.reshape(-1, 4).astype(np.int64))
    faces = {}
    for dim, tag in gmsh.model.getPhysicalGroups(2):
        name = gmsh.model.getPhysicalName(dim, tag)
        tri = []
        for ent in gmsh.model.getEntitiesForPhysicalGroup(dim, tag):
            types, _, nodes = gmsh.model.mesh.getElements(2, ent)
            for ty, nd in zip(types, nodes):
                if ty == 2:
                    tri.append(nd.reshape(-1, 3))
        faces[name] = lut(np.concatenate(tri).astype(np.int64))
    return MeshData(X, tags.astype(np.int64), T, faces)


def mesh_shape(shape: Shape, kind: str, h=None, h_fine=None, h_coarse=None, grade_dist=None, seed=1, out_msh=None):
    """Mesh `shape`. kind = "truth" (graded: h_fine on the probed faces -> h_coarse at grade_dist)
    or "dataset" (uniform h). Writes MSH 4.1 ASCII to out_msh if given. Returns MeshData."""
    gmsh.initialize(["-noenv"] if False else [])
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 1)
        gmsh.model.add(f"{shape.kind}-{kind}")
        vol = shape.build()
        gmsh.model.occ.synchronize()
        groups = {"bottom": [], "top": [], "sides": []}
        for dim, tag in gmsh.model.getEntities(2):
            groups[shape.classify(dim, tag)].append(tag)
        assert groups["bottom"] and groups["top"], groups
        for name in ["bottom", "top", "sides"]:
            if groups[name]:
                gmsh.model.addPhysicalGroup(2, groups[name], name=name)
        gmsh.model.addPhysicalGroup(3, [vol], name="body")
        gmsh.option.setNumber("Mesh.ElementOrder", 1)
        gmsh.option.setNumber("Mesh.RandomSeed", seed)
        if kind == "truth":
            probed = [t for g in shape.probed_groups() for t in groups[g]]
            f1 = gmsh.model.mesh.field.add("Distance")
            gmsh.model.mesh.field.setNumbers(f1, "SurfacesList", probed)
            gmsh.model.mesh.field.setNumber(f1, "Sampling", 60)
            f2 = gmsh.model.mesh.field.add("Threshold")
            gmsh.model.mesh.field.setNumber(f2, "InField", f1)
            gmsh.model.mesh.field.setNumber(f2, "SizeMin", h_fine)
            gmsh.model.mesh.field.setNumber(f2, "SizeMax", h_coarse)
            gmsh.model.mesh.field.setNumber(f2, "DistMin", 0.25 * grade_dist)
            gmsh.model.mesh.field.setNumber(f2, "DistMax", grade_dist)
            gmsh.model.mesh.field.setAsBackgroundMesh(f2)
            gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
            gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
            gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
            gmsh.option.setNumber("Mesh.Algorithm", 6)
            gmsh.option.setNumber("Mesh.Algorithm3D", 1)
        else:
            gmsh.option.setNumber("Mesh.MeshSizeMin", h)
            gmsh.option.setNumber("Mesh.MeshSizeMax", h)
            gmsh.option.setNumber("Mesh.Algorithm", 5)
            gmsh.option.setNumber("Mesh.Algorithm3D", 10)
        gmsh.model.mesh.generate(3)
        gmsh.model.mesh.optimize("Netgen" if kind == "truth" else "")
        md = _extract()
        if out_msh:
            gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
            gmsh.option.setNumber("Mesh.Binary", 0)
            gmsh.option.setNumber("Mesh.SaveAll", 0)
            tmp = out_msh + ".tmp.msh"
            gmsh.write(tmp)
            os.replace(tmp, out_msh)
        return md
    finally:
        gmsh.finalize()


def dataset_mesh(shape: Shape, rng, out_msh, n_target=None):
    """The coarse dataset mesh: h chosen for n_target tets (drawn in [1000, 3000] if not given)."""
    if n_target is None:
        n_target = int(rng.uniform(1000, 3000))
    h = (shape.volume() / (0.13 * n_target)) ** (1 / 3)
    seed = int(rng.integers(1, 10_000))
    md = None
    for _ in range(4):
        md = mesh_shape(shape, "dataset", h=h, seed=seed, out_msh=out_msh)
        n = len(md.T)
        if 800 <= n <= 3500:
            break
        h *= (n / n_target) ** (1 / 3)
    return md, h

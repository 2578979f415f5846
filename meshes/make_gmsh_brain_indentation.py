#!/usr/bin/env python3
"""Conforming tetrahedral meshes of the brain-indentation benchmark (issue 40, docs/reference.md
"Brain indentation benchmark"; cases/brain-indentation-benchmark*.toml, studies/indentation/).

Run from anywhere:  python3 meshes/make_gmsh_brain_indentation.py [LEVEL ...]
Needs the gmsh Python API (`pip install gmsh==4.15.2`, the version used). Meshing runs on one
thread with fixed algorithms (Delaunay 2D / 3D, Netgen optimisation), so re-running it with that
version reproduces the files.

The body is the half-ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0 (a, b, c = 46.25,
31.25, 28.5 mm), cut by the "plug" P = {x^2 + y^2 <= (5 mm)^2, z >= 27.5 mm} into two volumes
that share their faces, so that the plug's outline (the rim circle where it meets the free
surface and the circle of its flat bottom) is made of mesh edges. The mesh is graded towards
those two circles, where the driven plug makes the displacement field singular: element size
`h_rim` within 0.5 mm of them, growing linearly to the body size `h` over `grow` (m).

Writes meshes/brain-indentation-LEVEL.msh (MSH 4.1 binary, metres, linear tetrahedra) with
the physical groups `base` (surface z = 0), `surface` (the curved free surface outside the
plug), `plug_top` (the plug's part of the surface), `plug` (the plug volume: its nodes are the
driven set) and `volume` (the rest). Prints nodes, tets and the smallest dihedral angle.
"""

import math
import os
import sys

import gmsh

HERE = os.path.dirname(os.path.abspath(__file__))
A, B, C = 0.04625, 0.03125, 0.0285  # semi-axes, m
R_PLUG, Z_PLUG = 0.005, 0.0275  # plug radius and bottom, m

# Level: (body size h, rim size h_rim, growth distance), m. Nodes in the comment are those of
# the linear mesh (tet4); `element = "tet10"` adds one node per edge (about 6.5x).
LEVELS = {
    "c1": (0.0090, 0.0012, 0.008),  # coarse
    "c2": (0.0065, 0.0008, 0.008),
    "c3": (0.0048, 0.0006, 0.008),
    "c4": (0.0035, 0.0004, 0.008),
    "c5": (0.0025, 0.0003, 0.008),
    "c6": (0.0018, 0.0002, 0.008),
}


def physical(dim, tags, name):
    tag = gmsh.model.addPhysicalGroup(dim, tags)
    gmsh.model.setPhysicalName(dim, tag, name)


def build():
    occ = gmsh.model.occ
    ball = occ.addSphere(0, 0, 0, 1.0)
    occ.dilate([(3, ball)], 0, 0, 0, A, B, C)
    low = occ.addBox(-2 * A, -2 * B, -2 * C, 4 * A, 4 * B, 2 * C)
    half, _ = occ.cut([(3, ball)], [(3, low)])
    plug = occ.addCylinder(0, 0, Z_PLUG, 0, 0, 2 * C, R_PLUG)
    inside, _ = occ.intersect([(3, plug)], [(3, half[0][1])], removeObject=True, removeTool=False)
    occ.fragment(half, inside)
    occ.synchronize()
    vols = [t for _, t in gmsh.model.getEntities(3)]
    # OpenCASCADE's bounding boxes are loose: tell the volumes apart by their size.
    vols.sort(key=lambda v: gmsh.model.occ.getMass(3, v))
    plug_vol, body_vol = vols[:1], vols[1:]
    assert len(plug_vol) == 1 and len(body_vol) == 1, (plug_vol, body_vol)
    base, surface, plug_top = [], [], []
    for _, s in gmsh.model.getEntities(2):
        up, down = gmsh.model.getAdjacencies(2, s)
        if len(up) != 1:
            continue  # an inner face between the two volumes
        if abs(gmsh.model.occ.getCenterOfMass(2, s)[2]) < 1e-9:
            base.append(s)
        elif up[0] in plug_vol:
            plug_top.append(s)
        else:
            surface.append(s)
    physical(2, base, "base")
    physical(2, surface, "surface")
    physical(2, plug_top, "plug_top")
    physical(3, plug_vol, "plug")
    physical(3, body_vol, "volume")
    # The plug's circles: every curve of the plug volume's boundary.
    curves = set()
    for _, f in gmsh.model.getBoundary([(3, plug_vol[0])], oriented=False):
        for _, c in gmsh.model.getBoundary([(2, f)], oriented=False):
            curves.add(abs(c))
    return sorted(curves)


def mesh(level):
    h, h_rim, grow = LEVELS[level]
    gmsh.model.add(f"brain-{level}")
    curves = build()
    dist = gmsh.model.mesh.field.add("Distance")
    gmsh.model.mesh.field.setNumbers(dist, "CurvesList", curves)
    gmsh.model.mesh.field.setNumber(dist, "Sampling", 400)
    thr = gmsh.model.mesh.field.add("Threshold")
    gmsh.model.mesh.field.setNumber(thr, "InField", dist)
    gmsh.model.mesh.field.setNumber(thr, "SizeMin", h_rim)
    gmsh.model.mesh.field.setNumber(thr, "SizeMax", h)
    gmsh.model.mesh.field.setNumber(thr, "DistMin", 0.0005)
    gmsh.model.mesh.field.setNumber(thr, "DistMax", 0.0005 + grow)
    gmsh.model.mesh.field.setAsBackgroundMesh(thr)
    gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    gmsh.option.setNumber("Mesh.Optimize", 1)
    gmsh.option.setNumber("Mesh.OptimizeNetgen", 1)
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.option.setNumber("Mesh.Binary", 1)
    gmsh.model.mesh.generate(3)
    nodes, _, _ = gmsh.model.mesh.getNodes()
    tets = gmsh.model.mesh.getElementsByType(4)[0]
    name = f"brain-indentation-{level}.msh"
    gmsh.write(os.path.join(HERE, name))
    print(f"{name}: h = {h * 1e3} mm, rim {h_rim * 1e3} mm, {len(nodes)} nodes, {len(tets)} tets")
    gmsh.model.remove()


def main():
    levels = sys.argv[1:] or list(LEVELS)
    gmsh.initialize(sys.argv[:1])
    gmsh.option.setNumber("General.Terminal", 0)
    for level in levels:
        mesh(level)
    gmsh.finalize()


if __name__ == "__main__":
    main()

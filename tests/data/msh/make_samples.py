#!/usr/bin/env python3
"""Makes the Gmsh / VTK sample meshes the readers in src/io/msh.rs and src/io/vtk.rs are tested on.

Run from anywhere:  python3 tests/data/msh/make_samples.py
Needs the gmsh Python API (4.15.2 used) and meshio (5.3.5 used). See README.md.

Writes, next to this script (tests/data/msh/):
  cyl_v41.msh      cylinder r=0.05 m, h=0.1 m, tet4, MSH 4.1 ASCII
  cyl_v41_bin.msh  the same mesh, MSH 4.1 binary
  cyl_v22.msh      the same mesh, MSH 2.2 ASCII
  box_hex_v41.msh  structured hex8 box 0.04 x 0.03 x 0.02 m (transfinite + recombine), MSH 4.1 ASCII
  expected.json    counts gmsh reports for these meshes
and in tests/data/vtk/:
  cyl.vtu          the cylinder through meshio, VTU ASCII, with integer cell data gmsh:physical
  cyl.vtk          the same, legacy VTK 4.2 ASCII
  box_hex_b64.vtu  the hex box, VTU inline base64 binary as VTK lays it out (written here
                   with numpy: meshio's own binary VTU is not readable by vtkio)
  box_hex_bin.vtk  the hex box through meshio, legacy VTK 4.2 binary
  box_hex_meshio_b64.vtu  the hex box through meshio, VTU binary (base64, uncompressed): the
                   reader refuses it with a clear message (Int64 cell types)
  expected.json    counts for these files
"""

import base64
import json
import os

import gmsh
import meshio
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
VTK_DIR = os.path.join(os.path.dirname(HERE), "vtk")


def physical(dim, entities, name):
    tag = gmsh.model.addPhysicalGroup(dim, entities)
    gmsh.model.setPhysicalName(dim, tag, name)
    return tag


def mesh_counts():
    """Node count and element counts per type as gmsh reports them for the current model."""
    node_tags, _, _ = gmsh.model.mesh.getNodes()
    types, elem_tags, _ = gmsh.model.mesh.getElements()
    counts = {}
    for t, tags in zip(types, elem_tags):
        name = gmsh.model.mesh.getElementProperties(t)[0]
        counts[str(int(t))] = {"name": name, "count": int(len(tags))}
    groups = {}
    for dim, tag in gmsh.model.getPhysicalGroups():
        name = gmsh.model.getPhysicalName(dim, tag)
        nodes, _ = gmsh.model.mesh.getNodesForPhysicalGroup(dim, tag)
        n_elems = 0
        for ent in gmsh.model.getEntitiesForPhysicalGroup(dim, tag):
            _, etags, _ = gmsh.model.mesh.getElements(dim, ent)
            n_elems += sum(len(e) for e in etags)
        groups[name] = {"dim": dim, "tag": tag, "nodes": int(len(nodes)), "elements": n_elems}
    return {"nodes": int(len(node_tags)), "element_types": counts, "physical_groups": groups}


def cylinder():
    gmsh.model.add("cylinder")
    vol = gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, 0.1, 0.05)
    gmsh.model.occ.synchronize()
    bottom, top, lateral = [], [], []
    for dim, tag in gmsh.model.getBoundary([(3, vol)], oriented=False):
        # OCC bounding boxes are padded by about 1e-7.
        zmin = gmsh.model.getBoundingBox(dim, tag)[2]
        zmax = gmsh.model.getBoundingBox(dim, tag)[5]
        if zmax < 1e-6:
            bottom.append(tag)
        elif zmin > 0.1 - 1e-6:
            top.append(tag)
        else:
            lateral.append(tag)
    physical(2, bottom, "bottom")
    physical(2, top, "top")
    physical(2, lateral, "lateral")
    physical(3, [vol], "volume")
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.02)
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.02)
    gmsh.model.mesh.generate(3)
    counts = mesh_counts()

    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.write(os.path.join(HERE, "cyl_v41.msh"))
    gmsh.option.setNumber("Mesh.Binary", 1)
    gmsh.write(os.path.join(HERE, "cyl_v41_bin.msh"))
    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
    gmsh.write(os.path.join(HERE, "cyl_v22.msh"))
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    return counts


def hex_box():
    gmsh.model.add("box")
    vol = gmsh.model.occ.addBox(0, 0, 0, 0.04, 0.03, 0.02)
    gmsh.model.occ.synchronize()
    # 4 x 3 x 2 hexahedra: transfinite curves by length (1 cm per element).
    for dim, tag in gmsh.model.getEntities(1):
        b = gmsh.model.getBoundingBox(dim, tag)
        length = max(b[3] - b[0], b[4] - b[1], b[5] - b[2])
        gmsh.model.mesh.setTransfiniteCurve(tag, int(round(length / 0.01)) + 1)
    for dim, tag in gmsh.model.getEntities(2):
        gmsh.model.mesh.setTransfiniteSurface(tag)
        gmsh.model.mesh.setRecombine(dim, tag)
    gmsh.model.mesh.setTransfiniteVolume(vol)
    gmsh.model.mesh.setRecombine(3, vol)
    zmin_faces = []
    for dim, tag in gmsh.model.getBoundary([(3, vol)], oriented=False):
        if gmsh.model.getBoundingBox(dim, tag)[5] < 1e-6:
            zmin_faces.append(tag)
    physical(2, zmin_faces, "fixed")
    physical(3, [vol], "tissue")
    gmsh.model.mesh.generate(3)
    counts = mesh_counts()
    gmsh.option.setNumber("Mesh.Binary", 0)
    gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
    gmsh.write(os.path.join(HERE, "box_hex_v41.msh"))
    return counts


VTK_TYPES = {"vertex": 1, "line": 3, "triangle": 5, "quad": 9, "tetra": 10, "hexahedron": 12}


def write_vtu_base64(path, mesh):
    """A VTU file with inline base64 binary arrays, each encoded as one block of a UInt64
    byte count followed by the little-endian data (the layout VTK writes), cell types UInt8,
    and the integer cell arrays gmsh:physical / gmsh:geometrical as Int32."""

    def array(name, data, dtype, vtk_type, comps=1):
        raw = np.ascontiguousarray(data, dtype=dtype).tobytes()
        block = base64.b64encode(np.uint64(len(raw)).tobytes() + raw).decode()
        return (
            f'<DataArray type="{vtk_type}" Name="{name}" NumberOfComponents="{comps}" '
            f'format="binary">\n{block}\n</DataArray>\n'
        )

    conn = np.concatenate([c.data.ravel() for c in mesh.cells])
    offsets = np.cumsum([c.data.shape[1] for c in mesh.cells for _ in c.data])
    types = np.concatenate([np.full(len(c.data), VTK_TYPES[c.type]) for c in mesh.cells])
    n_cells = len(types)
    out = [
        '<?xml version="1.0"?>\n',
        '<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
        'header_type="UInt64">\n<UnstructuredGrid>\n',
        f'<Piece NumberOfPoints="{len(mesh.points)}" NumberOfCells="{n_cells}">\n',
        "<Points>\n",
        array("Points", mesh.points, "<f8", "Float64", 3),
        "</Points>\n<Cells>\n",
        array("connectivity", conn, "<i8", "Int64"),
        array("offsets", offsets, "<i8", "Int64"),
        array("types", types, "u1", "UInt8"),
        "</Cells>\n<CellData>\n",
    ]
    for name in ("gmsh:physical", "gmsh:geometrical"):
        values = np.concatenate([np.asarray(d).ravel() for d in mesh.cell_data[name]])
        out.append(array(name, values, "<i4", "Int32"))
    out.append("</CellData>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n")
    with open(path, "w") as f:
        f.write("".join(out))


def cell_counts(mesh):
    counts = {}
    for c in mesh.cells:
        counts[c.type] = counts.get(c.type, 0) + int(len(c.data))
    return counts


def main():
    os.makedirs(VTK_DIR, exist_ok=True)
    gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    # Deterministic output: one thread, fixed algorithms.
    gmsh.option.setNumber("General.NumThreads", 1)
    gmsh.option.setNumber("Mesh.Algorithm", 6)
    gmsh.option.setNumber("Mesh.Algorithm3D", 1)
    expected = {
        "gmsh": gmsh.__version__,
        "meshio": meshio.__version__,
        "cylinder": cylinder(),
        "box_hex": hex_box(),
    }
    gmsh.finalize()
    with open(os.path.join(HERE, "expected.json"), "w") as f:
        json.dump(expected, f, indent=1, sort_keys=True)
        f.write("\n")

    # VTK files from the gmsh meshes through meshio (gmsh:physical is an integer cell array).
    vtk_expected = {"meshio": meshio.__version__}
    cyl = meshio.read(os.path.join(HERE, "cyl_v41.msh"))
    # meshio keeps "gmsh:dim_tags" point data (2 components) and cell sets; drop what VTK
    # cannot hold or what the test does not need, keep gmsh:physical / gmsh:geometrical.
    cyl.point_data = {}
    cyl.cell_sets = {}
    meshio.write(os.path.join(VTK_DIR, "cyl.vtu"), cyl, binary=False)
    meshio.vtk.write(os.path.join(VTK_DIR, "cyl.vtk"), cyl, binary=False, fmt_version="4.2")
    vtk_expected["cyl"] = {
        "points": int(len(cyl.points)),
        "cells": cell_counts(cyl),
        "physical": sorted(
            {int(v) for d in cyl.cell_data["gmsh:physical"] for v in np.asarray(d).ravel()}
        ),
    }
    box = meshio.read(os.path.join(HERE, "box_hex_v41.msh"))
    box.point_data = {}
    box.cell_sets = {}
    # meshio's binary VTU (types as Int64, header base64-encoded apart from the data): the
    # reader must refuse it with a clear message.
    meshio.write(
        os.path.join(VTK_DIR, "box_hex_meshio_b64.vtu"), box, binary=True, compression=None
    )
    # Legacy binary (big-endian) VTK 4.2.
    meshio.vtk.write(os.path.join(VTK_DIR, "box_hex_bin.vtk"), box, binary=True, fmt_version="4.2")
    # Inline base64 VTU laid out as VTK itself writes it (one base64 block of UInt64 byte
    # count + data; UInt8 cell types).
    write_vtu_base64(os.path.join(VTK_DIR, "box_hex_b64.vtu"), box)
    vtk_expected["box_hex"] = {
        "files": ["box_hex_b64.vtu", "box_hex_bin.vtk"],
        "points": int(len(box.points)),
        "cells": cell_counts(box),
    }
    with open(os.path.join(VTK_DIR, "expected.json"), "w") as f:
        json.dump(vtk_expected, f, indent=1, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Makes the meshio-written VTK samples for the binary legacy 5.1 and compressed VTU readers.

Run from anywhere:  python3 tests/data/vtk/make_meshio_samples.py
Needs meshio (5.3.5 used) and numpy only; reads the Gmsh meshes in ../msh/ (made by
../msh/make_samples.py). See ../msh/README.md. Writes, next to this script:

  cyl_v51_bin.vtk        the cylinder, legacy VTK 5.1 BINARY (meshio's default version)
  box_hex_v51_bin.vtk    the hex box with an integer point array, legacy VTK 5.1 BINARY
  cyl_zlib.vtu           the cylinder, VTU as meshio writes by default (binary, zlib, UInt32 header)
  box_hex_zlib_u64.vtu   the hex box with the point array, VTU zlib with header_type="UInt64"
"""

import os

import meshio
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
MSH = os.path.join(os.path.dirname(HERE), "msh")


def main():
    # Same preparation as make_samples.py: drop gmsh's point data and cell sets, keep the
    # integer cell arrays gmsh:physical / gmsh:geometrical.
    cyl = meshio.read(os.path.join(MSH, "cyl_v41.msh"))
    cyl.point_data = {}
    cyl.cell_sets = {}
    meshio.vtk.write(os.path.join(HERE, "cyl_v51_bin.vtk"), cyl, binary=True)
    meshio.write(os.path.join(HERE, "cyl_zlib.vtu"), cyl)

    box = meshio.read(os.path.join(MSH, "box_hex_v41.msh"))
    box.cell_sets = {}
    # An integer point array: 1 on the face z = 0 (the nodes of the physical group "fixed").
    box.point_data = {"fixed": (box.points[:, 2] == 0.0).astype(np.int32)}
    meshio.vtk.write(os.path.join(HERE, "box_hex_v51_bin.vtk"), box, binary=True)
    meshio.write(os.path.join(HERE, "box_hex_zlib_u64.vtu"), box, header_type="UInt64")


if __name__ == "__main__":
    main()

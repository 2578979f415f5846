"""Writes meshes/brain-shift-exposed.csv, the synthetic measured displacements of
cases/brain-shift.toml: the surface nodes of its TetGen mesh within 15 mm of the z axis
(the cortex a craniotomy exposes), sinking by 2 mm (1 - (r / 15 mm)^2), in m.

    cargo run --release -- mesh cases/brain-shift.toml --vtu-format ascii --out /tmp/brain-shift.vtu
    python3 meshes/make_brain_shift_measurements.py /tmp/brain-shift.vtu
"""
import re
import sys

A, B, C = 0.04625, 0.03125, 0.0285  # semi-axes of the half-ellipsoid, m
R, DEPTH = 0.015, 0.002  # exposed radius and sag at the centre, m

text = open(sys.argv[1]).read()
points = text[text.index("<Points>"):text.index("</Points>")]
values = [float(v) for v in re.findall(r">([^<]*)<", points[points.index("<DataArray"):])[0].split()]
rows = ["x,y,z,ux,uy,uz"]
for k in range(0, len(values), 3):
    x, y, z = values[k:k + 3]
    r = (x * x + y * y) ** 0.5
    # On the curved surface (TetGen's surface points lie on it exactly) and in the window.
    if abs(x * x / A / A + y * y / B / B + z * z / C / C - 1) < 1e-9 and r <= R and z > 0:
        rows.append("%.17g,%.17g,%.17g,0,0,%.17g" % (x, y, z, -DEPTH * (1 - (r / R) ** 2)))
header = (
    "# Synthetic measured displacements of the cortex exposed by a craniotomy (cases/brain-shift.toml):\n"
    "# the surface nodes of its TetGen mesh (size 6 mm) within 15 mm of the z axis, sinking by\n"
    "# 2 mm (1 - (r / 15 mm)^2); x, y, z, ux, uy, uz in m. Made by meshes/make_brain_shift_measurements.py.\n"
)
open("meshes/brain-shift-exposed.csv", "w").write(header + "\n".join(rows) + "\n")
print(f"{len(rows) - 1} measured points")

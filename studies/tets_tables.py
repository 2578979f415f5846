#!/usr/bin/env python3
"""Tables of the unstructured-tet study (studies/README.md, "Issue 21: the cylinder on
unstructured tets") from the sweep.json files of studies/tets/{gmsh,tetgen}-*: per preset and
mesh, reaction / probe u_x error (%) against the SfePy reference, solve time (s) and steps,
then the cheapest runs within 1 % and 2 %. Usage: studies/tets_tables.py [STUDIES_DIR]"""
import json
import sys
from pathlib import Path

root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).parent)
ORDER = ["fe-tet4-anp", "mls", "mmls", "coupled", "coupled-mmls"]
for series in ["gmsh", "tetgen"]:
    for case in ["compression", "extension", "shear"]:
        rows = json.loads((root / "tets" / f"{series}-{case}" / "sweep.json").read_text())
        cells, nodes = {}, []
        for r in rows:
            s = r["summary"]
            preset = r["values"]["preset"]
            errs = s["reference"]
            e = (100 * abs(errs["force"]["relative_error"]), 100 * abs(errs["probe_ux"]["relative_error"]))
            if s["nodes"] not in nodes:
                nodes.append(s["nodes"])
            cells[(preset, s["nodes"])] = (e, s["wall_seconds"]["solve"], s["steps"], s.get("status", "converged"))
        print(f"**{series} {case}** (reaction / probe u_x error %, solve s, steps)\n")
        print("| preset | " + " | ".join(f"{n} nodes" for n in nodes) + " |")
        print("|---" * (len(nodes) + 1) + "|")
        for p in ORDER:
            out = []
            for n in nodes:
                c = cells.get((p, n))
                if c is None:
                    out.append("-")
                elif c[3] not in ("converged", "ok"):
                    out.append(c[3])
                else:
                    (ef, eu), t, k, _ = c
                    out.append(f"{ef:.2f} / {eu:.2f}, {t:.2f} s, {k}")
            print(f"| {p} | " + " | ".join(out) + " |")
        print()
        for bound in (1.0, 2.0):
            best = {}
            for (p, n), ((ef, eu), t, k, st) in cells.items():
                if max(ef, eu) <= bound and (p not in best or t < best[p][1]):
                    best[p] = (n, t, max(ef, eu))
            items = sorted(best.items(), key=lambda x: x[1][1])
            text = "; ".join(f"{p} {n} nodes {t:.2f} s ({e:.2f} %)" for p, (n, t, e) in items)
            print(f"cheapest within {bound:.0f} %: {text or 'none'}\n")

#!/usr/bin/env python3
"""Builds the inputs of cases/mni-brain-shift.toml from the MNI ICBM152 2009a template.

The template (nonlinear symmetric 2009a, 1 mm, RAS: Fonov et al. 2011, NeuroImage 54; Fonov
et al. 2009, NeuroImage 47 S102) ships inside the nilearn wheel on PyPI (BSD; the template's
own licence permits redistribution with its copyright notice, see meshes/mni/README.md). This
script downloads that wheel (pip), reads the T1 and the grey- and white-matter probability
maps, and writes into meshes/mni/:

- mni-labels.nii.gz: the labelmap, 1 mm, the template's grid and orientation:
    1 grey matter and the rest of the brain (grey + white probability > 0.5, its largest
      piece, small enclosed holes filled),
    2 white matter (white probability > 0.5),
    3 a synthetic tumour (ball of radius 12 mm at (35, 25, 30) mm RAS, right frontal),
    0 background and the ventricles (the large cavity the brain encloses: a hole, not tissue).
- mni-t1-2mm.nii.gz: the T1 on a 2 mm grid (every other voxel), the image the case warps.
- mni-craniotomy.csv: synthetic measured displacements of the cortex exposed by a craniotomy
  (x, y, z, ux, uy, uz in m, RAS): the points of a 2 mm grid over a disc of radius 25 mm
  about (35, -15) mm in x, y, placed on the cortex (the 0.5 level of the brain mask smoothed
  by a 2 mm Gaussian, found down each vertical line), sinking by 5 mm (1 - (r / 25 mm)^2)
  along -z, as an image registration of the exposed surface would give them.

Usage: python3 scripts/make_mni_case.py [--wheel nilearn-X.whl]   (needs numpy, scipy, nibabel)
"""

import argparse
import os
import subprocess
import sys
import tempfile
import zipfile

import nibabel as nib
import numpy as np
from scipy import ndimage as ndi

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, "..", "meshes", "mni")
NILEARN = "nilearn==0.14.1"
DATA = "nilearn/datasets/data/mni_icbm152_{}_tal_nlin_sym_09a_converted.nii.gz"

TUMOUR_CENTRE = np.array([35.0, 25.0, 30.0])  # mm, RAS
TUMOUR_RADIUS = 12.0  # mm
WINDOW_CENTRE = np.array([35.0, -15.0])  # mm, x and y
WINDOW_RADIUS = 25.0  # mm
SINK = 5.0  # mm at the window's centre
SPACING = 2.0  # mm between measured points


def wheel(path):
    if path:
        return path
    tmp = tempfile.mkdtemp()
    subprocess.check_call(
        [sys.executable, "-m", "pip", "download", NILEARN, "--no-deps", "-d", tmp]
    )
    return os.path.join(tmp, [f for f in os.listdir(tmp) if f.endswith(".whl")][0])


def load(z, name, tmp):
    p = os.path.join(tmp, name + ".nii.gz")
    with open(p, "wb") as f:
        f.write(z.read(DATA.format(name)))
    im = nib.load(p)
    return im, np.asarray(im.dataobj).astype(np.float64)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--wheel", help="a downloaded nilearn wheel (else pip downloads it)")
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    tmp = tempfile.mkdtemp()
    with zipfile.ZipFile(wheel(args.wheel)) as z:
        t1_im, t1 = load(z, "t1", tmp)
        _, gm = load(z, "gm", tmp)
        _, wm = load(z, "wm", tmp)
    aff = t1_im.affine
    # Probabilities are stored 0..255.
    tissue = (gm + wm) > 127.5
    lab, n = ndi.label(tissue)
    sizes = ndi.sum(tissue, lab, range(1, n + 1))
    brain = lab == (int(np.argmax(sizes)) + 1)
    filled = ndi.binary_fill_holes(brain)
    holes, nh = ndi.label(filled & ~brain)
    hole_sizes = ndi.sum(filled & ~brain, holes, range(1, nh + 1))
    ventricles = holes == (int(np.argmax(hole_sizes)) + 1)
    body = filled & ~ventricles
    labels = np.zeros(t1.shape, np.uint8)
    labels[body] = 1
    labels[body & (wm > 127.5)] = 2
    ijk = np.indices(t1.shape).reshape(3, -1).T
    world = (ijk @ aff[:3, :3].T + aff[:3, 3]).reshape(t1.shape + (3,))
    tumour = body & (np.linalg.norm(world - TUMOUR_CENTRE, axis=-1) <= TUMOUR_RADIUS)
    labels[tumour] = 3
    out = nib.Nifti1Image(labels, aff)
    out.header.set_xyzt_units("mm")
    out.set_sform(aff, code=2)
    out.set_qform(aff, code=2)
    nib.save(out, os.path.join(OUT, "mni-labels.nii.gz"))

    # The T1 on every other voxel (2 mm): the affine's columns double, the origin stays.
    a2 = aff.copy()
    a2[:3, :3] *= 2.0
    t1_2 = nib.Nifti1Image(t1[::2, ::2, ::2].astype(np.uint8), a2)
    t1_2.header.set_xyzt_units("mm")
    t1_2.set_sform(a2, code=2)
    t1_2.set_qform(a2, code=2)
    nib.save(t1_2, os.path.join(OUT, "mni-t1-2mm.nii.gz"))

    # Measured points on the smoothed cortex within the window.
    smooth = ndi.gaussian_filter(filled.astype(np.float64), 2.0)
    inv = np.linalg.inv(aff)
    rows = []
    r_max = WINDOW_RADIUS
    xs = np.arange(-r_max, r_max + 1e-9, SPACING)
    for dx in xs:
        for dy in xs:
            r = np.hypot(dx, dy)
            if r > r_max:
                continue
            x, y = WINDOW_CENTRE[0] + dx, WINDOW_CENTRE[1] + dy
            # Down the vertical line from above the head to the first crossing of 0.5.
            zs = np.arange(110.0, 0.0, -0.25)
            pts = np.stack([np.full_like(zs, x), np.full_like(zs, y), zs], axis=1)
            idx = pts @ inv[:3, :3].T + inv[:3, 3]
            v = ndi.map_coordinates(smooth, idx.T, order=1)
            k = int(np.argmax(v >= 0.5))
            if v[k] < 0.5 or k == 0:
                continue
            f = (0.5 - v[k - 1]) / (v[k] - v[k - 1])
            z = zs[k - 1] + f * (zs[k] - zs[k - 1])
            sink = SINK * (1.0 - (r / WINDOW_RADIUS) ** 2)
            rows.append((x, y, z, 0.0, 0.0, -sink))
    rows = np.array(rows) * 1e-3
    with open(os.path.join(OUT, "mni-craniotomy.csv"), "w") as f:
        f.write("# x, y, z, ux, uy, uz (m, RAS): synthetic craniotomy measurements, scripts/make_mni_case.py\n")
        for r in rows:
            f.write(", ".join(f"{v:.6e}" for v in r) + "\n")

    vol = lambda m: m.sum() * 1e-3
    print(
        f"brain {vol(body):.1f} cm^3 (white matter {vol(labels == 2):.1f}, tumour {vol(tumour):.1f}), "
        f"ventricles {vol(ventricles):.1f} cm^3, {nh - 1} small holes filled; "
        f"{len(rows)} measured points; extent {world[body].min(0)} .. {world[body].max(0)} mm"
    )


if __name__ == "__main__":
    main()

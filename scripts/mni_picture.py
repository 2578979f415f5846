#!/usr/bin/env python3
"""The README's picture of cases/mni-brain-shift.toml: a coronal slice through the craniotomy
and one through the tumour, each showing the template's T1, the T1 warped by the run and the
displacement magnitude. Usage: python3 scripts/mni_picture.py RUN_FOLDER docs/mni-brain-shift.png
(needs numpy, nibabel, matplotlib)."""

import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import nibabel as nib
import numpy as np

run, png = sys.argv[1], sys.argv[2]
here = os.path.dirname(os.path.abspath(__file__))
t1 = nib.load(os.path.join(here, "..", "meshes", "mni", "mni-t1-2mm.nii.gz"))
warped = nib.load(os.path.join(run, "mni-brain-shift_warped.nii.gz"))
field = nib.load(os.path.join(run, "mni-brain-shift_displacement.nii.gz"))
a = np.asarray(t1.dataobj, dtype=float)
w = np.asarray(warped.dataobj, dtype=float)
d = np.asarray(field.dataobj, dtype=float)[..., 0, :]  # LPS mm
mag = np.linalg.norm(d, axis=-1)
inv = np.linalg.inv(t1.affine)
fig, axes = plt.subplots(2, 3, figsize=(12, 8.2))
for row, (y_mm, what) in enumerate([(-15.0, "craniotomy"), (25.0, "tumour")]):
    j = int(round((inv @ np.array([0.0, y_mm, 0.0, 1.0]))[1]))
    ext = None
    for col, (img, title, cmap) in enumerate(
        [(a, "T1 (MNI ICBM152 2009a)", "gray"), (w, "T1 warped by the run", "gray"), (mag, "|displacement| (mm)", "magma")]
    ):
        ax = axes[row, col]
        sl = np.rot90(img[:, j, :])
        im = ax.imshow(sl, cmap=cmap, vmin=0 if cmap != "gray" else None)
        ax.set_title(f"{title}\ncoronal, y = {y_mm:.0f} mm ({what})", fontsize=9)
        ax.axis("off")
        if cmap != "gray":
            fig.colorbar(im, ax=ax, fraction=0.04)
fig.suptitle("hytled: brain shift on the MNI brain (gravity, skull contact, craniotomy measurements)", fontsize=11)
fig.tight_layout()
fig.savefig(png, dpi=80)
print("wrote", png)

"""A patient cohort as a sweep: three variants of cases/mni-brain-shift.toml, each with its
own labelmap (the MNI brain scaled by 0.95, 1.00 and 1.05 about the origin, as three heads of
different size) and its own craniotomy measurements (the positions scaled alike, the
displacements by 0.9, 1.0 and 1.2), run as one preset per patient on the local process pool
(or any executor: `executor=Client(...).get_executor()` for Dask). Needs nibabel. Run from
the repository root:

    python python/examples/cohort.py [OUT]

Each patient's row gives its tumour displacement; out/runs/<id>/ holds each run's summary and
`resume=True` reruns only the patients whose run is missing or failed.
"""

import os
import sys

import nibabel as nib
import numpy as np

import hytled

SCENE = "cases/mni-brain-shift.toml"
LABELS = "meshes/mni/mni-labels.nii.gz"
MEASURED = "meshes/mni/mni-craniotomy.csv"


def make_patient(out, name, scale, push):
    """A labelmap and measurements for one patient, in `out/patients/`; the overrides that
    make the MNI scene theirs."""
    d = os.path.join(out, "patients")
    os.makedirs(d, exist_ok=True)
    img = nib.load(LABELS)
    affine = img.affine.copy()
    affine[:3, :] *= scale
    image = os.path.abspath(os.path.join(d, f"{name}-labels.nii.gz"))
    nib.save(nib.Nifti1Image(np.asarray(img.dataobj), affine), image)
    rows = np.loadtxt(MEASURED, delimiter=",", comments="#")
    rows[:, :3] *= scale
    rows[:, 3:] *= push
    measured = os.path.abspath(os.path.join(d, f"{name}-craniotomy.csv"))
    np.savetxt(measured, rows, delimiter=", ", fmt="%.6e",
               header="x, y, z, ux, uy, uz (m, RAS)")
    s = scale
    return {
        "geometry.image": image,
        "contact.skull.file": image,
        "measured.craniotomy.file": measured,
        # The scene's brainstem box (z below -0.063 m), scaled, with 3 mm more: the labelmap
        # is meshed in blocks of 10 voxels, whose size scales too, so the lowest nodes of a
        # smaller head do not scale exactly with it.
        "boundaries.brainstem.select": (
            f"{{ box = {{ min = [-0.1, -0.2, -0.1], max = [0.1, 0.1, {-0.063 * s + 0.003:.5f}] }} }}"
        ),
        "probes.tumour_centre.position": [0.035 * s, 0.025 * s, 0.030 * s],
        "probes.craniotomy_centre.position": [0.035 * s, -0.015 * s, 0.070 * s],
    }


def main(out="cohort"):
    patients = {
        "small": make_patient(out, "small", 0.95, 0.9),
        "mni": make_patient(out, "mni", 1.00, 1.0),
        "large": make_patient(out, "large", 1.05, 1.2),
    }
    sweep = hytled.sweep(SCENE, presets=patients, out=out, resume=True)
    for row in sweep:
        u = row["summary"]["probes"]["tumour_centre"]["displacement"] if row["summary"] else None
        tumour = "-" if u is None else f"{1e3 * np.linalg.norm(u):.3f} mm"
        print(f"{row['preset']:6s} {row['status']:14s} {row['nodes']} nodes, "
              f"{row['wall_seconds'] or 0:.1f} s, tumour moved {tumour}"
              + (f" ({row['error']})" if row["error"] else ""))
    print(f"table: {os.path.join(out, 'sweep.md')}")


if __name__ == "__main__":
    main(*sys.argv[1:])

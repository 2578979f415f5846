"""Images read as the ecosystem reads them (issue 56): every NIfTI-1 test image written by
nibabel and every NRRD written by pynrrd is read by hytled (``hytled.read_image``) and compared,
voxel data and index-to-world map, with what nibabel and pynrrd read from the same file."""

import gzip
import pathlib
import struct

import numpy as np
import pytest

import hytled

nib = pytest.importorskip("nibabel")
nrrd = pytest.importorskip("nrrd")

SHAPE = (5, 4, 3)
DTYPES = [np.uint8, np.int8, np.int16, np.uint16, np.int32, np.uint32, np.float32, np.float64]


def ramp(dtype):
    v = np.arange(np.prod(SHAPE)).reshape(SHAPE, order="F") % 50
    return (v + (0.25 if np.dtype(dtype).kind == "f" else 0)).astype(dtype)


def oblique_affine():
    c, s = np.cos(0.3), np.sin(0.3)
    a = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    a = a @ np.diag([1.5, 2.0, 2.5, 1.0])
    a[:3, 3] = [-10.0, 4.0, 7.5]
    return a


def mm(affine):
    """hytled's index-to-world map (m) in millimetres, as nibabel and pynrrd give it."""
    a = np.array(affine, float)
    a[:3, :] *= 1e3
    return a


def same_as_nibabel(path):
    values, affine = hytled.read_image(path)
    img = nib.load(str(path))
    expected = np.asarray(img.get_fdata(dtype=np.float64))
    assert values.shape == expected.shape
    np.testing.assert_array_equal(values, expected)
    # nibabel's affine is in mm; hytled's in m.
    np.testing.assert_allclose(mm(affine), img.affine, rtol=0, atol=1e-9)
    return values, affine


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("endian", ["<", ">"])
def test_nifti_datatypes_and_byte_orders(tmp_path, dtype, endian):
    header = nib.Nifti1Header(endianness=endian)
    img = nib.Nifti1Image(ramp(dtype), oblique_affine(), header=header)
    img.header.set_xyzt_units("mm")
    for name in ["a.nii", "a.nii.gz"]:
        path = tmp_path / name
        nib.save(img, str(path))
        if endian == ">":
            raw = open(path, "rb").read() if name.endswith(".nii") else gzip.open(path).read()
            assert struct.unpack(">i", raw[:4])[0] == 348  # really written big-endian
        same_as_nibabel(path)


@pytest.mark.parametrize("codes", [(1, 0), (0, 1), (1, 2), (0, 0)])
def test_qform_only_sform_only_and_both(tmp_path, codes):
    qcode, scode = codes
    img = nib.Nifti1Image(ramp(np.int16), oblique_affine())
    sform = oblique_affine()
    sform[:3, 3] += [1.0, -2.0, 3.0]  # a different sform, to see which one is taken
    img.set_qform(oblique_affine(), code=qcode)
    img.set_sform(sform, code=scode)
    img.header.set_xyzt_units("mm")
    path = tmp_path / "codes.nii"
    nib.save(img, str(path))
    if codes == (0, 0):
        # Neither: hytled takes the voxel sizes alone (NIfTI's "method 1", as ITK and 3D Slicer
        # do); nibabel's fallback is ANALYZE's centred, x-flipped affine. The data still agree.
        values, affine = hytled.read_image(path)
        np.testing.assert_array_equal(values, ramp(np.int16))
        np.testing.assert_allclose(mm(affine), np.diag([1.5, 2.0, 2.5, 1.0]), atol=1e-9)
    else:
        same_as_nibabel(path)


def test_header_extensions_and_a_late_vox_offset(tmp_path):
    img = nib.Nifti1Image(ramp(np.float32), oblique_affine())
    img.header.extensions.append(nib.nifti1.Nifti1Extension("comment", b"x" * 600))
    path = tmp_path / "ext.nii"
    nib.save(img, str(path))
    raw = bytearray(open(path, "rb").read())
    start = int(struct.unpack("<f", raw[108:112])[0])
    assert start > 352 and raw[348] == 1  # the extension is in the file
    same_as_nibabel(path)
    # The data after a gap that no extension accounts for (vox_offset = 1024, flag 0).
    late = raw[:348] + b"\0\0\0\0" + b"\0" * (1024 - 352) + raw[start:]
    struct.pack_into("<f", late, 108, 1024.0)
    gap = tmp_path / "gap.nii"
    gap.write_bytes(bytes(late))
    values, _ = same_as_nibabel(gap)
    np.testing.assert_array_equal(values, ramp(np.float32))
    # A vox_offset past the end of the file is refused as a short file.
    struct.pack_into("<f", late, 108, 4096.0)
    gap.write_bytes(bytes(late))
    with pytest.raises(hytled.InputError, match="too short"):
        hytled.read_image(gap)


def test_scaled_voxels(tmp_path):
    img = nib.Nifti1Image(ramp(np.int16), oblique_affine())
    img.header.set_slope_inter(0.5, -3.0)
    path = tmp_path / "scaled.nii.gz"
    nib.save(img, str(path))
    values, _ = same_as_nibabel(path)
    assert values.min() == -3.0 and values.max() == 0.5 * 49 - 3.0


def test_four_d_images_are_refused(tmp_path):
    path = tmp_path / "four.nii.gz"
    nib.save(nib.Nifti1Image(np.zeros(SHAPE + (2,), np.int16), np.eye(4)), str(path))
    with pytest.raises(hytled.InputError, match="2 volumes"):
        hytled.read_image(path)
    # One volume along the fourth axis is a 3-D image.
    one = tmp_path / "one.nii.gz"
    nib.save(nib.Nifti1Image(ramp(np.int16)[..., None], np.eye(4)), str(one))
    values, _ = hytled.read_image(one)
    np.testing.assert_array_equal(values, ramp(np.int16))


def nrrd_affine(header):
    """Index to RAS (mm) from a NRRD header written in LPS."""
    a = np.eye(4)
    a[:3, :3] = np.asarray(header["space directions"], float).T
    a[:3, 3] = header["space origin"]
    return np.diag([-1.0, -1.0, 1.0, 1.0]) @ a


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("encoding", ["raw", "gzip"])
@pytest.mark.parametrize("endian", ["little", "big"])
def test_nrrd_as_pynrrd_reads_it(tmp_path, dtype, encoding, endian):
    direction = oblique_affine()[:3, :3].T  # one row per axis, as NRRD lists them
    header = {
        "space": "left-posterior-superior",
        "space directions": direction,
        "space origin": np.array([-10.0, 4.0, 7.5]),
        "encoding": encoding,
        "endian": endian,
        "kinds": ["domain", "domain", "domain"],
    }
    path = tmp_path / "a.nrrd"
    nrrd.write(str(path), ramp(dtype), header)
    data, read_header = nrrd.read(str(path))
    values, affine = hytled.read_image(path)
    np.testing.assert_array_equal(values, data.astype(np.float64))
    np.testing.assert_allclose(mm(affine), nrrd_affine(read_header), atol=1e-9)
    # The same file detached: a .nhdr beside its data.
    nhdr = tmp_path / "b.nhdr"
    nrrd.write(str(nhdr), ramp(dtype), header, detached_header=True)
    values, affine = hytled.read_image(nhdr)
    np.testing.assert_array_equal(values, data.astype(np.float64))


def test_nrrd_data_files_outside_the_header_s_folder_are_refused(tmp_path):
    for target in ["/etc/passwd", "../outside.raw"]:
        path = tmp_path / "evil.nhdr"
        path.write_text(
            "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n"
            f"data file: {target}\n\n"
        )
        with pytest.raises(hytled.InputError, match="not a path below the header"):
            hytled.read_image(path)


def test_vector_nrrd_is_refused(tmp_path):
    path = tmp_path / "vec.nrrd"
    nrrd.write(
        str(path),
        np.zeros((3,) + SHAPE, np.float32),
        {"kinds": ["vector", "domain", "domain", "domain"], "encoding": "raw"},
    )
    with pytest.raises(hytled.InputError, match="3 values per voxel"):
        hytled.read_image(path)

"""Writes a labelmap with the independent writers nibabel and pynrrd, for tests/registration/segmentation_python.rs.

Input (in DIR): labels.u16 (little-endian uint16, first index fastest) and meta.json
({"dims": [nx, ny, nz], "affine_lps": 4x4 rows, index -> LPS mm}).
Output (in DIR):
  sform.nii.gz   int16, sform_code 2 (aligned), qform_code 0, gzip      (nibabel)
  qform.nii      uint8, qform_code 1 (scanner), sform_code 0            (nibabel)
  liver.seg.nrrd uint8, gzip, space LPS, Slicer segment key/values      (pynrrd)
  ras.nrrd       int16 big-endian, raw, space RAS                       (pynrrd)

Needs: python3 -m pip install nibabel==5.4.2 pynrrd==1.1.3 numpy
"""

import json
import sys
from pathlib import Path

import nibabel as nib
import nrrd
import numpy as np


def main(out: Path) -> None:
    meta = json.loads((out / "meta.json").read_text())
    nx, ny, nz = meta["dims"]
    lps = np.array(meta["affine_lps"], dtype=float)
    labels = np.fromfile(out / "labels.u16", dtype="<u2")
    assert labels.size == nx * ny * nz, (labels.size, nx, ny, nz)
    # First index fastest: Fortran order with shape (nx, ny, nz).
    arr = labels.reshape((nx, ny, nz), order="F")

    # NIfTI's world is RAS+: negate x and y.
    ras = np.diag([-1.0, -1.0, 1.0, 1.0]) @ lps

    img = nib.Nifti1Image(arr.astype(np.int16), None)
    img.set_sform(ras, code=2)
    img.set_qform(None, code=0)
    nib.save(img, str(out / "sform.nii.gz"))

    img = nib.Nifti1Image(arr.astype(np.uint8), None)
    img.set_qform(ras, code=1)
    img.set_sform(None, code=0)
    nib.save(img, str(out / "qform.nii"))

    # NRRD: space directions are one vector per axis (the affine's columns).
    header = {
        "type": "uint8",
        "dimension": 3,
        "space": "left-posterior-superior",
        "space directions": lps[:3, :3].T,
        "space origin": lps[:3, 3],
        "kinds": ["domain", "domain", "domain"],
        "encoding": "gzip",
        "Segment0_ID": "Segment_1",
        "Segment0_Name": "liver",
        "Segment0_LabelValue": "1",
        "Segment0_Layer": "0",
        "Segment1_ID": "Segment_2",
        "Segment1_Name": "tumour",
        "Segment1_LabelValue": "2",
        "Segment1_Layer": "0",
    }
    nrrd.write(str(out / "liver.seg.nrrd"), arr.astype(np.uint8), header, index_order="F")

    header = {
        "type": "int16",
        "dimension": 3,
        "space": "right-anterior-superior",
        "space directions": ras[:3, :3].T,
        "space origin": ras[:3, 3],
        "kinds": ["domain", "domain", "domain"],
        "encoding": "raw",
        "endian": "big",
    }
    nrrd.write(str(out / "ras.nrrd"), arr.astype(">i2"), header, index_order="F")
    print(f"nibabel {nib.__version__}, pynrrd {nrrd.__version__}, numpy {np.__version__}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))

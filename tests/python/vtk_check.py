"""Independent VTK reader and writer for livereg's VTK tests (tests/cli/vtk_files.rs).

  vtk_check.py read FILE...        prints JSON: per file its points and cells as VTK reads them
  vtk_check.py write OBJ OUTDIR    writes the OBJ's surface in the encodings VTK itself uses
  vtk_check.py pvd FILE.pvd        prints JSON: the (timestep, file) entries of a collection

Needs the `vtk` package (python3 -m pip install vtk==9.7.1; scripts/test installs it).
"""
import json
import os
import sys
import xml.etree.ElementTree as ET

import vtk
from vtk.util.numpy_support import vtk_to_numpy


def cells(cell_array):
    out = []
    offsets = vtk_to_numpy(cell_array.GetOffsetsArray())
    conn = vtk_to_numpy(cell_array.GetConnectivityArray())
    for k in range(len(offsets) - 1):
        out.append([int(i) for i in conn[offsets[k]:offsets[k + 1]]])
    return out


def read(path):
    if path.endswith(".vtp"):
        reader = vtk.vtkXMLPolyDataReader()
    elif path.endswith(".vtk"):
        reader = vtk.vtkPolyDataReader()
        reader.ReadAllScalarsOn()
    else:
        raise SystemExit(f"unknown extension: {path}")
    reader.SetFileName(path)
    reader.Update()
    if hasattr(reader, "GetErrorCode") and reader.GetErrorCode() != 0:
        raise SystemExit(f"{path}: VTK reader error {reader.GetErrorCode()}")
    data = reader.GetOutput()
    if data.GetNumberOfPoints() == 0:
        raise SystemExit(f"{path}: VTK read no points")
    points = vtk_to_numpy(data.GetPoints().GetData())
    arrays = {}
    pd = data.GetPointData()
    for i in range(pd.GetNumberOfArrays()):
        a = pd.GetArray(i)
        arrays[a.GetName()] = vtk_to_numpy(a).tolist()
    return {
        "point_type": data.GetPoints().GetData().GetDataTypeAsString(),
        "points": points.tolist(),
        "polys": cells(data.GetPolys()),
        "verts": cells(data.GetVerts()),
        "strips": cells(data.GetStrips()),
        "arrays": arrays,
    }


def read_obj(path):
    pts, polys = [], []
    for line in open(path):
        t = line.split()
        if not t:
            continue
        if t[0] == "v":
            pts.append([float(x) for x in t[1:4]])
        elif t[0] == "f":
            polys.append([int(x.split("/")[0]) - 1 for x in t[1:]])
    return pts, polys


def write(obj, outdir):
    pts, polys = read_obj(obj)
    points = vtk.vtkPoints()
    points.SetDataTypeToDouble()
    for p in pts:
        points.InsertNextPoint(p)
    cells_ = vtk.vtkCellArray()
    for f in polys:
        cells_.InsertNextCell(len(f), f)
    poly = vtk.vtkPolyData()
    poly.SetPoints(points)
    poly.SetPolys(cells_)
    os.makedirs(outdir, exist_ok=True)

    def xml(name, configure):
        w = vtk.vtkXMLPolyDataWriter()
        w.SetFileName(os.path.join(outdir, name))
        w.SetInputData(poly)
        configure(w)
        if w.Write() != 1:
            raise SystemExit(f"writing {name} failed")

    xml("vtk_default.vtp", lambda w: None)  # appended, base64, zlib, UInt64 headers
    xml("vtk_raw.vtp", lambda w: (w.SetDataModeToAppended(), w.EncodeAppendedDataOff()))
    xml("vtk_binary_inline.vtp", lambda w: (w.SetDataModeToBinary(), w.SetCompressorTypeToNone()))
    xml("vtk_ascii.vtp", lambda w: w.SetDataModeToAscii())
    for name, binary in [("vtk_binary.vtk", True), ("vtk_ascii.vtk", False)]:
        w = vtk.vtkPolyDataWriter()
        w.SetFileName(os.path.join(outdir, name))
        w.SetInputData(poly)
        w.SetFileVersion(42)
        if binary:
            w.SetFileTypeToBinary()
        else:
            w.SetFileTypeToASCII()
        if w.Write() != 1:
            raise SystemExit(f"writing {name} failed")
    # The same surface as triangle strips (VTK's stripper), to check strip orientation.
    stripper = vtk.vtkStripper()
    stripper.SetInputData(poly)
    stripper.Update()
    w = vtk.vtkXMLPolyDataWriter()
    w.SetFileName(os.path.join(outdir, "vtk_strips.vtp"))
    w.SetInputData(stripper.GetOutput())
    w.Write()
    print(json.dumps({"strips": stripper.GetOutput().GetNumberOfStrips()}))


def pvd(path):
    root = ET.parse(path).getroot()
    assert root.get("type") == "Collection", root.get("type")
    entries = [
        {"timestep": float(d.get("timestep")), "file": d.get("file")}
        for d in root.iter("DataSet")
    ]
    return entries


if __name__ == "__main__":
    mode = sys.argv[1]
    if mode == "read":
        print(json.dumps({p: read(p) for p in sys.argv[2:]}))
    elif mode == "write":
        write(sys.argv[2], sys.argv[3])
    elif mode == "pvd":
        print(json.dumps(pvd(sys.argv[2])))
    else:
        raise SystemExit(f"unknown mode {mode}")

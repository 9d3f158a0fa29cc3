"""pyigtl side of tests/server/openigtlink_pyigtl.rs (livereg's OpenIGTLink codec against pyigtl 0.3.4).

Subcommands:
  check                      pyigtl 0.3.4 importable; prints pyigtl's CRC-64 of b"123456789"
  encode OUTDIR              pyigtl packs messages to OUTDIR/NAME.bin, expected values to
                             OUTDIR/expected.json (floats already rounded to float32)
  decode FILE EXPECTED.json  pyigtl parses FILE (header, CRC, extended header, metadata, content)
                             and compares with EXPECTED; exit status 1 with the differences
  client PORT                pyigtl.OpenIGTLinkClient connects to 127.0.0.1:PORT, sends a POINT
                             message, waits for the TRANSFORM "LiverToReference" and prints it
                             as JSON

pyigtl 0.3.4 has no STATUS class and its POLYDATA unpacking does not run (it indexes a
struct.Struct); for those two the script defines the content codec itself, from the
OpenIGTLink spec, and keeps pyigtl's MessageBase for header, CRC, extended header and metadata.
"""

import importlib.metadata
import json
import os
import struct
import sys
import time

import numpy as np
import pyigtl
from pyigtl import messages as igtl_messages

PYIGTL_VERSION = "0.3.4"


def f32(value):
    """The float32 that goes on the wire, as a Python float."""
    return float(np.float32(value))


class StatusMessage(pyigtl.MessageBase):
    """STATUS (spec "Status Message"): u16 code, i64 sub-code, char[20] error name, message + NUL."""

    def __init__(self, code=1, subcode=0, error_name="", status_message="", timestamp=None, device_name=None):
        pyigtl.MessageBase.__init__(self, timestamp=timestamp, device_name=device_name)
        self._message_type = "STATUS"
        self.code = code
        self.subcode = subcode
        self.error_name = error_name
        self.status_message = status_message
        self._valid_message = True

    def _pack_content(self):
        return (struct.pack(">Hq20s", self.code, self.subcode, self.error_name.encode("utf8"))
                + self.status_message.encode("utf8") + b"\0")

    def _unpack_content(self, content):
        self.code, self.subcode, name = struct.unpack(">Hq20s", content[:30])
        self.error_name = name.split(b"\0", 1)[0].decode("utf8")
        self.status_message = content[30:].split(b"\0", 1)[0].decode("utf8")


class PolyDataReader(pyigtl.PolyDataMessage):
    """pyigtl's PolyDataMessage with a working content decoder (points and the four cell arrays;
    attributes are not decoded)."""

    def _unpack_content(self, content):
        header = struct.unpack(">10I", content[:40])
        npoints = header[0]
        offset = 40
        self.points = np.frombuffer(content[offset:offset + 12 * npoints], dtype=">f4").reshape(-1, 3)
        offset += 12 * npoints
        arrays = []
        for size in header[2:9:2]:
            arrays.append(np.frombuffer(content[offset:offset + size], dtype=">u4"))
            offset += size
        self.vertices, self.lines, self.polygons, self.triangle_strips = arrays
        self.cell_counts = list(header[1:9:2])
        self.attribute_count = header[9]


def cells_to_lists(flat):
    """A VTK cell array (count, indices, count, ...) as a list of lists."""
    flat = [int(v) for v in flat]
    cells, i = [], 0
    while i < len(flat):
        n = flat[i]
        cells.append(flat[i + 1:i + 1 + n])
        i += 1 + n
    return cells


def lists_to_cells(cells):
    flat = []
    for cell in cells:
        flat.append(len(cell))
        flat.extend(cell)
    return np.array(flat, dtype=np.uint32)


def common_expected(message):
    return {
        "type": message.message_type,
        "device_name": message.device_name,
        "timestamp": message.timestamp,
        "header_version": message.header_version,
        "message_id": message.message_id,
        "metadata": dict(message.metadata),
    }


def encode(outdir):
    expected = {}

    def save(name, message, content):
        with open(os.path.join(outdir, name + ".bin"), "wb") as f:
            f.write(message.pack())
        entry = common_expected(message)
        entry["content"] = content
        expected[name] = entry

    matrix = np.array([[0.0, -1.0, 0.0, 10.5],
                       [1.0, 0.0, 0.0, -20.25],
                       [0.0, 0.0, 1.0, 300.125],
                       [0.0, 0.0, 0.0, 1.0]])
    rotated = np.eye(4)
    angle = 0.3
    rotated[:3, :3] = [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    rotated[:3, 3] = [1.1, 2.2, 3.3]

    m = pyigtl.TransformMessage(matrix, timestamp=1700000000.5, device_name="ToolToReference")
    save("transform_v1", m, {"matrix": [[f32(v) for v in row] for row in matrix]})

    m = pyigtl.TransformMessage(rotated, timestamp=1700000123.25, device_name="LiverToReference")
    m.header_version = 2
    m.message_id = 42
    m.metadata = {"units": "mm", "livereg.frame": "7"}
    save("transform_v2", m, {"matrix": [[f32(v) for v in row] for row in rotated]})

    positions = [[1.5, -2.25, 300.0], [0.1, 0.2, 0.3]]
    m = pyigtl.PointMessage(positions=positions, names=["Tip", "Entry"], rgba_colors=[[255, 0, 0, 255], [0, 128, 255, 100]],
                            diameters=[2.5, 0.0], groups="Landmark", owners=["CT", ""],
                            timestamp=1700000200.0, device_name="Fiducials")
    m.header_version = 2
    m.metadata = {"units": "mm"}
    save("point_v2", m, {"points": [
        {"name": "Tip", "group": "Landmark", "rgba": [255, 0, 0, 255], "position": [f32(v) for v in positions[0]],
         "diameter": 2.5, "owner": "CT"},
        {"name": "Entry", "group": "Landmark", "rgba": [0, 128, 255, 100], "position": [f32(v) for v in positions[1]],
         "diameter": 0.0, "owner": ""},
    ]})

    m = pyigtl.PointMessage(positions=[4.0, 5.0, 6.0], names="One", timestamp=1700000201.0, device_name="Fiducials")
    save("point_v1", m, {"points": [
        {"name": "One", "group": "", "rgba": [255, 255, 0, 255], "position": [4.0, 5.0, 6.0], "diameter": 0.0, "owner": ""},
    ]})

    # A tetrahedron as triangles, and a quad as a polygon, plus a polyline.
    points = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10.5], [0.1, 0.2, 0.3]], dtype=np.float64)
    polygons = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3], [0, 1, 3, 4]]
    lines = [[0, 1, 2]]
    m = pyigtl.PolyDataMessage(points=points, polygons=lists_to_cells(polygons), lines=lists_to_cells(lines),
                               timestamp=1700000300.0, device_name="LiverModel")
    m.header_version = 2
    m.metadata = {"units": "mm"}
    save("polydata_surface", m, {"points": [[f32(v) for v in p] for p in points], "polygons": polygons,
                                 "lines": lines, "vertices": [], "triangle_strips": []})

    cloud = np.array([[1.25, 2.5, 3.75], [-4.0, 5.5, 600.0], [0.1, 0.2, 0.3]])
    m = pyigtl.PolyDataMessage(points=cloud, timestamp=1700000301.0, device_name="IntraopCloud")
    save("polydata_cloud", m, {"points": [[f32(v) for v in p] for p in cloud], "polygons": [], "lines": [],
                               "vertices": [], "triangle_strips": []})

    # pyigtl 0.3.4 writes the VERTICES array in native (little-endian) byte order, against the spec.
    m = pyigtl.PolyDataMessage(points=cloud, vertices=lists_to_cells([[0], [1], [2]]),
                               timestamp=1700000302.0, device_name="IntraopCloud")
    save("polydata_vertices_pyigtl_byte_order", m, None)

    m = StatusMessage(code=10, subcode=-42, error_name="ConfigError", status_message="no scene loaded",
                      timestamp=1700000400.0, device_name="LiverModel")
    m.header_version = 2
    m.message_id = 9
    m.metadata = {"units": "mm"}
    save("status_v2", m, {"code": 10, "subcode": -42, "error_name": "ConfigError", "message": "no scene loaded"})

    m = StatusMessage(code=1, subcode=0, error_name="OK", status_message="", timestamp=1700000401.0, device_name="")
    save("status_v1", m, {"code": 1, "subcode": 0, "error_name": "OK", "message": ""})

    with open(os.path.join(outdir, "expected.json"), "w") as f:
        json.dump(expected, f, indent=1)


def decode(path, expected_path):
    with open(path, "rb") as f:
        data = f.read()
    with open(expected_path) as f:
        expected = json.load(f)
    problems = []

    def check(what, got, want):
        if got != want:
            problems.append(f"{what}: pyigtl decoded {got!r}, expected {want!r}")

    header = data[:pyigtl.MessageBase.IGTL_HEADER_SIZE]
    body = data[pyigtl.MessageBase.IGTL_HEADER_SIZE:]
    fields = pyigtl.MessageBase.parse_header(header)
    check("body size", fields["body_size"], len(body))
    # pyigtl does not verify the CRC when receiving: check it here with pyigtl's CRC function.
    crc_field = struct.unpack(">Q", header[50:58])[0]
    check("CRC field against pyigtl's CRC64(body)", crc_field, igtl_messages.CRC64(body))

    message_type = fields["message_type"]
    if message_type == "STATUS":
        message = StatusMessage()
    elif message_type == "POLYDATA":
        message = PolyDataReader()
    else:
        message = pyigtl.MessageBase.create_message(message_type)
        if message is None:
            print(f"pyigtl does not know message type {message_type!r}", file=sys.stderr)
            sys.exit(1)
    message.unpack(fields, body)

    check("type", message.message_type, expected["type"])
    check("device name", message.device_name, expected["device_name"])
    check("header version", message.header_version, expected["header_version"])
    check("message id", message.message_id, expected["message_id"])
    check("metadata", dict(message.metadata), expected["metadata"])
    if abs(message.timestamp - expected["timestamp"]) > 1e-6:
        problems.append(f"timestamp: pyigtl decoded {message.timestamp}, expected {expected['timestamp']}")

    content = expected["content"]
    if message_type == "TRANSFORM":
        check("matrix", [[float(v) for v in row] for row in message.matrix], content["matrix"])
    elif message_type == "POINT":
        got = [{"name": message.names[i], "group": message.groups[i], "rgba": [int(c) for c in message.rgba_colors[i]],
                "position": [float(v) for v in message.positions[i]], "diameter": float(message.diameters[i]),
                "owner": message.owners[i]} for i in range(len(message.names))]
        check("points", got, content["points"])
    elif message_type == "POLYDATA":
        check("points", [[float(v) for v in p] for p in message.points], content["points"])
        for key in ["vertices", "lines", "polygons", "triangle_strips"]:
            check(key, cells_to_lists(getattr(message, key)), content[key])
        check("cell counts", message.cell_counts, [len(content[k]) for k in ["vertices", "lines", "polygons", "triangle_strips"]])
        check("attribute count", message.attribute_count, 0)
    elif message_type == "STATUS":
        check("status", {"code": message.code, "subcode": message.subcode, "error_name": message.error_name,
                         "message": message.status_message}, content)
    if problems:
        print("\n".join(problems), file=sys.stderr)
        sys.exit(1)
    print("ok")


def client(port):
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)
    try:
        points = pyigtl.PointMessage(positions=[[1.0, 2.0, 3.0], [-4.5, 5.25, 600.0]], names=["A", "B"],
                                     timestamp=1700000500.0, device_name="IntraopCloud")
        points.header_version = 2
        points.metadata = {"livereg.frame": "3", "units": "mm"}
        deadline = time.time() + 20
        while not client.is_connected():
            if time.time() > deadline:
                print("pyigtl client could not connect", file=sys.stderr)
                sys.exit(1)
            time.sleep(0.01)
        client.send_message(points, wait=True)
        reply = client.wait_for_message("LiverToReference", timeout=20)
        if reply is None:
            print("no TRANSFORM LiverToReference received within 20 s", file=sys.stderr)
            sys.exit(1)
        print(json.dumps({
            "type": reply.message_type,
            "device_name": reply.device_name,
            "header_version": reply.header_version,
            "message_id": reply.message_id,
            "metadata": dict(reply.metadata),
            "timestamp": reply.timestamp,
            "matrix": [[float(v) for v in row] for row in reply.matrix],
        }))
    finally:
        client.stop()


def main():
    installed = importlib.metadata.version("pyigtl")
    if installed != PYIGTL_VERSION:
        print(f"pyigtl {installed} installed, the tests need {PYIGTL_VERSION}: "
              f"python3 -m pip install pyigtl=={PYIGTL_VERSION}", file=sys.stderr)
        sys.exit(2)
    command = sys.argv[1] if len(sys.argv) > 1 else ""
    if command == "check":
        print(f"{igtl_messages.CRC64(b'123456789'):016x}")
    elif command == "encode":
        encode(sys.argv[2])
    elif command == "decode":
        decode(sys.argv[2], sys.argv[3])
    elif command == "client":
        client(int(sys.argv[2]))
    else:
        print(__doc__, file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()

"""A pyigtl client streaming frames to `livereg serve`'s OpenIGTLink port (tests/server/server_igtl.rs).

  igtl_stream.py PORT FRAMES.json OUT.json

FRAMES.json is a list of frames, each a list of [x, y, z] in mm. Frame k goes out as a POINT
message (even k) or a POLYDATA message with points only (odd k; pyigtl 0.3.4 writes vertex
cells in the wrong byte order), device "IntraopCloud", header version 2 with metadata
livereg.frame = k. The client then waits for the frame's TRANSFORM "LiverToReference",
POLYDATA "DeformedLiver" and POINT "Targets" (each must carry livereg.frame = k) before sending
the next frame, and writes what it received to OUT.json.

pyigtl cannot decode POLYDATA or STATUS (it drops them); its message table gets the decoders
of igtl_pyigtl.py (written from the spec) for those two types. Everything else — the socket,
framing, header, CRC, metadata, TRANSFORM and POINT — is pyigtl's own.
"""
import json
import sys
import time

import numpy as np
import pyigtl
from pyigtl import messages as igtl_messages

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from igtl_pyigtl import PolyDataReader, StatusMessage, cells_to_lists  # noqa: E402

igtl_messages.message_type_to_class_constructor["POLYDATA"] = PolyDataReader
igtl_messages.message_type_to_class_constructor["STATUS"] = StatusMessage

TIMEOUT_S = 120


def wait_for(client, device, k):
    deadline = time.time() + TIMEOUT_S
    while time.time() < deadline:
        m = client.wait_for_message(device, timeout=max(0.0, deadline - time.time()))
        if m is None:
            break
        frame = dict(m.metadata).get("livereg.frame")
        if frame == str(k):
            return m
        if m.message_type == "STATUS":
            raise SystemExit(f"frame {k}: STATUS {m.code} {m.error_name}: {m.status_message}")
    statuses = [m for m in client.get_latest_messages() if m.message_type == "STATUS"]
    detail = "; ".join(f"{s.device_name}: {s.error_name} {s.status_message}" for s in statuses)
    raise SystemExit(f"frame {k}: no {device} with livereg.frame={k} within {TIMEOUT_S} s {detail}")


def main():
    port, frames_path, out_path = int(sys.argv[1]), sys.argv[2], sys.argv[3]
    frames = json.load(open(frames_path))
    client = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=port)
    results = []
    try:
        deadline = time.time() + 20
        while not client.is_connected():
            if time.time() > deadline:
                raise SystemExit("pyigtl could not connect")
            time.sleep(0.01)
        for k, pts in enumerate(frames):
            pts = np.asarray(pts, dtype=float)
            if k % 2 == 0:
                msg = pyigtl.PointMessage(positions=pts, names=[f"p{i}" for i in range(len(pts))],
                                          device_name="IntraopCloud")
            else:
                msg = pyigtl.PolyDataMessage(points=pts, device_name="IntraopCloud")
            msg.header_version = 2
            msg.metadata = {"livereg.frame": str(k)}
            t0 = time.perf_counter()
            client.send_message(msg, wait=True)
            transform = wait_for(client, "LiverToReference", k)
            liver = wait_for(client, "DeformedLiver", k)
            targets = wait_for(client, "Targets", k)
            results.append({
                "frame": k,
                "round_trip_ms": (time.perf_counter() - t0) * 1e3,
                "server_ms": float(dict(targets.metadata)["livereg.server_ms"]),
                "transform": [[float(v) for v in row] for row in transform.matrix],
                "liver_points": int(len(liver.points)),
                "liver_polygons": cells_to_lists(liver.polygons),
                "target_names": list(targets.names),
                "target_groups": list(targets.groups),
                "targets": [[float(v) for v in p] for p in targets.positions],
                "header_version": targets.header_version,
                "session": dict(targets.metadata).get("livereg.session"),
                "units": dict(targets.metadata).get("units"),
            })
    finally:
        client.stop()
    json.dump(results, open(out_path, "w"))
    print("ok")


if __name__ == "__main__":
    main()

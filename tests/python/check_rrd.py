#!/usr/bin/env python3
"""Reads a rerun .rrd file with rerun's Python SDK (0.36: `rerun.experimental.RrdReader`) and
prints one JSON object: the entity paths that hold data, the timelines and the values of the
`frame` timeline. Used by tests/rerun_demo.rs.

Usage: check_rrd.py FILE.rrd
"""
import json
import sys

import rerun as rr
from rerun.experimental import RrdReader


def main():
    reader = RrdReader(sys.argv[1])
    entities, timelines, frames = set(), set(), set()
    for chunk in reader.stream():
        if chunk.is_empty:
            continue
        entities.add(chunk.entity_path)
        names = chunk.timeline_names
        timelines.update(names)
        if "frame" in names:
            batch = chunk.to_record_batch()
            frames.update(v for v in batch.column("frame").to_pylist() if v is not None)
    print(json.dumps({"entities": sorted(entities), "timelines": sorted(timelines),
                      "frames": sorted(frames), "recordings": len(reader.recordings()),
                      "version": rr.__version__}))


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Reads a livereg MCAP recording with the `mcap` Python package (independent of the Rust
reader) and prints one JSON object: channels, schemas, message counts and a summary of the
decoded payloads. Used by tests/cli/recording_cli.rs.

Usage: check_recording.py FILE            (a finished recording: indexed reader + summary)
       check_recording.py FILE --stream   (any file, e.g. one cut short by a kill: sequential
                                           reader, stops at the first incomplete record)
"""
import json
import sys

from mcap.reader import NonSeekingReader, make_reader


def decode_all(messages):
    out = {"counts": {}, "frames": [], "results": [], "scene": None, "session": None,
           "schemas": {}, "channels": {}, "tail_error": None}
    try:
        for schema, channel, message in messages:
            out["channels"][channel.topic] = {"message_encoding": channel.message_encoding,
                                              "schema": schema.name if schema else None}
            if schema is not None:
                body = json.loads(schema.data)
                out["schemas"][schema.name] = {"encoding": schema.encoding,
                                               "title": body.get("title"),
                                               "required": body.get("required", [])}
            out["counts"][channel.topic] = out["counts"].get(channel.topic, 0) + 1
            payload = json.loads(message.data)
            if channel.topic == "/frames":
                pts = payload["points"]
                assert len(pts) % 3 == 0, "flat xyz"
                out["frames"].append({"frame": payload["frame"], "source": payload["source"],
                                      "points": len(pts) // 3,
                                      "first_point": pts[:3],
                                      "timestamp_ns": payload["timestamp_ns"],
                                      "log_time": message.log_time})
            elif channel.topic == "/results":
                out["results"].append({"frame": payload["frame"], "source": payload["source"],
                                       "surface_vertices": len(payload["surface"]) // 3,
                                       "structures": {k: len(v) for k, v in payload["structures"].items()},
                                       "diagnostics": sorted(payload["diagnostics"].keys()),
                                       "keys": sorted(payload.keys())})
            elif channel.topic == "/scene":
                out["scene"] = {"name": payload["name"], "format": payload["format"],
                                "files": [(f["key"], f["name"], f["size"]) for f in payload["files"]],
                                "text_starts": payload["text"][:40]}
            elif channel.topic == "/session":
                out["session"] = payload
    except Exception as e:  # a file cut short: report where reading stopped
        out["tail_error"] = f"{type(e).__name__}: {e}"
    return out


def main():
    path = sys.argv[1]
    stream_mode = "--stream" in sys.argv[2:]
    with open(path, "rb") as f:
        if stream_mode:
            result = decode_all(NonSeekingReader(f).iter_messages(log_time_order=False))
            result["summary"] = None
        else:
            reader = make_reader(f)
            summary = reader.get_summary()
            result = decode_all(reader.iter_messages(log_time_order=False))
            result["summary"] = {
                "chunks": len(summary.chunk_indexes),
                "message_count": summary.statistics.message_count,
                "channel_message_counts": {summary.channels[c].topic: n for c, n in
                                           summary.statistics.channel_message_counts.items()},
                "topics": sorted(c.topic for c in summary.channels.values()),
            }
    print(json.dumps(result))


if __name__ == "__main__":
    main()

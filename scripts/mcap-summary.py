#!/usr/bin/env python3
"""Summarise an `ima ... --record FILE.mcap` recording with the Python `mcap` package.

Usage:  python3 -m pip install mcap   # once
        scripts/mcap-summary.py FILE.mcap [--check [--summary DEMO.jsonl]]

Prints, per topic: the schema, the message count and the bytes; for raw serial channels the
port, baud and protocol from the channel metadata. With --check, exits 1 unless the file has
what a recorded `ima demo` must have (a raw channel per serial port of both robots, laser
scans, transforms, the SES scene, broadcasts as logs, camera images, sonar point clouds, the
SAN's and the Peer Agents' state as JSON that parses and has its fields), and the summary's
message counts agree with the messages actually read. With --summary, the file holding the
`ima demo --json` output too: the recorded scans and camera frames must then match the
counts the demo's drivers reported (`drivers` in its summary line).
"""

import json
import sys
from collections import Counter

from mcap.reader import make_reader

IMAGES = {"foxglove.RawImage", "foxglove.CompressedImage"}


def main(argv):
    if len(argv) < 2 or argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        return 2
    path, check = argv[1], "--check" in argv[2:]
    demo = argv[argv.index("--summary") + 1] if "--summary" in argv[2:-1] else None
    counts, sizes, chans = Counter(), Counter(), {}
    json_problems, last_json = [], {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            sizes[channel.topic] += len(message.data)
            chans[channel.topic] = (schema.name if schema else "", dict(channel.metadata))
            if channel.message_encoding == "json":
                try:
                    last_json[channel.topic] = json.loads(message.data)
                except ValueError as e:
                    json_problems.append(f"{channel.topic}: not JSON ({e})")
        summary = reader.get_summary()
    for topic in sorted(counts):
        schema, meta = chans[topic]
        extra = ""
        if "port" in meta:
            extra = f"  port={meta['port']} baud={meta.get('baud')} protocol={meta.get('protocol')}"
        print(f"{topic:32} {schema or '(raw bytes)':24} {counts[topic]:7} msgs {sizes[topic]:10} B{extra}")
    if summary and summary.statistics:
        s = summary.statistics
        span = (s.message_end_time - s.message_start_time) / 1e9
        print(f"{s.message_count} messages over {span:.1f} s in {len(summary.chunk_indexes)} chunks")
    if not check:
        return 0
    problems = []
    raw = {t: m.get("protocol") for t, (_, m) in chans.items() if "/serial/" in t}
    for want in ("/skeeter/serial/base", "/skeeter/serial/video_mux", "/scooter/serial/base",
                 "/scooter/serial/laser", "/scooter/serial/compass"):
        if want not in raw:
            problems.append(f"no raw channel {want}")
    schemas = {s for s, _ in chans.values()}
    for want in ("foxglove.LaserScan", "foxglove.FrameTransform", "foxglove.SceneUpdate",
                 "foxglove.Log", "foxglove.PointCloud"):
        if want not in schemas:
            problems.append(f"no {want} channel")
    if not schemas & IMAGES:
        problems.append("no foxglove.RawImage or foxglove.CompressedImage channel")
    problems += json_problems
    for topic, fields in (("/san/scooter", ("modules", "activation", "selected", "threshold")),
                          ("/san/skeeter", ("modules", "activation", "selected", "threshold")),
                          ("/peer/skeeter/status", ("broadcast", "sources", "clients")),
                          ("/peer/scooter/status", ("broadcast",))):
        msg = last_json.get(topic)
        if msg is None:
            problems.append(f"no JSON state topic {topic}")
        else:
            problems += [f"{topic}: no field {k}" for k in fields if k not in msg]
    if demo:
        lines = [json.loads(l) for l in open(demo) if l.strip()]
        drivers = next((l["drivers"] for l in lines if l.get("kind") == "summary"), None)
        if drivers is None:
            problems.append(f"{demo}: no summary line with the drivers' counters")
        else:
            images = sum(n for t, n in counts.items() if chans[t][0] in IMAGES)
            for what, recorded, counted in (
                    ("camera frames", images, drivers["skeeter"].get("camera_frames")),
                    ("scans read", counts["/scooter/laser/scan"],
                     drivers["scooter"].get("laser_scans_read"))):
                if recorded != counted:
                    problems.append(f"{what}: {recorded} recorded, the drivers counted {counted}")
    if summary is None or summary.statistics is None:
        problems.append("no summary (the recording was not closed)")
    else:
        by_id = {c.id: c.topic for c in summary.channels.values()}
        for cid, n in summary.statistics.channel_message_counts.items():
            if counts[by_id[cid]] != n:
                problems.append(f"{by_id[cid]}: summary says {n}, read {counts[by_id[cid]]}")
    for p in problems:
        print("problem:", p, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))

#!/usr/bin/env python3
"""Reads a hydrometrad procedure recording (MCAP, docs/recording.md) with the `mcap` package and
decodes its statuses with the layout table of docs/ipc.md.

    pip install mcap        # with lz4 (a dependency of mcap)
    python3 record/examples/python/read_recording.py RECORDING.mcap --ipc-doc docs/ipc.md --json

Prints the channel counts and the first and last status (every field of the table) as JSON. The
layout is read from the `<!-- layout: hydrometra.v1.Status size=N -->` table of docs/ipc.md, so
this script decodes whatever that document specifies, independently of the Rust struct.
"""

import argparse
import json
import math
import re
import struct
import sys

from mcap.reader import make_reader

# 1 mmHg in Pa: hydrometra_units::PA_PER_MMHG (ipc/tests/python_constants.rs keeps them equal).
PA_PER_MMHG = 133.322387415
TYPES = {"u32": "I", "u64": "Q", "f64": "d", "i32": "i", "i64": "q", "f32": "f"}


def status_layout(ipc_doc):
    """[(offset, struct format, count, name)] and the size, from the Status table of docs/ipc.md."""
    text = open(ipc_doc, encoding="utf-8").read()
    m = re.search(r"<!-- layout: hydrometra\.v1\.Status size=(\d+) -->\n(.*?)\n\n", text, re.S)
    if not m:
        sys.exit(f"{ipc_doc}: no '<!-- layout: hydrometra.v1.Status size=N -->' table")
    size = int(m.group(1))
    fields = []
    for line in m.group(2).splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 4 or not cells[0].isdigit():
            continue
        offset, nbytes, typ, name = int(cells[0]), int(cells[1]), cells[2], cells[3].strip("`")
        t = re.fullmatch(r"([a-z]\d+)(?:\[(\d+)\])?", typ)
        if not t or t.group(1) not in TYPES:
            sys.exit(f"{ipc_doc}: field {name}: unknown type {typ}")
        count = int(t.group(2) or 1)
        fields.append((offset, TYPES[t.group(1)], count, name))
        if struct.calcsize("<" + TYPES[t.group(1)] * count) != nbytes:
            sys.exit(f"{ipc_doc}: field {name}: size {nbytes} does not match type {typ}")
    return fields, size


def decode_status(data, fields, size):
    if len(data) != size:
        raise ValueError(f"status of {len(data)} bytes, the layout says {size}")
    out = {}
    for offset, fmt, count, name in fields:
        values = struct.unpack_from("<" + fmt * count, data, offset)
        v = list(values) if count > 1 else values[0]
        out[name] = v
    return out


def clean(v):
    """JSON has no NaN: NaN becomes null."""
    if isinstance(v, float) and math.isnan(v):
        return None
    if isinstance(v, list):
        return [clean(x) for x in v]
    return v


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording")
    ap.add_argument("--ipc-doc", default="docs/ipc.md")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    fields, size = status_layout(args.ipc_doc)
    counts, first, last, n_status = {}, None, None, 0
    with open(args.recording, "rb") as f:
        reader = make_reader(f)
        profile = reader.get_header().profile
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/status":
                s = decode_status(message.data, fields, size)
                s["log_time_ns"] = message.log_time
                first = first or s
                last = s
                n_status += 1
    result = {
        "profile": profile,
        "channels": counts,
        "first_status": {k: clean(v) for k, v in (first or {}).items()},
        "last_status": {k: clean(v) for k, v in (last or {}).items()},
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{args.recording}: profile {profile}, channels {counts}")
        if last:
            print(f"last status: sequence {last['sequence']}, deficit {last['deficit_m3'] * 1e6:.1f} ml, "
                  f"cavity pressure {last['cavity_pressure_pa'] / PA_PER_MMHG:.1f} mmHg")


if __name__ == "__main__":
    main()

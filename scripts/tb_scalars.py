#!/usr/bin/env python3
"""Scalars of a run's TensorBoard event files as CSV (step, tag, value), for archiving what a
run logged only to TensorBoard (e.g. `train/conservative_gap`, `train/conservative_weight`).

usage: python3 scripts/tb_scalars.py RUN_DIR TAG_SUBSTRING[,TAG_SUBSTRING...] > scalars.csv

Reads every events.out.tfevents.* in RUN_DIR (TFRecord framing, Event and Summary protos decoded
by hand: pure Python, no TensorFlow) and prints the simple values whose tag contains one of the
substrings, in file order.
"""
import glob
import os
import struct
import sys


def varint(b, i):
    r = s = 0
    while True:
        c = b[i]
        i += 1
        r |= (c & 0x7F) << s
        s += 7
        if c < 0x80:
            return r, i


def fields(b):
    """(field number, wire type, value) of one protobuf message."""
    i = 0
    while i < len(b):
        k, i = varint(b, i)
        f, w = k >> 3, k & 7
        if w == 0:
            v, i = varint(b, i)
        elif w == 1:
            v, i = b[i:i + 8], i + 8
        elif w == 5:
            v, i = b[i:i + 4], i + 4
        elif w == 2:
            n, i = varint(b, i)
            v, i = b[i:i + n], i + n
        else:
            raise ValueError(f"wire type {w}")
        yield f, w, v


def scalars(path):
    """(step, tag, value) of every simple value in one event file (Event.step = 2, Event.summary
    = 5, Summary.value = 1, Value.tag = 1, Value.simple_value = 2)."""
    data = open(path, "rb").read()
    i = 0
    while i < len(data):
        # A record is length (u64), its CRC (u32), the bytes, their CRC (u32). A run killed while
        # writing leaves a cut last record: what came before it is whole and is kept.
        if i + 12 > len(data):
            print(f"tb_scalars: {path}: {len(data) - i} bytes of a cut record at the end, ignored", file=sys.stderr)
            return
        n = struct.unpack("<Q", data[i:i + 8])[0]
        if i + 12 + n + 4 > len(data):
            print(f"tb_scalars: {path}: a cut record at byte {i} ({n} bytes announced, "
                  f"{len(data) - i - 12} present), ignored", file=sys.stderr)
            return
        record = data[i + 12:i + 12 + n]
        i += 12 + n + 4
        step = 0
        for f, _, v in fields(record):
            if f == 2:
                step = v
            elif f == 5:
                for f2, _, value in fields(v):
                    if f2 != 1:
                        continue
                    tag = val = None
                    for f3, w3, x in fields(value):
                        if f3 == 1:
                            tag = x.decode()
                        elif f3 == 2 and w3 == 5:
                            val = struct.unpack("<f", x)[0]
                    if tag is not None and val is not None:
                        yield step, tag, val


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__.strip().splitlines()[2].strip())
    run, want = sys.argv[1], sys.argv[2].split(",")
    files = sorted(glob.glob(os.path.join(run, "events.out.tfevents.*")))
    if not files:
        sys.exit(f"tb_scalars: no event files in {run}")
    print("step,tag,value")
    for path in files:
        for step, tag, value in scalars(path):
            if any(w in tag for w in want):
                print(f"{step},{tag},{value:.6g}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Decodes an animation that pp5echo's GIF writer made (Pillow, which applies
each frame's disposal as a browser does) and compares every frame with its
source: no pixel may keep a fragment of an earlier frame (a ghost), and the
palette's rounding stays small. Usage: gif_frames.py GIF_WRITER OUT_DIR"""
import os
import subprocess
import sys

from PIL import Image, ImageSequence

writer, out = sys.argv[1], sys.argv[2]
w, h, n = map(int, subprocess.check_output([writer, out], text=True).split())
gif = Image.open(os.path.join(out, "anim.gif"))
frames = [f.convert("RGB").tobytes() for f in ImageSequence.Iterator(gif)]
failed = False
if len(frames) != n:
    print(f"FAIL: {len(frames)} frames decoded, {n} written")
    sys.exit(1)
for i, got in enumerate(frames):
    with open(os.path.join(out, f"frame{i}.rgb"), "rb") as fh:
        want = fh.read()
    diffs = [abs(a - b) for a, b in zip(got, want)]
    ghosts = sum(1 for d in diffs if d > 64)  # far off: a lit pixel of another frame, or a hole
    mean = sum(diffs) / len(diffs)
    print(f"frame {i}: mean |error| {mean:.2f}, pixels far off {ghosts}")
    if ghosts or mean > 8.0:
        failed = True
print("FAIL" if failed else f"every one of the {n} frames matches its source")
sys.exit(1 if failed else 0)

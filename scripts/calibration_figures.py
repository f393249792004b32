#!/usr/bin/env python3
"""Figures and pictures of docs/calibration.md.

For each of PLUS's two N-wire recordings: `pp5echo calibrate` (default settings), then the
recording reconstructed twice with the same reconstruction settings (the calibration config's
VolumeReconstruction element), once with the new calibration and once with the config's own
(PLUS's fCal result for the fCal 2.0 probe, the hand-typed one of the 1.2 server config). The
wires' positions are known in the Reference frame (PhantomDefinition and Phantom to Reference),
so each reconstruction is scored against them: for every wire, the voxels within 3 mm of the
wire's line, weighted by their value, give the reconstructed wire's offset from the true line
(its centroid) and its spread (RMS distance from that centroid: a sharp wire has little). A
picture shows both reconstructions as maximum intensity projections: along the wires, where each
wire is a dot, and square to the first pattern's plane, where its N shows whole.

Usage: scripts/calibration_figures.py [--build build] [--out out/calibration] [--images docs/images]
                                     [--calibrate-args "--refine all-wires"]
Needs numpy and Pillow (Debian's python3-numpy, python3-pil).
"""
import argparse
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
import zlib

import numpy as np
from PIL import Image

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(os.path.dirname(ROOT), "shared", "data", "plus")

CASES = [
    ("fcal20", "fCal_Test_Calibration_3NWires_fCal2.0.igs.mha", "PlusDeviceSet_fCal_Sim_SpatialCalibration_2.0.xml",
     "PlusDeviceSet_fCal_Sim_VolumeReconstruction.xml"),
    ("fcal12", "fCal_Test_Calibration_3NWires.igs.mha", "PlusDeviceSet_fCal_Sim_SpatialCalibration_1.2.xml",
     "PlusDeviceSet_Server_Sim_NwirePhantom.xml"),
]


def run(cmd):
    print("+", " ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def matrix(text):
    return np.array([float(v) for v in text.split()]).reshape(4, 4)


def transform(root, frm, to):
    for t in root.iter("Transform"):
        if t.get("From") == frm and t.get("To") == to and t.get("Matrix"):
            return matrix(t.get("Matrix"))
        if t.get("From") == to and t.get("To") == frm and t.get("Matrix"):
            return np.linalg.inv(matrix(t.get("Matrix")))
    return None


def with_image_to_probe(src, dst, m):
    tree = ET.parse(src)
    defs = tree.getroot().find("CoordinateDefinitions")
    for t in list(defs):
        if {t.get("From"), t.get("To")} == {"Image", "Probe"}:
            defs.remove(t)
    e = ET.SubElement(defs, "Transform", From="Image", To="Probe")
    e.set("Matrix", " ".join("%.9g" % v for v in m.flatten()))
    tree.write(dst)


def read_mha(path):
    with open(path, "rb") as f:
        data = f.read()
    head, _, body = data.partition(b"ElementDataFile = LOCAL\n")
    h = {}
    for line in head.decode().splitlines():
        k, _, v = line.partition(" = ")
        h[k.strip()] = v.strip()
    dims = [int(v) for v in h["DimSize"].split()]
    if h.get("CompressedData") == "True":
        body = zlib.decompress(body)
    dtype = {"MET_UCHAR": np.uint8, "MET_FLOAT": np.float32, "MET_USHORT": np.uint16}[h["ElementType"]]
    vol = np.frombuffer(body, dtype=dtype)[: dims[0] * dims[1] * dims[2]].reshape(dims[2], dims[1], dims[0])
    origin = np.array([float(v) for v in h["Offset"].split()])
    spacing = np.array([float(v) for v in h["ElementSpacing"].split()])
    return vol.astype(np.float32), origin, spacing


def wires(root, phantom_to_ref):
    out = []
    for pat in root.find("PhantomDefinition").find("Geometry").findall("Pattern"):
        for w in pat.findall("Wire"):
            a = np.array([float(v) for v in w.get("EndPointFront").split()] + [1.0])
            b = np.array([float(v) for v in w.get("EndPointBack").split()] + [1.0])
            out.append((w.get("Name"), (phantom_to_ref @ a)[:3], (phantom_to_ref @ b)[:3]))
    return out


def score(vol, origin, spacing, wire_list):
    """Per wire: offset of the value-weighted centroid from the true line, and the spread about it."""
    zz, yy, xx = np.nonzero(vol > 0)
    vals = vol[zz, yy, xx]
    pts = np.stack([xx, yy, zz], axis=1) * spacing + origin
    rows = []
    for name, a, b in wire_list:
        d = (b - a) / np.linalg.norm(b - a)
        rel = pts - a
        t = rel @ d
        perp = rel - np.outer(t, d)
        dist = np.linalg.norm(perp, axis=1)
        length = np.linalg.norm(b - a)
        sel = (dist < 3.0) & (t > 3.0) & (t < length - 3.0)
        if vals[sel].sum() <= 0:
            rows.append((name, float("nan"), float("nan")))
            continue
        w = vals[sel] ** 2  # the bright core, not the faint halo
        c = (perp[sel] * w[:, None]).sum(0) / w.sum()
        spread = np.sqrt((((perp[sel] - c) ** 2).sum(1) * w).sum() / w.sum())
        rows.append((name, float(np.linalg.norm(c)), float(spread)))
    return rows


def mip(vol, origin, spacing, axis, lo, hi, px=0.25):
    """Maximum intensity projection along world axis `axis` (0 x, 1 y, 2 z) of the world box [lo, hi],
    sampled every `px` mm by nearest voxel: rows along the higher remaining axis, columns the lower."""
    other = [i for i in range(3) if i != axis]
    nx, ny, nz = vol.shape[2], vol.shape[1], vol.shape[0]
    size = [nx, ny, nz]
    # Voxel index ranges of the box along the projection axis.
    a0 = max(int(np.floor((lo[axis] - origin[axis]) / spacing[axis])), 0)
    a1 = min(int(np.ceil((hi[axis] - origin[axis]) / spacing[axis])) + 1, size[axis])
    slab = [slice(None)] * 3
    slab[2 - axis] = slice(a0, max(a1, a0 + 1))
    m = vol[tuple(slab)].max(axis=2 - axis)  # remaining numpy axes: the world axes in descending order
    u = np.arange(lo[other[0]], hi[other[0]], px)
    v = np.arange(lo[other[1]], hi[other[1]], px)
    iu = np.round((u - origin[other[0]]) / spacing[other[0]]).astype(int)
    iv = np.round((v - origin[other[1]]) / spacing[other[1]]).astype(int)
    ok_u = (iu >= 0) & (iu < size[other[0]])
    ok_v = (iv >= 0) & (iv < size[other[1]])
    img = np.zeros((len(v), len(u)), np.float32)
    # m's rows are world axis other[1] (the higher), columns other[0].
    sub = m[np.ix_(iv[ok_v], iu[ok_u])]
    img[np.ix_(np.nonzero(ok_v)[0], np.nonzero(ok_u)[0])] = sub
    return img


def picture(vols, wl, path):
    """Rows: the new calibration, the config's own. Columns: along the wires (every pattern), and
    square to the first pattern's plane (that pattern's N alone)."""
    from PIL import ImageDraw
    d = wl[0][2] - wl[0][1]
    along = int(np.argmax(np.abs(d)))
    n = np.cross(wl[0][2] - wl[0][1], wl[2][1] - wl[0][1])
    square = int(np.argmax(np.abs(n)))
    pts = np.array([p for w in wl for p in (w[1], w[2])])
    lo, hi = pts.min(0) - 4.0, pts.max(0) + 4.0
    first = np.array([p for w in wl[:3] for p in (w[1], w[2])])
    lo1, hi1 = lo.copy(), hi.copy()
    lo1[square], hi1[square] = first[:, square].min() - 2.0, first[:, square].max() + 2.0
    rows = []
    for name in ("pp5echo", "own"):
        tiles = [mip(*vols[name], along, lo, hi), mip(*vols[name], square, lo1, hi1)]
        top = max(t.max() for t in tiles)
        tiles = [np.clip(t / max(top, 1.0) * 255.0, 0, 255).astype(np.uint8) for t in tiles]
        h = max(t.shape[0] for t in tiles)
        tiles = [np.pad(t, ((0, h - t.shape[0]), (0, 0))) for t in tiles]
        rows.append(np.hstack([tiles[0], np.full((h, 6), 255, np.uint8), tiles[1]]))
    w = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, w - r.shape[1]))) for r in rows]
    img = np.vstack([rows[0], np.full((6, w), 255, np.uint8), rows[1]])
    im = Image.fromarray(img).resize((img.shape[1] * 2, img.shape[0] * 2), Image.NEAREST).convert("RGB")
    draw = ImageDraw.Draw(im)
    draw.text((6, 4), "pp5echo calibrate", fill=(255, 220, 0))
    draw.text((6, rows[0].shape[0] * 2 + 16), "the config's own", fill=(255, 220, 0))
    im.save(path)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "calibration"))
    ap.add_argument("--images", default=os.path.join(ROOT, "docs", "images"))
    ap.add_argument("--calibrate-args", default="", help="extra arguments for pp5echo calibrate (one string)")
    a = ap.parse_args()
    exe = os.path.join(a.build, "src", "app", "pp5echo")
    os.makedirs(a.out, exist_ok=True)
    results = {}
    for key, seq, cfg, own in CASES:
        seq_p, cfg_p, own_p = (os.path.join(DATA, x) for x in (seq, cfg, own))
        cal = os.path.join(a.out, key + "_calibrated.xml")
        run([exe, "calibrate", seq_p, "--plus-config", cfg_p, "-o", cal, "--json", os.path.join(a.out, key + ".json"),
             "--compare", own_p] + a.calibrate_args.split())
        root = ET.parse(cfg_p).getroot()
        own_cfg = os.path.join(a.out, key + "_own.xml")
        with_image_to_probe(cfg_p, own_cfg, transform(ET.parse(own_p).getroot(), "Image", "Probe"))
        wl = wires(root, transform(root, "Phantom", "Reference"))
        vols = {}
        for name, c in (("pp5echo", cal), ("own", own_cfg)):
            out = os.path.join(a.out, "%s_%s.mha" % (key, name))
            run([exe, "reconstruct", seq_p, "--plus-config", c, "-o", out])
            vols[name] = read_mha(out)
        res = {name: score(*vols[name], wl) for name in vols}
        results[key] = res
        print("\n%s: per wire, offset of the reconstructed wire from the true one / its spread (mm)" % key)
        print("| wire | new calibration | the config's own |")
        print("|---|---|---|")
        for i, (wname, _, _) in enumerate(wl):
            n, o = res["pp5echo"][i], res["own"][i]
            print("| %s | %.2f / %.2f | %.2f / %.2f |" % (wname, n[1], n[2], o[1], o[2]))
        for name in ("pp5echo", "own"):
            arr = np.array([(r[1], r[2]) for r in res[name]])
            print("%s: mean offset %.2f mm, mean spread %.2f mm" % (name, np.nanmean(arr[:, 0]), np.nanmean(arr[:, 1])))
        picture(vols, wl, os.path.join(a.images, "calibration_%s.png" % key))
    with open(os.path.join(a.out, "figures.json"), "w") as f:
        json.dump(results, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())

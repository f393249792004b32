#!/usr/bin/env python3
"""Measures reconstruction accuracy for docs/quality.md.

1. Ground truth: simulated doll and forearm sweeps at 2, 3 and 5 mm spacing and a
   6-DOF freehand doll sweep; each reconstructed by every method and compared
   with the simulator's truth volume (`pp5echo evaluate truth`).
2. Leave-out (Rohling, Gee & Berman 1999) on the PLUS recordings
   SpinePhantomFreehand and NwirePhantomFreehand, keeping every 2nd and every
   4th frame (`pp5echo evaluate leave-out`).

Usage: scripts/quality.py [--build build] [--out out/quality] [--quick]
Prints markdown tables; the raw JSON lands in the output folder.
"""
import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(os.path.dirname(ROOT), "shared", "data", "plus")

METHODS = {
    "tent + fill-in (1990 paper)": ["recon.method=tent", "recon.fill_in=true"],
    "tent, no fill-in": ["recon.method=tent", "recon.fill_in=false"],
    "nearest + hole filling": ["recon.method=nearest", "recon.fill_holes=true"],
    "nearest": ["recon.method=nearest"],
    "trilinear": ["recon.method=trilinear"],
}


def run(cmd):
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if r.returncode != 0:
        sys.exit("failed: %s\n%s%s" % (" ".join(cmd), r.stdout, r.stderr))
    return r.stdout


def slug(text):
    return "".join(c if c.isalnum() else "_" for c in text).strip("_")


def sets(args):
    out = []
    for a in args:
        out += ["--set", a]
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "quality"))
    ap.add_argument("--quick", action="store_true", help="2 mm doll only (smoke test)")
    a = ap.parse_args()
    exe = os.path.join(a.build, "src", "app", "pp5echo")
    os.makedirs(a.out, exist_ok=True)

    sweeps = []
    for phantom, cfg in (("doll", "doll.toml"), ("forearm", "forearm.toml")):
        for mm in (2, 3, 5):
            sweeps.append(("%s, %d mm" % (phantom, mm), cfg, ["sim.sweep.capture_interval_mm=%d" % mm]))
    sweeps.append(("doll, 6-DOF freehand", "freehand.toml", []))
    if a.quick:
        sweeps = sweeps[:1]

    truth_rows = []
    for label, cfg, extra in sweeps:
        d = os.path.join(a.out, label.replace(", ", "_").replace(" ", "_"))
        run([exe, "simulate", os.path.join(ROOT, "configs", cfg), "-o", d] + sets(extra + ["output.preview_frames=0"]))
        phantom = "doll" if "doll" in label else "forearm"
        seq = os.path.join(d, phantom + "_sweep.igs.mha")
        xml = os.path.join(d, phantom + "_config.xml")
        truth = os.path.join(d, phantom + "_truth.mha")
        row = {"sweep": label}
        for name, opts in METHODS.items():
            js = os.path.join(d, "truth_%s.json" % slug(name))
            run([exe, "evaluate", "truth", seq, "--plus-config", xml, "--truth", truth, "--json", js] + sets(opts))
            row[name] = json.load(open(js))
        truth_rows.append(row)
        print("measured", label, file=sys.stderr)

    print("### Against the ground truth\n")
    print("RMSE in grey levels over covered voxels inside the swept region (lower is better); "
          "holes: fraction of swept voxels left uncovered.\n")
    names = list(METHODS)
    print("| sweep | " + " | ".join(names) + " | tent+fill-in / nearest+holes |")
    print("|---|" + "---|" * (len(names) + 1))
    for row in truth_rows:
        cells = ["%.2f (holes %.3f)" % (row[n]["rmse"], row[n]["hole_fraction"]) for n in names]
        ratio = row[names[0]]["rmse"] / row["nearest + hole filling"]["rmse"]
        print("| %s | %s | %.3f |" % (row["sweep"], " | ".join(cells), ratio))

    if a.quick:
        return
    print("\n### Leave-out on real PLUS recordings\n")
    print("MAE / RMSE in grey levels between held-out pixels and the volume sampled there.\n")
    recs = [
        ("SpinePhantomFreehand", "SpinePhantomFreehand.igs.mha",
         "PlusDeviceSet_VolumeReconstructionOnly_SpinePhantom_NN_MEAN.xml"),
        ("NwirePhantomFreehand", "NwirePhantomFreehand.igs.mha",
         "PlusDeviceSet_NwirePhantomFreehand_vtkVolumeReconstructorTest2.xml"),
    ]
    lo_methods = {
        "tent + fill-in": ["recon.method=tent", "grid.spacing=[0.5,0.5,0.5]", "grid.margin_mm=0",
                           "recon.kernel_lateral_mm=0.5", "recon.kernel_axial_mm=0.5"],
        "nearest + hole filling": ["recon.method=nearest", "recon.fill_holes=true", "grid.spacing=[0.5,0.5,0.5]",
                                   "grid.margin_mm=0"],
        "nearest": ["recon.method=nearest", "grid.spacing=[0.5,0.5,0.5]", "grid.margin_mm=0"],
        "trilinear": ["recon.method=trilinear", "grid.spacing=[0.5,0.5,0.5]", "grid.margin_mm=0"],
    }
    print("| recording | method | keep every 2nd: MAE / RMSE (compared, skipped) | keep every 4th: MAE / RMSE (compared, skipped) |")
    print("|---|---|---|---|")
    for rec, seq, xml in recs:
        for name, opts in lo_methods.items():
            cells = []
            for k in (2, 4):
                js = os.path.join(a.out, "leave_%s_%s_%d.json" % (rec, slug(name), k))
                run([exe, "evaluate", "leave-out", os.path.join(DATA, seq), "--plus-config", os.path.join(DATA, xml),
                     "--keep-every", str(k), "--json", js] + sets(opts))
                j = json.load(open(js))
                cells.append("%.2f / %.2f (%d, %d)" % (j["mae"], j["rmse"], j["pixels_compared"], j["pixels_skipped"]))
            print("| %s | %s | %s |" % (rec, name, " | ".join(cells)))


if __name__ == "__main__":
    main()

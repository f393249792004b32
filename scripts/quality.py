#!/usr/bin/env python3
"""Measures reconstruction accuracy for docs/quality.md.

1. Ground truth: simulated doll and forearm sweeps at 2, 3 and 5 mm spacing and a
   6-DOF freehand doll sweep; each reconstructed by every method and compared
   with the simulator's truth volume (`pp5echo evaluate truth`).
2. Leave-out (Rohling, Gee & Berman 1999) on the PLUS recordings
   SpinePhantomFreehand and NwirePhantomFreehand, keeping every 2nd and every
   4th frame (`pp5echo evaluate leave-out`).

Usage: scripts/quality.py [--build build] [--out out/quality] [--quick | --kernel-grid [doll|forearm]]
                          [--no-leave-out]
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
    "trilinear + hole filling": ["recon.method=trilinear", "recon.fill_holes=true"],
    "trilinear": ["recon.method=trilinear"],
}
PAPER = "tent + fill-in (1990 paper)"
BASELINE = "nearest + hole filling"

# Tent kernels compared on the 2 mm doll sweep (the sweep the default was chosen on).
KERNELS = [(1.0, 0.75, 1.5), (1.5, 0.75, 2.0), (1.5, 1.0, 3.0), (2.0, 1.0, 2.0), (2.0, 1.0, 3.0), (2.0, 0.5, 3.0),
           (3.0, 1.0, 4.0), (3.0, 0.75, 6.0), (3.0, 2.0, 4.0)]

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
    ap.add_argument("--kernel-grid", nargs="?", const="doll", choices=("doll", "forearm"),
                    help="only the search over tent kernels: on the 2 mm doll (48 kernels, about 40 s), or "
                         "on the forearm at 2, 3 and 5 mm (54 kernels, about 2 minutes)")
    ap.add_argument("--no-leave-out", action="store_true", help="only the ground-truth tables (skip the PLUS recordings)")
    a = ap.parse_args()
    exe = os.path.join(a.build, "src", "app", "pp5echo")
    os.makedirs(a.out, exist_ok=True)

    # The "ideal" medium (speckle only) makes the truth volume the expected
    # image, so the errors are the reconstruction's; one physical sweep shows
    # what attenuation, interfaces and shadows add on top.
    ideal = ["sim.bmode.medium=ideal"]
    sweeps = []
    for phantom, cfg in (("doll", "doll.toml"), ("forearm", "forearm.toml")):
        for mm in (2, 3, 5):
            sweeps.append(("%s, %d mm" % (phantom, mm), cfg, ideal + ["sim.sweep.capture_interval_mm=%d" % mm]))
    sweeps.append(("doll, 6-DOF freehand", "freehand.toml", ideal))
    sweeps.append(("doll, 2 mm, physical medium", "doll.toml", []))
    if a.kernel_grid == "forearm":
        sweeps = sweeps[3:6]
    elif a.quick or a.kernel_grid:
        sweeps = sweeps[:1]

    def evaluate(d, cfg, phantom, opts, name, against="expected"):
        seq = os.path.join(d, phantom + "_sweep.igs.mha")
        xml = os.path.join(d, phantom + "_config.xml")
        truth = os.path.join(d, "%s_%s.mha" % (phantom, against))
        js = os.path.join(d, "%s_%s.json" % (against, slug(name)))
        run([exe, "evaluate", "truth", seq, "--plus-config", xml, "--truth", truth, "--json", js,
             "-c", os.path.join(ROOT, "configs", cfg)] + sets(opts))
        return json.load(open(js))

    if a.kernel_grid:
        phantom = a.kernel_grid
        if phantom == "doll":
            grid = [(lat, ax, el) for lat in (2.0, 3.0, 4.0, 5.0) for ax in (0.75, 1.0, 1.25) for el in (3.0, 4.0, 6.0, 8.0)]
        else:
            grid = [(lat, ax, el) for lat in (0.55, 0.8, 1.1) for ax in (0.3, 0.4, 0.6)
                    for el in (1.1, 2.0, 3.0, 4.0, 5.0, 6.0)]
        ratios = {k: [] for k in grid}  # per sweep: (all, tissue)
        for label, cfg, extra in sweeps:
            d = os.path.join(a.out, slug(label))
            run([exe, "simulate", os.path.join(ROOT, "configs", cfg), "-o", d] +
                sets(extra + ["output.preview_frames=0"]))
            base = evaluate(d, cfg, phantom, METHODS[BASELINE], BASELINE)
            for k in grid:
                opts = METHODS[PAPER] + ["recon.kernel_lateral_mm=%g" % k[0], "recon.kernel_axial_mm=%g" % k[1],
                                         "recon.kernel_elevation_mm=%g" % k[2]]
                j = evaluate(d, cfg, phantom, opts, "grid_%g_%g_%g" % k)
                ratios[k].append((j["rmse"] / base["rmse"], j["rmse_tissue"] / base["rmse_tissue"]))
            print("measured", label, file=sys.stderr)
        labels = [s[0] for s in sweeps]
        print("### Tent kernels against nearest + hole filling (RMSE ratio: all / tissue), sorted by the worst\n")
        print("| lateral, axial, elevation (mm) | " + " | ".join(labels) + " |")
        print("|---|" + "---|" * len(labels))
        for k in sorted(grid, key=lambda k: max(r[0] for r in ratios[k])):
            print("| %g, %g, %g | " % k + " | ".join("%.3f / %.3f" % r for r in ratios[k]) + " |")
        return

    truth_rows = []
    kernel_rows = []
    for label, cfg, extra in sweeps:
        d = os.path.join(a.out, slug(label))
        run([exe, "simulate", os.path.join(ROOT, "configs", cfg), "-o", d] + sets(extra + ["output.preview_frames=0"]))
        phantom = "forearm" if "forearm" in label else "doll"
        row = {"sweep": label}
        primary = "truth" if "physical" in label else "expected"
        for name, opts in METHODS.items():
            row[name] = evaluate(d, cfg, phantom, opts, name, primary)
        for name in (PAPER, BASELINE):
            row["echogenicity " + name] = evaluate(d, cfg, phantom, METHODS[name], name, "truth")
        truth_rows.append(row)
        if label == "doll, 2 mm":
            for k in KERNELS:
                opts = METHODS[PAPER] + ["recon.kernel_lateral_mm=%g" % k[0], "recon.kernel_axial_mm=%g" % k[1],
                                         "recon.kernel_elevation_mm=%g" % k[2]]
                kernel_rows.append((k, evaluate(d, cfg, phantom, opts, "kernel_%g_%g_%g" % k)))
        print("measured", label, file=sys.stderr)

    print("### Against the expected image\n")
    print("Each cell: RMSE over the swept voxels that hold a value / RMSE over the tissue among them, in grey "
          "levels (lower is better), and the fraction of swept voxels left without a value. The physical-medium "
          "row has no expected image (attenuation and shadows): it is measured against the echogenicity truth.\n")
    names = list(METHODS)
    print("| sweep | " + " | ".join(names) + " | paper / nearest+holes: all, tissue |")
    print("|---|" + "---|" * (len(names) + 1))
    for row in truth_rows:
        cells = ["%.2f / %.2f (holes %.3f)" % (row[n]["rmse"], row[n]["rmse_tissue"], row[n]["hole_fraction"])
                 for n in names]
        ratio = row[PAPER]["rmse"] / row[BASELINE]["rmse"]
        ratio_t = row[PAPER]["rmse_tissue"] / row[BASELINE]["rmse_tissue"]
        print("| %s | %s | %.3f, %.3f |" % (row["sweep"], " | ".join(cells), ratio, ratio_t))
    print("\n### Where the errors are\n")
    print("RMSE against the expected image over the tissue, the background within %g mm of tissue (*edge*, with "
          "its mean signed error) and the rest of the background (*far*), in grey levels.\n"
          % truth_rows[0][PAPER]["edge_mm"])
    print("| sweep | %s: tissue / edge (bias) / far | %s: tissue / edge (bias) / far |" % (PAPER, BASELINE))
    print("|---|---|---|")
    for row in truth_rows:
        cells = ["%.2f / %.2f (%+.2f) / %.2f" % (row[n]["rmse_tissue"], row[n]["rmse_edge"], row[n]["bias_edge"],
                                                row[n]["rmse_far"]) for n in (PAPER, BASELINE)]
        print("| %s | %s |" % (row["sweep"], " | ".join(cells)))
    print("\n### Against the echogenicity truth (no PSF)\n")
    print("| sweep | %s: all / tissue | %s: all / tissue | ratio: all, tissue |" % (PAPER, BASELINE))
    print("|---|---|---|---|")
    for row in truth_rows:
        p, b = row["echogenicity " + PAPER], row["echogenicity " + BASELINE]
        print("| %s | %.2f / %.2f | %.2f / %.2f | %.3f, %.3f |" % (row["sweep"], p["rmse"], p["rmse_tissue"], b["rmse"],
              b["rmse_tissue"], p["rmse"] / b["rmse"], p["rmse_tissue"] / b["rmse_tissue"]))
    if kernel_rows:
        base = truth_rows[0][BASELINE]
        print("\n### Tent kernel half-widths (doll, 2 mm)\n")
        print("| lateral, axial, elevation (mm) | RMSE all | RMSE tissue | / nearest+holes (all, tissue) |")
        print("|---|---|---|---|")
        for k, j in kernel_rows:
            print("| %g, %g, %g | %.2f | %.2f | %.3f, %.3f |" % (k + (j["rmse"], j["rmse_tissue"], j["rmse"] / base["rmse"],
                                                                   j["rmse_tissue"] / base["rmse_tissue"])))

    if a.quick or a.no_leave_out:
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

#!/usr/bin/env python3
"""Plots of `pp5echo bench`'s bench.csv: throughput, latency, imbalance and the
per-stage CPU time against the layout.

Usage: /usr/bin/python3 scripts/bench_plots.py BENCH_CSV OUT_DIR
Writes OUT_DIR/bench_throughput.png, bench_latency.png, bench_imbalance.png,
bench_stages.png and bench_latency_frames.png (the paced runs' latency frame by
frame, from BENCH_CSV's folder's layouts/<name>/stats.csv). Needs matplotlib (Debian: python3-matplotlib).
"""
import csv
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

SLAB, TILE = "#1f77b4", "#ff7f0e"


def load(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    ok = [r for r in rows if r["status"] == "ok"]
    for r in ok:
        for k, v in r.items():
            if v == "":
                r[k] = math.nan  # e.g. no cost model for a paced run
                continue
            try:
                r[k] = float(v)
            except (TypeError, ValueError):
                pass
    return rows, ok


def colour(r):
    return SLAB if r["gp_partition"] == "slab" else TILE


def label(r):
    return r["layout"].replace("_contig", "").replace("_inter", "_il").replace("_paced30", " @30")


def bars(ax, rows, series, ylabel, title, log=False, hline=None, hlabel=None):
    """Grouped bars, one group per layout (coloured by partitioning), one bar per (column, name, hatch)."""
    width = 0.8 / len(series)
    for i, (col, _, hatch) in enumerate(series):
        for x, r in enumerate(rows):
            ax.bar(x - 0.4 + width * (i + 0.5), r[col], width, color=colour(r), hatch=hatch, edgecolor="black",
                   linewidth=0.4)
    ax.set_xticks(range(len(rows)))
    ax.set_xticklabels([label(r) for r in rows], rotation=60, ha="right", fontsize=8)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    if log:
        ax.set_yscale("log")
    handles = [Patch(color=SLAB, label="slab (object space)"), Patch(color=TILE, label="tile (screen space)")]
    handles += [Patch(facecolor="white", edgecolor="black", hatch=h, label=name) for _, name, h in series]
    if hline is not None:
        ax.axhline(hline, color="red", linestyle="--", linewidth=1)
        if hlabel:
            handles.append(Line2D([], [], color="red", linestyle="--", label=hlabel))
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1.005, 1.0))
    ax.grid(axis="y", alpha=0.3)


def save(fig, out, name, wrote):
    fig.tight_layout()
    p = os.path.join(out, name)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    wrote.append(p)


def main():
    if len(sys.argv) != 3:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    rows, ok = load(sys.argv[1])
    out = sys.argv[2]
    os.makedirs(out, exist_ok=True)
    if not ok:
        print("bench_plots: no successful layout in", sys.argv[1], file=sys.stderr)
        return 1
    wrote = []

    fig, ax = plt.subplots(figsize=(14, 5.5))
    bars(ax, ok, [("frames_per_s_in", "measured frames/s in (every rank on 2 shared cores)", ""),
                  ("model_fps_10gbe", "model, one rank per node, 10 Gb/s: whole run's CPU", "//"),
                  ("steady_fps_10gbe", "model, the same less start-up", ".."),
                  ("incremental_fps_10gbe", "model, GPs' frame updates only (no view change, final pass)", "xx")],
         "frames/s", "Throughput per layout (@30: paced at 30 frames/s; no model)", hline=30,
         hlabel="30 frames/s target")
    save(fig, out, "bench_throughput.png", wrote)

    fig, ax = plt.subplots(figsize=(14, 5.5))
    bars(ax, ok, [("latency_ms_median", "latency median", ""), ("latency_ms_p95", "latency p95", "//")],
         "ms (log scale)", "Frame-to-image latency (unpaced: the source queue is always full; @30: paced)",
         log=True, hline=100, hlabel="100 ms target (p95, paced)")
    save(fig, out, "bench_latency.png", wrote)

    fig, ax = plt.subplots(figsize=(14, 5.5))
    bars(ax, ok, [("reconstruct_imbalance", "reconstruct (wall)", ""), ("shade_imbalance", "shade (wall)", "//"),
                  ("sample_imbalance", "sample (wall)", ".."), ("gp_cpu_imbalance", "GP CPU less start-up", "xx")],
         "busiest GP / mean GP", "Imbalance between the GPs per layout", hline=1.0)
    ax.set_ylim(bottom=0.8)
    save(fig, out, "bench_imbalance.png", wrote)

    # The G sweep (P = 1, contiguous 128 px tiles, unpaced): where the CPU time goes.
    sweep = [r for r in ok if r["pps"] == 1 and r["tile_owner"] == "contiguous" and r["tile_size"] == 128
             and r["pace_fps"] == 0]
    if sweep:
        fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
        stages = [("reconstruct", "o"), ("shade", "s"), ("sample", "^"), ("send", "v")]
        for part, c in (("slab", SLAB), ("tile", TILE)):
            rs = sorted([r for r in sweep if r["gp_partition"] == part], key=lambda r: r["gps"])
            if not rs:
                continue
            g = [r["gps"] for r in rs]
            ls = "-" if part == "slab" else "--"
            for st, m in stages:
                axes[0].plot(g, [r[f"gp_{st}_cpu_ms_sum"] for r in rs], marker=m, color=c, linestyle=ls,
                             label=f"{part}: {st}")
                axes[1].plot(g, [r[f"gp_{st}_cpu_ms_max"] for r in rs], marker=m, color=c, linestyle=ls,
                             label=f"{part}: {st}")
            axes[2].plot(g, [r.get("gp_steady_cpu_ms_max", math.nan) for r in rs], marker="o", color=c, linestyle="-",
                         label=f"{part}: busiest GP")
            axes[2].plot(g, [r.get("gp_steady_cpu_ms_sum", math.nan) for r in rs], marker="s", color=c,
                         linestyle="--", label=f"{part}: all GPs")
            axes[2].plot(g, [r.get("steady_cpu_ms_sum_all", math.nan) for r in rs], marker="^", color=c,
                         linestyle=":", label=f"{part}: all ranks")
        axes[0].set_title("Work by stage: summed over the GPs (estimate)")
        axes[1].set_title("Critical path by stage: the busiest GP (estimate)")
        axes[2].set_title("Each rank's CPU ms per frame, start-up taken off")
        axes[2].axhline(1000 / 30, color="red", linestyle="--", linewidth=1, label="33 ms (30 frames/s)")
        for a in axes:
            a.set_xlabel("graphics processors (1 PP)")
            a.set_xticks(sorted({r["gps"] for r in sweep}))
            a.grid(alpha=0.3)
            a.legend(fontsize=7, ncol=2 if a is not axes[2] else 1)
            a.set_ylim(bottom=0)
        axes[0].set_ylabel("CPU ms per frame (stage estimated from its wall share)")
        save(fig, out, "bench_stages.png", wrote)

    # Latency frame by frame in the paced runs (the host's rows of each run's stats.csv).
    paced = [r for r in ok if r["pace_fps"] > 0]
    if paced:
        fig, ax = plt.subplots(figsize=(12, 4.8))
        styles = ["-", "--", ":", "-."]
        marked = False
        for r in paced:
            path = os.path.join(os.path.dirname(os.path.abspath(sys.argv[1])), "layouts", r["layout"], "stats.csv")
            if not os.path.exists(path):
                continue
            frames, lat, epochs = [], [], []
            with open(path, newline="") as f:
                for row in csv.DictReader(f):
                    if float(row["role"]) == 0 and float(row["latency_ms"]) >= 0:
                        frames.append(float(row["frame"]))
                        lat.append(float(row["latency_ms"]))
                        epochs.append(float(row["epoch"]))
            if not frames:
                continue
            rep = int(r.get("repeat", 1) or 1)
            ax.plot(frames, lat, color=colour(r), linestyle=styles[(rep - 1) % len(styles)], linewidth=1,
                    label=f'{label(r)} ({int(r["drops"])} dropped)')
            change = [f for f, e, e0 in zip(frames[1:], epochs[1:], epochs) if e != e0]
            if change and not marked:
                ax.axvline(change[0], color="grey", linestyle=":", linewidth=1)
                ax.text(change[0], max(lat), " view change", fontsize=8, va="top")
                marked = True
        ax.axhline(100, color="red", linestyle="--", linewidth=1, label="100 ms")
        ax.set_yscale("log")
        ax.set_xlabel("frame (in the order sent; dropped frames are not counted)")
        ax.set_ylabel("latency, ms (log scale)")
        ax.set_title("Paced at 30 frames/s: frame-to-image latency of every frame")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2, loc="lower right")
        save(fig, out, "bench_latency_frames.png", wrote)

    for p in wrote:
        print("bench_plots: wrote", p)
    return 0


if __name__ == "__main__":
    sys.exit(main())

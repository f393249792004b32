#!/usr/bin/env python3
"""Predicted against measured frames/s from `pp5echo bench --cost-model`'s cost_model.csv.

Usage: scripts/cost_model_plot.py DIR/cost_model.csv OUT.png

Fit layouts are hollow, predicted ones filled; TCP layouts are squares. The grey band is the
issue's +-25%.
"""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    rows = [r for r in csv.DictReader(open(sys.argv[1])) if r["measured_fps_median"]]
    if not rows:
        sys.exit(f"cost_model_plot: no measured layout in {sys.argv[1]}")
    top = 1.1 * max(max(float(r["measured_fps_median"]), float(r["predicted_fps"])) for r in rows)
    fig, ax = plt.subplots(figsize=(6.5, 6))
    ax.fill_between([0, top], [0, 0.75 * top], [0, 1.25 * top], color="0.9", label="within 25%")
    ax.plot([0, top], [0, top], color="0.5", lw=1)
    for r in rows:
        tcp = r["layout"].endswith("_tcp")
        slab = "_slab_" in r["layout"]
        fit = r["set"] == "fit"
        colour = "tab:blue" if slab else "tab:orange"
        ax.scatter(float(r["measured_fps_median"]), float(r["predicted_fps"]), s=55, marker="s" if tcp else "o",
                   facecolors="none" if fit else colour, edgecolors=colour, linewidths=1.5)
        if not fit:
            ax.annotate(r["layout"].replace("_contig", "").replace("_t128", ""),
                        (float(r["measured_fps_median"]), float(r["predicted_fps"])), fontsize=6,
                        xytext=(4, -3), textcoords="offset points")
    for label, kw in [("slab", dict(color="tab:blue")), ("tile", dict(color="tab:orange"))]:
        ax.scatter([], [], marker="o", **kw, label=label)
    ax.scatter([], [], marker="o", facecolors="none", edgecolors="k", label="fitted on")
    ax.scatter([], [], marker="o", color="k", label="predicted, then run")
    ax.scatter([], [], marker="s", facecolors="none", edgecolors="k", label="over TCP")
    ax.set_xlim(0, top)
    ax.set_ylim(0, top)
    ax.set_xlabel("measured frames/s (median of runs)")
    ax.set_ylabel("predicted frames/s")
    ax.set_title("Cost model: predicted against measured, 2-core machine")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(sys.argv[2], dpi=120)
    print(f"cost_model_plot: wrote {sys.argv[2]}")


if __name__ == "__main__":
    main()

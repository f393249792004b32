#!/usr/bin/env python3
"""Plots figures of the results log (docs/results.csv) against their date.

Each row of the log is one measurement: date, commit, machine, command, figure, value, unit.
This draws one panel per figure: every row as a point (rows of one date spread around it in
the order the log lists them), and a line through each date's median. Rows measured on a
machine the log describes as other than the usual one (a busy core, a slower machine) are drawn
as open circles.

Needs python3-matplotlib (Debian's, so /usr/bin/python3 where another python3 comes first on PATH).

Usage:
  scripts/results_plot.py                       # the default figures, into docs/images/results_trend.png
  scripts/results_plot.py --figure 'BM_PipelineViewChange' --figure 'main job latency p95' -o out.png
  scripts/results_plot.py --list                # every figure name with its row count
"""
import argparse
import collections
import csv
import datetime
import os
import statistics
import sys

DEFAULT_FIGURES = [
    "BM_PipelineIncremental",
    "main job latency p95",
    "viewer drag views/s",
    "test.sh from a fresh clone",
]
USUAL_MACHINE = "2-core dev VM, 24 GB"


def read_log(path):
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    expected = ["date", "commit", "machine", "command", "figure", "value", "unit"]
    if not rows or list(rows[0].keys()) != expected:
        sys.exit(f"{path}: expected the columns {','.join(expected)}")
    for i, row in enumerate(rows, start=2):
        try:
            row["date"] = datetime.date.fromisoformat(row["date"])
            row["value"] = float(row["value"])
        except ValueError as e:
            sys.exit(f"{path}:{i}: {e}")
    return rows


def spread(rows):
    """x positions: each date's rows spread over 0.8 of a day centred on the date, in log order."""
    by_date = collections.defaultdict(list)
    for row in rows:
        by_date[row["date"]].append(row)
    xs = []
    for date, day in sorted(by_date.items()):
        start = datetime.datetime.combine(date, datetime.time()) - datetime.timedelta(hours=0.4 * 24)
        for i, row in enumerate(day):
            xs.append((start + datetime.timedelta(hours=0.8 * 24 * (i + 0.5) / len(day)), row))
    return xs, by_date


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--csv", default="docs/results.csv", help="the results log (default: docs/results.csv)")
    ap.add_argument("--figure", action="append", help="a figure name as the log spells it (repeatable)")
    ap.add_argument("-o", "--out", default="docs/images/results_trend.png", help="the PNG to write")
    ap.add_argument("--list", action="store_true", help="list the figure names and their row counts")
    a = ap.parse_args()

    rows = read_log(a.csv)
    if a.list:
        counts = collections.Counter(r["figure"] for r in rows)
        for name, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])):
            print(f"{n:4d}  {name}")
        return
    figures = a.figure or DEFAULT_FIGURES
    missing = [f for f in figures if not any(r["figure"] == f for r in rows)]
    if missing:
        sys.exit(f"no rows for {', '.join(repr(m) for m in missing)} in {a.csv} (--list shows the names)")

    try:
        import matplotlib
    except ImportError:
        sys.exit("results_plot.py: needs matplotlib (Debian: python3-matplotlib, with /usr/bin/python3)")
    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(figures), 1, figsize=(9, 2.6 * len(figures)), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], figures):
        sel = [r for r in rows if r["figure"] == name]
        units = sorted({r["unit"] for r in sel})
        xs, by_date = spread(sel)
        usual = [(x, r["value"]) for x, r in xs if r["machine"] == USUAL_MACHINE]
        other = [(x, r["value"]) for x, r in xs if r["machine"] != USUAL_MACHINE]
        if usual:
            ax.plot(*zip(*usual), "o", ms=4, color="tab:blue", alpha=0.6, label="a measurement")
        if other:
            ax.plot(*zip(*other), "o", ms=5, mfc="none", color="tab:red", label="another machine or load")
        med = [(datetime.datetime.combine(d, datetime.time()), statistics.median(r["value"] for r in day))
               for d, day in sorted(by_date.items())]
        ax.plot(*zip(*med), "-", color="black", lw=1.2, label="median of the day")
        ax.set_title(f"{name} ({len(sel)} rows)", fontsize=10, loc="left")
        ax.set_ylabel(" / ".join(units))
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    ax = axes[-1, 0]
    ax.xaxis.set_major_locator(mdates.DayLocator())
    ax.xaxis.set_major_formatter(mdates.DateFormatter("%Y-%m-%d"))
    fig.autofmt_xdate()
    fig.suptitle(f"{os.path.basename(a.csv)}: value against date", fontsize=11)
    fig.tight_layout()
    os.makedirs(os.path.dirname(a.out) or ".", exist_ok=True)
    fig.savefig(a.out, dpi=110)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()

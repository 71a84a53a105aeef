#!/usr/bin/python3
"""Draws what `tofu estimate` produced: the estimated paths against ground truth (top view,
after the alignment named in estimate_<method>.json) and each method's position and
rotation error over time, from the estimate_<method>_errors.csv files of a directory.

usage: scripts/plot_estimate.py DIR [--out FILE.png] [--title TEXT]
"""
import argparse
import glob
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory")
    parser.add_argument("--out", help="PNG to write (default: DIR/estimate.png)")
    parser.add_argument("--title", default=None)
    args = parser.parse_args()
    files = sorted(glob.glob(os.path.join(args.directory, "estimate_*_errors.csv")))
    if not files:
        sys.exit(f"plot_estimate: no estimate_*_errors.csv in {args.directory} "
                 "(run `tofu estimate` on a log with ground truth first)")
    fig = plt.figure(figsize=(11, 7.5))
    path_ax = fig.add_subplot(1, 2, 1)
    pos_ax = fig.add_subplot(2, 2, 2)
    rot_ax = fig.add_subplot(2, 2, 4, sharex=pos_ax)
    truth_drawn = False
    for f in files:
        stem = os.path.basename(f)[len("estimate_"):-len("_errors.csv")]
        summary_file = os.path.join(args.directory, f"estimate_{stem}.json")
        label = stem
        if os.path.exists(summary_file):
            with open(summary_file) as s:
                summary = json.load(s)
            label = summary.get("method", stem)
            if "ate" in summary:
                label += f"  (ATE {100 * summary['ate']['position_rmse_m']:.1f} cm)"
        d = np.loadtxt(f, delimiter=",", comments="#", ndmin=2)
        if d.shape[0] == 0:
            continue
        t = (d[:, 0] - d[0, 0]) * 1e-9
        if not truth_drawn:
            path_ax.plot(d[:, 6], d[:, 7], color="k", lw=2.0, alpha=0.35, label="ground truth")
            truth_drawn = True
        path_ax.plot(d[:, 3], d[:, 4], lw=1.0, label=label)
        pos_ax.plot(t, 100 * d[:, 1], lw=0.9, label=label)
        rot_ax.plot(t, d[:, 2], lw=0.9, label=label)
    path_ax.set_aspect("equal", adjustable="datalim")
    path_ax.set_xlabel("x [m]")
    path_ax.set_ylabel("y [m]")
    path_ax.set_title("top view (estimate aligned to ground truth)")
    path_ax.legend(fontsize=8, loc="best")
    pos_ax.set_ylabel("position error [cm]")
    pos_ax.grid(alpha=0.3)
    rot_ax.set_ylabel("rotation error [deg]")
    rot_ax.set_xlabel("time since the first estimate [s]")
    rot_ax.grid(alpha=0.3)
    fig.suptitle(args.title or f"tofu estimate: {os.path.abspath(args.directory)}", fontsize=10)
    fig.tight_layout()
    out = args.out or os.path.join(args.directory, "estimate.png")
    fig.savefig(out, dpi=110)
    print(out)


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""Plot a tofu run directory: flown path against the reference (top and side views),
position and attitude tracking error over time, collisions marked.

    scripts/plot_run.py RUN_DIR [--out FILE.png]

Reads groundtruth.csv, tracking.csv and summary.json (DESIGN.md run-directory layout).
"""
import argparse
import json
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def load_csv(path):
    return np.loadtxt(path, delimiter=",", comments="#", ndmin=2)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=pathlib.Path)
    parser.add_argument("--out", type=pathlib.Path, help="PNG file (default RUN_DIR/tracking.png)")
    args = parser.parse_args()
    run = args.run_dir
    for name in ("groundtruth.csv", "tracking.csv", "summary.json"):
        if not (run / name).is_file():
            print(f"plot_run: {run / name} not found (is {run} a tofu run directory?)",
                  file=sys.stderr)
            return 2
    truth = load_csv(run / "groundtruth.csv")
    tracking = load_csv(run / "tracking.csv")
    summary = json.loads((run / "summary.json").read_text())
    t = truth[:, 0] * 1e-9

    fig = plt.figure(figsize=(12, 6.5), constrained_layout=True)
    grid = fig.add_gridspec(2, 2, width_ratios=[1.0, 1.3])
    top = fig.add_subplot(grid[0, 0])
    side = fig.add_subplot(grid[1, 0])
    pos_err = fig.add_subplot(grid[0, 1])
    att_err = fig.add_subplot(grid[1, 1], sharex=pos_err)

    top.plot(tracking[:, 1], tracking[:, 2], "--", color="0.55", lw=1.2, label="reference")
    top.plot(truth[:, 1], truth[:, 2], color="tab:blue", lw=1.4, label="flown (ground truth)")
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.set_aspect("equal", adjustable="datalim")
    top.set_title("top view")
    top.legend(loc="best", fontsize=8)
    side.plot(tracking[:, 1], tracking[:, 3], "--", color="0.55", lw=1.2)
    side.plot(truth[:, 1], truth[:, 3], color="tab:blue", lw=1.4)
    side.set_xlabel("x [m]")
    side.set_ylabel("z [m]")
    side.set_title("side view")

    pos_err.plot(tracking[:, 0] * 1e-9, tracking[:, 11] * 100.0, color="tab:red", lw=1.0)
    pos_err.set_ylabel("position error [cm]")
    rmse = summary["metrics"].get("tracking.position_rmse_m")
    pos_err.set_title(f"position error (RMSE {rmse * 100:.2f} cm)" if rmse is not None
                      else "position error")
    att_err.plot(tracking[:, 0] * 1e-9, tracking[:, 12], color="tab:purple", lw=1.0)
    att_err.set_ylabel("attitude error [deg]")
    att_err.set_xlabel("time [s]")
    for collision in summary.get("collisions", []):
        for ax in (pos_err, att_err):
            ax.axvline(collision["start_s"], color="k", ls=":", lw=1)
        pos_err.annotate(f"collision: {collision['robot_geom']} / {collision['structure_geom']}",
                         (collision["start_s"], pos_err.get_ylim()[1]), fontsize=8,
                         va="top", rotation=90)
    for ax in (pos_err, att_err, top, side):
        ax.grid(alpha=0.3)
    verdict = "PASSED" if summary.get("passed") else "FAILED"
    fig.suptitle(f"tofu run {summary['scenario']} (world {summary['world']}, seed "
                 f"{summary['seed']}): {verdict}",
                 color="tab:green" if summary.get("passed") else "tab:red")
    out = args.out or (run / "tracking.png")
    fig.savefig(out, dpi=110)
    print(f"plot_run: wrote {out} ({t[-1]:.1f} s of flight)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

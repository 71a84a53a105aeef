#!/usr/bin/python3
"""The seed paper's metric-evaluation figure (Lanegger et al., Fig. 3) from a tofu run:
top, the angle between the true and the estimated reference frame of a position sensor;
bottom, the consistency metrics of one sensor pair over time, with the phases of its
scheduled faults shaded (misaligned/unobservable, healthy, noisy, diverging). Prints the
numbers of docs/RESULTS.md: each metric's median per phase, how well it separates them,
and its response delay after the divergence onset.

    scripts/plot_consistency.py RUN_DIR [--pair leica-vio] [--sensor leica] [--out FILE.png]
"""
import argparse
import collections
import csv
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

METRIC_LABELS = {"cm": "Cramér-von Mises", "mae": "MAE", "pcc": "PCC", "kl": "KL divergence"}
PHASE_COLOURS = {"healthy": "#c8e6c9", "noisy": "#fff59d", "diverging": "#ef9a9a"}


def read_rows(path):
    with open(path, newline="") as f:
        reader = csv.reader(f)
        next(reader)
        return list(reader)


def fault_windows(labels_path, sensor):
    """{kind: [start_s, end_s]} of the sensor's scheduled faults (end inf if open)."""
    windows = {}
    for row in read_rows(labels_path):
        t_s, who, label, source, active = float(row[0]) * 1e-9, row[1], row[2], row[3], row[4]
        if who != sensor or source != "fault":
            continue
        if active == "1":
            windows[label] = [t_s, float("inf")]
        elif label in windows:
            windows[label][1] = t_s
    return windows


def phases(windows, alignment, run_end_s):
    """Healthy starts once the frame alignment is observable (all rotation DoFs)."""
    observable = [t for t, _, dofs in alignment if dofs == 3]
    healthy_from = observable[0] if observable else 0.0
    noisy = windows.get("non_gaussian_noise", [run_end_s, run_end_s])
    diverging = windows.get("divergence", [run_end_s, run_end_s])
    return collections.OrderedDict([
        ("healthy", (healthy_from, min(noisy[0], diverging[0]))),
        ("noisy", (noisy[0], min(noisy[1], diverging[0]))),
        ("diverging", (diverging[0], min(diverging[1], run_end_s))),
    ])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=pathlib.Path)
    parser.add_argument("--pair", default="leica-vio")
    parser.add_argument("--sensor", default="leica")
    parser.add_argument("--out", type=pathlib.Path)
    args = parser.parse_args()
    run = args.run_dir
    for name in ("consistency.csv", "alignment.csv", "labels.csv"):
        if not (run / name).is_file():
            print(f"plot_consistency: {run / name} not found (does the scenario have a "
                  f"'consistency:' section and sensors?)", file=sys.stderr)
            return 2

    series = collections.defaultdict(lambda: ([], []))
    for t_ns, pair, metric, value in read_rows(run / "consistency.csv"):
        if pair != args.pair or value == "":
            continue
        series[metric][0].append(int(t_ns) * 1e-9)
        series[metric][1].append(float(value))
    if not series:
        print(f"plot_consistency: no values for pair {args.pair}", file=sys.stderr)
        return 2
    alignment = [(int(r[0]) * 1e-9, float(r[2]), int(r[3]))
                 for r in read_rows(run / "alignment.csv") if r[1] == args.sensor]
    run_end_s = max(max(t) for t, _ in series.values())
    windows = fault_windows(run / "labels.csv", args.sensor)
    phase = phases(windows, alignment, run_end_s)

    metrics = [m for m in ("cm", "mae", "pcc", "kl") if m in series]
    fig, axes = plt.subplots(1 + len(metrics), 1, figsize=(11, 2.0 + 1.6 * len(metrics)),
                             sharex=True, constrained_layout=True)
    for ax in axes:
        for name, (begin, end) in phase.items():
            if end > begin:
                ax.axvspan(begin, end, color=PHASE_COLOURS[name], alpha=0.6, lw=0)
        ax.grid(alpha=0.3)
    if alignment:
        axes[0].plot([a[0] for a in alignment], [a[1] for a in alignment], color="k", lw=1.2)
    axes[0].set_ylabel("frame error [deg]")
    axes[0].set_yscale("symlog", linthresh=1.0)
    axes[0].set_title(f"{args.sensor}: true vs closed-form estimated reference frame "
                      f"(white: vertical motion only, yaw unobservable)")
    for ax, metric in zip(axes[1:], metrics):
        t, v = series[metric]
        ax.plot(t, v, lw=0.9, color="tab:blue")
        ax.set_ylabel(METRIC_LABELS[metric], fontsize=9)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(f"Consistency of {args.pair} (paper Fig. 3): green healthy, yellow "
                 f"non-Gaussian noise, red divergence")
    out = args.out or (run / "consistency.png")
    fig.savefig(out, dpi=110)

    # Numbers: per-phase medians, separation ratios, divergence response delay.
    print(f"| metric | median healthy | median noisy | median diverging | noisy/healthy | "
          f"diverging/noisy | response delay [s] |")
    print("|---|---|---|---|---|---|---|")
    onset = phase["diverging"][0]
    for metric in metrics:
        t, v = (np.array(x) for x in series[metric])
        med = {}
        for name, (begin, end) in phase.items():
            sel = (t >= begin) & (t < end)
            med[name] = float(np.median(v[sel])) if sel.any() else float("nan")
        # Delay: first time after the onset the metric leaves the band it held in the 20 s
        # before it (beyond the previous phase's 1st..99th percentile), for good (3 in a row).
        before = v[(t >= onset - 20.0) & (t < onset)]
        lo, hi = (np.percentile(before, 1), np.percentile(before, 99)) if before.size else (0, 0)
        outside = (t >= onset) & ((v > hi) | (v < lo))
        delay = float("nan")
        idx = np.flatnonzero(outside)
        for k in idx:
            if k + 2 < len(v) and outside[k + 1] and outside[k + 2]:
                delay = t[k] - onset
                break
        print(f"| {metric} | {med['healthy']:.3g} | {med['noisy']:.3g} | {med['diverging']:.3g} "
              f"| {med['noisy'] / med['healthy']:.2f} | {med['diverging'] / med['noisy']:.2f} "
              f"| {delay:.1f} |")
    print(f"plot_consistency: wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

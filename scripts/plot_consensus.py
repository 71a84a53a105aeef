#!/usr/bin/python3
"""Plot how the estimator methods of a tofu run handled corrupted sensors (the seed
paper's Fig. "abs_errs", Lanegger et al.): on one time axis,
 (a) which corruption each sensor suffers when (labels.csv: green clean, white dropout,
     yellow non-Gaussian noise or outliers, red divergence, grey other faults; the
     scene's conditions such as occluded or no_fix hatched),
 (b) the position error and (c) the rotation error of every method (errors.csv),
 (d) the FUSED line: the sensors each consensus method fuses, excludes or lacks, when
     (decisions.csv),
 (e) the consistency values each consensus method computed (consistency_<method>.csv),
     with its threshold dashed (summary.json methods.<method>.threshold, else 0.1).

    scripts/plot_consensus.py RUN_DIR [--out FILE.png] [--when-ready]
                                                      (default RUN_DIR/consensus.png)

Missing files and methods are left out of the plot (exit 0); a malformed CSV is an error
naming the file and line (exit 2).
"""
import argparse
import collections
import json
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.patches as mpatches  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tofu_csv import (CsvError, any_text, flag, name, number,  # noqa: E402
                      optional_number, read_csv, timestamp)

DEFAULT_THRESHOLD = 0.1  # the seed paper's CM threshold [m/s]
CLEAN = "#a5d6a7"
FAULT_COLOURS = {
    "dropout": "white",
    "non_gaussian_noise": "#fff176",
    "outliers": "#fff176",
    "divergence": "#e57373",
}
OTHER_FAULT = "#9e9e9e"
# Drawn in this order, so that what hides the sensor completely (dropout) ends on top.
FAULT_ORDER = ["other", "non_gaussian_noise", "outliers", "divergence", "dropout"]
SENSOR_COLOURS = ["tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:cyan", "tab:olive",
                  "tab:pink"]


def sensor_set(text):
    """'+'-joined sensor names or nothing"""
    parts = [p for p in text.split("+")] if text else []
    if any(not p.strip() for p in parts):
        raise ValueError(text)
    return tuple(parts)


def intervals(events, end_s):
    """[(start, end)] from (t, active) transitions; an interval still open ends at end_s."""
    out, start = [], None
    for t, active in sorted(events):
        if active and start is None:
            start = t
        elif not active and start is not None:
            out.append((start, t))
            start = None
    if start is not None:
        out.append((start, end_s))
    return [(a, b) for a, b in out if b > a]


def steps(times_states, end_s):
    """{state: [(start, end)]} from a step signal given as sorted (t, states) samples; the
    samples of one stretch in one interval (a rectangle per stretch, not per sample: the
    hatched ones cost Agg a pattern fill each)."""
    out = collections.defaultdict(list)
    for k, (t, states) in enumerate(times_states):
        t_next = times_states[k + 1][0] if k + 1 < len(times_states) else end_s
        for s in states:
            if out[s] and out[s][-1][1] == t:
                out[s][-1] = (out[s][-1][0], t_next)
            else:
                out[s].append((t, t_next))
    return out


def method_order(methods):
    """consensus methods first, then naive, then the single-sensor baselines."""
    def key(m):
        rank = 0 if m.startswith("consensus") else 1 if m.startswith("naive") else 2
        return (rank, m)
    return sorted(methods, key=key)


def method_style(method, index):
    if method.startswith("consensus"):
        colour = "black" if method == "consensus" else plt.cm.Greys(0.5 + 0.1 * (index % 4))
    elif method.startswith("naive"):
        colour = "tab:orange"
    else:
        colour = SENSOR_COLOURS[index % len(SENSOR_COLOURS)]
    # The un-faulted baselines (single:vio@clean) dashed, like the paper's blue reference.
    return {"color": colour, "ls": "--" if method.endswith("@clean") else "-", "lw": 1.1}


def spans(ax, y, height, pieces, **style):
    widths = [(a, b - a) for a, b in pieces]
    if widths:
        ax.broken_barh(widths, (y - height / 2, height), **style)


def no_data(ax, text):
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", color="0.5",
            fontsize=9)


def fit_margins(fig, axes, named_axes):
    """Margins that hold what sticks out of the axes: the sensor and method names left of
    the categorical panels (named_axes), the legends right of the axes. Measured from
    those texts alone: constrained_layout measures every axis's ticks for its tight boxes,
    a third of this script's time, and the log axes' tick labels are short."""
    renderer = fig.canvas.get_renderer()
    width_px = fig.get_figwidth() * fig.dpi
    tick_labels_px = [t.get_window_extent(renderer).width
                      for ax in named_axes for t in ax.get_yticklabels() if t.get_text()]
    # Room for a log axis's "10^-2" labels and the axis label beside them, at the least.
    left_px = max([45.0] + tick_labels_px) + 40.0
    legends_px = [ax.get_legend().get_window_extent(renderer).width
                  for ax in axes if ax.get_legend() is not None]
    right_px = max([0.0] + legends_px) + 15.0
    fig.subplots_adjust(left=left_px / width_px, right=1.0 - right_px / width_px,
                        top=0.93, bottom=0.05, hspace=0.32)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=pathlib.Path)
    parser.add_argument("--out", type=pathlib.Path,
                        help="PNG file (default RUN_DIR/consensus.png)")
    parser.add_argument("--when-ready", action="store_true",
                        help="import, then wait for a line 'go' on standard input before "
                             "reading RUN_DIR (tofu starts the script while it writes the "
                             "files); anything else ends the script without drawing, exit 0")
    args = parser.parse_args()
    if args.when_ready and sys.stdin.readline().strip() != "go":
        return 0
    run = args.run_dir
    if not run.is_dir():
        print(f"plot_consensus: {run} is not a directory (expected a tofu run directory)",
              file=sys.stderr)
        return 2

    summary = {}
    if (run / "summary.json").is_file():
        try:
            summary = json.loads((run / "summary.json").read_text())
        except json.JSONDecodeError as e:
            print(f"plot_consensus: {run / 'summary.json'}:{e.lineno}: {e.msg}", file=sys.stderr)
            return 2
        if not isinstance(summary, dict):
            print(f"plot_consensus: {run / 'summary.json'}:1: expected a JSON object",
                  file=sys.stderr)
            return 2
    methods_summary = summary.get("methods") if isinstance(summary.get("methods"), dict) else {}

    try:
        labels = (read_csv(run / "labels.csv", ["timestamp", "sensor", "label", "source", "active"],
                           [timestamp, name, name, name, flag])
                  if (run / "labels.csv").is_file() else [])
        errors = (read_csv(run / "errors.csv",
                           ["timestamp", "method", "position_error", "rotation_error", "valid",
                            "nees"],
                           [timestamp, name, optional_number, optional_number, flag,
                            optional_number])
                  if (run / "errors.csv").is_file() else [])
        decisions = (read_csv(run / "decisions.csv",
                              ["timestamp", "method", "fused", "excluded", "unavailable",
                               "reason"],
                              [timestamp, name, sensor_set, sensor_set, sensor_set, any_text])
                     if (run / "decisions.csv").is_file() else [])
        consistency = {}
        for path in sorted(run.glob("consistency_*.csv")):
            method = path.stem[len("consistency_"):]
            consistency[method] = read_csv(path, ["timestamp", "pair", "metric", "value"],
                                           [timestamp, name, name, optional_number])
    except CsvError as e:
        print(f"plot_consensus: {e}", file=sys.stderr)
        return 2

    # One time axis for all panels: to the end of the run, else of the latest sample.
    stamps = [r[0] for rows in [labels, errors, decisions, *consistency.values()] for r in rows]
    end_s = max([float(summary.get("simulated_s") or 0.0)] + stamps + [1e-9])

    fig, axes = plt.subplots(
        5, 1, figsize=(12, 11), sharex=True,
        gridspec_kw={"height_ratios": [1.0, 1.6, 1.6, 1.1, 1.5]})
    timeline, pos_ax, rot_ax, fused_ax, cons_ax = axes

    # (a) corruption timeline per sensor.
    sensors = sorted({r[1] for r in labels}
                     | {s for r in decisions for s in r[2] + r[3] + r[4]}
                     | {s for rows in consistency.values() for r in rows
                        for s in r[1].split("-") if s and s != "local"})
    faults = collections.defaultdict(list)      # (sensor, kind) -> [(t, active)]
    conditions = collections.defaultdict(list)  # (sensor, label) -> [(t, active)]
    for t, sensor, label, source, active in labels:
        if source == "fault":
            faults[(sensor, label if label in FAULT_COLOURS else "other")].append((t, active))
        else:
            conditions[(sensor, label)].append((t, active))
    for y, sensor in enumerate(sensors):
        spans(timeline, y, 0.8, [(0.0, end_s)], facecolors=CLEAN, edgecolor="none")
        for kind in FAULT_ORDER:
            colour = FAULT_COLOURS.get(kind, OTHER_FAULT)
            spans(timeline, y, 0.8, intervals(faults.get((sensor, kind), []), end_s),
                  facecolors=colour, edgecolor="0.4" if kind == "dropout" else "none", lw=0.5)
        for (who, _), events in sorted(conditions.items()):
            if who == sensor:
                spans(timeline, y - 0.2, 0.4, intervals(events, end_s), facecolors="none",
                      edgecolor="0.45", hatch="////", lw=0.0)
    timeline.set_yticks(range(len(sensors)), sensors)
    timeline.set_ylim(-0.6, max(len(sensors), 1) - 0.4)
    timeline.invert_yaxis()
    timeline.set_title("sensor corruption")
    timeline.legend(handles=[
        mpatches.Patch(facecolor=CLEAN, label="clean"),
        mpatches.Patch(facecolor="white", edgecolor="0.4", label="dropout"),
        mpatches.Patch(facecolor=FAULT_COLOURS["non_gaussian_noise"],
                       label="non-Gaussian noise / outliers"),
        mpatches.Patch(facecolor=FAULT_COLOURS["divergence"], label="divergence"),
        mpatches.Patch(facecolor=OTHER_FAULT, label="other fault"),
        mpatches.Patch(facecolor="none", edgecolor="0.45", hatch="////",
                       label="condition (occluded, no fix, ...)"),
    ], loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    if not sensors:
        no_data(timeline, "no labels.csv")

    # (b), (c) errors per method; invalid samples are gaps.
    per_method = collections.defaultdict(list)
    for t, method, pos, rot, valid, _ in errors:
        per_method[method].append((t, pos if valid else np.nan, rot if valid else np.nan))
    for index, method in enumerate(method_order(per_method)):
        data = np.array(per_method[method])
        style = method_style(method, index)
        pos_ax.plot(data[:, 0], data[:, 1], label=method, **style)
        rot_ax.plot(data[:, 0], data[:, 2], label=method, **style)
    # Log scale: a diverged baseline (metres) and consensus (centimetres) on one axis.
    if per_method:
        pos_ax.set_yscale("log")
        rot_ax.set_yscale("log")
    pos_ax.set_ylabel("position error [m]")
    rot_ax.set_ylabel("rotation error [deg]")
    pos_ax.set_title("estimation error per method")
    if per_method:
        pos_ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    else:
        no_data(pos_ax, "no errors.csv")
        no_data(rot_ax, "no errors.csv")

    # (d) FUSED line: per consensus method, one row per sensor: fused (solid, the sensor's
    # colour), excluded (red edge), unavailable (light grey).
    by_method = collections.defaultdict(list)
    for t, method, fused, excluded, unavailable, _ in decisions:
        by_method[method].append((t, fused, excluded, unavailable))
    colour_of = {s: SENSOR_COLOURS[k % len(SENSOR_COLOURS)] for k, s in enumerate(sensors)}
    rows = []
    for method in method_order(by_method):
        samples = sorted(by_method[method], key=lambda r: r[0])
        fused = steps([(t, f) for t, f, _, _ in samples], end_s)
        excluded = steps([(t, e) for t, _, e, _ in samples], end_s)
        unavailable = steps([(t, u) for t, _, _, u in samples], end_s)
        for sensor in sorted(set(fused) | set(excluded) | set(unavailable)):
            y = len(rows)
            rows.append(f"{method}: {sensor}" if len(by_method) > 1 else sensor)
            spans(fused_ax, y, 0.7, unavailable.get(sensor, []), facecolors="0.9",
                  edgecolor="none")
            spans(fused_ax, y, 0.7, excluded.get(sensor, []), facecolors="none",
                  edgecolor="tab:red", hatch="xx", lw=0.0)
            spans(fused_ax, y, 0.7, fused.get(sensor, []),
                  facecolors=colour_of.get(sensor, "tab:gray"), edgecolor="none")
    fused_ax.set_yticks(range(len(rows)), rows, fontsize=8)
    fused_ax.set_ylim(-0.6, max(len(rows), 1) - 0.4)
    fused_ax.invert_yaxis()
    fused_ax.set_title("FUSED: sensors each consensus method fuses (coloured), excludes "
                       "(red hatch), lacks (grey)")
    if not rows:
        no_data(fused_ax, "no decisions.csv")

    # (e) consistency per pair, threshold dashed.
    metrics_seen = set()
    for index, method in enumerate(method_order(consistency)):
        series = collections.defaultdict(list)
        for t, pair, metric, value in consistency[method]:
            series[(pair, metric)].append((t, value))
            metrics_seen.add(metric)
        for k, ((pair, metric), points) in enumerate(sorted(series.items())):
            data = np.array(sorted(points))
            label = f"{pair} ({metric})"
            if len(consistency) > 1:
                label = f"{method}: {label}"
            cons_ax.plot(data[:, 0], data[:, 1], lw=0.9, label=label,
                         color=SENSOR_COLOURS[(k + index) % len(SENSOR_COLOURS)])
        entry = methods_summary.get(method) if isinstance(methods_summary, dict) else None
        threshold = entry.get("threshold") if isinstance(entry, dict) else None
        if not isinstance(threshold, (int, float)) or isinstance(threshold, bool):
            threshold = DEFAULT_THRESHOLD
        cons_ax.axhline(threshold, color="k" if index == 0 else "0.5", ls="--", lw=1.0,
                        label=f"threshold {method} ({threshold:g})")
    if consistency:
        cons_ax.set_yscale("log")  # the threshold region and a divergence's values together
    ylabels = {"cm": "CM distance (eq. 5) [m/s]", "nis": "normalised squared difference per dof"}
    cons_ax.set_ylabel(" / ".join(ylabels.get(m, m) for m in sorted(metrics_seen)) or "CM distance (eq. 5)")
    cons_ax.set_title("consistency between sensors (and against the local estimate)")
    if consistency:
        cons_ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8, frameon=False)
    else:
        no_data(cons_ax, "no consistency_<method>.csv")

    for ax in axes:
        ax.grid(alpha=0.3)
        ax.set_xlim(0.0, end_s)
    axes[-1].set_xlabel("time [s]")
    title = "tofu run"
    if "scenario" in summary:
        title += f" {summary['scenario']}"
    if "seed" in summary:
        title += f" (seed {summary['seed']})"
    fig.suptitle(f"{title}: corruption, errors, fused sensors and consistency")
    fit_margins(fig, axes, [timeline, fused_ax])
    out = args.out or (run / "consensus.png")
    fig.savefig(out, dpi=100)
    print(f"plot_consensus: wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""Figures of `tofu search`.

  plot_search.py SEARCH_DIR --out PNG
      one search: every flight's margin and the best so far over the search's simulations,
      the confirmed failures marked where they were found.
  plot_search.py --benchmark DIR --out PNG
      repeated searches (DIR/<problem>/<optimizer>_<rep>/search.json, as scripts/results.py
      flies them): per problem, the median best margin so far over the simulations per
      optimiser with its interquartile band, and each trial's first confirmed failure.
"""
import argparse
import json
import math
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

CLIP = 10.0  # what the optimiser is told of a flight without a margin (campaign/search.cc)
COLOURS = {"random": "#7f7f7f", "tpe": "#1f77b4"}


def margins(search):
    """The search flights' margins in order, a flight without one at -CLIP."""
    return [-CLIP if e["margin"] is None else max(-CLIP, min(CLIP, e["margin"])) for e in search["evaluations"]]


def best_so_far(values, length):
    """Running minimum, held after the search stopped (stop_at_first) up to `length`."""
    out = np.minimum.accumulate(np.array(values, dtype=float)) if values else np.array([CLIP])
    if len(out) < length:
        out = np.concatenate([out, np.full(length - len(out), out[-1])])
    return out


def load(path):
    try:
        return json.loads(pathlib.Path(path).read_text())
    except (OSError, ValueError) as e:
        sys.exit(f"plot_search.py: cannot read {path}: {e}")


def plot_one(directory, out):
    search = load(pathlib.Path(directory) / "search.json")
    values = margins(search)
    x = np.arange(1, len(values) + 1)
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.scatter(x, values, s=10, c=["#d62728" if v < 0 else "#7f7f7f" for v in values], label="flight's margin")
    ax.step(x, best_so_far(values, len(values)), where="post", color="#1f77b4", label="best so far")
    ax.axhline(0.0, color="black", lw=0.8)
    for f in search["failures"]:
        if f["confirmed"]:
            ax.axvline(f["first_simulation"], color="#d62728", ls=":", lw=1)
            ax.annotate(f["id"], (f["first_simulation"], ax.get_ylim()[1]), fontsize=8, color="#d62728",
                        ha="left", va="top")
    ax.set_xlabel("search simulation")
    ax.set_ylabel("margin (negative: violated)")
    ax.set_title(f"tofu search {search['spec']} ({search['optimizer']}): {', '.join(search['objective'])}",
                 fontsize=9)
    ax.legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    fig.savefig(out, dpi=120)


def plot_benchmark(directory, out):
    root = pathlib.Path(directory)
    problems = sorted(p for p in root.iterdir() if p.is_dir() and any(p.glob("*/search.json")))
    if not problems:
        sys.exit(f"plot_search.py: no <problem>/<optimizer>_<rep>/search.json under {root}")
    fig, axes = plt.subplots(1, len(problems), figsize=(4.2 * len(problems), 3.6), squeeze=False)
    for ax, problem in zip(axes[0], problems):
        for optimizer in ("random", "tpe"):
            searches = [load(p) for p in sorted(problem.glob(f"{optimizer}_*/search.json"))]
            if not searches:
                continue
            length = max(s["budget"] for s in searches)
            curves = np.array([best_so_far(margins(s), length) for s in searches])
            x = np.arange(1, length + 1)
            colour = COLOURS[optimizer]
            ax.plot(x, np.median(curves, axis=0), color=colour, label=f"{optimizer} (median of {len(searches)})")
            ax.fill_between(x, np.percentile(curves, 25, axis=0), np.percentile(curves, 75, axis=0), color=colour,
                            alpha=0.2, lw=0)
            firsts = [s["simulations_to_first_confirmed"] for s in searches if s["simulations_to_first_confirmed"]]
            ax.plot(firsts, [0.0] * len(firsts), "|", color=colour, ms=14, mew=1.5)
        ax.axhline(0.0, color="black", lw=0.8)
        ax.set_title(problem.name, fontsize=9)
        ax.set_xlabel("search simulations")
        ax.set_xscale("log")
        ax.set_ylim(bottom=max(-2.0, ax.get_ylim()[0]))
    axes[0][0].set_ylabel("best margin so far")
    axes[0][0].legend(fontsize=8, loc="upper right")
    fig.suptitle("tofu search: best margin over simulations (ticks on 0: each trial's first confirmed failure)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=120)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("search", nargs="?", help="a tofu search --out directory")
    parser.add_argument("--benchmark", help="a directory of repeated searches (scripts/results.py)")
    parser.add_argument("--out", required=True, help="PNG to write")
    args = parser.parse_args()
    if bool(args.search) == bool(args.benchmark):
        parser.error("give either SEARCH_DIR or --benchmark DIR")
    if args.benchmark:
        plot_benchmark(args.benchmark, args.out)
    else:
        plot_one(args.search, args.out)


if __name__ == "__main__":
    main()

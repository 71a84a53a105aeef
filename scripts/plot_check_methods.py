#!/usr/bin/python3
"""Plot the estimation methods of a tofu check over its seeds (methods.csv, written by
`tofu check`): one panel per scenario, a bar per method at its median ATE over the seeds
with a whisker up to its worst seed, on a log axis; the ATE over the oracle's (median) is
written above each bar when the scenario has an oracle method.

    scripts/plot_check_methods.py CHECK_DIR|METHODS_CSV [--out FILE.png]
                                                    (default CHECK_DIR/methods.png)

Scenarios and methods are drawn in the order of the CSV (the order of `tofu check`'s
inputs and of each scenario's estimation.methods). A method without an ATE is marked
"no ATE"; a CSV without any ATE still gives a figure (exit 0). A missing or malformed
CSV is an error naming the file (and line) (exit 2).
"""
import argparse
import math
import pathlib
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from tofu_csv import CsvError, name, optional_number, read_csv  # noqa: E402

COLUMNS = ["scenario", "method", "metric", "seeds", "median", "worst"]


def count(text):
    """a whole number >= 0"""
    value = int(text)
    if value < 0:
        raise ValueError(text)
    return value


def colour(method):
    if method == "oracle":
        return "0.55"
    if method.startswith("consensus"):
        return "black" if method == "consensus" else "0.3"
    if method.startswith("naive"):
        return "tab:orange"
    return "tab:blue"


def finite(x):
    return x is not None and math.isfinite(x)


def read(path):
    """{scenario: {method: {metric: (seeds, median, worst)}}} in file order."""
    table = {}
    for scenario, method, metric, seeds, median, worst in read_csv(
            path, COLUMNS, [name, name, name, count, optional_number, optional_number]):
        table.setdefault(scenario, {}).setdefault(method, {})[metric] = (seeds, median, worst)
    return table


def draw_panel(ax, scenario, methods):
    names = list(methods)
    xs = list(range(len(names)))
    lows, highs = [], []
    for x, method in zip(xs, names):
        seeds, median, worst = methods[method].get("ate_m", (0, math.nan, math.nan))
        if seeds == 0 or not finite(median) or median <= 0:
            ax.text(x, 0.02, "no ATE", transform=ax.get_xaxis_transform(), ha="center",
                    va="bottom", fontsize=7, color="0.4", rotation=90)
            continue
        up = worst - median if finite(worst) and worst >= median else 0.0
        ax.bar(x, median, width=0.7, color=colour(method), log=True,
               yerr=[[0.0], [up]], capsize=3, error_kw={"elinewidth": 1.0, "ecolor": "0.2"})
        lows.append(median)
        highs.append(median + up)
        ratio = methods[method].get("ate_over_oracle")
        if ratio and ratio[0] > 0 and finite(ratio[1]) and method != "oracle":
            ax.annotate(f"x{ratio[1]:.3g}", (x, median + up), xytext=(0, 2),
                        textcoords="offset points", ha="center", va="bottom", fontsize=7)
    ax.set_yscale("log")
    if lows:  # room below the lowest bar, and above the highest whisker for its label
        ax.set_ylim(min(lows) / 3, max(highs) * 2.5)
    ax.set_xticks(xs)
    ax.set_xticklabels(names, rotation=30, ha="right", fontsize=8)
    ax.set_xlim(-0.6, len(names) - 0.4)
    seeds = max((m.get("ate_m", (0,))[0] for m in methods.values()), default=0)
    ax.set_title(f"{scenario} ({seeds} seed{'' if seeds == 1 else 's'})", fontsize=10)
    ax.set_ylabel("ATE [m]")
    ax.grid(axis="y", which="both", alpha=0.3)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", type=pathlib.Path, help="check directory or its methods.csv")
    parser.add_argument("--out", type=pathlib.Path,
                        help="PNG file (default CHECK_DIR/methods.png)")
    args = parser.parse_args()
    csv = args.input / "methods.csv" if args.input.is_dir() else args.input
    out = args.out or csv.parent / "methods.png"
    if not csv.is_file():
        print(f"plot_check_methods: no {csv} (expected a tofu check directory or its "
              "methods.csv)", file=sys.stderr)
        return 2
    try:
        table = read(csv)
    except CsvError as e:
        print(f"plot_check_methods: {e}", file=sys.stderr)
        return 2

    panels = max(len(table), 1)
    columns = 1 if panels == 1 else 2
    rows = math.ceil(panels / columns)
    widest = max((len(m) for m in table.values()), default=1)
    fig, axes = plt.subplots(rows, columns, figsize=(columns * max(6.5, 0.65 * widest + 2.0),
                                                      3.6 * rows),
                             squeeze=False, constrained_layout=True)
    flat = [ax for row in axes for ax in row]
    for ax, (scenario, methods) in zip(flat, table.items()):
        draw_panel(ax, scenario, methods)
    for ax in flat[len(table):]:
        ax.axis("off")
    if not table:
        flat[0].text(0.5, 0.5, "no methods in " + str(csv), ha="center", va="center",
                     color="0.5", transform=flat[0].transAxes)
    fig.suptitle("ATE over the seeds: bar median, whisker worst seed\n"
                 "xN: ATE / oracle's ATE in the same seed (median)", fontsize=9)
    # format explicitly: tofu check draws into a staging name (methods.png.tmp-<pid>).
    fig.savefig(out, format="png", dpi=100)
    plt.close(fig)
    return 0


if __name__ == "__main__":
    sys.exit(main())

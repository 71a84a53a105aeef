#!/usr/bin/python3
"""Plot a tofu comparison (`tofu compare ... --json FILE`, or a check's compare.json with
--baseline): what changed, seed by seed, in one figure a reviewer reads at a glance.

    scripts/plot_compare.py COMPARE_JSON|CHECK_DIR --out FIGURE.png [--cells N]

The table of `tofu compare` gives each cell's median effect, interval and verdict; this
shows the seeds behind them, so a regression that every seed shares reads differently from
one carried by a single outlying seed. One panel per cell that is not unchanged (regressed
first, then improved, then inconclusive, each in the file's order; at most --cells, default
6); when every cell is unchanged, the first cells of the ATE metric. A panel is a slope
chart of the per-seed pairs: the base's value on the left, the new's on the right, one line
per seed (a log axis for an error's scale, whose values are positive; no lines between
unpaired seeds, which are points on their own side), with each side's median as a black
tick. Its title holds the verdict, the median effect (new / base, or new - base) and its
bootstrap interval, coloured by the verdict: regressed red, improved green, inconclusive
grey, unchanged blue. Yes/no outcomes (a failure, a missed fault, a collision, an
expectation) are bars of the seeds with the event on each side instead. The header names
the base and the new and counts the verdicts of the whole comparison.

The figure is written to a temporary sibling and renamed into place, without a timestamp
(the same JSON gives the same bytes). A missing, malformed or foreign JSON is an error
naming the file and what is wrong (exit 2).
"""
import argparse
import json
import math
import os
import pathlib
import sys
import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib import ticker  # noqa: E402

VERDICTS = ["regressed", "improved", "inconclusive", "unchanged"]
COLOURS = {"regressed": "#c62828", "improved": "#2e7d32", "inconclusive": "#757575",
           "unchanged": "#1565c0"}
KINDS = ("ratio", "difference", "event")
ATE = "methods.<method>.ate_m"
BASE_COLOUR = "#9e9e9e"


class InputError(Exception):
    pass


# ---- reading ----

def field(obj, key, types, where, allow_none=False):
    if not isinstance(obj, dict) or key not in obj:
        raise InputError(f"{where}: no '{key}'")
    value = obj[key]
    if value is None and allow_none:
        return None
    # bool is an int in Python: a count or a value must not be true/false.
    if isinstance(value, bool) and bool not in types:
        raise InputError(f"{where}: '{key}' is {json.dumps(value)}, "
                         f"expected {types_text(types)}")
    if not isinstance(value, types):
        raise InputError(f"{where}: '{key}' is {json.dumps(value)[:60]}, "
                         f"expected {types_text(types)}")
    return value


def types_text(types):
    names = {str: "a string", int: "a number", float: "a number", list: "a list",
             dict: "an object", bool: "true or false"}
    return " or ".join(dict.fromkeys(names[t] for t in types))


NUMBER = (int, float)


def finite(value):
    """A value to draw, or None (no value; json reads NaN and Infinity too)."""
    return float(value) if value is not None and math.isfinite(value) else None


def read_cell(c, i):
    where = f"cells[{i}]"
    if not isinstance(c, dict):
        raise InputError(f"{where}: expected an object")
    cell = {key: field(c, key, (str,), where) for key in
            ("scenario", "metric", "subject", "unit", "pairing", "note")}
    cell["kind"] = field(c, "kind", (str,), where)
    if cell["kind"] not in KINDS:
        raise InputError(f"{where}: 'kind' is \"{cell['kind']}\", expected one of "
                         f"{', '.join(KINDS)}")
    cell["verdict"] = field(c, "verdict", (str,), where)
    if cell["verdict"] not in VERDICTS:
        raise InputError(f"{where}: 'verdict' is \"{cell['verdict']}\", expected one of "
                         f"{', '.join(VERDICTS)}")
    for key in ("base_count", "new_count", "pairs", "base_events", "new_events", "base_only",
                "new_only"):
        cell[key] = field(c, key, (int,), where)
    for key in ("minimal_effect", "p_adjusted"):
        cell[key] = float(field(c, key, NUMBER, where))
    effect = field(c, "effect", NUMBER, where, allow_none=True)
    cell["effect"] = None if effect is None else float(effect)
    interval = field(c, "interval", (list,), where, allow_none=True)
    if interval is not None:
        if len(interval) != 2 or not all(isinstance(v, NUMBER) and not isinstance(v, bool)
                                         for v in interval):
            raise InputError(f"{where}: 'interval' is {json.dumps(interval)[:60]}, "
                             "expected [low, high]")
        interval = [float(v) for v in interval]
    cell["interval"] = interval
    seeds = []
    for k, s in enumerate(field(c, "seeds", (list,), where)):
        w = f"{where}.seeds[{k}]"
        seed = field(s, "seed", (int,), w)
        base = field(s, "base", NUMBER, w, allow_none=True)
        new = field(s, "new", NUMBER, w, allow_none=True)
        seeds.append((seed, finite(base), finite(new)))
    cell["seeds"] = seeds
    return cell


def read(path):
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise InputError(f"cannot read it ({e.strerror})") from e
    except UnicodeDecodeError as e:
        raise InputError("is not UTF-8 text (expected the JSON of tofu compare --json)") from e
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"line {e.lineno}, column {e.colno}: not JSON ({e.msg})") from e
    if not isinstance(doc, dict) or doc.get("format") != "tofu compare":
        raise InputError('is not a tofu comparison (expected "format": "tofu compare", as '
                         "tofu compare --json or tofu check --baseline write)")
    version = doc.get("version")
    if version != 1:
        raise InputError(f"'version' is {json.dumps(version)}: this script reads version 1")
    comparison = {"base": field(doc, "base", (str,), "top level"),
                  "new": field(doc, "new", (str,), "top level")}
    counts = field(doc, "counts", (dict,), "top level")
    comparison["counts"] = {v: field(counts, v, (int,), "counts") for v in VERDICTS}
    comparison["fdr"] = float(field(doc, "fdr", NUMBER, "top level"))
    comparison["fdr_procedure"] = field(doc, "fdr_procedure", (str,), "top level")
    comparison["confidence"] = float(field(doc, "confidence", NUMBER, "top level"))
    comparison["cells"] = [read_cell(c, i)
                           for i, c in enumerate(field(doc, "cells", (list,), "top level"))]
    return comparison


def chosen(cells, limit):
    """The cells to draw and whether they are the all-unchanged fallback."""
    shown = [c for v in VERDICTS[:3] for c in cells if c["verdict"] == v]
    if shown:
        return shown[:limit], False
    ate = [c for c in cells if c["metric"] == ATE]
    return (ate or cells)[:limit], True


# ---- words ----

def metric_text(c):
    """As the terminal table: methods.ate_m, run.failed, expectation <label>."""
    if c["metric"].startswith("run.expectation."):
        return "expectation " + c["subject"]
    return c["metric"].replace(".<method>", "")


def effect_text(c):
    if c["kind"] == "event":
        return f"{c['base_events']}/{c['base_count']} \u2192 {c['new_events']}/{c['new_count']}"
    if c["effect"] is None:
        return ""  # no values on a side: the note says so
    low, high = c["interval"] if c["interval"] else (math.nan, math.nan)
    if c["kind"] == "ratio":
        return f"\u00d7{c['effect']:.3f} [{low:.3f}, {high:.3f}]"
    unit = f" {c['unit']}" if c["unit"] else ""
    return f"{c['effect']:+.4g}{unit} [{low:+.4g}, {high:+.4g}]"


def minimal_text(c):
    if c["kind"] == "event":
        return None
    if c["kind"] == "ratio":
        return f"minimal {100 * c['minimal_effect']:g} %"
    return f"minimal {c['minimal_effect']:g}{' ' + c['unit'] if c['unit'] else ''}"


def n_text(c):
    if c["pairing"] == "unpaired":
        return f"{c['base_count']} + {c['new_count']} seeds, unpaired"
    return f"{c['pairs']} pair{'' if c['pairs'] == 1 else 's'}, {c['pairing']}"


def short(label, width=22):
    """A check directory or baseline file by its last component, as an axis label."""
    name = pathlib.PurePath(label).name or label
    return name if len(name) <= width else name[:width - 1] + "\u2026"


def title(ax, c, width):
    """Three or four lines of where and how sure, and the verdict above them in colour."""
    colour = COLOURS[c["verdict"]]
    verdict = c["verdict"].upper() if c["verdict"] in ("regressed", "improved") else c["verdict"]
    expectation = c["metric"].startswith("run.expectation.")
    where = " \u00b7 ".join(x for x in (c["scenario"], "" if expectation else c["subject"]) if x)
    metric = " \u00b7 ".join(x for x in (metric_text(c), minimal_text(c)) if x)
    how = n_text(c) + " \u00b7 " + (c["note"] if c["note"] else f"p adj {c['p_adjusted']:.3g}")
    lines = [textwrap.shorten(where, width, placeholder="\u2026"),
             textwrap.shorten(metric, width, placeholder="\u2026")]
    lines += textwrap.wrap(how, width)[:2]
    text = ax.set_title("\n".join(lines), fontsize=8, color="0.2", loc="left", pad=5,
                        linespacing=1.25)
    ax.annotate(f"{verdict}  {effect_text(c)}".strip(), (0.0, 1.0), xycoords=text, xytext=(0, 4),
                textcoords="offset points", ha="left", va="bottom", fontsize=10.5,
                fontweight="bold", color=colour, annotation_clip=False)


# ---- drawing ----

def style(ax, colour):
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    for side in ("left", "bottom"):
        ax.spines[side].set_color("0.6")
    ax.tick_params(colors="0.3", labelsize=8)
    # A faint tint of the verdict's colour: it reads before the text does.
    ax.set_facecolor(matplotlib.colors.to_rgba(colour, 0.045))


def draw_event(ax, c, labels):
    colour = COLOURS[c["verdict"]]
    heights = [c["base_events"], c["new_events"]]
    totals = [c["base_count"], c["new_count"]]
    ax.bar([0, 1], heights, width=0.5, color=[BASE_COLOUR, colour], zorder=2)
    top = max(max(totals), 1)
    for x, h, n in zip((0, 1), heights, totals):
        ax.text(x, h + 0.02 * top, f"{h} of {n}", ha="center", va="bottom", fontsize=9,
                color="0.15")
    ax.set_ylim(0, top * 1.22)
    ax.yaxis.set_major_locator(ticker.MaxNLocator(nbins=5, integer=True))
    ax.set_ylabel("seeds with the event", fontsize=8)
    if c["pairing"] != "unpaired" and c["pairs"]:
        ax.text(0.5, 0.98, f"discordant seeds: {c['base_only']} base only, "
                f"{c['new_only']} new only", transform=ax.transAxes, ha="center", va="top",
                fontsize=7, color="0.35")
    ax.set_xticks([0, 1])
    ax.set_xticklabels(labels, fontsize=8)
    ax.set_xlim(-0.6, 1.6)
    ax.grid(axis="y", alpha=0.3, zorder=0)


def median(values):
    v = sorted(values)
    if not v:
        return None
    m = len(v) // 2
    return v[m] if len(v) % 2 else 0.5 * (v[m - 1] + v[m])


def log_ticks(lo, hi):
    """Ticks of a log axis from lo to hi: decades when they are enough, else 1-2-5 (or
    finer) steps, else evenly spaced round values (a range narrower than a factor 2)."""
    first, last = math.floor(math.log10(lo)) - 1, math.ceil(math.log10(hi)) + 1
    for subs in ([1], [1, 3], [1, 2, 5], [1, 1.5, 2, 3, 5, 7]):
        ticks = [m * 10.0 ** e for e in range(first, last + 1) for m in subs]
        ticks = [t for t in ticks if lo <= t <= hi]
        if len(ticks) >= 3:
            return ticks
    return [t for t in ticker.MaxNLocator(nbins=4).tick_values(lo, hi) if lo <= t <= hi]


def clusters(ys, gap):
    """Indices of ys grouped where consecutive values (sorted) are closer than gap."""
    order = sorted(range(len(ys)), key=lambda i: ys[i])
    groups = []
    for i in order:
        if groups and ys[i] - ys[groups[-1][-1]] < gap:
            groups[-1].append(i)
        else:
            groups.append([i])
    return groups


def draw_slopes(ax, c, labels):
    colour = COLOURS[c["verdict"]]
    seeds = c["seeds"]
    values = [v for _, b, n in seeds for v in (b, n) if v is not None]
    log = c["kind"] == "ratio" and values and min(values) > 0
    paired = c["pairing"] != "unpaired"
    ends = []  # (seed, new value) of the lines, for their labels
    for seed, b, n in seeds:
        if paired and b is not None and n is not None:
            ax.plot([0, 1], [b, n], color=colour, alpha=0.55, lw=1.3, zorder=3,
                    solid_capstyle="round")
            ends.append((seed, n))
    # Unpaired seeds: each side's points spread a little sideways so that they do not hide
    # each other (the same spread every time).
    sides = ([b for _, b, _ in seeds if b is not None], [n for _, _, n in seeds if n is not None])
    for x, side, face in ((0, sides[0], BASE_COLOUR), (1, sides[1], colour)):
        xs = [x] * len(side)
        if not paired and len(side) > 1:
            xs = [x + 0.12 * ((k % 5) - 2) / 2 for k in range(len(side))]
        ax.scatter(xs, side, s=18, color=face, edgecolors="white", linewidths=0.5, zorder=4)
        m = median(side)
        if m is not None:
            ax.plot([x - 0.15, x + 0.15], [m, m], color="black", lw=2.2, zorder=5,
                    solid_capstyle="butt")
        else:
            ax.text(x, 0.5, "no values", transform=ax.get_xaxis_transform(), ha="center",
                    va="center", fontsize=8, color="0.45", rotation=90)
    if values:
        lo, hi = min(values), max(values)
        if log:
            ax.set_yscale("log")
            pad = (hi / lo) ** 0.08 if hi / lo > 1.05 else 1.05
            ax.set_ylim(lo / pad, hi * pad)
            ticks = log_ticks(lo / pad, hi * pad)
            ax.yaxis.set_major_locator(ticker.FixedLocator(ticks))
            ax.yaxis.set_minor_locator(ticker.NullLocator())
            ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:.3g}"))
        else:
            pad = 0.08 * (hi - lo) if hi > lo else (abs(hi) * 0.25 or 1.0)
            ax.set_ylim(lo - pad, hi + pad)
            ax.yaxis.set_major_locator(ticker.MaxNLocator(nbins=5))
            ax.yaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:.4g}"))
    unit = f" [{c['unit']}]" if c["unit"] else ""
    key = c["metric"].rsplit(".", 1)[-1]
    ax.set_ylabel(key + unit, fontsize=8)
    ax.set_xticks([0, 1])
    ax.set_xticklabels(labels, fontsize=8)
    ax.set_xlim(-0.35, 1.55)
    ax.grid(axis="y", alpha=0.3, zorder=0)
    label_seeds(ax, ends)


def label_seeds(ax, ends):
    """The seed of each line beside its new end; lines that end closer than a label's
    height share one label ("seeds 2, 7", or "5 seeds": they are told apart by their left
    ends, if at all)."""
    if not ends or len(ends) > 12:
        return
    ax.figure.canvas.draw()  # the layout as drawn, for display coordinates
    to_display = ax.transData.transform
    ys = [to_display((1, n))[1] for _, n in ends]
    gap = 8.0 * ax.figure.dpi / 72.0  # one label's height
    inverse = ax.transData.inverted()
    for group in clusters(ys, gap):
        seeds = sorted(ends[i][0] for i in group)
        text = (f"seed {seeds[0]}" if len(seeds) == 1 else
                "seeds " + ", ".join(map(str, seeds)) if len(seeds) == 2 else
                f"{len(seeds)} seeds")
        y = inverse.transform((0, sum(ys[i] for i in group) / len(group)))[1]
        ax.text(1.2, y, text, fontsize=6.5, color="0.35", va="center", ha="left",
                clip_on=False)


PANEL_W, PANEL_H = 4.2, 2.9   # inches of a panel's axes and its margins
TITLE_H = 0.95                # inches above a panel for its verdict and title lines
HEADER_GAP = 0.08             # inches between the header's title, summary and legend


def draw(comparison, limit, out):
    cells, fallback = chosen(comparison["cells"], limit)
    base, new = comparison["base"], comparison["new"]
    labels = [f"base\n{short(base)}", f"new\n{short(new)}"]
    panels = max(len(cells), 1)
    columns = min(panels, 3)
    rows = math.ceil(panels / columns)
    width = max(PANEL_W * columns, 5.2)

    counts = comparison["counts"]
    summary = (f"{len(comparison['cells'])} cells: "
               + ", ".join(f"{counts[v]} {v}" for v in VERDICTS))
    if fallback and cells:
        what = metric_text(cells[0]) if cells[0]["metric"] == ATE else "the comparison"
        summary += f"; every cell unchanged, drawn: the first {len(cells)} of {what}"
    else:
        hidden = counts["regressed"] + counts["improved"] + counts["inconclusive"] - len(cells)
        if hidden > 0:
            summary += f"; {hidden} more not drawn (--cells)"
    procedure = {"benjamini-hochberg": "Benjamini-Hochberg",
                 "benjamini-yekutieli": "Benjamini-Yekutieli"}.get(
                     comparison["fdr_procedure"], comparison["fdr_procedure"])
    legend = (f"effect: median over the seeds of new / base (\u00d7, an error's scale) or "
              f"new \u2212 base, [{100 * comparison['confidence']:g} % bootstrap interval]; "
              f"false-discovery rate {comparison['fdr']:g} ({procedure}). A line is a seed, "
              "a black tick each side's median.")
    # characters per line at the header's sizes (about 0.55 em a character)
    header = []  # (line, font size, weight, colour, inches down to the next line)
    for text, size, weight, colour, em in (
            (f"tofu compare: base {base}  \u2192  new {new}", 12, "bold", "0.1", 0.62),
            (summary, 9, "normal", "0.2", 0.55), (legend, 7.5, "normal", "0.4", 0.55)):
        lines = textwrap.wrap(text, int(width * 72 / (em * size)), break_on_hyphens=False)
        header += [(line, size, weight, colour, size * 1.4 / 72) for line in lines]
        header[-1] = header[-1][:4] + (size * 1.4 / 72 + HEADER_GAP,)
    header_h = 0.15 + sum(h[4] for h in header) + 0.1
    height = header_h + rows * (TITLE_H + PANEL_H)
    fig, axes = plt.subplots(rows, columns, figsize=(width, height), squeeze=False)
    y = height - 0.15
    for line, size, weight, colour, down in header:
        fig.text(0.12 / width, y / height, line, fontsize=size, fontweight=weight, va="top",
                 ha="left", color=colour)
        y -= down
    # A panel: its title above it, the axes, its tick labels below (in PANEL_H).
    fig.subplots_adjust(left=0.8 / width, right=1 - 0.45 / width, bottom=0.55 / height,
                        top=1 - (header_h + TITLE_H) / height,
                        wspace=1.2 / (PANEL_W - 1.25), hspace=(TITLE_H + 0.55) / (PANEL_H - 0.55))
    flat = [ax for row in axes for ax in row]
    chars = int((PANEL_W - 0.9) * 72 / (0.55 * 8))
    for ax, c in zip(flat, cells):
        style(ax, COLOURS[c["verdict"]])
        if c["kind"] == "event":
            draw_event(ax, c, labels)
        else:
            draw_slopes(ax, c, labels)
        title(ax, c, chars)
    for ax in flat[len(cells):]:
        ax.axis("off")
    if not cells:
        flat[0].text(0.5, 0.5, "no cells in the comparison", ha="center", va="center",
                     color="0.5", transform=flat[0].transAxes)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    try:
        # No metadata: no timestamp or version in the file, the same bytes every time.
        fig.savefig(tmp, format="png", dpi=100, metadata={"Software": None})
        os.replace(tmp, out)
    finally:
        plt.close(fig)
        if tmp.exists():
            tmp.unlink()


def positive(text):
    """a whole number >= 1"""
    value = int(text)
    if value < 1:
        raise ValueError(text)
    return value


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("input", type=pathlib.Path,
                        help="JSON of tofu compare --json, or a check directory of "
                             "tofu check --baseline (its compare.json)")
    parser.add_argument("--out", type=pathlib.Path, required=True, help="PNG file")
    parser.add_argument("--cells", type=positive, default=6,
                        help="most panels drawn (default 6)")
    args = parser.parse_args()
    path = args.input / "compare.json" if args.input.is_dir() else args.input
    if not path.is_file():
        print(f"plot_compare: {path}: no such file (expected the JSON of tofu compare --json, "
              "or a check directory of tofu check --baseline holding compare.json)",
              file=sys.stderr)
        return 2
    if not args.out.parent.resolve().is_dir():
        print(f"plot_compare: {args.out}: its directory does not exist", file=sys.stderr)
        return 2
    if args.out.is_dir():
        print(f"plot_compare: {args.out}: is a directory (expected the PNG file to write)",
              file=sys.stderr)
        return 2
    try:
        comparison = read(path)
    except InputError as e:
        print(f"plot_compare: {path}: {e}", file=sys.stderr)
        return 2
    draw(comparison, args.cells, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

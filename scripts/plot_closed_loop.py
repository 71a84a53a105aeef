#!/usr/bin/python3
"""Plot the closed-loop flights of a tofu run (a scenario with `control: {state_source:
estimate}`): each flight was flown with the controller on one estimation method's output
and is judged against ground truth.
 (a) plan view: the world's structure (models/worlds/<world>.xml), the reference, and the
     TRUE path of every flight, collisions (x) and failsafe starts (triangles) marked;
 (b) tracking error: true position against the reference, per flight;
 (c) estimate error: the estimate the controller flew on against the truth;
 (d) distance of the robot to the nearest structure.
Time plots shade every scheduled fault (labels.csv) and mark handovers and failsafes.

    scripts/plot_closed_loop.py RUN_DIR [--out FILE.png] [--models DIR] [--when-ready]
                                (default RUN_DIR/closed_loop.png, DIR = repository models/)

Reads RUN_DIR/summary.json (closed_loop), RUN_DIR/labels.csv, RUN_DIR/scenario.yaml (world)
and RUN_DIR/closed_loop/<method>/{control.csv, events.csv, summary.json}. Missing files and
flights are left out (exit 0); a malformed CSV row is an error naming file:line and the
column (exit 2, no PNG).
"""
import argparse
import json
import math
import pathlib
import re
import sys
import xml.etree.ElementTree as ElementTree

import matplotlib

matplotlib.use("Agg")
import matplotlib.patches as mpatches  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from tofu_csv import (CsvError, any_text, flag, name, number,  # noqa: E402
                      optional_number, read_csv, timestamp)

FLIGHT_COLOURS = {"consensus": "black", "naive": "tab:orange"}
OTHER_COLOURS = ["tab:blue", "tab:green", "tab:purple", "tab:brown", "tab:cyan", "tab:pink"]
FAULT_COLOUR = "#e57373"
CONDITION_COLOUR = "#bdbdbd"
CONTROL_COLUMNS = ["timestamp", "mode", "p_ref_x", "p_ref_y", "p_ref_z", "p_true_x", "p_true_y",
                   "p_true_z", "p_est_x", "p_est_y", "p_est_z", "tracking_error",
                   "estimate_error", "structure_distance"]
MODES = ("truth", "estimate", "failsafe_hold", "failsafe_land", "landed")


def mode(text):
    """a flight mode (truth, estimate, failsafe_hold, failsafe_land, landed)"""
    if text not in MODES:
        raise ValueError(text)
    return text


def method_stem(method):
    return re.sub(r"[:+/ ]", "_", method)


def colour_of(method, index):
    return FLIGHT_COLOURS.get(method, OTHER_COLOURS[index % len(OTHER_COLOURS)])


def load_json(path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def world_name(run):
    try:
        for line in (run / "scenario.yaml").read_text(encoding="utf-8").splitlines():
            match = re.match(r"^world:\s*\"?([A-Za-z0-9_]+)\"?\s*$", line)
            if match:
                return match.group(1)
    except OSError:
        pass
    return None


def rotation_of(geom):
    """The geom's rotation matrix from euler (degrees, MJCF's default xyz), xyaxes or quat."""
    if geom.get("xyaxes"):
        v = [float(x) for x in geom.get("xyaxes").split()]
        x_axis, y_axis = np.array(v[:3]), np.array(v[3:])
        x_axis /= np.linalg.norm(x_axis)
        y_axis -= x_axis * np.dot(x_axis, y_axis)
        y_axis /= np.linalg.norm(y_axis)
        return np.column_stack([x_axis, y_axis, np.cross(x_axis, y_axis)])
    if geom.get("quat"):
        w, x, y, z = [float(q) for q in geom.get("quat").split()]
        n = math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / n, x / n, y / n, z / n
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    if geom.get("euler"):
        a, b, c = [math.radians(float(e)) for e in geom.get("euler").split()]
        rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
        ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
        rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
        return rx @ ry @ rz  # MJCF euler "xyz": rotations about the moving axes
    return np.eye(3)


def structure_outlines(world_file):
    """Plan-view outlines of the world's structure: (kind, data) with kind "polygon"
    (corner list in x-y) or "circle" ((x, y), r). Ground, decoration, planes and the
    ceiling/roof are left out."""
    try:
        root = ElementTree.parse(world_file).getroot()
    except (OSError, ElementTree.ParseError):
        return []
    outlines = []
    for geom in root.iter("geom"):
        geom_class = geom.get("class", "")
        geom_name = geom.get("name", "")
        if "ground" in geom_class or "deco" in geom_class or geom.get("type") == "plane":
            continue
        if geom_name in ("ceiling", "roof") or not geom.get("pos") or not geom.get("size"):
            continue
        pos = np.array([float(p) for p in geom.get("pos").split()])
        size = [float(s) for s in geom.get("size").split()]
        if geom.get("type") == "cylinder" and len(size) >= 1:
            outlines.append(("circle", ((pos[0], pos[1]), size[0])))
        elif geom.get("type", "sphere") == "box" and len(size) == 3:
            rotation = rotation_of(geom)
            corners = []
            for sx, sy, sz in [(-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1),
                               (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)]:
                corners.append(pos + rotation @ np.array([sx * size[0], sy * size[1], sz * size[2]]))
            points = np.array(corners)[:, :2]
            # The convex hull of the projected corners (a box projects to a convex polygon).
            centre = points.mean(axis=0)
            angles = np.arctan2(points[:, 1] - centre[1], points[:, 0] - centre[0])
            outlines.append(("polygon", points[np.argsort(angles)]))
    return outlines


def fault_windows(run, end_s):
    """(sensor, label, source, start, end) of every fault and condition in labels.csv."""
    path = run / "labels.csv"
    if not path.exists():
        return []
    rows = read_csv(path, ["timestamp", "sensor", "label", "source", "active"],
                    [timestamp, name, name, name, flag])
    open_windows, windows = {}, []
    for t, sensor, label, source, active in rows:
        key = (sensor, label, source)
        if active:
            open_windows.setdefault(key, t)
        elif key in open_windows:
            windows.append((sensor, label, source, open_windows.pop(key), t))
    for (sensor, label, source), start in open_windows.items():
        windows.append((sensor, label, source, start, end_s))
    return windows


def load_flight(run, method):
    folder = run / "closed_loop" / method_stem(method)
    control_path = folder / "control.csv"
    if not control_path.exists():
        return None
    parsers = [timestamp, mode] + [number] * 6 + [optional_number] * 3 + [number] + \
              [optional_number] * 2
    rows = read_csv(control_path, CONTROL_COLUMNS, parsers)
    events = []
    if (folder / "events.csv").exists():
        events = read_csv(folder / "events.csv", ["timestamp", "event", "detail"],
                          [timestamp, name, any_text], last_field_may_hold_commas=True)
    summary = load_json(folder / "summary.json") or {}
    collisions = [c.get("start_s") for c in summary.get("collisions", [])
                  if isinstance(c, dict) and isinstance(c.get("start_s"), (int, float))]
    columns = list(zip(*rows)) if rows else [[] for _ in CONTROL_COLUMNS]
    data = {name: np.array(values) for name, values in zip(CONTROL_COLUMNS, columns)
            if name != "mode"}
    data["mode"] = list(columns[1])
    return {"data": data, "events": events, "collisions": collisions}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=pathlib.Path)
    parser.add_argument("--out", type=pathlib.Path, help="PNG file (default RUN_DIR/closed_loop.png)")
    parser.add_argument("--models", type=pathlib.Path,
                        default=pathlib.Path(__file__).resolve().parent.parent / "models")
    parser.add_argument("--when-ready", action="store_true",
                        help="import, then wait for a line 'go' on standard input before "
                             "reading RUN_DIR (tofu starts the script while it writes the "
                             "files); anything else ends the script without drawing, exit 0")
    args = parser.parse_args()
    if args.when_ready and sys.stdin.readline().strip() != "go":
        return 0
    run = args.run_dir
    out = args.out or run / "closed_loop.png"

    summary = load_json(run / "summary.json") or {}
    closed_loop = summary.get("closed_loop") if isinstance(summary.get("closed_loop"), dict) else {}
    methods = list(closed_loop.keys())
    if not methods and (run / "closed_loop").is_dir():
        methods = sorted(p.name for p in (run / "closed_loop").iterdir() if p.is_dir())
    try:
        flights = {m: f for m in methods if (f := load_flight(run, m)) is not None}
        end_s = max((f["data"]["timestamp"][-1] for f in flights.values()
                     if len(f["data"]["timestamp"])), default=0.0)
        windows = fault_windows(run, end_s)
    except (CsvError, OSError) as e:
        print(f"plot_closed_loop: {e}", file=sys.stderr)
        return 2

    fig = plt.figure(figsize=(15, 9), dpi=110)
    grid = fig.add_gridspec(3, 2, width_ratios=[1.0, 1.35], hspace=0.35, wspace=0.18)
    plan = fig.add_subplot(grid[:, 0])
    tracking = fig.add_subplot(grid[0, 1])
    estimate = fig.add_subplot(grid[1, 1], sharex=tracking)
    distance = fig.add_subplot(grid[2, 1], sharex=tracking)
    scenario = summary.get("scenario", run.name)
    if not flights:
        fig.suptitle(f"{scenario}: no closed-loop flight to draw")
        fig.savefig(out)
        return 0

    # (a) plan view.
    world = world_name(run)
    xs, ys = [], []
    for index, (method, flight) in enumerate(flights.items()):
        d = flight["data"]
        xs += [d["p_true_x"].min(), d["p_true_x"].max(), d["p_ref_x"].min(), d["p_ref_x"].max()]
        ys += [d["p_true_y"].min(), d["p_true_y"].max(), d["p_ref_y"].min(), d["p_ref_y"].max()]
    # A margin of 1.5 m, and at least 6 m across, so that nearby structure shows.
    margin = 1.5
    x_lim = [min(xs) - margin, max(xs) + margin]
    y_lim = [min(ys) - margin, max(ys) + margin]
    for lim in (x_lim, y_lim):
        if lim[1] - lim[0] < 6.0:
            centre = 0.5 * (lim[0] + lim[1])
            lim[0], lim[1] = centre - 3.0, centre + 3.0
    if world:
        for kind, shape in structure_outlines(args.models / "worlds" / f"{world}.xml"):
            if kind == "circle":
                plan.add_patch(mpatches.Circle(shape[0], shape[1], color="#9e9e9e", alpha=0.8))
            else:
                plan.add_patch(mpatches.Polygon(shape, closed=True, color="#9e9e9e", alpha=0.8))
    first = next(iter(flights.values()))["data"]
    plan.plot(first["p_ref_x"], first["p_ref_y"], "--", color="grey", lw=1.2, label="reference")
    for index, (method, flight) in enumerate(flights.items()):
        d = flight["data"]
        colour = colour_of(method, index)
        plan.plot(d["p_true_x"], d["p_true_y"], color=colour, lw=1.4,
                  label=f"true path, flown on {method}")
        t = d["timestamp"]
        for hit_s in flight["collisions"]:
            k = min(int(np.searchsorted(t, hit_s)), len(t) - 1)
            plan.plot(d["p_true_x"][k], d["p_true_y"][k], "x", color="red", ms=12, mew=3)
        for event_t, event, _ in flight["events"]:
            if event == "failsafe_start":
                k = min(int(np.searchsorted(t, event_t)), len(t) - 1)
                plan.plot(d["p_true_x"][k], d["p_true_y"][k], "^", color=colour, ms=9)
    plan.set_xlim(*x_lim)
    plan.set_ylim(*y_lim)
    plan.set_aspect("equal")
    plan.set_xlabel("x [m]")
    plan.set_ylabel("y [m]")
    plan.set_title(f"plan view ({world or 'world unknown'}); x: collision, ^: failsafe")
    plan.legend(loc="best", fontsize=8)

    # (b)-(d) over time.
    for axis in (tracking, estimate, distance):
        for sensor, label, source, start, end in windows:
            if source == "fault":
                axis.axvspan(start, end, color=FAULT_COLOUR, alpha=0.18, lw=0)
        axis.grid(True, alpha=0.3)
    for sensor, label, source, start, end in windows:
        if source == "fault":
            tracking.text(start, 1.0, f" {sensor} {label}", transform=tracking.get_xaxis_transform(),
                          fontsize=7, va="bottom", color="#b71c1c")
    for index, (method, flight) in enumerate(flights.items()):
        d = flight["data"]
        colour = colour_of(method, index)
        # Log scale: a few mm and metres on one axis; below 1 mm is drawn at 1 mm.
        tracking.plot(d["timestamp"], np.maximum(d["tracking_error"], 1e-3), color=colour,
                      lw=1.1, label=method)
        estimate.plot(d["timestamp"], np.fmax(d["estimate_error"], 1e-3), color=colour, lw=1.1,
                      label=method)
        distance.plot(d["timestamp"], d["structure_distance"], color=colour, lw=1.1, label=method)
        for event_t, event, _ in flight["events"]:
            style = {"handover": ":", "failsafe_start": "-", "failsafe_land": "-.",
                     "landed": "-."}.get(event)
            if style:
                for axis in (tracking, estimate, distance):
                    axis.axvline(event_t, color=colour, ls=style, lw=0.9, alpha=0.7)
        for hit_s in flight["collisions"]:
            distance.plot(hit_s, 0.0, "x", color="red", ms=9, mew=2)
    tracking.set_ylabel("tracking error [m]\n(true vs reference)")
    estimate.set_ylabel("estimate error [m]\n(controller's vs true)")
    distance.set_ylabel("distance to\nstructure [m]")
    distance.axhline(0.0, color="red", lw=0.8)
    distance.set_xlabel("time [s]   (red: scheduled faults; dotted: handover; solid: failsafe)")
    for axis in (tracking, estimate):
        axis.set_yscale("log")
    tracking.legend(loc="upper left", fontsize=8)

    lines = []
    for method in flights:
        s = closed_loop.get(method, {}) if isinstance(closed_loop.get(method), dict) else {}
        rmse, hits, dist = s.get("tracking_rmse_m"), s.get("collisions"), s.get("min_structure_distance_m")
        lines.append(f"flown on {method}: tracking RMSE "
                     f"{rmse:.3f} m" if isinstance(rmse, (int, float)) else f"flown on {method}: -")
        if isinstance(hits, int):
            lines[-1] += f", {hits} collision{'s' if hits != 1 else ''}"
        if isinstance(dist, (int, float)):
            lines[-1] += f", closest {dist:.2f} m"
    fig.suptitle(f"{scenario}: closed loop (the controller flying on each method's estimate)\n"
                 + "\n".join(lines), fontsize=10)
    fig.savefig(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""The measured numbers of docs/RESULTS.md and README.md, regenerated (issue 35, item 4).

Each *source* (SOURCES below) is a declared list of commands (`tofu check DIR --seeds N`,
`tofu run`, `tofu estimate`, scripts/plot_consistency.py) and a function that reads their
output files (summary.json of every seed, estimate_*.json, the script's printed table) into
named values ("key": "text as printed"). The values and
a stamp per source (tofu's commit from `tofu --version`, seeds, date, machine, the
commands and their wall time) go to one generated file, docs/results/results.json. The
documents then take every generated number from that file, in regions delimited by
markers that do not render:

    <!-- results:table NAME -->            a table (TABLES below), stamped, to
    ...                                     <!-- /results -->
    <!-- r:KEY -->5.5<!-- /r -->            one number (or range) inline

    scripts/results.py                      run every source, write results.json and the docs
    scripts/results.py --only euroc         run one source (repeatable); the others keep theirs
    scripts/results.py --render             rewrite the docs from results.json, run nothing
    scripts/results.py --check              run nothing; exit 1 when a marked number or table
                                            differs from results.json (file:line and key),
                                            or when a number README states as measured
                                            (a paragraph citing docs/RESULTS.md) is unmarked
Options: --tofu PATH (default build/tofu), --jobs N (tofu check --jobs, default 1),
--runs DIR (outputs, default runs/results), --reuse (take a command's outputs from a
previous run into the same --runs when its <name>.run.json records the same command and a
commit whose product code is this tofu's: outputs of a build of uncommitted changes, or of
a commit whose code differs, are made again; the stamp names the commit reused),
--root DIR (the repository whose docs are read and written; default this script's),
--euroc DIR (the EuRoC excerpt; default ../shared/data/euroc_v1_02 beside the repository).
Exit codes: 0 ok, 1 --check found a difference, 2 bad input or a failed command.
"""
import argparse
import datetime
import decimal
import json
import math
import os
import pathlib
import platform
import re
import shutil
import statistics
import subprocess
import sys
import time

SCRIPT_ROOT = pathlib.Path(__file__).resolve().parent.parent
DATA = pathlib.Path("docs/results/results.json")
DOCS = [pathlib.Path("docs/RESULTS.md"), pathlib.Path("README.md")]
EUROC = pathlib.Path("../shared/data/euroc_v1_02")


class ResultsError(Exception):
    """Bad input or a failed command; the message says which."""


# ---- formatting: every number is printed by one of these -------------------------------

def fixed(x, digits):
    if x is None:
        return "-"
    if math.isinf(x):
        return "inf"
    return f"{x:.{digits}f}"


def sig(x, digits=3):
    """x to `digits` significant digits, without exponent below 1e4 (0.0339, 1.95, 16.1)."""
    if x is None:
        return "-"
    if math.isinf(x):
        return "inf"
    if x == 0:
        return "0"
    exponent = math.floor(math.log10(abs(x)))
    if exponent >= 4:
        return sci(x, digits)
    decimals = max(digits - 1 - exponent, 0)
    return f"{x:.{decimals}f}"


def sci(x, digits=2):
    """0.38, 4.7e3, 8.1e5: significant digits, exponent only from 1e3 on."""
    if x is None:
        return "-"
    if abs(x) < 1000:
        return sig(x, digits)
    mantissa, exponent = f"{x:.{digits - 1}e}".split("e")
    return f"{mantissa}e{int(exponent)}"


def span(values, fmt):
    """'a-b' of the smallest and largest (one value when they print alike)."""
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    low, high = fmt(min(values)), fmt(max(values))
    return low if low == high else f"{low}-{high}"


def percent(x, digits=1):
    return "-" if x is None else ("inf" if math.isinf(x) else f"{100 * x:.{digits}f} %")


def seeds_label(seeds):
    seeds = sorted(seeds)
    if len(seeds) == 1:
        return f"seed {seeds[0]}"
    if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 1:
        return f"seeds {seeds[0]}-{seeds[-1]}"
    return "seeds " + ", ".join(str(s) for s in seeds)


# ---- running tofu -----------------------------------------------------------------------

class Runner:
    """Runs a source's commands in the repository root, records each command's wall time
    in <runs>/<name>.run.json (reused with --reuse when the command is the same)."""

    def __init__(self, args, root, commit):
        self.tofu = str(pathlib.Path(args.tofu).resolve()) if os.sep in args.tofu else args.tofu
        self.commit = commit  # of the tofu that runs the commands (`tofu --version`)
        self.jobs = args.jobs
        self.runs = (root / args.runs).resolve()
        self.reuse = args.reuse
        self.root = root
        self.euroc = pathlib.Path(args.euroc)
        self.commands = []
        self.seconds = 0.0

    def tofu_cmd(self, name, *arguments, ok=(0,), fresh=None):
        """Run `tofu ARGUMENTS` once (name: its record); exit codes in ok are accepted
        (tofu check exits 1 when an expectation fails: that is a result, not an error).
        fresh: a directory removed before the command runs (not when its outputs are
        reused): `tofu search` resumes from what its --out holds."""
        arguments = [self._relative(a) for a in arguments]
        self._run(name, [self.tofu, *arguments], ["tofu", *arguments], ok, fresh)

    def script_cmd(self, name, script, *arguments):
        """Run one of scripts/ with Debian's python3; its output is in <runs>/<name>.log."""
        arguments = [script, *[self._relative(a) for a in arguments]]
        self._run(name, ["/usr/bin/python3", *arguments], arguments, (0,))

    def log(self, name):
        return (self.runs / f"{name}.log").read_text()

    def _run(self, name, command, shown, ok, fresh=None):
        record = self.runs / f"{name}.run.json"
        if self.reuse and record.exists():
            previous = json.loads(record.read_text())
            if previous.get("command", [])[1:] == command[1:] and previous.get("exit_code") in ok:
                why_not = reuse_refusal(self.root, previous.get("commit"), self.commit)
                if why_not is None:
                    self.commands.append({"command": " ".join(shown), "seconds": previous["seconds"],
                                          "exit_code": previous["exit_code"],
                                          "started": previous.get("started"), "reused": True,
                                          "commit": previous["commit"]})
                    self.seconds += previous["seconds"]
                    return
                print(f"results: {name}: not reused: {why_not}", flush=True)
        record.parent.mkdir(parents=True, exist_ok=True)
        if fresh is not None:
            shutil.rmtree(fresh, ignore_errors=True)
        log = self.runs / f"{name}.log"
        start = time.monotonic()
        started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        with open(log, "w") as out:
            code = subprocess.call(command, cwd=self.root, stdout=out, stderr=subprocess.STDOUT)
        seconds = round(time.monotonic() - start, 1)
        record.write_text(json.dumps({"command": command, "exit_code": code, "seconds": seconds,
                                      "started": started, "commit": self.commit}, indent=1) + "\n")
        if code not in ok:
            raise ResultsError(f"`{' '.join(shown)}` exited {code} (log: {log})")
        self.commands.append({"command": " ".join(shown), "seconds": seconds, "exit_code": code,
                              "started": started, "commit": self.commit})
        self.seconds += seconds

    def _relative(self, argument):
        """Paths inside the repository as relative paths (the recorded command is then the
        same in every clone)."""
        if isinstance(argument, pathlib.Path):
            try:
                return str(argument.resolve().relative_to(self.root))
            except ValueError:
                return str(argument)
        return str(argument)

    def out(self, *parts):
        return self.runs.joinpath(*parts)


# What a result depends on: everything but the documents, tests, benchmarks, fuzzing and
# deployment examples (git pathspecs, from the repository's root).
PRODUCT_PATHSPEC = [".", ":!docs", ":!README.md", ":!tests", ":!bench", ":!fuzz", ":!deploy",
                    ":!.ci", ":!scripts/results.py"]


def reuse_refusal(root, made_by, running):
    """Why the outputs a command made with the tofu of commit `made_by` cannot stand for
    what the tofu of commit `running` would make (None: they can): no commit recorded, a
    build from uncommitted changes, or product code that differs between the two (a
    `-dirty` running commit is compared as the working tree)."""
    if not made_by:
        return "its record names no commit (made before results.py recorded one)"
    if made_by.endswith("-dirty") or made_by == "unknown":
        return f"made by a build of uncommitted changes ({made_by}): its code cannot be compared"
    if made_by == running:
        return None
    against = [] if running.endswith("-dirty") else [running.removesuffix("-dirty")]
    diff = subprocess.run(["git", "diff", "--quiet", made_by, *against, "--", *PRODUCT_PATHSPEC],
                          cwd=root, capture_output=True)
    if diff.returncode == 0:
        return None
    if diff.returncode == 1:
        return f"made by {made_by}, and product code changed since (git diff {made_by} -- {' '.join(PRODUCT_PATHSPEC)})"
    return f"made by {made_by}, which git cannot compare here ({diff.stderr.decode().strip()})"


def tofu_version(tofu, root):
    text = subprocess.run([tofu, "--version"], cwd=root, capture_output=True, text=True,
                          check=True).stdout.strip()
    match = re.search(r"commit ([0-9a-f]+(?:-dirty)?|unknown)", text)
    if not match:
        raise ResultsError(f"`{tofu} --version` does not name a commit: '{text}'")
    return text, match.group(1)


def machine():
    model = platform.processor() or "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{os.cpu_count()}-core {model}"


def load_json(path):
    try:
        return json.loads(pathlib.Path(path).read_text())
    except (OSError, ValueError) as e:
        raise ResultsError(f"{path}: {e}") from None


def seed_summaries(check_dir, scenario, seeds):
    """summary.json of every seed of a `tofu check --out CHECK_DIR` of one scenario."""
    out = {}
    for seed in seeds:
        out[seed] = load_json(check_dir / scenario / f"seed_{seed}" / "summary.json")
    return out


def expectation(summary, metric, nth=0):
    hits = [e for e in summary["expectations"] if e["metric"] == metric]
    if len(hits) <= nth:
        raise ResultsError(f"{summary['scenario']} seed {summary['seed']}: no expectation "
                           f"#{nth + 1} on {metric}")
    return hits[nth]["value"]


# ---- sources ---------------------------------------------------------------------------
# Each: name, the seeds it flies (for the stamp), run(runner) and extract(runner) -> values.

EUROC_CUTS = [(0, 40), (5, 35), (10, 30), (15, 25), (20, 20)]
IMU_NOISE_SCALES = [1, 3, 10, 30]


def _cut_euroc(src, dst, start_s, length_s):
    """The excerpt restricted to [first IMU sample + start, + length], every stream and the
    ground truth, as tests/euroc_cuts_test.cc cuts it in memory."""
    imu_lines = (src / "mav0/imu0/data.csv").read_text().splitlines(keepends=True)
    first = next(int(line.split(",")[0]) for line in imu_lines if line and line[0] != "#")
    lo = first + int(start_s * 1_000_000_000)
    hi = lo + int(length_s * 1_000_000_000)

    def keep_csv(lines):
        return "".join(line for line in lines
                       if line.startswith("#") or lo <= int(line.split(",")[0]) <= hi)

    for rel in ("mav0/imu0/data.csv", "mav0/state_groundtruth_estimate0/data.csv"):
        (dst / rel).parent.mkdir(parents=True, exist_ok=True)
        (dst / rel).write_text(keep_csv((src / rel).read_text().splitlines(keepends=True)))
    for tum in src.glob("*.tum"):
        kept = []
        for line in tum.read_text().splitlines(keepends=True):
            if not line.strip() or line.startswith("#"):
                kept.append(line)
                continue
            t_ns = int(decimal.Decimal(line.split()[0]) * 1_000_000_000)
            if lo <= t_ns <= hi:
                kept.append(line)
        (dst / tum.name).write_text("".join(kept))


def run_euroc(r):
    src = (r.root / r.euroc).resolve()
    if not (src / "mav0/imu0/data.csv").exists():
        raise ResultsError(f"{src}: the EuRoC V1_02 excerpt is missing (docs/RESULTS.md)")
    for start, length in EUROC_CUTS:
        cut = r.out("euroc", f"cut_{start}", "log")
        if cut.exists():
            shutil.rmtree(cut)
        _cut_euroc(src, cut, start, length)
        r.tofu_cmd(f"euroc/cut_{start}", "estimate", cut, "--quiet",
                   "--out", r.out("euroc", f"cut_{start}", "estimate"))
    for k in IMU_NOISE_SCALES:
        r.tofu_cmd(f"euroc/imu_noise_{k}", "estimate", src, "--quiet", "--imu-noise-scale", k,
                   "--out", r.out("euroc", f"imu_noise_{k}"))


def extract_euroc(r):
    v = {}
    fused_ate, fused_rot, vio_ate, vio_rot, ratios, tilt_rms = [], [], [], [], [], []
    for start, _ in EUROC_CUTS:
        d = load_json(r.out("euroc", f"cut_{start}", "estimate", "estimate_single_pose_estimate.json"))
        c = f"euroc.cut{start}."
        check = d["input_check"]
        fused_ate.append(check["ate_m"])
        fused_rot.append(check["rotation_rmse_deg"])
        vio_ate.append(check["input_ate_m"])
        vio_rot.append(check["input_rotation_rmse_deg"])
        ratios.append(check["ate_m"] / check["input_ate_m"])
        v[c + "ate_cm"] = fixed(100 * check["ate_m"], 1)
        v[c + "rot_deg"] = fixed(check["rotation_rmse_deg"], 2)
        v[c + "vio_ate_cm"] = fixed(100 * check["input_ate_m"], 1)
        v[c + "vio_rot_deg"] = fixed(check["input_rotation_rmse_deg"], 2)
        v[c + "ratio"] = fixed(ratios[-1], 2)
        init = d["initialisation"][0]
        method = init["method"].replace("_", "-")
        if init["method"] == "rest":
            v[c + "init"] = f"rest, {fixed(init['after_first_sample_s'], 1)} s after the first IMU sample"
        else:
            window = init.get("window_s")
            v[c + "init"] = (f"{method}, {fixed(init['after_first_sample_s'], 1)} s"
                             + (f" (window {fixed(window, 1)} s)" if window else ""))
        v[c + "gravity_init_deg"] = fixed(init["gravity_direction_error_deg"], 2)
        noise = d["stream_noise"]["pose_estimate"]
        tilt = d["tilt_error"]
        tilt_rms.append(tilt["rms_deg"])
        v[c + "tilt_rms_deg"] = fixed(tilt["rms_deg"], 2)
        v[c + "tilt_max_deg"] = fixed(tilt["max_deg"], 2)
        # "(floor)": the measured scatter is below the floor the weights are clamped to
        measured = init.get("relative_position_std_m")
        floor = measured is not None and measured < noise["between_position_std_m"]
        v[c + "noise"] = (f"{fixed(1000 * noise['between_position_std_m'], 1)} mm / "
                          f"{fixed(noise['between_rotation_std_deg'], 2)}°"
                          + (" (floor)" if floor else "")
                          + ("" if noise.get("source", "measured") == "measured"
                             else f" ({noise['source']})"))
        b = d["bias_error"]
        gyro_final = math.dist(b["gyro_final_radps"], b["gyro_true_final_radps"])
        accel_final = math.dist(b["accel_final_mps2"], b["accel_true_final_mps2"])
        v[c + "gyro_bias"] = f"{fixed(1000 * b['gyro_rms_radps'], 1)} / {fixed(1000 * gyro_final, 1)}"
        v[c + "accel_bias"] = f"{fixed(b['accel_rms_mps2'], 3)} / {fixed(accel_final, 3)}"
    v["euroc.mean.ate_cm"] = fixed(100 * statistics.fmean(fused_ate), 1)
    v["euroc.mean.rot_deg"] = fixed(statistics.fmean(fused_rot), 2)
    v["euroc.mean.vio_ate_cm"] = fixed(100 * statistics.fmean(vio_ate), 1)
    v["euroc.mean.vio_rot_deg"] = fixed(statistics.fmean(vio_rot), 2)
    v["euroc.mean.ratio"] = fixed(statistics.fmean(fused_ate) / statistics.fmean(vio_ate), 2)
    v["euroc.mean.tilt_rms_deg"] = fixed(statistics.fmean(tilt_rms), 2)
    for k in IMU_NOISE_SCALES:
        d = load_json(r.out("euroc", f"imu_noise_{k}", "estimate_single_pose_estimate.json"))
        v[f"euroc.imu_noise_{k}"] = f"{fixed(d['ate']['position_rmse_m'], 3)} / {fixed(d['ate']['rotation_rmse_deg'], 2)}"
    return v


ARENA_METHODS = ["raw:vio", "single:vio", "single:leica", "fuse:vio+leica"]
# raw:<sensor> (the stream itself, scored) is written beside single:<sensor>; not a --method
ARENA_ESTIMATED = [m for m in ARENA_METHODS if not m.startswith("raw:")]


def run_estimator_arena(r):
    run_dir = r.out("estimator_arena", "run")
    r.tofu_cmd("estimator_arena/run", "run", "scenarios/estimator_arena.yaml", "--quiet",
               "--out", run_dir)
    r.tofu_cmd("estimator_arena/estimate", "estimate", run_dir, "--quiet",
               "--method", *ARENA_ESTIMATED, "--out", r.out("estimator_arena", "estimate"))
    for k in IMU_NOISE_SCALES:
        r.tofu_cmd(f"estimator_arena/imu_noise_{k}", "estimate", run_dir, "--quiet",
                   "--method", "single:vio", "single:leica", "--imu-noise-scale", k,
                   "--out", r.out("estimator_arena", f"imu_noise_{k}"))


def _estimate_file(directory, method):
    return directory / ("estimate_" + method.replace(":", "_").replace("+", "_") + ".json")


def _find_estimate(directory, method):
    wanted = _estimate_file(directory, method)
    if wanted.exists():
        return load_json(wanted)
    for path in sorted(directory.glob("estimate_*.json")):
        d = load_json(path)
        if d.get("method") == method:
            return d
    raise ResultsError(f"{directory}: no estimate_*.json of method {method}")


def extract_estimator_arena(r):
    v = {}
    for method in ARENA_METHODS:
        d = _find_estimate(r.out("estimator_arena", "estimate"), method)
        key = "arena." + method.replace(":", "_").replace("+", "_")
        v[key + ".ate_m"] = sig(d["ate"]["position_rmse_m"], 3)
        v[key + ".rot_deg"] = fixed(d["ate"]["rotation_rmse_deg"], 2)
        v[key + ".rpe_m"] = sig(d["ate"]["rpe_translation_rmse_m"], 2)
    for k in IMU_NOISE_SCALES:
        for method in ("single:vio", "single:leica"):
            d = _find_estimate(r.out("estimator_arena", f"imu_noise_{k}"), method)
            v[f"arena.imu_noise_{k}.{method.split(':')[1]}"] = (
                f"{sig(d['ate']['position_rmse_m'], 2)} / {fixed(d['ate']['rotation_rmse_deg'], 2)}")
    return v


PAPER_METRICS = [("cm", "CM"), ("mae", "MAE [m/s]"), ("pcc", "PCC"), ("kl", "KL")]
PAPER_METRIC_PAIRS = ["leica-vio", "leica-truth"]


def run_paper_metric(r):
    for scenario in ("paper_metric_evaluation", "paper_metric_divergence"):
        run_dir = r.out("paper_metric", scenario)
        r.tofu_cmd(f"paper_metric/{scenario}", "run", f"scenarios/{scenario}.yaml", "--quiet",
                   "--out", run_dir)
        for pair in PAPER_METRIC_PAIRS:
            r.script_cmd(f"paper_metric/{scenario}_{pair}", "scripts/plot_consistency.py", run_dir,
                         "--pair", pair, "--out", r.out("paper_metric", f"{scenario}_{pair}.png"))


def _consistency_table(text, where):
    """The rows scripts/plot_consistency.py prints: metric -> its cells as printed."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and len(cells) == 7 and cells[0] in dict(PAPER_METRICS):
            rows[cells[0]] = dict(zip(["healthy", "noisy", "diverging", "noisy_over_healthy",
                                       "diverging_over_noisy", "delay_s"], cells[1:]))
    if len(rows) != len(PAPER_METRICS):
        raise ResultsError(f"{where}: expected a row per metric {[m for m, _ in PAPER_METRICS]}, "
                           f"found {sorted(rows)}")
    return rows


def extract_paper_metric(r):
    v = {}
    for scenario, short in (("paper_metric_evaluation", "evaluation"), ("paper_metric_divergence", "divergence")):
        for pair in PAPER_METRIC_PAIRS:
            name = f"paper_metric/{scenario}_{pair}"
            rows = _consistency_table(r.log(name), r.out(f"{name}.log"))
            for metric, cells in rows.items():
                for column, text in cells.items():
                    v[f"paper_metric.{short}.{pair}.{metric}.{column}"] = text
    return v


def _check_source(name, scenario_path, seeds):
    def run(r):
        r.tofu_cmd(name, "check", scenario_path, "--seeds", seeds, "--jobs", r.jobs, "--quiet",
                   "--out", r.out(name), ok=(0, 1, 3))
    return run


PAPER_SEEDS = list(range(1, 11))
PAPER_METHODS = [("consensus", "consensus (threshold 0.3, priority leica > lio > vio)"),
                 ("naive", "naive: every sensor all the time, true frame transforms"),
                 ("single:vio@clean", "VIO alone, uncorrupted (`single:vio@clean`, the paper's reference)"),
                 ("single:vio", "VIO alone, corrupted (`single:vio`)")]


def extract_paper_consensus(r):
    s = seed_summaries(r.out("paper_consensus"), "paper_consensus_indoor", PAPER_SEEDS)
    v = {}
    for method, _ in PAPER_METHODS:
        m = s[1]["methods"][method]
        key = "paper_consensus.seed1." + method
        v[key + ".ate_m"] = sig(m["ate_m"], 3)
        rot = m["rotation_rmse_deg"]
        v[key + ".rot_deg"] = sig(rot, 2) if rot < 10 else fixed(rot, 1)
        v[key + ".nees"] = sci(m["nees_position_mean"], 2)
    for group in (PAPER_SEEDS[:5], PAPER_SEEDS[5:]):
        g = f"paper_consensus.seeds{group[0]}_{group[-1]}."
        cons = [s[i]["methods"]["consensus"]["ate_m"] for i in group]
        naive = [s[i]["methods"]["naive"]["ate_m"] for i in group]
        clean = [s[i]["methods"]["single:vio@clean"]["ate_m"] for i in group]
        v[g + "consensus"] = " ".join(sig(x, 2) for x in cons)
        v[g + "naive"] = " ".join(sig(x, 3) for x in naive)
        v[g + "clean_vio"] = " ".join(sig(x, 2) for x in clean)
        v[g + "over_naive"] = span([c / n for c, n in zip(cons, naive)], lambda x: fixed(100 * x, 1)) + " %"
        v[g + "over_clean"] = span([c / n for c, n in zip(cons, clean)], lambda x: fixed(x, 2))
    cons = {i: s[i]["methods"]["consensus"] for i in PAPER_SEEDS}
    v["paper_consensus.over_naive"] = span(
        [cons[i]["ate_m"] / s[i]["methods"]["naive"]["ate_m"] for i in PAPER_SEEDS],
        lambda x: fixed(100 * x, 1)) + " %"
    v["paper_consensus.over_clean"] = span(
        [cons[i]["ate_m"] / s[i]["methods"]["single:vio@clean"]["ate_m"] for i in PAPER_SEEDS],
        lambda x: fixed(x, 2))
    v["paper_consensus.rot_deg"] = span([cons[i]["rotation_rmse_deg"] for i in PAPER_SEEDS],
                                        lambda x: fixed(x, 2))
    v["paper_consensus.nees"] = span([cons[i]["nees_position_mean"] for i in PAPER_SEEDS],
                                     lambda x: fixed(x, 2))
    for fault in ("divergence", "non_gaussian_noise"):
        delays = [d["delay_s"] for i in PAPER_SEEDS for d in cons[i]["detections"]
                  if d["fault"] == fault]
        if any(d is None for d in delays):
            v[f"paper_consensus.detection.{fault}"] = "missed in some seed"
        else:
            v[f"paper_consensus.detection.{fault}"] = span(delays, lambda x: fixed(x, 1)) + " s"
    v["paper_consensus.false_exclusion_max_s"] = fixed(
        max(max(cons[i]["false_exclusion_s"].values()) for i in PAPER_SEEDS), 1)
    v["paper_consensus.false_exclusion"] = span(
        [cons[i]["false_exclusion_fraction"] for i in PAPER_SEEDS], lambda x: fixed(100 * x, 1)) + " %"
    seed1 = cons[1]
    v["paper_consensus.seed1.ate_cm"] = fixed(100 * seed1["ate_m"], 1)
    v["paper_consensus.seed1.clean_vio_ate_cm"] = fixed(
        100 * s[1]["methods"]["single:vio@clean"]["ate_m"], 1)
    v["paper_consensus.seed1.naive_ate_m"] = fixed(s[1]["methods"]["naive"]["ate_m"], 1)
    v["paper_consensus.seed1.max_detection_s"] = fixed(detection_delay(seed1), 1)
    v["paper_consensus.passed"] = f"{sum(1 for i in PAPER_SEEDS if s[i]['passed'])} of {len(PAPER_SEEDS)}"
    return v


CLOSED_LOOP_SEEDS = list(range(1, 11))


def _naive_hit(check_dir, scenario, seed):
    summary = load_json(check_dir / scenario / f"seed_{seed}" / "closed_loop" / "naive" / "summary.json")
    geoms = []
    for c in summary["collisions"]:
        if c["structure_geom"] not in geoms:
            geoms.append(c["structure_geom"])
    text = ", ".join(geoms) if geoms else "-"
    if summary.get("failure"):
        at = re.search(r"at t = ([0-9.]+) s", summary["failure"])
        text += "; simulation failed" + (f" at {float(at.group(1)):.1f} s" if at else "")
    for event in (summary.get("closed_loop_flight") or {}).get("events", []):
        if event["event"] == "ended_after_collision":
            text += f"; flight ended at {event['t_s']:.1f} s (physics broke after the crash)"
    return text


def _closed_loop_values(r, name, scenario, window_nth, open_loop_methods, check_dir=None):
    """Per seed and over seeds: the flights on consensus and on naive fusion (summary.json
    closed_loop), the open-loop ATE of open_loop_methods; "RMSE in window": the
    window_nth expectation on closed_loop.consensus.tracking_rmse_m (its window). Keys
    under `name.`; the run in check_dir (default <runs>/<name>)."""
    check_dir = check_dir or r.out(name)
    s = seed_summaries(check_dir, scenario, CLOSED_LOOP_SEEDS)
    v = {}
    k = f"{name}."
    for i in CLOSED_LOOP_SEEDS:
        cl = s[i]["closed_loop"]
        c, n = cl["consensus"], cl["naive"]
        key = f"{k}seed{i}."
        v[key + "consensus_rmse_m"] = fixed(c["tracking_rmse_m"], 3)
        v[key + "consensus_max_m"] = fixed(c["tracking_max_m"], 3)
        v[key + "consensus_window_rmse_m"] = fixed(
            expectation(s[i], "closed_loop.consensus.tracking_rmse_m", window_nth), 3)
        v[key + "consensus_hits"] = str(c["collisions"])
        v[key + "consensus_dist_m"] = fixed(c["min_structure_distance_m"], 2)
        v[key + "naive_rmse_m"] = fixed(n["tracking_rmse_m"], 3)
        v[key + "naive_over_consensus"] = fixed(n["tracking_rmse_m"] / c["tracking_rmse_m"], 2)
        v[key + "naive_hits"] = str(n["collisions"])
        v[key + "naive_first_hit_s"] = fixed(n["time_to_first_collision_s"], 1)
        v[key + "naive_hit"] = _naive_hit(check_dir, scenario, i)
        v[key + "naive_diverged"] = "yes" if n["diverged"] else "no"
        v[key + "open_loop_ate"] = " / ".join(fixed(s[i]["methods"][m]["ate_m"], 3)
                                              for m in open_loop_methods)
    groups = {"1_5": CLOSED_LOOP_SEEDS[:5], "6_10": CLOSED_LOOP_SEEDS[5:], "1_10": CLOSED_LOOP_SEEDS}
    for group, seeds in groups.items():
        cl = [s[i]["closed_loop"] for i in seeds if i in s]
        if not cl:
            continue
        v[f"{k}seeds{group}.naive_over_consensus"] = span(
            [x["naive"]["tracking_rmse_m"] / x["consensus"]["tracking_rmse_m"] for x in cl],
            lambda x: f"{x:.0f}") + "x"
        v[f"{k}seeds{group}.consensus_rmse_m"] = span(
            [x["consensus"]["tracking_rmse_m"] for x in cl], lambda x: fixed(x, 3)) + " m"
        v[f"{k}seeds{group}.consensus_rmse_cm"] = span(
            [x["consensus"]["tracking_rmse_m"] for x in cl], lambda x: fixed(100 * x, 1)) + " cm"
        window = [expectation(s[i], "closed_loop.consensus.tracking_rmse_m", window_nth) for i in seeds]
        v[f"{k}seeds{group}.consensus_window_rmse_m"] = span(window, lambda x: fixed(x, 3)) + " m"
        v[f"{k}seeds{group}.consensus_window_rmse_cm"] = span(window, lambda x: fixed(100 * x, 1)) + " cm"
        v[f"{k}seeds{group}.naive_over_consensus_ratio"] = span(
            [x["naive"]["tracking_rmse_m"] / x["consensus"]["tracking_rmse_m"] for x in cl],
            lambda x: fixed(x, 2)) + "x"
        v[f"{k}seeds{group}.naive_worse"] = (
            f"{sum(1 for x in cl if x['naive']['tracking_rmse_m'] > x['consensus']['tracking_rmse_m'])}"
            f" of {len(cl)}")
        for method in open_loop_methods:
            v[f"{k}seeds{group}.open_loop_ate_m.{method}"] = span(
                [s[i]["methods"][method]["ate_m"] for i in seeds], lambda x: fixed(x, 3)) + " m"
    cl = [s[i]["closed_loop"] for i in CLOSED_LOOP_SEEDS]
    v[k + "consensus_rmse_cm"] = span([x["consensus"]["tracking_rmse_m"] for x in cl],
                                      lambda x: fixed(100 * x, 1)) + " cm"
    v[k + "consensus_min_dist_m"] = fixed(min(x["consensus"]["min_structure_distance_m"] for x in cl), 2)
    v[k + "consensus_dist_cm"] = span([x["consensus"]["min_structure_distance_m"] for x in cl],
                                      lambda x: f"{100 * x:.0f}") + " cm"
    window = [expectation(s[i], "closed_loop.consensus.tracking_rmse_m", window_nth) for i in CLOSED_LOOP_SEEDS]
    v[k + "window_rmse_above_5cm"] = f"{sum(1 for x in window if x > 0.05)} of {len(window)}"
    v[k + "naive_first_hit_s"] = span([x["naive"]["time_to_first_collision_s"] for x in cl],
                                      lambda x: fixed(x, 1)) + " s"
    v[k + "naive_hit_seeds"] = f"{sum(1 for x in cl if x['naive']['collisions'] > 0)} of {len(cl)}"
    v[k + "detection_s"] = span([detection_delay(s[i]["methods"]["consensus"])
                                 for i in CLOSED_LOOP_SEEDS], lambda x: fixed(x, 1)) + " s"
    v[k + "passed"] = f"{sum(1 for i in CLOSED_LOOP_SEEDS if s[i]['passed'])} of {len(CLOSED_LOOP_SEEDS)}"
    return s, v


def extract_closed_loop_wall(r):
    s, v = _closed_loop_values(r, "closed_loop_wall", "closed_loop_vio_divergence_wall", 0,
                               ["consensus", "naive"])
    one = s[1]
    k = "closed_loop_wall."
    v[k + "seed1.consensus_rmse_cm"] = fixed(100 * one["closed_loop"]["consensus"]["tracking_rmse_m"], 1)
    v[k + "seed1.naive_first_hit_s"] = fixed(one["closed_loop"]["naive"]["time_to_first_collision_s"], 1)
    v[k + "seed1.naive_min_dist_m"] = fixed(one["closed_loop"]["naive"]["min_structure_distance_m"], 2)
    v[k + "seed1.naive_over_consensus"] = sig(one["closed_loop"]["naive"]["tracking_rmse_m"] /
                                              one["closed_loop"]["consensus"]["tracking_rmse_m"], 2)
    v[k + "seed1.detection_s"] = fixed(detection_delay(one["methods"]["consensus"]), 1)
    cl = [s[i]["closed_loop"] for i in CLOSED_LOOP_SEEDS]
    v[k + "naive_min_dist_m"] = span([x["naive"]["min_structure_distance_m"] for x in cl],
                                     lambda x: fixed(x, 2)) + " m"
    return v


def extract_closed_loop_corridor(r):
    s, v = _closed_loop_values(r, "closed_loop_corridor", "closed_loop_corridor_occlusion", 1,
                               ["consensus", "naive"])
    for i in CLOSED_LOOP_SEEDS:
        leica = s[i]["closed_loop"]["single:leica"]
        events = {e["event"]: e["t_s"] for e in reversed(leica["events"])}  # the first of each
        key = f"closed_loop_corridor.seed{i}.leica_"
        v[key + "failsafe_s"] = fixed(events.get("failsafe_start"), 1)
        v[key + "landed_s"] = fixed(events.get("landed"), 1)
        v[key + "rmse_m"] = fixed(leica["tracking_rmse_m"], 2)
        v[key + "hits"] = str(leica["collisions"])
    leica = [s[i]["closed_loop"]["single:leica"] for i in CLOSED_LOOP_SEEDS]
    firsts = [{e["event"]: e["t_s"] for e in reversed(x["events"])} for x in leica]
    v["closed_loop_corridor.leica_failsafe_s"] = span([f.get("failsafe_start") for f in firsts],
                                                      lambda x: fixed(x, 1)) + " s"
    v["closed_loop_corridor.leica_landed_s"] = span([f.get("landed") for f in firsts],
                                                    lambda x: fixed(x, 1)) + " s"
    v["closed_loop_corridor.leica_hits"] = str(sum(x["collisions"] for x in leica))
    return v


def extract_closed_loop_window(r):
    _, v = _closed_loop_values(r, "closed_loop_window", "closed_loop_indoor_outdoor_window", 1,
                               ["consensus", "naive", "single:vio"])
    return v


# The three closed-loop scenarios with `position_factors: offset`: (short name, scenario,
# window expectation's index, open-loop methods), as their own sources extract them.
CLOSED_LOOP_OFFSET = (("wall", "closed_loop_vio_divergence_wall", 0, ["consensus", "naive"]),
                      ("corridor", "closed_loop_corridor_occlusion", 1, ["consensus", "naive"]),
                      ("window", "closed_loop_indoor_outdoor_window", 1, ["consensus", "naive", "single:vio"]))


def run_closed_loop_offset(r):
    d = r.out("closed_loop_offset", "scenarios")
    d.mkdir(parents=True, exist_ok=True)
    for short, scenario, _, _ in CLOSED_LOOP_OFFSET:
        where = f"scenarios/{scenario}.yaml"
        path = d / f"{scenario}.yaml"
        path.write_text(_with_estimation_key((r.root / where).read_text(), "position_factors", "offset", where))
        r.tofu_cmd(f"closed_loop_offset_{short}", "check", path, "--seeds", len(CLOSED_LOOP_SEEDS),
                   "--jobs", r.jobs, "--quiet", "--out", r.out("closed_loop_offset", short), ok=(0, 1, 3))


def extract_closed_loop_offset(r):
    v = {}
    for short, scenario, window_nth, methods in CLOSED_LOOP_OFFSET:
        _, values = _closed_loop_values(r, f"closed_loop_offset_{short}", scenario, window_nth, methods,
                                        check_dir=r.out("closed_loop_offset", short))
        v.update(values)
    return v


CLIENT_SEEDS = list(range(1, 11))
CLIENT_GROUPS = {"1_5": CLIENT_SEEDS[:5], "6_10": CLIENT_SEEDS[5:]}


def extract_clients(r):
    """scenarios/clients: the user's method (EKF, plug-in) beside consensus and flown on,
    and the user's controller; millimetres unless stated."""
    v = {}
    mm = lambda digits: (lambda x: fixed(1000 * x, digits))  # noqa: E731
    s = {name: seed_summaries(r.out("clients"), name, CLIENT_SEEDS)
         for name in ("python_ekf_wall", "cpp_plugin_filter", "python_controller")}

    def vio_delay(method):
        delays = [d["delay_s"] for d in method.get("detections", [])
                  if d["sensor"] == "vio" and d["fault"] == "divergence"]
        return delays[0] if delays and delays[0] is not None else math.inf

    for group, seeds in CLIENT_GROUPS.items():
        ekf = [s["python_ekf_wall"][i] for i in seeds]
        k = f"clients.python_ekf_wall.seeds{group}."
        m = [x["methods"]["external:python_ekf"] for x in ekf]
        cl = [x["closed_loop"]["external:python_ekf"] for x in ekf]
        v[k + "ate_mm"] = span([x["ate_m"] for x in m], mm(2))
        v[k + "rot_deg"] = span([x["rotation_rmse_deg"] for x in m], lambda x: fixed(x, 2))
        v[k + "nees"] = span([x["nees_position_mean"] for x in m], lambda x: fixed(x, 2))
        v[k + "vio_detection_s"] = span([vio_delay(x) for x in m], lambda x: fixed(x, 2))
        v[k + "consensus_ate_mm"] = span([x["methods"]["consensus"]["ate_m"] for x in ekf], mm(1))
        v[k + "closed_loop_mm"] = (span([x["tracking_rmse_m"] for x in cl], mm(1)) + " / " +
                                   span([x["tracking_max_m"] for x in cl], mm(1)))
        v[k + "nearest_m"] = span([x["min_structure_distance_m"] for x in cl], lambda x: fixed(x, 3))

        plug = [s["cpp_plugin_filter"][i] for i in seeds]
        k = f"clients.cpp_plugin_filter.seeds{group}."
        m = [x["methods"]["plugin:complementary"] for x in plug]
        cl = [x["closed_loop"]["plugin:complementary"] for x in plug]
        v[k + "ate_mm"] = span([x["ate_m"] for x in m], mm(2))
        v[k + "rot_deg"] = span([x["rotation_rmse_deg"] for x in m], lambda x: fixed(x, 2))
        v[k + "nees"] = span([x["nees_position_mean"] for x in m], lambda x: fixed(x, 2))
        v[k + "consensus_ate_mm"] = span([x["methods"]["consensus"]["ate_m"] for x in plug], mm(1))
        v[k + "closed_loop_mm"] = (span([x["tracking_rmse_m"] for x in cl], mm(1)) + " / " +
                                   span([x["tracking_max_m"] for x in cl], mm(1)))
        v[k + "failsafe_events"] = span([x["failsafe_events"] for x in cl], lambda x: f"{x:.0f}")

        ctl = [s["python_controller"][i] for i in seeds]
        k = f"clients.python_controller.seeds{group}."
        cl = [x["closed_loop"]["consensus"] for x in ctl]
        v[k + "truth_tracking_mm"] = span([x["metrics"]["tracking.position_rmse_m"] for x in ctl], mm(2))
        v[k + "closed_loop_mm"] = (span([x["tracking_rmse_m"] for x in cl], mm(1)) + " / " +
                                   span([x["tracking_max_m"] for x in cl], mm(1)))
        v[k + "estimate_mm"] = span([x["estimate_ate_m"] for x in cl], mm(1))
        v[k + "collisions"] = str(int(sum(x["metrics"]["collisions.count"] for x in ctl) +
                                      sum(c["collisions"] for c in cl)))
    ekf = list(s["python_ekf_wall"].values())
    v["clients.python_ekf_wall.consensus_over_ekf"] = span(
        [x["methods"]["consensus"]["ate_m"] / x["methods"]["external:python_ekf"]["ate_m"] for x in ekf],
        lambda x: fixed(x, 1)) + "x"
    v["clients.python_ekf_wall.rot_max_deg"] = fixed(
        max(x["methods"]["external:python_ekf"]["rotation_rmse_deg"] for x in ekf), 1)
    v["clients.python_ekf_wall.vio_detection_s"] = span(
        [vio_delay(x["methods"]["external:python_ekf"]) for x in ekf], lambda x: fixed(x, 1)) + " s"
    v["clients.python_ekf_wall.consensus_vio_detection_s"] = span(
        [vio_delay(x["methods"]["consensus"]) for x in ekf], lambda x: fixed(x, 1)) + " s"
    v["clients.python_ekf_wall.nees"] = span(
        [x["methods"]["external:python_ekf"]["nees_position_mean"] for x in ekf], lambda x: fixed(x, 1))
    ctl = [x["closed_loop"]["consensus"] for x in s["python_controller"].values()]
    v["clients.python_controller.tracking_minus_estimate_mm"] = span(
        [x["tracking_rmse_m"] - x["estimate_ate_m"] for x in ctl], mm(1))
    runs = [x for name in s for x in s[name].values()]
    v["clients.passed"] = f"{sum(1 for x in runs if x['passed'])} of {len(runs)}"
    return v


SUITE_SEEDS = list(range(1, 11))


# ---- delays scored honestly: a missed fault and a sensor never re-admitted are infinite ----
# summary.json writes an infinite delay as null (JSON has no infinity), as it writes a delay
# with nothing to measure: the detections say which (as harness/check_methods.cc reads them).

def missed(meth):
    """A fault of the run the method never excluded its sensor for."""
    return meth.get("faults_detected", 0) < meth.get("faults", 0)


def never_readmitted(meth):
    """A detected fault that ended before the run did, its sensor never trusted again
    (meth["_run_end_s"]: the run's simulated_s)."""
    return any(d.get("detected") and d.get("readmission_delay_s") is None
               and d.get("end_s") is not None and d["end_s"] < meth["_run_end_s"] - 1e-6
               for d in meth.get("detections", []))


def detection_delay(meth):
    """One run's worst detection delay, infinite when a fault was missed."""
    return math.inf if missed(meth) else meth.get("max_detection_delay_s")


def worst_delay(methods, metric, infinite_when):
    """The worst `metric` over one method's summaries (one per seed): infinity when a seed
    has `infinite_when` (missed, never_readmitted), None when no seed has a value."""
    values = []
    for meth in methods:
        if infinite_when(meth):
            return math.inf
        if meth.get(metric) is not None:
            values.append(meth[metric])
    return max(values) if values else None


def delay_text(delay):
    return "-" if delay is None else ("inf" if math.isinf(delay) else f"{delay:.1f}")


def _suite_scenarios(root):
    return sorted(p.stem for p in (root / "scenarios/suite").glob("*.yaml"))


def extract_suite(r):
    v = {}
    for scenario in _suite_scenarios(r.root):
        s = seed_summaries(r.out("suite"), scenario, SUITE_SEEDS)
        m = {i: s[i]["methods"] for i in SUITE_SEEDS}
        key = f"suite.{scenario}."
        for i in SUITE_SEEDS:  # as harness/check_methods.cc: a fault ending before the run did
            for meth in m[i].values():
                meth["_run_end_s"] = s[i]["simulated_s"]
        for i in SUITE_SEEDS:
            failed = [e for e in s[i]["expectations"] if not e["passed"]]
            v[f"{key}seed{i}.failed"] = "; ".join(
                f"{e['metric']}" + (f" / {e['relative_to']}" if e.get("relative_to") else "") +
                f" {sig(e['value'], 3) if e['value'] is not None else 'none'}"
                f" (bound {'≥ ' + sig(e['min'], 3) if e['min'] is not None else ''}"
                f"{', ' if e['min'] is not None and e['max'] is not None else ''}"
                f"{'≤ ' + sig(e['max'], 3) if e['max'] is not None else ''})" for e in failed)
        key = f"suite.{scenario}."

        def values(method, metric, seeds=SUITE_SEEDS):
            return [m[i][method].get(metric) for i in seeds]

        def med(xs):
            xs = [x for x in xs if x is not None]
            return statistics.median(xs) if xs else None

        def worst(xs, missing=None):
            if any(x is None for x in xs):
                return missing
            return max(xs)

        passed = sum(1 for i in SUITE_SEEDS if s[i]["passed"])
        v[key + "passed"] = f"{passed}/{len(SUITE_SEEDS)}"
        ate = values("consensus", "ate_m")
        v[key + "consensus_ate"] = f"{sig(med(ate), 3)} / {sig(max(ate), 3)}"
        cs = values("consensus:consistent_set", "ate_m")
        oracle = values("oracle", "ate_m")
        cs_over = [c / o for c, o in zip(cs, oracle)]
        v[key + "cs_ate"] = (f"{sig(med(cs), 3)} / {sig(max(cs), 3)} "
                             f"({fixed(med(cs_over), 2)} / {fixed(max(cs_over), 2)})")
        v[key + "oracle_ate"] = sig(med(oracle), 3)
        singles = sorted(meth for meth in m[1] if meth.startswith("single:") and meth.endswith("@clean"))
        best = min(singles, key=lambda meth: med(values(meth, "ate_m")))
        best_ate = values(best, "ate_m")
        v[key + "best_single"] = f"{best[len('single:'):-len('@clean')]} {sig(med(best_ate), 3)}"
        v[key + "oracle_over_best"] = fixed(med([o / b for o, b in zip(oracle, best_ate)]), 2)
        for method, name in (("consensus", "c"), ("consensus:consistent_set", "cs")):
            meth = lambda i: m[i][method]  # noqa: E731
            v[f"{key}{name}.detection_worst_s"] = delay_text(
                worst_delay([meth(i) for i in SUITE_SEEDS], "max_detection_delay_s", missed))
            v[f"{key}{name}.readmission_worst_s"] = delay_text(
                worst_delay([meth(i) for i in SUITE_SEEDS], "max_readmission_delay_s", never_readmitted))
            v[f"{key}{name}.false_exclusion_worst"] = percent(max(meth(i)["false_exclusion_fraction"] for i in SUITE_SEEDS))
            v[f"{key}{name}.nees_median"] = sci(med([meth(i)["nees_position_mean"] for i in SUITE_SEEDS]), 2)
            v[f"{key}{name}.rotation_over_oracle"] = fixed(med(
                [meth(i)["rotation_rmse_deg"] / m[i]["oracle"]["rotation_rmse_deg"] for i in SUITE_SEEDS]), 2)
    return v


# ---- tofu compare, calibrated ------------------------------------------------------------
# On the suite's own check (the suite source's command, reused with --reuse): a check
# against itself; three splits of its ten seeds into disjoint halves compared as
# independent samples (A/A, every cell a null); an injected regression; a method known to
# be worse; and the seeds a 10 % ATE regression needs at 80 % power, paired and unpaired.
CALIBRATION_SPLITS = {"1-5 vs 6-10": ([1, 2, 3, 4, 5], [6, 7, 8, 9, 10]),
                      "odd vs even": ([1, 3, 5, 7, 9], [2, 4, 6, 8, 10]),
                      "1,2,5,6,9 vs 3,4,7,8,10": ([1, 2, 5, 6, 9], [3, 4, 7, 8, 10])}
CALIBRATION_FDR = 0.05  # tofu compare's default --fdr; for one cell alone, its test's level
INJECTED_FACTOR = 1.2   # consensus ATE x this in every seed of one scenario at a time
DEGRADED_STD_M = 0.012  # consensus re-estimated with the pose sensors' between-position std
                        # x1.2 (default 0.01 m, no suite scenario sets it): a real degradation
POWER_RATIO = 1.10      # the regression to detect: ATE x 1.10 (a ratio)
POWER_MINIMAL_FRACTION = 0.05  # ATE's minimal effect, 5 % (campaign/compared_metrics.cc)
POWER_TRIALS = 2000
# Seed counts tried, smallest first: exact tests up to 40 seeds, the normal approximation
# (scipy's asymptotic mode, tie-free draws) beyond.
POWER_SEEDS = list(range(3, 41)) + [50, 60, 80, 100, 130, 160, 200]
POWER_EXACT_MAX = 40


def _suite_check(r):
    # The suite source's command itself: with --reuse both read one check.
    r.tofu_cmd("suite", "check", "scenarios/suite", "--seeds", 10, "--jobs", r.jobs, "--quiet",
               "--out", r.out("suite"), ok=(0, 1, 3))


def _baseline_subset(baseline, seeds, path):
    subset = dict(baseline)
    subset["cells"] = [c for c in baseline["cells"] if c["seed"] in seeds]
    path.write_text(json.dumps(subset, indent=1) + "\n")


def run_compare_calibration(r):
    _suite_check(r)
    out = r.out("compare_calibration")
    out.mkdir(parents=True, exist_ok=True)
    whole = out / "suite.json"
    r.tofu_cmd("compare_calibration/baseline", "baseline", r.out("suite"), "--out", whole, "--quiet")
    r.tofu_cmd("compare_calibration/same", "compare", r.out("suite"), r.out("suite"), "--quiet",
               "--json", out / "same.json", ok=(0, 1))
    baseline = load_json(whole)
    for i, (name, (a, b)) in enumerate(CALIBRATION_SPLITS.items()):
        _baseline_subset(baseline, a, out / f"split{i}_a.json")
        _baseline_subset(baseline, b, out / f"split{i}_b.json")
        r.tofu_cmd(f"compare_calibration/split{i}", "compare", out / f"split{i}_a.json",
                   out / f"split{i}_b.json", "--unpaired", "--quiet", "--json",
                   out / f"split{i}.json", ok=(0, 1))
    for scenario in _suite_scenarios(r.root):
        injected = json.loads(json.dumps(baseline))
        for cell in injected["cells"]:
            if cell["scenario"] == scenario and "methods.consensus.ate_m" in cell["values"]:
                cell["values"]["methods.consensus.ate_m"] *= INJECTED_FACTOR
        (out / f"injected_{scenario}.json").write_text(json.dumps(injected, indent=1) + "\n")
        r.tofu_cmd(f"compare_calibration/injected_{scenario}", "compare", whole,
                   out / f"injected_{scenario}.json", "--quiet", "--json",
                   out / f"injected_{scenario}.out.json", ok=(0, 1))
    r.tofu_cmd("compare_calibration/naive", "compare", r.out("suite"), "--methods", "consensus",
               "naive", "--quiet", "--json", out / "naive.json", ok=(0, 1))
    r.script_cmd("compare_calibration/plot", "scripts/plot_compare.py", out / "naive.json", "--out",
                 r.root / "docs/images/compare_suite.png")
    # The degradation, on the very same samples: `tofu estimate` of each run's streams with
    # constant between weights (the recommended profile weights pose streams by their own
    # noise, which a between std does not apply to) at the nominal std and at x1.2.
    reference = _reestimated(r, baseline, out / "reference", "reference",
                             ["--set", "pose_between_noise=constant"])
    (out / "reference.json").write_text(json.dumps(reference, indent=1) + "\n")
    degraded = _reestimated(r, baseline, out / "degraded", "degraded",
                            ["--set", "pose_between_noise=constant",
                             "--between-position-std", DEGRADED_STD_M])
    (out / "degraded.json").write_text(json.dumps(degraded, indent=1) + "\n")
    r.tofu_cmd("compare_calibration/degraded", "compare", out / "reference.json",
               out / "degraded.json", "--quiet", "--json", out / "degraded.out.json", ok=(0, 1))


def _reestimated(r, baseline, where_root, name, settings):
    """The baseline's cells with consensus's figures from `tofu estimate` of each run."""
    cells = json.loads(json.dumps(baseline))
    for cell in cells["cells"]:
        scenario, seed = cell["scenario"], cell["seed"]
        where = where_root / scenario / f"seed_{seed}"
        r.tofu_cmd(f"compare_calibration/{name}/{scenario}_{seed}", "estimate",
                   r.out("suite", scenario, f"seed_{seed}"), "--method", "consensus",
                   *settings, "--out", where, "--quiet")
        ate = load_json(where / "estimate_consensus.json")["ate"]
        for key, field in (("ate_m", "position_rmse_m"), ("rotation_rmse_deg", "rotation_rmse_deg"),
                           ("rpe_m", "rpe_translation_rmse_m"),
                           ("position_step_max_m", "position_step_max_m")):
            cell["values"][f"methods.consensus.{key}"] = ate[field]
    return cells


def _verdicts(cells):
    counts = {v: 0 for v in ("regressed", "improved", "inconclusive", "unchanged")}
    for c in cells:
        counts[c["verdict"]] += 1
    return counts


def _exact_upper_critical(counts, alpha):
    """The smallest statistic value c with P(S >= c) <= alpha under the null whose counts
    (over the statistic's values 0, 1, ...) are given."""
    total = sum(counts)
    tail = 0
    for value in range(len(counts) - 1, -1, -1):
        if (tail + counts[value]) / total > alpha:
            return value + 1
        tail += counts[value]
    return 0


def _signed_rank_counts(n):
    """Null counts of the signed-rank statistic W+ over n untied pairs: the number of
    subsets of the ranks 1..n with each sum."""
    counts = [1] + [0] * (n * (n + 1) // 2)
    for rank in range(1, n + 1):
        for s in range(len(counts) - 1, rank - 1, -1):
            counts[s] += counts[s - rank]
    return counts


def _rank_sum_counts(m, n):
    """Null counts of the Mann-Whitney statistic U (pairs where the first sample is larger)
    for untied samples of sizes m and n."""
    # f[j][u]: arrangements of i items of the first sample and j of the second with U = u,
    # built up over i (the classic recursion f(i, j, u) = f(i-1, j, u-j) + f(i, j-1, u)).
    f = [[1] + [0] * (m * n) for _ in range(n + 1)]
    for _ in range(1, m + 1):
        g = [[0] * (m * n + 1) for _ in range(n + 1)]
        for j in range(n + 1):
            for u in range(m * n + 1):
                g[j][u] = (f[j][u - j] if u >= j else 0) + (g[j - 1][u] if j > 0 else 0)
        f = g
    return f[n]


def _power(sigma_between, sigma_within, paired, n, rng):
    """Share of POWER_TRIALS comparisons of n seeds (per side) that find an ATE x POWER_RATIO
    regression with tofu compare's verdict rule for one cell: the rank test shifted by the
    minimal effect, two-sided p (twice the one-sided) <= CALIBRATION_FDR. Draws are
    continuous (no ties), so the exact tests reduce to critical values of their null
    distributions (counted here; the normal approximation beyond POWER_EXACT_MAX seeds)."""
    import numpy
    alpha = CALIBRATION_FDR / 2
    shift = math.log(POWER_RATIO) - math.log1p(POWER_MINIMAL_FRACTION)
    z = 1.959963984540054  # the normal quantile of 1 - alpha
    if paired:
        if sigma_within == 0.0:  # every pair moves alike: the signed-rank floor
            return 1.0 if 0.5 ** n <= alpha else 0.0
        d = rng.normal(shift, sigma_within, (POWER_TRIALS, n))
        ranks = numpy.argsort(numpy.argsort(numpy.abs(d), axis=1), axis=1) + 1
        w = (ranks * (d > 0)).sum(axis=1)
        if n <= POWER_EXACT_MAX:
            critical = _exact_upper_critical(_signed_rank_counts(n), alpha)
        else:
            mean, sd = n * (n + 1) / 4, math.sqrt(n * (n + 1) * (2 * n + 1) / 24)
            critical = mean + z * sd
        return float((w >= critical).mean())
    base = rng.normal(0.0, sigma_between, (POWER_TRIALS, n))
    new = rng.normal(shift, math.hypot(sigma_between, sigma_within), (POWER_TRIALS, n))
    u = (new[:, :, None] > base[:, None, :]).sum(axis=(1, 2))
    if n <= POWER_EXACT_MAX:
        critical = _exact_upper_critical(_rank_sum_counts(n, n), alpha)
    else:
        mean, sd = n * n / 2, math.sqrt(n * n * (2 * n + 1) / 12)
        critical = mean + z * sd
    return float((u >= critical).mean())


def _seeds_for_power(sigma_between, sigma_within, paired, seed):
    import numpy
    rng = numpy.random.default_rng(seed)
    for n in POWER_SEEDS:
        if _power(sigma_between, sigma_within, paired, n, rng) >= 0.8:
            return n
    return None


def extract_compare_calibration(r):
    out = r.out("compare_calibration")
    v = {}
    same = load_json(out / "same.json")["cells"]
    counts = _verdicts(same)
    v["calibration.same.cells"] = str(len(same))
    for verdict, n in counts.items():
        v[f"calibration.same.{verdict}"] = str(n)
    total_tested = total_false = 0
    for i, name in enumerate(CALIBRATION_SPLITS):
        cells = load_json(out / f"split{i}.json")["cells"]
        counts = _verdicts(cells)
        false = counts["regressed"] + counts["improved"]
        tested = sum(1 for c in cells if not c.get("note"))
        total_tested += tested
        total_false += false
        v[f"calibration.split{i}.name"] = name
        v[f"calibration.split{i}.cells"] = str(len(cells))
        v[f"calibration.split{i}.tested"] = str(tested)
        for verdict, n in counts.items():
            v[f"calibration.split{i}.{verdict}"] = str(n)
        v[f"calibration.split{i}.false_rate"] = percent(false / tested, 2) if tested else "-"
    v["calibration.splits.tested"] = str(total_tested)
    v["calibration.splits.false"] = str(total_false)
    v["calibration.level"] = percent(CALIBRATION_FDR, 0)
    found = elsewhere = 0
    scenarios = _suite_scenarios(r.root)
    for scenario in scenarios:
        for c in load_json(out / f"injected_{scenario}.out.json")["cells"]:
            target = c["scenario"] == scenario and c["metric"] == "methods.<method>.ate_m" and \
                c["subject"] == "consensus"
            if target:
                found += c["verdict"] == "regressed"
            elif c["verdict"] != "unchanged":
                elsewhere += 1
    v["calibration.injected.factor"] = f"{INJECTED_FACTOR:g}"
    v["calibration.injected.found"] = f"{found}/{len(scenarios)}"
    v["calibration.injected.elsewhere"] = str(elsewhere)
    naive = [c for c in load_json(out / "naive.json")["cells"] if c["metric"] == "methods.<method>.ate_m"]
    v["calibration.naive.regressed"] = f"{sum(c['verdict'] == 'regressed' for c in naive)}/{len(naive)}"
    v["calibration.naive.effects"] = span([c["effect"] for c in naive], lambda x: f"×{sig(x, 3)}")

    degraded_cells = [c for c in load_json(out / "degraded.out.json")["cells"]
                      if c["metric"] == "methods.<method>.ate_m" and c["subject"] == "consensus"]
    v["calibration.degraded.std"] = f"{DEGRADED_STD_M:g}"
    v["calibration.degraded.found"] = (f"{sum(c['verdict'] == 'regressed' for c in degraded_cells)}"
                                       f"/{len(degraded_cells)}")
    v["calibration.degraded.effects"] = span([c["effect"] for c in degraded_cells],
                                             lambda x: f"×{sig(x, 3)}")
    v["calibration.degraded.other"] = str(sum(
        1 for c in load_json(out / "degraded.out.json")["cells"]
        if c["subject"] != "consensus" and c["verdict"] != "unchanged"))

    # The spreads a power analysis needs, measured per suite scenario on its ten seeds:
    # between seeds, of log consensus ATE (what an unpaired comparison must see through),
    # and within a seed, of log(degraded ATE / ATE), the degradation above on identical
    # samples (what a paired comparison sees), its median taken out.
    baseline = load_json(out / "suite.json")
    reference = load_json(out / "reference.json")
    degraded = load_json(out / "degraded.json")
    paired_n, unpaired_n = [], []
    for k, scenario in enumerate(scenarios):
        cells = [c for c in baseline["cells"] if c["scenario"] == scenario]
        logs = [math.log(c["values"]["methods.consensus.ate_m"]) for c in cells
                if "methods.consensus.ate_m" in c["values"]]
        same = [c for c in reference["cells"] if c["scenario"] == scenario]
        worse = {c["seed"]: c for c in degraded["cells"] if c["scenario"] == scenario}
        ratios = [math.log(worse[c["seed"]]["values"]["methods.consensus.ate_m"] /
                           c["values"]["methods.consensus.ate_m"]) for c in same
                  if "methods.consensus.ate_m" in c["values"]]
        sigma_between = statistics.stdev(logs)
        sigma_within = statistics.stdev(ratios) if len(ratios) > 1 else 0.0
        key = f"calibration.power.{scenario}."
        v[key + "sigma_between"] = fixed(sigma_between, 3)
        v[key + "sigma_within"] = fixed(sigma_within, 3)
        verdict = next(c["verdict"] for c in degraded_cells if c["scenario"] == scenario)
        v[key + "degraded_effect"] = f"×{sig(math.exp(statistics.median(ratios)), 3)} ({verdict})"
        p = _seeds_for_power(sigma_between, sigma_within, True, 52 + k)
        u = _seeds_for_power(sigma_between, sigma_within, False, 52 + k)
        v[key + "paired"] = f"> {POWER_SEEDS[-1]}" if p is None else str(p)
        v[key + "unpaired"] = f"> {POWER_SEEDS[-1]}" if u is None else str(u)
        paired_n.append(math.inf if p is None else p)
        unpaired_n.append(math.inf if u is None else u)
    def n_text(n):
        return f"> {POWER_SEEDS[-1]}" if math.isinf(n) else sig(n, 2)
    v["calibration.power.paired_median"] = n_text(statistics.median(paired_n))
    v["calibration.power.unpaired_median"] = n_text(statistics.median(unpaired_n))
    return v


# tofu search in the ARCH-COMP falsification style: each problem (searches/<problem>.yaml,
# a failure region known by construction) searched SEARCH_REPS times per optimiser, seeds
# 1..SEARCH_REPS, stopping at the first confirmed failure, at the spec's budget.
SEARCH_PROBLEMS = ["vio_divergence_near_wall", "station_occluded_gnss_outage", "slow_drift_below_threshold"]
SEARCH_OPTIMIZERS = ["random", "tpe"]
SEARCH_REPS = 10


def run_search_benchmark(r):
    for problem in SEARCH_PROBLEMS:
        for optimizer in SEARCH_OPTIMIZERS:
            for rep in range(1, SEARCH_REPS + 1):
                out = r.out("search_benchmark", problem, f"{optimizer}_{rep}")
                r.tofu_cmd(f"search_benchmark/{problem}/{optimizer}_{rep}", "search", f"searches/{problem}.yaml",
                           "--out", out, "--optimizer", optimizer, "--optimizer-seed", rep, "--jobs", r.jobs,
                           "--no-renders", "--quiet", ok=(0, 1), fresh=out)
    r.script_cmd("search_benchmark/plot", "scripts/plot_search.py", "--benchmark", r.out("search_benchmark"),
                 "--out", "docs/images/search_benchmark.png")


def _median_or_inf(values):
    """The median with None (no confirmed failure within the budget) as infinity."""
    return statistics.median([math.inf if v is None else v for v in values])


def extract_search_benchmark(r):
    v = {"search.reps": str(SEARCH_REPS)}
    all_medians = {}
    for problem in SEARCH_PROBLEMS:
        medians = {}
        spec_budget = None
        for optimizer in SEARCH_OPTIMIZERS:
            firsts, flights = [], []
            for rep in range(1, SEARCH_REPS + 1):
                search = load_json(r.out("search_benchmark", problem, f"{optimizer}_{rep}", "search.json"))
                spec_budget = search["budget"]
                firsts.append(search["simulations_to_first_confirmed"])
                flights.append(sum(search["simulations"].values()))
            found = [f for f in firsts if f is not None]
            median = _median_or_inf(firsts)
            medians[optimizer] = median
            k = f"search.{problem}.{optimizer}."
            v[k + "rate"] = f"{len(found)}/{len(firsts)}"
            v[k + "median"] = f"> {spec_budget}" if math.isinf(median) else f"{median:g}"
            v[k + "range"] = span(found, lambda x: str(x)) if found else "-"
            v[k + "flights"] = f"{statistics.median(flights):g}"
        v[f"search.{problem}.budget"] = str(spec_budget)
        all_medians[problem] = medians
        ratio = medians["random"] / medians["tpe"]
        v[f"search.{problem}.ratio"] = ("-" if math.isinf(medians["tpe"]) else
                                        f"> {sig(spec_budget / medians['tpe'], 2)}" if math.isinf(ratio) else
                                        sig(ratio, 2))
    # The issue's goals: >= 5x fewer simulations than random on two problems, never more.
    five_x = [p for p, m in all_medians.items() if m["tpe"] * 5 <= m["random"]]
    worse = [p for p, m in all_medians.items() if m["tpe"] > m["random"]]
    v["search.goal.five_x"] = f"{len(five_x)} of {len(all_medians)}"
    v["search.goal.worse"] = ", ".join(worse) if worse else "none"
    return v


NIS_SEEDS = list(range(1, 11))
NIS_THRESHOLD = 3.0  # chosen before the runs: healthy pairs sit at 0.5-2 (one seed looked at)
# cm: the paper's metric, as the scenario says; nis: the normalised one; nis_left_out: nis
# with the degenerate directions of a pose sensor left out of its between factors too
# (issue 34 item 3 whole: a degenerate direction neither votes nor is fused).
NIS_VARIANTS = ("cm", "nis", "nis_left_out")


def _write_suite_variants(r, source, variants, methods, edit, scenarios=None):
    """Each suite scenario (or those of `scenarios`) without its expectations, its methods
    list rewritten by `methods(text, where)`, once per variant as `edit(text, variant,
    where)` makes it, into <runs>/<source>/scenarios/<variant>/. Returns {variant: directory}."""
    dirs = {}
    for variant in variants:
        d = r.out(source, "scenarios", variant)
        d.mkdir(parents=True, exist_ok=True)
        dirs[variant] = d
    for scenario in scenarios if scenarios is not None else _suite_scenarios(r.root):
        where = f"scenarios/suite/{scenario}.yaml"
        text = methods((r.root / where).read_text(), where).split("\nexpect:")[0] + "\n"
        for variant, d in dirs.items():
            (d / f"{scenario}.yaml").write_text(edit(text, variant, where))
    return dirs


def _with_estimation_key(text, key, value, where):
    """The scenario `text` with `key: value` in its estimation block."""
    if f"{key}:" in text:
        raise ResultsError(f"{where}: states {key} already")
    out, count = re.subn(r"^  consensus: \{", f"  {key}: {value}\n  consensus: {{", text, flags=re.M)
    if count != 1:
        raise ResultsError(f"{where}: no single `  consensus: {{` line in its estimation block")
    return out


def _with_degenerate_directions(text, variant, where):
    """The scenario `text` with `degenerate_directions: variant` in its estimation block."""
    return _with_estimation_key(text, "degenerate_directions", variant, where)


def _consensus_and_oracle(text, where):
    """The scenario's methods list replaced by [consensus, oracle]."""
    return re.sub(r"  methods: \[[^\]]*\]", "  methods: [consensus, oracle]", text, flags=re.S)


def _run_variants(r, source, dirs, seeds):
    """`tofu check` of each variant's scenario directory into <runs>/<source>/<variant>."""
    for variant, d in dirs.items():
        r.tofu_cmd(f"{source}_{variant}", "check", str(d), "--seeds", len(seeds),
                   "--jobs", r.jobs, "--quiet", "--out", r.out(source, variant), ok=(0, 1, 3))


def _nis_variants(r):
    """The suite's scenarios with methods [consensus, oracle] and no expectations, once as
    written (cm, the paper's metric), once with `metric: nis` at NIS_THRESHOLD (a
    leave_threshold doubled as the cm one is) and once more with `degenerate_directions:
    left_out` as well."""
    def edit(text, variant, where):
        if variant == "cm":
            return text
        nis, count = re.subn(r"consensus: \{threshold: [0-9.]+",
                             f"consensus: {{metric: nis, threshold: {NIS_THRESHOLD:g}", text)
        if count != 1:
            raise ResultsError(f"{where}: no single `consensus: {{threshold: ...`")
        nis = re.sub(r"leave_threshold: [0-9.]+", f"leave_threshold: {2 * NIS_THRESHOLD:g}", nis)
        return nis if variant == "nis" else _with_degenerate_directions(nis, "left_out", where)

    return _write_suite_variants(r, "consensus_nis", NIS_VARIANTS, _consensus_and_oracle, edit)


def run_consensus_nis(r):
    _run_variants(r, "consensus_nis", _nis_variants(r), NIS_SEEDS)


def _selection_scores(r, source, variants, seeds):
    """Per suite scenario and variant of `source` (methods consensus and oracle): consensus
    × oracle ATE over seeds 1-5 and 6-10 (median / worst), both ATE medians, and consensus's
    detection, re-admission, false exclusion and switches."""
    v = {}
    for scenario in _suite_scenarios(r.root):
        for variant in variants:
            s = seed_summaries(r.out(source, variant), scenario, seeds)
            c = {i: s[i]["methods"]["consensus"] for i in seeds}
            o = {i: s[i]["methods"]["oracle"] for i in seeds}
            key = f"{source}.{scenario}.{variant}."
            for half, group in (("1_5", seeds[:5]), ("6_10", seeds[5:])):
                ratio = [c[i]["ate_m"] / o[i]["ate_m"] for i in group]
                v[f"{key}ratio_{half}"] = f"{fixed(statistics.median(ratio), 2)} / {fixed(max(ratio), 2)}"
            v[key + "consensus_ate"] = sig(statistics.median(c[i]["ate_m"] for i in seeds), 3)
            v[key + "oracle_ate"] = sig(statistics.median(o[i]["ate_m"] for i in seeds), 3)
            for i in seeds:
                c[i]["_run_end_s"] = s[i]["simulated_s"]
            methods = [c[i] for i in seeds]
            v[key + "detection_worst_s"] = delay_text(worst_delay(methods, "max_detection_delay_s", missed))
            v[key + "readmission_worst_s"] = delay_text(
                worst_delay(methods, "max_readmission_delay_s", never_readmitted))
            v[key + "false_exclusion_worst"] = percent(max(c[i]["false_exclusion_fraction"] for i in seeds))
            v[key + "switches_median"] = f"{statistics.median(c[i]['switches'] for i in seeds):g}"
    return v


def extract_consensus_nis(r):
    return _selection_scores(r, "consensus_nis", NIS_VARIANTS, NIS_SEEDS)


LEVEL_SEEDS = list(range(1, 11))
# Above the local estimate's rms tilt error (0.27-0.34° for consensus and oracle on
# gnss_facade_rtk_loss seed 2, estimate_*.json tilt_error), below the 0.5° an alignment
# must be known to before it is fused; chosen before the runs.
LEVEL_PRIOR_DEG = 0.35
LEVEL_VARIANTS = ("paper", "level")


def _level_variants(r):
    """The suite's scenarios with methods [consensus, oracle] and no expectations, as
    written (the paper's 6-DoF alignments) and with `alignment_level_prior_deg`."""
    def edit(text, variant, where):
        if variant == "paper":
            return text
        return _with_estimation_key(text, "alignment_level_prior_deg", f"{LEVEL_PRIOR_DEG:g}", where)

    return _write_suite_variants(r, "level_alignment", LEVEL_VARIANTS, _consensus_and_oracle, edit)


def run_level_alignment(r):
    _run_variants(r, "level_alignment", _level_variants(r), LEVEL_SEEDS)


def extract_level_alignment(r):
    return _selection_scores(r, "level_alignment", LEVEL_VARIANTS, LEVEL_SEEDS)


BIAS_SEEDS = list(range(1, 11))
# The bias test's window and its mean's floor (consistency.h MeanDifferenceOptions), both
# chosen before the runs; the floor of 3 mm/s is run beside it to show the trade.
BIAS_WINDOW_S = 10
BIAS_VARIANTS = ("paper", "bias", "bias_floor3", "nis_bias")
BIAS_FLOOR_MPS = {"bias": 0.001, "bias_floor3": 0.003, "nis_bias": 0.001}


def _bias_variants(r):
    """The suite's scenarios with methods [consensus, oracle] and no expectations, as
    written (the paper's window metric alone), with the bias test at two floors, and with
    it beside `metric: nis` (consensus_nis's threshold), whose pairs with a GNSS are below
    their threshold when healthy and so are tested too."""
    def edit(text, variant, where):
        if variant == "paper":
            return text
        if variant == "nis_bias":
            text, count = re.subn(r"consensus: \{threshold: [0-9.]+",
                                  f"consensus: {{metric: nis, threshold: {NIS_THRESHOLD:g}", text)
            if count != 1:
                raise ResultsError(f"{where}: no single `consensus: {{threshold: ...`")
            text = re.sub(r"leave_threshold: [0-9.]+", f"leave_threshold: {2 * NIS_THRESHOLD:g}", text)
        out, count = re.subn(r"^  consensus: \{",
                             f"  consensus: {{bias_window_s: {BIAS_WINDOW_S}, "
                             f"bias_floor_mps: {BIAS_FLOOR_MPS[variant]:g}, ", text, flags=re.M)
        if count != 1:
            raise ResultsError(f"{where}: no single `  consensus: {{` line in its estimation block")
        return out

    return _write_suite_variants(r, "bias_test", BIAS_VARIANTS, _consensus_and_oracle, edit)


def run_bias_test(r):
    _run_variants(r, "bias_test", _bias_variants(r), BIAS_SEEDS)


def extract_bias_test(r):
    """_selection_scores, and consensus × oracle over all ten seeds (median / worst)."""
    v = _selection_scores(r, "bias_test", BIAS_VARIANTS, BIAS_SEEDS)
    for scenario in _suite_scenarios(r.root):
        for variant in BIAS_VARIANTS:
            s = seed_summaries(r.out("bias_test", variant), scenario, BIAS_SEEDS)
            ratio = [s[i]["methods"]["consensus"]["ate_m"] / s[i]["methods"]["oracle"]["ate_m"]
                     for i in BIAS_SEEDS]
            v[f"bias_test.{scenario}.{variant}.ratio_1_10"] = \
                f"{fixed(statistics.median(ratio), 2)} / {fixed(max(ratio), 2)}"
    return v


FACTOR_SEEDS = list(range(1, 11))
FACTOR_VARIANTS = ("between", "absolute")


def _factor_methods(text, where):
    """The scenario's methods without naive and consensus:consistent_set (the comparison
    is of consensus's default fusion, the oracle and each sensor alone)."""
    found = re.search(r"  methods: \[([^\]]*)\]", text, flags=re.S)
    if not found:
        raise ResultsError(f"{where}: no `methods: [...]` in its estimation block")
    methods = [m.strip().strip('"') for m in found.group(1).replace("\n", " ").split(",")]
    kept = [m for m in methods if m and m not in ("naive", "consensus:consistent_set")]
    return text[:found.start()] + "  methods: [" + ", ".join(f'"{m}"' for m in kept) + "]" + \
        text[found.end():]


def _factor_variants(r, variants=FACTOR_VARIANTS, source="position_factors"):
    """The suite's scenarios without expectations, with `position_factors: VARIANT` for each
    of `variants`: between (the paper's displacements between keyframes, the default),
    absolute (unary factors through each sensor's T_AL), offset (unary factors up to an
    offset per chain that the local graph estimates)."""
    def edit(text, variant, where):
        return _with_estimation_key(text, "position_factors", variant, where)

    return _write_suite_variants(r, source, variants, _factor_methods, edit)


def run_position_factors(r):
    _run_variants(r, "position_factors", _factor_variants(r), FACTOR_SEEDS)


def extract_position_factors(r):
    v = {}
    for variant in FACTOR_VARIANTS:
        v.update(_factor_scores(r, "position_factors", variant))
    return v


def run_position_offset(r):
    dirs = _factor_variants(r, ("offset",), "position_offset")
    _run_variants(r, "position_offset", dirs, FACTOR_SEEDS)


def extract_position_offset(r):
    return _factor_scores(r, "position_offset", "offset")


POSE_NOISE_VARIANTS = ("white_and_drift", "white_and_drift_offset")


def run_pose_noise(r):
    """The suite's scenarios as for position_factors, with `pose_between_noise:
    white_and_drift` (pose streams' between factors from their own white error and drift),
    and with `position_factors: offset` as well."""
    def edit(text, variant, where):
        text = _with_estimation_key(text, "pose_between_noise", "white_and_drift", where)
        if variant == "white_and_drift_offset":
            text = _with_estimation_key(text, "position_factors", "offset", where)
        return text

    dirs = _write_suite_variants(r, "pose_noise", POSE_NOISE_VARIANTS, _factor_methods, edit)
    _run_variants(r, "pose_noise", dirs, FACTOR_SEEDS)


def extract_pose_noise(r):
    v = {}
    for variant in POSE_NOISE_VARIANTS:
        v.update(_factor_scores(r, "pose_noise", variant))
    return v


def _factor_scores(r, source, variant):
    """Per suite scenario, the scores of one variant of a position-factor comparison."""
    v = {}
    for scenario in _suite_scenarios(r.root):
        s = seed_summaries(r.out(source, variant), scenario, FACTOR_SEEDS)
        m = {i: s[i]["methods"] for i in FACTOR_SEEDS}
        key = f"{source}.{scenario}.{variant}."

        def values(method, metric):
            return [m[i][method].get(metric) for i in FACTOR_SEEDS]

        oracle = values("oracle", "ate_m")
        consensus = values("consensus", "ate_m")
        singles = sorted(meth for meth in m[1] if meth.startswith("single:") and meth.endswith("@clean"))
        best = min(singles, key=lambda meth: statistics.median(values(meth, "ate_m")))
        best_ate = values(best, "ate_m")
        over_oracle = [c / o for c, o in zip(consensus, oracle)]
        v[key + "oracle_ate"] = sig(statistics.median(oracle), 3)
        v[key + "consensus_ate"] = sig(statistics.median(consensus), 3)
        v[key + "best_single"] = f"{best[len('single:'):-len('@clean')]} {sig(statistics.median(best_ate), 3)}"
        v[key + "oracle_over_best"] = fixed(statistics.median([o / b for o, b in zip(oracle, best_ate)]), 2)
        v[key + "consensus_over_oracle"] = f"{fixed(statistics.median(over_oracle), 2)} / {fixed(max(over_oracle), 2)}"
        for method, name in (("consensus", "consensus"), ("oracle", "oracle")):
            steps = [x * 1000.0 for x in values(method, "position_step_max_m")]
            v[f"{key}{name}_step_mm"] = f"{sig(statistics.median(steps), 2)} / {sig(max(steps), 2)}"
        for method in ("consensus", "oracle"):
            nees = [x for x in values(method, "nees_position_mean") if x is not None]
            inside = [x for x in values(method, "position_containment_95") if x is not None]
            v[f"{key}{method}_nees"] = sci(statistics.median(nees), 2) if nees else "-"
            v[f"{key}{method}_containment"] = percent(statistics.median(inside), 0) if inside else "-"
    return v


DEGENERATE_SEEDS = list(range(1, 11))
DEGENERATE_VARIANTS = ("fused", "left_out")
DEGENERATE_METHODS = ("consensus", "consensus:consistent_set", "oracle", "single:lio@clean")


def _degenerate_variants(r):
    """The suite's scenarios with a LiDAR odometry, methods DEGENERATE_METHODS and no
    expectations, once fusing every direction of its between factors (the paper, the
    default) and once with `degenerate_directions: left_out`."""
    def methods(text, where):
        listed = ", ".join(f'"{m}"' for m in DEGENERATE_METHODS)
        return re.sub(r"  methods: \[[^\]]*\]", f"  methods: [{listed}]", text, flags=re.S)

    return _write_suite_variants(r, "degenerate_directions", DEGENERATE_VARIANTS, methods,
                                 _with_degenerate_directions,
                                 scenarios=_lio_scenarios(r.root))


def _lio_scenarios(root):
    """The suite's scenarios that fly a LiDAR odometry."""
    return [s for s in _suite_scenarios(root)
            if "type: lidar_odometry" in (root / "scenarios" / "suite" / f"{s}.yaml").read_text()]


def run_degenerate_directions(r):
    _run_variants(r, "degenerate_directions", _degenerate_variants(r), DEGENERATE_SEEDS)


def extract_degenerate_directions(r):
    v = {}
    for scenario in _lio_scenarios(r.root):
        for variant in DEGENERATE_VARIANTS:
            s = seed_summaries(r.out("degenerate_directions", variant), scenario, DEGENERATE_SEEDS)
            key = f"degenerate_directions.{scenario}.{variant}."

            def ate(method):
                return [s[i]["methods"][method]["ate_m"] for i in DEGENERATE_SEEDS]

            oracle = ate("oracle")
            for method, name in (("consensus", "consensus"), ("consensus:consistent_set", "consistent_set")):
                ratio = [a / o for a, o in zip(ate(method), oracle)]
                v[f"{key}{name}_ate"] = sig(statistics.median(ate(method)), 3)
                v[f"{key}{name}_over_oracle"] = f"{fixed(statistics.median(ratio), 2)} / {fixed(max(ratio), 2)}"
            v[key + "oracle_ate"] = sig(statistics.median(oracle), 3)
            v[key + "lio_ate"] = sig(statistics.median(ate("single:lio@clean")), 3)
    return v


# ---- the recommended profile, chosen by measurement (issue 54) ---------------------------
# scripts/measure_profiles.py on the suite's own check (the suite source's command, reused
# with --reuse): configurations scored by `tofu estimate --set` on the recorded runs, a
# greedy forward selection on seeds 1-5 from what the shipped scenarios used, reported on
# seeds 6-10.
PROFILE_ROUNDS = 2
PROFILE_GOALS = [("ate", "consensus / oracle ATE, median / worst", "≤ 1.5 / 2.5"),
                 ("detection", "detection, abrupt (worst, s)", "≤ 1"),
                 ("detection_slow", "detection, slow drift (worst, s)", "≤ 5"),
                 ("readmit", "re-admission (worst, s)", "≤ 3"),
                 ("exclusion", "false exclusion (worst)", "≤ 1 %"),
                 ("nees_consensus", "NEES, consensus (median of means)", "1-6"),
                 ("nees_oracle", "NEES, oracle", "1-6"),
                 ("contain_consensus", "95 % containment, consensus", "90-99 %"),
                 ("contain_oracle", "95 % containment, oracle", "90-99 %"),
                 ("rotation", "rotation RMSE / oracle's (median)", "≤ 1.5")]


def run_profiles(r):
    _suite_check(r)
    r.script_cmd("profiles/measure", "scripts/measure_profiles.py", "--tofu", r.tofu, "--check", r.out("suite"),
                 "--out", r.out("profiles"), "--jobs", r.jobs, "--rounds", PROFILE_ROUNDS)


def _goal_text(goal, g):
    if g is None:
        return "-"
    value = g["value"]
    mark = "" if g["met"] else " ✗"
    if goal == "ate":
        return f"{fixed(value[0], 2)} / {fixed(value[1], 2)}{mark}"
    if goal == "exclusion":
        return percent(value) + mark
    if goal.startswith("contain"):
        return percent(value) + mark
    if goal.startswith("detection") or goal == "readmit":
        return fixed(value, 1) + mark
    return (sci(value, 2) if goal.startswith("nees") else fixed(value, 2)) + mark


def extract_profiles(r):
    d = load_json(r.out("profiles", "profiles.json"))
    v = {"profiles.calibration_seeds": seeds_label(d["calibration_seeds"]),
         "profiles.validation_seeds": seeds_label(d["validation_seeds"])}
    for label, p in d["profiles"].items():
        k = f"profiles.{label}."
        v[k + "configuration"] = p["configuration"]
        v[k + "settings"] = " ".join(f"{key}={value}" for key, value in sorted(p["settings"].items()))
        for half in ("calibration", "validation"):
            s = p[half]
            v[k + half] = f"{s['met']} of {s['applicable']}"
            for scenario, table in s["tables"].items():
                for goal, _, _ in PROFILE_GOALS:
                    v[f"{k}{half}.{scenario}.{goal}"] = _goal_text(goal, table.get(goal))
    for n, rnd in enumerate(d["rounds"], 1):
        v[f"profiles.round{n}.from"] = rnd["from"]
        v[f"profiles.round{n}.chosen"] = rnd["chosen"]
        v[f"profiles.round{n}.count"] = str(len(rnd["tried"]))
        v[f"profiles.round{n}.tried"] = "|".join(t["configuration"] for t in rnd["tried"])
        for t in rnd["tried"]:
            v[f"profiles.round{n}.{t['configuration']}"] = f"{t['met']} ({t['excess']:.1f})"
    v["profiles.rounds"] = str(len(d["rounds"]))
    return v


SOURCES = {
    "paper_metric": {"describe": "`tofu run` of scenarios/paper_metric_evaluation.yaml and "
                                 "paper_metric_divergence.yaml (seed 1), then scripts/plot_consistency.py "
                                 "on each for the pairs leica-vio and leica-truth",
                     "seeds": [1], "run": run_paper_metric, "extract": extract_paper_metric},
    "euroc": {"describe": "`tofu estimate` on the EuRoC V1_02 excerpt (../shared/data/euroc_v1_02) "
                          "cut at five start times, and with --imu-noise-scale 1, 3, 10, 30",
              "seeds": None, "run": run_euroc, "extract": extract_euroc},
    "estimator_arena": {"describe": "`tofu run scenarios/estimator_arena.yaml` (seed 1), then `tofu "
                                    "estimate` of four methods, and with --imu-noise-scale 1, 3, 10, 30",
                        "seeds": [1], "run": run_estimator_arena, "extract": extract_estimator_arena},
    "paper_consensus": {"describe": "`tofu check scenarios/paper_consensus_indoor.yaml --seeds 10`",
                        "seeds": PAPER_SEEDS,
                        "run": _check_source("paper_consensus", "scenarios/paper_consensus_indoor.yaml", 10),
                        "extract": extract_paper_consensus},
    "closed_loop_wall": {"describe": "`tofu check scenarios/closed_loop_vio_divergence_wall.yaml --seeds 10`",
                         "seeds": CLOSED_LOOP_SEEDS,
                         "run": _check_source("closed_loop_wall",
                                              "scenarios/closed_loop_vio_divergence_wall.yaml", 10),
                         "extract": extract_closed_loop_wall},
    "closed_loop_corridor": {"describe": "`tofu check scenarios/closed_loop_corridor_occlusion.yaml --seeds 10`",
                             "seeds": CLOSED_LOOP_SEEDS,
                             "run": _check_source("closed_loop_corridor",
                                                  "scenarios/closed_loop_corridor_occlusion.yaml", 10),
                             "extract": extract_closed_loop_corridor},
    "closed_loop_window": {"describe": "`tofu check scenarios/closed_loop_indoor_outdoor_window.yaml --seeds 10`",
                           "seeds": CLOSED_LOOP_SEEDS,
                           "run": _check_source("closed_loop_window",
                                                "scenarios/closed_loop_indoor_outdoor_window.yaml", 10),
                           "extract": extract_closed_loop_window},
    "clients": {"describe": "`tofu check scenarios/clients --seeds 10` (the C++ plug-in from "
                            "build/examples/cpp_plugin, README's commands, or TOFU_PLUGIN_DIR)",
                "seeds": CLIENT_SEEDS, "run": _check_source("clients", "scenarios/clients", 10),
                "extract": extract_clients},
    "suite": {"describe": "`tofu check scenarios/suite --seeds 10`", "seeds": SUITE_SEEDS,
              "run": _check_source("suite", "scenarios/suite", 10), "extract": extract_suite},
    "compare_calibration": {"describe": "`tofu compare` on the suite's check (`tofu check scenarios/suite "
                                       "--seeds 10`, the suite source's command): against itself; "
                                       "three disjoint 5-seed halves, --unpaired; consensus ATE x"
                                       f"{INJECTED_FACTOR:g} injected per scenario; --methods consensus "
                                       "naive; consensus re-estimated (`tofu estimate`) on every run "
                                       f"with constant between weights, at the nominal std and with --between-position-std "
                                       f"{DEGRADED_STD_M:g} (x1.2); and the "
                                       "seeds for 80 % power at ATE x1.10, paired and unpaired, "
                                       "simulated with the spreads measured on the suite",
                            "seeds": SUITE_SEEDS, "run": run_compare_calibration,
                            "extract": extract_compare_calibration},
    "search_benchmark": {"describe": "`tofu search searches/<problem>.yaml --optimizer O --optimizer-seed K` "
                                     f"for O in {', '.join(SEARCH_OPTIMIZERS)} and K = 1..{SEARCH_REPS}, "
                                     "each stopping at its first confirmed failure, then "
                                     "scripts/plot_search.py --benchmark",
                         "seeds": None, "run": run_search_benchmark, "extract": extract_search_benchmark},
    "profiles": {"describe": "scripts/measure_profiles.py on the suite's check (`tofu check scenarios/suite "
                             "--seeds 10`, the suite source's command): `tofu estimate --method consensus "
                             "--method oracle --set profile=paper --set KEY=VALUE...` of each configuration on "
                             "every recorded run, a greedy selection on seeds 1-5 from the shipped scenarios' "
                             f"configuration ({PROFILE_ROUNDS} rounds), reported on seeds 6-10",
                 "seeds": SUITE_SEEDS, "run": run_profiles, "extract": extract_profiles},
    "consensus_nis": {"describe": "`tofu check` of the suite's scenarios with methods [consensus, "
                                  "oracle], as written (cm), with `consensus: {metric: nis, "
                                  f"threshold: {NIS_THRESHOLD:g}}}` (nis) and with that and "
                                  "`degenerate_directions: left_out` (nis_left_out), --seeds 10",
                      "seeds": NIS_SEEDS, "run": run_consensus_nis, "extract": extract_consensus_nis},
    "level_alignment": {"describe": "`tofu check` of the suite's scenarios with methods [consensus, "
                                    "oracle], as written (the paper's 6-DoF alignments) and with "
                                    f"`alignment_level_prior_deg: {LEVEL_PRIOR_DEG:g}`, --seeds 10",
                        "seeds": LEVEL_SEEDS, "run": run_level_alignment, "extract": extract_level_alignment},
    "bias_test": {"describe": "`tofu check` of the suite's scenarios with methods [consensus, "
                              "oracle], as written (the paper's window metric) and with "
                              f"`consensus: {{bias_window_s: {BIAS_WINDOW_S}, bias_floor_mps: F}}` "
                              "for F = 0.001 (bias, the default floor) and 0.003 (bias_floor3), "
                              "and with F = 0.001 beside `metric: nis` (nis_bias), --seeds 10",
                  "seeds": BIAS_SEEDS, "run": run_bias_test, "extract": extract_bias_test},
    "position_factors": {"describe": "`tofu check` of the suite's scenarios without naive and "
                                     "consensus:consistent_set, with `position_factors: between` "
                                     "(the default) and `absolute`, --seeds 10",
                         "seeds": FACTOR_SEEDS, "run": run_position_factors,
                         "extract": extract_position_factors},
    "closed_loop_offset": {"describe": "`tofu check` of the three closed-loop scenarios with "
                                       "`position_factors: offset`, --seeds 10",
                           "seeds": CLOSED_LOOP_SEEDS, "run": run_closed_loop_offset,
                           "extract": extract_closed_loop_offset},
    "position_offset": {"describe": "`tofu check` of the suite's scenarios without naive and "
                                    "consensus:consistent_set, with `position_factors: offset`, "
                                    "--seeds 10",
                        "seeds": FACTOR_SEEDS, "run": run_position_offset,
                        "extract": extract_position_offset},
    "pose_noise": {"describe": "`tofu check` of the suite's scenarios without naive and "
                               "consensus:consistent_set, with `pose_between_noise: white_and_drift` "
                               "(white_and_drift) and with `position_factors: offset` as well "
                               "(white_and_drift_offset), --seeds 10",
                   "seeds": FACTOR_SEEDS, "run": run_pose_noise, "extract": extract_pose_noise},
    "degenerate_directions": {"describe": "`tofu check` of the suite's scenarios with a LiDAR odometry, "
                                          "methods [consensus, consensus:consistent_set, oracle, "
                                          "single:lio@clean], with `degenerate_directions: fused` (the "
                                          "default) and `left_out`, --seeds 10",
                              "seeds": DEGENERATE_SEEDS, "run": run_degenerate_directions,
                              "extract": extract_degenerate_directions},
}


# ---- tables: rendered from the values at render time, so a hand edit is found ----------

class Values:
    """The generated values of every source; records which sources a table read."""

    def __init__(self, data):
        self.data = data
        self.index = {}
        for name, source in data.get("sources", {}).items():
            for key, text in source["values"].items():
                self.index[key] = (name, text)
        self.used = set()

    def __call__(self, key):
        if key not in self.index:
            raise KeyError(key)
        name, text = self.index[key]
        self.used.add(name)
        return text

    def __contains__(self, key):
        return key in self.index


def md_table(header, rows):
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines)


def table_euroc_cuts(V):
    rows = []
    for start, length in EUROC_CUTS:
        c = f"euroc.cut{start}."
        rows.append([f"{start} + {length}", f"**{V(c + 'ate_cm')} / {V(c + 'rot_deg')}**",
                     f"{V(c + 'vio_ate_cm')} / {V(c + 'vio_rot_deg')}", V(c + "ratio"), V(c + "init"),
                     V(c + "gravity_init_deg"), f"{V(c + 'tilt_rms_deg')} / {V(c + 'tilt_max_deg')}",
                     V(c + "noise"), V(c + "gyro_bias"), V(c + "accel_bias")])
    rows.append(["mean", f"{V('euroc.mean.ate_cm')} / {V('euroc.mean.rot_deg')}",
                 f"{V('euroc.mean.vio_ate_cm')} / {V('euroc.mean.vio_rot_deg')}", V("euroc.mean.ratio"),
                 "", "", V("euroc.mean.tilt_rms_deg"), "", "", ""])
    return md_table(["cut: start + length [s]", "fused ATE [cm] / rot [deg]", "VIO alone, same span",
                     "fused/VIO ATE", "initialised", "gravity error at init [deg]",
                     "gravity error RMS / max over the cut [deg]",
                     "stream noise measured (per relative pose)", "gyro bias error RMS / final [mrad/s]",
                     "accel bias error RMS / final [m/s²]"], rows)


def table_imu_noise(V):
    rows = []
    for k in IMU_NOISE_SCALES:
        cells = [V(f"euroc.imu_noise_{k}"), V(f"arena.imu_noise_{k}.vio"), V(f"arena.imu_noise_{k}.leica")]
        label = {1: "1 (datasheet)", 10: "10 (default)"}.get(k, str(k))
        if k == 10:
            label, cells = f"**{label}**", [f"**{c}**" for c in cells]
        rows.append([label, *cells])
    return md_table(["k", "EuRoC V1_02 ATE [m] / rot [deg]", "estimator_arena, single:vio",
                     "single:leica"], rows)


def table_estimator_arena(V):
    labels = {"raw:vio": "VIO alone (`raw:vio`)", "single:vio": "IMU + VIO (`single:vio`)",
              "single:leica": "IMU + total station (`single:leica`)",
              "fuse:vio+leica": "IMU + VIO + total station (`fuse:vio+leica`; the graph starts on the total station at 0 s)"}
    rows = []
    for method in ARENA_METHODS:
        key = "arena." + method.replace(":", "_").replace("+", "_")
        rows.append([labels[method], V(key + ".ate_m"), V(key + ".rot_deg"), V(key + ".rpe_m")])
    return md_table(["method", "ATE [m]", "rotation RMSE [deg]", "RPE 1 s [m]"], rows)


def table_paper_consensus_seed1(V):
    rows = []
    for method, label in PAPER_METHODS:
        key = "paper_consensus.seed1." + method
        ate = V(key + ".ate_m")
        rows.append([label, f"**{ate}**" if method == "consensus" else ate, V(key + ".rot_deg"),
                     V(key + ".nees")])
    return md_table(["method (seed 1)", "ATE [m]", "rotation RMSE [deg]", "NEES (3 = consistent)"], rows)


def table_paper_consensus_seeds(V):
    rows = []
    for a, b in ((1, 5), (6, 10)):
        g = f"paper_consensus.seeds{a}_{b}."
        rows.append([f"{a}-{b}", V(g + "consensus"), V(g + "naive"), V(g + "clean_vio"),
                     V(g + "over_naive"), V(g + "over_clean")])
    return md_table(["seeds", "consensus ATE [m]", "naive ATE [m]", "clean VIO ATE [m]",
                     "consensus / naive", "consensus / clean VIO"], rows)


def _closed_loop_table(V, name, extra_header=(), extra=lambda i: [], open_loop="consensus / naive"):
    rows = []
    for i in CLOSED_LOOP_SEEDS:
        k = f"{name}.seed{i}."
        rows.append([str(i), V(k + "consensus_rmse_m"), V(k + "naive_rmse_m"), V(k + "naive_over_consensus"),
                     V(k + "naive_hits"), V(k + "naive_first_hit_s"), V(k + "naive_hit"),
                     V(k + "naive_diverged"), V(k + "open_loop_ate")] + extra(i))
    return md_table(["seed", "consensus: tracking RMSE [m]", "naive: tracking RMSE [m]", "naive / consensus",
                     "hits", "first hit [s]", "hit", "diverged", f"open-loop ATE {open_loop} [m]",
                     *extra_header], rows)


def table_closed_loop_wall(V):
    return _closed_loop_table(V, "closed_loop_wall")


def table_closed_loop_corridor(V):
    def leica(i):
        k = f"closed_loop_corridor.seed{i}.leica_"
        return [V(k + "failsafe_s"), V(k + "landed_s"), V(k + "rmse_m"), V(k + "hits")]
    return _closed_loop_table(V, "closed_loop_corridor", ["single:leica: failsafe at [s]", "landed [s]",
                                                          "tracking RMSE [m]", "hits"], leica)


def table_closed_loop_window(V):
    return _closed_loop_table(V, "closed_loop_window", open_loop="consensus / naive / VIO")


def _mission_frame(V, name, seeds):
    rows = []
    for i in seeds:
        k = f"{name}.seed{i}."
        rows.append([str(i), f"{V(k + 'consensus_rmse_m')} / {V(k + 'consensus_max_m')}",
                     V(k + "consensus_window_rmse_m"), V(k + "consensus_hits"), V(k + "consensus_dist_m"),
                     V(k + "naive_rmse_m"), V(k + "naive_hits")])
    return md_table(["seed", "consensus: tracking RMSE / max [m]", "RMSE in window [m]", "hits", "dist [m]",
                     "naive: tracking RMSE [m]", "hits"], rows)


def table_suite(V):
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        k = f"suite.{scenario}."
        rows.append([f"{scenario} ({V(k + 'passed')} pass)", V(k + "consensus_ate"), V(k + "cs_ate"),
                     V(k + "oracle_ate"), V(k + "best_single"), V(k + "oracle_over_best"),
                     f"{V(k + 'c.detection_worst_s')} ({V(k + 'cs.detection_worst_s')})",
                     f"{V(k + 'c.readmission_worst_s')} ({V(k + 'cs.readmission_worst_s')})",
                     f"{V(k + 'c.false_exclusion_worst')} ({V(k + 'cs.false_exclusion_worst')})",
                     f"{V(k + 'c.nees_median')} ({V(k + 'cs.nees_median')})",
                     f"{V(k + 'c.rotation_over_oracle')} ({V(k + 'cs.rotation_over_oracle')})"])
    return md_table(["scenario", "consensus ATE med/worst",
                     "consistent_set ATE med/worst (× oracle med/worst)", "oracle med",
                     "best single @clean (med)", "oracle × best single (med)", "detection worst [s] (cs)",
                     "re-admission worst [s] (cs)", "false excl. worst (cs)", "NEES med consensus (cs)",
                     "rotation × oracle med (cs)"], rows)


def _selection_table(V, source, variants, first_header, fields, headers):
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        k = f"{source}.{scenario}."
        rows.append([scenario] + [" → ".join(V(f"{k}{variant}.{f}") for variant in variants) for f in fields])
    return md_table([first_header] + headers, rows)


SELECTION_FIELDS = ("ratio_1_5", "ratio_6_10", "detection_worst_s", "readmission_worst_s",
                    "false_exclusion_worst", "switches_median")
SELECTION_HEADERS = ["consensus × oracle ATE, seeds 1-5 (med / worst)", "seeds 6-10 (med / worst)",
                     "detection worst [s]", "re-admission worst [s]", "false excl. worst", "switches (med)"]


def table_consensus_nis(V):
    return _selection_table(V, "consensus_nis", NIS_VARIANTS, "scenario (cm → nis → nis + degenerate left out)",
                            SELECTION_FIELDS, SELECTION_HEADERS)


def table_level_alignment(V):
    return _selection_table(V, "level_alignment", LEVEL_VARIANTS, "scenario (6-DoF → level prior)",
                            ("consensus_ate", "oracle_ate") + SELECTION_FIELDS,
                            ["consensus ATE med [m]", "oracle ATE med [m]"] + SELECTION_HEADERS)


def table_bias_test(V):
    return _selection_table(V, "bias_test", BIAS_VARIANTS,
                            "scenario (paper → bias test → floor 3 mm/s → nis + bias test)",
                            ("consensus_ate", "oracle_ate") + SELECTION_FIELDS,
                            ["consensus ATE med [m]", "oracle ATE med [m]"] + SELECTION_HEADERS)


def table_position_factors(V):
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        k = f"position_factors.{scenario}."
        rows.append([scenario] + [f"{V(k + 'between.' + f)} → {V(k + 'absolute.' + f)}" for f in (
            "consensus_ate", "oracle_ate", "best_single", "oracle_over_best", "consensus_over_oracle",
            "consensus_step_mm", "oracle_step_mm", "consensus_nees", "consensus_containment")])
    return md_table(["scenario (between → absolute)", "consensus ATE med [m]", "oracle ATE med [m]", "best single @clean (med)",
                     "oracle × best single (med)", "consensus × oracle (med / worst)",
                     "largest step consensus [mm] (med / worst)", "largest step oracle [mm]",
                     "NEES consensus (med)", "95 % containment consensus (med)"], rows)


def table_position_offset(V):
    """`position_factors: offset` beside the between → absolute figures of position_factors
    (the same flights; the between and absolute estimates do not depend on the offset's
    code, which golden_runs and the stamps of the two sources show)."""
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        k = f"position_factors.{scenario}."
        o = f"position_offset.{scenario}.offset."
        rows.append([scenario] + [f"{V(k + 'between.' + f)} → {V(k + 'absolute.' + f)} → {V(o + f)}" for f in (
            "consensus_ate", "oracle_ate", "best_single", "oracle_over_best", "consensus_over_oracle",
            "consensus_step_mm", "consensus_nees", "consensus_containment")] +
            [f"{V(o + 'oracle_nees')} / {V(o + 'oracle_containment')}"])
    return md_table(["scenario (between → absolute → offset)", "consensus ATE med [m]", "oracle ATE med [m]",
                     "best single @clean (med)", "oracle × best single (med)", "consensus × oracle (med / worst)",
                     "largest step consensus [mm] (med / worst)", "NEES consensus (med)",
                     "95 % containment consensus (med)", "oracle with offset: NEES / 95 % containment (med)"], rows)


def table_pose_noise(V):
    """Pose streams' between factors with the paper's constant weights (position_factors'
    between variant: the same flights) → from each stream's own white error and drift."""
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        k = f"position_factors.{scenario}.between."
        o = f"pose_noise.{scenario}.white_and_drift."
        b = f"pose_noise.{scenario}.white_and_drift_offset."
        rows.append([scenario] + [f"{V(k + f)} → {V(o + f)} → {V(b + f)}" for f in (
            "consensus_ate", "oracle_ate", "oracle_over_best", "consensus_over_oracle",
            "consensus_nees", "consensus_containment")] +
            [f"{V(o + 'oracle_nees')} / {V(o + 'oracle_containment')} → "
             f"{V(b + 'oracle_nees')} / {V(b + 'oracle_containment')}"])
    return md_table(["scenario (constant → white and drift → and offset)", "consensus ATE med [m]",
                     "oracle ATE med [m]", "oracle × best single (med)",
                     "consensus × oracle (med / worst)", "NEES consensus (med)",
                     "95 % containment consensus (med)",
                     "oracle: NEES / 95 % containment (med), white and drift → and offset"], rows)


def table_closed_loop_offset(V):
    """The closed-loop flights on consensus with displacements (the scenarios as written)
    → with `position_factors: offset`, seeds 1-10."""
    rows = []
    for short, scenario, _, _ in CLOSED_LOOP_OFFSET:
        a, b = f"closed_loop_{short}.", f"closed_loop_offset_{short}."
        rows.append([scenario] + [f"{V(a + f)} → {V(b + f)}" for f in (
            "seeds1_10.consensus_rmse_cm", "seeds1_10.consensus_window_rmse_cm", "window_rmse_above_5cm",
            "consensus_dist_cm", "naive_hit_seeds", "passed")])
    return md_table(["scenario (between → offset)", "consensus: tracking RMSE", "RMSE in window",
                     "seeds above 5 cm in window", "nearest structure", "naive: seeds with contact",
                     "seeds whose every expectation held"], rows)


def _number(text):
    """The first number of a generated value ('4.9 %' -> 4.9, 'inf' -> inf, '0.12 / 0.2'
    -> 0.12, '1.1e3' -> 1100); None for '-'."""
    text = text.strip()
    if text.startswith("inf") or text == "never":
        return math.inf
    found = re.match(r"-?[0-9.]+(?:e-?[0-9]+)?", text)
    return float(found.group(0)) if found else None


def _numbers(text):
    return [_number(part) for part in text.split("/")]


def _goal_row(V, goal, variants, passes, worst_of, fmt):
    """One goal over the suite's scenarios: per variant (label, key template with
    {scenario}), how many scenarios pass, and the worst value."""
    cells = []
    met_any = False
    for label, template in variants:
        values = {sc: V(template.format(scenario=sc)) for sc in _suite_scenarios(SCRIPT_ROOT)}
        held = [sc for sc, text in values.items() if passes(sc, text)]
        worst = worst_of(values)
        met_any |= len(held) == len(values)
        cells.append(f"{label}: {len(held)} of {len(values)} ({fmt(worst)})")
    return [goal, "; ".join(cells), "met" if met_any else "missed"]


def table_issue34_goals(V):
    """Issue 34's goals over seeds 1-10 of the suite (and the closed-loop scenarios), each
    marked met where every scenario meets it in at least one variant."""
    rows = []
    slow = "total_station_slow_drift"
    worst_max = lambda f: (lambda vals: max(f(t) for t in vals.values()))  # noqa: E731
    rows.append(_goal_row(
        V, "oracle ≤ 1.1x the best healthy single sensor (median)",
        [("between", "position_factors.{scenario}.between.oracle_over_best"),
         ("absolute", "position_factors.{scenario}.absolute.oracle_over_best"),
         ("offset", "position_offset.{scenario}.offset.oracle_over_best"),
         ("pose white+drift", "pose_noise.{scenario}.white_and_drift.oracle_over_best"),
         ("pose white+drift + offset", "pose_noise.{scenario}.white_and_drift_offset.oracle_over_best")],
        lambda sc, t: _number(t) <= 1.1, worst_max(_number), lambda x: f"worst {x:.2f}x"))
    rows.append(_goal_row(
        V, "consensus ≤ 1.5x the oracle's median ATE and ≤ 2.5x its worst",
        [("between", "position_factors.{scenario}.between.consensus_over_oracle"),
         ("absolute", "position_factors.{scenario}.absolute.consensus_over_oracle"),
         ("offset", "position_offset.{scenario}.offset.consensus_over_oracle"),
         ("pose white+drift", "pose_noise.{scenario}.white_and_drift.consensus_over_oracle"),
         ("pose white+drift + offset",
          "pose_noise.{scenario}.white_and_drift_offset.consensus_over_oracle"),
         ("between + bias test", "bias_test.{scenario}.bias.ratio_1_10"),
         ("between + nis + bias test", "bias_test.{scenario}.nis_bias.ratio_1_10")],
        lambda sc, t: _numbers(t)[0] <= 1.5 and _numbers(t)[1] <= 2.5,
        worst_max(lambda t: _numbers(t)[0]), lambda x: f"largest median {x:.2f}x"))
    selection = [("cm", "consensus_nis.{scenario}.cm."), ("nis", "consensus_nis.{scenario}.nis."),
                 ("level prior", "level_alignment.{scenario}.level."),
                 ("bias test", "bias_test.{scenario}.bias."),
                 ("nis + bias test", "bias_test.{scenario}.nis_bias.")]
    rows.append(_goal_row(
        V, "detection ≤ 1 s after abrupt faults, ≤ 5 s for the slow drift (worst seed)",
        [(label, prefix + "detection_worst_s") for label, prefix in selection],
        lambda sc, t: _number(t) <= (5.0 if sc == slow else 1.0),
        lambda vals: max(_number(t) for sc, t in vals.items() if sc != slow),
        lambda x: f"abrupt worst {x:.1f} s"))
    rows.append(_goal_row(
        V, "re-admission ≤ 3 s after a fault ends (worst seed)",
        [(label, prefix + "readmission_worst_s") for label, prefix in selection],
        lambda sc, t: _number(t) <= 3.0, worst_max(_number), lambda x: f"worst {x:.1f} s"))
    rows.append(_goal_row(
        V, "false exclusion ≤ 1 % of healthy sensor time (worst seed)",
        [(label, prefix + "false_exclusion_worst") for label, prefix in selection],
        lambda sc, t: _number(t) <= 1.0, worst_max(_number), lambda x: f"worst {x:.1f} %"))
    nees_ok = lambda t: 1.0 <= _number(t) <= 6.0  # noqa: E731
    rows.append(_goal_row(
        V, "NEES median within 1-6 (consensus)",
        [("between", "position_factors.{scenario}.between.consensus_nees"),
         ("absolute", "position_factors.{scenario}.absolute.consensus_nees"),
         ("offset", "position_offset.{scenario}.offset.consensus_nees"),
         ("pose white+drift", "pose_noise.{scenario}.white_and_drift.consensus_nees"),
         ("pose white+drift + offset", "pose_noise.{scenario}.white_and_drift_offset.consensus_nees")],
        lambda sc, t: nees_ok(t), worst_max(_number), lambda x: f"largest {sci(x)}"))
    rows.append(_goal_row(
        V, "NEES median within 1-6 (oracle)",
        [("offset", "position_offset.{scenario}.offset.oracle_nees"),
         ("pose white+drift", "pose_noise.{scenario}.white_and_drift.oracle_nees"),
         ("pose white+drift + offset", "pose_noise.{scenario}.white_and_drift_offset.oracle_nees")],
        lambda sc, t: nees_ok(t), worst_max(_number), lambda x: f"largest {sci(x)}"))
    rows.append(_goal_row(
        V, "95 % containment within 90-99 % (consensus)",
        [("between", "position_factors.{scenario}.between.consensus_containment"),
         ("absolute", "position_factors.{scenario}.absolute.consensus_containment"),
         ("offset", "position_offset.{scenario}.offset.consensus_containment"),
         ("pose white+drift", "pose_noise.{scenario}.white_and_drift.consensus_containment"),
         ("pose white+drift + offset",
          "pose_noise.{scenario}.white_and_drift_offset.consensus_containment")],
        lambda sc, t: 90.0 <= _number(t) <= 99.0,
        lambda vals: min(_number(t) for t in vals.values()), lambda x: f"lowest {x:.0f} %"))
    rows.append(_goal_row(
        V, "95 % containment within 90-99 % (oracle)",
        [("offset", "position_offset.{scenario}.offset.oracle_containment"),
         ("pose white+drift", "pose_noise.{scenario}.white_and_drift.oracle_containment"),
         ("pose white+drift + offset",
          "pose_noise.{scenario}.white_and_drift_offset.oracle_containment")],
        lambda sc, t: 90.0 <= _number(t) <= 99.0,
        lambda vals: min(_number(t) for t in vals.values()), lambda x: f"lowest {x:.0f} %"))
    rows.append(_goal_row(
        V, "rotation RMSE ≤ 1.5x the oracle's (consensus, median)",
        [("between", "suite.{scenario}.c.rotation_over_oracle")],
        lambda sc, t: _number(t) <= 1.5, worst_max(_number), lambda x: f"worst {x:.2f}x"))
    # The closed-loop scenarios: the largest in-window tracking RMSE and contacts.
    loops = ("wall", "corridor", "window")
    cells = []
    met = False
    for label, prefix in (("between", "closed_loop_"), ("offset", "closed_loop_offset_")):
        windows = [_number(V(f"{prefix}{k}.seeds1_10.consensus_window_rmse_cm").split("-")[-1]) for k in loops]
        above = sum(int(V(f"{prefix}{k}.window_rmse_above_5cm").split()[0]) for k in loops)
        cells.append(f"{label}: largest {max(windows):.1f} cm, {above} of 30 flights above 5 cm")
        met |= above == 0
    rows.append(["closed loop: tracking RMSE ≤ 5 cm while an absolute sensor is healthy",
                 "; ".join(cells), "met" if met else "missed"])
    hits = []
    for label, prefix in (("between", "closed_loop_"), ("offset", "closed_loop_offset_")):
        n = sum(int(V(f"{prefix}{k}.seed{i}.consensus_hits")) for k in loops for i in CLOSED_LOOP_SEEDS)
        hits.append((label, n))
    rows.append(["closed loop: no collision of consensus (30 flights)",
                 "; ".join(f"{label}: {n} contacts" for label, n in hits),
                 "met" if all(n == 0 for _, n in hits) else "missed"])
    ratios = [_number(V(f"euroc.cut{start}.ratio")) for start, _ in EUROC_CUTS]
    rows.append(["EuRoC: fused ATE ≤ 1.1x the pose stream's own (five cuts of V1_02)",
                 f"worst {max(ratios):.2f}x", "met" if max(ratios) <= 1.1 else "missed"])
    return md_table(["goal (issue 34)", "measured, per variant: scenarios meeting it of the suite's eight",
                     "met / missed"], rows)


def table_degenerate_directions(V):
    rows = []
    for scenario in _lio_scenarios(SCRIPT_ROOT):
        k = f"degenerate_directions.{scenario}."
        rows.append([scenario] + [f"{V(k + 'fused.' + f)} → {V(k + 'left_out.' + f)}" for f in (
            "consensus_ate", "consensus_over_oracle", "consistent_set_ate", "consistent_set_over_oracle",
            "oracle_ate", "lio_ate")])
    return md_table(["scenario (fused → left out)", "consensus ATE med [m]", "consensus × oracle (med / worst)",
                     "consistent_set ATE med [m]", "consistent_set × oracle (med / worst)",
                     "oracle ATE med [m]", "LIO alone @clean ATE med [m]"], rows)


def table_suite_failures(V):
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        for i in SUITE_SEEDS:
            failed = V(f"suite.{scenario}.seed{i}.failed")
            if failed:
                rows.append([scenario, str(i), failed])
    if not rows:
        rows.append(["(none)", "", ""])
    return md_table(["scenario", "seed", "failed expectations: value (bound)"], rows)


def table_paper_metric_phases(V):
    rows = []
    for pair in PAPER_METRIC_PAIRS:
        for metric, label in PAPER_METRICS:
            k = f"paper_metric.evaluation.{pair}.{metric}."
            rows.append([pair, label] + [V(k + c) for c in ("healthy", "noisy", "diverging",
                                                            "noisy_over_healthy", "diverging_over_noisy")])
    return md_table(["pair", "metric", "healthy", "noisy (50-100 s)", "diverging (100-130 s)",
                     "noisy / healthy", "diverging / noisy"], rows)


def table_paper_metric_divergence(V):
    rows = []
    for pair in PAPER_METRIC_PAIRS:
        rows.append([f"{pair}: delay [s]"] +
                    [V(f"paper_metric.divergence.{pair}.{m}.delay_s") for m, _ in PAPER_METRICS])
    rows.append(["leica-vio: median healthy → diverging (60-90 s)"] +
                [f"{V(f'paper_metric.divergence.leica-vio.{m}.healthy')} → "
                 f"{V(f'paper_metric.divergence.leica-vio.{m}.diverging')}" for m, _ in PAPER_METRICS])
    return md_table(["pair", "CM", "MAE", "PCC", "KL"], rows)


def table_clients_ekf(V):
    rows = []
    for group, seeds in CLIENT_GROUPS.items():
        k = f"clients.python_ekf_wall.seeds{group}."
        rows.append([seeds_label(seeds)[len("seeds "):]] + [V(k + c) for c in (
            "ate_mm", "rot_deg", "nees", "vio_detection_s", "consensus_ate_mm", "closed_loop_mm", "nearest_m")])
    return md_table(["seeds", "EKF ATE", "EKF rotation RMSE [deg]", "EKF NEES", "EKF VIO detection [s]",
                     "consensus ATE", "closed loop on the EKF: tracking RMSE / max", "nearest structure [m]"], rows)


def table_clients_plugin(V):
    rows = []
    for group, seeds in CLIENT_GROUPS.items():
        k = f"clients.cpp_plugin_filter.seeds{group}."
        rows.append([seeds_label(seeds)[len("seeds "):]] + [V(k + c) for c in (
            "ate_mm", "rot_deg", "nees", "consensus_ate_mm", "closed_loop_mm", "failsafe_events")])
    return md_table(["seeds", "filter ATE", "filter rotation RMSE [deg]", "filter NEES", "consensus ATE",
                     "closed loop: tracking RMSE / max", "failsafe events"], rows)


def table_clients_controller(V):
    rows = []
    for group, seeds in CLIENT_GROUPS.items():
        k = f"clients.python_controller.seeds{group}."
        rows.append([seeds_label(seeds)[len("seeds "):]] + [V(k + c) for c in (
            "truth_tracking_mm", "closed_loop_mm", "estimate_mm", "collisions")])
    return md_table(["seeds", "tracking on ground truth RMSE", "closed loop on consensus: tracking RMSE / max",
                     "estimate error", "collisions"], rows)


def table_compare_calibration(V):
    rows = [["A/A: the check against itself (identical samples)", V("calibration.same.cells"), "-",
             V("calibration.same.regressed"), V("calibration.same.improved"),
             V("calibration.same.inconclusive"), V("calibration.same.unchanged"), "0.00 %"]]
    for i in range(len(CALIBRATION_SPLITS)):
        k = f"calibration.split{i}."
        rows.append([f"A/A: seeds {V(k + 'name')}, --unpaired", V(k + "cells"), V(k + "tested"),
                     V(k + "regressed"), V(k + "improved"), V(k + "inconclusive"), V(k + "unchanged"),
                     V(k + "false_rate")])
    return md_table(["comparison", "cells", "tested", "regressed", "improved", "inconclusive",
                     "unchanged", "false verdicts (of tested)"], rows)


def table_search_benchmark(V):
    rows = []
    for problem in SEARCH_PROBLEMS:
        for optimizer in SEARCH_OPTIMIZERS:
            k = f"search.{problem}.{optimizer}."
            rows.append([problem if optimizer == SEARCH_OPTIMIZERS[0] else "", optimizer, V(k + "rate"),
                         V(k + "median"), V(k + "range"), V(k + "flights"),
                         V(f"search.{problem}.ratio") if optimizer == "tpe" else ""])
    return md_table(["problem", "optimiser", "falsified (of trials)", "median simulations to the first "
                     "confirmed failure", "range (falsified trials)", "median flights in all (confirm, shrink)",
                     "random / tpe"], rows)


def table_compare_power(V):
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        k = f"calibration.power.{scenario}."
        rows.append([scenario, V(k + "sigma_between"), V(k + "degraded_effect"), V(k + "sigma_within"),
                     V(k + "paired"), V(k + "unpaired")])
    rows.append(["median", "", "", "", V("calibration.power.paired_median"),
                 V("calibration.power.unpaired_median")])
    return md_table(["scenario", "σ between seeds (log ATE)", "degraded ATE: median ratio (verdict)",
                     "σ within a seed (log ratio)", "seeds, paired", "seeds per side, unpaired"], rows)


def table_profiles_choice(V):
    rows = []
    for label in ("paper", "start", "recommended"):
        k = f"profiles.{label}."
        rows.append([label, V(k + "settings") or "(the paper's)", V(k + "calibration"), V(k + "validation")])
    return md_table(["configuration", "over the paper's", f"goal cells met, {V('profiles.calibration_seeds')}",
                     f"goal cells met, {V('profiles.validation_seeds')}"], rows)


def table_profiles_rounds(V):
    rows = []
    for n in range(1, int(V("profiles.rounds")) + 1):
        k = f"profiles.round{n}."
        for i, configuration in enumerate(V(k + "tried").split("|")):
            chosen = " (chosen)" if configuration == V(k + "chosen") else ""
            rows.append([str(n) if i == 0 else "", configuration.replace("+", " ") + chosen,
                         V(k + configuration)])
    return md_table(["round", "configuration (over the paper's)", "goal cells met (excess)"], rows)


def table_profiles_goals(V):
    rows = []
    for scenario in _suite_scenarios(SCRIPT_ROOT):
        for label in ("paper", "recommended"):
            k = f"profiles.{label}.validation.{scenario}."
            rows.append([scenario if label == "paper" else "", label] + [V(k + goal) for goal, _, _ in PROFILE_GOALS])
    return md_table(["scenario", "profile"] + [f"{title} ({bound})" for _, title, bound in PROFILE_GOALS], rows)


TABLES = {
    "profiles_choice": table_profiles_choice,
    "profiles_goals": table_profiles_goals,
    "profiles_rounds": table_profiles_rounds,
    "clients_ekf": table_clients_ekf,
    "clients_plugin": table_clients_plugin,
    "clients_controller": table_clients_controller,
    "paper_metric_phases": table_paper_metric_phases,
    "paper_metric_divergence": table_paper_metric_divergence,
    "euroc_cuts": table_euroc_cuts,
    "imu_noise": table_imu_noise,
    "estimator_arena": table_estimator_arena,
    "paper_consensus_seed1": table_paper_consensus_seed1,
    "paper_consensus_seeds": table_paper_consensus_seeds,
    "closed_loop_wall": table_closed_loop_wall,
    "closed_loop_corridor": table_closed_loop_corridor,
    "closed_loop_window": table_closed_loop_window,
    "mission_frame_wall_1_5": lambda V: _mission_frame(V, "closed_loop_wall", CLOSED_LOOP_SEEDS[:5]),
    "mission_frame_wall_6_10": lambda V: _mission_frame(V, "closed_loop_wall", CLOSED_LOOP_SEEDS[5:]),
    "mission_frame_corridor_1_5": lambda V: _mission_frame(V, "closed_loop_corridor", CLOSED_LOOP_SEEDS[:5]),
    "mission_frame_corridor_6_10": lambda V: _mission_frame(V, "closed_loop_corridor", CLOSED_LOOP_SEEDS[5:]),
    "mission_frame_window_1_5": lambda V: _mission_frame(V, "closed_loop_window", CLOSED_LOOP_SEEDS[:5]),
    "mission_frame_window_6_10": lambda V: _mission_frame(V, "closed_loop_window", CLOSED_LOOP_SEEDS[5:]),
    "suite": table_suite,
    "suite_failures": table_suite_failures,
    "compare_calibration": table_compare_calibration,
    "compare_power": table_compare_power,
    "search_benchmark": table_search_benchmark,
    "consensus_nis": table_consensus_nis,
    "level_alignment": table_level_alignment,
    "bias_test": table_bias_test,
    "position_factors": table_position_factors,
    "position_offset": table_position_offset,
    "pose_noise": table_pose_noise,
    "closed_loop_offset": table_closed_loop_offset,
    "issue34_goals": table_issue34_goals,
    "degenerate_directions": table_degenerate_directions,
}


# ---- rendering and checking ------------------------------------------------------------

# An inline value stays on one line; a table's markers stand alone on their lines.
INLINE = re.compile(r"<!-- r:([A-Za-z0-9_.:@+-]+) -->([^<\n]*)<!-- /r -->")
TABLE = re.compile(r"^(<!-- results:table ([A-Za-z0-9_]+) -->\n)(.*?)^(<!-- /results -->)$", re.S | re.M)


def stamp_line(data, sources):
    parts = []
    for name in sorted(sources):
        st = data["sources"][name]["stamp"]
        seeds = f", {st['seeds']}" if st.get("seeds") else ""
        # Outputs reused from another commit (with the same product code) say so.
        made = sorted({c["commit"] for c in st.get("commands", [])
                       if c.get("reused") and c.get("commit") and c["commit"] != st["commit"]})
        reused = f", outputs of {', '.join(made)} reused" if made else ""
        parts.append(f"`{name}` ({st['commit']}{reused}{seeds}, {st['date']}, {st['machine']})")
    return ("*Generated by `scripts/results.py` from " + "; ".join(parts) +
            ": docs/results/results.json.*")


def render_text(text, data, path, errors):
    """The document with every marked region filled from data; unknown keys or tables go
    to errors as 'path:line: ...'."""

    def line_of(pos):
        return text.count("\n", 0, pos) + 1

    def table(match):
        name = match.group(2)
        if name not in TABLES:
            errors.append(f"{path}:{line_of(match.start())}: unknown table '{name}' "
                          f"(scripts/results.py TABLES)")
            return match.group(0)
        V = Values(data)
        try:
            body = TABLES[name](V)
        except KeyError as e:
            errors.append(f"{path}:{line_of(match.start())}: table '{name}' needs value {e} "
                          f"that docs/results/results.json does not hold (run scripts/results.py)")
            return match.group(0)
        return f"{match.group(1)}{body}\n\n{stamp_line(data, V.used)}\n{match.group(4)}"

    text = TABLE.sub(table, text)
    V = Values(data)

    def inline(match):
        key = match.group(1)
        if key not in V:
            errors.append(f"{path}:{line_of(match.start())}: unknown value '{key}' "
                          f"(not in docs/results/results.json)")
            return match.group(0)
        return f"<!-- r:{key} -->{V(key)}<!-- /r -->"

    return INLINE.sub(inline, text)


def region_differences(path, current, rendered):
    """file:line and key of each marked region whose text differs from the rendered one."""
    out = []
    cur_regions = [(m.start(), m.group(1), m.group(2)) for m in INLINE.finditer(current)]
    new_regions = [(m.group(1), m.group(2)) for m in INLINE.finditer(rendered)]
    for (pos, key, text), (_, want) in zip(cur_regions, new_regions):
        if text != want:
            out.append(f"{path}:{current.count(chr(10), 0, pos) + 1}: value r:{key} is '{text}' "
                       f"here, '{want}' in docs/results/results.json")
    cur_tables = [(m.start(3), m.group(2), m.group(3)) for m in TABLE.finditer(current)]
    new_tables = [m.group(3) for m in TABLE.finditer(rendered)]
    for (pos, name, body), want in zip(cur_tables, new_tables):
        if body == want:
            continue
        have_lines, want_lines = body.split("\n"), want.split("\n")
        offset = next((i for i, (a, b) in enumerate(zip(have_lines, want_lines)) if a != b),
                      min(len(have_lines), len(want_lines)) - 1)
        line = current.count("\n", 0, pos) + 1 + offset
        generated = want_lines[offset] if offset < len(want_lines) else ""
        out.append(f"{path}:{line}: table '{name}' differs from docs/results/results.json; "
                   f"generated line: '{generated}'")
    if not out and current != rendered:
        out.append(f"{path}: differs from its rendering outside the marked regions")
    return out


# The README states these numbers without measuring them: the scenario's inputs (fault
# onsets, the flight's distance to the wall). Every other number with a unit in a README
# paragraph that cites docs/RESULTS.md must be a marked, generated value.
README_GIVEN = ["diverges at 18 s", "turns noisy at 82 s", "diverges from 12 s", "0.6 m from it",
                "inflated 10x"]
MEASURED_NUMBER = re.compile(r"(?<![\w.])\d+(?:\.\d+)?(?:-\d+(?:\.\d+)?)?\s?(?:cm|mm|m|s|x|%|°)(?![\w])")


def unmarked_readme_numbers(text, path):
    out = []
    pos = 0
    for paragraph in re.split(r"\n\s*\n", text):
        start = text.index(paragraph, pos)
        pos = start + len(paragraph)
        if "docs/RESULTS.md" not in paragraph:
            continue
        masked = INLINE.sub(lambda m: " " * len(m.group(0)), paragraph)
        masked = re.sub(r"`[^`]*`", lambda m: " " * len(m.group(0)), masked)
        for given in README_GIVEN:
            masked = masked.replace(given, " " * len(given))
        for m in MEASURED_NUMBER.finditer(masked):
            line = text.count("\n", 0, start + m.start()) + 1
            out.append(f"{path}:{line}: '{m.group(0)}' is stated as measured (its paragraph cites "
                       f"docs/RESULTS.md) but is not a generated value: mark it "
                       f"<!-- r:KEY -->…<!-- /r --> (scripts/results.py), or list it in README_GIVEN "
                       f"if it is a scenario input")
    return out


def broken_markers(text, path):
    """Markers that open a region no rule matches (a closing marker deleted, a value
    spread over lines): their numbers would otherwise go unchecked."""
    out = []
    inline = {m.start() for m in INLINE.finditer(text)}
    for m in re.finditer(r"<!-- r:", text):
        if m.start() not in inline:
            out.append(f"{path}:{text.count(chr(10), 0, m.start()) + 1}: a value marker without "
                       f"its '<!-- /r -->' on the same line")
    tables = {m.start() for m in TABLE.finditer(text)}
    for m in re.finditer(r"^<!-- results:table ", text, re.M):
        if m.start() not in tables:
            out.append(f"{path}:{text.count(chr(10), 0, m.start()) + 1}: a table marker without "
                       f"its '<!-- /results -->' line")
    return out


def check(root, data):
    problems = []
    for rel in DOCS:
        path = root / rel
        current = path.read_text()
        problems += broken_markers(current, rel)
        errors = []
        rendered = render_text(current, data, rel, errors)
        problems += errors
        if rendered != current:
            problems += region_differences(rel, current, rendered)
        if rel.name == "README.md":
            problems += unmarked_readme_numbers(current, rel)
    return problems


def write_docs(root, data):
    problems = []
    for rel in DOCS:
        path = root / rel
        current = path.read_text()
        rendered = render_text(current, data, rel, problems)
        if rendered != current:
            path.write_text(rendered)
            print(f"results: rewrote {rel}")
    return problems


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="\n".join(__doc__.split("\n")[1:]))
    parser.add_argument("--only", action="append", choices=sorted(SOURCES), help="run this source only")
    parser.add_argument("--tofu", default="build/tofu")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--runs", default="runs/results")
    parser.add_argument("--reuse", action="store_true")
    parser.add_argument("--euroc", default=str(EUROC),
                        help="the EuRoC V1_02 excerpt (default ../shared/data/euroc_v1_02, from --root)")
    parser.add_argument("--render", action="store_true", help="rewrite the docs from results.json only")
    parser.add_argument("--check", action="store_true", help="compare the docs with results.json only")
    parser.add_argument("--root", default=str(SCRIPT_ROOT))
    args = parser.parse_args()
    root = pathlib.Path(args.root).resolve()
    data_path = root / DATA
    try:
        data = load_json(data_path) if data_path.exists() else {"sources": {}}
        if args.check:
            problems = check(root, data)
            for p in problems:
                print(p, file=sys.stderr)
            if problems:
                print(f"results: {len(problems)} difference(s) between the docs and {DATA}; "
                      "regenerate with scripts/results.py (or --render)", file=sys.stderr)
                return 1
            print(f"results: README.md and docs/RESULTS.md agree with {DATA}")
            return 0
        if not args.render:
            runner_args = args
            version, commit = tofu_version(
                str(pathlib.Path(args.tofu).resolve()) if os.sep in args.tofu else args.tofu, root)
            for name in args.only or list(SOURCES):
                source = SOURCES[name]
                r = Runner(runner_args, root, commit)
                print(f"results: {name}: {source['describe']}", flush=True)
                source["run"](r)
                values = source["extract"](r)
                # Re-read: another results.py (--only) may have stored a source meanwhile.
                if data_path.exists():
                    data = load_json(data_path)
                data["sources"][name] = {
                    "describe": source["describe"],
                    "stamp": {"commit": commit, "tofu": version,
                              "seeds": seeds_label(source["seeds"]) if source["seeds"] else None,
                              "date": min(c["started"] for c in r.commands)[:10], "machine": machine(),
                              "seconds": round(r.seconds, 1), "commands": r.commands},
                    "values": dict(sorted(values.items())),
                }
                print(f"results: {name}: {len(values)} values, {r.seconds:.0f} s", flush=True)
                data["sources"] = dict(sorted(data["sources"].items()))
                data_path.parent.mkdir(parents=True, exist_ok=True)
                data_path.write_text(json.dumps(data, indent=1, ensure_ascii=False) + "\n")
        problems = write_docs(root, data)
        for p in problems:
            print(p, file=sys.stderr)
        return 2 if problems else 0
    except (ResultsError, subprocess.CalledProcessError, OSError) as e:
        print(f"results: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

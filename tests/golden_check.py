#!/usr/bin/python3
"""Ground-truth runs unchanged by the run-loop redesign: every file of every scenario's run
directory (timing files and figures aside) has the SHA-256 recorded in
tests/data/golden_runs.json, which was made with the code before the estimators moved into
the run loop (the post-pass over the written CSVs); re-recorded since when every run
directory gained its marker file .tofu-run (nothing else differed), and when the estimator
learnt to start in flight from a visual-inertial alignment and to report its start, the
stream weights, IMU gaps and tilt error (issue 21: only the estimates and what is derived
from them differed, estimate_*, decisions.csv, consistency_consensus.csv, errors.csv,
summary.json; every sensor stream, the ground truth and the tracking are unchanged), and
for the scenario.yaml of estimator_arena and paper_consensus_indoor when a zero attitude
angle stopped being written as ±1e-15 deg (fuzz finding 4), and for the consensus runs
(bridge_inspection, indoor_outdoor_window, paper_consensus_indoor, wall_contact_inspection)
when consensus learnt to restart an inconsistent sensor's alignment and to return to the
preferred sensor (issue 16: only the consensus estimate and what derives from it, and the
resolved scenario.yaml's `fuse`/`return_to_priority` keys, differed), and again when a
sensor fused again took back its earlier frame alignment and `position_factors` joined the
resolved scenario (bridge_inspection's consensus estimate, paper_consensus_indoor's
estimate_consensus.json, every estimation scenario's scenario.yaml), and when a restarted
alignment kept its frame as a candidate (wall_contact_inspection's summary.json: its
consensus values) and bridge_sensors asserted the time without RTK (its scenario.yaml and
summary.json: the expectation, nothing flown differed), and when calibration.yaml gained
the GNSS sky (`sky_directions_S`, issue 18: the renderer reads it from the run directory;
the calibration.yaml of bridge_sensors, indoor_outdoor_window and window_sensors, one added
line each, nothing else differed), and when calibration.yaml gained `mission:` (issue 34:
the launch pad and the surveyed frames every estimator is told; each calibration.yaml is
the golden one with that section appended, checked before re-recording, nothing else
differed), and when each method's summary gained the median NEES and the 95 % containment
of its position covariance (issue 34 item 4: the summary.json of bridge_inspection,
indoor_outdoor_window, paper_consensus_indoor and wall_contact_inspection, two keys per
method added, nothing else differed), and when each method's summary and estimate JSON
gained the largest step of its position error (issue 34 item 2, continuity: the
summary.json and estimate_*.json of the same four, two keys per method added, checked
against the previous binary's run with those keys removed, nothing else differed), and
when the LiDAR odometry's twist covariance started to state its scan's degeneracy (issue 34
item 3: the lio/lidar CSVs of wall_contact_inspection and wall_sensors, whose LiDAR
odometry is degenerate, differ only in the velocity block of cov_twist; every estimate is
unchanged, the paper's metric reading no covariance), and when every summary.json gained
`digests` (the samples the methods saw and the random streams, issue 52) and
`failure_kind` (issue 55): only the 16 summary.json files differed, each equal to the
golden one once those keys are removed (checked by re-serialising; every other file
byte-identical), and when the `estimation:` block came from its option table with a
profile (issue 54: the resolved block writes `profile` and every key; only the 14
scenario.yaml files of the scenarios with an estimation block differed, every estimate,
summary and stream byte-identical).

    golden_check.py GOLDEN_JSON CHECK_DIR [SOURCE_DIR]    compare (CHECK_DIR: what
                                                          `tofu check` wrote)
    golden_check.py --write GOLDEN_JSON CHECK_DIR [SOURCE_DIR]   record it as the golden set

SOURCE_DIR: the checkout the scenarios were given from; "SOURCE_DIR/" is removed from the
files' text before hashing (summary.json names each expectation's file as it was given),
so that the set holds for any clone.

A scenario of the golden set missing from CHECK_DIR, a file missing or added, or a file whose
hash differs fails the check (exit 1) and is named. Scenarios that are not in the golden set
(new ones) are not compared.
"""
import hashlib
import json
import pathlib
import sys


def skipped(relative: str) -> bool:
    name = pathlib.PurePath(relative).name
    return name.startswith("timing") or name.endswith(".png") or name.endswith(".log")


def hashes(run_dir: pathlib.Path, source_prefix: bytes) -> dict:
    out = {}
    for path in sorted(run_dir.rglob("*")):
        if not path.is_file():
            continue
        relative = path.relative_to(run_dir).as_posix()
        if skipped(relative):
            continue
        data = path.read_bytes()
        if source_prefix:
            data = data.replace(source_prefix, b"")
        out[relative] = hashlib.sha256(data).hexdigest()
    return out


def runs(check_dir: pathlib.Path) -> dict:
    """scenario/seed_N -> run directory, for every run directory under check_dir."""
    found = {}
    for summary in sorted(check_dir.glob("*/seed_*/summary.json")):
        run = summary.parent
        found[f"{run.parent.name}/{run.name}"] = run
    return found


def main(argv: list) -> int:
    write = len(argv) > 1 and argv[1] == "--write"
    args = argv[2:] if write else argv[1:]
    if len(args) not in (2, 3):
        print(__doc__, file=sys.stderr)
        return 2
    golden_path, check_dir = pathlib.Path(args[0]), pathlib.Path(args[1])
    prefix = (str(pathlib.Path(args[2]).resolve()) + "/").encode() if len(args) == 3 else b""
    if write:
        golden = {key: hashes(run, prefix) for key, run in runs(check_dir).items()}
        golden_path.write_text(json.dumps(golden, indent=1, sort_keys=True) + "\n")
        print(f"golden_check: recorded {len(golden)} runs into {golden_path}")
        return 0
    golden = json.loads(golden_path.read_text())
    found = runs(check_dir)
    failures = []
    for key, expected in sorted(golden.items()):
        if key not in found:
            failures.append(f"{key}: no run directory under {check_dir}")
            continue
        actual = hashes(found[key], prefix)
        for name in sorted(set(expected) | set(actual)):
            if name not in actual:
                failures.append(f"{key}/{name}: missing")
            elif name not in expected:
                failures.append(f"{key}/{name}: new file")
            elif expected[name] != actual[name]:
                failures.append(f"{key}/{name}: differs from the golden run")
    for f in failures:
        print(f"golden_check: FAIL: {f}", file=sys.stderr)
    if failures:
        return 1
    print(f"golden_check: {len(golden)} runs byte-identical to the golden set")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))

#!/usr/bin/python3
"""Ground-truth runs unchanged unless a change means them to be: every file of every
scenario's seed-1 run directory (timing files and figures aside) has the SHA-256 recorded in
tests/data/golden_runs.json. A deliberate change that alters a golden file re-records the set
in the commit that makes the change, and that commit's message names which files differed
and why (`git log tests/data/golden_runs.json` is the history of every re-recording).

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

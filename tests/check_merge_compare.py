#!/usr/bin/env python3
"""Whether a merged sharded `tofu check` wrote what one machine wrote over the same grid.

    check_merge_compare.py --junit ONE MERGED [--out ONE MERGED] [--report ONE MERGED]

--junit: the two JUnit files, equal once every time="..." attribute (the runs' wall clock,
the only field that may differ) is emptied. --out: the two check directories' method tables
(methods.csv, methods.md, methods.png), byte for byte, present in both or in neither.
--report: the two HTML report directories (`tofu check --report`): the same files, byte for
byte. Exit 0 when all is equal, 1 with the first difference of each file otherwise, 2 on
misuse. Used by check_shard_test and slurm_check_check.sh: one rule for what is stripped.
"""
import argparse
import difflib
import pathlib
import re
import sys

WALL_CLOCK = re.compile(rb' time="[0-9.]*"')
METHOD_TABLES = ("methods.csv", "methods.md", "methods.png")


def first_difference(name, one, merged):
    """A few lines of unified diff, or a note for binary files."""
    try:
        a = one.decode().splitlines()
        b = merged.decode().splitlines()
    except UnicodeDecodeError:
        return f"{name}: binary files differ ({len(one)} vs {len(merged)} bytes)"
    diff = list(difflib.unified_diff(a, b, "one machine", "merged", n=1, lineterm=""))
    return f"{name}:\n  " + "\n  ".join(diff[:12])


def compare_bytes(name, one, merged, problems):
    if one != merged:
        problems.append(first_difference(name, one, merged))


def compare_files(one_path, merged_path, problems):
    one_path, merged_path = pathlib.Path(one_path), pathlib.Path(merged_path)
    if one_path.exists() != merged_path.exists():
        problems.append(f"{one_path.name}: present in {'one' if one_path.exists() else 'merged'} only")
        return 0
    if not one_path.exists():
        return 0
    compare_bytes(str(merged_path), one_path.read_bytes(), merged_path.read_bytes(), problems)
    return 1


def compare_trees(one, merged, problems):
    one, merged = pathlib.Path(one), pathlib.Path(merged)
    files = lambda root: {p.relative_to(root) for p in root.rglob("*") if p.is_file()}
    a, b = files(one), files(merged)
    for only, where in ((a - b, "one machine's"), (b - a, "the merge's")):
        if only:
            problems.append(f"only in {where} report: {', '.join(sorted(map(str, only))[:10])}")
    for rel in sorted(a & b):
        compare_bytes(str(merged / rel), (one / rel).read_bytes(), (merged / rel).read_bytes(), problems)
    return len(a & b)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--junit", nargs=2, required=True, metavar=("ONE", "MERGED"))
    parser.add_argument("--out", nargs=2, metavar=("ONE", "MERGED"))
    parser.add_argument("--report", nargs=2, metavar=("ONE", "MERGED"))
    args = parser.parse_args()
    problems = []
    one, merged = (pathlib.Path(p).read_bytes() for p in args.junit)
    compare_bytes(args.junit[1], WALL_CLOCK.sub(b' time=""', one), WALL_CLOCK.sub(b' time=""', merged), problems)
    compared = 1
    if args.out:
        for name in METHOD_TABLES:
            compared += compare_files(pathlib.Path(args.out[0]) / name, pathlib.Path(args.out[1]) / name, problems)
    if args.report:
        compared += compare_trees(args.report[0], args.report[1], problems)
    if problems:
        print("the merge differs from one machine:\n" + "\n".join(problems), file=sys.stderr)
        return 1
    print(f"merge equals one machine: {compared} files compared (JUnit without time=)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""Soak run (issue 19): fly a long scenario and report its memory and speed over time.

    scripts/soak.py [--tofu build/tofu] [--scenario bench/soak_1h.yaml]
                    [--out runs/soak] [--json FILE]

Runs `tofu run` once and prints, per simulated minute, the real-time factor and the
resident set at the minute's end (both from the run's timing.json, which the run loop
fills), then the peak resident set of the tofu process itself (its VmHWM, polled twice a
second: it includes scoring and writing the run directory after the flight) and, apart,
the largest of the processes it starts (the figure scripts, which run while tofu waits),
the wall time and the run directory's size. The markdown table goes to
docs/BENCHMARKS.md by hand, with the machine and the date.
"""
import argparse
import json
import os
import resource
import subprocess
import sys
import time


def directory_bytes(path):
    total = 0
    for root, _, files in os.walk(path):
        for name in files:
            total += os.path.getsize(os.path.join(root, name))
    return total


def vm_hwm_mb(pid):
    """The peak resident set of a live process (VmHWM), MB; None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def run_and_watch(command):
    """Runs `command`; returns (exit status, its own peak MB, the largest descendant's MB)."""
    process = subprocess.Popen(command)
    own_mb = 0.0
    while process.poll() is None:
        own_mb = max(own_mb, vm_hwm_mb(process.pid) or 0.0)
        time.sleep(0.5)
    # Every descendant was waited for by its parent: the largest of them, from the kernel.
    descendants_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return process.returncode, own_mb, descendants_mb


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tofu", default="build/tofu")
    parser.add_argument("--scenario", default="bench/soak_1h.yaml")
    parser.add_argument("--out", default="runs/soak")
    parser.add_argument("--json", help="also write the figures as JSON to this file")
    args = parser.parse_args()

    command = [args.tofu, "run", args.scenario, "--out", args.out, "--force", "--quiet"]
    print("soak:", " ".join(command), flush=True)
    start = time.monotonic()
    status, peak_mb, descendants_mb = run_and_watch(command)
    wall_s = time.monotonic() - start
    if status not in (0, 1):  # 1: an expectation failed; the figures still count
        print(f"soak: tofu run exited {status}", file=sys.stderr)
        return status
    with open(os.path.join(args.out, "timing.json")) as f:
        timing = json.load(f)
    minutes = timing["minutes"]
    figures = {
        "scenario": args.scenario,
        "simulated_s": timing["simulated_s"],
        "flight_wall_time_s": timing["wall_time_s"],
        "total_wall_time_s": wall_s,
        "real_time_factor": timing["real_time_factor"],
        "peak_resident_mb": peak_mb,
        "largest_process_mb": descendants_mb,
        "output_mb": directory_bytes(args.out) / 1e6,
        "minutes": minutes,
    }
    print("| minute | real-time factor | resident [MB] |")
    print("|---:|---:|---:|")
    for m in minutes:
        print(f"| {m['minute']} | {m['real_time_factor']:.1f} | {m['resident_mb']:.0f} |")
    rtf = sorted(m["real_time_factor"] for m in minutes)
    if rtf:
        print(f"\nper-minute real-time factor: min {rtf[0]:.1f}, median {rtf[len(rtf) // 2]:.1f},"
              f" max {rtf[-1]:.1f}")
    if len(minutes) >= 2:
        growth = (minutes[-1]["resident_mb"] - minutes[0]["resident_mb"]) / (len(minutes) - 1)
        print(f"resident set growth: {growth:.1f} MB per simulated minute")
    print(f"simulated {figures['simulated_s']:.0f} s: flight {figures['flight_wall_time_s']:.0f} s,"
          f" whole run {wall_s:.0f} s wall; peak resident set of tofu {peak_mb:.0f} MB (largest"
          f" process including the figure scripts {descendants_mb:.0f} MB);"
          f" run directory {figures['output_mb']:.0f} MB")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(figures, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

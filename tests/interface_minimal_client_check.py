#!/usr/bin/python3
"""ctest interface_minimal_client: the minimal estimator of docs/INTERFACE.md ("A minimal
estimator to copy"), exactly as the document prints it, flies beside consensus in a short
run and is scored: the document's client cannot drift from the protocol.

Usage: interface_minimal_client_check.py TOFU SOURCE_DIR WORK_DIR"""
import json
import pathlib
import re
import shutil
import subprocess
import sys

SCENARIO = """name: minimal_client
world: indoor_arena
duration_s: 6
seed: 1
trajectory:
  start: {position_m: [0, 0, 1.5]}
  segments:
    - hover: {duration_s: 1}
    - line: {to_m: [1.5, 0, 1.5]}
sensors:
  imu: {}
  vio: {}
  leica: {type: total_station}
external:
  mine: {command: [/usr/bin/python3, mine.py]}
estimation:
  methods: [consensus, "external:mine"]
"""


def main():
    tofu, source, work = sys.argv[1], pathlib.Path(sys.argv[2]), pathlib.Path(sys.argv[3])
    text = (source / "docs/INTERFACE.md").read_text()
    match = re.search(r"<!-- minimal-client -->\n```python\n(.*?)```", text, re.S)
    if not match:
        print("docs/INTERFACE.md: no ```python block after <!-- minimal-client -->", file=sys.stderr)
        return 1
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    (work / "mine.py").write_text(match.group(1))
    (work / "s.yaml").write_text(SCENARIO)
    run = subprocess.run([tofu, "run", "s.yaml", "--out", "R", "--quiet"], cwd=work,
                         capture_output=True, text=True)
    if run.returncode != 0:
        print(f"tofu run exited {run.returncode}:\n{run.stderr}", file=sys.stderr)
        return 1
    method = json.loads((work / "R/summary.json").read_text())["methods"]["external:mine"]
    if "failure" in method or not isinstance(method.get("ate_m"), (int, float)) or \
            not method.get("valid_fraction"):
        print(f"the minimal client was not scored: {json.dumps(method)[:400]}", file=sys.stderr)
        return 1
    print(f"interface_minimal_client: scored, ATE {method['ate_m']:.3f} m, valid "
          f"{method['valid_fraction']:.2f}")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env bash
# The Python side of the corpora (issue 17, item 5): the smoke corpus generated as two
# shards and verified, then read by python/tofu_corpus.py -- its summary counts the 4
# episodes, and the window labels agree with the event table both ways (every scheduled
# event labels a window of its sensor; every labelled fault lies on an event of its sensor
# and kind; a window emptied by a dropout is labelled dropout although no sample carries
# the mask) -- bad corpus directories are exit 2 naming the file, and
# python/train_detector.py runs end to end on it (train = eval = smoke: this proves it runs,
# the numbers are not checked), writes its table and JSON, and judges no window from a
# sample later than the window.
#   corpus_python_check.sh TOFU SOURCE_DIR WORK_DIR
set -euo pipefail
tofu="$1"
source_dir="$2"
work="$3"
python="${TOFU_PYTHON:-/usr/bin/python3}"  # Debian's: python3-h5py, -numpy, -sklearn
export PYTHONDONTWRITEBYTECODE=1  # no __pycache__ in the source tree

fail() { echo "corpus_python_check: FAIL: $*" >&2; exit 1; }
"$python" -c 'import h5py, numpy, sklearn' ||
  fail "$python lacks h5py/numpy/sklearn (apt-get install python3-h5py python3-sklearn)"

rm -rf "$work"
mkdir -p "$work"
corpus="$work/smoke"
for shard in 0/2 1/2; do
  "$tofu" corpus generate "$source_dir/corpora/smoke.yaml" --out "$corpus" --shard "$shard" \
    > "$work/generate.log" 2>&1 || fail "generate shard $shard: exit $? ($(tail -n 3 "$work/generate.log"))"
done
"$tofu" corpus verify "$corpus" > "$work/verify.log" 2>&1 || fail "verify: $(cat "$work/verify.log")"

# The summary: 4 episodes, every scheduled event labels a window.
"$python" "$source_dir/python/tofu_corpus.py" "$corpus" --json > "$work/summary.json" ||
  fail "tofu_corpus.py --json: exit $?"
"$python" - "$work/summary.json" <<'EOF' || fail "summary"
import json, sys
s = json.load(open(sys.argv[1]))
assert s["episodes"] == 4, f"episodes {s['episodes']}, expected 4"
assert s["shards"] == 2, f"shards {s['shards']}, expected 2"
assert abs(s["flight_hours"] - 4 * 12 / 3600) < 1e-9, s["flight_hours"]
assert not s["scheduled_events_without_label"], s["scheduled_events_without_label"]
assert any(k.endswith(":dropout") for k in s["labels"]), "no dropout label: " + str(s["labels"])
print("corpus_python_check: summary:", s["episodes"], "episodes,", s["sensor_windows"],
      "sensor windows")
EOF
"$python" "$source_dir/python/tofu_corpus.py" "$corpus" > "$work/summary.txt" ||
  fail "tofu_corpus.py: exit $?"
grep -q '^episodes: 4 of 4 planned$' "$work/summary.txt" || fail "text summary: $(head -n 3 "$work/summary.txt")"

# Labels against the event table, recomputed here from the raw windows (not the summary's
# own bookkeeping): both directions, for two window layouts.
PYTHONPATH="$source_dir/python" "$python" - "$corpus" <<'EOF' || fail "labels disagree with the events"
import sys
import numpy as np
import tofu_corpus as tc

checked = empty_dropout = 0
with tc.Corpus(sys.argv[1]) as corpus:
    assert len(corpus) == 4
    scheduled = 0
    for ep in corpus.episodes():
        events = ep.events()
        for window_s, hop_s in ((1.0, 0.5), (0.3, 0.3)):
            windows = list(ep.windows(window_s, hop_s))
            assert len(windows) == len(ep.window_bounds(window_s, hop_s)) > 0
            for e in events:
                hits = [w for w in windows if e.kind in w.sensors[e.sensor].labels]
                inside = [w for w in windows if e.overlaps(w.start_ns, w.end_ns)]
                assert not inside or hits, f"{ep.id}: {e} labels no window ({window_s} s)"
                scheduled += e.cause == "scheduled"
            for w in windows:
                for name, sw in w.sensors.items():
                    for kind in sw.labels:
                        assert any(o.sensor == name and o.kind == kind and
                                   o.overlaps(w.start_ns, w.end_ns) for o in events), \
                            f"{ep.id} {name} window {w.start_ns}: '{kind}' without an event"
                    assert np.all(np.diff(sw.t_ns) > 0)
                    assert np.all((sw.t_ns >= w.start_ns) & (sw.t_ns < w.end_ns))
                    if "dropout" in sw.faults and len(sw.t_ns) == 0:
                        empty_dropout += 1
                    checked += 1
            # consensus decisions sliced to the window
            for w in windows:
                d = w.decisions["consensus"]
                assert np.all((d.t_ns >= w.start_ns) & (d.t_ns < w.end_ns))
assert scheduled > 0, "smoke has no scheduled event: nothing was checked"
assert empty_dropout > 0, "no window emptied by a dropout was labelled dropout"
print(f"corpus_python_check: labels: {checked} sensor windows agree with the events "
      f"({empty_dropout} empty windows labelled dropout)")
EOF

# Bad corpus directories: exit 2, the message names what is wrong.
expect_refused() {  # DIR WHAT
  set +e
  "$python" "$source_dir/python/tofu_corpus.py" "$1" > /dev/null 2> "$work/err.txt"
  local status=$?
  set -e
  [[ $status -eq 2 ]] || fail "$2: exit $status, expected 2"
  grep -qF "$1" "$work/err.txt" || fail "$2: the message does not name $1: $(cat "$work/err.txt")"
}
expect_refused "$work/missing" "a missing directory"
mkdir -p "$work/no_spec" && cp "$corpus"/shard_*.h5 "$work/no_spec/"
expect_refused "$work/no_spec/shard_0000_of_0002.h5" "a file instead of a directory"
expect_refused "$work/no_spec" "no corpus.yaml"
grep -q "corpus.yaml" "$work/err.txt" || fail "no corpus.yaml: message $(cat "$work/err.txt")"
mkdir -p "$work/broken" && cp "$corpus/corpus.yaml" "$work/broken/"
echo "not hdf5" > "$work/broken/shard_0000_of_0001.h5"
expect_refused "$work/broken" "a broken shard"
grep -q "shard_0000_of_0001.h5" "$work/err.txt" || fail "broken shard: message $(cat "$work/err.txt")"

# The detector end to end (smoke as both train and eval: it runs, writes, exits 0).
"$python" "$source_dir/python/train_detector.py" "$corpus" "$corpus" --out "$work/detector" \
  > "$work/detector.txt" 2> "$work/detector.err" || fail "train_detector.py: exit $? ($(tail -n 5 "$work/detector.err"))"
[[ -s "$work/detector/results.md" ]] || fail "no results.md"
grep -q '^| all faults |' "$work/detector/results.md" || fail "results.md has no 'all faults' row"
grep -q '^| dropout |' "$work/detector/results.md" || fail "results.md has no dropout row"
"$python" - "$work/detector/results.json" <<'EOF' || fail "results.json"
import json, sys
r = json.load(open(sys.argv[1]))
assert r["train"]["episodes"] == r["eval"]["episodes"] == 4
for method in ("detector", "consensus"):
    row = r[method]["all faults"]
    assert row["windows"] > 0 and row["events"] > 0, row
    assert row["recall"] is not None and 0.0 <= row["recall"] <= 1.0, row
EOF
# The detector is causal: altering every sample after a time t_cut (positions moved 5 m,
# reported covariances x100) changes neither the grid values at or before t_cut nor any
# feature of a window that ends by t_cut. A grid filled by interpolation towards the next
# sample, or a variance averaged over the whole stream, fails it.
PYTHONPATH="$source_dir/python" "$python" - "$corpus" <<'EOF' || fail "the detector looks ahead"
import dataclasses, sys
import numpy as np
import tofu_corpus as tc
import train_detector as td


def altered(stream, cut_ns):
    after = stream.t_ns > cut_ns
    values = stream.values.copy()
    values[after, :3] += 5.0
    cov = None if stream.covariance is None else stream.covariance.copy()
    if cov is not None:
        cov[after] *= 100.0
    return dataclasses.replace(stream, values=values, covariance=cov)


class Altered:
    """An episode whose position streams are altered after cut_ns."""
    def __init__(self, ep, cut_ns):
        self._ep, self._cut = ep, cut_ns

    def __getattr__(self, name):
        return getattr(self._ep, name)

    def stream(self, name):
        st = self._ep.stream(name)
        return altered(st, self._cut) if st.type in td.POSITION_TYPES else st


def same(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.all((a == b) | (np.isnan(a) & np.isnan(b))))


# The grid of one stream sampled off the grid (period 0.1 s, first sample at 0.037 s).
t_ns = (37_000_000 + 100_000_000 * np.arange(60)).astype(np.int64)
values = np.column_stack([np.arange(60.0), np.zeros(60), np.zeros(60)])
stream = tc.Stream(name="s", type="lidar_odometry", t_ns=t_ns, arrival_ns=t_ns,
                   values=values, covariance=np.full((60, 6), 1e-4),
                   fault_mask=np.zeros(60, np.uint32), condition_mask=np.zeros(60, np.uint32),
                   fault_bits=(), condition_bits=(), columns="")
grid_t = np.arange(0.0, 6.0 + 1e-9, td.GRID_S)
base = td.SensorTrack(stream, grid_t).grid
assert np.isnan(base[0]).all(), "a grid time before the first sample has a value"
assert base[1, 0] == 0.0 and base[5, 0] == 4.0, "the grid is not the newest sample before it"
for cut in (1_000_000_000, 2_437_000_000, 3_050_000_000):
    grid = td.SensorTrack(altered(stream, cut), grid_t).grid
    upto = np.round(grid_t * 1e9).astype(np.int64) <= cut
    assert same(grid[upto], base[upto]), f"grid at or before {cut} ns changed"
    assert not same(grid, base), f"altering after {cut} ns changed nothing"

# Every feature of every window of each smoke episode, its streams altered after t_cut.
checked = 0
with tc.Corpus(sys.argv[1]) as corpus:
    for ep in corpus.episodes():
        cut_ns = int(0.55 * ep.duration_s * 1e9) + 3_000_000  # not on the grid
        rows, _ = td.episode_rows(ep)
        rows_altered, _ = td.episode_rows(Altered(ep, cut_ns))
        assert len(rows) == len(rows_altered)
        changed = 0
        for r, q in zip(rows, rows_altered):
            if r["end_ns"] <= cut_ns:
                bad = [k for k, x, y in zip(td.FEATURES, r["x"], q["x"]) if not same(x, y)]
                assert not bad, f"{ep.id} {r['sensor']} window ending {r['end_ns']} ns: {bad}"
                checked += 1
            else:
                changed += not same(r["x"], q["x"])
        assert changed, f"{ep.id}: altering the streams changed no later window"
assert checked > 0
print(f"corpus_python_check: causal: {checked} sensor windows unchanged by later samples")
EOF
echo "corpus_python_check: detector: $(grep -m 1 '^| all faults |' "$work/detector/results.md")"
echo "corpus_python_check: PASS"

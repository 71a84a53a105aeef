#!/usr/bin/python3
"""Read a tofu failure corpus (docs/CORPUS.md) with h5py and numpy only.

Why this exists: the HDF5 schema stores each stream at its own rate and keeps the truth in
two forms (per-sample masks, and an event table that also holds what left no sample behind,
e.g. a dropout). Every learning experiment on a corpus needs the same two steps -- cut the
streams of an episode into common time windows, and say which fault kinds and conditions
are active in each window for each sensor -- and getting the second step subtly wrong
(forgetting dropouts, which have no samples to carry a mask) silently biases any detector
trained on it. This module does both once, so that the detector and the tests read the
corpus the same way.

    corpus = Corpus("/tmp/detector_train")          # checks corpus.yaml and the shards
    for episode in corpus.episodes():
        for window in episode.windows(window_s=1.0, hop_s=0.5):
            window.sensors["lio"].labels              # e.g. frozenset({"jump"})
            window.excluded("lio")                    # consensus excluded lio in the window

Run as a script for a summary: ``python3 python/tofu_corpus.py CORPUS_DIR [--json]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
from collections import Counter
from typing import Iterator

import h5py
import numpy as np

SCHEMA_VERSION = 1
_SHARD_RE = re.compile(r"^shard_(\d{4})_of_(\d{4})\.h5$")
_FAULT_LINE_RE = re.compile(
    r"^\s*-\s*\{sensor:\s*([A-Za-z0-9_]+),\s*kind:\s*([a-z_]+),\s*start_s:\s*([-0-9.e+]+),"
    r"\s*end_s:\s*([-0-9.e+]+|\.inf)")

# Bit orders of the masks, as written by tofu (checked against each dataset's `bits` attr
# when an episode is read: a corpus from another schema must not be mislabelled silently).
FAULT_BITS = ("misalignment", "non_gaussian_noise", "divergence", "dropout", "freeze", "delay",
              "jump", "outliers")


class CorpusError(Exception):
    """A missing or invalid corpus; the message names the file or directory at fault."""


def _str(value) -> str:
    """HDF5 strings come back as bytes or str depending on how they were stored."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.ndarray) and value.shape == ():
        return _str(value.item())
    return str(value)


def _bit_names(dataset: h5py.Dataset, path: str) -> tuple[str, ...]:
    if "bits" not in dataset.attrs:
        raise CorpusError(f"{path}: {dataset.name} has no 'bits' attribute")
    return tuple(_str(dataset.attrs["bits"]).split(","))


def mask_names(mask: int | np.integer, bits: tuple[str, ...]) -> frozenset[str]:
    """The names of the bits set in `mask` (bit k = bits[k])."""
    mask = int(mask)
    return frozenset(name for k, name in enumerate(bits) if mask >> k & 1)


@dataclasses.dataclass(frozen=True)
class Event:
    """One row of an episode's event table (the truth)."""

    sensor: str
    kind: str
    cause: str  # "scheduled" | "physical"
    onset_ns: int
    offset_ns: int
    open: bool
    severity: float
    phase: str
    removes_samples: bool  # no sample of the sensor carries it: a dropout-like event

    def overlaps(self, start_ns: int, end_ns: int) -> bool:
        return self.onset_ns < end_ns and self.offset_ns > start_ns


@dataclasses.dataclass
class Stream:
    """One sensor's whole stream in an episode (arrays as stored; see docs/CORPUS.md)."""

    name: str
    type: str
    t_ns: np.ndarray
    arrival_ns: np.ndarray
    values: np.ndarray
    covariance: np.ndarray | None  # None for the IMU (it stores none)
    fault_mask: np.ndarray
    condition_mask: np.ndarray
    fault_bits: tuple[str, ...]
    condition_bits: tuple[str, ...]
    columns: str


@dataclasses.dataclass
class SensorWindow:
    """One sensor's samples in a window and what is active in it.

    `faults` and `conditions` are the truth for the window: the kinds set in the masks of its
    samples, plus the events that remove samples (dropouts) overlapping the window -- a
    dropout leaves no sample to carry its bit, so the masks alone would call the window
    clean exactly when the sensor is silent.
    """

    name: str
    type: str
    t_ns: np.ndarray
    values: np.ndarray
    covariance: np.ndarray | None
    fault_mask: np.ndarray
    condition_mask: np.ndarray
    faults: frozenset[str]
    conditions: frozenset[str]

    @property
    def labels(self) -> frozenset[str]:
        """Fault kinds and conditions active in the window (empty: clean)."""
        return self.faults | self.conditions


@dataclasses.dataclass
class Decisions:
    """A method's consensus decisions (predictions, not truth); masks' bits = `sensors`."""

    t_ns: np.ndarray
    fused_mask: np.ndarray
    excluded_mask: np.ndarray
    unavailable_mask: np.ndarray
    reason: list[str]
    sensors: tuple[str, ...]

    def slice(self, start_ns: int, end_ns: int) -> "Decisions":
        lo, hi = np.searchsorted(self.t_ns, [start_ns, end_ns], side="left")
        return Decisions(self.t_ns[lo:hi], self.fused_mask[lo:hi], self.excluded_mask[lo:hi],
                         self.unavailable_mask[lo:hi], self.reason[lo:hi], self.sensors)

    def _any(self, mask: np.ndarray, sensor: str) -> bool:
        bit = self.sensors.index(sensor)
        return bool(np.any((mask >> np.uint32(bit)) & np.uint32(1)))

    def excluded(self, sensor: str) -> bool:
        """True if any decision here excluded `sensor` (consensus's own detection)."""
        return self._any(self.excluded_mask, sensor)

    def unavailable(self, sensor: str) -> bool:
        return self._any(self.unavailable_mask, sensor)

    def fused(self, sensor: str) -> bool:
        return self._any(self.fused_mask, sensor)


@dataclasses.dataclass
class Window:
    """All streams of an episode in [start_ns, end_ns) with their labels."""

    episode_id: str
    index: int
    start_ns: int
    end_ns: int
    sensors: dict[str, SensorWindow]
    decisions: dict[str, Decisions]  # method -> its decisions in the window
    groundtruth: dict[str, np.ndarray]  # the truth; a detector must not read it

    def excluded(self, sensor: str, method: str = "consensus") -> bool:
        return self.decisions[method].excluded(sensor)


class Episode:
    """One episode of a shard; streams are read on first use and cached."""

    def __init__(self, group: h5py.Group, shard_path: str):
        self._group = group
        self.shard_path = shard_path
        self.attrs = {k: (_str(v) if isinstance(v, (bytes, str)) else v.item()
                          if isinstance(v, np.generic) else v) for k, v in group.attrs.items()}
        for key in ("id", "index", "scenario_yaml", "sensors", "duration_s"):
            if key not in self.attrs:
                raise CorpusError(f"{shard_path}: episode {group.name} has no attribute '{key}'")
        self.id: str = self.attrs["id"]
        self.index: int = int(self.attrs["index"])
        self.scenario_yaml: str = self.attrs["scenario_yaml"]
        self.world: str = self.attrs.get("world", "")
        self.family: str = self.attrs.get("family", "")
        self.duration_s: float = float(self.attrs["duration_s"])
        self.duration_ns: int = int(round(self.duration_s * 1e9))
        self.sensors: tuple[str, ...] = tuple(self.attrs["sensors"].split(","))
        self._streams: dict[str, Stream] = {}
        self._events: list[Event] | None = None

    def __repr__(self) -> str:
        return f"Episode({self.id!r}, world={self.world!r}, family={self.family!r})"

    def _need(self, path: str):
        if path not in self._group:
            raise CorpusError(f"{self.shard_path}: {self._group.name}/{path} is missing")
        return self._group[path]

    def stream(self, name: str) -> Stream:
        """The whole stream of sensor `name`."""
        if name not in self._streams:
            g = self._need(f"sensors/{name}")
            fault = g["fault_mask"]
            fault_bits = _bit_names(fault, self.shard_path)
            if fault_bits != FAULT_BITS:
                raise CorpusError(f"{self.shard_path}: {fault.name} bits {fault_bits} are not "
                                  f"schema {SCHEMA_VERSION}'s {FAULT_BITS}")
            self._streams[name] = Stream(
                name=name, type=_str(g.attrs.get("type", "")), t_ns=g["t_ns"][:],
                arrival_ns=g["arrival_ns"][:], values=g["values"][:],
                covariance=g["covariance"][:] if "covariance" in g else None,
                fault_mask=fault[:], condition_mask=g["condition_mask"][:],
                fault_bits=fault_bits,
                condition_bits=_bit_names(g["condition_mask"], self.shard_path),
                columns=_str(g["values"].attrs.get("columns", "")))
        return self._streams[name]

    def events(self) -> list[Event]:
        """The event table, each row marked whether it removes samples (see SensorWindow)."""
        if self._events is None:
            g = self._need("events")
            n = len(g["kind"])
            self._events = []
            for i in range(n):
                sensor, kind = _str(g["sensor"][i]), _str(g["kind"][i])
                onset, offset = int(g["onset_ns"][i]), int(g["offset_ns"][i])
                s = self.stream(sensor)
                if kind in s.fault_bits:
                    mask, bits = s.fault_mask, s.fault_bits
                else:
                    mask, bits = s.condition_mask, s.condition_bits
                lo, hi = np.searchsorted(s.t_ns, [onset, offset], side="left")
                flagged = kind in bits and bool(
                    np.any(mask[lo:hi] >> np.uint32(bits.index(kind)) & np.uint32(1)))
                self._events.append(Event(
                    sensor=sensor, kind=kind, cause=_str(g["cause"][i]), onset_ns=onset,
                    offset_ns=offset, open=bool(g["open"][i]), severity=float(g["severity"][i]),
                    phase=_str(g["phase"][i]), removes_samples=not flagged))
        return self._events

    def schedule(self) -> list[tuple[str, str, int, int]]:
        """The scheduled faults (sensor, kind, start_ns, end_ns) of the episode's scenario.

        Read from `scenario_yaml` (the corpus writes one flow map per fault). Why: it is the
        plan the events table is made from, and the table holds one event where two faults
        of one kind on one sensor overlap (tofu 0.1.0, corpus/episode_writer.cc
        FaultEvents); for sample-removing kinds the masks cannot show the lost one.
        """
        out = []
        in_faults = False
        for line in self.scenario_yaml.splitlines():
            if re.match(r"^faults:\s*(#.*)?$", line):
                in_faults = True
                continue
            if in_faults and re.match(r"^\S", line):
                break
            m = _FAULT_LINE_RE.match(line) if in_faults else None
            if m:
                end = float("inf") if m.group(4) == ".inf" else float(m.group(4))
                end_ns = min(self.duration_ns, int(round(end * 1e9))) if end != float("inf") \
                    else self.duration_ns
                out.append((m.group(1), m.group(2), int(round(float(m.group(3)) * 1e9)), end_ns))
        return out

    def methods(self) -> list[str]:
        return sorted(self._group["methods"]) if "methods" in self._group else []

    def decisions(self, method: str = "consensus") -> Decisions:
        g = self._need(f"methods/{method}/decisions")
        return Decisions(t_ns=g["t_ns"][:], fused_mask=g["fused_mask"][:],
                         excluded_mask=g["excluded_mask"][:],
                         unavailable_mask=g["unavailable_mask"][:],
                         reason=[_str(r) for r in g["reason"][:]], sensors=self.sensors)

    def groundtruth(self) -> dict[str, np.ndarray]:
        g = self._need("groundtruth")
        return {k: g[k][:] for k in g}

    def window_bounds(self, window_s: float, hop_s: float) -> list[tuple[int, int]]:
        """[start, end) of each whole window inside the episode, hop_s apart from 0."""
        if window_s <= 0 or hop_s <= 0:
            raise ValueError(f"window_s ({window_s}) and hop_s ({hop_s}) must be positive")
        w, h = int(round(window_s * 1e9)), int(round(hop_s * 1e9))
        return [(s, s + w) for s in range(0, self.duration_ns - w + 1, h)]

    def windows(self, window_s: float = 1.0, hop_s: float = 0.5,
                sensors: list[str] | None = None) -> Iterator[Window]:
        """Fixed-length windows of all streams (or `sensors`) with labels and decisions."""
        names = list(sensors) if sensors is not None else list(self.sensors)
        streams = {n: self.stream(n) for n in names}
        removing: dict[str, list[tuple[str, int, int]]] = {n: [] for n in names}
        for e in self.events():
            if e.removes_samples and e.sensor in removing:
                removing[e.sensor].append((e.kind, e.onset_ns, e.offset_ns))
        for sensor, kind, start, end in self.schedule():  # what the table lost (see schedule)
            if kind == "dropout" and sensor in removing:
                removing[sensor].append((kind, start, end))
        decisions = {m: self.decisions(m) for m in self.methods()
                     if f"methods/{m}/decisions" in self._group}
        gt = self.groundtruth()
        for index, (start, end) in enumerate(self.window_bounds(window_s, hop_s)):
            per_sensor = {}
            for n, s in streams.items():
                lo, hi = np.searchsorted(s.t_ns, [start, end], side="left")
                fm = s.fault_mask[lo:hi]
                cm = s.condition_mask[lo:hi]
                faults = set(mask_names(np.bitwise_or.reduce(fm) if len(fm) else 0, s.fault_bits))
                conditions = set(mask_names(np.bitwise_or.reduce(cm) if len(cm) else 0,
                                            s.condition_bits))
                for kind, onset, offset in removing[n]:
                    if onset < end and offset > start:
                        (faults if kind in s.fault_bits else conditions).add(kind)
                per_sensor[n] = SensorWindow(
                    name=n, type=s.type, t_ns=s.t_ns[lo:hi], values=s.values[lo:hi],
                    covariance=None if s.covariance is None else s.covariance[lo:hi],
                    fault_mask=fm, condition_mask=cm, faults=frozenset(faults),
                    conditions=frozenset(conditions))
            glo, ghi = np.searchsorted(gt["t_ns"], [start, end], side="left")
            yield Window(episode_id=self.id, index=index, start_ns=start, end_ns=end,
                         sensors=per_sensor,
                         decisions={m: d.slice(start, end) for m, d in decisions.items()},
                         groundtruth={k: v[glo:ghi] for k, v in gt.items()})


class Corpus:
    """A corpus directory: corpus.yaml plus every finished shard_<I>_of_<N>.h5.

    Only finished shards are read (a `.shard_*` directory in progress is ignored): the
    corpus is what `tofu corpus verify` would check. Use as a context manager, or close().
    """

    def __init__(self, path: str):
        self.path = os.path.abspath(path)
        if not os.path.isdir(self.path):
            raise CorpusError(f"{self.path}: not a directory (expected a tofu corpus directory)")
        spec_path = os.path.join(self.path, "corpus.yaml")
        if not os.path.isfile(spec_path):
            raise CorpusError(f"{spec_path}: missing (not a tofu corpus directory: "
                              "`tofu corpus generate` writes it)")
        with open(spec_path, encoding="utf-8") as f:
            self.spec_yaml = f.read()
        m = re.search(r"^name:\s*([a-z0-9_]+)\s*(#.*)?$", self.spec_yaml, re.MULTILINE)
        if not m:
            raise CorpusError(f"{spec_path}: no 'name:' line")
        self.name = m.group(1)
        shard_names = sorted(n for n in os.listdir(self.path) if _SHARD_RE.match(n))
        if not shard_names:
            raise CorpusError(f"{self.path}: no shard_<I>_of_<N>.h5 (is generation finished?)")
        counts = {int(_SHARD_RE.match(n).group(2)) for n in shard_names}
        if len(counts) != 1:
            raise CorpusError(f"{self.path}: shards of different layouts {sorted(counts)}")
        self._files: list[h5py.File] = []
        self._where: dict[str, tuple[h5py.File, str]] = {}
        try:
            for n in shard_names:
                shard = os.path.join(self.path, n)
                try:
                    f = h5py.File(shard, "r")
                except OSError as e:
                    raise CorpusError(f"{shard}: not a readable HDF5 file ({e})") from None
                self._files.append(f)
                version = f.attrs.get("schema_version")
                if version is None or int(version) != SCHEMA_VERSION:
                    raise CorpusError(f"{shard}: schema_version {version}, this reader reads "
                                      f"{SCHEMA_VERSION}")
                corpus = _str(f.attrs.get("corpus", ""))
                if corpus != self.name:
                    raise CorpusError(f"{shard}: corpus '{corpus}', but {spec_path} says "
                                      f"'{self.name}'")
                if "episodes" not in f:
                    raise CorpusError(f"{shard}: no /episodes group")
                self.episodes_planned = int(f.attrs["episodes_planned"])
                for eid in f["episodes"]:
                    if eid in self._where:
                        raise CorpusError(f"{shard}: episode {eid} also in "
                                          f"{self._where[eid][1]}")
                    self._where[eid] = (f, shard)
        except BaseException:
            self.close()
            raise
        self.shards = [os.path.join(self.path, n) for n in shard_names]
        self.episode_ids = sorted(self._where,
                                  key=lambda e: int(self._where[e][0]["episodes"][e].attrs["index"]))

    def __enter__(self) -> "Corpus":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        for f in self._files:
            f.close()
        self._files = []

    def __len__(self) -> int:
        return len(self.episode_ids)

    def episode(self, episode_id: str) -> Episode:
        if episode_id not in self._where:
            raise KeyError(f"{self.path}: no episode {episode_id}")
        f, shard = self._where[episode_id]
        return Episode(f["episodes"][episode_id], shard)

    def episodes(self) -> Iterator[Episode]:
        """Every episode in index order."""
        for eid in self.episode_ids:
            yield self.episode(eid)


def summarize(corpus: Corpus, window_s: float, hop_s: float) -> dict:
    """Episodes, flight hours, windows and label counts (windows per sensor and label)."""
    labels: Counter = Counter()
    events: Counter = Counter()
    windows = sensor_windows = 0
    hours = 0.0
    events_missing: list[str] = []  # scheduled events that label no window of their sensor
    lost: list[str] = []  # scheduled faults of the scenario without their own event row
    for ep in corpus.episodes():
        hours += ep.duration_s / 3600.0
        seen: set[tuple[str, str]] = set()
        bounds = ep.window_bounds(window_s, hop_s)
        for w in ep.windows(window_s, hop_s):
            windows += 1
            for name, sw in w.sensors.items():
                sensor_windows += 1
                for label in sw.labels or {"clean"}:
                    labels[(name, label)] += 1
                for label in sw.labels:
                    seen.add((name, label))
        table = ep.events()
        for sensor, kind, start, end in ep.schedule():
            if start < ep.duration_ns and not any(
                    e.sensor == sensor and e.kind == kind and start <= e.onset_ns < end
                    for e in table):
                lost.append(f"{ep.id}:{sensor}:{kind}@{start}")
        for e in table:
            events[(e.sensor, e.kind, e.cause)] += 1
            inside = any(e.overlaps(s, t) for s, t in bounds)
            if e.cause == "scheduled" and inside and (e.sensor, e.kind) not in seen:
                events_missing.append(f"{ep.id}:{e.sensor}:{e.kind}@{e.onset_ns}")
    return {
        "corpus": corpus.name, "path": corpus.path, "shards": len(corpus.shards),
        "episodes": len(corpus), "episodes_planned": corpus.episodes_planned,
        "flight_hours": hours, "window_s": window_s, "hop_s": hop_s, "windows": windows,
        "sensor_windows": sensor_windows,
        "labels": {f"{s}:{k}": n for (s, k), n in sorted(labels.items())},
        "events": {f"{s}:{k}:{c}": n for (s, k, c), n in sorted(events.items())},
        "scheduled_events_without_label": events_missing,
        "scheduled_faults_without_event": lost,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("corpus", help="corpus directory (corpus.yaml + shard_*.h5)")
    parser.add_argument("--window-s", type=float, default=1.0)
    parser.add_argument("--hop-s", type=float, default=0.5)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = parser.parse_args(argv)
    try:
        with Corpus(args.corpus) as corpus:
            s = summarize(corpus, args.window_s, args.hop_s)
    except CorpusError as e:
        print(f"tofu_corpus: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(s, indent=1, sort_keys=True))
        return 0
    print(f"corpus {s['corpus']} ({s['path']}): {s['shards']} shard(s)")
    print(f"episodes: {s['episodes']} of {s['episodes_planned']} planned")
    print(f"flight hours: {s['flight_hours']:.3f}")
    print(f"windows: {s['windows']} ({s['window_s']} s, hop {s['hop_s']} s), "
          f"{s['sensor_windows']} sensor windows")
    print("events (sensor:kind:cause):")
    for k, n in s["events"].items():
        print(f"  {k:40s} {n}")
    print("sensor windows per label (sensor:label; a window can carry several):")
    for k, n in s["labels"].items():
        print(f"  {k:40s} {n}")
    if s["scheduled_faults_without_event"]:
        print("scheduled faults without their own event row (overlapping a fault of the same "
              "kind on the same sensor; labels from the masks and the schedule):",
              *s["scheduled_faults_without_event"])
    if s["scheduled_events_without_label"]:
        print("scheduled events labelling no window:", *s["scheduled_events_without_label"])
    return 0


if __name__ == "__main__":
    sys.exit(main())

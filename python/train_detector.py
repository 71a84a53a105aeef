#!/usr/bin/python3
"""Train a per-window sensor-fault detector on one tofu corpus, evaluate it on another.

    python3 python/train_detector.py TRAIN_CORPUS EVAL_CORPUS [--out DIR]

Why: a failure corpus is only useful if something can be learnt from it and measured on
data it has not seen. This script is the smallest end-to-end use: hand-made features of the
kind fault-detection papers use, a random forest, and an evaluation on a corpus of another
seed (same distribution, other flights) next to the consensus estimator's own detections,
computed the same way on the same windows, so the two can be compared row by row.

The detector sees only what a flight computer sees: the sensor streams (positions,
reported covariances, twists, attitudes) and the IMU, never ground truth. Each window is
judged from its own samples and the seconds before it (causal), so the detection delay is
meaningful. A window of a sensor is a positive when a scheduled fault of any kind is active
in it for that sensor (tofu_corpus labels: masks plus dropout events); physical conditions
(e.g. LiDAR degeneracy along the inspection wall) are not targets, they are reported apart.

Metrics, per fault kind k, over the windows of the sensors that carry k in the eval corpus:
  recall     windows with k flagged / windows with k
  precision  windows with k flagged / (those + flagged windows with no scheduled fault)
             -- k against the clean windows (windows with another kind are left out, since
             a binary detector does not name the kind; consensus gets the same definition)
  delay      per event: end of the first flagged window that overlaps the event minus the
             event's onset (when the flag is available); median over the detected events
  detected   events with at least one flagged window overlapping them / events
Consensus flags a window of a sensor when any of its decisions in the window has the sensor
in excluded_mask.

Everything is seeded (random_state fixed, features deterministic, single-threaded): the same
two corpora give the same table.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import tofu_corpus  # noqa: E402

WINDOW_S = 1.0  # long enough for a few LiDAR samples (10 Hz), short enough to localise onsets
HOP_S = 0.25  # delay resolution
GRID_S = 0.1  # common resampling grid for comparing sensors (LiDAR rate)
HISTORY_S = 6.0  # recent past in which a sensor must fit another rigidly (kabsch_long)
RANDOM_STATE = 0
POSITION_TYPES = ("vio", "lidar_odometry", "total_station", "gnss")
TYPE_CODE = {t: i for i, t in enumerate(POSITION_TYPES)}

FEATURES = [
    "type_code",          # which kind of sensor (noise levels and failure modes differ)
    "count_ratio",        # samples / expected samples in the window (dropout)
    "max_gap_ratio",      # longest silence / nominal period (dropout)
    "zero_step_frac",     # share of exactly repeated positions (freeze)
    "zero_run_s",         # longest run of repeated positions (freeze)
    "step_max_m",         # largest position increment (jump, outliers)
    "step_max_ratio",     # ... over the median increment
    "dd_max_m",           # largest second difference of positions (jump, outliers)
    "dd_ratio",           # ... over the median second difference
    "rough_m",            # RMS residual of a quadratic fit to the window (noise)
    "rough_nis",          # ... squared over the reported position variance (NIS-like)
    "reported_std_m",     # reported position standard deviation
    "twist_resid_mps",    # |speed from positions - reported twist speed| (jump, freeze)
    "rot_resid_rad",      # |attitude change - IMU gyro integral| (freeze)
    "imu_gyro_rads",      # motion context: mean gyro norm
    "imu_acc_std",        # motion context: accelerometer norm std
    "disp_resid_min_m",   # | |window displacement| - other sensor's |, min over others
    "disp_resid_max_m",   # ... max over others
    "kabsch_win_min_m",   # RMS after the best rigid fit onto another sensor, in the window
    "kabsch_win_max_m",
    "kabsch_long_min_m",  # ... over the recent past + window
    "kabsch_long_max_m",
    "pred_resid_min_m",   # mean residual in the window under the past's (robust) rigid fit
    "pred_resid_max_m",
    "pred_resid_nis_min",  # ... squared over the two reported variances (NIS-like)
    "pred_jump_min_m",    # window residual - median past residual under that fit
    "past_sv1_m",         # RMS extent of the past motion along its main axis and ...
    "past_sv2_m",         # ... its second: a hover or a straight pass leaves the fit's
                          #     rotation free, so the residuals above mean less
    "twist_vs_min_mps",   # |reported twist - other sensor's velocity| in its frame, min
    "twist_speed_vs_min_mps",  # the same with speeds only (needs no alignment)
]


def kabsch(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid (R, t) minimising |R x + t - y|: sensors report in their own frames, so they can
    only be compared after a rigid alignment (Kabsch 1976 / Umeyama 1991 without scale)."""
    mx, my = x.mean(axis=0), y.mean(axis=0)
    h = (x - mx).T @ (y - my)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, my - r @ mx


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotates each v by the unit quaternion q (w, x, y, z), row by row."""
    w, u = q[:, :1], q[:, 1:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def rigid_rms(x: np.ndarray, y: np.ndarray) -> float:
    r, t = kabsch(x, y)
    return float(np.sqrt(np.mean(np.sum((x @ r.T + t - y) ** 2, axis=1))))


class SensorTrack:
    """One position-reporting sensor of an episode, resampled onto the common grid."""

    def __init__(self, stream: tofu_corpus.Stream, grid_t: np.ndarray):
        self.name, self.type = stream.name, stream.type
        self.t = stream.t_ns.astype(np.float64) * 1e-9
        self.p = stream.values[:, :3]
        # The nominal period: the median spacing is the configured rate (a sensor's
        # dropouts and faults do not move it), which a flight computer knows beforehand.
        self.period = float(np.median(np.diff(self.t))) if len(self.t) > 1 else np.nan
        cov = stream.covariance
        if cov is None:
            self.var = np.full(len(self.t), np.nan)
        elif cov.shape[1] == 6:  # position: p_00 p_01 p_02 p_11 p_12 p_22
            self.var = (cov[:, 0] + cov[:, 3] + cov[:, 5]) / 3.0
        else:  # pose [dtheta; dp] 21 upper-triangle entries: dp diagonal at 15, 18, 20
            self.var = (cov[:, 15] + cov[:, 18] + cov[:, 20]) / 3.0
        cols = stream.values.shape[1]
        self.q = stream.values[:, 3:7] if cols >= 13 else None
        self.speed = np.linalg.norm(stream.values[:, 7:10], axis=1) if cols >= 13 else None
        # The twist v_s (in the sensor frame s) rotated into the sensor's reference frame S.
        self.twist_S = quat_rotate(self.q, stream.values[:, 7:10]) if cols >= 13 else None
        # Zero-order hold onto the grid: each grid time takes the newest sample at or before
        # it (a detector at time t has nothing later), and none when that sample is more
        # than 2.5 periods old (a dropout is not bridged). Compared in integer nanoseconds,
        # so that a sample stamped exactly at a grid time counts as at it.
        self.grid = np.full((len(grid_t), 3), np.nan)
        if len(self.t) >= 2:
            grid_ns = np.round(np.asarray(grid_t) * 1e9).astype(np.int64)
            t_ns = stream.t_ns.astype(np.int64)
            held = np.searchsorted(t_ns, grid_ns, side="right") - 1
            held_c = np.clip(held, 0, len(t_ns) - 1)
            age_s = (grid_ns - t_ns[held_c]) * 1e-9
            ok = (held >= 0) & (age_s <= 2.5 * self.period)
            self.grid[ok] = self.p[held_c[ok]]

    def var_before(self, b: float) -> float:
        """Mean reported position variance of the samples before b (none later: causal)."""
        hi = int(np.searchsorted(self.t, b, side="left"))
        v = self.var[:hi]
        return float(np.mean(v[np.isfinite(v)])) if np.any(np.isfinite(v)) else np.nan


def own_features(tr: SensorTrack, a: float, b: float, imu) -> dict:
    """Features of one sensor's own samples in [a, b) (no other sensor involved)."""
    lo, hi = np.searchsorted(tr.t, [a, b], side="left")
    t, p = tr.t[lo:hi], tr.p[lo:hi]
    n = len(t)
    expected = (b - a) / tr.period if tr.period > 0 else np.nan
    f = {"type_code": TYPE_CODE.get(tr.type, -1), "count_ratio": n / expected}
    edges = np.concatenate([[a], t, [b]])
    f["max_gap_ratio"] = float(np.max(np.diff(edges))) / tr.period
    f["reported_std_m"] = float(np.sqrt(np.nanmean(tr.var[lo:hi]))) if n else np.nan
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1) if n >= 2 else np.array([])
    if len(steps):
        zero = steps < 1e-12
        f["zero_step_frac"] = float(zero.mean())
        run = best = 0
        for z in zero:
            run = run + 1 if z else 0
            best = max(best, run)
        f["zero_run_s"] = best * tr.period
        f["step_max_m"] = float(steps.max())
        f["step_max_ratio"] = float(steps.max() / (np.median(steps) + 1e-6))
    if n >= 3:
        dd = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=1)
        f["dd_max_m"] = float(dd.max())
        f["dd_ratio"] = float(dd.max() / (np.median(dd) + 1e-6))
    if n >= 4:
        tc = t - t.mean()
        a_mat = np.stack([np.ones_like(tc), tc, tc * tc], axis=1)
        coef, *_ = np.linalg.lstsq(a_mat, p, rcond=None)
        res = p - a_mat @ coef
        rough2 = float(np.mean(np.sum(res * res, axis=1)) / 3.0)
        f["rough_m"] = np.sqrt(rough2)
        var = float(np.nanmean(tr.var[lo:hi]))
        f["rough_nis"] = rough2 / var if var > 0 else np.nan
    if tr.speed is not None and n >= 2 and t[-1] > t[0]:
        v_pos = np.linalg.norm(p[-1] - p[0]) / (t[-1] - t[0])
        twist = tr.speed[lo:hi]
        if np.any(np.isfinite(twist)):
            f["twist_resid_mps"] = float(abs(v_pos - np.nanmean(twist)))
    ilo, ihi = np.searchsorted(imu["t"], [a, b], side="left")
    if ihi - ilo >= 2:
        gyro, acc, it = imu["gyro"][ilo:ihi], imu["acc"][ilo:ihi], imu["t"][ilo:ihi]
        f["imu_gyro_rads"] = float(np.mean(np.linalg.norm(gyro, axis=1)))
        f["imu_acc_std"] = float(np.std(np.linalg.norm(acc, axis=1)))
        if tr.q is not None and n >= 2:
            q0, q1 = tr.q[lo], tr.q[hi - 1]
            angle = 2.0 * np.arccos(min(1.0, abs(float(np.dot(q0, q1)))))
            sel = (it >= t[0]) & (it <= t[-1])
            if sel.sum() >= 2:
                dt = np.diff(it[sel], append=it[sel][-1])
                rotvec = np.sum(gyro[sel] * dt[:, None], axis=0)
                f["rot_resid_rad"] = float(abs(angle - np.linalg.norm(rotvec)))
    return f


def robust_kabsch(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kabsch, refitted on the best-fitting half of the points: a fault earlier in the history (a
    jump still active, an old divergence) must not drag the alignment towards itself."""
    rot, tr = kabsch(x, y)
    res = np.linalg.norm(x @ rot.T + tr - y, axis=1)
    keep = res <= np.quantile(res, 0.5)
    if keep.sum() >= 6:
        rot, tr = kabsch(x[keep], y[keep])
    return rot, tr


def pair_features(s: SensorTrack, r: SensorTrack, ga: int, gb: int, gh: int) -> dict:
    """Agreement of s with another sensor r on the grid: [ga, gb) = the window, [gh, ga) =
    the recent history, [0, ga) = everything before the window (for the frame alignment)."""
    out = {}
    xs, xr = s.grid[:gb], r.grid[:gb]
    ok = np.all(np.isfinite(xs), axis=1) & np.all(np.isfinite(xr), axis=1)
    win = np.zeros(len(ok), bool)
    win[ga:] = True
    w_ok = ok & win
    recent = ok.copy()
    recent[:gh] = False
    if w_ok.sum() >= 2:
        i0, i1 = np.flatnonzero(w_ok)[[0, -1]]
        out["disp"] = abs(np.linalg.norm(xs[i1] - xs[i0]) - np.linalg.norm(xr[i1] - xr[i0]))
    if w_ok.sum() >= 4:
        out["kabsch_win"] = rigid_rms(xs[w_ok], xr[w_ok])
    if recent.sum() >= 6:
        out["kabsch_long"] = rigid_rms(xs[recent], xr[recent])
    h_idx = np.flatnonzero(ok & ~win)
    if len(h_idx) >= 10 and w_ok.sum() >= 2:
        h_idx = h_idx[:: max(1, len(h_idx) // 120)]  # at most ~120 points: bounded cost
        rot, tr = robust_kabsch(xs[h_idx], xr[h_idx])
        res_h = np.linalg.norm(xs[h_idx] @ rot.T + tr - xr[h_idx], axis=1)
        res_w = np.linalg.norm(xs[w_ok] @ rot.T + tr - xr[w_ok], axis=1)
        out["pred"] = float(res_w.mean())
        var = s.var_before(gb * GRID_S) + r.var_before(gb * GRID_S)
        out["pred_nis"] = float(np.mean(res_w ** 2) / var) if var > 0 else np.nan
        out["pred_jump"] = float(res_w.mean() - np.median(res_h))
        # How well the past pins the rotation down: RMS extent along its two main axes
        # (a straight pass leaves the rotation about it free; a hover leaves all of it).
        sv = np.linalg.svd(xs[h_idx] - xs[h_idx].mean(0), compute_uv=False) / np.sqrt(len(h_idx))
        out["sv1"], out["sv2"] = float(sv[0]), float(sv[1])
        # The reported twist against the other sensor's motion, in r's frame: a divergence
        # shows in the twist at once (the position offset only grows from zero).
        if s.twist_S is not None:
            lo, hi = np.searchsorted(s.t, [ga * GRID_S, gb * GRID_S], side="left")
            v = s.twist_S[lo:hi]
            v = v[np.all(np.isfinite(v), axis=1)]
            i0, i1 = np.flatnonzero(w_ok)[[0, -1]]
            if len(v) and i1 > i0:
                v_r = (xr[i1] - xr[i0]) / ((i1 - i0) * GRID_S)
                out["twist_vs"] = float(np.linalg.norm(rot @ v.mean(axis=0) - v_r))
                # Rotation-free: speeds only (blind across the motion, but needs no fit).
                out["twist_speed_vs"] = float(abs(np.linalg.norm(v.mean(axis=0)) -
                                                  np.linalg.norm(v_r)))
    return out


def episode_rows(ep: tofu_corpus.Episode):
    """Feature rows, truth and consensus flags for every (window, position sensor)."""
    grid_t = np.arange(0.0, ep.duration_s + 1e-9, GRID_S)
    tracks = {}
    imu = None
    for name in ep.sensors:
        st = ep.stream(name)
        if st.type == "imu":
            imu = {"t": st.t_ns * 1e-9, "gyro": st.values[:, :3], "acc": st.values[:, 3:6]}
        elif st.type in POSITION_TYPES:
            tracks[name] = SensorTrack(st, grid_t)
    if imu is None:
        imu = {"t": np.array([]), "gyro": np.zeros((0, 3)), "acc": np.zeros((0, 3))}
    rows = []
    for w in ep.windows(WINDOW_S, HOP_S, sensors=list(tracks)):
        a, b = w.start_ns * 1e-9, w.end_ns * 1e-9
        ga, gb = int(round(a / GRID_S)), int(round(b / GRID_S))
        gh = max(0, int(round((a - HISTORY_S) / GRID_S)))
        pairs = {}
        for s in tracks:
            for r in tracks:
                if s != r:
                    pairs[(s, r)] = pair_features(tracks[s], tracks[r], ga, gb, gh)
        for s, tr in tracks.items():
            f = own_features(tr, a, b, imu)
            others = [pairs[(s, r)] for r in tracks if r != s]
            for key, name in (("disp", "disp_resid"), ("kabsch_win", "kabsch_win"),
                              ("kabsch_long", "kabsch_long"), ("pred", "pred_resid")):
                vals = [o[key] for o in others if key in o]
                if vals:
                    f[f"{name}_min_m"], f[f"{name}_max_m"] = min(vals), max(vals)
            for key, name in (("pred_nis", "pred_resid_nis_min"), ("pred_jump", "pred_jump_min_m")):
                vals = [o[key] for o in others if key in o and np.isfinite(o[key])]
                if vals:
                    f[name] = min(vals, key=abs) if key == "pred_jump" else min(vals)
            vals = [o["twist_vs"] for o in others if "twist_vs" in o]
            if vals:
                f["twist_vs_min_mps"] = min(vals)
            vals = [o["twist_speed_vs"] for o in others if "twist_speed_vs" in o]
            if vals:
                f["twist_speed_vs_min_mps"] = min(vals)
            for key in ("sv1", "sv2"):
                vals = [o[key] for o in others if key in o]
                if vals:
                    f[f"past_{key}_m"] = max(vals)
            sw = w.sensors[s]
            rows.append({
                "episode": ep.id, "world": ep.world, "sensor": s, "start_ns": w.start_ns,
                "end_ns": w.end_ns, "x": [f.get(k, np.nan) for k in FEATURES],
                "faults": sorted(sw.faults), "conditions": sorted(sw.conditions),
                "consensus": bool(w.decisions["consensus"].excluded(s))
                if "consensus" in w.decisions else False,
                "consensus_unavailable": bool(w.decisions["consensus"].unavailable(s))
                if "consensus" in w.decisions else False,
            })
    events = [e for e in ep.events() if e.cause == "scheduled" and e.sensor in tracks]
    return rows, events


def load(path: str, what: str):
    t0 = time.time()
    rows, events, hours, episodes = [], [], 0.0, 0
    with tofu_corpus.Corpus(path) as corpus:
        name = corpus.name
        for ep in corpus.episodes():
            r, e = episode_rows(ep)
            rows += r
            events += [(ep.id, x) for x in e]
            hours += ep.duration_s / 3600.0
            episodes += 1
    print(f"{what}: {name}: {episodes} episodes, {hours:.2f} h, {len(rows)} sensor windows, "
          f"{len(events)} scheduled events ({time.time() - t0:.1f} s)", file=sys.stderr)
    x = np.array([r["x"] for r in rows], dtype=np.float64)
    return {"name": name, "path": os.path.abspath(path), "episodes": episodes, "hours": hours,
            "rows": rows, "x": x, "events": events}


def prepare(x: np.ndarray) -> np.ndarray:
    """Random forests here (scikit-learn 1.2) take no NaN: a missing feature (too few
    samples, no past yet, no twist) becomes -1e6, below every real value, so a tree can
    still split "missing" off on its own."""
    return np.where(np.isfinite(x), x, -1e6)


def make_model():
    from sklearn.ensemble import RandomForestClassifier
    return RandomForestClassifier(n_estimators=100, min_samples_leaf=3, max_features="sqrt",
                                  class_weight="balanced_subsample", n_jobs=1,
                                  random_state=RANDOM_STATE)


def choose_threshold(x: np.ndarray, y: np.ndarray, groups: np.ndarray) -> float:
    """Decision threshold maximising F1 on out-of-fold predictions of the TRAIN corpus
    (episodes kept whole per fold): chosen without looking at the eval corpus."""
    from sklearn.model_selection import GroupKFold
    oof = np.zeros(len(y))
    folds = min(5, len(np.unique(groups)))
    if folds < 2 or len(np.unique(y)) < 2:
        return 0.5
    for tr, te in GroupKFold(n_splits=folds).split(x, y, groups):
        if len(np.unique(y[tr])) < 2:
            oof[te] = float(y[tr][0])
            continue
        m = make_model().fit(x[tr], y[tr])
        oof[te] = m.predict_proba(x[te])[:, 1]
    best, best_f1 = 0.5, -1.0
    for th in np.round(np.arange(0.1, 0.91, 0.05), 2):
        p = oof >= th
        tp = np.sum(p & (y == 1))
        f1 = 2 * tp / max(1, p.sum() + (y == 1).sum())
        if f1 > best_f1 + 1e-12:
            best, best_f1 = float(th), f1
    return best


def evaluate(rows: list[dict], events: list, flags: np.ndarray) -> dict:
    """Per-kind precision / recall / delay of `flags` (one per row); see the module doc."""
    faults = [set(r["faults"]) for r in rows]
    sensors = np.array([r["sensor"] for r in rows])
    clean = np.array([not f for f in faults])
    kinds = sorted({e.kind for _, e in events} | {k for f in faults for k in f})
    by_window: dict[tuple[str, str], list[int]] = {}
    for i, r in enumerate(rows):
        by_window.setdefault((r["episode"], r["sensor"]), []).append(i)

    def event_delays(evs):
        delays, detected = [], 0
        for eid, e in evs:
            first = None
            for i in by_window.get((eid, e.sensor), []):
                r = rows[i]
                if r["end_ns"] > e.onset_ns and r["start_ns"] < e.offset_ns and flags[i]:
                    first = r["end_ns"] if first is None else min(first, r["end_ns"])
            if first is not None:
                detected += 1
                delays.append((first - e.onset_ns) * 1e-9)
        return {"events": len(evs), "detected": detected,
                "delay_median_s": float(np.median(delays)) if delays else None}

    out = {}
    for k in kinds:
        on = {e.sensor for _, e in events if e.kind == k} | \
             {rows[i]["sensor"] for i in range(len(rows)) if k in faults[i]}
        in_s = np.isin(sensors, sorted(on))
        pos = in_s & np.array([k in f for f in faults])
        neg = in_s & clean
        tp, fp = int(np.sum(flags & pos)), int(np.sum(flags & neg))
        out[k] = {"sensors": sorted(on), "windows": int(pos.sum()),
                  "recall": tp / pos.sum() if pos.sum() else None,
                  "precision": tp / (tp + fp) if tp + fp else None,
                  **event_delays([(eid, e) for eid, e in events if e.kind == k])}
    pos = ~clean
    tp, fp = int(np.sum(flags & pos)), int(np.sum(flags & clean))
    out["all faults"] = {"sensors": sorted(set(sensors)), "windows": int(pos.sum()),
                         "recall": tp / pos.sum() if pos.sum() else None,
                         "precision": tp / (tp + fp) if tp + fp else None,
                         **event_delays(events)}
    out["clean windows: false alarm rate"] = {
        "windows": int(clean.sum()), "rate": fp / clean.sum() if clean.sum() else None}
    conds = sorted({c for r in rows for c in r["conditions"]})
    for c in conds:
        sel = clean & np.array([c in r["conditions"] for r in rows])
        out[f"condition {c} (no fault): flag rate"] = {
            "windows": int(sel.sum()), "rate": float(np.mean(flags[sel])) if sel.sum() else None}
    return out


def fmt(v, digits=2) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def table(det: dict, con: dict) -> str:
    lines = ["| fault kind | sensors | windows | events | detector P | R | delay [s] | detected |"
             " consensus P | R | delay [s] | detected |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for k, d in det.items():
        c = con[k]
        if "recall" not in d:
            continue
        lines.append(
            f"| {k} | {','.join(d['sensors'])} | {d['windows']} | {d['events']} | "
            f"{fmt(d['precision'])} | {fmt(d['recall'])} | {fmt(d['delay_median_s'])} | "
            f"{d['detected']}/{d['events']} | {fmt(c['precision'])} | {fmt(c['recall'])} | "
            f"{fmt(c['delay_median_s'])} | {c['detected']}/{c['events']} |")
    for k, d in det.items():
        if "rate" in d:
            lines.append(f"| {k} | | {d['windows']} | | | {fmt(d['rate'], 3)} | | | | "
                         f"{fmt(con[k]['rate'], 3)} | | |")
    return "\n".join(lines)


def table_single(res: dict) -> str:
    """One method's per-kind rows (P, R, delay, detected) -- for a variant of consensus."""
    lines = ["| fault kind | P | R | delay [s] | detected |", "|---|---:|---:|---:|---:|"]
    for k, d in res.items():
        if "recall" in d:
            lines.append(f"| {k} | {fmt(d['precision'])} | {fmt(d['recall'])} | "
                         f"{fmt(d['delay_median_s'])} | {d['detected']}/{d['events']} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("train", help="training corpus directory")
    parser.add_argument("eval", help="evaluation corpus directory (another seed)")
    parser.add_argument("--out", default="detector_results", help="output directory")
    args = parser.parse_args(argv)
    t0 = time.time()
    try:
        train = load(args.train, "train")
        ev = load(args.eval, "eval")
    except tofu_corpus.CorpusError as e:
        print(f"train_detector: {e}", file=sys.stderr)
        return 2
    y = np.array([1 if r["faults"] else 0 for r in train["rows"]])
    if len(np.unique(y)) < 2:
        print(f"train_detector: {train['path']}: the training windows need both faulty and "
              "clean windows", file=sys.stderr)
        return 2
    groups = np.array([r["episode"] for r in train["rows"]])
    xtr, xev = prepare(train["x"]), prepare(ev["x"])
    threshold = choose_threshold(xtr, y, groups)
    model = make_model().fit(xtr, y)
    flags = model.predict_proba(xev)[:, 1] >= threshold
    consensus = np.array([r["consensus"] for r in ev["rows"]])
    det = evaluate(ev["rows"], ev["events"], flags)
    con = evaluate(ev["rows"], ev["events"], consensus)
    con_unavail = evaluate(ev["rows"], ev["events"], consensus | np.array(
        [r["consensus_unavailable"] for r in ev["rows"]]))
    importance = sorted(zip(FEATURES, model.feature_importances_), key=lambda kv: -kv[1])
    md = table(det, con)
    header = (
        f"Detector: random forest (100 trees, balanced classes, random_state {RANDOM_STATE}) on "
        f"{len(FEATURES)} per-window features, windows {WINDOW_S} s every {HOP_S} s; decision "
        f"threshold {threshold:.2f} (best F1 in 5-fold cross-validation on the training corpus, "
        f"by episode).\n"
        f"Trained on `{train['name']}` ({train['episodes']} episodes, {train['hours']:.2f} h, "
        f"{len(train['rows'])} sensor windows, {int(y.sum())} with a fault); evaluated on "
        f"`{ev['name']}` ({ev['episodes']} episodes, {ev['hours']:.2f} h, {len(ev['rows'])} sensor "
        f"windows, {int(sum(1 for r in ev['rows'] if r['faults']))} with a fault).\n"
        "P: flagged windows with the kind / (those + flagged windows without any fault, on "
        "the same sensors); R: share of the windows with the kind that are flagged; delay: "
        "median over detected events of (end of the first flagged window overlapping the event "
        "- onset); detected: events with a flagged window; consensus: a window is flagged "
        "when a decision in it excluded the sensor. Last rows: share of the windows without a "
        "fault (and with the named physical condition) that are flagged, in the R columns.\n")
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "results.md"), "w", encoding="utf-8") as f:
        f.write(f"# Fault detector: `{train['name']}` -> `{ev['name']}`\n\n{header}\n{md}\n\n"
                "Consensus again, counting a window as flagged also when a decision in it "
                "found the sensor unavailable (no usable data or frame alignment: it notices a "
                "silent sensor without excluding it):\n\n" + table_single(con_unavail) + "\n\n"
                "Feature importances (mean decrease in impurity): " +
                ", ".join(f"{k} {v:.3f}" for k, v in importance[:10]) + "\n")
    result = {
        "train": {k: train[k] for k in ("name", "path", "episodes", "hours")},
        "eval": {k: ev[k] for k in ("name", "path", "episodes", "hours")},
        "window_s": WINDOW_S, "hop_s": HOP_S, "threshold": threshold,
        "random_state": RANDOM_STATE, "features": FEATURES,
        "feature_importances": dict(importance),
        "train_windows": len(train["rows"]), "train_fault_windows": int(y.sum()),
        "eval_windows": len(ev["rows"]),
        "detector": det, "consensus": con, "consensus_excluded_or_unavailable": con_unavail,
    }
    with open(os.path.join(args.out, "results.json"), "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1, sort_keys=True)
    print(header)
    print(md)
    print(f"\nwrote {os.path.join(args.out, 'results.md')} and results.json "
          f"({time.time() - t0:.1f} s)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/python3
"""An error-state EKF (ESKF) as a tofu process client (docs/INTERFACE.md, protocol 1).

Run:  /usr/bin/python3 examples/python/ekf_estimator.py   (tofu writes stdin, reads stdout)

Conventions follow Sola 2017, "Quaternion kinematics for the error-state Kalman filter"
(arXiv:1711.02508; cited below as [S] with section numbers): the nominal state is
p_LI [m], v_L [m/s], R_LI (a rotation matrix; q_LI is reported), b_a [m/s^2], b_g
[rad/s]; the 15-dim error state is [dp, dv, dtheta, db_a, db_g] with the *local* (right)
attitude error R_LI = R_hat Exp(dtheta) [S 5.3]. Frame offsets of the sensors'
reference frames S are further error states (below).

IMU propagation [S 5.4]: tofu's simulated IMU sample stamped t_k is the *average* of the
specific force and the angular rate over (t_{k-1}, t_k], so sample k drives the step
from t_{k-1} to t_k (dt from consecutive t_ns), with the rotation increment
Exp(omega dt) and the specific force rotated by the midpoint attitude (second order).
The covariance uses the discrete error-state Jacobian F_x and the diagonal impulse
covariances of [S 5.4.3]: sigma_a^2 dt and sigma_g^2 dt (white noise densities),
sigma_ba^2 dt, sigma_bg^2 dt (bias random walks). The densities come from config, else
from the IMU's options in setup.calibration_yaml (*_noise_density_*, *_random_walk_*),
else tofu's defaults (ADIS16448), and are inflated (config imu_noise_inflation, default
5, and imu_bias_walk_inflation, default 2) as a flight filter does for rotor vibration
and unmodelled effects (tofu's IMU adds ~0.16 m/s^2 RMS vibration at hover to a 0.04
m/s^2 white noise per sample).

Frames. Each sensor reports in its own frame S, never in L. L (ours, gravity aligned):
  * anchor = config "anchor", else the first fused *pose* sensor, else the first fused
    position sensor. (Deviation from "first position sensor": with only a position
    anchor the heading is unobservable during the start-up hover, yet tofu registers W
    to L at the first valid estimate; a pose sensor gives the heading at once.)
  * pose anchor: L is the anchor's S *levelled*: same origin, z up, x the horizontal
    projection of S's x axis (S of a VIO is the camera's optical frame at boot, not
    gravity aligned, so L cannot be S itself). For a gravity-aligned S, L = S.
  * position anchor (total station, GNSS: z-up frames): L = S; the robot's heading is
    then unknown at start-up (config unknown_heading_std_rad) and becomes observable
    with horizontal acceleration (a known limitation of position-only fusion).
Frame offsets T_LS as error states:
  * every fused pose sensor (the anchor included) has a 6-DoF offset (R_LS, t_LS):
    its S need not be gravity aligned. It is initialised from its first sample given
    the current state by a correlated state augmentation (the sample adds no
    information, the offset inherits the state's uncertainty), and random-walks
    (config odometry_drift_*) so that an odometry frame's slow drift is absorbed;
  * every non-anchor position sensor has a 4-DoF offset (yaw psi + translation d;
    z-up S assumed): p_S = c_S + Rz(psi)^T (p_Ls - c_L - d) about the centroids c of
    the alignment pairs. The yaw is unobservable from one sample, so the sensor is
    first *aligned*: (measured p_S, predicted p_Ls) pairs are collected until the
    horizontal spread reaches align_baseline_m, a 2-D Procrustes fit gives psi (and
    the residual its prior variance), and only then is the sensor fused.
Measurement models (lever arms from the setup's mounts T_Is = T_BI^-1 T_Bs):
  * position: p_Ss = R_LS^T (p_LI + R_LI p_Is - t_LS), covariance_m2 as given;
  * pose: R_Ss = R_LS^T R_LI R_Is, p_Ss as above; residual [Log(R_hat^T R_meas); dp]
    with the sample's 6x6 covariance of [dtheta; dp] (right perturbation, dp in S).
  Jacobians w.r.t. the error state [S 6.1.1]; update P <- P - K S K^T; injection
  [S 6.2] and reset with G = I - [dtheta/2]x on each rotation block [S 6.3] (skipped
  when |dtheta| < 1 mrad, where it changes P by < 0.05 %).
  Each sensor is fused at most max_update_rate_hz (default 50 Hz): tofu's VIO streams
  200 Hz of strongly time-correlated poses, which a filter assuming white noise would
  over-trust; the skipped samples are counted ("decimated" in the report).
Latency: samples arrive late (arrival order). The prediction uses the nominal state at
the sample's t_ns, interpolated from a 2 s history of IMU steps (corrected since by the
sum of later corrections); the correction is applied to the current state with the
current covariance (the error over the lag is taken as constant - an approximation, no
clones). A sample stamped after the newest IMU sample waits for it.

Fault detection (honest and simple): each update passes a chi-square gate
d^2 = y^T S^-1 y <= chi2(gate_chi2_prob, dim y) (default 0.999). A rejected sample is
dropped. After gate_max_rejections (default 5) consecutive rejections the sensor is
*excluded*: it leaves "fused", its samples are only tested; after gate_readmit (default
5) consecutive consistent innovations it is re-admitted. Two guards: no gating while
the heading is unknown (its std above gate_heading_std_rad, 0.1 rad: the position-anchor
start-up, where the linearised covariance is too optimistic), and the sole fused sensor
is never excluded - without redundancy a faulty sensor cannot be told from a wrong
state, so after N rejections the filter follows it ("followed" in the report); and
when every sensor has been excluded, the next excluded one heard from is re-admitted. A pose sensor excluded for
more than reinit_after_s (default 2 s) whose recent *relative* motion (over ~1 s)
agrees with the filter's is re-initialised (new frame offset; e.g. after a VIO reset)
and re-admitted. It cannot tell which of two disagreeing sensors is wrong when neither
is clearly inconsistent with the IMU; gating is only as good as the covariances.

Initialisation: the first init_duration_s (0.2 s) of IMU samples are averaged (the
robot starts hovering): gravity direction -> roll/pitch, mean gyro -> gyro bias. The
state starts at the anchor's first sample. Before that every IMU sample is answered
with valid=false, initialized=false. Afterwards one estimate per IMU sample (its t_ns),
valid unless no update was accepted for more than max_update_gap_s (1 s).

Config keys (all optional): fuse [names], anchor, gate_chi2_prob, gate_max_rejections,
gate_readmit, gate_heading_std_rad, accel_noise_density, gyro_noise_density, accel_random_walk,
gyro_random_walk (used as given), imu_noise_inflation, imu_bias_walk_inflation,
init_duration_s, max_update_gap_s, align_baseline_m, odometry_drift_pos_m_per_sqrts,
odometry_drift_rot_rad_per_sqrts, unknown_heading_std_rad, reinit_after_s, history_s,
max_update_rate_hz. Twists of pose samples are not used.

Output: "finished" carries a report (anchor, IMU noise used, per-sensor counts and
events: aligned/excluded/re-admitted, final frame offsets, mean us per IMU step).
"""

import bisect
import math
import os
import re
import sys
import time
from statistics import NormalDist

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import tofu_client  # noqa: E402  (the helper next to this file)

# Error-state layout (core): [S 5.3.1] order p, v, theta, a_b, omega_b.
IP, IV, ITH, IBA, IBG = 0, 3, 6, 9, 12
NCORE = 15
I3 = np.eye(3)

# tofu's simulated IMU defaults (ADIS16448, Kalibr convention), used when neither the
# config nor calibration_yaml states them.
DEFAULT_IMU_NOISE = {
    "accel_noise_density": 2.0e-3,   # m/s^2/sqrt(Hz)
    "gyro_noise_density": 1.6968e-4,  # rad/s/sqrt(Hz)
    "accel_random_walk": 3.0e-3,     # m/s^3/sqrt(Hz)
    "gyro_random_walk": 1.9393e-5,   # rad/s^2/sqrt(Hz)
}
CONFIG_KEYS = {
    "fuse", "anchor", "gate_chi2_prob", "gate_max_rejections", "gate_readmit",
    "gate_heading_std_rad", "accel_noise_density", "gyro_noise_density",
    "accel_random_walk", "gyro_random_walk", "imu_noise_inflation",
    "imu_bias_walk_inflation", "init_duration_s", "max_update_gap_s", "align_baseline_m",
    "odometry_drift_pos_m_per_sqrts", "odometry_drift_rot_rad_per_sqrts",
    "unknown_heading_std_rad", "reinit_after_s", "history_s", "max_update_rate_hz",
}
CALIBRATION_KEYS = {
    "accel_noise_density": "accel_noise_density_mps2_per_sqrthz",
    "gyro_noise_density": "gyro_noise_density_radps_per_sqrthz",
    "accel_random_walk": "accel_random_walk_mps3_per_sqrthz",
    "gyro_random_walk": "gyro_random_walk_radps2_per_sqrthz",
}


# ---------------------------------------------------------------------------------------
# SO(3) helpers. Hand-written with plain floats where that beats numpy's call overhead.

def skew(v):
    """[v]x, the skew-symmetric cross-product matrix: [v]x u = v x u."""
    x, y, z = v.tolist() if isinstance(v, np.ndarray) else v
    return np.array(((0.0, -z, y), (z, 0.0, -x), (-y, x, 0.0)))


def exp9(x, y, z):
    """Exp of the rotation vector (x, y, z), the Rodrigues formula [S 2.3.3], as a
    row-major 9-tuple of floats (cheaper than a numpy call at 400 Hz)."""
    a2 = x * x + y * y + z * z
    if a2 < 1e-12:  # second-order series: exact to double precision here
        b, c = 1.0 - a2 / 6.0, 0.5 - a2 / 24.0
    else:
        a = math.sqrt(a2)
        b = math.sin(a) / a
        c = (1.0 - math.cos(a)) / a2
    xx, yy, zz, xy, xz, yz = x * x, y * y, z * z, x * y, x * z, y * z
    return (1.0 - c * (yy + zz), c * xy - b * z, c * xz + b * y,
            c * xy + b * z, 1.0 - c * (xx + zz), c * yz - b * x,
            c * xz - b * y, c * yz + b * x, 1.0 - c * (xx + yy))


def exp_so3(x, y, z):
    """Exp of the rotation vector as a 3x3 numpy array."""
    return np.array(exp9(float(x), float(y), float(z))).reshape(3, 3)


def mul9(A, B):
    """Product of two row-major 9-tuples."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = A
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = B
    return (a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21,
            a00 * b02 + a01 * b12 + a02 * b22,
            a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21,
            a10 * b02 + a11 * b12 + a12 * b22,
            a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21,
            a20 * b02 + a21 * b12 + a22 * b22)


def np9(R9):
    return np.array(R9).reshape(3, 3)


def to9(R):
    return tuple(R.ravel().tolist())


def log9(R9):
    """Log of a rotation (row-major 9-tuple) as a rotation vector [S 2.3.4]: a
    3-tuple, robust near pi."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R9
    c = max(-1.0, min(1.0, 0.5 * (r00 + r11 + r22 - 1.0)))
    wx, wy, wz = r21 - r12, r02 - r20, r10 - r01
    if c > 0.999999:
        k = 0.5 * (1.0 + (1.0 - c) / 3.0)  # theta/sin(theta) ~ 1 + theta^2/6
        return (k * wx, k * wy, k * wz)
    angle = math.acos(c)
    if c > -0.99:
        k = 0.5 * angle / math.sin(angle)
        return (k * wx, k * wy, k * wz)
    # Near pi: the axis from the symmetric part (1 - c) a a^T, its sign from w.
    B = ((r00 - c, 0.5 * (r01 + r10), 0.5 * (r02 + r20)),
         (0.5 * (r01 + r10), r11 - c, 0.5 * (r12 + r21)),
         (0.5 * (r02 + r20), 0.5 * (r12 + r21), r22 - c))
    k = max(range(3), key=lambda i: B[i][i])
    n = math.sqrt(sum(x * x for x in B[k]))
    axis = [x / n for x in B[k]]
    if axis[0] * wx + axis[1] * wy + axis[2] * wz < 0.0:
        axis = [-x for x in axis]
    return (axis[0] * angle, axis[1] * angle, axis[2] * angle)


def log_so3(R):
    """Log of a 3x3 numpy rotation as a numpy rotation vector."""
    return np.array(log9(tuple(R.ravel().tolist())))


def rot_z(psi):
    c, s = math.cos(psi), math.sin(psi)
    return np.array(((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)))


def heading(R):
    """Heading of the frame R (in a z-up frame): of its x axis, or of its y axis minus
    90 deg when x is (nearly) vertical."""
    if math.hypot(R[0, 0], R[1, 0]) > 0.2:
        return math.atan2(R[1, 0], R[0, 0])
    return math.atan2(R[1, 1], R[0, 1]) - 0.5 * math.pi


def R_from_quat(q):
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not n > 0.0:
        raise ValueError("zero quaternion")
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array((
        (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        (2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        (2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))))


def quat_from_R(R9):
    """Hamilton (w, x, y, z) with w >= 0 (Shepperd's method), of a row-major 9-tuple."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = R9
    tr = r00 + r11 + r22
    if tr > 0.0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s]
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        q = [(r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s]
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        q = [(r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        q = [(r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s]
    if q[0] < 0.0:
        q = [-c for c in q]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [c / n for c in q]


def orthonormalise(R):
    u, _, vt = np.linalg.svd(R)
    return u @ vt


def inverse(S):
    """Inverse of a small symmetric positive-definite matrix: the 3x3 by cofactors in
    floats (numpy.linalg's call overhead exceeds the arithmetic), larger by numpy.
    Raises numpy.linalg.LinAlgError when singular."""
    if S.shape[0] != 3:
        return np.linalg.inv(S)
    (a, b, c), (d, e, f), (g, h, i) = S.tolist()
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * A + b * B + c * C
    if not abs(det) > 1e-300:
        raise np.linalg.LinAlgError("singular innovation covariance")
    k = 1.0 / det
    return np.array(((A * k, (c * h - b * i) * k, (b * f - c * e) * k),
                     (B * k, (a * i - c * g) * k, (c * d - a * f) * k),
                     (C * k, (b * g - a * h) * k, (a * e - b * d) * k)))


def chi2_quantile(prob, dof):
    """Wilson-Hilferty approximation of the chi-square quantile (no scipy needed): a
    little conservative, +0.2 % (3 dof, p = 0.99) to +3.5 % (3 dof, p = 0.9999); 16.55
    instead of 16.27 for 3 dof at the default 0.999."""
    z = NormalDist().inv_cdf(prob)
    h = 2.0 / (9.0 * dof)
    return dof * (1.0 - h + z * math.sqrt(h)) ** 3


def finite_matrix(values, n):
    """An n x n covariance from a flat row-major list, or None when it is malformed or
    not finite (a sensor fault, delivered as it is)."""
    try:
        M = np.array(values, dtype=float)
    except (TypeError, ValueError):
        return None
    total = float(M.sum())
    if M.shape != (n * n,) or total - total != 0.0:  # x - x is 0 only for a finite x
        return None
    return M.reshape(n, n)


def pose_from_json(pose):
    return np.array([float(x) for x in pose["p_m"]]), R_from_quat(pose["q_wxyz"])


def imu_noise_from_calibration(text, imu_name):
    """The IMU's noise options from calibration.yaml: {short key: value}. PyYAML when
    importable, else a line scan for the (unique) option keys."""
    found = {}
    if not text:
        return found
    try:
        import yaml
        doc = yaml.safe_load(text) or {}
        sensors = doc.get("sensors") or {}
        entry = sensors.get(imu_name) or next(
            (s for s in sensors.values() if isinstance(s, dict) and s.get("type") == "imu"), {})
        options = (entry or {}).get("options") or {}
        for short, key in CALIBRATION_KEYS.items():
            if key in options:
                found[short] = float(options[key])
        return found
    except ImportError:
        pass
    for short, key in CALIBRATION_KEYS.items():
        m = re.search(r"^\s*" + re.escape(key) + r"\s*:\s*([-+0-9.eE]+)\s*$", text, re.M)
        if m:
            found[short] = float(m.group(1))
    return found


# ---------------------------------------------------------------------------------------

class SensorTrack:
    """One fused stream: mount, frame offset, gating state, statistics."""

    def __init__(self, index, info, R_BI, p_BI):
        self.index = index
        self.name = info["name"]
        self.kind = info["kind"]
        # The mount in the IMU frame (the setup's T_Is = T_BI^-1 T_Bs): lever arm and
        # mount rotation.
        self.p_Is, self.R_Is = pose_from_json(info["T_Is"])
        self.neg_skew_p_Is = -skew(self.p_Is)
        self.R_sI = self.R_Is.T.copy()
        self.is_anchor = False
        self.slot = None          # first index of the offset in the error state
        self.active = False       # has a usable frame offset (or is the position anchor)
        self.excluded = False
        self.bad = 0              # consecutive gate rejections
        self.good = 0             # consecutive consistent innovations while excluded
        self.excluded_since_ns = None
        self.last_t_ns = None
        # Offset nominal values (pose: R_LS, t_LS; position: psi, d, c_S, c_L).
        self.R_LS = I3.copy()
        self.t_LS = np.zeros(3)
        self.psi = 0.0
        self.d = np.zeros(3)
        self.c_S = np.zeros(3)
        self.c_L = np.zeros(3)
        self.pairs = []           # position alignment: (z_S, p_Ls)
        self.recent = []          # pose re-initialisation: (t, p_Ss, R_Ss, p_Ls, R_Ls)
        self.stats = {"accepted": 0, "rejected": 0, "tested_while_excluded": 0,
                      "invalid": 0, "stale": 0, "out_of_order": 0, "decimated": 0,
                      "followed_as_sole_sensor": 0}
        self.events = []


class EskfEstimator:
    def __init__(self):
        self.t_imu = None
        self.initialized = False

    # -- setup ---------------------------------------------------------------------------

    def start(self, setup):
        cfg = setup.get("config") or {}
        if not isinstance(cfg, dict):
            raise ValueError("config must be a map")
        unknown = sorted(set(cfg) - CONFIG_KEYS)
        if unknown:
            tofu_client.log(f"ekf: ignoring unknown config keys {unknown}")
        self.g = float(setup["gravity_mps2"])
        sensors = setup["sensors"]
        self.imu_index = int(setup["imu"])
        imu = sensors[self.imu_index]
        # The setup gives every mount in I (T_Is); the body frame B is not needed.
        self.p_BI, self.R_BI = np.zeros(3), I3.copy()

        names = [s["name"] for s in sensors]
        fuse = cfg.get("fuse")
        if fuse is None:
            fuse = [s["name"] for i, s in enumerate(sensors)
                    if i != self.imu_index and s["kind"] in ("pose", "position")]
        if not isinstance(fuse, list):
            raise ValueError("config fuse: expected a list of sensor names")
        for name in fuse:
            if name not in names:
                raise ValueError(f"config fuse: no sensor {name!r} (sensors: {names})")
        self.tracks = {}
        for i, s in enumerate(sensors):
            if s["name"] in fuse and i != self.imu_index:
                if s["kind"] not in ("pose", "position"):
                    raise ValueError(f"config fuse: {s['name']!r} is of kind {s['kind']!r}")
                self.tracks[i] = SensorTrack(i, s, self.R_BI, self.p_BI)
        ordered = [self.tracks[i] for i in sorted(self.tracks)]
        anchor = cfg.get("anchor")
        if anchor is not None:
            match = [t for t in ordered if t.name == anchor]
            if not match:
                raise ValueError(f"config anchor: {anchor!r} is not a fused sensor")
            self.anchor_order = match + [t for t in ordered if t.name != anchor]
        else:
            self.anchor_order = ([t for t in ordered if t.kind == "pose"] +
                                 [t for t in ordered if t.kind == "position"])

        # IMU noise: config (as given) > calibration.yaml (inflated) > defaults (inflated).
        calib = imu_noise_from_calibration(setup.get("calibration_yaml", ""), imu["name"])
        white_k = float(cfg.get("imu_noise_inflation", 5.0))
        walk_k = float(cfg.get("imu_bias_walk_inflation", 2.0))
        noise = {}
        for key, default in DEFAULT_IMU_NOISE.items():
            if key in cfg:
                noise[key] = float(cfg[key])
            else:
                k = white_k if "density" in key else walk_k
                noise[key] = k * calib.get(key, default)
        self.noise = noise
        self.noise_source = "config/calibration_yaml" if calib else "config/defaults"
        self.gate_prob = float(cfg.get("gate_chi2_prob", 0.999))
        self.gate_thr = {d: chi2_quantile(self.gate_prob, d) for d in range(1, 7)}
        self.gate_max_rej = int(cfg.get("gate_max_rejections", 5))
        self.gate_readmit = int(cfg.get("gate_readmit", 5))
        self.gate_heading_var = float(cfg.get("gate_heading_std_rad", 0.1)) ** 2
        self.init_duration_ns = int(1e9 * float(cfg.get("init_duration_s", 0.2)))
        self.max_gap_ns = int(1e9 * float(cfg.get("max_update_gap_s", 1.0)))
        self.align_baseline = float(cfg.get("align_baseline_m", 1.0))
        self.drift_pos = float(cfg.get("odometry_drift_pos_m_per_sqrts", 0.01))
        self.drift_rot = float(cfg.get("odometry_drift_rot_rad_per_sqrts", 0.002))
        self.heading_std = float(cfg.get("unknown_heading_std_rad", 1.0))
        self.reinit_after_ns = int(1e9 * float(cfg.get("reinit_after_s", 2.0)))
        self.history_ns = int(1e9 * float(cfg.get("history_s", 2.0)))
        rate = float(cfg.get("max_update_rate_hz", 50.0))
        self.min_update_period_ns = int(0.95e9 / rate) if rate > 0.0 else 0

        # Nominal state and covariance.
        # Plain floats (lists, a row-major 9-tuple for R_LI): replaced, never mutated in
        # place, so that the history can keep references.
        self.p = [0.0, 0.0, 0.0]
        self.v = [0.0, 0.0, 0.0]
        self.R9 = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
        self.ba = [0.0, 0.0, 0.0]
        self.bg = [0.0, 0.0, 0.0]
        self.P = np.zeros((NCORE, NCORE))
        self.F = np.eye(NCORE)
        self.F_dt = None
        # F_x entries that change every step: rows v, cols theta and b_a; rows theta,
        # cols theta.
        self.f_idx = np.array([r * NCORE + c for r in range(IV, IV + 3)
                               for c in range(ITH, ITH + 6)] +
                              [r * NCORE + c for r in range(ITH, ITH + 3)
                               for c in range(ITH, ITH + 3)])
        self.rot_blocks = [ITH]       # error-state indices of every rotation block
        self.walk_diag = []           # (indices, variance per second) for offset walks
        self.q_idx = np.array([], dtype=int)
        self.q_rate = np.array([])
        self._rebuild_process_noise()

        # Start-up averaging.
        self.init_sum_acc = np.zeros(3)
        self.init_sum_gyro = np.zeros(3)
        self.init_n = 0
        self.init_t0 = None
        self.gravity_ready_ns = None
        self.latest = {}              # sensor index -> last sample before initialisation

        # History of nominal states for delayed samples, and the running sum of the
        # corrections (dp, dtheta) injected since (a new array per correction).
        self.h_t, self.h_p, self.h_R, self.h_c = [], [], [], []
        self.corr = (0.0,) * 6
        self.pending = []             # samples stamped after the newest IMU sample
        self.last_accept_ns = None
        self.omega_I = [0.0, 0.0, 0.0]
        self.fused_names = []
        self.steps = 0
        self.updates = 0
        self.step_time_s = 0.0
        self.imu_invalid = 0
        self.imu_out_of_order = 0
        self.events = []

    def _rebuild_process_noise(self):
        """Diagonal continuous-time noise rates of the error state [S 5.4.3]."""
        n = self.noise
        idx = list(range(IV, IV + 3)) + list(range(ITH, ITH + 3)) + \
            list(range(IBA, IBA + 3)) + list(range(IBG, IBG + 3))
        rate = [n["accel_noise_density"] ** 2] * 3 + [n["gyro_noise_density"] ** 2] * 3 + \
            [n["accel_random_walk"] ** 2] * 3 + [n["gyro_random_walk"] ** 2] * 3
        for indices, var in self.walk_diag:
            idx += indices
            rate += [var] * len(indices)
        N = self.P.shape[0]
        self.q_idx = np.array(idx) * (N + 1)  # flat indices of the diagonal
        self.q_rate = np.array(rate)
        self.F_dt = None  # recompute the dt-dependent parts

    # -- protocol entry points -----------------------------------------------------------

    def add(self, m):
        index = m["sensor_index"]
        if index == self.imu_index:
            t0 = time.perf_counter()
            out = self._imu(m)
            self.step_time_s += time.perf_counter() - t0
            self.steps += 1
            return out
        track = self.tracks.get(index)
        if track is None:
            return []  # not fused
        self._sample(track, m)
        return []

    def finish(self):
        # The filter's own time per IMU step is the machine's, not the flight's: it goes to
        # the log (standard error), so the report, which tofu writes into the estimate's
        # JSON, is the same bytes on every run.
        print(f"ekf: {1e6 * self.step_time_s / max(self.steps, 1):.1f} us per IMU step in the "
              f"filter", file=sys.stderr)
        report = {
            "method": "eskf (examples/python/ekf_estimator.py)",
            "anchor": next((t.name for t in self.tracks.values() if t.is_anchor), None),
            "fused_at_end": list(self.fused_names),
            "imu_noise": self.noise,
            "imu_noise_source": self.noise_source,
            "imu_steps": self.steps,
            "imu_invalid": self.imu_invalid,
            "imu_out_of_order": self.imu_out_of_order,
            "sensors": {t.name: dict(t.stats, events=t.events) for t in self.tracks.values()},
            "events": self.events,
        }
        offsets = {}
        for t in self.tracks.values():
            if t.active and t.kind == "pose":
                offsets[t.name] = {"p_LS_m": t.t_LS.tolist(),
                                   "q_LS_wxyz": quat_from_R(to9(t.R_LS))}
            elif t.active and not t.is_anchor:
                offsets[t.name] = {"yaw_LS_rad": t.psi, "c_S_m": t.c_S.tolist(),
                                   "c_L_m": (t.c_L + t.d).tolist()}
        report["frame_offsets"] = offsets
        return [], report

    # -- IMU -----------------------------------------------------------------------------

    def _imu(self, m):
        t = m["t_ns"]
        acc, gyro = m["acc_I_mps2"], m["gyro_I_radps"]
        try:  # six finite numbers (x - x is 0 only for a finite x); inline for speed
            ax, ay, az = acc
            gx, gy, gz = gyro
            total = ax + ay + az + gx + gy + gz
            ok = total - total == 0.0
        except (TypeError, ValueError):
            ok = False
        if not ok:
            self.imu_invalid += 1
            return []
        acc, gyro = (ax, ay, az), (gx, gy, gz)
        if self.t_imu is not None and t <= self.t_imu:
            self.imu_out_of_order += 1
            return []
        if not self.initialized:
            # The sample averages (t_prev, t]: the start-up mean covers (t0, t].
            if self.t_imu is not None:
                if self.init_t0 is None:
                    self.init_t0 = self.t_imu
                self.init_sum_acc += np.array(acc)
                self.init_sum_gyro += np.array(gyro)
                self.init_n += 1
                if self.gravity_ready_ns is None and t - self.init_t0 >= self.init_duration_ns:
                    self.gravity_ready_ns = t
            self.t_imu = t
            if self.gravity_ready_ns is not None:
                self._try_initialise()
            if not self.initialized:
                return [{"t_ns": t, "valid": False, "initialized": False,
                         "p_LI_m": [0.0, 0.0, 0.0], "q_LI_wxyz": [1.0, 0.0, 0.0, 0.0],
                         "v_L_mps": [0.0, 0.0, 0.0], "omega_I_radps": list(gyro)}]
            self._push_history()
            return [self._estimate()]
        dt = (t - self.t_imu) * 1e-9
        self._propagate(acc, gyro, dt)
        self.t_imu = t
        self._push_history()
        if self.pending:
            ready = [s for s in self.pending if s[1]["t_ns"] <= t]
            if ready:
                self.pending = [s for s in self.pending if s[1]["t_ns"] > t]
                for track, sample in ready:
                    self._sample(track, sample)
        return [self._estimate()]

    def _propagate(self, acc, gyro, dt):
        """One IMU step: nominal kinematics [S 5.4.1] with the averaged sample, covariance
        P <- F_x P F_x^T + Q [S 5.4.3]. Plain floats for the nominal state and the
        changing entries of F_x; numpy only for P."""
        ba, bg = self.ba, self.bg
        ax, ay, az = acc[0] - ba[0], acc[1] - ba[1], acc[2] - ba[2]
        wx, wy, wz = gyro[0] - bg[0], gyro[1] - bg[1], gyro[2] - bg[2]
        self.omega_I = [wx, wy, wz]
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = R = self.R9
        dR = exp9(wx * dt, wy * dt, wz * dt)
        n00, n01, n02, n10, n11, n12, n20, n21, n22 = R_new = mul9(R, dR)
        # Specific force in L with the midpoint attitude, (R + R Exp(w dt)) / 2 to
        # second order, plus gravity.
        fx = 0.5 * ((r00 + n00) * ax + (r01 + n01) * ay + (r02 + n02) * az)
        fy = 0.5 * ((r10 + n10) * ax + (r11 + n11) * ay + (r12 + n12) * az)
        fz = 0.5 * ((r20 + n20) * ax + (r21 + n21) * ay + (r22 + n22) * az) - self.g
        p, v = self.p, self.v
        h = 0.5 * dt * dt
        self.p = [p[0] + v[0] * dt + h * fx, p[1] + v[1] * dt + h * fy,
                  p[2] + v[2] * dt + h * fz]
        self.v = [v[0] + fx * dt, v[1] + fy * dt, v[2] + fz * dt]
        self.R9 = R_new

        F = self.F
        if dt != self.F_dt:
            F[IP:IP + 3, IV:IV + 3] = I3 * dt
            F[ITH:ITH + 3, IBG:IBG + 3] = -dt * I3
            self.q_dt = self.q_rate * dt
            self.F_dt = dt
        # d(dv)/d(dtheta) = -R [a]x dt, d(dv)/d(db_a) = -R dt,
        # d(dtheta)/d(dtheta) = Exp(w dt)^T [S 5.4.3].
        m = -dt
        F.flat[self.f_idx] = (
            m * (r01 * az - r02 * ay), m * (r02 * ax - r00 * az), m * (r00 * ay - r01 * ax),
            m * r00, m * r01, m * r02,
            m * (r11 * az - r12 * ay), m * (r12 * ax - r10 * az), m * (r10 * ay - r11 * ax),
            m * r10, m * r11, m * r12,
            m * (r21 * az - r22 * ay), m * (r22 * ax - r20 * az), m * (r20 * ay - r21 * ax),
            m * r20, m * r21, m * r22,
            dR[0], dR[3], dR[6], dR[1], dR[4], dR[7], dR[2], dR[5], dR[8])
        P = self.P
        if P.shape[0] == NCORE:
            P = self.P = F @ P @ F.T
        else:  # the frame offsets are constant: F_x acts on the first 15 rows/columns
            P[:NCORE] = F @ P[:NCORE]
            P[:, :NCORE] = P[:, :NCORE] @ F.T
        P.flat[self.q_idx] += self.q_dt
        if self.steps % 200 == 0:
            self.P = 0.5 * (P + P.T)
            self.R9 = to9(orthonormalise(np9(self.R9)))

    def _push_history(self):
        self.h_t.append(self.t_imu)
        self.h_p.append(self.p)       # replaced (never mutated) by each step/correction
        self.h_R.append(self.R9)      # idem
        self.h_c.append(self.corr)    # idem
        if self.h_t[-1] - self.h_t[0] > 2 * self.history_ns:
            cut = bisect.bisect_left(self.h_t, self.h_t[-1] - self.history_ns)
            del self.h_t[:cut], self.h_p[:cut], self.h_R[:cut], self.h_c[:cut]

    def _past_state(self, t):
        """Nominal (p_LI, R_LI) at t as numpy arrays: interpolated history (plain floats),
        plus the corrections injected since (positions added, local attitude errors
        composed)."""
        h_t = self.h_t
        i = bisect.bisect_left(h_t, t)
        if i == len(h_t) or (i == 0 and h_t[0] != t):
            return None
        if h_t[i] == t:
            p, R9, c = self.h_p[i], self.h_R[i], self.h_c[i]
        else:
            a = (t - h_t[i - 1]) / (h_t[i] - h_t[i - 1])
            p0, p1 = self.h_p[i - 1], self.h_p[i]
            p = [p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]),
                 p0[2] + a * (p1[2] - p0[2])]
            R0 = self.h_R[i - 1]
            # R0 Exp(a Log(R0^T R1)); one IMU step turns little, so the small-angle log
            # vee((M - M^T) / 2) is exact to ~1e-7 rad.
            M = mul9((R0[0], R0[3], R0[6], R0[1], R0[4], R0[7], R0[2], R0[5], R0[8]),
                     self.h_R[i])
            R9 = mul9(R0, exp9(0.5 * a * (M[7] - M[5]), 0.5 * a * (M[2] - M[6]),
                               0.5 * a * (M[3] - M[1])))
            c = self.h_c[i - 1]
        if c is not self.corr:
            n = self.corr
            p = [p[0] + n[0] - c[0], p[1] + n[1] - c[1], p[2] + n[2] - c[2]]
            R9 = mul9(R9, exp9(n[3] - c[3], n[4] - c[4], n[5] - c[5]))
        return np.array(p), np9(R9)

    # -- initialisation ------------------------------------------------------------------

    def _try_initialise(self):
        anchor = None
        for track in self.anchor_order:
            if track.index in self.latest:
                anchor = track
                break
            # Wait up to 1 s after the start-up averaging for the preferred anchor.
            if self.t_imu - self.gravity_ready_ns < 1_000_000_000:
                return
        if anchor is None:
            return
        f_I = self.init_sum_acc / self.init_n
        omega = self.init_sum_gyro / self.init_n
        # Gyro bias: the mean rate of the hover (only if it looks like one).
        self.bg = omega.tolist() if np.linalg.norm(omega) < 0.05 else [0.0, 0.0, 0.0]
        # R_LI with R_LI f_I = |f| e_z (hover: f = -g), heading fixed below.
        z_I = f_I / np.linalg.norm(f_I)
        e = I3[int(np.argmin(np.abs(z_I)))]
        x_I = e - (e @ z_I) * z_I
        x_I /= np.linalg.norm(x_I)
        R_IL = np.column_stack((x_I, np.cross(z_I, x_I), z_I))
        R_LI = R_IL.T
        sample = self.latest[anchor.index]
        anchor.is_anchor = True
        P0 = np.zeros((NCORE, NCORE))
        tilt_var = (0.1 / self.g) ** 2 + 1e-6  # ~ an unknown accel bias of 0.1 m/s^2
        if anchor.kind == "pose":
            z_p, R_Ss, cov = sample
            R_LS = R_LI @ anchor.R_Is @ R_Ss.T
            Rz = rot_z(-heading(R_LS))
            R_LI = Rz @ R_LI
            R_LS = Rz @ R_LS
            p_Ls = R_LS @ z_p  # t_LS = 0: L's origin is S's origin
            p_LI = p_Ls - R_LI @ anchor.p_Is
            pos_var = np.clip(np.diag(cov)[3:], 1e-6, 1.0)
            yaw_var = float(np.clip(np.max(np.diag(cov)[:3]), 1e-6, 0.1))
        else:
            z_p, cov = sample
            R_LB = R_LI @ self.R_BI.T
            R_LI = rot_z(-heading(R_LB)) @ R_LI  # body x heading 0 (arbitrary)
            p_LI = z_p - R_LI @ anchor.p_Is
            pos_var = np.clip(np.diag(cov), 1e-6, 1.0)
            yaw_var = self.heading_std ** 2
            anchor.active = True
        self.p = p_LI.tolist()
        self.R9 = to9(R_LI)
        self.v = [0.0, 0.0, 0.0]
        P0[IP:IP + 3, IP:IP + 3] = np.diag(pos_var)
        P0[IV:IV + 3, IV:IV + 3] = 0.1 ** 2 * I3
        # Attitude: tilt and heading variances in L, as the local error in I.
        P0[ITH:ITH + 3, ITH:ITH + 3] = R_LI.T @ np.diag((tilt_var, tilt_var, yaw_var)) @ R_LI
        P0[IBA:IBA + 3, IBA:IBA + 3] = 0.1 ** 2 * I3
        P0[IBG:IBG + 3, IBG:IBG + 3] = 0.005 ** 2 * I3
        self.P = P0
        self._rebuild_process_noise()
        self.initialized = True
        self.last_accept_ns = self.t_imu
        if anchor.kind == "pose":
            z_p, R_Ss, cov = sample
            # The anchor defines L: its offset inherits the state's uncertainty only.
            self._init_pose_offset(anchor, z_p, R_Ss, None, p_LI, R_LI)
        self.events.append({"t_ns": self.t_imu, "event": "initialised", "anchor": anchor.name})
        tofu_client.log(f"ekf: initialised at t={self.t_imu * 1e-9:.3f} s on anchor "
                        f"{anchor.name!r} ({anchor.kind}); IMU noise {self.noise}")
        self._refresh_fused()

    # -- state augmentation --------------------------------------------------------------

    def _grow(self, size):
        N = self.P.shape[0]
        P = np.zeros((N + size, N + size))
        P[:N, :N] = self.P
        self.P = P  # F_x acts on the core only (offsets are constant): it stays 15x15
        return N

    def _init_pose_offset(self, track, z_p, R_Ss, cov, p_LI, R_LI):
        """(Re-)initialises T_LS of a pose sensor from a sample and the state at its time:
        R_LS = R_Ls R_Ss^T, t_LS = p_Ls - R_LS p_Ss, with the correlated augmentation
        P_aug = [[P, P J^T], [J P, J P J^T + Jn cov Jn^T]]."""
        R_Ls = R_LI @ track.R_Is
        p_Ls = p_LI + R_LI @ track.p_Is
        R_LS = R_Ls @ R_Ss.T
        t_LS = p_Ls - R_LS @ z_p
        if track.slot is None:
            track.slot = self._grow(6)
            self.rot_blocks.append(track.slot)
            self.walk_diag.append((list(range(track.slot, track.slot + 3)), self.drift_rot ** 2))
            self.walk_diag.append((list(range(track.slot + 3, track.slot + 6)),
                                   self.drift_pos ** 2))
        s = track.slot
        N = self.P.shape[0]
        M_T = R_Ss @ track.R_Is.T  # dphi = M^T dtheta, M = R_Is R_Ss^T
        J = np.zeros((6, N))
        J[0:3, ITH:ITH + 3] = M_T
        J[3:6, IP:IP + 3] = I3
        J[3:6, ITH:ITH + 3] = R_LI @ track.neg_skew_p_Is + R_LS @ skew(z_p) @ M_T
        P = self.P
        P[s:s + 6, :] = 0.0
        P[:, s:s + 6] = 0.0
        JP = J @ P
        block = JP @ J.T
        if cov is not None:
            Jn = np.zeros((6, 6))
            Jn[0:3, 0:3] = -R_Ss
            Jn[3:6, 0:3] = -R_LS @ skew(z_p) @ R_Ss
            Jn[3:6, 3:6] = -R_LS
            block += Jn @ cov @ Jn.T
        P[s:s + 6, :] = JP
        P[:, s:s + 6] = JP.T
        P[s:s + 6, s:s + 6] = block
        track.R_LS, track.t_LS = R_LS, t_LS
        track.active = True
        track.excluded = False
        track.bad = track.good = 0
        track.recent = []
        self._rebuild_process_noise()
        self._refresh_fused()

    def _align_position(self, track):
        """2-D Procrustes fit of (yaw, translation) between a position sensor's S and L
        from its pairs; the offset enters the state with the fit's uncertainty."""
        z = np.array([pair[0] for pair in track.pairs])
        q = np.array([pair[1] for pair in track.pairs])
        c_S, c_L = z.mean(axis=0), q.mean(axis=0)
        a, b = z - c_S, q - c_L
        spread = math.sqrt(float(np.mean(a[:, 0] ** 2 + a[:, 1] ** 2)))
        if spread < 0.5 * self.align_baseline:
            return
        psi = math.atan2(float(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])),
                         float(np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
        res = b - a @ rot_z(psi).T
        rms = math.sqrt(float(np.mean(np.sum(res ** 2, axis=1))) / 3.0)
        if rms > 0.25:
            # Inconsistent (a fault, or the state is off): start again later.
            track.pairs = track.pairs[len(track.pairs) // 2:]
            return
        slot = self._grow(4)
        track.slot = slot
        track.psi, track.d, track.c_S, track.c_L = psi, np.zeros(3), c_S, c_L
        # Prior: the residual (correlated in time, hence the factor 2) with floors.
        sig = max(2.0 * rms, 0.01)
        P = self.P
        P[slot, slot] = (sig / spread) ** 2
        P[slot + 1:slot + 4, slot + 1:slot + 4] = (sig ** 2) * I3 + P[IP:IP + 3, IP:IP + 3]
        self.walk_diag.append((list(range(slot, slot + 4)), 1e-10))
        self._rebuild_process_noise()
        track.active = True
        track.pairs = []
        track.events.append({"t_ns": self.t_imu, "event": "aligned", "yaw_rad": psi,
                             "residual_rms_m": rms})
        tofu_client.log(f"ekf: {track.name} aligned at t={self.t_imu * 1e-9:.3f} s: yaw "
                        f"{math.degrees(psi):.2f} deg, residual {1000 * rms:.1f} mm")
        self._refresh_fused()

    # -- absolute samples ----------------------------------------------------------------

    def _sample(self, track, m):
        t = m["t_ns"]
        if track.kind == "pose":
            z_p = tofu_client.finite_floats(m["p_Ss_m"], 3)
            q = tofu_client.finite_floats(m["q_Ss_wxyz"], 4)
            cov = finite_matrix(m["covariance"], 6)
            if z_p is None or q is None or cov is None or not any(q):
                track.stats["invalid"] += 1
                return
            sample = (np.array(z_p), R_from_quat(q), cov)
        else:
            z_p = tofu_client.finite_floats(m["p_Ss_m"], 3)
            cov = finite_matrix(m["covariance_m2"], 3)
            if z_p is None or cov is None:
                track.stats["invalid"] += 1
                return
            sample = (np.array(z_p), cov)
        if track.last_t_ns is not None and t <= track.last_t_ns:
            track.stats["out_of_order"] += 1  # a repeated/regressing stamp: a fault
            return
        if track.last_t_ns is not None and t - track.last_t_ns < self.min_update_period_ns \
                and self.initialized:
            track.stats["decimated"] += 1
            return
        if not self.initialized:
            track.last_t_ns = t
            self.latest[track.index] = sample
            if self.gravity_ready_ns is not None:
                self._try_initialise()
            return
        if t > self.t_imu:
            self.pending.append((track, m))  # wait for the IMU to reach t
            return
        track.last_t_ns = t
        past = self._past_state(t)
        if past is None:
            track.stats["stale"] += 1
            return
        p_LI, R_LI = past
        if track.kind == "pose":
            self._pose_update(track, t, sample, p_LI, R_LI)
        else:
            self._position_update(track, t, sample, p_LI, R_LI)

    def _position_update(self, track, t, sample, p_LI, R_LI):
        z, cov = sample
        p_Ls = p_LI + R_LI @ track.p_Is
        N = self.P.shape[0]
        H = np.zeros((3, N))
        if track.is_anchor:
            pred = p_Ls
            H[:, IP:IP + 3] = I3
            H[:, ITH:ITH + 3] = R_LI @ track.neg_skew_p_Is
        elif not track.active:
            # Collect alignment pairs while the state is tracking (10 Hz is plenty).
            if self._valid() and (not track.pairs or t - track.pairs[-1][2] >= 100_000_000):
                track.pairs.append((z, p_Ls, t))
                if len(track.pairs) > 300:
                    del track.pairs[:100]
                self._align_position(track)
            return
        else:
            RzT = rot_z(track.psi).T
            w = RzT @ (p_Ls - track.c_L - track.d)
            pred = track.c_S + w
            s = track.slot
            H[:, IP:IP + 3] = RzT
            H[:, ITH:ITH + 3] = (RzT @ R_LI) @ track.neg_skew_p_Is
            H[0, s], H[1, s] = w[1], -w[0]
            H[:, s + 1:s + 4] = -RzT
        self._gated_update(track, t, z - pred, H, cov)

    def _pose_update(self, track, t, sample, p_LI, R_LI):
        z_p, R_meas, cov = sample
        R_Ls = R_LI @ track.R_Is
        p_Ls = p_LI + R_LI @ track.p_Is
        if not track.active:
            self._init_pose_offset(track, z_p, R_meas, cov, p_LI, R_LI)
            track.events.append({"t_ns": t, "event": "frame offset initialised"})
            return
        R_LS_T = track.R_LS.T
        R_Ss = R_LS_T @ R_Ls
        p_Ss = R_LS_T @ (p_Ls - track.t_LS)
        # Residual [Log(R_hat_Ss^T R_meas); p_meas - p_hat] of the right perturbation.
        y = np.array(log9(tuple((R_Ss.T @ R_meas).ravel().tolist())) +
                     tuple((z_p - p_Ss).tolist()))
        s = track.slot
        H = np.zeros((6, self.P.shape[0]))
        H[0:3, ITH:ITH + 3] = track.R_sI                # d(eps)/d(dtheta) = R_sI
        H[0:3, s:s + 3] = -R_Ss.T                       # d(eps)/d(dphi) = -R_Ss^T
        H[3:6, IP:IP + 3] = R_LS_T                      # d(p)/d(dp)
        H[3:6, ITH:ITH + 3] = (R_LS_T @ R_LI) @ track.neg_skew_p_Is
        H[3:6, s:s + 3] = skew(p_Ss)                    # d(p)/d(dphi) = [p_Ss]x
        H[3:6, s + 3:s + 6] = -R_LS_T                   # d(p)/d(dt)
        if track.excluded:
            track.recent.append((t, z_p, R_meas, p_Ls, R_Ls))
            self._maybe_reinitialise(track, t, sample, p_LI, R_LI)
            if not track.active or not track.excluded:
                return
        self._gated_update(track, t, y, H, cov)

    def _maybe_reinitialise(self, track, t, sample, p_LI, R_LI):
        """An excluded pose sensor whose relative motion over the last ~1 s agrees with
        the filter's gets a new frame offset (e.g. after an odometry reset)."""
        recent = track.recent
        while recent and t - recent[0][0] > 1_500_000_000:
            recent.pop(0)
        if t - track.excluded_since_ns < self.reinit_after_ns or not recent or \
                t - recent[0][0] < 1_000_000_000:
            return
        _, z0, Rm0, pL0, RL0 = recent[0]
        _, z1, Rm1, pL1, RL1 = recent[-1]
        # Frame-free quantities: displacement in the mount frame at the first sample,
        # and the relative rotation.
        d_sensor = Rm0.T @ (z1 - z0)
        d_filter = RL0.T @ (pL1 - pL0)
        rot_err = np.linalg.norm(log_so3((Rm0.T @ Rm1).T @ (RL0.T @ RL1)))
        if np.linalg.norm(d_sensor - d_filter) < 0.05 + 0.1 * np.linalg.norm(d_filter) \
                and rot_err < 0.05:
            z_p, R_meas, cov = sample
            self._init_pose_offset(track, z_p, R_meas, cov, p_LI, R_LI)
            track.events.append({"t_ns": t, "event": "re-initialised and re-admitted"})
            tofu_client.log(f"ekf: {track.name} re-initialised at t={t * 1e-9:.3f} s")

    def _gated_update(self, track, t, y, H, Rm):
        P = self.P
        PHt = P @ H.T
        S = H @ PHt + Rm
        try:
            S_inv = inverse(S)
        except np.linalg.LinAlgError:
            track.stats["invalid"] += 1
            return False
        d2 = float(y @ (S_inv @ y))
        consistent = d2 <= self.gate_thr[len(y)] or not self._heading_known()
        if track.excluded:
            track.stats["tested_while_excluded"] += 1
            # With no sensor fused at all nothing can become consistent again: the filter
            # follows this one (re-admitted at once).
            lone = not self.fused_names
            if not consistent and not lone:
                track.good = 0
                return False
            track.good += 1
            if track.good < self.gate_readmit and not lone:
                return False
            track.excluded = False
            track.bad = track.good = 0
            track.events.append({"t_ns": t, "event": "re-admitted"})
            tofu_client.log(f"ekf: {track.name} re-admitted at t={t * 1e-9:.3f} s")
            self._refresh_fused()
        elif not consistent and track.bad + 1 >= self.gate_max_rej and \
                self.fused_names == [track.name]:
            # The sole fused sensor: no redundancy tells a faulty sensor from a wrong
            # state, so after N rejections the filter follows it (this sample is used).
            track.stats["followed_as_sole_sensor"] += 1
            track.events.append({"t_ns": t, "event": "followed (sole sensor)", "chi2": d2})
            tofu_client.log(f"ekf: {track.name} inconsistent (chi2 {d2:.1f}) but the only "
                            f"fused sensor: followed at t={t * 1e-9:.3f} s")
        elif not consistent:
            track.stats["rejected"] += 1
            track.bad += 1
            if track.bad >= self.gate_max_rej:
                track.excluded = True
                track.excluded_since_ns = t
                track.good = 0
                track.recent = []
                track.events.append({"t_ns": t, "event": "excluded", "chi2": d2})
                tofu_client.log(f"ekf: {track.name} excluded at t={t * 1e-9:.3f} s "
                                f"(chi2 {d2:.1f} after {track.bad} rejections)")
                self._refresh_fused()
            return False
        track.bad = 0
        track.stats["accepted"] += 1
        # Kalman update, P <- P - K S K^T = P - K (P H^T)^T for the optimal gain (cheaper
        # than the Joseph form; symmetry is restored every 20 updates and every 200 IMU
        # steps).
        K = PHt @ S_inv
        dx = K @ y
        P = self.P = P - K @ PHt.T
        self.updates += 1
        if self.updates % 20 == 0:
            self.P = 0.5 * (P + P.T)
        self._inject(dx)
        self.last_accept_ns = self.t_imu
        return True

    def _inject(self, dx):
        """Injection [S 6.2] and reset [S 6.3] of the observed error."""
        d = dx[:NCORE].tolist()
        p, v, ba, bg = self.p, self.v, self.ba, self.bg
        self.p = [p[0] + d[0], p[1] + d[1], p[2] + d[2]]
        self.v = [v[0] + d[3], v[1] + d[4], v[2] + d[5]]
        self.R9 = mul9(self.R9, exp9(d[6], d[7], d[8]))
        self.ba = [ba[0] + d[9], ba[1] + d[10], ba[2] + d[11]]
        self.bg = [bg[0] + d[12], bg[1] + d[13], bg[2] + d[14]]
        n = self.corr
        self.corr = (n[0] + d[0], n[1] + d[1], n[2] + d[2], n[3] + d[6], n[4] + d[7],
                     n[5] + d[8])
        for track in self.tracks.values():
            s = track.slot
            if s is None or not track.active:
                continue
            if track.kind == "pose":
                o = dx[s:s + 6].tolist()
                track.R_LS = track.R_LS @ exp_so3(o[0], o[1], o[2])
                track.t_LS = track.t_LS + dx[s + 3:s + 6]
            else:
                track.psi += float(dx[s])
                track.d = track.d + dx[s + 1:s + 4]
        # Reset Jacobian G = I - [dtheta/2]x on every rotation block [S 6.3, eq. 287].
        # Its effect on P is of the order |dtheta|/2 relative: skipped below 1 mrad.
        P = self.P
        for b in self.rot_blocks:
            x, y, z = dx[b:b + 3].tolist()
            if x * x + y * y + z * z < 1e-6:
                continue
            G = I3 - 0.5 * skew((x, y, z))
            P[b:b + 3, :] = G @ P[b:b + 3, :]
            P[:, b:b + 3] = P[:, b:b + 3] @ G.T

    # -- output --------------------------------------------------------------------------

    def _heading_known(self):
        """The heading's standard deviation (about z in L) is below gate_heading_std_rad:
        before that (a position anchor at start-up) the linearised covariance is not
        trustworthy enough to gate on."""
        r = self.R9
        Pt = self.P[ITH:ITH + 3, ITH:ITH + 3].tolist()
        z = (r[6], r[7], r[8])  # e_z of L in I: the yaw axis of the local error
        var = sum(z[i] * Pt[i][j] * z[j] for i in range(3) for j in range(3))
        return var < self.gate_heading_var

    def _valid(self):
        return self.initialized and self.t_imu - self.last_accept_ns <= self.max_gap_ns

    def _refresh_fused(self):
        self.fused_names = [t.name for t in sorted(self.tracks.values(), key=lambda t: t.index)
                            if t.active and not t.excluded]

    def _estimate(self):
        (c00, c01, c02), (c10, c11, c12), (c20, c21, c22) = self.P[:3, :3].tolist()
        c01 = 0.5 * (c01 + c10)
        c02 = 0.5 * (c02 + c20)
        c12 = 0.5 * (c12 + c21)
        return {
            "t_ns": self.t_imu,
            "valid": self.t_imu - self.last_accept_ns <= self.max_gap_ns,
            "initialized": True,
            "p_LI_m": self.p,
            "q_LI_wxyz": quat_from_R(self.R9),
            "v_L_mps": self.v,
            "omega_I_radps": self.omega_I,
            "bias_acc_mps2": self.ba,
            "bias_gyro_radps": self.bg,
            "position_covariance_m2": [c00, c01, c02, c01, c11, c12, c02, c12, c22],
            "fused": self.fused_names,
        }


if __name__ == "__main__":
    sys.exit(tofu_client.run_estimator(EskfEstimator()))

#!/usr/bin/python3
"""A geometric SE(3) controller for a fully actuated (omnidirectional) rigid body, as a
tofu process client (docs/INTERFACE.md, role "controller", protocol 1).

Run:  /usr/bin/python3 examples/python/pd_controller.py   (tofu writes stdin, reads stdout)

The OMAV can produce any force and torque in B (within its rotor limits), so position
and attitude are controlled independently (no thrust-vector tilting as on a quadrotor):

  position (in W):  a_cmd   = a_ref + Kp e_p + Kd e_v + Ki int(e_p) dt,
                    e_p = p_ref - p_WB, e_v = v_ref - v_W, the integral clamped per axis
                    (integral_limit_ms) and frozen while the force saturates;
                    force_W = m (a_cmd + g e_z),  force_B = R_WB^T force_W;
  attitude (in B):  R_err   = R_WB^T R_ref,  e_R = Log(R_err) (the SO(3) log: exact for
                    large errors, unlike the vee of the skew part, Lee et al. 2010 eq. 10,
                    which it equals to first order), e_w = R_err w_ref - w,
                    alpha_ff = R_err alpha_ref - [w]x R_err w_ref (Lee et al. 2010, eq. 16),
                    torque_B = J (alpha_ff + Kr e_R + Kw e_w) + w x J w.

(T. Lee, M. Leok, N. H. McClamroch, "Geometric tracking control of a quadrotor UAV on
SE(3)", CDC 2010.) Gains are accelerations per unit error, so the mass and the inertia
from setup scale them to the robot. Defaults (~4.5 kg OMAV): Kp 20 1/s^2, Kd 9 1/s,
Ki 12 1/s^3 - per axis s^3 + Kd s^2 + Kp s + Ki = (s + 1)(s + 2)(s + 6), so an offset
(wind, a mass error) decays with a 1 s time constant; Kr 100 1/s^2, Kw 20 1/s
(attitude: w_n = 10 rad/s, critically damped).

Config keys (all optional; a number or [x, y, z]): kp_pos, kd_pos, ki_pos, kp_att,
kd_att, integral_limit_ms (default 0.3 m s per axis: Ki times it is 3.6 m/s^2, 37 % of
g), max_force_N (default: all rotors at max_rotor_thrust_N; the force is scaled down to
it, the torque is left to tofu's allocation).
"""

import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import tofu_client  # noqa: E402
from ekf_estimator import R_from_quat, log_so3  # noqa: E402  (shared SO(3) helpers)


def _gain(cfg, key, default):
    value = cfg.get(key, default)
    gains = np.array([float(value)] * 3 if np.isscalar(value) else [float(x) for x in value])
    if gains.shape != (3,) or not np.all(np.isfinite(gains)) or np.any(gains < 0.0):
        raise ValueError(f"config {key}: expected a non-negative number or [x, y, z]")
    return gains


def _vec3(obj, key):
    values = tofu_client.finite_floats(obj[key], 3)
    if values is None:
        raise ValueError(f"{key}: expected 3 finite numbers")
    return np.array(values)


class Se3Controller:
    def start(self, setup):
        cfg = setup.get("config") or {}
        if not isinstance(cfg, dict):
            raise ValueError("config must be a map")
        unknown = sorted(set(cfg) - {"kp_pos", "kd_pos", "ki_pos", "kp_att", "kd_att",
                                     "integral_limit_ms", "max_force_N"})
        if unknown:
            tofu_client.log(f"pd_controller: ignoring unknown config keys {unknown}")
        self.mass_kg = float(setup["mass_kg"])
        self.J_B = np.array([float(x) for x in setup["inertia_B_kgm2"]]).reshape(3, 3)
        self.g = float(setup["gravity_mps2"])
        self.kp = _gain(cfg, "kp_pos", 20.0)
        self.kd = _gain(cfg, "kd_pos", 9.0)
        self.ki = _gain(cfg, "ki_pos", 12.0)
        self.kr = _gain(cfg, "kp_att", 100.0)
        self.kw = _gain(cfg, "kd_att", 20.0)
        self.integral_limit = _gain(cfg, "integral_limit_ms", 0.3)
        rotors = 2 * int(setup.get("arm_count", 6))
        max_thrust = float(setup.get("max_rotor_thrust_N", 0.0))
        default_max = rotors * max_thrust if max_thrust > 0.0 else math.inf
        self.max_force = float(cfg.get("max_force_N", default_max))
        self.integral = np.zeros(3)  # int(e_p) dt [m s]
        self.t_prev_ns = None
        self.saturated = False
        tofu_client.log(f"pd_controller: m={self.mass_kg} kg, rate {setup.get('rate_hz')} Hz, "
                        f"max force {self.max_force:.1f} N")

    def compute(self, state, reference):
        t_ns = state.get("t_ns")  # the control instant (tofu_client copies it in)
        p_WB, v_W = _vec3(state, "p_WB_m"), _vec3(state, "v_W_mps")
        w_B = _vec3(state, "omega_B_radps")
        R_WB = R_from_quat(state["q_WB_wxyz"])
        p_ref, v_ref = _vec3(reference, "p_WB_m"), _vec3(reference, "v_W_mps")
        a_ref = _vec3(reference, "a_W_mps2")
        w_ref, alpha_ref = _vec3(reference, "omega_B_radps"), _vec3(reference, "alpha_B_radps2")
        R_ref = R_from_quat(reference["q_WB_wxyz"])

        dt = 0.0
        if t_ns is not None and self.t_prev_ns is not None:
            dt = min(max((t_ns - self.t_prev_ns) * 1e-9, 0.0), 0.1)
        self.t_prev_ns = t_ns

        # Position loop in W.
        e_p = p_ref - p_WB
        e_v = v_ref - v_W
        if not self.saturated:  # anti-windup: freeze the integral while saturated
            self.integral = np.clip(self.integral + e_p * dt, -self.integral_limit,
                                    self.integral_limit)
        a_cmd = a_ref + self.kp * e_p + self.kd * e_v + self.ki * self.integral
        force_W = self.mass_kg * (a_cmd + np.array([0.0, 0.0, self.g]))
        force_B = R_WB.T @ force_W
        norm = float(np.linalg.norm(force_B))
        self.saturated = norm > self.max_force
        if self.saturated:
            force_B *= self.max_force / norm

        # Attitude loop in B.
        R_err = R_WB.T @ R_ref
        e_R = log_so3(R_err)
        w_ref_B = R_err @ w_ref
        e_w = w_ref_B - w_B
        alpha_ff = R_err @ alpha_ref - np.cross(w_B, w_ref_B)
        J = self.J_B
        torque_B = J @ (alpha_ff + self.kr * e_R + self.kw * e_w) + np.cross(w_B, J @ w_B)
        return {"force_B_N": force_B.tolist(), "torque_B_Nm": torque_B.tolist()}


if __name__ == "__main__":
    sys.exit(tofu_client.run_controller(Se3Controller()))

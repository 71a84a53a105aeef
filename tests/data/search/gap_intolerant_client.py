#!/usr/bin/python3
"""A user's estimator that crashes at some parameters (tests/search_test.cc): docs/INTERFACE.md's
minimal client, except that it exits with an error when its `vio` stream falls silent for more
than 1.2 s. `tofu search` must find that crash as a failure, with this program's stderr."""
import json
import sys


def send(message):
    sys.stdout.write(json.dumps(message, allow_nan=False) + "\n")
    sys.stdout.flush()


pose = None
last_vio_ns = None
for line in sys.stdin:
    m = json.loads(line)
    if m["type"] == "hello":
        send({"type": "hello", "version": 2})
    elif m["type"] == "setup":
        send({"type": "ready"})
    elif m["type"] == "measurement":
        if m["sensor"] == "vio":
            last_vio_ns = m["t_ns"]
        elif m["kind"] == "imu" and last_vio_ns is not None and m["t_ns"] - last_vio_ns > 1.2e9:
            sys.stderr.write(f"gap_intolerant: no vio for {(m['t_ns'] - last_vio_ns) / 1e9:.2f} s, giving up\n")
            sys.exit(3)
        if m["kind"] == "pose" and None not in m["p_Ss_m"] + m["q_Ss_wxyz"]:
            pose = (m["p_Ss_m"], m["q_Ss_wxyz"])
        answer = []
        if m["kind"] == "imu":
            p, q = pose if pose else ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
            answer.append({"t_ns": m["t_ns"], "valid": pose is not None, "p_LI_m": p,
                           "q_LI_wxyz": q, "v_L_mps": [0.0, 0.0, 0.0],
                           "omega_I_radps": m["gyro_I_radps"]})
        send({"type": "estimates", "seq": m["seq"], "estimates": answer})
    elif m["type"] == "finish":
        send({"type": "finished"})
        break

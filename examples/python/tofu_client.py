"""tofu_client: a small helper for writing tofu process clients in Python.

Speaks tofu's lockstep protocol (docs/INTERFACE.md, version 2) on standard input and
standard output, and hands each message to an estimator or a controller object:

    estimator:  start(setup)                     setup message (dict), answered "ready"
                add(measurement) -> [estimate]   one "estimates" answer per measurement
                finish() -> (estimates, report)  answered "finished"
    controller: start(setup)                     answered "ready"
                compute(state, reference) -> {"force_B_N": [3], "torque_B_Nm": [3]}
                                                 (or "tilt_rad"/"rotor_thrust_N"); state
                                                 also holds the control's "t_ns"
                finish() (optional)              answered "finished"

Usage (see ekf_estimator.py, pd_controller.py):

    if __name__ == "__main__":
        sys.exit(tofu_client.run_estimator(MyEstimator()))

Encoding: JSON lines by default (standard library only). MessagePack is used only when
the environment variable TOFU_CLIENT_ENCODING=msgpack asks for it, the `msgpack` module is
importable and tofu offers it; otherwise JSON. Messages are read from sys.stdin.buffer
and written to sys.stdout.buffer, one flush per message (tofu waits for each answer).
Doubles are written by json's float repr, the shortest round-trip form.

Errors: any exception (in the protocol or in the estimator/controller) is answered with
{"type": "error", "message": ...}, its traceback goes to standard error, and the
process exits with status 1. Logging goes to standard error only (`log()`), since
standard output carries the protocol.
"""

import json
import math
import os
import struct
import sys
import time
import traceback

PROTOCOL_VERSION = 2


class ProtocolError(Exception):
    """The conversation broke the protocol (an unknown message type, a missing key...)."""


def log(*args):
    """Writes one line to standard error (tofu keeps the last 20 lines for its run log)."""
    print(*args, file=sys.stderr, flush=True)


def _default(obj):
    # numpy arrays and scalars (np.int64 is not an int): encode their Python value.
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


class Connection:
    """Reads tofu's messages and writes the answers, in JSON lines or MessagePack."""

    def __init__(self, stdin=None, stdout=None):
        self._in = stdin if stdin is not None else sys.stdin.buffer
        self._out = stdout if stdout is not None else sys.stdout.buffer
        self.encoding = "json"
        # allow_nan=False: "every number must be finite" - a NaN in an answer raises
        # here (and becomes an error message) instead of reaching tofu as invalid JSON.
        self._encode = json.JSONEncoder(separators=(",", ":"), allow_nan=False,
                                        default=_default).encode
        self._decode = json.loads
        self._msgpack = None

    def use_msgpack(self, msgpack_module):
        self.encoding = "msgpack"
        self._msgpack = msgpack_module

    def read(self):
        """The next message (a dict), or None at the end of standard input."""
        if self.encoding == "json":
            while True:
                line = self._in.readline()
                if not line:
                    return None
                if line.strip():
                    break
            msg = self._decode(line)
        else:
            header = self._in.read(4)
            if not header:
                return None
            if len(header) < 4:
                raise ProtocolError("standard input ended inside a MessagePack length")
            (size,) = struct.unpack(">I", header)
            data = self._in.read(size)
            if len(data) < size:
                raise ProtocolError("standard input ended inside a MessagePack message")
            msg = self._msgpack.unpackb(data, raw=False)
        if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
            raise ProtocolError("a message is not an object with a string \"type\"")
        return msg

    def write(self, msg):
        if self.encoding == "json":
            self._out.write(self._encode(msg).encode() + b"\n")
        else:
            # Same finiteness rule as the JSON encoder (msgpack would send NaN silently).
            data = self._msgpack.packb(msg, use_bin_type=True, default=_default)
            self._out.write(struct.pack(">I", len(data)) + data)
        self._out.flush()


def _choose_encoding(hello, conn):
    wanted = os.environ.get("TOFU_CLIENT_ENCODING", "json")
    if wanted == "msgpack" and "msgpack" in hello.get("encodings", []):
        try:
            import msgpack  # optional; only when asked for
        except ImportError:
            log("tofu_client: msgpack not importable, using JSON lines")
            return "json"
        return "msgpack", msgpack
    return "json"


def _describe(msg):
    seq = msg.get("seq") if isinstance(msg, dict) else None
    kind = msg.get("type") if isinstance(msg, dict) else None
    return f"{kind}" + (f" seq={seq}" if seq is not None else "")


def serve(handler, role, conn=None):
    """Runs the whole conversation for `handler` in `role` ("estimator" or "controller").
    Returns the process exit status: 0 after "finished", 1 on any error."""
    conn = conn if conn is not None else Connection()
    msg = None
    counts = {}
    cpu_start = time.process_time()
    try:
        msg = conn.read()
        if msg is None:
            raise ProtocolError("standard input closed before hello")
        if msg["type"] != "hello":
            raise ProtocolError(f"expected hello, got message type {msg['type']!r}")
        if msg.get("protocol", "tofu") != "tofu":
            raise ProtocolError(f"not a tofu hello (protocol {msg.get('protocol')!r})")
        if msg["version"] != PROTOCOL_VERSION:
            # Answer our version anyway: tofu refuses it naming both numbers.
            log(f"tofu_client: tofu speaks protocol version {msg['version']}, "
                f"this client speaks {PROTOCOL_VERSION}")
        if msg["role"] != role:
            raise ProtocolError(f"this client is a {role}, tofu asked for a {msg['role']!r}")
        choice = _choose_encoding(msg, conn)
        encoding = choice if isinstance(choice, str) else choice[0]
        conn.write({"type": "hello", "version": PROTOCOL_VERSION, "encoding": encoding})
        if encoding == "msgpack":
            conn.use_msgpack(choice[1])

        is_estimator = role == "estimator"
        while True:
            msg = conn.read()
            if msg is None:
                raise ProtocolError("standard input closed before finish")
            kind = msg["type"]
            counts[kind] = counts.get(kind, 0) + 1
            if kind == "measurement" and is_estimator:
                conn.write({"type": "estimates", "seq": msg["seq"],
                            "estimates": handler.add(msg)})
            elif kind == "control" and not is_estimator:
                # The state gets the control instant, as ControlState::t_ns in api.h.
                state = msg["state"]
                state["t_ns"] = msg["t_ns"]
                command = dict(handler.compute(state, msg["reference"]))
                command["type"] = "command"
                command["seq"] = msg["seq"]
                conn.write(command)
            elif kind == "setup":
                handler.start(msg)
                conn.write({"type": "ready"})
            elif kind == "finish":
                answer = {"type": "finished"}
                if is_estimator:
                    estimates, report = handler.finish()
                    answer["estimates"] = list(estimates or [])
                    answer["report"] = dict(report or {})
                elif hasattr(handler, "finish"):
                    handler.finish()
                conn.write(answer)
                cpu_s = time.process_time() - cpu_start
                n = sum(counts.values())
                log(f"tofu_client: finished after {n} messages "
                    f"({', '.join(f'{k}: {v}' for k, v in sorted(counts.items()))}); "
                    f"{cpu_s:.2f} s CPU, {1e6 * cpu_s / max(n, 1):.1f} us per message")
                return 0
            else:
                raise ProtocolError(f"unknown message type {kind!r} for a {role}")
    except Exception as error:  # noqa: BLE001 - every failure is reported to tofu
        if isinstance(error, KeyError):
            text = f"missing key {error.args[0]!r}"
        else:
            text = f"{type(error).__name__}: {error}"
        if msg is not None:
            text = f"{_describe(msg)}: {text}"
        traceback.print_exc(file=sys.stderr)
        log(f"tofu_client: error: {text}")
        try:
            conn.write({"type": "error", "message": text})
        except Exception:  # noqa: BLE001 - tofu may be gone (broken pipe)
            pass
        return 1


def run_estimator(estimator, conn=None):
    return serve(estimator, "estimator", conn)


def run_controller(controller, conn=None):
    return serve(controller, "controller", conn)


def finite_floats(values, count):
    """`values` as a list of `count` finite floats, or None (a missing/NaN/null sample:
    tofu delivers sensor faults as they are)."""
    try:
        out = [float(x) for x in values]
    except (TypeError, ValueError):
        return None
    if len(out) != count or not all(math.isfinite(x) for x in out):
        return None
    return out

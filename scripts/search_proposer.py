#!/usr/bin/python3
"""The guided optimiser of `tofu search` (campaign/search.h): optuna's TPE sampler behind an
ask/tell protocol of one JSON object per line on stdin/stdout.

  {"op": "init", "sampler": "tpe", "seed": s, "dimensions": [{"name": n, "choices": k}, ...]}
  {"op": "ask", "n": k}            -> {"points": [[u_0, ..., u_d-1], ...]}   (each u in [0, 1])
  {"op": "tell", "values": [...]}  -> {"ok": true}   (the margins of the last ask, in order)

A dimension with k > 0 choices is categorical; its coordinate is (index + 0.5) / k. Asks of
one batch are told together; TPE's constant liar keeps a batch's points apart. Seeded and
replayed in the same order, it proposes the same points (tofu resumes a search so).
"""
import json
import sys
import warnings


def make_study(init):
    import optuna
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    if init["sampler"] != "tpe":
        raise ValueError(f"unknown sampler {init['sampler']!r} (expected tpe)")
    sampler = optuna.samplers.TPESampler(seed=int(init["seed"]), multivariate=True, constant_liar=True)
    return optuna.create_study(direction="minimize", sampler=sampler)


def suggest(trial, dimensions):
    point = []
    for i, d in enumerate(dimensions):
        k = int(d["choices"])
        if k > 0:
            index = trial.suggest_categorical(f"x{i}", list(range(k)))
            point.append((index + 0.5) / k)
        else:
            point.append(trial.suggest_float(f"x{i}", 0.0, 1.0))
    return point


def reply(message):
    sys.stdout.write(json.dumps(message) + "\n")
    sys.stdout.flush()


def main():
    init = json.loads(sys.stdin.readline())
    study = make_study(init)
    dimensions = init["dimensions"]
    pending = []
    reply({"ok": True})
    for line in sys.stdin:
        message = json.loads(line)
        if message["op"] == "ask":
            # One at a time: the constant liar sees the batch's earlier points as running.
            pending, points = [], []
            for _ in range(int(message["n"])):
                pending.append(study.ask())
                points.append(suggest(pending[-1], dimensions))
            reply({"points": points})
        elif message["op"] == "tell":
            values = message["values"]
            if len(values) != len(pending):
                reply({"error": f"told {len(values)} values for {len(pending)} points"})
                continue
            for trial, value in zip(pending, values):
                study.tell(trial, float(value))
            pending = []
            reply({"ok": True})
        else:
            reply({"error": f"unknown op {message['op']!r}"})


if __name__ == "__main__":
    main()

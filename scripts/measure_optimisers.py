#!/usr/bin/python3
"""Measure which guided optimiser `tofu search` should use, on synthetic margins.

Four deterministic problems in the unit cube imitate sensor-fault searches (margin < 0 is a
failure). Optuna's TPE and NLopt's global methods run seeded, fixed-budget trials against
uniform random sampling, the control: a search is worth guiding only if it finds failures
in fewer flights. Reported per problem: share of trials finding one, median evaluations to it.
"""
import argparse
import json
import math
import multiprocessing
import sys
import time
import warnings
from collections import namedtuple

import nlopt
import numpy as np
import optuna

CLIP = 10.0
BATCH = 2  # tofu search evaluates --jobs points at once; 2 here
CHOICES = 6  # choices of the categorical dimension (dimension 0 of "categorical")

Problem = namedtuple("Problem", "name dim margin categorical")


# --- problems: margin(u) for u of shape (..., dim), vectorised so volumes are cheap ---

def onset_near_wall(u):
    """A bias (onset, duration, magnitude, direction) that fails if active at 0.45-0.52."""
    onset, duration, magnitude, direction = (u[..., i] for i in range(4))
    end = onset + 0.3 * duration
    gap = np.maximum(0.0, np.maximum(0.45 - end, onset - 0.52))  # 0 when the windows overlap
    overlap = np.exp(-gap / 0.05)
    toward = np.minimum(0.1 + direction, 1.0)  # share of the bias that points at the wall
    return 1.0 - magnitude / 0.6 * toward * overlap


NEEDLE_CENTRE = np.array([0.71, 0.29, 0.62, 0.78, 0.35])
NEEDLE_HALF = 0.5 * 0.005 ** (1 / 5)  # a box of volume 0.5 %


def needle(u):
    """A small failing box; its margin slopes within twice its size and is flat (1) beyond."""
    distance = np.max(np.abs(u - NEEDLE_CENTRE), axis=-1) / NEEDLE_HALF
    return np.minimum(distance - 1.0, 1.0)


CATEGORY_OFFSET = np.array([0.6, 0.3, 0.8, 0.5, 0.0, 0.7])  # no order: a fault kind


def categorical(u):
    """Only choice 4 of dimension 0 fails, when u1 > 0.8 and u2 < 0.3; u3, u4 do nothing."""
    choice = np.minimum((u[..., 0] * CHOICES).astype(int), CHOICES - 1)
    shape = np.maximum((0.8 - u[..., 1]) / 0.8, (u[..., 2] - 0.3) / 0.7)
    return CATEGORY_OFFSET[choice] + shape


def two_faults(u):
    """Two slots (onset, duration, magnitude, direction): fail if overlapping, both > 0.5."""
    start = u[..., [0, 4]]
    end = start + 0.1 * u[..., [1, 5]]
    separation = np.maximum(start[..., 0] - end[..., 1], start[..., 1] - end[..., 0])
    weakest = np.max((0.5 - u[..., [2, 6]]) / 0.5, axis=-1)
    return np.maximum(separation / 0.1, weakest)


PROBLEMS = [
    Problem("onset_near_wall", 4, onset_near_wall, False),
    Problem("needle", 5, needle, False),
    Problem("categorical", 5, categorical, True),
    Problem("two_faults", 8, two_faults, False),
]


def margin(problem, u):
    return float(np.clip(problem.margin(np.asarray(u, dtype=float)), -CLIP, CLIP))


def failure_volume(problem, samples=400_000):
    u = np.random.default_rng(12345).random((samples, problem.dim))
    return float(np.mean(problem.margin(u) < 0))


# --- one trial: evaluations counted, the first failure's (1-based) index kept ---

class Trial:
    def __init__(self, problem, budget):
        self.problem, self.budget = problem, budget
        self.count = 0  # evaluations within the budget
        self.first = None
        self.past_budget = 0  # calls an optimiser made past the budget (maxeval not kept)
        self.after_stop = 0  # calls it made after being told to stop (the first failure)
        self.ended = ""  # why an NLopt run returned, when it returned by itself

    def done(self):
        return self.first is not None or self.count >= self.budget

    def evaluate(self, u):
        if self.first is not None:
            self.after_stop += 1
            return CLIP
        if self.count >= self.budget:
            self.past_budget += 1
            return CLIP
        self.count += 1
        value = margin(self.problem, u)
        if value < 0:
            self.first = self.count
        return value


def run_random(trial, seed):
    rng = np.random.default_rng(seed)
    while not trial.done():
        trial.evaluate(rng.random(trial.problem.dim))


def optuna_sampler(kind, seed):
    if kind == "qmc":
        return optuna.samplers.QMCSampler(qmc_type="sobol", scramble=True, seed=seed)
    return optuna.samplers.TPESampler(seed=seed, constant_liar=True,
                                      multivariate=(kind == "tpe_mv"))


def optuna_space(problem, as_category):
    space = {f"u{i}": optuna.distributions.FloatDistribution(0.0, 1.0)
             for i in range(problem.dim)}
    if as_category:
        space["u0"] = optuna.distributions.CategoricalDistribution(list(range(CHOICES)))
    return space


def optuna_point(params, problem, as_category):
    u = [params[f"u{i}"] for i in range(problem.dim)]
    if as_category:
        u[0] = (u[0] + 0.5) / CHOICES
    return u


def run_optuna(trial, seed, kind, as_category):
    """Ask BATCH points (the constant liar sees the pending ones), evaluate and tell them."""
    study = optuna.create_study(direction="minimize", sampler=optuna_sampler(kind, seed))
    space = optuna_space(trial.problem, as_category)
    while not trial.done():
        asked = [study.ask(space) for _ in range(min(BATCH, trial.budget - trial.count))]
        for t in asked:
            if trial.done():  # the batch's other point is flown, but not counted
                break
            study.tell(t, trial.evaluate(optuna_point(t.params, trial.problem, as_category)))


def nlopt_optimiser(algorithm, dim, budget):
    """MLSL needs a local optimiser: BOBYQA, at most 40 evaluations per local search."""
    opt = nlopt.opt(getattr(nlopt, algorithm), dim)
    opt.set_lower_bounds([0.0] * dim)
    opt.set_upper_bounds([1.0] * dim)
    opt.set_maxeval(budget)
    if algorithm == "GN_MLSL_LDS":
        local = nlopt.opt(nlopt.LN_BOBYQA, dim)
        local.set_xtol_rel(1e-3)
        local.set_maxeval(40)
        opt.set_local_optimizer(local)
    return opt


NLOPT_RESULTS = {1: "success", 2: "stopval", 3: "ftol", 4: "xtol", 5: "maxeval",
                 6: "maxtime", -1: "failure", -4: "roundoff", -5: "forced stop"}


def run_nlopt(trial, seed, algorithm):
    """Minimise the margin; the objective forces a stop at the first failure (or if the
    optimiser ignores maxeval by far), else NLopt stops by itself (maxeval or another test)."""
    nlopt.srand(seed)
    opt = nlopt_optimiser(algorithm, trial.problem.dim, trial.budget)

    def objective(x, grad):
        value = trial.evaluate(x)
        if trial.first is not None or trial.past_budget > 10 * trial.budget:
            opt.force_stop()  # raising ForcedStop again, on a later call, is a SystemError
        return value

    opt.set_min_objective(objective)
    start = np.random.default_rng(seed).random(trial.problem.dim)
    try:
        opt.optimize(start)
        code = opt.last_optimize_result()
        trial.ended = NLOPT_RESULTS.get(code, str(code))
    except nlopt.ForcedStop:
        pass
    except (nlopt.RoundoffLimited, RuntimeError, ValueError) as error:
        trial.ended = type(error).__name__


NLOPT = ["GN_CRS2_LM", "GN_ESCH", "GN_ISRES", "GN_DIRECT_L", "GN_MLSL_LDS"]
OPTIMISERS = (["random", "qmc", "tpe", "tpe_mv", "tpe[cat]", "tpe_mv[cat]"]
              + [a[3:].lower() for a in NLOPT])


def applies(optimiser, problem):
    return problem.categorical or not optimiser.endswith("[cat]")


def run_trial(job):
    problem_name, optimiser, seed, budget = job
    warnings.filterwarnings("ignore")
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    problem = next(p for p in PROBLEMS if p.name == problem_name)
    trial = Trial(problem, budget)
    began = time.perf_counter()
    if optimiser == "random":
        run_random(trial, seed)
    elif optimiser in ("qmc", "tpe", "tpe_mv", "tpe[cat]", "tpe_mv[cat]"):
        run_optuna(trial, seed, optimiser.removesuffix("[cat]"), optimiser.endswith("[cat]"))
    else:
        run_nlopt(trial, seed, "GN_" + optimiser.upper())
    seconds = time.perf_counter() - began
    return {"problem": problem_name, "optimiser": optimiser, "seed": seed,
            "first": trial.first, "evaluations": trial.count, "ended": trial.ended,
            "past_budget": trial.past_budget, "after_stop": trial.after_stop,
            "ms_per_eval": 1000.0 * seconds / max(trial.count, 1)}


# --- summary ---

def median_to_failure(trials):
    return float(np.median([t["first"] if t["first"] else math.inf for t in trials]))


def ratio(control, median):
    if math.isinf(control) and math.isinf(median):
        return math.nan
    return control / median


def early_stops(trials, budget):
    """Why the trials that ended before the budget without a failure ended, counted."""
    reasons = {}
    for t in trials:
        if t["first"] is None and t["evaluations"] < budget:
            reasons[t["ended"]] = reasons.get(t["ended"], 0) + 1
    return reasons


def summarise(results, budget, reps):
    rows = []
    for problem in PROBLEMS:
        control = median_to_failure([r for r in results if r["problem"] == problem.name
                                     and r["optimiser"] == "random"])
        for optimiser in OPTIMISERS:
            trials = [r for r in results
                      if r["problem"] == problem.name and r["optimiser"] == optimiser]
            if not trials:
                continue
            median = median_to_failure(trials)
            rows.append({
                "problem": problem.name, "optimiser": optimiser,
                "rate": sum(t["first"] is not None for t in trials) / reps,
                "median": median, "random_over_optimiser": ratio(control, median),
                "early_stops": early_stops(trials, budget),
                "calls_past_budget": sum(t["past_budget"] for t in trials),
                "calls_after_stop": sum(t["after_stop"] for t in trials),
                "same_every_seed": len(trials) > 1
                and len({(t["first"], t["evaluations"]) for t in trials}) == 1,
                "ms_per_eval": float(np.mean([t["ms_per_eval"] for t in trials])),
            })
    return rows


def number(x, digits=1):
    if math.isnan(x):
        return "-"
    return "inf" if math.isinf(x) else f"{x:.{digits}f}"


def notes(row, budget):
    said = [f"{n} ended before {budget} with no failure ({why})"
            for why, n in row["early_stops"].items()]
    if row["calls_past_budget"]:
        said.append(f"{row['calls_past_budget']} calls past maxeval")
    if row["calls_after_stop"]:
        said.append(f"{row['calls_after_stop']} calls after the forced stop")
    if row["same_every_seed"]:
        said.append("same for every seed")
    return "; ".join(said)


def markdown(rows, volumes, budget, reps):
    lines = [f"budget {budget} evaluations, {reps} seeds; median = evaluations to the first "
             "failure (unfound = inf); ratio = random's median / the optimiser's; "
             "random's expected median is ln 0.5 / ln(1 - volume)", "",
             "| problem (failure volume) | optimiser | found | median | ratio | ms/eval | notes |",
             "|---|---|---|---|---|---|---|"]
    for row in rows:
        volume = volumes[row["problem"]]
        expected = math.log(0.5) / math.log1p(-volume)
        name = f"{row['problem']} ({100 * volume:.2f} %, random ~{expected:.0f})"
        lines.append(f"| {name} | {row['optimiser']} | {row['rate']:.2f} | "
                     f"{number(row['median'])} | {number(row['random_over_optimiser'], 2)} | "
                     f"{row['ms_per_eval']:.2f} | {notes(row, budget)} |")
    return "\n".join(lines)


def json_safe(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None if math.isnan(x) else "inf"
    return x


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=int, default=200, help="evaluations per trial")
    parser.add_argument("--reps", type=int, default=10, help="trials (seeds 1..reps)")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    args = parser.parse_args()

    began = time.perf_counter()
    jobs = [(p.name, o, seed, args.budget) for p in PROBLEMS for o in OPTIMISERS
            if applies(o, p) for seed in range(1, args.reps + 1)]
    with multiprocessing.Pool(args.jobs) as pool:
        results = pool.map(run_trial, jobs, chunksize=1)
    volumes = {p.name: failure_volume(p) for p in PROBLEMS}
    rows = summarise(results, args.budget, args.reps)
    wall = time.perf_counter() - began

    print(markdown(rows, volumes, args.budget, args.reps))
    print(f"\nwall time {wall:.1f} s with {args.jobs} worker(s)")
    if args.json:
        document = {"budget": args.budget, "reps": args.reps, "wall_seconds": wall,
                    "failure_volume": volumes,
                    "rows": [{k: json_safe(v) for k, v in r.items()} for r in rows],
                    "trials": results}
        with open(args.json, "w") as f:
            json.dump(document, f, indent=1, allow_nan=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())

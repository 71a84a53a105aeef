#!/usr/bin/python3
"""tofu compare's statistics (campaign/statistics.h) against scipy.stats on the same inputs.

    statistics_scipy_check.py PROBE

PROBE is tests/statistics_probe (JSON lines in, answers out). Random cases with a fixed seed:
exact Wilcoxon signed-rank and Mann-Whitney p-values against scipy's exact tests where scipy
has them (no ties, no zeros), and against scipy.stats.permutation_test's exact enumeration
where ties make scipy's exact mode unavailable; McNemar's exact test against
scipy.stats.binomtest; Fisher's one-sided test against scipy.stats.fisher_exact; the median
against numpy; Benjamini-Hochberg and -Yekutieli against their definitions (scipy 1.10 has
no false_discovery_control). Exits 1 on the first disagreement beyond 1e-9, naming it.
"""
import json
import subprocess
import sys

import numpy as np
from scipy import stats

RNG = np.random.default_rng(52)
TOLERANCE = 1e-9


def ask(probe, queries):
    text = "".join(json.dumps(q) + "\n" for q in queries)
    out = subprocess.run([probe], input=text, capture_output=True, text=True, check=True).stdout
    return [json.loads(line) for line in out.splitlines()]


def close(a, b):
    return abs(a - b) <= TOLERANCE * max(1.0, abs(b))


def wilcoxon_cases():
    cases = []
    for _ in range(150):
        n = int(RNG.integers(1, 18))
        d = RNG.normal(0.3, 1.0, n)
        alt = "greater" if RNG.random() < 0.5 else "less"
        want = stats.wilcoxon(d, alternative=alt, method="exact").pvalue
        cases.append(({"fn": "wilcoxon", "d": d.tolist(), "alternative": alt}, want))
    for _ in range(60):  # ties and zeros: the exact sign-flip distribution of T+
        n = int(RNG.integers(2, 11))
        d = RNG.integers(-3, 4, n).astype(float)
        nonzero = d[d != 0]
        alt = "greater" if RNG.random() < 0.5 else "less"
        if nonzero.size == 0:
            want = 1.0
        elif nonzero.size == 1:  # permutation_test takes two or more: T+ is 0 or r, each 1/2
            want = 0.5 if (nonzero[0] > 0) == (alt == "greater") else 1.0
        else:
            ranks = stats.rankdata(np.abs(nonzero))
            res = stats.permutation_test(
                (nonzero,), lambda x: np.sum(ranks[x > 0]), permutation_type="samples",
                n_resamples=np.inf, alternative=alt)
            want = res.pvalue
        cases.append(({"fn": "wilcoxon", "d": d.tolist(), "alternative": alt}, want))
    return cases


def mannwhitney_cases():
    cases = []
    for _ in range(120):
        nx, ny = int(RNG.integers(1, 12)), int(RNG.integers(1, 12))
        x = RNG.normal(0.0, 1.0, nx)
        y = RNG.normal(0.4, 1.0, ny)
        alt = "greater" if RNG.random() < 0.5 else "less"
        # scipy's first sample is the one shifted to `alternative`: ours is y.
        want = stats.mannwhitneyu(y, x, alternative=alt, method="exact").pvalue
        cases.append(({"fn": "mannwhitney", "x": x.tolist(), "y": y.tolist(), "alternative": alt}, want))
    for _ in range(40):  # ties: the exact distribution of y's rank sum
        nx, ny = int(RNG.integers(2, 7)), int(RNG.integers(2, 7))
        x = RNG.integers(0, 4, nx).astype(float)
        y = RNG.integers(0, 4, ny).astype(float)
        alt = "greater" if RNG.random() < 0.5 else "less"
        pooled_ranks = stats.rankdata(np.concatenate([x, y]))

        def rank_sum_of_y(a, b, axis=-1):
            r = stats.rankdata(np.concatenate([a, b], axis=axis), axis=axis)
            return np.sum(r[..., a.shape[axis]:], axis=axis)
        del pooled_ranks
        want = stats.permutation_test((x, y), rank_sum_of_y, permutation_type="independent",
                                      n_resamples=np.inf, alternative=alt, vectorized=True).pvalue
        cases.append(({"fn": "mannwhitney", "x": x.tolist(), "y": y.tolist(), "alternative": alt}, want))
    return cases


def count_cases():
    cases = []
    for _ in range(80):
        b, c = int(RNG.integers(0, 15)), int(RNG.integers(0, 15))
        alt = "greater" if RNG.random() < 0.5 else "less"
        want = 1.0 if b + c == 0 else stats.binomtest(c, b + c, 0.5, alternative=alt).pvalue
        cases.append(({"fn": "mcnemar", "base_only": b, "new_only": c, "alternative": alt}, want))
    for _ in range(80):
        n, m = int(RNG.integers(1, 25)), int(RNG.integers(1, 25))
        a, b = int(RNG.integers(0, n + 1)), int(RNG.integers(0, m + 1))
        alt = "greater" if RNG.random() < 0.5 else "less"
        want = stats.fisher_exact([[b, m - b], [a, n - a]], alternative=alt)[1]
        cases.append(({"fn": "fisher", "base_yes": a, "base_n": n, "new_yes": b, "new_n": m,
                       "alternative": alt}, want))
    for _ in range(30):
        x = RNG.normal(size=int(RNG.integers(1, 20)))
        cases.append(({"fn": "median", "x": x.tolist()}, float(np.median(x))))
    return cases


def bh_reference(p, dependence_factor=1.0):
    p = np.asarray(p, dtype=float)
    m = p.size
    order = np.argsort(p, kind="stable")
    scaled = p[order] * m / np.arange(1, m + 1) * dependence_factor
    adjusted = np.minimum.accumulate(scaled[::-1])[::-1]
    out = np.empty(m)
    out[order] = np.minimum(adjusted, 1.0)
    return out


def main():
    probe = sys.argv[1]
    failures = 0
    scalar = wilcoxon_cases() + mannwhitney_cases() + count_cases()
    answers = ask(probe, [q for q, _ in scalar])
    for (query, want), got in zip(scalar, answers):
        value = got.get("p", got.get("median"))
        if not close(value, want):
            print(f"MISMATCH {query}: tofu {value!r}, scipy {want!r}")
            failures += 1
    vectors = []
    for _ in range(40):
        p = RNG.uniform(0, 1, int(RNG.integers(1, 40))) ** 2
        vectors.append(("bh", p, bh_reference(p)))
        harmonic = np.sum(1.0 / np.arange(1, p.size + 1))
        vectors.append(("by", p, bh_reference(p, harmonic)))
    answers = ask(probe, [{"fn": fn, "p": p.tolist()} for fn, p, _ in vectors])
    for (fn, p, want), got in zip(vectors, answers):
        if not np.allclose(got["adjusted"], want, rtol=TOLERANCE, atol=TOLERANCE):
            print(f"MISMATCH {fn} {p.tolist()}: tofu {got['adjusted']}, reference {want.tolist()}")
            failures += 1
    total = len(scalar) + len(vectors)
    print(f"statistics_scipy_check: {total - failures} of {total} cases agree with scipy "
          f"{__import__('scipy').__version__}")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()

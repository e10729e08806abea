#!/usr/bin/python3
"""Reference values for the noise model fit and u(T) (analysis/noise_model.h).

Reads the Allan curves of tests/analysis/data/allan_<case>.txt (the numpy
reference points of allan_reference.py: m, tau, adev, terms, edf) and writes
tests/analysis/data/noise_model_<case>.txt, read by
tests/analysis/noise_model_test.cpp; the case gm_white has no series: its
curve is a Gauss-Markov process's and white noise's exact Allan deviations
(sigma_g 0.01 deg/h, T_c 300 s, white 0.02 deg/h at 1 s, octave taus 1 ...
2048 s, white-noise edf of a 7 200 s record) times fixed factors near 1,
written into its file as "point" lines. Computed here with numpy,
independently of the C++ code (Eigen's LDLT on the normal equations there;
the weighted design matrix through np.linalg.lstsq here), by the method
noise_model.h documents: the terms (1/tau, 1, tau, a(tau/T_c)) with
a(x) = (2/x) [1 - (3 - 4 e^-x + e^-2x) / (2x)] (here with np.expm1, the C++
with a series below x = 0.01), T_c on 16 log-spaced values from twice the
shortest tau to twice the longest; every non-empty subset fitted to the
Allan variances by least squares with weights edf / (2 m^2), m the model's
values (the measured ones in the first round, at least 0.05 of the measured
value), 8 rounds; subsets with a negative coefficient dropped; the least
deviance sum edf (s2/m - 1 - ln(s2/m)) + 10 per parameter (2 for the
Gauss-Markov term) wins; covariance inv(A' W A) at the last weights;
u^2(T) = q_n / T + q_b + q_k T + q_g v(T/T_c), v(x) = (2/x) [1 - (1 - e^-x)/x],
the largest of it over the chosen terms' fits at every grid T_c within 3.84
of the best deviance, and its Welch-Satterthwaite dof.

Run: /usr/bin/python3 tools/reference/noise_model_reference.py  (deterministic).
"""

import itertools
import math
import os

import numpy as np

from refgen import OUT_DIR

PENALTY = 10.0
PROFILE = 3.84
ROUNDS = 8
WINDOWS_S = [1.0, 100.0, 2000.0, 1e5]


def read_points(case):
    tau, adev, edf = [], [], []
    with open(os.path.join(OUT_DIR, f"allan_{case}.txt")) as f:
        for line in f:
            w = line.split()
            if w and w[0] == "expect_point":
                tau.append(float(w[2]))
                adev.append(float(w[3]))
                edf.append(float(w[5]))
    return np.array(tau), np.array(adev), np.array(edf)


TERMS = 4
GM = 3
GRID = 16


def gm_allan(x):
    x = np.asarray(x, dtype=np.float64)
    # 3 - 4 e^-x + e^-2x = -4 expm1(-x) + expm1(-2x)
    return 2.0 / x * (1.0 - (-4.0 * np.expm1(-x) + np.expm1(-2.0 * x)) / (2.0 * x))


def gm_mean(x):
    return 2.0 / x * (1.0 + np.expm1(-x) / x)


def design_of(tau, tc):
    cols = [1.0 / tau, np.ones_like(tau), tau,
            gm_allan(tau / tc) if tc > 0 else np.zeros_like(tau)]
    return np.stack(cols, axis=1)


def fit_subset(tau, s2, edf, idx, tc):
    design = design_of(tau, tc)[:, idx]
    model = s2.copy()
    for _ in range(ROUNDS):
        w = edf / (2.0 * np.maximum(model, 0.05 * s2) ** 2)
        sw = np.sqrt(w)
        coef = np.linalg.lstsq(design * sw[:, None], s2 * sw, rcond=None)[0]
        model = design @ coef
    m = np.maximum(model, 0.05 * s2)
    w = edf / (2.0 * m ** 2)
    chi2 = float(np.sum(w * (s2 - model) ** 2))
    ratio = s2 / m
    deviance = float(np.sum(edf * (ratio - 1.0 - np.log(ratio))))
    cov = np.linalg.inv((design * w[:, None]).T @ design)
    q = np.zeros(TERMS)
    q[idx] = coef
    full = np.zeros((TERMS, TERMS))
    full[np.ix_(idx, idx)] = cov
    return q, full, chi2, deviance, bool(np.all(coef >= 0))


def gm_case():
    """The gm_white curve: exact Allan deviations times fixed factors near 1."""
    tau = 2.0 ** np.arange(12)
    n = 7200
    s2 = 0.02 ** 2 / tau + 0.01 ** 2 * gm_allan(tau / 300.0)
    edf = (3.0 * (n - 1) / (2.0 * tau) - 2.0 * (n - 2) / n) * 4.0 * tau ** 2 / (4.0 * tau ** 2 + 5.0)
    factors = 1.0 + 0.04 * np.sin(1.7 * np.arange(12))
    return tau, np.sqrt(s2) * factors, edf


def best_fit(tau, s2, edf):
    lo, hi = 2.0 * tau[0], 2.0 * tau[-1]
    grid = lo * (hi / lo) ** (np.arange(GRID) / (GRID - 1))
    best = None
    for mask in itertools.product([False, True], repeat=TERMS):
        idx = [i for i in range(TERMS) if mask[i]]
        params = len(idx) + (1 if GM in idx else 0)
        if not idx or params > len(tau):
            continue
        for tc in (grid if GM in idx else [0.0]):
            try:
                q, cov, chi2, dev, ok = fit_subset(tau, s2, edf, idx, tc)
            except np.linalg.LinAlgError:
                continue
            if not ok:
                continue
            score = dev + PENALTY * params
            if best is None or score < best[0]:
                best = (score, q, cov, chi2, idx, tc, dev)
    # The other correlation times the curve cannot tell from the best one's.
    _, _, _, _, idx, tc, dev = best
    alternatives = []
    if GM in idx:
        for other in grid:
            if other == tc:
                continue
            try:
                q, cov, _, d, ok = fit_subset(tau, s2, edf, idx, other)
            except np.linalg.LinAlgError:
                continue
            if ok and d <= dev + PROFILE:
                alternatives.append((q, cov, other))
    return best, alternatives


def main():
    for case in ["white_walk", "offset_1e4", "gm_white"]:
        points = []
        if case == "gm_white":
            tau, adev, edf = gm_case()
            points = [f"point {t!r} {a!r} {e!r}" for t, a, e in zip(tau, adev, edf)]
        else:
            tau, adev, edf = read_points(case)
        s2 = adev**2
        best, alternatives = best_fit(tau, s2, edf)
        _, q, cov, chi2, idx, tc, _ = best
        out = os.path.join(OUT_DIR, f"noise_model_{case}.txt")
        with open(out, "w") as f:
            f.write("# Generated by tools/reference/noise_model_reference.py; do not edit.\n")
            if points:
                f.write("# An exact Gauss-Markov + white Allan curve, perturbed (gm_case).\n")
                f.write("\n".join(points) + "\n")
            else:
                f.write(f"# The noise model of the Allan curve of allan_{case}.txt.\n")
            f.write("active " + " ".join(str(int(i in idx)) for i in range(TERMS)) + "\n")
            f.write(f"tc {float(tc if GM in idx else 0.0)!r}\n")
            f.write("q " + " ".join(repr(float(v)) for v in q) + "\n")
            for r in range(TERMS):
                f.write("cov " + " ".join(repr(float(v)) for v in cov[r]) + "\n")
            f.write(f"chi2 {chi2!r}\n")
            f.write(f"alternatives {len(alternatives)}\n")
            for window in WINDOWS_S:
                def u2_of(q_, cov_, tc_):
                    g = np.array([1.0 / window, 1.0, window,
                                  float(gm_mean(window / tc_)) if tc_ > 0 else 0.0])
                    return float(g @ q_), float(g @ cov_ @ g)
                u2, var = u2_of(q, cov, tc if GM in idx else 0.0)
                for q_a, cov_a, tc_a in alternatives:
                    a2, a_var = u2_of(q_a, cov_a, tc_a)
                    if a2 > u2:
                        u2, var = a2, a_var
                dof = 2.0 * u2 * u2 / var if var > 0 else math.inf
                f.write(f"u {window!r} {math.sqrt(u2)!r} {dof!r}\n")
        print("wrote", out, "active", idx, "tc", tc)


if __name__ == "__main__":
    main()

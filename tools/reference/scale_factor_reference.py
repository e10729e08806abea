#!/usr/bin/python3
"""Reference values for the scale-factor fit (docs/analysis.md, "Scale factor").

Writes tests/analysis/data/scale_factor.txt, read by
tests/analysis/scale_factor_test.cpp:
- "case NAME" then its points "p RATE_DPS OUTPUT_DPS REPETITION TEMPERATURE_C",
  "fit K B_DPS K_SE B_SE_DPS S_DPS NONLIN_PPM NONLIN_POINT NONLIN_FS_PPM
  K_POS K_NEG ASYM_PPM REPEAT_PPM B_SPLIT_DPS" ("nan" = absent / undefined), one
  "r RESIDUAL_DPS" per point in input order, one "rep REPETITION K B_DPS" per
  repetition with >= 2 distinct rates, then "end";
- "tcase NAME ORDER" then "tp T_C K BIAS_DPH" per plateau, "tfit T_MEAN_C
  SF_TC_PPM_PER_C BIAS_TC_DPH_PER_C", "tk C0 .. C_ORDER", "tb C0 .. C_ORDER"
  (K(T) and B(T) in T - T_mean), one "tr K_RESIDUAL BIAS_RESIDUAL_DPH" per
  plateau, then "end".

Independent of the C++ code (centred sums; Householder QR): the line is
numpy.linalg.lstsq on the design [rate, 1]; standard errors are
s^2 (X'X)^-1 with numpy.linalg.inv; K+, K- and their bias B_SPLIT are one
lstsq on the design [max(rate, 0), min(rate, 0), 1]; each repetition is its
own lstsq;
repeatability is numpy.std(ddof=1) / numpy.mean of their K. The temperature
polynomials are numpy.polyfit on T - mean(T).

The gyro model of the synthetic data (rates in deg/s):
  output = K (1 + A/2 sign(rate)) rate + Q rate^2 + B (+ noise),
so the asymmetry is A, the quadratic nonlinearity Q; the noise-free case is
also checked in closed form in the C++ test. Values are written with repr,
so the C++ test reads exactly the same doubles.

Run: /usr/bin/python3 tools/reference/scale_factor_reference.py
(deterministic).
"""

import os

import numpy as np

from refgen import OUT_DIR

RATES_DPS = [1.0, 5.0, 10.0, 50.0, 100.0, 200.0, 500.0]
K_TRUE = 1.00025
B_TRUE_DPS = 0.0021
A_TRUE = 300e-6
Q_TRUE = 4e-8  # (deg/s out) per (deg/s in)^2


def model(rate, k=K_TRUE):
    rate = np.asarray(rate, dtype=np.float64)
    return k * (1 + A_TRUE / 2 * np.sign(rate)) * rate + Q_TRUE * rate**2 + B_TRUE_DPS


def both_directions():
    return [-r for r in reversed(RATES_DPS)] + RATES_DPS


def fmt(v):
    return "nan" if v is None or (isinstance(v, float) and np.isnan(v)) else repr(float(v))


def line_fit(x, y):
    design = np.column_stack([x, np.ones_like(x)])
    coef, _, _, _ = np.linalg.lstsq(design, y, rcond=None)
    return design, coef


def scale_factor_case(name, rate, output, rep, temp):
    rate = np.asarray(rate, dtype=np.float64)
    output = np.asarray(output, dtype=np.float64)
    rep = np.asarray(rep, dtype=np.int64)
    temp = np.asarray(temp, dtype=np.float64)
    n = len(rate)
    design, (k, b) = line_fit(rate, output)
    resid = output - design @ np.array([k, b])
    if n > 2:
        s2 = float(resid @ resid) / (n - 2)
        cov = s2 * np.linalg.inv(design.T @ design)
        k_se, b_se, s = np.sqrt(cov[0, 0]), np.sqrt(cov[1, 1]), np.sqrt(s2)
    else:
        k_se = b_se = s = float("nan")
    nz = np.nonzero(rate != 0)[0]
    rel = np.abs(resid[nz]) / np.abs(k * rate[nz])
    nonlin_point = int(nz[np.argmax(rel)])
    nonlin = float(np.max(rel)) * 1e6
    nonlin_fs = float(np.max(np.abs(resid))) / (abs(k) * float(np.max(np.abs(rate)))) * 1e6

    # The asymmetry: one joint lstsq on [rate+, rate-, 1], defined when both
    # directions are present and the design has full rank (>= 3 distinct rates).
    k_pos = k_neg = b_split = asym = None
    if (rate > 0).any() and (rate < 0).any():
        split = np.column_stack([np.maximum(rate, 0), np.minimum(rate, 0), np.ones_like(rate)])
        if np.linalg.matrix_rank(split) == 3:
            (k_pos, k_neg, b_split), _, _, _ = np.linalg.lstsq(split, output, rcond=None)
            asym = (k_pos - k_neg) / ((k_pos + k_neg) / 2) * 1e6

    reps = []
    for r in sorted(set(rep.tolist())):
        m = rep == r
        if len(np.unique(rate[m])) < 2:
            continue
        _, (kr, br) = line_fit(rate[m], output[m])
        reps.append((r, float(kr), float(br)))
    repeat = None
    if len(reps) >= 2:
        ks = np.array([x[1] for x in reps])
        repeat = float(np.std(ks, ddof=1) / np.mean(ks)) * 1e6

    lines = [f"case {name}"]
    for i in range(n):
        lines.append(f"p {fmt(rate[i])} {fmt(output[i])} {int(rep[i])} {fmt(temp[i])}")
    lines.append("fit " + " ".join(
        [fmt(k), fmt(b), fmt(k_se), fmt(b_se), fmt(s), fmt(nonlin), str(nonlin_point),
         fmt(nonlin_fs), fmt(k_pos), fmt(k_neg), fmt(asym), fmt(repeat), fmt(b_split)]))
    for v in resid:
        lines.append(f"r {fmt(v)}")
    for r, kr, br in reps:
        lines.append(f"rep {r} {fmt(kr)} {fmt(br)}")
    lines.append("end")
    return lines


def temperature_case(name, order, t, k, b_dph):
    t = np.asarray(t, dtype=np.float64)
    k = np.asarray(k, dtype=np.float64)
    b_dph = np.asarray(b_dph, dtype=np.float64)
    t_mean = float(np.mean(t))
    tc = t - t_mean
    pk = np.polyfit(tc, k, order)
    pb = np.polyfit(tc, b_dph, order)
    ck, cb = pk[::-1], pb[::-1]  # constant term first
    lines = [f"tcase {name} {order}"]
    for i in range(len(t)):
        lines.append(f"tp {fmt(t[i])} {fmt(k[i])} {fmt(b_dph[i])}")
    lines.append(f"tfit {fmt(t_mean)} {fmt(ck[1] / ck[0] * 1e6)} {fmt(cb[1])}")
    lines.append("tk " + " ".join(fmt(c) for c in ck))
    lines.append("tb " + " ".join(fmt(c) for c in cb))
    for rk, rb in zip(k - np.polyval(pk, tc), b_dph - np.polyval(pb, tc)):
        lines.append(f"tr {fmt(rk)} {fmt(rb)}")
    lines.append("end")
    return lines


def main():
    rng = np.random.default_rng(952)
    lines = ["# scale_factor_reference.py: scale-factor fits (numpy lstsq, polyfit)"]

    # Noise-free, both directions, one repetition.
    r = np.array(both_directions())
    lines += scale_factor_case("clean", r, model(r), [1] * len(r), [25.0] * len(r))

    # Three repetitions with noise (2e-4 deg/s per dwell mean) and a K that
    # moves by a few ppm between repetitions; rates in a shuffled order.
    rate, out, rep, temp = [], [], [], []
    for k_rep in (1, 2, 3):
        rr = np.array(both_directions())
        rng.shuffle(rr)
        k = K_TRUE * (1 + 4e-6 * (k_rep - 2))
        rate += rr.tolist()
        out += (model(rr, k) + rng.normal(0, 2e-4, len(rr))).tolist()
        rep += [k_rep] * len(rr)
        temp += (25.0 + rng.normal(0, 0.05, len(rr))).tolist()
    lines += scale_factor_case("noisy_3rep", rate, out, rep, temp)

    # A zero-rate point among noisy points (skipped by the nonlinearity relative to K).
    rr = np.array([-100.0, -10.0, 0.0, 10.0, 100.0])
    lines += scale_factor_case("zero_rate", rr, model(rr) + rng.normal(0, 2e-4, len(rr)),
                               [1] * len(rr), [25.0] * len(rr))

    # Exactly two points: an exact line, no standard errors.
    rr = np.array([-50.0, 200.0])
    lines += scale_factor_case("two_points", rr, model(rr) + np.array([1e-4, -3e-4]),
                               [1, 1], [25.0, 25.0])

    # One direction only, two repetitions: no asymmetry, a repeatability.
    rr = np.array(RATES_DPS * 2)
    lines += scale_factor_case("positive_only", rr, model(rr) + rng.normal(0, 2e-4, len(rr)),
                               [1] * 7 + [2] * 7, [25.0] * 14)

    # Repetition 2 holds a single rate: only repetition 1 counts, no repeatability.
    rr = np.array(both_directions() + [100.0, 100.0])
    lines += scale_factor_case("one_usable_repetition", rr,
                               model(rr) + rng.normal(0, 2e-4, len(rr)), [1] * 14 + [2, 2],
                               [25.0] * 16)

    def k_of(t):
        d = np.asarray(t) - 25.0
        return K_TRUE * (1 + 30e-6 * d + 0.2e-6 * d**2)

    def b_of(t):
        d = np.asarray(t) - 25.0
        return 7.0 + 0.05 * d - 4e-4 * d**2

    for name, order, temps in (("t2_order1", 1, [-20.0, 60.0]),
                               ("t3_order1", 1, [-40.0, 25.0, 70.0]),
                               ("t3_order2", 2, [-40.0, 25.0, 70.0]),
                               ("t5_order2", 2, [-40.0, -10.0, 20.0, 50.0, 80.0])):
        t = np.array(temps)
        k = k_of(t) + rng.normal(0, 1e-6, len(t))
        b = b_of(t) + rng.normal(0, 0.01, len(t))
        lines += temperature_case(name, order, t, k, b)

    path = os.path.join(OUT_DIR, "scale_factor.txt")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print("wrote", path)


if __name__ == "__main__":
    main()

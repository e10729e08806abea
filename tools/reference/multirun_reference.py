#!/usr/bin/python3
"""Reference values for the comparison grid (paper Tables II-IV), the
start-temperature model (paper eq. 3) and the fits to the paper's Table I.

Writes, into tests/analysis/data/:
- comparison_grid.txt: three 1 Hz runs (described by a generator, see below)
  and, per cell (term set x order, paper and centred form), the mean and
  sample std of the compensated output rate - drift_terms in-sample and
  leave-one-run-out; read by tests/analysis/comparison_test.cpp;
- comparison_grid_smoothed.txt: the same three runs and grid, the
  compensated output of each run smoothed by a SMOOTH_POINTS-point centred
  moving average (the n - SMOOTH_POINTS + 1 full windows, numpy.convolve
  "valid") before the runs are pooled (and "none" likewise); read by
  tests/analysis/comparison_test.cpp;
- start_temperature_cubic.txt: five runs started at different temperatures,
  each run's own fit and the cubic in T0 of every coefficient (eq. 3); read
  by tests/analysis/start_temperature_test.cpp;
- paper_table1_fit.txt: numpy.polyfit of orders 1-4 to the eight
  (temperature, mean bias) points of the paper's Table I; read by
  tests/analysis/paper_table1_fit_test.cpp.

Independent of the C++ code: the smoothing derivative and the least-squares
fits are those of drift_reference.py (a per-point window found with
np.searchsorted, the whole raw-power design matrix, equilibrated columns and
numpy.linalg.lstsq). The compensated output is rate - X @ beta with X the
raw powers (the intercept column left out), i.e. L0 + residual in the paper
form. The cubic in T0 is numpy.linalg.lstsq on [1, T0, T0^2, T0^3]
(equilibrated).

The runs are not stored: each is described by its parameters ("run" lines)
and rebuilt bit for bit by the C++ test (tests/analysis/multirun_data.h)
with only + - * / and abs on doubles in the same order and the splitmix64
noise of refgen.py; a few generated points are stored ("check" lines) so the
test can prove it rebuilt the same input.

Run: /usr/bin/python3 tools/reference/multirun_reference.py  (deterministic).
"""

import os

import numpy as np

from drift_reference import lstsq_equilibrated, smoothing_derivative
from refgen import OUT_DIR, noise

DERIVATIVE_WINDOW_S = 60.0
L0_WINDOW_S = 120.0
T0_WINDOW_S = 120.0
PARAM_KEYS = ["n", "t_start", "t0", "span", "period", "tri_amp", "g0", "g_amp", "g_period",
              "seed", "temp_sigma", "rate_sigma", "bias", "a1", "a2", "a3", "b1", "c1"]


def make_run(p):
    """t_s, top_c, side_c, rate_dph of one run (the generator the C++ test mirrors)."""
    n = int(p["n"])
    k = np.arange(n)
    kf = k.astype(np.float64)
    t = p["t_start"] + kf
    x = kf / float(n)
    warm = x * (2.0 - x)
    period = int(p["period"])
    ph = (k % period).astype(np.float64) / float(period)
    tri = np.abs(4.0 * ph - 2.0) - 1.0
    sign = np.where(4.0 * ph - 2.0 >= 0.0, 1.0, -1.0)
    temp = p["t0"] + p["span"] * warm + p["tri_amp"] * tri
    dtdt = p["span"] * (2.0 - 2.0 * x) / float(n) + p["tri_amp"] * (4.0 / float(period)) * sign
    g_period = int(p["g_period"])
    phg = (k % g_period).astype(np.float64) / float(g_period)
    grad = p["g0"] + p["g_amp"] * (np.abs(4.0 * phg - 2.0) - 1.0)
    seed = int(p["seed"])
    top = temp + grad / 2.0 + noise(seed, n, p["temp_sigma"])
    side = temp - grad / 2.0 + noise(seed + 1, n, p["temp_sigma"])
    rate = (p["bias"] + p["a1"] * temp + p["a2"] * temp * temp + p["a3"] * temp * temp * temp +
            p["b1"] * dtdt + p["c1"] * grad + noise(seed + 2, n, p["rate_sigma"]))
    return {"t": t, "top": top, "side": side, "rate": rate}


def variables(run):
    temp = (run["top"] + run["side"]) / 2
    deriv = smoothing_derivative(run["t"], temp, DERIVATIVE_WINDOW_S)
    return {"T": temp, "R": deriv, "G": run["top"] - run["side"]}


def parse(spec):
    orders = {"T": 0, "R": 0, "G": 0}
    for term in spec.split("+"):
        orders[term[0]] = int(term[1:])
    return orders


def raw_powers(spec, v):
    o = parse(spec)
    cols, names = [], []
    for letter in ("T", "R", "G"):
        for i in range(1, o[letter] + 1):
            cols.append(v[letter]**i)
            names.append(f"{letter}{i}")
    return np.column_stack(cols), names


def l0(run):
    return float(np.mean(run["rate"][run["t"] - run["t"][0] < L0_WINDOW_S]))


def fit(runs, vars_, spec, form):
    """Pooled fit; returns (beta of the raw powers, intercept, names)."""
    xs, ys = [], []
    for run, v in zip(runs, vars_):
        x, names = raw_powers(spec, v)
        xs.append(x)
        ys.append(run["rate"] - l0(run) if form == "paper" else run["rate"])
    x = np.vstack(xs)
    y = np.concatenate(ys)
    if form == "centered":
        x = np.column_stack([np.ones(len(y)), x])
    beta = lstsq_equilibrated(x, y)[0]
    if form == "centered":
        return beta[1:], float(beta[0]), names
    return beta, 0.0, names


def compensated(run, v, spec, beta):
    x, _ = raw_powers(spec, v)
    return run["rate"] - x @ beta


def stats(parts):
    c = np.concatenate(parts)
    return len(c), float(np.mean(c)), float(np.std(c, ddof=1))


def smoothed(parts, points):
    """Each run's SMOOTH_POINTS-point moving average (full windows only)."""
    return [np.convolve(p, np.ones(points) / points, mode="valid") for p in parts]


def fmt(v):
    return repr(float(v))


def run_line(p):
    return "run " + " ".join(f"{key} {fmt(p[key])}" for key in PARAM_KEYS)


def check_lines(index, run):
    lines = []
    n = len(run["t"])
    for i in (0, 1, n // 3, n - 1):
        lines.append(f"check {index} {i} {fmt(run['t'][i])} {fmt(run['top'][i])} "
                     f"{fmt(run['side'][i])} {fmt(run['rate'][i])}")
    return lines


COMMON = {"temp_sigma": 0.01, "rate_sigma": 0.05, "a1": 0.02, "a2": -4e-4, "a3": 5e-6, "b1": 30.0,
          "c1": 0.15}
COMPARISON_RUNS = [
    dict(COMMON, n=900, t_start=1000.0, t0=-10.0, span=25.0, period=300, tri_amp=1.5, g0=0.3,
         g_amp=0.4, g_period=470, seed=101, bias=8.0),
    dict(COMMON, n=900, t_start=20000.0, t0=15.0, span=20.0, period=240, tri_amp=2.0, g0=-0.1,
         g_amp=0.3, g_period=610, seed=202, bias=8.3),
    dict(COMMON, n=900, t_start=50000.0, t0=35.0, span=15.0, period=360, tri_amp=1.0, g0=0.5,
         g_amp=0.5, g_period=390, seed=303, bias=7.8),
]
GRID_CELLS = [(form, f"T{o}" if s == "T" else f"T{o}+G1" if s == "T+G" else f"T{o}+R1+G1")
              for form in ("paper",) for s in ("T", "T+G", "T+G+R") for o in (1, 2, 3, 4)]
GRID_CELLS += [("centered", "T2"), ("centered", "T2+G1"), ("centered", "T3+R1+G1")]


def write_comparison():
    runs = [make_run(p) for p in COMPARISON_RUNS]
    vars_ = [variables(r) for r in runs]
    lines = ["# multirun_reference.py: comparison grid on three generated runs",
             f"derivative_window_s {DERIVATIVE_WINDOW_S!r}", f"l0_window_s {L0_WINDOW_S!r}"]
    for i, (p, r) in enumerate(zip(COMPARISON_RUNS, runs)):
        lines.append(run_line(p))
        lines += check_lines(i, r)
    n, m, s = stats([r["rate"] for r in runs])
    lines.append(f"none {n} {fmt(m)} {fmt(s)}")
    lines.append("# cell form spec n in_mean in_std loro_mean loro_std")
    for form, spec in GRID_CELLS:
        beta, _, _ = fit(runs, vars_, spec, form)
        n, in_m, in_s = stats([compensated(r, v, spec, beta) for r, v in zip(runs, vars_)])
        held = []
        for h in range(len(runs)):
            others = [i for i in range(len(runs)) if i != h]
            b, _, _ = fit([runs[i] for i in others], [vars_[i] for i in others], spec, form)
            held.append(compensated(runs[h], vars_[h], spec, b))
        _, lo_m, lo_s = stats(held)
        lines.append(f"cell {form} {spec} {n} {fmt(in_m)} {fmt(in_s)} {fmt(lo_m)} {fmt(lo_s)}")
    with open(os.path.join(OUT_DIR, "comparison_grid.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")


SMOOTH_POINTS = 101
SMOOTHED_CELLS = [(form, f"T{o}" if s == "T" else f"T{o}+G1" if s == "T+G" else f"T{o}+R1+G1")
                  for form in ("centered", "paper") for s in ("T", "T+G", "T+G+R")
                  for o in (1, 2, 3, 4)]


def write_comparison_smoothed():
    runs = [make_run(p) for p in COMPARISON_RUNS]
    vars_ = [variables(r) for r in runs]
    lines = ["# multirun_reference.py: comparison grid on three generated runs, each run's "
             f"compensated output smoothed by a {SMOOTH_POINTS}-point moving average",
             f"derivative_window_s {DERIVATIVE_WINDOW_S!r}", f"l0_window_s {L0_WINDOW_S!r}",
             f"smooth_points {SMOOTH_POINTS}"]
    for i, (p, r) in enumerate(zip(COMPARISON_RUNS, runs)):
        lines.append(run_line(p))
        lines += check_lines(i, r)
    n, m, s = stats(smoothed([r["rate"] for r in runs], SMOOTH_POINTS))
    lines.append(f"none {n} {fmt(m)} {fmt(s)}")
    lines.append("# cell form spec n in_mean in_std loro_mean loro_std")
    for form, spec in SMOOTHED_CELLS:
        beta, _, _ = fit(runs, vars_, spec, form)
        parts = [compensated(r, v, spec, beta) for r, v in zip(runs, vars_)]
        n, in_m, in_s = stats(smoothed(parts, SMOOTH_POINTS))
        held = []
        for h in range(len(runs)):
            others = [i for i in range(len(runs)) if i != h]
            b, _, _ = fit([runs[i] for i in others], [vars_[i] for i in others], spec, form)
            held.append(compensated(runs[h], vars_[h], spec, b))
        _, lo_m, lo_s = stats(smoothed(held, SMOOTH_POINTS))
        lines.append(f"cell {form} {spec} {n} {fmt(in_m)} {fmt(in_s)} {fmt(lo_m)} {fmt(lo_s)}")
    with open(os.path.join(OUT_DIR, "comparison_grid_smoothed.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")


def start_runs():
    out = []
    for i, t0 in enumerate((-15.0, 0.0, 15.0, 30.0, 45.0)):
        out.append(dict(COMMON, n=700, t_start=1000.0 + 1e4 * i, t0=t0, span=12.0,
                        period=200 + 40 * i, tri_amp=1.5, g0=0.2 - 0.05 * i, g_amp=0.3,
                        g_period=330 + 50 * i, seed=500 + 10 * i, bias=8.0 + 0.01 * t0,
                        a1=0.02 + 2e-4 * t0 - 3e-6 * t0 * t0, a2=-4e-4 + 2e-6 * t0,
                        a3=0.0, b1=25.0 + 0.1 * t0, c1=0.2 - 0.002 * t0))
    return out


START_CASES = [("paper", "T2+R1+G1"), ("centered", "T2+R1+G1")]
T0_GRID = [-25.0, -15.0, -5.0, 0.0, 10.0, 20.0, 30.0, 45.0, 55.0]


def write_start_temperature():
    params = start_runs()
    runs = [make_run(p) for p in params]
    vars_ = [variables(r) for r in runs]
    t0s = np.array([float(np.mean(((r["top"] + r["side"]) / 2)[r["t"] - r["t"][0] < T0_WINDOW_S]))
                    for r in runs])
    lines = ["# multirun_reference.py: start-temperature model (eq. 3) on five generated runs",
             f"derivative_window_s {DERIVATIVE_WINDOW_S!r}", f"l0_window_s {L0_WINDOW_S!r}",
             f"t0_window_s {T0_WINDOW_S!r}"]
    for i, (p, r) in enumerate(zip(params, runs)):
        lines.append(run_line(p))
        lines += check_lines(i, r)
        lines.append(f"t0 {i} {fmt(t0s[i])}")
    for form, spec in START_CASES:
        lines.append(f"case {form} {spec}")
        per_run = []
        for i, (r, v) in enumerate(zip(runs, vars_)):
            beta, intercept, names = fit([r], [v], spec, form)
            coefs = dict(zip(names, beta))
            if form == "centered":
                coefs["intercept"] = intercept
            per_run.append(coefs)
            for name in sorted(coefs):
                lines.append(f"run_coef {i} {name} {fmt(coefs[name])}")
        vander = np.column_stack([t0s**j for j in range(4)])
        for name in sorted(per_run[0]):
            a = lstsq_equilibrated(vander, np.array([c[name] for c in per_run]))[0]
            lines.append(f"cubic {name} " + " ".join(fmt(v) for v in a))
            for t0 in T0_GRID:
                value = float(np.polynomial.polynomial.polyval(t0, a))
                lines.append(f"at {name} {fmt(t0)} {fmt(value)}")
        lines.append("end_case")
    with open(os.path.join(OUT_DIR, "start_temperature_cubic.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")


# Table I of the paper: temperature (degC) and zero-bias mean (deg/h).
PAPER_TABLE1 = [(-14.60, 7.6967), (2.70, 8.0374), (22.93, 7.6844), (39.95, 8.1986),
                (47.28, 7.6761), (50.83, 7.9121), (56.43, 8.0771), (60.27, 8.0594)]


def write_paper_table1():
    temp = np.array([p[0] for p in PAPER_TABLE1])
    bias = np.array([p[1] for p in PAPER_TABLE1])
    lines = ["# multirun_reference.py: numpy.polyfit of the paper's Table I (8 points)",
             "# point temperature_c bias_dph"]
    for t, b in PAPER_TABLE1:
        lines.append(f"point {fmt(t)} {fmt(b)}")
    for order in (1, 2, 3, 4):
        c = np.polyfit(temp, bias, order)  # highest power first
        fitted = np.polyval(c, temp)
        resid = bias - fitted
        vander = np.vander(temp, order + 1, increasing=True)
        cond_raw = np.linalg.cond(vander / np.linalg.norm(vander, axis=0))
        z = (temp - temp.mean()) / temp.std()
        vz = np.vander(z, order + 1, increasing=True)
        cond_centred = np.linalg.cond(vz / np.linalg.norm(vz, axis=0))
        dof = len(temp) - order - 1
        lines.append(f"order {order} residual_std {fmt(np.sqrt(resid @ resid / dof))} "
                     f"cond_raw {cond_raw:.6e} cond_centred {cond_centred:.6e}")
        lines.append(f"coef {order} " + " ".join(fmt(v) for v in c[::-1]))
        lines.append(f"fitted {order} " + " ".join(fmt(v) for v in fitted))
    with open(os.path.join(OUT_DIR, "paper_table1_fit.txt"), "w") as f:
        f.write("\n".join(lines) + "\n")


def main():
    write_comparison()
    write_comparison_smoothed()
    write_start_temperature()
    write_paper_table1()


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""Reference values for the drift model fit (paper eq. 1, docs/analysis.md).

Writes tests/analysis/data/drift_series.txt (a synthetic 1 Hz analysis series
and its smoothing derivative) and tests/analysis/data/drift_fit_<case>.txt (one
least-squares fit each), read by tests/analysis/drift_model_test.cpp.

Independent of the C++ code (which uses a block-sequential Householder QR and
sliding sums): here the derivative is a per-point window found with
np.searchsorted and a centred two-pass slope; the fit builds the whole design
matrix explicitly, equilibrates its columns (divides each by its norm) and
calls numpy.linalg.lstsq; standard errors are sigma^2 (X'X)^-1 from the SVD of
the equilibrated design; R^2 = 1 - RSS / sum((y - mean(y))^2).

The physical coefficients of the centred form are obtained by fitting the raw
powers with an intercept column (same column space), not by expanding the
centred polynomial as the C++ code does.

Run: /usr/bin/python3 tools/reference/drift_reference.py  (deterministic).
"""

import os

import numpy as np

OUT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "tests",
                       "analysis", "data")
N = 5000
DERIVATIVE_WINDOW_S = 60.0
L0_WINDOW_S = 120.0
WINDOW_TOL = 1e-9  # relative to the half width, as in drift_model.h
FITTED_STRIDE = 4  # fitted values stored for every 4th point (and the last)


def make_series():
    rng = np.random.RandomState(20260521)
    k = np.arange(N, dtype=np.float64)
    t = 1000.0 + k
    temp = 10.0 + 40.0 * k / N + 3.0 * np.sin(2 * np.pi * k / 900.0)
    grad = 1.5 + 0.8 * np.sin(2 * np.pi * k / 1700.0)
    top = temp + grad / 2 + rng.normal(0, 0.01, N)
    side = temp - grad / 2 + rng.normal(0, 0.01, N)
    return t, top, side


def smoothing_derivative(t, y, window_s):
    n = len(t)
    half = window_s / 2
    tol = WINDOW_TOL * half
    out = np.empty(n)
    for i in range(n):
        lo = int(np.searchsorted(t, t[i] - half - tol, side="left"))
        hi = int(np.searchsorted(t, t[i] + half + tol, side="right")) - 1
        if i > 0:
            lo = min(lo, i - 1)
        if i + 1 < n:
            hi = max(hi, i + 1)
        tw = t[lo:hi + 1] - np.mean(t[lo:hi + 1])
        yw = y[lo:hi + 1] - np.mean(y[lo:hi + 1])
        out[i] = np.dot(tw, yw) / np.dot(tw, tw)
    return out


def variables(t, top, side):
    temp = (top + side) / 2
    return temp, smoothing_derivative(t, temp, DERIVATIVE_WINDOW_S), top - side


def parse(spec):
    orders = {"T": 0, "R": 0, "G": 0}
    for term in spec.split("+"):
        orders[term[0]] = int(term[1:])
    return orders


def design(spec, temp, deriv, grad, intercept):
    o = parse(spec)
    cols, names = [], []
    if intercept:
        cols.append(np.ones_like(temp))
        names.append("intercept")
    for letter, x in (("T", temp), ("R", deriv), ("G", grad)):
        for i in range(1, o[letter] + 1):
            cols.append(x**i)
            names.append(f"{letter}{i}")
    return np.column_stack(cols), names


def lstsq_equilibrated(x, y):
    norms = np.linalg.norm(x, axis=0)
    xs = x / norms
    bs, _, _, sv = np.linalg.lstsq(xs, y, rcond=None)
    beta = bs / norms
    fitted = xs @ bs
    _, s, vt = np.linalg.svd(xs, full_matrices=False)
    inv_xtx = (vt.T / s**2) @ vt / np.outer(norms, norms)
    return beta, fitted, inv_xtx, sv[0] / sv[-1]


def fit(spec, form, t, rate, temp, deriv, grad):
    n = len(t)
    if form == "paper":
        l0 = float(np.mean(rate[t - t[0] < L0_WINDOW_S]))
        y = rate - l0
        x, names = design(spec, temp, deriv, grad, intercept=False)
    else:
        l0 = 0.0
        y = rate.copy()
        x, names = design(spec, temp, deriv, grad, intercept=True)
    beta, fitted, inv_xtx, cond = lstsq_equilibrated(x, y)
    resid = y - fitted
    rss = float(np.dot(resid, resid))
    p = x.shape[1]
    sigma2 = rss / (n - p)
    se = np.sqrt(sigma2 * np.diag(inv_xtx))
    tss = float(np.sum((y - np.mean(y))**2))
    if form == "centered":
        # Fitted values from the centred, scaled basis as a cross-check of the
        # column space (population std, as the C++ code).
        o = parse(spec)
        cols = [np.ones(n)]
        for letter, v in (("T", temp), ("R", deriv), ("G", grad)):
            z = (v - np.mean(v)) / np.std(v)
            cols += [z**i for i in range(1, o[letter] + 1)]
        xc = np.column_stack(cols)
        bc = np.linalg.lstsq(xc, y, rcond=None)[0]
        assert np.max(np.abs(xc @ bc - fitted)) < 1e-9 * np.max(np.abs(y))
    return {
        "names": names, "beta": beta, "se": se, "fitted": fitted + l0, "l0": l0, "n": n, "p": p,
        "rss": rss, "residual_std": np.sqrt(sigma2), "r_squared": 1 - rss / tss, "cond": cond,
    }


def write_series(t, rate, top, side, deriv):
    path = os.path.join(OUT_DIR, "drift_series.txt")
    with open(path, "w") as f:
        f.write("# drift_reference.py: synthetic 1 Hz analysis series; columns:\n")
        f.write("# t_s rate_dph top_c side_c dTdt_c_per_s (smoothing derivative, "
                f"window {DERIVATIVE_WINDOW_S} s)\n")
        f.write(f"derivative_window_s {DERIVATIVE_WINDOW_S!r}\n")
        for row in zip(t, rate, top, side, deriv):
            f.write("point " + " ".join(repr(float(v)) for v in row) + "\n")


def write_fit(case, spec, form, r):
    path = os.path.join(OUT_DIR, f"drift_fit_{case}.txt")
    lines = [
        f"# drift_reference.py: {spec}, {form} form, on drift_series.txt",
        f"# condition number of the equilibrated raw design: {r['cond']:.3e}",
        f"spec {spec}", f"form {form}", f"n {r['n']}", f"p {r['p']}",
        f"l0_dph {r['l0']!r}", f"rss {r['rss']!r}", f"residual_std_dph {r['residual_std']!r}",
        f"r_squared {r['r_squared']!r}",
    ]
    for name, b, s in zip(r["names"], r["beta"], r["se"]):
        lines.append(f"coef {name} {float(b)!r} {float(s)!r}")
    idx = list(range(0, r["n"], FITTED_STRIDE))
    if idx[-1] != r["n"] - 1:
        idx.append(r["n"] - 1)
    for i in idx:
        lines.append(f"fitted {i} {float(r['fitted'][i])!r}")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")


CASES = [
    ("t1_paper", "T1", "paper"),
    ("t4_paper", "T4", "paper"),
    ("t2g1_paper", "T2+G1", "paper"),
    ("t4r1g1_paper", "T4+R1+G1", "paper"),
    ("t4r1g1_centered", "T4+R1+G1", "centered"),
    ("t2r2g2_centered", "G2+T2+R2", "centered"),
]


def main():
    t, top, side = make_series()
    temp, deriv, grad = variables(t, top, side)
    rng = np.random.RandomState(7)
    rate = (8.0 + 0.02 * temp - 4e-4 * temp**2 + 5e-6 * temp**3 - 3e-8 * temp**4 + 30.0 * deriv +
            0.1 * grad + rng.normal(0, 0.005, N))
    # Round-trip the stored values so the fits see exactly what the test reads.
    rate = np.array([float(repr(float(v))) for v in rate])
    write_series(t, rate, top, side, deriv)
    for case, spec, form in CASES:
        write_fit(case, spec, form, fit(spec, form, t, rate, temp, deriv, grad))


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""The numpy column of the analysis speed benchmark (issue 5).

The same three computations as bench/analysis_bench.cpp, in idiomatic numpy,
on a series of the same size and model (10 M points at 1 s; see the C++ file):
  table1        mean shell temperature, mean and std (ddof 1) of the rate, std
                after a 101-point moving average (cumsum)
  drift_fit     np.linalg.lstsq on a prebuilt 10 M x 9 design (centred form,
                intercept + T4 + R2 + G2); building the design is timed apart
  allan_octave  overlapping Allan deviation for m = 1, 2, 4, ... (cumsum)
Each is timed with time.perf_counter, best of 3. Prints one line per
computation: "numpy: <name> <ms> ms", then "check:" lines of results.
Run with Debian's numpy: /usr/bin/python3 bench/analysis_numpy.py [--n N]
"""
import argparse
import time

import numpy as np

MA_WINDOW = 101
DERIVATIVE_WINDOW_S = 60.0


def make_series(n):
    rng = np.random.default_rng(20261121)
    t = np.arange(n, dtype=np.float64)
    shell = 40.0 + 20.0 * np.sin(2 * np.pi / 86400.0 * t)
    dshell = 20.0 * (2 * np.pi / 86400.0) * np.cos(2 * np.pi / 86400.0 * t)
    grad = 0.5 * np.sin(2 * np.pi / 25200.0 * t) + 0.1
    top = shell + grad / 2 + rng.normal(0.0, 0.01, n)
    side = shell - grad / 2 + rng.normal(0.0, 0.01, n)
    dt = shell - 40.0
    rate = 0.8 + 0.01 * dt + 2e-4 * dt * dt + 50.0 * dshell + 0.3 * grad + rng.normal(0.0, 0.05, n)
    return t, rate, top, side


def table1(rate, top, side):
    shell = (top + side) / 2
    temp_mean = shell.mean()
    bias_mean = rate.mean()
    bias_std = rate.std(ddof=1)
    c = np.concatenate(([0.0], np.cumsum(rate - bias_mean)))
    ma = (c[MA_WINDOW:] - c[:-MA_WINDOW]) / MA_WINDOW
    return temp_mean, bias_mean, bias_std, ma.std(ddof=1)


def smoothing_derivative(t, y, window_s):
    """Least-squares slope over the points within +-window_s / 2. t is evenly
    spaced, so inside the series that is one fixed kernel (a convolution); the
    h points at each end use a window cut off at the end, as in the C++."""
    dt = t[1] - t[0]
    h = max(1, int(round(window_s / 2 / dt)))
    k = np.arange(-h, h + 1, dtype=np.float64)
    out = np.empty_like(y)
    out[h:-h] = np.convolve(y, (k / (dt * np.sum(k * k)))[::-1], mode="valid")
    for i in list(range(h)) + list(range(len(y) - h, len(y))):
        lo, hi = max(i - h, 0), min(i + h, len(y) - 1) + 1
        out[i] = np.polyfit(t[lo:hi] - t[i], y[lo:hi], 1)[0]
    return out


def design(t, rate, top, side):
    shell = (top + side) / 2
    deriv = smoothing_derivative(t, shell, DERIVATIVE_WINDOW_S)
    grad = top - side
    cols = [np.ones_like(rate)]
    for x, order in ((shell, 4), (deriv, 2), (grad, 2)):
        z = (x - x.mean()) / x.std()
        zk = z
        cols.append(zk)
        for _ in range(order - 1):
            zk = zk * z
            cols.append(zk)
    return np.column_stack(cols)


def lstsq(x, y):
    beta, rss, _, _ = np.linalg.lstsq(x, y, rcond=None)
    return beta, float(np.sqrt(rss[0] / (len(y) - x.shape[1])))


def allan_octave(rate):
    n = len(rate)
    c = np.concatenate(([0.0], np.cumsum(rate - rate.mean())))
    adev = []
    m = 1
    while 2 * m < n + 1:
        s = c[m:] - c[:-m]  # cluster sums
        d = s[m:] - s[:-m]
        adev.append(np.sqrt(np.mean(d * d) / (2.0 * m * m)))
        m *= 2
    return np.array(adev)


def best_of(k, f, *args):
    best = float("inf")
    out = None
    for _ in range(k):
        t0 = time.perf_counter()
        out = f(*args)
        best = min(best, time.perf_counter() - t0)
    return best * 1e3, out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    t, rate, top, side = make_series(args.n)
    ms, (_, _, std, std_ma) = best_of(args.repeat, table1, rate, top, side)
    print(f"numpy: table1 {ms:.3f} ms")
    design_ms, x = best_of(1, design, t, rate, top, side)
    ms, (_, resid) = best_of(args.repeat, lstsq, x, rate)
    print(f"numpy: drift_fit {ms:.3f} ms")
    print(f"numpy: drift_fit_design {design_ms:.3f} ms")
    del x
    ms, adev = best_of(args.repeat, allan_octave, rate)
    print(f"numpy: allan_octave {ms:.3f} ms")
    print(f"check: numpy version {np.__version__}")
    print(f"check: table1 std_dph {std:.6g}")
    print(f"check: table1 std_ma_dph {std_ma:.6g}")
    print(f"check: drift_fit residual_std_dph {resid:.6g}")
    print(f"check: allan_octave adev_1s_dph {adev[0]:.6g} ({len(adev)} taus)")


if __name__ == "__main__":
    main()

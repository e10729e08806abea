#!/usr/bin/python3
"""Reference values for the result-quality numerics (docs/analysis.md,
"Result quality" and "Rate points"), pasted into
tests/analysis/quality_test.cpp.

The data are closed forms the C++ test computes the same way (index i from
0, doubles): a rate point's output
  y_i = 10 + 0.02 sin(0.7 i) + 0.006 cos(1.3 i)       (N = 300, flat)
and the same with its first 35 samples at 5 (the previous rate), and a
binned rate series
  x_i = 0.5 + 0.001 i + 0.03 sin(1.7 i) + 0.01 cos(0.37 i)   (N = 500).

Independent of the C++ code: numpy.mean, numpy.var(ddof=1) and
numpy.median on those arrays.

Run: /usr/bin/python3 tools/reference/quality_reference.py
"""
import numpy as np


def flatness(y, rate, n_sigma=5.0, ppm=500.0):
    third = len(y) // 3
    a, b = y[:third], y[-third:]
    var = np.var(a, ddof=1) / len(a) + np.var(b, ddof=1) / len(b)
    tol = n_sigma * np.sqrt(var) + ppm * 1e-6 * abs(rate)
    return np.mean(a), np.mean(b), tol


i = np.arange(300, dtype=float)
y = 10 + 0.02 * np.sin(0.7 * i) + 0.006 * np.cos(1.3 * i)
print("flat: first %r last %r tolerance %r" % flatness(y, 10.0))
y2 = y.copy()
y2[:35] = 5.0 + 0.02 * np.sin(0.7 * i[:35]) + 0.006 * np.cos(1.3 * i[:35])
print("contaminated: first %r last %r tolerance %r" % flatness(y2, 10.0))

j = np.arange(500, dtype=float)
x = 0.5 + 0.001 * j + 0.03 * np.sin(1.7 * j) + 0.01 * np.cos(0.37 * j)
d = np.diff(x)
noise = 1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0)
print("noise %r" % noise)

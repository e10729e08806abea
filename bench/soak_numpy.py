#!/usr/bin/python3
"""The numpy column of bench/soak_analysis_bench.cpp (issue 27, item 5).

Reads the soak's raw samples (float64 t_s then float64 rate_dph, as the
bench writes them) into memory, untimed, then times in idiomatic numpy what
`gyrotherm stats` and `gyrotherm allan` compute from the database:
  table1  the samples in 1 s bins (bincount), then the mean, std (ddof 1) and
          the std after a 101-point moving average (cumsum) of the bins
  allan   the overlapping Allan deviation of the samples as recorded at
          m = 1, 2, 4, ... (cumsum; second differences)
Best of 2 each. Prints "numpy: table1 <s> s, allan <s> s" and check values.
Run with Debian's numpy: /usr/bin/python3 bench/soak_numpy.py FILE
"""
import sys
import time

import numpy as np

MA_WINDOW = 101


def table1(t, rate):
    k = np.floor(t - t[0] + 1e-9).astype(np.int64)
    nbins = int(np.floor(t[-1] - t[0] + (t[1] - t[0]) + 1e-9))
    keep = k < nbins
    counts = np.bincount(k[keep], minlength=nbins)
    sums = np.bincount(k[keep], weights=rate[keep], minlength=nbins)
    bins = sums[counts > 0] / counts[counts > 0]
    c = np.cumsum(np.concatenate(([0.0], bins - bins[0])))
    ma = (c[MA_WINDOW:] - c[:-MA_WINDOW]) / MA_WINDOW
    return bins.size, bins.mean(), bins.std(ddof=1), ma.std(ddof=1)


def allan(rate):
    c = np.cumsum(np.concatenate(([0.0], rate - rate[0])))
    n = rate.size
    out = []
    m = 1
    while 2 * m < n + 1:
        d = c[2 * m:] - 2 * c[m:-m] + c[: n + 1 - 2 * m]
        out.append((m, np.sqrt(np.mean(d * d) / (2.0 * m * m))))
        m *= 2
    return out


def best_of(f, *args):
    best, result = None, None
    for _ in range(2):
        t0 = time.perf_counter()
        result = f(*args)
        dt = time.perf_counter() - t0
        best = dt if best is None else min(best, dt)
    return best, result


def main():
    raw = np.fromfile(sys.argv[1], dtype=np.float64)
    n = raw.size // 2
    t, rate = raw[:n], raw[n:]
    t1, row = best_of(table1, t, rate)
    t2, curve = best_of(allan, rate)
    print(f"numpy: table1 {t1:.3f} s, allan {t2:.3f} s, both {t1 + t2:.3f} s (n = {n})")
    print(f"check: bins {row[0]}, mean {row[1]:.6f}, std {row[2]:.6f}, std_ma {row[3]:.6f}; "
          f"adev(m=1) {curve[0][1]:.6f}, adev(m={curve[-1][0]}) {curve[-1][1]:.6g}")


if __name__ == "__main__":
    main()

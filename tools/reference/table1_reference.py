#!/usr/bin/python3
"""Reference values for the Table I statistics (docs/analysis.md).

Writes tests/analysis/data/table1_<case>.txt, read by
tests/analysis/table1_reference_test.cpp. Everything expected is computed here
with numpy, independently of the C++ code: np.mean, np.std(ddof=1),
np.convolve(x, ones(w)/w, 'valid'), binning with np.floor indices and
np.bincount, temperatures of empty bins with np.interp.

Inputs are either stored in the file ("gyro"/"temp" lines, repr floats) or,
for the large cases, described by a generator that the C++ test reproduces
bit for bit: a counter-based splitmix64 stream, uniforms (z >> 11) * 2^-53,
noise = sigma * sqrt(3) * (((u0 + u1) + u2) + u3 - 2), only + - * on doubles
in a fixed order. A few generated samples are stored ("check_*" lines) so the
test can prove it regenerated the same input.

Run: /usr/bin/python3 tools/reference/table1_reference.py  (from the repo root
or anywhere; output goes next to the tests). Deterministic.
"""

import math
import os
import sys

import numpy as np

from refgen import OUT_DIR, noise

EARTH_RATE_DPH = 15.041067
PAPER_LATITUDE_DEG = 31.9
BOUNDARY_TOL = 1e-9  # relative to bin_s, as in make_analysis_series


def generate(g):
    """The input described by generator parameters g (same arithmetic as the C++ test)."""
    gi = np.arange(g["gyro_n"], dtype=np.float64)
    gt = g["gyro_t0"] + g["gyro_dt"] * gi
    rate = (g["rate_offset_dph"] + g["rate_drift_dph_per_s"] * (gt - g["gyro_t0"]) +
            noise(g["seed"], g["gyro_n"], g["rate_sigma_dph"]))
    ti = np.arange(g["temp_n"], dtype=np.float64)
    tt = g["temp_t0"] + g["temp_dt"] * ti
    top = (g["top0_c"] + g["top_slope_c_per_s"] * (tt - g["temp_t0"]) +
           noise(g["seed"] + 1, g["temp_n"], g["temp_sigma_c"]))
    side = (g["side0_c"] + g["side_slope_c_per_s"] * (tt - g["temp_t0"]) +
            noise(g["seed"] + 2, g["temp_n"], g["temp_sigma_c"]))
    return gt, rate, tt, top, side


def analysis_series(gt, rate, tt, top, side, bin_s):
    """The analysis series of docs/analysis.md, as specified in table1.h."""
    tau = float(np.median(np.diff(gt))) if len(gt) > 1 else bin_s
    if tau >= bin_s * (1 - BOUNDARY_TOL):
        # Used as is: sample i stands for [t_i, t_{i+1}), the last for [t_last, t_last + tau).
        starts = gt.copy()
        ends = np.append(gt[1:], gt[-1] + tau)
        # Temperature j belongs to the sample whose interval holds it.
        idx = np.searchsorted(starts, tt, side="right") - 1
        inside = (idx >= 0) & (tt < ends[np.clip(idx, 0, None)])
        nb = len(gt)
        cnt = np.bincount(idx[inside], minlength=nb)
        top_sum = np.bincount(idx[inside], weights=top[inside], minlength=nb)
        side_sum = np.bincount(idx[inside], weights=side[inside], minlength=nb)
        centres = (starts + ends) / 2
        with np.errstate(invalid="ignore", divide="ignore"):
            s_top = np.where(cnt > 0, top_sum / cnt, np.interp(centres, tt, top))
            s_side = np.where(cnt > 0, side_sum / cnt, np.interp(centres, tt, side))
        return dict(t=gt.copy(), rate=rate.copy(), top=s_top, side=s_side, bin_s=tau,
                    binned=False)

    t0 = gt[0]
    nbins = int(math.floor(((gt[-1] - t0) + tau) / bin_s + BOUNDARY_TOL))
    k = np.floor((gt - t0) / bin_s + BOUNDARY_TOL).astype(np.int64)
    keep = k < nbins
    cnt = np.bincount(k[keep], minlength=nbins)
    rsum = np.bincount(k[keep], weights=rate[keep], minlength=nbins)
    kt = np.floor((tt - t0) / bin_s + BOUNDARY_TOL).astype(np.int64)
    tin = (kt >= 0) & (kt < nbins)
    tcnt = np.bincount(kt[tin], minlength=nbins)
    top_sum = np.bincount(kt[tin], weights=top[tin], minlength=nbins)
    side_sum = np.bincount(kt[tin], weights=side[tin], minlength=nbins)
    bins = np.nonzero(cnt > 0)[0]  # bins without gyro samples (gaps) are dropped
    starts = t0 + bins * bin_s
    centres = starts + bin_s / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        s_top = np.where(tcnt[bins] > 0, top_sum[bins] / tcnt[bins], np.interp(centres, tt, top))
        s_side = np.where(tcnt[bins] > 0, side_sum[bins] / tcnt[bins],
                          np.interp(centres, tt, side))
    return dict(t=starts, rate=rsum[bins] / cnt[bins], top=s_top, side=s_side, bin_s=bin_s,
                binned=True)


def table1(series, ma_window, earth_rate_dph):
    x = series["rate"]
    n = len(x)
    ma_std = float("nan")
    if n > ma_window:
        ma = np.convolve(x, np.ones(ma_window) / ma_window, "valid")
        assert len(ma) == n - ma_window + 1
        ma_std = float(np.std(ma, ddof=1))
    mean = float(np.mean(x))
    return dict(n=n, duration_s=n * series["bin_s"],
                temp_mean_c=float(np.mean((series["top"] + series["side"]) / 2)),
                bias_mean_dph=mean, bias_std_dph=float(np.std(x, ddof=1)),
                bias_std_ma_dph=ma_std, bias_mean_earth_removed_dph=mean - earth_rate_dph)


def fmt(v):
    if isinstance(v, (bool, np.bool_)):
        return "1" if v else "0"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return repr(float(v))


def write_case(name, comment, bin_s, ma_window, gen=None, stored=None, series_rows="ends"):
    earth = EARTH_RATE_DPH * math.sin(math.radians(PAPER_LATITUDE_DEG))
    lines = ["# Generated by tools/reference/table1_reference.py; do not edit.",
             "# " + comment,
             f"case {name}", f"bin_s {fmt(bin_s)}", f"ma_window {ma_window}",
             f"latitude_deg {fmt(PAPER_LATITUDE_DEG)}", f"earth_rate_dph {fmt(earth)}"]
    if gen is not None:
        gt, rate, tt, top, side = generate(gen)
        lines.append("input generated")
        for key, val in gen.items():
            lines.append(f"gen {key} {fmt(val)}")
        for i in sorted({0, 1, len(gt) // 2, len(gt) - 1}):
            lines.append(f"check_gyro {i} {fmt(gt[i])} {fmt(rate[i])}")
        for j in sorted({0, 1, len(tt) // 2, len(tt) - 1}):
            lines.append(f"check_temp {j} {fmt(tt[j])} {fmt(top[j])} {fmt(side[j])}")
    else:
        gt, rate, tt, top, side = stored
        lines.append("input stored")
        lines += [f"gyro {fmt(a)} {fmt(b)}" for a, b in zip(gt, rate)]
        lines += [f"temp {fmt(a)} {fmt(b)} {fmt(c)}" for a, b, c in zip(tt, top, side)]

    s = analysis_series(gt, rate, tt, top, side, bin_s)
    row = table1(s, ma_window, earth)
    lines.append(f"expect_binned {fmt(s['binned'])}")
    lines.append(f"expect_bin_s {fmt(s['bin_s'])}")
    for key, val in row.items():
        lines.append(f"expect_{key} {fmt(val)}")
    n = len(s["rate"])
    rows = range(n) if series_rows == "all" else sorted({0, 1, n // 2, n - 2, n - 1})
    for k in rows:
        lines.append(f"expect_series {k} {fmt(s['t'][k])} {fmt(s['rate'][k])} "
                     f"{fmt(s['top'][k])} {fmt(s['side'][k])}")
    path = os.path.join(OUT_DIR, f"table1_{name}.txt")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print(f"{path}: n={row['n']} std={row['bias_std_dph']:.6g} ma={row['bias_std_ma_dph']:.6g}")


def irregular_input():
    """10 Hz with timing jitter, a 7 s gap, temperatures every 3.3 s (many bins interpolate)."""
    rng = np.random.default_rng(20240611)
    t = 5.0 + 0.1 * np.arange(900) + rng.uniform(-0.01, 0.01, 900)
    t = t[(t < 41.0) | (t >= 48.0)]
    rate = 8.0 + 3.0 * rng.standard_normal(len(t)) + 0.02 * (t - 5.0)
    tt = 3.1 + 3.3 * np.arange(30)
    top = 25.0 + 0.05 * tt + 0.01 * rng.standard_normal(30)
    side = 24.5 + 0.04 * tt + 0.01 * rng.standard_normal(30)
    # Round to a few digits so the stored text stays small (the values are exact inputs).
    return (np.round(t, 6), np.round(rate, 6), np.round(tt, 3), np.round(top, 5),
            np.round(side, 5))


def main():
    os.makedirs(OUT_DIR, exist_ok=True)
    base = dict(seed=1, gyro_n=12004, gyro_t0=37.25, gyro_dt=0.1, rate_offset_dph=8.0,
                rate_drift_dph_per_s=0.0005, rate_sigma_dph=3.0, temp_n=1201, temp_t0=37.75,
                temp_dt=1.0, top0_c=20.0, top_slope_c_per_s=0.001, side0_c=19.8,
                side_slope_c_per_s=0.0012, temp_sigma_c=0.02)
    write_case("10hz_drift",
               "10 Hz for 1200.4 s: 1200 full 1 s bins, the partial last one dropped.",
               1.0, 101, gen=base)
    write_case("1hz_as_is",
               "1 Hz data used as is; temperatures every 2 s, so half the samples interpolate.",
               1.0, 101, gen=dict(base, seed=7, gyro_n=600, gyro_t0=0.0, gyro_dt=1.0,
                                  temp_n=300, temp_t0=0.7, temp_dt=2.0))
    write_case("offset_1e4",
               "Rates around 1e4 + 8 deg/h (10 Hz, 400 bins): stresses cancellation.",
               1.0, 101, gen=dict(base, seed=11, gyro_n=4000, gyro_t0=1000.0,
                                  rate_offset_dph=10008.0, temp_n=400, temp_t0=1000.5))
    write_case("n_102", "1 Hz, n = 102: the moving average has exactly two full windows.",
               1.0, 101, gen=dict(base, seed=13, gyro_n=102, gyro_t0=3.0, gyro_dt=1.0,
                                  temp_n=103, temp_t0=2.5))
    write_case("long_1e6",
               "1e6 samples at 1 Hz used as is, offset 1e5 deg/h: running-sum accuracy.",
               1.0, 101, gen=dict(base, seed=17, gyro_n=1000000, gyro_t0=0.0, gyro_dt=1.0,
                                  rate_offset_dph=100008.0, rate_drift_dph_per_s=1e-6,
                                  temp_n=1000, temp_t0=0.5, temp_dt=1000.0))
    write_case("irregular",
               "Jittered 10 Hz, a 7 s gap, 2 s bins, sparse temperatures, 5-point moving average.",
               2.0, 5, stored=irregular_input(), series_rows="all")
    return 0


if __name__ == "__main__":
    sys.exit(main())

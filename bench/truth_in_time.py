#!/usr/bin/python3
"""What a run stored against the simulator's truth (bench/truth_in_time.sh).

Table I: for every completed soak without the table spinning, one row per
DUT and analysed axis is expected, with n = the soak's acquire time in
one-second bins; each row's Earth-removed bias is compared with that DUT
axis's truth (linear between the truth's 5 degC static points), in sigmas of
the mean (row std / sqrt(n)). Scale factor: each stored fit of the first
DUT's table axis against the truth's K through the same line fit, in ppm.
"""
import argparse
import json
import math
import sqlite3
import sys
import tomllib


def truth_bias(truth, serial, axis, temp_c):
    for d in truth.get("duts", []):
        if d.get("serial") != serial:
            continue
        pts = d["axes"][axis]["static"]
        for a, b in zip(pts, pts[1:]):
            if a["temp_c"] <= temp_c <= b["temp_c"]:
                f = (temp_c - a["temp_c"]) / (b["temp_c"] - a["temp_c"])
                return a["bias_earth_removed_dph"] + f * (
                    b["bias_earth_removed_dph"] - a["bias_earth_removed_dph"])
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--db", required=True)
    ap.add_argument("--truth", required=True)
    ap.add_argument("--config", required=True)
    ap.add_argument("--wall-s", type=float, required=True)
    ap.add_argument("--scale", type=float, required=True)
    ap.add_argument("--hogs", type=int, default=0)
    ap.add_argument("--sim-status", default="")
    a = ap.parse_args()

    truth = json.load(open(a.truth))
    with open(a.config, "rb") as f:
        config = tomllib.load(f)
    analysed = {}
    for d in config.get("dut", []):
        axes = d.get("axes") or (["x", "y", "z"] if d.get("protocol", "kvh1750") == "kvh1750"
                                 else [c["axis"] for c in d["ascii"]["columns"]
                                       if c.get("kind") == "rate"])
        analysed[d["serial"]] = axes
    db = sqlite3.connect("file:%s?mode=ro" % a.db, uri=True)

    soaks = db.execute(
        "SELECT s.id, s.run_id, s.idx, s.setpoint_c, s.t_acquire_start_s, s.t_acquire_end_s "
        "FROM segments s WHERE s.kind = 'soak' AND s.state = 'completed' "
        "AND COALESCE(s.table_mode, '') != 'rate' ORDER BY s.run_id, s.idx").fetchall()
    expected = sum(len(v) for v in analysed.values()) * len(soaks)
    rows = db.execute("SELECT segment_id, dut_serial, axis, n, temp_mean_c, bias_std_dph, "
                      "bias_mean_earth_removed_dph, t_from_s, t_to_s FROM segment_stats").fetchall()
    worst_sigma, worst_dph, short = 0.0, 0.0, 0
    ns = []
    for seg_id, serial, axis, n, temp_c, std, bias, t0, t1 in rows:
        ns.append(n)
        tb = truth_bias(truth, serial, axis, temp_c)
        if tb is None or not n:
            continue
        err = bias - tb
        worst_dph = max(worst_dph, abs(err))
        worst_sigma = max(worst_sigma, abs(err) / (std / math.sqrt(n)))
    acquire_s = {}
    sched_rows = db.execute("SELECT id, t_acquire_start_s, t_acquire_end_s FROM segments").fetchall()
    for seg_id, s0, s1 in sched_rows:
        acquire_s[seg_id] = (s1 - s0) if s0 is not None and s1 is not None else None

    print("== truth in time: x%g asked, %d hog(s), %.1f wall s" % (a.scale, a.hogs, a.wall_s))
    try:
        sim = json.loads(a.sim_status) if a.sim_status else {}
    except json.JSONDecodeError:
        sim = {}
    if sim:
        clock = sim.get("clock", {})
        print("simulator: %.0f station s, effective x%.0f, lag %.1f s, shared clock %s, "
              "held %.1f wall s" % (sim.get("t_s", 0), sim.get("t_s", 0) / a.wall_s,
                                    sim.get("lag_s", 0), clock.get("shared", False),
                                    clock.get("held_wall_s", 0)))
    print("Table I rows: %d of %d expected (%d soaks x %d DUT axes)" % (
        len(rows), expected, len(soaks), sum(len(v) for v in analysed.values())))
    if ns:
        print("n per row: min %d, max %d" % (min(ns), max(ns)))
    print("bias vs truth: worst %.3f deg/h, %.1f sigma of the mean" % (worst_dph, worst_sigma))

    sf = truth.get("scale_factor")
    if sf:
        earth_dps = truth.get("earth_rate_dph", 0.0) / 3600.0

        def out(rate, t_c):
            k = 1 + (sf["k_ppm"] + sf["k_tc_ppm_per_c"] * (t_c - sf["reference_temp_c"])) * 1e-6
            w = rate + earth_dps
            k *= 1 + (0.5 if w >= 0 else -0.5) * sf["asymmetry_ppm"] * 1e-6
            return k * w * (1 + sf["nonlinearity_ppm"] * 1e-6 * abs(w) / sf["full_scale_dps"])

        def slope(xs, ys):
            mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
            return (sum((x - mx) * (y - my) for x, y in zip(xs, ys)) /
                    sum((x - mx) ** 2 for x in xs))

        fits = db.execute(
            "SELECT f.run_id, f.sf_sequence, f.temperature_c, f.k, f.asymmetry_ppm, "
            "f.nonlinearity_ppm FROM scale_factor_fits f WHERE f.dut_serial = (SELECT d.serial "
            "FROM run_duts r JOIN duts d ON d.id = r.dut_id WHERE r.run_id = f.run_id ORDER BY "
            "r.position LIMIT 1) ORDER BY f.run_id, f.temperature_c").fetchall()
        worst_ppm = 0.0
        for run_id, seq, t_c, k, asym, nl in fits:
            rates = [r for (r,) in db.execute(
                "SELECT rate_dps FROM scale_factor_points WHERE run_id = ? AND sf_sequence = ? "
                "AND dut_serial = (SELECT d.serial FROM run_duts r JOIN duts d ON d.id = r.dut_id "
                "WHERE r.run_id = ? ORDER BY r.position LIMIT 1)", (run_id, seq, run_id))]
            k_true = slope(rates, [out(r, t_c) for r in rates])
            ppm = (k / k_true - 1) * 1e6
            worst_ppm = max(worst_ppm, abs(ppm))
            print("scale factor run %d at %.2f degC: K %.7f (truth %.7f, %+.1f ppm), asymmetry "
                  "%s ppm (truth %g), nonlinearity %.1f ppm" % (
                      run_id, t_c, k, k_true, ppm, "-" if asym is None else "%.1f" % asym,
                      sf["asymmetry_ppm"], nl))
        if fits:
            print("scale factor: worst K error %.1f ppm over %d fits" % (worst_ppm, len(fits)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

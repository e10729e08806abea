#!/usr/bin/python3
"""Reference values for Table I grouped by set point (the paper's form).

Writes tests/analysis/data/table1_groups.txt, read by
tests/analysis/table1_groups_test.cpp:
- "soak SETPOINT_C TEMP_C BIAS_DPH STD_DPH STD_MA_DPH BIAS_E_DPH" lines: the
  per-soak Table I rows, in the order given to the C++ code (a campaign of
  eight set points x four repetitions, shuffled; the repetitions' set points
  differ by up to 4e-4 degC, as a set point read back from a database may;
  one soak too short for the moving average, "nan");
- "group SETPOINT_C REPETITIONS" then, per column, "MEAN STD N" (n = the
  values that are not NaN; a std of fewer than 2 values is "nan").

numpy only: per group the columns are numpy.nanmean and numpy.nanstd(ddof=1)
of the rows whose set point is within 1e-3 degC of the group's lowest.
Rows are generated with numpy.random.default_rng(15) and written with repr,
so the C++ test reads exactly the same doubles.

Run: /usr/bin/python3 tools/reference/table1_groups_reference.py
(deterministic).
"""

import os

import numpy as np

from refgen import OUT_DIR

TOL_C = 1e-3
# The paper's set points (its Table I temperatures are the measured means).
SETPOINTS_C = [-15.0, 2.5, 22.5, 40.0, 47.5, 51.0, 56.5, 60.0]
REPETITIONS = 4


def main():
    rng = np.random.default_rng(15)
    rows = []
    for sp in SETPOINTS_C:
        for _ in range(REPETITIONS):
            jitter = float(rng.uniform(-4e-4, 4e-4)) if sp != -15.0 else 0.0
            temp = sp + 0.3 + float(rng.normal(0, 0.2))
            bias = 7.9 + 0.004 * sp + float(rng.normal(0, 0.15))
            std = 0.05 + float(rng.uniform(0, 0.02))
            std_ma = 0.006 + float(rng.uniform(0, 0.003))
            rows.append([sp + jitter, temp, bias, std, std_ma, bias - 7.9512])
    rows[9][4] = float("nan")  # one soak shorter than the moving average
    order = rng.permutation(len(rows))
    rows = [rows[i] for i in order]

    data = np.array(rows)
    sp = data[:, 0]
    lines = ["# table1_groups_reference.py: Table I grouped by set point (numpy)"]
    for r in rows:
        lines.append("soak " + " ".join(repr(float(v)) for v in r))
    idx = np.argsort(sp, kind="stable")
    k = 0
    while k < len(idx):
        first = sp[idx[k]]
        members = [i for i in idx[k:] if sp[i] - first < TOL_C]
        g = data[members]
        fields = [f"group {first!r} {len(members)}"]
        for col in range(1, 6):
            v = g[:, col]
            n = int(np.count_nonzero(~np.isnan(v)))
            mean = float(np.nanmean(v)) if n else float("nan")
            std = float(np.nanstd(v, ddof=1)) if n >= 2 else float("nan")
            fields.append(f"{mean!r} {std!r} {n}")
        lines.append(" ".join(fields))
        k += len(members)
    path = os.path.join(OUT_DIR, "table1_groups.txt")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    print("wrote", path)


if __name__ == "__main__":
    main()

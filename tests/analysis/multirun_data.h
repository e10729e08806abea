// Generated multi-run data of tools/reference/multirun_reference.py: the
// "run" lines' parameters and the generator (make_run there), operation for
// operation, so the tests rebuild the same runs bit for bit.
#pragma once

#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "reference_data.h"

namespace gyrotherm::analysis::testing {

using RunParams = std::map<std::string, double>;

// The parameters of a "run" line: key value pairs after the word "run".
inline RunParams parse_run_line(const Tokens& t) {
  RunParams p;
  for (std::size_t i = 1; i + 1 < t.size(); i += 2) p[t[i]] = std::stod(t[i + 1]);
  return p;
}

inline AnalysisSeries make_run(const RunParams& p) {
  const auto n = static_cast<std::size_t>(p.at("n"));
  const auto period = static_cast<std::size_t>(p.at("period"));
  const auto g_period = static_cast<std::size_t>(p.at("g_period"));
  const auto seed = static_cast<uint64_t>(p.at("seed"));
  const double nd = static_cast<double>(n);
  const double pd = static_cast<double>(period);
  const double gd = static_cast<double>(g_period);
  AnalysisSeries s;
  for (std::size_t k = 0; k < n; ++k) {
    const double kf = static_cast<double>(k);
    const double t = p.at("t_start") + kf;
    const double x = kf / nd;
    const double warm = x * (2.0 - x);
    const double ph = static_cast<double>(k % period) / pd;
    const double tri = std::abs(4.0 * ph - 2.0) - 1.0;
    const double sign = 4.0 * ph - 2.0 >= 0.0 ? 1.0 : -1.0;
    const double temp = p.at("t0") + p.at("span") * warm + p.at("tri_amp") * tri;
    const double dtdt = p.at("span") * (2.0 - 2.0 * x) / nd + p.at("tri_amp") * (4.0 / pd) * sign;
    const double phg = static_cast<double>(k % g_period) / gd;
    const double grad = p.at("g0") + p.at("g_amp") * (std::abs(4.0 * phg - 2.0) - 1.0);
    s.t_s.push_back(t);
    s.top_c.push_back(temp + grad / 2.0 + noise(seed, k, p.at("temp_sigma")));
    s.side_c.push_back(temp - grad / 2.0 + noise(seed + 1, k, p.at("temp_sigma")));
    s.rate_dph.push_back(p.at("bias") + p.at("a1") * temp + p.at("a2") * temp * temp +
                         p.at("a3") * temp * temp * temp + p.at("b1") * dtdt + p.at("c1") * grad +
                         noise(seed + 2, k, p.at("rate_sigma")));
  }
  return s;
}

// The runs of a reference file, each checked against its "check" lines
// (index, t_s, top_c, side_c, rate_dph exactly).
inline std::vector<AnalysisSeries> load_runs(const std::vector<Tokens>& lines) {
  std::vector<AnalysisSeries> runs;
  for (const Tokens& t : lines) {
    if (t[0] == "run") runs.push_back(make_run(parse_run_line(t)));
  }
  for (const Tokens& t : lines) {
    if (t[0] != "check") continue;
    const std::size_t r = std::stoul(t[1]);
    const std::size_t i = std::stoul(t[2]);
    EXPECT_LT(r, runs.size());
    if (r >= runs.size()) continue;
    const AnalysisSeries& s = runs[r];
    EXPECT_EQ(s.t_s.at(i), std::stod(t[3])) << "run " << r << " point " << i;
    EXPECT_EQ(s.top_c.at(i), std::stod(t[4])) << "run " << r << " point " << i;
    EXPECT_EQ(s.side_c.at(i), std::stod(t[5])) << "run " << r << " point " << i;
    EXPECT_EQ(s.rate_dph.at(i), std::stod(t[6])) << "run " << r << " point " << i;
  }
  return runs;
}

}  // namespace gyrotherm::analysis::testing

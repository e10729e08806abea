// Table I against numpy reference values (tools/reference/table1_reference.py,
// files in tests/analysis/data/). Tolerances: statistics 1e-10 relative, bin
// times 1e-9 s, bin means and temperatures 1e-12 relative, counts exact.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "reference_data.h"

namespace gyrotherm::analysis {
namespace {

using testing::noise;
using testing::Tokens;

struct ReferenceCase {
  std::map<std::string, std::string> scalars;  // "key value" lines
  std::map<std::string, std::string> gen;      // "gen key value"
  std::vector<Tokens> checks_gyro, checks_temp, expect_series;
  std::vector<GyroSample> gyro;
  std::vector<TemperatureSample> temps;

  double num(const std::string& key) const { return std::stod(scalars.at(key)); }
  double gnum(const std::string& key) const { return std::stod(gen.at(key)); }
};

ReferenceCase load(const std::string& name) {
  ReferenceCase c;
  for (const Tokens& t : testing::read_reference_lines("table1_" + name + ".txt",
                                                       "tools/reference/table1_reference.py")) {
    if (t[0] == "gen") {
      c.gen[t[1]] = t[2];
    } else if (t[0] == "check_gyro") {
      c.checks_gyro.push_back(t);
    } else if (t[0] == "check_temp") {
      c.checks_temp.push_back(t);
    } else if (t[0] == "expect_series") {
      c.expect_series.push_back(t);
    } else if (t[0] == "gyro") {
      c.gyro.push_back({.t_s = std::stod(t[1]), .rate_dph = std::stod(t[2])});
    } else if (t[0] == "temp") {
      c.temps.push_back(
          {.t_s = std::stod(t[1]), .top_c = std::stod(t[2]), .side_c = std::stod(t[3])});
    } else {
      c.scalars[t[0]] = t.size() > 1 ? t[1] : "";
    }
  }
  return c;
}

void generate(ReferenceCase& c) {
  const auto seed = static_cast<uint64_t>(std::stoull(c.gen.at("seed")));
  const auto gn = static_cast<std::size_t>(std::stoull(c.gen.at("gyro_n")));
  const double gt0 = c.gnum("gyro_t0"), gdt = c.gnum("gyro_dt");
  const double offset = c.gnum("rate_offset_dph"), drift = c.gnum("rate_drift_dph_per_s");
  const double sigma = c.gnum("rate_sigma_dph");
  c.gyro.resize(gn);
  for (std::size_t i = 0; i < gn; ++i) {
    const double t = gt0 + gdt * static_cast<double>(i);
    c.gyro[i].t_s = t;
    c.gyro[i].rate_dph = offset + drift * (t - gt0) + noise(seed, i, sigma);
  }
  const auto tn = static_cast<std::size_t>(std::stoull(c.gen.at("temp_n")));
  const double tt0 = c.gnum("temp_t0"), tdt = c.gnum("temp_dt");
  const double tsig = c.gnum("temp_sigma_c");
  c.temps.resize(tn);
  for (std::size_t j = 0; j < tn; ++j) {
    const double t = tt0 + tdt * static_cast<double>(j);
    c.temps[j].t_s = t;
    c.temps[j].top_c =
        c.gnum("top0_c") + c.gnum("top_slope_c_per_s") * (t - tt0) + noise(seed + 1, j, tsig);
    c.temps[j].side_c =
        c.gnum("side0_c") + c.gnum("side_slope_c_per_s") * (t - tt0) + noise(seed + 2, j, tsig);
  }
}

void expect_rel(double actual, double expected, double rel, const char* what) {
  if (std::isnan(expected)) {
    EXPECT_TRUE(std::isnan(actual)) << what << ": expected NaN, got " << actual;
    return;
  }
  EXPECT_NEAR(actual, expected, rel * std::abs(expected)) << what;
}

class Table1Reference : public ::testing::TestWithParam<const char*> {};

TEST_P(Table1Reference, MatchesNumpy) {
  ReferenceCase c = load(GetParam());
  ASSERT_FALSE(c.scalars.empty());
  if (c.scalars.at("input") == "generated") {
    generate(c);
    // The regenerated input must be the one numpy saw.
    for (const Tokens& t : c.checks_gyro) {
      const GyroSample& g = c.gyro.at(std::stoul(t[1]));
      ASSERT_EQ(g.t_s, std::stod(t[2])) << "gyro " << t[1];
      ASSERT_NEAR(g.rate_dph, std::stod(t[3]), 1e-15 * std::abs(g.rate_dph)) << "gyro " << t[1];
    }
    for (const Tokens& t : c.checks_temp) {
      const TemperatureSample& s = c.temps.at(std::stoul(t[1]));
      ASSERT_EQ(s.t_s, std::stod(t[2])) << "temp " << t[1];
      ASSERT_NEAR(s.top_c, std::stod(t[3]), 1e-15 * std::abs(s.top_c)) << "temp " << t[1];
      ASSERT_NEAR(s.side_c, std::stod(t[4]), 1e-15 * std::abs(s.side_c)) << "temp " << t[1];
    }
  }
  ASSERT_FALSE(c.gyro.empty());

  auto series = make_analysis_series(c.gyro, c.temps, c.num("bin_s"));
  ASSERT_TRUE(series.ok()) << series.error().message;
  EXPECT_EQ(series->binned, c.scalars.at("expect_binned") == "1");
  EXPECT_NEAR(series->bin_s, c.num("expect_bin_s"), 1e-12);
  ASSERT_EQ(series->rate_dph.size(), std::stoul(c.scalars.at("expect_n")));
  for (const Tokens& t : c.expect_series) {
    const std::size_t k = std::stoul(t[1]);
    SCOPED_TRACE("bin " + t[1]);
    EXPECT_NEAR(series->t_s.at(k), std::stod(t[2]), 1e-9);
    expect_rel(series->rate_dph.at(k), std::stod(t[3]), 1e-12, "rate_dph");
    expect_rel(series->top_c.at(k), std::stod(t[4]), 1e-12, "top_c");
    expect_rel(series->side_c.at(k), std::stod(t[5]), 1e-12, "side_c");
  }

  Table1Options options;
  options.bin_s = c.num("bin_s");
  options.ma_window = std::stoul(c.scalars.at("ma_window"));
  options.earth_rate_dph = c.num("earth_rate_dph");
  EXPECT_NEAR(earth_rate_component_dph(c.num("latitude_deg"), AxisOrientation::kUp),
              options.earth_rate_dph, 1e-12);
  auto row = table1_row(*series, options);
  ASSERT_TRUE(row.ok()) << row.error().message;
  EXPECT_EQ(row->n, std::stoul(c.scalars.at("expect_n")));
  expect_rel(row->duration_s, c.num("expect_duration_s"), 1e-12, "duration_s");
  expect_rel(row->temp_mean_c, c.num("expect_temp_mean_c"), 1e-10, "temp_mean_c");
  expect_rel(row->bias_mean_dph, c.num("expect_bias_mean_dph"), 1e-10, "bias_mean_dph");
  expect_rel(row->bias_std_dph, c.num("expect_bias_std_dph"), 1e-10, "bias_std_dph");
  expect_rel(row->bias_std_ma_dph, c.num("expect_bias_std_ma_dph"), 1e-10, "bias_std_ma_dph");
  expect_rel(row->bias_mean_earth_removed_dph, c.num("expect_bias_mean_earth_removed_dph"), 1e-10,
             "bias_mean_earth_removed_dph");
}

INSTANTIATE_TEST_SUITE_P(Cases, Table1Reference,
                         ::testing::Values("10hz_drift", "1hz_as_is", "offset_1e4", "n_102",
                                           "long_1e6", "irregular"),
                         [](const auto& info) { return std::string("case_") + info.param; });

}  // namespace
}  // namespace gyrotherm::analysis

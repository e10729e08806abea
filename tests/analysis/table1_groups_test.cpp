// Table I grouped by set point (table1_by_setpoint) against numpy
// (tools/reference/table1_groups_reference.py, tests/analysis/data/
// table1_groups.txt): eight set points x four repetitions, shuffled, with set
// points that differ by < 1e-3 °C within a group and one soak without a
// moving-average std. Tolerances: means 1e-13 relative, stds 1e-11 relative,
// counts and set points exact.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "reference_data.h"

namespace gyrotherm::analysis {
namespace {

struct Expected {
  double setpoint_c;
  std::size_t repetitions;
  MeanSpread columns[5];
};

double parse_number(const std::string& s) { return s == "nan" ? std::nan("") : std::stod(s); }

void expect_close(double got, double want, double rel, const std::string& what) {
  if (std::isnan(want)) {
    EXPECT_TRUE(std::isnan(got)) << what << ": got " << got << ", numpy gives nan";
    return;
  }
  EXPECT_NEAR(got, want, rel * std::max(1.0, std::fabs(want))) << what;
}

TEST(Table1BySetpoint, MatchesNumpyForTheFourRepetitionsOfEightSetpoints) {
  std::vector<Table1Soak> soaks;
  std::vector<Expected> expected;
  for (const auto& t : testing::read_reference_lines(
           "table1_groups.txt", "tools/reference/table1_groups_reference.py")) {
    if (t[0] == "soak") {
      ASSERT_EQ(t.size(), 7u);
      Table1Soak s;
      s.setpoint_c = parse_number(t[1]);
      s.row.temp_mean_c = parse_number(t[2]);
      s.row.bias_mean_dph = parse_number(t[3]);
      s.row.bias_std_dph = parse_number(t[4]);
      s.row.bias_std_ma_dph = parse_number(t[5]);
      s.row.bias_mean_earth_removed_dph = parse_number(t[6]);
      soaks.push_back(s);
    } else if (t[0] == "group") {
      ASSERT_EQ(t.size(), 18u);
      Expected e{parse_number(t[1]), std::stoul(t[2]), {}};
      for (int c = 0; c < 5; ++c) {
        e.columns[c] = {parse_number(t[3 + 3 * c]), parse_number(t[4 + 3 * c]),
                        std::stoul(t[5 + 3 * c])};
      }
      expected.push_back(e);
    }
  }
  ASSERT_EQ(soaks.size(), 32u);
  ASSERT_EQ(expected.size(), 8u);

  auto groups = table1_by_setpoint(soaks);
  ASSERT_TRUE(groups) << groups.error().message;
  ASSERT_EQ(groups->size(), expected.size());
  const char* names[5] = {"temp_mean_c", "bias_mean_dph", "bias_std_dph", "bias_std_ma_dph",
                          "bias_mean_earth_removed_dph"};
  std::vector<int> seen(soaks.size());
  for (std::size_t g = 0; g < expected.size(); ++g) {
    const Table1SetpointRow& got = (*groups)[g];
    const Expected& want = expected[g];
    SCOPED_TRACE("set point " + std::to_string(want.setpoint_c));
    EXPECT_EQ(got.setpoint_c, want.setpoint_c);
    EXPECT_EQ(got.repetitions, want.repetitions);
    ASSERT_EQ(got.soaks.size(), got.repetitions);
    for (std::size_t i : got.soaks) {
      ASSERT_LT(i, soaks.size());
      ++seen[i];
      EXPECT_GE(soaks[i].setpoint_c, got.setpoint_c);
      EXPECT_LT(soaks[i].setpoint_c - got.setpoint_c, kSetpointGroupTolC);
    }
    const MeanSpread* cols[5] = {&got.temp_mean_c, &got.bias_mean_dph, &got.bias_std_dph,
                                 &got.bias_std_ma_dph, &got.bias_mean_earth_removed_dph};
    for (int c = 0; c < 5; ++c) {
      expect_close(cols[c]->mean, want.columns[c].mean, 1e-13, std::string(names[c]) + " mean");
      expect_close(cols[c]->std, want.columns[c].std, 1e-11, std::string(names[c]) + " std");
      EXPECT_EQ(cols[c]->n, want.columns[c].n) << names[c];
    }
  }
  for (std::size_t i = 0; i < seen.size(); ++i) EXPECT_EQ(seen[i], 1) << "soak " << i;
}

TEST(Table1BySetpoint, OneSoakPerSetpointHasNoSpreadAndANonFiniteSetpointIsNamed) {
  std::vector<Table1Soak> soaks(2);
  soaks[0].setpoint_c = 40;
  soaks[0].row.bias_mean_dph = 8.1;
  soaks[1].setpoint_c = -15;
  soaks[1].row.bias_mean_dph = 7.7;
  auto groups = table1_by_setpoint(soaks);
  ASSERT_TRUE(groups) << groups.error().message;
  ASSERT_EQ(groups->size(), 2u);
  EXPECT_EQ((*groups)[0].setpoint_c, -15);
  EXPECT_EQ((*groups)[0].bias_mean_dph.mean, 7.7);
  EXPECT_EQ((*groups)[0].bias_mean_dph.n, 1u);
  EXPECT_TRUE(std::isnan((*groups)[0].bias_mean_dph.std));

  soaks[1].setpoint_c = std::nan("");
  auto bad = table1_by_setpoint(soaks);
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("soak 1"), std::string::npos) << bad.error().message;
}

}  // namespace
}  // namespace gyrotherm::analysis

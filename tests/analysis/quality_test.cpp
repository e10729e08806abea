// The flatness of a rate point (docs/analysis.md "Rate points"). The
// numbers are numpy's (tools/reference/quality_reference.py), on the same
// closed-form data.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "gyrotherm/analysis/scale_factor.h"

namespace gyrotherm::analysis {
namespace {

using ::testing::HasSubstr;

std::vector<double> point_output(int contaminated, double previous) {
  std::vector<double> y;
  for (int i = 0; i < 300; ++i) {
    const double noise = 0.02 * std::sin(0.7 * i) + 0.006 * std::cos(1.3 * i);
    y.push_back((i < contaminated ? previous : 10.0) + noise);
  }
  return y;
}

TEST(RatePointFlatness, AFlatPointPasses) {
  const auto f = check_rate_point_flatness(point_output(0, 0), 10.0, {});
  EXPECT_TRUE(f.checked);
  EXPECT_TRUE(f.ok) << f.why;
  EXPECT_NEAR(f.first_mean, 10.000027377484988, 1e-13);
  EXPECT_NEAR(f.last_mean, 10.000180119691064, 1e-13);
  EXPECT_NEAR(f.tolerance, 0.015403533858649354, 1e-13);
}

TEST(RatePointFlatness, SamplesOfThePreviousRateAtTheStartAreNotFlat) {
  const auto f = check_rate_point_flatness(point_output(35, 5.0), 10.0, {});
  EXPECT_FALSE(f.ok);
  EXPECT_NEAR(f.first_mean, 8.25002737748499, 1e-12);
  EXPECT_NEAR(f.last_mean, 10.000180119691064, 1e-13);
  EXPECT_NEAR(f.tolerance, 1.2032968311955263, 1e-12);
  EXPECT_THAT(f.why, HasSubstr("not flat: the first third of its samples reads 8.250027 °/s"));
}

TEST(RatePointFlatness, TheTableMustBeAtTheDemand) {
  std::vector<double> table(30, 10.0);
  EXPECT_TRUE(check_rate_point_flatness(table, 10.0, {}, true).ok);
  // Flat, but at 9.9 °/s for a demand of 10 (10 000 ppm off).
  std::vector<double> slow(30, 9.9);
  const auto f = check_rate_point_flatness(slow, 10.0, {}, true);
  EXPECT_FALSE(f.ok);
  EXPECT_THAT(f.why, HasSubstr("not at the demanded rate: the first third reads 9.9 °/s"));
  // The gyro is not held to the demand: its K and bias are the fit's.
  EXPECT_TRUE(check_rate_point_flatness(slow, 10.0, {}).ok);
  // Too few samples to tell: not checked.
  const auto few = check_rate_point_flatness(std::vector<double>{1, 2, 3, 4, 5}, 10.0, {});
  EXPECT_FALSE(few.checked);
  EXPECT_TRUE(few.ok);
}

}  // namespace
}  // namespace gyrotherm::analysis

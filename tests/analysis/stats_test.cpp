// Plain statistics against hand-computed values. Tolerances are stated per
// check; "exact" cases use inputs whose results are representable.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <numeric>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "numbers.h"

namespace gyrotherm::analysis {
namespace {

using gyrotherm::testing::kNaN;

TEST(Mean, OneToFive) {
  const std::vector<double> x = {1, 2, 3, 4, 5};
  EXPECT_EQ(mean(x), 3.0);
  EXPECT_NEAR(std_ddof1(x), std::sqrt(2.5), 1e-15);
}

TEST(Mean, EmptyAndShortInputGiveNaN) {
  const std::vector<double> empty;
  const std::vector<double> one = {4.0};
  EXPECT_TRUE(std::isnan(mean(empty)));
  EXPECT_EQ(mean(one), 4.0);
  EXPECT_TRUE(std::isnan(std_ddof1(empty)));
  EXPECT_TRUE(std::isnan(std_ddof1(one)));
}

TEST(Mean, NonFiniteInputGivesNaN) {
  const std::vector<double> with_nan = {1, kNaN, 3};
  const std::vector<double> with_inf = {1, std::numeric_limits<double>::infinity(), 3};
  EXPECT_TRUE(std::isnan(mean(with_nan)));
  EXPECT_TRUE(std::isnan(std_ddof1(with_nan)));
  EXPECT_TRUE(std::isnan(std_ddof1(with_inf)));
  EXPECT_TRUE(std::isnan(moving_average_std(with_nan, 2)));
}

TEST(StdDdof1, SurvivesALargeOffset) {
  // 1e9 + {0, 0.5, ..., 4.5}: all exact in double; a one-pass sum of squares
  // would lose every digit of the spread (1e18 vs 1).
  std::vector<double> x;
  for (int i = 0; i < 10; ++i) x.push_back(1e9 + 0.5 * i);
  // std of 0.5 * {0..9} = 0.5 * sqrt(55/6).
  EXPECT_NEAR(std_ddof1(x), 0.5 * std::sqrt(55.0 / 6.0), 1e-12);
  EXPECT_EQ(mean(x), 1e9 + 2.25);
}

TEST(StdDdof1, ConstantIsZero) {
  const std::vector<double> x(1000, 10008.123);
  EXPECT_EQ(std_ddof1(x), 0.0);
}

TEST(MovingAverageStd, WindowThreeByHand) {
  // Means of 3: {2, 3, 4, 5, 7}; mean 4.2; squared deviations sum to 14.8.
  const std::vector<double> x = {1, 2, 3, 4, 5, 6, 10};
  EXPECT_NEAR(moving_average_std(x, 3), std::sqrt(14.8 / 4), 1e-14);
}

TEST(MovingAverageStd, NeedsMoreThanWindowPoints) {
  const std::vector<double> x = {1, 2, 3, 4, 5};
  EXPECT_TRUE(std::isnan(moving_average_std(x, 5)));  // n == window: one mean only
  EXPECT_TRUE(std::isnan(moving_average_std(x, 6)));
  EXPECT_TRUE(std::isnan(moving_average_std(x, 0)));
  // n == window + 1: two means, 2.5 and 3.5.
  EXPECT_NEAR(moving_average_std(x, 4), std::sqrt(0.5), 1e-15);
}

TEST(MovingAverageStd, WindowOneIsThePlainStd) {
  const std::vector<double> x = {3, 1, 4, 1, 5, 9, 2, 6};
  EXPECT_NEAR(moving_average_std(x, 1), std_ddof1(x), 1e-15);
}

TEST(MovingAverageStd, MatchesDirectSumsOnALongOffsetSeries) {
  // 2e5 points around 1e4 with a deterministic pattern; the running sum must
  // agree with window sums recomputed from scratch (long double, small data).
  const std::size_t n = 200000, w = 101;
  std::vector<double> x(n);
  for (std::size_t i = 0; i < n; ++i) {
    x[i] = 1e4 + 3.0 * std::sin(0.37 * static_cast<double>(i)) + 1e-5 * static_cast<double>(i);
  }
  std::vector<double> means(n - w + 1);
  for (std::size_t k = 0; k < means.size(); ++k) {
    long double s = 0;
    for (std::size_t j = 0; j < w; ++j) s += static_cast<long double>(x[k + j]) - 1e4L;
    means[k] = static_cast<double>(s / w);
  }
  const double expected = std_ddof1(means);
  EXPECT_NEAR(moving_average_std(x, w), expected, 1e-11 * expected);
}

TEST(LinearSlope, ExactLine) {
  const std::vector<double> t = {0, 1, 2, 3, 10};
  std::vector<double> y;
  for (double v : t) y.push_back(3.0 * v + 2.0);
  EXPECT_NEAR(linear_slope(t, y), 3.0, 1e-14);
}

TEST(LinearSlope, LargeTimeOffset) {
  // Station time ~1e6 s, temperature creeping 0.02 °C/min.
  std::vector<double> t, y;
  for (int i = 0; i < 600; ++i) {
    t.push_back(1e6 + i);
    y.push_back(60.0 + (0.02 / 60.0) * i);
  }
  EXPECT_NEAR(linear_slope(t, y), 0.02 / 60.0, 1e-12);
}

TEST(LinearSlope, DegenerateInputGivesNaN) {
  const std::vector<double> one = {1};
  const std::vector<double> two = {1, 2};
  const std::vector<double> same_t = {5, 5, 5};
  const std::vector<double> y3 = {1, 2, 3};
  EXPECT_TRUE(std::isnan(linear_slope(one, one)));
  EXPECT_TRUE(std::isnan(linear_slope(two, y3)));
  EXPECT_TRUE(std::isnan(linear_slope(same_t, y3)));
}

}  // namespace
}  // namespace gyrotherm::analysis

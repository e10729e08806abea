// Result quality (docs/analysis.md "Result quality", "Rate points"):
// coverage over windows, the rules that flag a result, the series' noise
// and the flatness of a rate point. The numbers of the noise and the
// flatness are numpy's (tools/reference/quality_reference.py), on the
// same closed-form data.
#include "gyrotherm/analysis/quality.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "gyrotherm/analysis/scale_factor.h"

namespace gyrotherm::analysis {
namespace {

using ::testing::HasSubstr;

TEST(Coverage, AWindowWithA30PercentGapCovers70Percent) {
  // 600 s at 10 Hz, nothing recorded in [200, 380): 180 s of 600.
  std::vector<double> t_s;
  for (int i = 0; i < 6000; ++i) {
    const double t = i / 10.0;
    if (t < 200.0 || t >= 380.0) t_s.push_back(t);
  }
  const Coverage c = coverage_of(t_s, {{0.0, 600.0}}, 10.0);
  EXPECT_EQ(c.samples, 4200);
  EXPECT_DOUBLE_EQ(c.expected, 6000.0);
  ASSERT_TRUE(c.fraction.has_value());
  EXPECT_NEAR(*c.fraction, 0.7, 1e-12);
  EXPECT_NEAR(c.longest_gap_s, 380.0 - 199.9, 1e-9);  // last sample before to first after
  const auto reasons = coverage_reasons(c, QualityRules{});
  ASSERT_EQ(reasons.size(), 1u);
  EXPECT_THAT(reasons[0], HasSubstr("coverage 70.0 % (4200 of 6000 samples expected)"));
  EXPECT_THAT(reasons[0], HasSubstr("under 99 %"));
  EXPECT_THAT(reasons[0], HasSubstr("longest gap 180 s"));
}

TEST(Coverage, CountsOnlyInsideTheWindowsAndTheGapsAtTheirEnds) {
  // Two windows; samples before, between and after them are not counted.
  // The stream stops 5 s before the second window's end.
  std::vector<double> t_s;
  for (int i = 0; i < 400; ++i) t_s.push_back(i * 0.5);  // 0 ... 199.5 s at 2 Hz
  const Coverage c = coverage_of(t_s, {{10.0, 20.0}, {195.0, 205.0}}, 2.0);
  EXPECT_EQ(c.samples, 20 + 10);  // [10, 20) and [195, 200)
  EXPECT_DOUBLE_EQ(c.window_s, 20.0);
  EXPECT_DOUBLE_EQ(c.expected, 40.0);
  EXPECT_NEAR(*c.fraction, 0.75, 1e-15);
  EXPECT_NEAR(c.longest_gap_s, 205.0 - 199.5, 1e-12);
  // A window without a sample is one gap of its length.
  const Coverage empty = coverage_of(t_s, {{300.0, 330.0}}, 2.0);
  EXPECT_EQ(empty.samples, 0);
  EXPECT_NEAR(empty.longest_gap_s, 30.0, 1e-12);
  EXPECT_NEAR(*empty.fraction, 0.0, 0.0);
  // The rate not known: no expectation, nothing flagged for it.
  const Coverage unknown = coverage_of(t_s, {{10.0, 20.0}}, 0.0);
  EXPECT_FALSE(unknown.fraction.has_value());
  EXPECT_TRUE(coverage_reasons(unknown, QualityRules{}).empty());
}

TEST(Coverage, MedianRateOfAStreamWithGaps) {
  std::vector<double> t_s;
  for (int i = 0; i < 100; ++i) t_s.push_back(i * 0.01);
  for (int i = 0; i < 50; ++i) t_s.push_back(10.0 + i * 0.01);  // a gap of 9 s
  EXPECT_NEAR(median_rate_hz(t_s), 100.0, 1e-6);
  EXPECT_EQ(median_rate_hz(std::vector<double>{1.0}), 0.0);
}

TEST(QualityRules, ScaleFactorLines) {
  const QualityRules rules;  // K in [0.5, 2], nonlinearity at most 10 000 ppm
  EXPECT_TRUE(scale_factor_reasons(1.000123, 35.0, rules).empty());
  auto r = scale_factor_reasons(-0.53, 35.0, rules);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_THAT(r[0], HasSubstr("K = -0.53 is not positive"));
  r = scale_factor_reasons(0.3, 35.0, rules);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_THAT(r[0], HasSubstr("K = 0.3 is outside [0.5, 2]"));
  r = scale_factor_reasons(1.0, 5e7, rules);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_THAT(r[0], HasSubstr("nonlinearity 5e+07 ppm is over 10000 ppm"));
  EXPECT_EQ(scale_factor_reasons(NAN, NAN, rules).size(), 2u);
}

TEST(QualityRules, SeriesNoiseIsNumpys) {
  std::vector<double> x;
  for (int j = 0; j < 500; ++j) {
    x.push_back(0.5 + 0.001 * j + 0.03 * std::sin(1.7 * j) + 0.01 * std::cos(0.37 * j));
  }
  // numpy: 1.4826 * median(|diff - median(diff)|) / sqrt(2)
  EXPECT_NEAR(series_noise_dph(x), 0.03236684141052598, 1e-13);
  EXPECT_TRUE(std::isnan(series_noise_dph(std::vector<double>{1.0, 2.0})));
}

TEST(QualityRules, ResidualFarBeyondTheNoise) {
  const QualityRules rules;  // 20 times
  EXPECT_TRUE(residual_reasons(0.5, 0.1, rules).empty());
  const auto r = residual_reasons(49779.0, 0.1, rules);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_THAT(r[0], HasSubstr("residual std 4.978e+04 °/h is 4.98e+05 times"));
  // Noise-free data: the floor (1e-3 °/h) stands in for the noise.
  EXPECT_TRUE(residual_reasons(0.01, 0.0, rules).empty());
  EXPECT_EQ(residual_reasons(0.05, 0.0, rules).size(), 1u);
}

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

TEST(RatePointFlatnessOptions, Validity) {
  std::string why;
  EXPECT_TRUE(RatePointFlatnessOptions{}.is_valid(&why)) << why;
  const RatePointFlatnessOptions sharp{.n_sigma = 1, .tolerance_ppm = 0};
  EXPECT_TRUE(sharp.is_valid(&why)) << why;
  EXPECT_FALSE(RatePointFlatnessOptions{.n_sigma = 0}.is_valid(&why));
  EXPECT_THAT(why, HasSubstr("n_sigma = 0 must be"));
  EXPECT_FALSE(RatePointFlatnessOptions{.n_sigma = NAN}.is_valid(nullptr));
  EXPECT_FALSE(RatePointFlatnessOptions{.tolerance_ppm = -1}.is_valid(&why));
  EXPECT_THAT(why, HasSubstr("tolerance_ppm = -1 must be"));
  // The check says so rather than judging with a negative tolerance.
  const auto f =
      check_rate_point_flatness(std::vector<double>(12, 10.0), 10.0, {.tolerance_ppm = -1});
  EXPECT_TRUE(f.checked);
  EXPECT_FALSE(f.ok);
  EXPECT_THAT(f.why, HasSubstr("tolerance_ppm"));
}

}  // namespace
}  // namespace gyrotherm::analysis

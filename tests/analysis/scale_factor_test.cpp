// Scale-factor fit (scale_factor.h) against numpy
// (tools/reference/scale_factor_reference.py, tests/analysis/data/
// scale_factor.txt) and in closed form; awkward inputs; the fit over
// temperature against numpy.polyfit on T − T̄; the Earth-rate projection by
// hand.
//
// Tolerances: K, B, K₊, K₋, standard errors and polynomial coefficients
// 1e-10 relative to numpy; residuals 1e-12 °/s absolute (a few ulps of the
// 500 °/s full scale, where the residual is a difference of two numbers
// that size); the ppm figures 1e-9 relative plus 1e-6 ppm (the residual's
// rounding over |K·Ω| at 1 °/s); the noise-free closed form 1e-9 relative.
#include "gyrotherm/analysis/scale_factor.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <string>
#include <vector>

#include "reference_data.h"

namespace gyrotherm::analysis {
namespace {

constexpr char kScript[] = "tools/reference/scale_factor_reference.py";
constexpr double kRel = 1e-10;
constexpr double kResidualAbsDps = 1e-12;
constexpr double kPpmRel = 1e-9;
constexpr double kPpmAbs = 1e-6;

double parse(const std::string& s) {
  return s == "nan" ? std::numeric_limits<double>::quiet_NaN() : std::stod(s);
}

struct RefCase {
  std::vector<RatePoint> points;
  std::vector<double> fit;  // the "fit" line's 13 numbers
  std::vector<double> residuals;
  std::vector<RepetitionScaleFactor> repetitions;
};

struct RefTemperatureCase {
  int order = 0;
  std::vector<ScaleFactorAtTemperature> plateaus;
  double t_mean_c = 0, sf_tc_ppm = 0, bias_tc_dph = 0;
  std::vector<double> k_coef, b_coef, k_resid, b_resid;
};

struct References {
  std::map<std::string, RefCase> cases;
  std::map<std::string, RefTemperatureCase> temperature_cases;
};

const References& references() {
  static const References refs = [] {
    References r;
    RefCase* c = nullptr;
    RefTemperatureCase* tc = nullptr;
    for (const auto& t : testing::read_reference_lines("scale_factor.txt", kScript)) {
      if (t[0] == "case") {
        c = &r.cases[t[1]];
      } else if (t[0] == "p") {
        RatePoint p;
        p.rate_dps = parse(t[1]);
        p.output_dps = parse(t[2]);
        p.repetition = std::stoi(t[3]);
        p.temperature_c = parse(t[4]);
        c->points.push_back(p);
      } else if (t[0] == "fit") {
        for (std::size_t i = 1; i < t.size(); ++i) c->fit.push_back(parse(t[i]));
      } else if (t[0] == "r") {
        c->residuals.push_back(parse(t[1]));
      } else if (t[0] == "rep") {
        c->repetitions.push_back({std::stoi(t[1]), 0, parse(t[2]), parse(t[3])});
      } else if (t[0] == "tcase") {
        tc = &r.temperature_cases[t[1]];
        tc->order = std::stoi(t[2]);
      } else if (t[0] == "tp") {
        tc->plateaus.push_back({parse(t[1]), parse(t[2]), parse(t[3])});
      } else if (t[0] == "tfit") {
        tc->t_mean_c = parse(t[1]);
        tc->sf_tc_ppm = parse(t[2]);
        tc->bias_tc_dph = parse(t[3]);
      } else if (t[0] == "tk" || t[0] == "tb") {
        auto& v = t[0] == "tk" ? tc->k_coef : tc->b_coef;
        for (std::size_t i = 1; i < t.size(); ++i) v.push_back(parse(t[i]));
      } else if (t[0] == "tr") {
        tc->k_resid.push_back(parse(t[1]));
        tc->b_resid.push_back(parse(t[2]));
      }
    }
    return r;
  }();
  return refs;
}

void expect_rel(double got, double want, double rel, const std::string& what) {
  if (std::isnan(want)) {
    EXPECT_TRUE(std::isnan(got)) << what << ": got " << got << ", numpy gives nan";
    return;
  }
  EXPECT_NEAR(got, want, rel * std::fabs(want)) << what;
}

void expect_ppm(double got, double want, const std::string& what) {
  EXPECT_NEAR(got, want, kPpmRel * std::fabs(want) + kPpmAbs) << what;
}

void expect_optional_ppm(const std::optional<double>& got, double want, const std::string& what) {
  if (std::isnan(want)) {
    EXPECT_FALSE(got.has_value()) << what << ": got " << got.value_or(0) << ", numpy gives none";
  } else {
    ASSERT_TRUE(got.has_value()) << what << ": absent, numpy gives " << want;
    expect_ppm(*got, want, what);
  }
}

// Checks every figure of one case against numpy; returns the fit.
ScaleFactorFit check_case(const std::string& name) {
  SCOPED_TRACE("case " + name);
  const auto it = references().cases.find(name);
  EXPECT_NE(it, references().cases.end()) << "no case " << name << " in scale_factor.txt";
  if (it == references().cases.end()) return {};
  const RefCase& ref = it->second;
  EXPECT_EQ(ref.fit.size(), 13u);
  if (ref.fit.size() != 13u) return {};
  auto fit = fit_scale_factor(ref.points);
  EXPECT_TRUE(fit) << fit.error().message;
  if (!fit) return {};
  const ScaleFactorFit& f = *fit;
  EXPECT_EQ(f.points, ref.points.size());
  expect_rel(f.k, ref.fit[0], kRel, "K");
  expect_rel(f.bias_dps, ref.fit[1], kRel, "B");
  expect_rel(f.bias_dph, ref.fit[1] * 3600, kRel, "B in °/h");
  // The standard errors carry RSS, whose terms are the residuals: their
  // rounding (kResidualAbsDps) over the smallest residual std here (2e-4 °/s)
  // is the tolerance.
  expect_rel(f.k_std_error, ref.fit[2], 1e-8, "K standard error");
  expect_rel(f.bias_std_error_dps, ref.fit[3], 1e-8, "B standard error");
  expect_rel(f.residual_std_dps, ref.fit[4], 1e-8, "residual std");
  expect_ppm(f.nonlinearity_ppm, ref.fit[5], "nonlinearity relative to K");
  // The point named reaches the maximum (two points may tie to rounding,
  // e.g. ±1 °/s of the noise-free case, so its index is not compared).
  EXPECT_LT(f.nonlinearity_point, ref.points.size());
  if (f.nonlinearity_point < ref.points.size()) {
    const std::size_t i = f.nonlinearity_point;
    expect_ppm(std::fabs(ref.residuals[i]) / std::fabs(ref.fit[0] * ref.points[i].rate_dps) * 1e6,
               ref.fit[5], "nonlinearity at the point named");
  }
  expect_ppm(f.nonlinearity_fs_ppm, ref.fit[7], "nonlinearity relative to full scale");
  if (std::isnan(ref.fit[8])) {
    EXPECT_FALSE(f.k_positive.has_value());
  } else {
    EXPECT_TRUE(f.k_positive.has_value());
    if (f.k_positive) expect_rel(*f.k_positive, ref.fit[8], kRel, "K+");
  }
  if (std::isnan(ref.fit[9])) {
    EXPECT_FALSE(f.k_negative.has_value());
  } else {
    EXPECT_TRUE(f.k_negative.has_value());
    if (f.k_negative) expect_rel(*f.k_negative, ref.fit[9], kRel, "K-");
  }
  if (std::isnan(ref.fit[12])) {
    EXPECT_FALSE(f.asymmetry_bias_dps.has_value());
  } else {
    EXPECT_TRUE(f.asymmetry_bias_dps.has_value());
    // B± is ~1e-3 °/s beside outputs of 500 °/s: absolute, as the residuals.
    if (f.asymmetry_bias_dps) {
      EXPECT_NEAR(*f.asymmetry_bias_dps, ref.fit[12], kResidualAbsDps) << "B of the split fit";
    }
  }
  expect_optional_ppm(f.asymmetry_ppm, ref.fit[10], "asymmetry");
  expect_optional_ppm(f.repeatability_ppm, ref.fit[11], "repeatability");
  EXPECT_EQ(f.residuals_dps.size(), ref.residuals.size());
  for (std::size_t i = 0; i < std::min(f.residuals_dps.size(), ref.residuals.size()); ++i) {
    EXPECT_NEAR(f.residuals_dps[i], ref.residuals[i], kResidualAbsDps) << "residual " << i;
  }
  EXPECT_EQ(f.repetitions.size(), ref.repetitions.size());
  for (std::size_t i = 0; i < std::min(f.repetitions.size(), ref.repetitions.size()); ++i) {
    EXPECT_EQ(f.repetitions[i].repetition, ref.repetitions[i].repetition);
    expect_rel(f.repetitions[i].k, ref.repetitions[i].k, kRel, "repetition K");
    expect_rel(f.repetitions[i].bias_dps, ref.repetitions[i].bias_dps, kRel, "repetition B");
  }
  return f;
}

TEST(ScaleFactor, NoiseFreeBothDirectionsMatchNumpy) { check_case("clean"); }
TEST(ScaleFactor, ThreeNoisyRepetitionsMatchNumpy) {
  const ScaleFactorFit f = check_case("noisy_3rep");
  EXPECT_EQ(f.repetitions.size(), 3u);
  EXPECT_EQ(f.distinct_rates, 14u);
  EXPECT_TRUE(f.repeatability_ppm.has_value());
}
TEST(ScaleFactor, ZeroRatePointMatchesNumpy) { check_case("zero_rate"); }
TEST(ScaleFactor, ExactlyTwoPointsMatchNumpy) {
  const ScaleFactorFit f = check_case("two_points");
  EXPECT_TRUE(std::isnan(f.k_std_error));
  EXPECT_TRUE(std::isnan(f.residual_std_dps));
}
TEST(ScaleFactor, OneDirectionOnlyMatchesNumpy) {
  const ScaleFactorFit f = check_case("positive_only");
  EXPECT_FALSE(f.asymmetry_ppm.has_value());
  EXPECT_TRUE(f.repeatability_ppm.has_value());
}
TEST(ScaleFactor, OneUsableRepetitionMatchesNumpy) {
  const ScaleFactorFit f = check_case("one_usable_repetition");
  EXPECT_EQ(f.repetitions.size(), 1u);
  EXPECT_FALSE(f.repeatability_ppm.has_value());
}

// The noise-free model output = K(1 + A/2·sign Ω)Ω + QΩ² + B on the
// symmetric rate set ±{1, 5, 10, 50, 100, 200, 500}: |Ω| and Ω² are even, so
// the line's slope is K exactly and the even terms go to the intercept and
// the residuals. In the split fit both directions see Q·|Ω|² against |Ω|:
// the slope of that regression, c = Σ(|Ω| − mean|Ω|)·Ω² / Σ(|Ω| − mean|Ω|)²
// over one direction, adds to K₊ and subtracts from K₋.
TEST(ScaleFactor, NoiseFreeModelRecoveredInClosedForm) {
  const double k = 1.00025, b = 0.0021, a = 300e-6, q = 4e-8;
  const double magnitudes[] = {1, 5, 10, 50, 100, 200, 500};
  std::vector<RatePoint> points;
  for (double sign : {-1.0, 1.0}) {
    for (double m : magnitudes) {
      const double w = sign * m;
      points.push_back({w, k * (1 + a / 2 * sign) * w + q * w * w + b});
    }
  }
  double s1 = 0, s2 = 0;  // Σ|Ω|, ΣΩ² over one direction
  for (double m : magnitudes) {
    s1 += m;
    s2 += m * m;
  }
  const double mean_abs = s1 / 7, mean_sq = s2 / 7;
  double sxx = 0, sxy = 0;
  for (double m : magnitudes) {
    sxx += (m - mean_abs) * (m - mean_abs);
    sxy += (m - mean_abs) * m * m;
  }
  const double c = sxy / sxx;
  const double b_fit = b + k * a / 2 * mean_abs + q * mean_sq;
  const double k_pos = k * (1 + a / 2) + q * c;
  const double k_neg = k * (1 - a / 2) - q * c;
  const double b_split = b + q * (mean_sq - c * mean_abs);

  auto fit = fit_scale_factor(points);
  ASSERT_TRUE(fit) << fit.error().message;
  EXPECT_NEAR(fit->k, k, 1e-9 * k);
  EXPECT_NEAR(fit->bias_dps, b_fit, 1e-9 * b_fit);
  for (std::size_t i = 0; i < points.size(); ++i) {
    const double w = points[i].rate_dps;
    const double want = k * a / 2 * (std::fabs(w) - mean_abs) + q * (w * w - mean_sq);
    EXPECT_NEAR(fit->residuals_dps[i], want, kResidualAbsDps) << "rate " << w;
  }
  // The largest |residual| / |KΩ| is at ±1 °/s (residual ≈ −(K·A/2·mean|Ω| + Q·mean Ω²)).
  const double r1 = k * a / 2 * (1 - mean_abs) + q * (1 - mean_sq);
  EXPECT_NEAR(fit->nonlinearity_ppm, std::fabs(r1) / k * 1e6, 1e-9 * std::fabs(r1) / k * 1e6);
  ASSERT_TRUE(fit->k_positive && fit->k_negative && fit->asymmetry_ppm && fit->asymmetry_bias_dps);
  EXPECT_NEAR(*fit->k_positive, k_pos, 1e-9 * k_pos);
  EXPECT_NEAR(*fit->k_negative, k_neg, 1e-9 * k_neg);
  EXPECT_NEAR(*fit->asymmetry_bias_dps, b_split, kResidualAbsDps);
  const double asym_ppm = (k_pos - k_neg) / ((k_pos + k_neg) / 2) * 1e6;
  EXPECT_NEAR(*fit->asymmetry_ppm, asym_ppm, 1e-9 * asym_ppm);
  // The quadratic's share: 2Q·c / K, about 39.6 ppm with Q = 4e-8 (°/s)⁻¹.
  EXPECT_NEAR(*fit->asymmetry_ppm - a * 1e6, 2 * q * c / k * 1e6, 1e-3);
  EXPECT_FALSE(fit->repeatability_ppm.has_value());  // one repetition
}

// A pure asymmetry, output = K(1 ± A/2)Ω + B, is recovered exactly: on the
// symmetric set of the docs and on lopsided sets (more, and other, rates on
// one side; a zero-rate point).
TEST(ScaleFactor, TrueAsymmetryRecoveredExactly) {
  const double k = 1.00025, b = 0.0021, a = 300e-6;
  const std::vector<std::vector<double>> rate_sets = {
      {-500, -200, -100, -50, -10, -5, -1, 1, 5, 10, 50, 100, 200, 500},
      {-100, -10, 1, 5, 50, 300, 500},
      {-7, 0, 2, 20, 200},
      {-500, -3, 400},
  };
  for (const auto& rates : rate_sets) {
    SCOPED_TRACE("rates from " + std::to_string(rates.front()) + " to " +
                 std::to_string(rates.back()) + ", " + std::to_string(rates.size()) + " points");
    std::vector<RatePoint> points;
    for (double w : rates) {
      const double sign = w > 0 ? 1.0 : (w < 0 ? -1.0 : 0.0);
      points.push_back({w, k * (1 + a / 2 * sign) * w + b});
    }
    auto fit = fit_scale_factor(points);
    ASSERT_TRUE(fit) << fit.error().message;
    ASSERT_TRUE(fit->asymmetry_ppm && fit->k_positive && fit->k_negative &&
                fit->asymmetry_bias_dps);
    EXPECT_NEAR(*fit->asymmetry_ppm, 300.0, 1e-9 * 300.0);
    EXPECT_NEAR(*fit->k_positive, k * (1 + a / 2), 1e-12);
    EXPECT_NEAR(*fit->k_negative, k * (1 - a / 2), 1e-12);
    EXPECT_NEAR(*fit->asymmetry_bias_dps, b, 1e-12);
  }
}

TEST(ScaleFactor, AsymmetryNeedsBothDirectionsAndThreeRates) {
  // +a and −b only: K₊, K₋ and B are not separately determined.
  std::vector<RatePoint> points = {{-50, -50.01}, {200, 200.03}, {-50, -50.012}};
  auto fit = fit_scale_factor(points);
  ASSERT_TRUE(fit) << fit.error().message;
  EXPECT_FALSE(fit->asymmetry_ppm.has_value());
  EXPECT_FALSE(fit->k_positive.has_value());
  // A third rate on either side (or zero) makes it determined.
  points.push_back({0, 0.002});
  fit = fit_scale_factor(points);
  ASSERT_TRUE(fit) << fit.error().message;
  EXPECT_TRUE(fit->asymmetry_ppm.has_value());
  // One direction only, however many rates: none.
  fit = fit_scale_factor(std::vector<RatePoint>{{1, 1.0}, {10, 10.01}, {100, 100.02}, {0, 0}});
  ASSERT_TRUE(fit) << fit.error().message;
  EXPECT_FALSE(fit->asymmetry_ppm.has_value());
}

TEST(ScaleFactor, PureLineRecoveredExactly) {
  std::vector<RatePoint> points;
  for (double w : {-500.0, -200.0, -100.0, -50.0, -10.0, -5.0, -1.0, 1.0, 5.0, 10.0, 50.0, 100.0,
                   200.0, 500.0}) {
    points.push_back({w, 0.99987 * w - 0.0035});
  }
  auto fit = fit_scale_factor(points);
  ASSERT_TRUE(fit) << fit.error().message;
  EXPECT_NEAR(fit->k, 0.99987, 1e-12);
  EXPECT_NEAR(fit->bias_dps, -0.0035, 1e-12);
  EXPECT_NEAR(fit->bias_dph, -0.0035 * 3600, 1e-9);
  EXPECT_LT(fit->nonlinearity_ppm, 1e-6);
  ASSERT_TRUE(fit->asymmetry_ppm.has_value());
  EXPECT_LT(std::fabs(*fit->asymmetry_ppm), 1e-6);
}

TEST(ScaleFactor, ConstantRateIsRefused) {
  const std::vector<RatePoint> points = {{100, 100.01}, {100, 100.02}, {100, 100.03}};
  auto fit = fit_scale_factor(points);
  ASSERT_FALSE(fit);
  EXPECT_NE(fit.error().message.find("2 distinct rates"), std::string::npos) << fit.error().message;
  EXPECT_FALSE(fit.error().transient);
}

TEST(ScaleFactor, NoPointsIsRefused) {
  auto fit = fit_scale_factor({});
  ASSERT_FALSE(fit);
  EXPECT_NE(fit.error().message.find("no rate points"), std::string::npos);
}

TEST(ScaleFactor, NonFiniteInputIsRefusedNamingPointAndField) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<RatePoint> points = {{-10, -10.0}, {10, 10.0}, {100, 100.0}};
  points[2].output_dps = nan;
  auto fit = fit_scale_factor(points);
  ASSERT_FALSE(fit);
  EXPECT_NE(fit.error().message.find("point 2"), std::string::npos) << fit.error().message;
  EXPECT_NE(fit.error().message.find("output_dps"), std::string::npos) << fit.error().message;

  points[2].output_dps = 100;
  points[1].rate_dps = inf;
  fit = fit_scale_factor(points);
  ASSERT_FALSE(fit);
  EXPECT_NE(fit.error().message.find("point 1"), std::string::npos) << fit.error().message;
  EXPECT_NE(fit.error().message.find("rate_dps"), std::string::npos) << fit.error().message;

  points[1].rate_dps = 10;
  points[0].temperature_c = nan;
  fit = fit_scale_factor(points);
  ASSERT_FALSE(fit);
  EXPECT_NE(fit.error().message.find("temperature_c"), std::string::npos) << fit.error().message;
}

// ---- Rate points from CSV --------------------------------------------------------

TEST(RatePointsCsv, ReadsRequiredAndOptionalColumnsInAnyOrder) {
  const std::string text =
      "note, output_dps ,temperature_c,rate_dps,repetition\r\n"
      "a,-10.002,25.5,-10,1\r\n"
      "\r\n"
      "b,+10.001,25.5,10,2\r\n";
  auto csv = parse_rate_points_csv(text, "sf.csv");
  ASSERT_TRUE(csv) << csv.error().message;
  EXPECT_TRUE(csv->has_repetition);
  EXPECT_TRUE(csv->has_temperature);
  ASSERT_EQ(csv->points.size(), 2u);
  EXPECT_EQ(csv->lines, (std::vector<std::size_t>{2, 4}));
  EXPECT_EQ(csv->points[0].rate_dps, -10);
  EXPECT_EQ(csv->points[0].output_dps, -10.002);
  EXPECT_EQ(csv->points[1].repetition, 2);
  EXPECT_EQ(csv->points[1].temperature_c, 25.5);

  csv = parse_rate_points_csv("rate_dps,output_dps\n1,1.0001\n", "min.csv");
  ASSERT_TRUE(csv) << csv.error().message;
  EXPECT_FALSE(csv->has_repetition);
  EXPECT_FALSE(csv->has_temperature);
  EXPECT_EQ(csv->points[0].repetition, 1);
}

TEST(RatePointsCsv, ErrorsNameFileLineAndColumn) {
  auto csv = parse_rate_points_csv("rate_dps,temperature_c\n1,25\n", "sf.csv");
  ASSERT_FALSE(csv);
  EXPECT_NE(csv.error().message.find("sf.csv:1: header lacks column(s) output_dps"),
            std::string::npos)
      << csv.error().message;
  csv = parse_rate_points_csv("rate_dps,output_dps\n1,1\n5,abc\n10,10\n", "sf.csv");
  ASSERT_FALSE(csv);
  EXPECT_NE(csv.error().message.find("sf.csv:3: column output_dps: 'abc' is not a number"),
            std::string::npos)
      << csv.error().message;
  csv = parse_rate_points_csv("rate_dps,output_dps,repetition\n1,1,1\n5,5,1.5\n", "sf.csv");
  ASSERT_FALSE(csv);
  EXPECT_NE(csv.error().message.find("sf.csv:3: column repetition: 1.5 is not a whole number"),
            std::string::npos)
      << csv.error().message;
  csv = parse_rate_points_csv("rate_dps,output_dps\n", "sf.csv");
  ASSERT_FALSE(csv);
  EXPECT_NE(csv.error().message.find("no data rows"), std::string::npos) << csv.error().message;
}

// ---- Over temperature -------------------------------------------------------

void check_temperature_case(const std::string& name) {
  SCOPED_TRACE("temperature case " + name);
  const auto it = references().temperature_cases.find(name);
  ASSERT_NE(it, references().temperature_cases.end()) << "no case " << name;
  const RefTemperatureCase& ref = it->second;
  auto fit = fit_scale_factor_over_temperature(ref.plateaus, ref.order);
  ASSERT_TRUE(fit) << fit.error().message;
  EXPECT_EQ(fit->order, ref.order);
  EXPECT_EQ(fit->temperatures, ref.plateaus.size());
  expect_rel(fit->temperature_mean_c, ref.t_mean_c, 1e-15, "T mean");
  ASSERT_EQ(fit->k_coefficients.size(), ref.k_coef.size());
  ASSERT_EQ(fit->bias_coefficients_dph.size(), ref.b_coef.size());
  for (std::size_t j = 0; j < ref.k_coef.size(); ++j) {
    expect_rel(fit->k_coefficients[j], ref.k_coef[j], kRel, "K coefficient " + std::to_string(j));
    expect_rel(fit->bias_coefficients_dph[j], ref.b_coef[j], kRel,
               "B coefficient " + std::to_string(j));
  }
  expect_rel(fit->k_at_mean, ref.k_coef[0], kRel, "K(T mean)");
  expect_rel(fit->sf_temperature_coefficient_ppm_per_c, ref.sf_tc_ppm, kRel, "SF coefficient");
  expect_rel(fit->bias_temperature_coefficient_dph_per_c, ref.bias_tc_dph, kRel,
             "bias coefficient");
  ASSERT_EQ(fit->k_residuals.size(), ref.k_resid.size());
  for (std::size_t i = 0; i < ref.k_resid.size(); ++i) {
    // Residuals are differences of numbers near K ≈ 1 and B ≈ 7 °/h.
    EXPECT_NEAR(fit->k_residuals[i], ref.k_resid[i], 1e-14) << "K residual " << i;
    EXPECT_NEAR(fit->bias_residuals_dph[i], ref.b_resid[i], 1e-12) << "B residual " << i;
  }
}

TEST(ScaleFactorOverTemperature, TwoTemperaturesOrder1MatchNumpy) {
  check_temperature_case("t2_order1");
}
TEST(ScaleFactorOverTemperature, ThreeTemperaturesOrder1MatchNumpy) {
  check_temperature_case("t3_order1");
}
TEST(ScaleFactorOverTemperature, ThreeTemperaturesOrder2MatchNumpy) {
  check_temperature_case("t3_order2");
}
TEST(ScaleFactorOverTemperature, FiveTemperaturesOrder2MatchNumpy) {
  check_temperature_case("t5_order2");
}

TEST(ScaleFactorOverTemperature, LinearTruthGivesItsCoefficientsByHand) {
  // K = 1.0002 · (1 + 25e-6 (T − 20)), B = 6 + 0.04 (T − 20) °/h at −20, 20, 60 °C.
  std::vector<ScaleFactorAtTemperature> plateaus;
  for (double t : {-20.0, 20.0, 60.0}) {
    plateaus.push_back({t, 1.0002 * (1 + 25e-6 * (t - 20)), 6 + 0.04 * (t - 20)});
  }
  auto fit = fit_scale_factor_over_temperature(plateaus, 1);
  ASSERT_TRUE(fit) << fit.error().message;
  EXPECT_DOUBLE_EQ(fit->temperature_mean_c, 20.0);
  EXPECT_NEAR(fit->sf_temperature_coefficient_ppm_per_c, 25.0, 1e-9);
  EXPECT_NEAR(fit->bias_temperature_coefficient_dph_per_c, 0.04, 1e-12);
  EXPECT_NEAR(fit->k_at_mean, 1.0002, 1e-14);
}

TEST(ScaleFactorOverTemperature, RefusesBadOrdersAndInputs) {
  const std::vector<ScaleFactorAtTemperature> two = {{-20, 1.0, 6.0}, {60, 1.001, 7.0}};
  auto fit = fit_scale_factor_over_temperature(two, 2);
  ASSERT_FALSE(fit);
  EXPECT_NE(fit.error().message.find("order 2"), std::string::npos) << fit.error().message;
  EXPECT_FALSE(fit_scale_factor_over_temperature(two, 0));
  EXPECT_FALSE(fit_scale_factor_over_temperature(two, 3));
  // Three plateaus at two temperatures: order 2 is still undetermined.
  const std::vector<ScaleFactorAtTemperature> repeated = {
      {-20, 1.0, 6.0}, {60, 1.001, 7.0}, {60, 1.0011, 7.1}};
  EXPECT_FALSE(fit_scale_factor_over_temperature(repeated, 2));
  EXPECT_TRUE(fit_scale_factor_over_temperature(repeated, 1));
  std::vector<ScaleFactorAtTemperature> bad = two;
  bad[1].k = std::numeric_limits<double>::quiet_NaN();
  fit = fit_scale_factor_over_temperature(bad, 1);
  ASSERT_FALSE(fit);
  EXPECT_NE(fit.error().message.find("plateau 1"), std::string::npos) << fit.error().message;
}

// ---- Earth rate ---------------------------------------------------------------

TEST(EarthRateProjection, ByHand) {
  constexpr double kE = 15.041067;
  const double deg = std::numbers::pi / 180;
  // Along the table: Ω_E sin φ whatever the position.
  EXPECT_NEAR(earth_rate_projection_dph(45, SensitiveAxis::kAlongTable, 30, 123),
              kE * std::sqrt(0.5), 1e-12);
  EXPECT_NEAR(earth_rate_projection_dph(90, SensitiveAxis::kAlongTable, 0, 0), kE, 1e-12);
  EXPECT_NEAR(earth_rate_projection_dph(0, SensitiveAxis::kAlongTable, 0, 0), 0, 1e-12);
  EXPECT_NEAR(earth_rate_projection_dph(-30, SensitiveAxis::kAlongTable, 0, 0), -kE / 2, 1e-12);
  // Radial: Ω_E cos φ cos(heading + position).
  EXPECT_NEAR(earth_rate_projection_dph(60, SensitiveAxis::kRadial, 0, 0), kE / 2, 1e-12);
  EXPECT_NEAR(earth_rate_projection_dph(60, SensitiveAxis::kRadial, 0, 180), -kE / 2, 1e-12);
  EXPECT_NEAR(earth_rate_projection_dph(60, SensitiveAxis::kRadial, 30, 60), 0, 1e-12);
  EXPECT_NEAR(earth_rate_projection_dph(0, SensitiveAxis::kRadial, 90, 270), kE, 1e-12);
  EXPECT_NEAR(earth_rate_projection_dph(31.9, SensitiveAxis::kRadial, 10, 35),
              kE * std::cos(31.9 * deg) * std::sqrt(0.5), 1e-12);
}

TEST(SensitiveAxisNames, ParseAndPrint) {
  for (SensitiveAxis a : {SensitiveAxis::kAlongTable, SensitiveAxis::kRadial}) {
    auto parsed = parse_sensitive_axis(to_string(a));
    ASSERT_TRUE(parsed);
    EXPECT_EQ(*parsed, a);
  }
  auto bad = parse_sensitive_axis("tangential");
  ASSERT_FALSE(bad);
  EXPECT_NE(bad.error().message.find("tangential"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::analysis

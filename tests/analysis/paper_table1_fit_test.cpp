// The drift model against the paper: orders 1-4 of T fitted to the eight
// (temperature, mean bias) points of Table I, compared with numpy.polyfit
// (tools/reference/multirun_reference.py, data in
// tests/analysis/data/paper_table1_fit.txt). polyfit has an intercept, so
// the centred form is the matching model. Tolerance: 1e-9 relative in the
// fitted values (and in the coefficients and residual std: the equilibrated
// raw Vandermonde's condition number is at most ~170 at order 4, so the
// coefficients themselves are well determined numerically).
//
// Statistically, the 8 points do not support any order above 1: the
// residual std grows with the order (0.206, 0.226, 0.237, 0.266 deg/h), and
// order 4 leaves 3 degrees of freedom. The test states it.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "gyrotherm/analysis/drift_model.h"
#include "reference_data.h"

namespace gyrotherm::analysis {
namespace {

using testing::read_reference_lines;
using testing::Tokens;

AnalysisSeries table1_series(const std::vector<Tokens>& lines) {
  AnalysisSeries s;
  for (const Tokens& t : lines) {
    if (t[0] != "point") continue;
    s.t_s.push_back(static_cast<double>(s.t_s.size()));  // one point a second
    s.top_c.push_back(std::stod(t[1]));
    s.side_c.push_back(std::stod(t[1]));
    s.rate_dph.push_back(std::stod(t[2]));
  }
  return s;
}

TEST(PaperTable1Fit, OrdersOneToFourMatchPolyfit) {
  const std::vector<Tokens> lines =
      read_reference_lines("paper_table1_fit.txt", "tools/reference/multirun_reference.py");
  const AnalysisSeries s = table1_series(lines);
  ASSERT_EQ(s.t_s.size(), 8u);
  std::vector<double> residual_std(5, 0);
  std::size_t orders = 0;
  for (const Tokens& t : lines) {
    if (t[0] == "order") {
      const int order = std::stoi(t[1]);
      DriftModelSpec spec;
      spec.t_order = order;
      auto fit = fit_drift_model(s, spec, DriftModelForm::kCentered);
      ASSERT_TRUE(fit.ok()) << fit.error().message;
      residual_std[static_cast<std::size_t>(order)] = fit->residual_std_dph;
      const double expected = std::stod(t[3]);
      EXPECT_NEAR(fit->residual_std_dph, expected, 1e-9 * expected) << "order " << order;
      // The condition of the (centred, scaled) design the code solves stays small.
      EXPECT_LT(fit->condition_estimate, 100.0) << "order " << order;
      ++orders;
      continue;
    }
    if (t[0] != "coef" && t[0] != "fitted") continue;
    const int order = std::stoi(t[1]);
    SCOPED_TRACE(fmt::format("order {}", order));
    DriftModelSpec spec;
    spec.t_order = order;
    auto fit = fit_drift_model(s, spec, DriftModelForm::kCentered);
    ASSERT_TRUE(fit.ok()) << fit.error().message;
    if (t[0] == "coef") {
      ASSERT_EQ(t.size(), static_cast<std::size_t>(order) + 3);
      const double c0 = std::stod(t[2]);
      EXPECT_NEAR(fit->coefficients.at("intercept"), c0, 1e-9 * std::abs(c0));
      for (int i = 1; i <= order; ++i) {
        const double ci = std::stod(t[static_cast<std::size_t>(2 + i)]);
        EXPECT_NEAR(fit->coefficients.at(fmt::format("T{}", i)), ci, 1e-9 * std::abs(ci))
            << "T" << i;
      }
    } else {
      auto predicted = predict_drift(*fit, s);
      ASSERT_TRUE(predicted.ok()) << predicted.error().message;
      ASSERT_EQ(t.size(), 10u);
      for (std::size_t i = 0; i < 8; ++i) {
        const double expected = std::stod(t[2 + i]);
        EXPECT_NEAR((*predicted)[i], expected, 1e-9 * std::abs(expected)) << "point " << i;
      }
    }
  }
  EXPECT_EQ(orders, 4u);
  // No order above 1 is supported by the 8 points.
  for (std::size_t order = 2; order <= 4; ++order) {
    EXPECT_GT(residual_std[order], residual_std[order - 1]) << order;
  }
}

// More parameters than 8 points allow, and the paper form on the same points.
TEST(PaperTable1Fit, TooManyParametersForEightPointsIsAnError) {
  const AnalysisSeries s = table1_series(
      read_reference_lines("paper_table1_fit.txt", "tools/reference/multirun_reference.py"));
  auto fit = fit_drift_model(s, *parse_model_spec("T4+R4"), DriftModelForm::kCentered);
  ASSERT_FALSE(fit.ok());
  EXPECT_NE(fit.error().message.find("8 points for 9 parameters"), std::string::npos)
      << fit.error().message;
}

}  // namespace
}  // namespace gyrotherm::analysis

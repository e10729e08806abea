// Pieces of the calibration report (report.h): a stored fit read back for
// export and compensation, the CSV of Table I rows, the plots' JSON.
#include "gyrotherm/daemon/report.h"

#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

namespace gyrotherm::daemon {
namespace {

// A run's analysis series with a known drift in T, dT/dt and dT.
analysis::AnalysisSeries drifting_series() {
  analysis::AnalysisSeries s;
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.05);
  for (int i = 0; i < 4000; ++i) {
    const double t = i;
    const double temp = 20.0 + 15.0 * std::tanh((t - 2000.0) / 700.0);
    const double grad = 0.2 + 0.1 * std::sin(t / 300.0);
    s.t_s.push_back(t);
    s.top_c.push_back(temp + grad / 2);
    s.side_c.push_back(temp - grad / 2);
    s.rate_dph.push_back(7.5 + 0.02 * temp - 3e-4 * temp * temp + 0.8 * grad + noise(rng));
  }
  return s;
}

TEST(Report, AStoredFitReadsBackWithTheSameCoefficientsAndCompensation) {
  const auto series = drifting_series();
  const analysis::DriftModelSpec spec{.t_order = 2, .r_order = 1, .g_order = 1};
  for (auto form : {analysis::DriftModelForm::kPaper, analysis::DriftModelForm::kCentered}) {
    SCOPED_TRACE(std::string(analysis::to_string(form)));
    auto fit = analysis::fit_drift_model(series, spec, form);
    ASSERT_TRUE(fit) << fit.error().message;
    storage::FitRecord record = fit_record(*fit, {4}, {}, 1.0);
    record.id = 9;
    auto back = report_fit_of_record(record);
    ASSERT_TRUE(back) << back.error().message;
    EXPECT_EQ(back->stored_id, 9);
    EXPECT_EQ(back->run_ids, std::vector<int64_t>{4});
    EXPECT_EQ(back->fit.coefficients, fit->coefficients);
    EXPECT_EQ(back->fit.std_errors, fit->std_errors);
    EXPECT_EQ(back->fit.l0_dph, fit->l0_dph);
    EXPECT_EQ(back->fit.residual_std_dph, fit->residual_std_dph);
    // The export files of the stored fit are those of the fit itself.
    analysis::ExportInfo info;
    info.run_ids = {4};
    info.computed_utc = "2026-11-21T02:00:00.000Z";
    EXPECT_EQ(analysis::drift_fit_c_header(back->fit, info),
              analysis::drift_fit_c_header(*fit, info));
    // Compensating with the stored (physical) coefficients agrees with the
    // fit's own scaled evaluation to rounding.
    auto a = analysis::drift_terms(*fit, series);
    auto b = analysis::drift_terms(back->fit, series);
    ASSERT_TRUE(a && b);
    double worst = 0;
    for (std::size_t i = 0; i < a->size(); ++i)
      worst = std::max(worst, std::fabs((*a)[i] - (*b)[i]));
    EXPECT_LT(worst, 1e-9);
  }
}

TEST(Report, AStoredFitThatDoesNotParseIsNamed) {
  storage::FitRecord record;
  record.id = 3;
  record.model = "T2";
  record.form = "paper";
  record.coefficients_json = R"({"T1": 0.1})";  // T2 missing
  record.standard_errors_json = "{}";
  record.inputs_json = "{}";
  auto r = report_fit_of_record(record);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("stored fit 3"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("T2"), std::string::npos) << r.error().message;
  record.model = "T9";
  auto bad_model = report_fit_of_record(record);
  ASSERT_FALSE(bad_model);
  EXPECT_NE(bad_model.error().message.find("T9"), std::string::npos);
}

TEST(Report, Table1CsvReadsBackExactly) {
  storage::SegmentStatsRecord r;
  r.run_id = 2;
  r.segment_index = 2;
  r.setpoint_c = -20;
  r.n = 7200;
  r.duration_s = 7200;
  r.temp_mean_c = -19.987654321012345;
  r.bias_mean_dph = 0.1 + 0.2;  // not representable in few digits
  r.bias_std_dph = 1.0 / 3.0;
  r.bias_std_ma_dph = std::nan("");
  r.bias_mean_earth_removed_dph = -7.123456789012345e-3;
  r.computed_utc = "2026-11-21T02:00:00.000Z";
  std::istringstream in(table1_csv({r}));
  std::string header, line;
  std::getline(in, header);
  std::getline(in, line);
  EXPECT_EQ(header.substr(0, 21), "run_id,step,segment_i");
  std::vector<std::string> f;
  std::stringstream ls(line);
  for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
  ASSERT_GE(f.size(), 11u);
  EXPECT_EQ(f[0], "2");
  EXPECT_EQ(f[1], "3");  // step numbers are 1-based
  EXPECT_EQ(std::stod(f[4]), r.temp_mean_c);
  EXPECT_EQ(std::stod(f[7]), r.bias_mean_dph);
  EXPECT_EQ(std::stod(f[8]), r.bias_mean_earth_removed_dph);
  EXPECT_EQ(std::stod(f[9]), r.bias_std_dph);
  EXPECT_EQ(f[10], "") << "a value that could not be computed is an empty field";
}

TEST(Report, PlotsJsonKeepsGapsAndCannotCloseTheScriptElement) {
  Plot p;
  p.id = "chart-x";
  p.title = "</script><script>alert(1)</script>";
  PlotSeries s;
  s.label = "a";
  s.x = {1, 2, 3};
  s.y = {0.5, std::nan(""), 1.2345678912345};
  p.series.push_back(s);
  const std::string text = plots_json({p});
  const auto j = nlohmann::json::parse(text);
  EXPECT_TRUE(j["charts"][0]["series"][0]["y"][1].is_null());
  EXPECT_NEAR(j["charts"][0]["series"][0]["y"][2].get<double>(), 1.2345678912345, 1e-6);
  EXPECT_EQ(j["charts"][0]["title"], p.title);
  EXPECT_EQ(text.find("</"), std::string::npos) << text;
}

}  // namespace
}  // namespace gyrotherm::daemon

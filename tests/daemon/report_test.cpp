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

// Issue 15 item 3: the daemon stores the centred fit first, the campaign's
// joint fit (drift-fit.json / drift-fit.h) and the start model are centred,
// the paper's form is labelled as the paper's, and a coefficient within 2
// standard errors of zero is warned about under its table (and only then).
analysis::AnalysisSeries started_at(double t0_c, double t_offset_s, unsigned seed) {
  analysis::AnalysisSeries s;
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.05);
  for (int i = 0; i < 3000; ++i) {
    const double t = t_offset_s + i;
    const double temp = t0_c + 12.0 * std::tanh(i / 900.0) + 0.8 * std::sin(i / 150.0);
    const double grad = 0.2 + 0.1 * std::sin(i / 230.0);
    s.t_s.push_back(t);
    s.top_c.push_back(temp + grad / 2);
    s.side_c.push_back(temp - grad / 2);
    s.rate_dph.push_back(7.5 + 0.004 * temp - 1e-4 * temp * temp + 0.8 * grad + noise(rng));
  }
  return s;
}

TEST(Report, DefaultsAreTheCentredFormAndThePapersIsLabelled) {
  EXPECT_EQ(AnalysisSettings{}.forms.front(), analysis::DriftModelForm::kCentered);
  std::vector<RunReport> runs;
  for (int k = 0; k < 5; ++k) {
    RunReport r;
    r.run.id = k + 1;
    r.settings.model = {.t_order = 2, .g_order = 1};
    r.series = started_at(-15.0 + 15.0 * k, 1e4 * k, 11 + k);
    runs.push_back(std::move(r));
  }
  ReportOptions options;
  options.generated_utc = "2026-11-21T02:00:00.000Z";
  const CampaignReport c = collect_campaign_report(runs, options);
  ASSERT_TRUE(c.joint_fit) << c.joint_fit_error;
  EXPECT_EQ(c.joint_fit->fit.form, analysis::DriftModelForm::kCentered);
  ASSERT_TRUE(c.start_model) << c.start_model_note;
  EXPECT_EQ(c.start_model->form, analysis::DriftModelForm::kCentered);
  ASSERT_TRUE(c.comparison) << c.comparison_error;
  EXPECT_EQ(c.comparison->options.smooth_points, 101u);
  std::string header, index;
  for (const auto& f : render_campaign_files(c, options)) {
    if (f.path == "drift-fit.h") header = f.content;
    if (f.path == "index.html") index = f.content;
  }
  EXPECT_NE(header.find("intercept"), std::string::npos) << header;
  EXPECT_NE(header.find("Centred form"), std::string::npos) << header;
  EXPECT_EQ(header.find("Paper form"), std::string::npos) << header;
  EXPECT_NE(index.find("101-point centred moving average"), std::string::npos);

  // A run's report: the centred fit is clean; the paper's form is labelled
  // and (forced) a coefficient within 2 SE of zero is flagged.
  RunReport r = runs.front();
  auto centred =
      analysis::fit_drift_model(*r.series, r.settings.model, analysis::DriftModelForm::kCentered);
  ASSERT_TRUE(centred) << centred.error().message;
  // (forced) every coefficient 10 standard errors from zero: no warning.
  for (auto& [name, se] : centred->std_errors) se = std::abs(centred->coefficients.at(name)) / 10;
  ASSERT_TRUE(analysis::near_zero_coefficients(*centred).empty());
  auto paper =
      analysis::fit_drift_model(*r.series, r.settings.model, analysis::DriftModelForm::kPaper);
  ASSERT_TRUE(paper) << paper.error().message;
  paper->std_errors["G1"] = std::abs(paper->coefficients.at("G1")) / 1.9;  // 1.9 SE from zero
  r.fits = {{.fit = *centred, .run_ids = {1}}, {.fit = *paper, .run_ids = {1}}};
  std::string html;
  for (const auto& f : render_run_files(r, options)) {
    if (f.path.find("report.html") != std::string::npos) html = f.content;
  }
  ASSERT_FALSE(html.empty());
  EXPECT_NE(html.find("the paper&#39;s form"), std::string::npos);
  const auto warning = html.find("Warning: G1 within 2 standard errors of zero");
  EXPECT_NE(warning, std::string::npos);
  EXPECT_EQ(html.find("Warning:", warning + 1), std::string::npos) << "only the paper fit warns";
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

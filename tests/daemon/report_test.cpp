// Pieces of the calibration report (report.h): a stored fit read back for
// export and compensation, the CSV of Table I rows, the plots' JSON.
#include "gyrotherm/calibration/report.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <unistd.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <regex>
#include <set>
#include <span>
#include <sstream>

#include "test_files.h"

namespace gyrotherm::calibration {
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

ReportOptions fixed_time() {
  ReportOptions o;
  o.generated_utc = "2026-11-24T00:00:00Z";
  return o;
}

// A soak's Table I row as stored.
storage::SegmentStatsRecord soak_row(int64_t run_id, int segment, double setpoint_c,
                                     double bias_dph) {
  storage::SegmentStatsRecord r;
  r.run_id = run_id;
  r.segment_index = segment;
  r.setpoint_c = setpoint_c;
  r.n = 3600;
  r.duration_s = 3600;
  r.temp_mean_c = setpoint_c + 0.25;
  r.bias_mean_dph = bias_dph;
  r.bias_std_dph = 0.05;
  r.bias_std_ma_dph = 0.007;
  r.bias_mean_earth_removed_dph = bias_dph - 7.95;
  r.bin_s = 1;
  r.ma_window = 101;
  r.earth_rate_dph = 7.95;
  return r;
}

const ReportFile* find_file(const std::vector<ReportFile>& files, const std::string& path) {
  for (const auto& f : files) {
    if (f.path == path) return &f;
  }
  return nullptr;
}

// The CSV's rows as field lists (no quoted fields in these files).
std::vector<std::vector<std::string>> csv_rows(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
    if (!line.empty() && line.back() == ',') f.push_back("");
    rows.push_back(f);
  }
  return rows;
}

TEST(Report, RepeatedSetpointsGetThePapersTableIGroupedBySetpoint) {
  // One run that visits 20 °C three times and 40 °C once.
  RunReport r;
  r.run.id = 5;
  r.table1 = {soak_row(5, 0, 20, 7.0), soak_row(5, 2, 40, 8.0), soak_row(5, 4, 20, 7.2),
              soak_row(5, 6, 20, 7.4)};
  // The 20 °C soaks' own uncertainties (u, dof); the 40 °C soak has none.
  r.table1[0].bias_u = storage::BiasUncertainty{.u_dph = 0.01, .dof = 10};
  r.table1[2].bias_u = storage::BiasUncertainty{.u_dph = 0.02, .dof = 20};
  r.table1[3].bias_u = storage::BiasUncertainty{.u_dph = 0.02, .dof = 1e6};
  r.table1[1].bias_u_note = "no noise model: too short";
  const auto files = render_run_files(r, fixed_time());
  const ReportFile* csv = find_file(files, "run-0005/table1-by-setpoint.csv");
  ASSERT_NE(csv, nullptr) << "no run-0005/table1-by-setpoint.csv";
  const auto rows = csv_rows(csv->content);
  ASSERT_EQ(rows.size(), 3u) << csv->content;
  ASSERT_EQ(rows[0][0], "setpoint_c");
  ASSERT_EQ(rows[0].size(), 23u);
  ASSERT_EQ(rows[1].size(), 23u);
  ASSERT_EQ(rows[2].size(), 23u);
  EXPECT_EQ(rows[0][17], "bias_mean_u_dph");
  EXPECT_EQ(rows[0][22], "bias_mean_u_note");
  // The mean of the three 20 °C biases, by hand: u = sqrt(0.01² + 0.02² +
  // 0.02²) / 3 = 0.01; Welch-Satterthwaite nu = u⁴ / sum((u_i / 3)⁴ / nu_i)
  // = 81 / (0.1 + 0.8 + 1.6e-5) = 89.998...; k the Student t quantile for it.
  EXPECT_NEAR(std::stod(rows[1][17]), 0.01, 1e-15);
  EXPECT_NEAR(std::stod(rows[1][20]), 81 / 0.900016, 1e-9);
  EXPECT_NEAR(std::stod(rows[1][19]), 1.98667, 1e-4);  // t(0.975, 90)
  EXPECT_NEAR(std::stod(rows[1][18]), std::stod(rows[1][19]) * 0.01, 1e-15);
  EXPECT_EQ(rows[1][21], "0");
  EXPECT_EQ(rows[1][22], "");
  // 40 °C: none, and why.
  EXPECT_EQ(rows[2][17], "");
  EXPECT_EQ(rows[2][18], "");
  EXPECT_EQ(rows[2][22], "soak 1 has no uncertainty of its mean: no noise model: too short");
  // 20 °C: biases 7.0, 7.2, 7.4: mean 7.2, sample std 0.2 (by hand).
  EXPECT_EQ(rows[1][0], "20");
  EXPECT_EQ(rows[1][1], "3");
  EXPECT_NEAR(std::stod(rows[1][2]), 20.25, 1e-12);  // temperature mean
  EXPECT_NEAR(std::stod(rows[1][3]), 0.0, 1e-12);    // temperature spread
  EXPECT_NEAR(std::stod(rows[1][5]), 7.2, 1e-12);
  EXPECT_NEAR(std::stod(rows[1][6]), 0.2, 1e-12);
  EXPECT_EQ(rows[1][7], "3");
  // 40 °C: one soak, no spread.
  EXPECT_EQ(rows[2][0], "40");
  EXPECT_EQ(rows[2][1], "1");
  EXPECT_EQ(std::stod(rows[2][5]), 8.0);
  EXPECT_EQ(rows[2][6], "");
  const ReportFile* html = find_file(files, "run-0005/report.html");
  ASSERT_NE(html, nullptr);
  EXPECT_NE(html->content.find("id=\"table1-by-setpoint\""), std::string::npos);
  EXPECT_NE(
      html->content.find(fmt::format("<td class=\"num\">{:.4f}</td>", std::stod(rows[1][18]))),
      std::string::npos);
  EXPECT_NE(html->content.find("title=\"soak 1 has no uncertainty of its mean"), std::string::npos);

  // Without a repeated set point a run's page keeps its one table.
  RunReport single;
  single.run.id = 6;
  single.table1 = {soak_row(6, 0, 20, 7.0), soak_row(6, 2, 40, 8.0)};
  const auto single_files = render_run_files(single, ReportOptions{});
  EXPECT_EQ(find_file(single_files, "run-0006/table1-by-setpoint.csv"), nullptr);

  // The campaign summary groups the soaks of every run: 20 °C from both runs.
  CampaignReport c;
  c.runs = {r, single};
  const auto campaign = render_campaign_files(c, ReportOptions{});
  const ReportFile* all = find_file(campaign, "table1-by-setpoint.csv");
  ASSERT_NE(all, nullptr) << "no table1-by-setpoint.csv in the campaign";
  const auto all_rows = csv_rows(all->content);
  ASSERT_EQ(all_rows.size(), 3u) << all->content;
  EXPECT_EQ(all_rows[1][1], "4");
  EXPECT_NEAR(std::stod(all_rows[1][5]), 7.15, 1e-12);  // 7.0, 7.2, 7.4, 7.0
  EXPECT_NEAR(std::stod(all_rows[1][6]), std::sqrt(0.11 / 3), 1e-12);
  EXPECT_EQ(all_rows[2][1], "2");
  const ReportFile* index = find_file(campaign, "index.html");
  ASSERT_NE(index, nullptr);
  EXPECT_NE(index->content.find("Table I — by set point"), std::string::npos);
}

// Runs `cmd` through the shell; its exit status, and stderr in `log`.
int run_logged(const std::string& cmd, const std::filesystem::path& log, std::string* text) {
  const int st = std::system((cmd + " 2>'" + log.string() + "'").c_str());
  *text = testing::read_text(log);
  return st;
}

TEST(Report, CHeadersWithAHostileStationNameCompileInOneTranslationUnit) {
  // A station name and a gyro serial that try to close the comment, open a
  // nested one, and start lines of their own.
  const std::string hostile = "Lab */ #error closed /* nested\n#error injected\r\n */";
  const auto series = drifting_series();
  const analysis::DriftModelSpec spec{.t_order = 2, .r_order = 1, .g_order = 1};
  RunReport r;
  r.run.id = 7;
  r.station_name = hostile;
  for (auto form : {analysis::DriftModelForm::kPaper, analysis::DriftModelForm::kCentered}) {
    auto fit = analysis::fit_drift_model(series, spec, form);
    ASSERT_TRUE(fit) << fit.error().message;
    r.fits.push_back(ReportFit{.fit = *fit, .stored_id = 0, .run_ids = {7}});
  }
  const auto run_files = render_run_files(r, fixed_time());
  CampaignReport c;
  c.station_name = hostile;
  c.joint_fit = r.fits.front();
  const auto campaign_files = render_campaign_files(c, ReportOptions{});
  analysis::ExportInfo info;
  info.station = hostile;
  info.gyro_serial = "SN*/1\n#error serial";
  info.computed_utc = "2026-11-24T00:00:00Z ?\?/";  // a trigraph at the end of its line

  std::string tmpl = (std::filesystem::temp_directory_path() / "gyrotherm-hdr-XXXXXX").string();
  ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
  const std::filesystem::path dir = tmpl;
  std::vector<std::pair<std::string, std::string>> headers;  // file name, text
  for (const char* path : {"run-0007/drift-fit-paper.h", "run-0007/drift-fit-centered.h"}) {
    const ReportFile* f = find_file(run_files, path);
    ASSERT_NE(f, nullptr) << path;
    headers.emplace_back(std::filesystem::path(path).filename().string(), f->content);
  }
  const ReportFile* joint = find_file(campaign_files, "drift-fit.h");
  ASSERT_NE(joint, nullptr);
  headers.emplace_back("drift-fit.h", joint->content);
  headers.emplace_back("serial.h", analysis::drift_fit_c_header(r.fits.back().fit, info, "serial"));

  std::string main_c;
  std::set<std::string> guards;
  for (const auto& [name, text] : headers) {
    SCOPED_TRACE(name);
    // The leading comment: every line opens it or continues it with " *";
    // the text of the station cannot end it early.
    std::istringstream lines(text);
    std::string line;
    std::getline(lines, line);
    EXPECT_EQ(line.rfind("/* ", 0), 0u) << line;
    while (std::getline(lines, line) && line != " */") {
      EXPECT_EQ(line.rfind(" *", 0), 0u)
          << "a comment line that does not continue the comment: " << line;
      EXPECT_EQ(line.find("*/"), std::string::npos) << line;
    }
    std::smatch m;
    ASSERT_TRUE(std::regex_search(text, m, std::regex(R"(#ifndef (\w+)\n#define (\w+)\n)")))
        << text;
    EXPECT_EQ(m[1].str(), m[2].str());
    EXPECT_TRUE(guards.insert(m[1].str()).second) << "include guard " << m[1] << " used twice";
    ASSERT_TRUE(std::regex_search(text, m, std::regex(R"(static inline double (\w+)_terms\()")))
        << text;
    std::ofstream(dir / name) << text;
    main_c += fmt::format("#include \"{}\"\n", name);
    main_c += fmt::format(
        "double call_{0}(void);\ndouble call_{0}(void) {{ return {0}_terms(20.0, "
        "0.001, 0.5); }}\n",
        m[1].str());
  }
  std::ofstream(dir / "main.c") << main_c;
  std::string log;
  const std::string c99 = fmt::format(
      "cc -std=c99 -Wall -Wextra -pedantic -Werror -c '{0}/main.c' -o '{0}/main.o'", dir.string());
  EXPECT_EQ(run_logged(c99, dir / "cc.log", &log), 0) << c99 << "\n" << log << "\n" << main_c;
  const std::string cxx = fmt::format(
      "g++ -x c++ -std=c++17 -Wall -Wextra -pedantic -Werror -c '{0}/main.c' -o '{0}/main_cxx.o'",
      dir.string());
  EXPECT_EQ(run_logged(cxx, dir / "cxx.log", &log), 0) << cxx << "\n" << log;
  if (!::testing::Test::HasFailure()) std::filesystem::remove_all(dir);
}

// report.js's tick labels: node's test runner on tests/browser/report_format.test.mjs.
TEST(Report, ScriptTickLabelsKeepTheDigitsOfTheirStep) {
  const std::filesystem::path dir =
      std::filesystem::temp_directory_path() / fmt::format("gyrotherm-node-{}", ::getpid());
  std::filesystem::create_directories(dir);
  ASSERT_EQ(std::system("command -v node >/dev/null 2>&1"), 0)
      << "node is not on PATH; run scripts/install-deps";
  std::string log;
  const std::string cmd = fmt::format("node --test '{}/tests/browser/report_format.test.mjs' >'{}'",
                                      GYROTHERM_SOURCE_DIR, (dir / "out.log").string());
  const int st = run_logged(cmd, dir / "err.log", &log);
  EXPECT_EQ(st, 0) << cmd << "\n" << testing::read_text(dir / "out.log") << log;
  std::filesystem::remove_all(dir);
}

// The mean of the `window` points centred on each point (NaN where the window
// does not fit), summed directly: the reference for the smoothed figures.
std::vector<double> centred_average(const std::vector<double>& y, std::size_t window) {
  const std::size_t half = window / 2;
  std::vector<double> out(y.size(), std::nan(""));
  for (std::size_t i = half; i + half < y.size(); ++i) {
    double sum = 0;
    for (std::size_t j = i - half; j <= i + half; ++j) sum += y[j];
    out[i] = sum / static_cast<double>(window);
  }
  return out;
}

const PlotSeries* find_series(const Plot& p, const std::string& label) {
  for (const auto& s : p.series) {
    if (s.label == label) return &s;
  }
  return nullptr;
}

void expect_same_curve(const std::vector<double>& got, const std::vector<double>& want,
                       const std::string& what) {
  ASSERT_EQ(got.size(), want.size()) << what;
  std::size_t checked = 0;
  for (std::size_t i = 0; i < want.size(); ++i) {
    if (std::isnan(want[i])) {
      EXPECT_TRUE(std::isnan(got[i])) << what << " point " << i << ": " << got[i];
      continue;
    }
    ASSERT_NEAR(got[i], want[i], 1e-9) << what << " point " << i;
    ++checked;
  }
  EXPECT_GT(checked, want.size() / 2) << what;
}

TEST(Report, Figures4And6DrawTheMovingAverageOverAFaintRawOutput) {
  const auto series = drifting_series();
  auto cmp = analysis::compare_models(std::span(&series, 1));
  ASSERT_TRUE(cmp) << cmp.error().message;
  for (auto terms : {analysis::TermSet::kT, analysis::TermSet::kTGR}) {
    SCOPED_TRACE(std::string(analysis::to_string(terms)));
    std::vector<std::string> problems;
    const Plot p = output_plot(series, *cmp, terms, "chart-output", "Fig.", 10000, 101, problems);
    EXPECT_TRUE(problems.empty()) << problems.front();
    // The raw 1 s output stays, as faint dots under the lines.
    const PlotSeries* raw = find_series(p, "raw (1 s bins)");
    ASSERT_NE(raw, nullptr) << "no faint raw series";
    EXPECT_EQ(raw->style, "points");
    EXPECT_EQ(raw->y, series.rate_dph);
    // The lines are the 101-point moving averages (Table I's last column).
    const PlotSeries* smooth = find_series(p, "raw, 101-point moving average");
    ASSERT_NE(smooth, nullptr) << "no smoothed raw output";
    EXPECT_EQ(smooth->style, "line");
    expect_same_curve(smooth->y, centred_average(series.rate_dph, 101), "raw average");
    int compensated = 0;
    for (const auto& cell : cmp->cells) {
      if (cell.terms != terms || (cell.order != 2 && cell.order != 4) || !cell.fit) continue;
      const std::string label =
          fmt::format("compensated, {}, 101-point moving average", analysis::to_string(cell.spec));
      const PlotSeries* c = find_series(p, label);
      ASSERT_NE(c, nullptr) << "no series " << label;
      EXPECT_EQ(c->style, "line");
      auto drift = analysis::drift_terms(*cell.fit, series);
      ASSERT_TRUE(drift);
      std::vector<double> out(series.rate_dph.size());
      for (std::size_t i = 0; i < out.size(); ++i) out[i] = series.rate_dph[i] - (*drift)[i];
      expect_same_curve(c->y, centred_average(out, 101), label);
      ++compensated;
    }
    EXPECT_EQ(compensated, 2);
    // Every line is drawn over the dots: nothing but the raw output is a raw series.
    for (const auto& s : p.series) {
      if (s.axis == "y" && &s != raw) {
        EXPECT_NE(s.style, "points") << s.label;
      }
    }
  }
}

}  // namespace
}  // namespace gyrotherm::calibration

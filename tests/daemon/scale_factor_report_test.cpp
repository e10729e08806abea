// The scale-factor part of the calibration report (report.h): a run whose
// database holds scale-factor rows gets a "Scale factor" section, its CSV,
// JSON and C header with the stored numbers; a run without gets none of it,
// and its other files are as before. The reference numbers are the analysis
// library's fits the rows were made from (scale_factor_rows.h); the C header
// is compiled and run, and compared with the polynomials summed term by term.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <stdlib.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <tuple>

#include "gyrotherm/calibration/report.h"
#include "scale_factor_rows.h"
#include "test_files.h"

namespace gyrotherm::calibration {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

ReportOptions fixed_time() {
  ReportOptions o;
  o.generated_utc = "2026-11-24T00:00:00Z";
  o.station_name = "Lab 2";
  return o;
}

const ReportFile* find_file(const std::vector<ReportFile>& files, const std::string& path) {
  for (const auto& f : files) {
    if (f.path == path) return &f;
  }
  return nullptr;
}

// Rows of a CSV as maps column -> text (no quoted fields in these files).
std::vector<std::map<std::string, std::string>> csv_records(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    std::vector<std::string> f;
    std::stringstream ls(line);
    for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
    if (!line.empty() && line.back() == ',') f.push_back("");
    rows.push_back(f);
  }
  std::vector<std::map<std::string, std::string>> out;
  for (std::size_t i = 1; i < rows.size(); ++i) {
    std::map<std::string, std::string> m;
    EXPECT_EQ(rows[i].size(), rows[0].size()) << "line " << i + 1 << " of\n" << text;
    for (std::size_t c = 0; c < rows[0].size() && c < rows[i].size(); ++c) {
      m[rows[0][c]] = rows[i][c];
    }
    out.push_back(m);
  }
  return out;
}

// The text of the cells of table `id` in `html`, row by row.
std::vector<std::vector<std::string>> table_cells(const std::string& html, const std::string& id) {
  std::vector<std::vector<std::string>> rows;
  const auto at = html.find(fmt::format("id=\"{}\"", id));
  if (at == std::string::npos) return rows;
  const auto body = html.find("<tbody>", at);
  const auto end = html.find("</tbody>", body);
  const std::string text = html.substr(body, end - body);
  const std::regex row(R"(<tr[^>]*>(.*?)</tr>)"), cell(R"(<td[^>]*>(.*?)</td>)");
  for (auto r = std::sregex_iterator(text.begin(), text.end(), row); r != std::sregex_iterator();
       ++r) {
    const std::string cells = (*r)[1];
    std::vector<std::string> v;
    for (auto c = std::sregex_iterator(cells.begin(), cells.end(), cell);
         c != std::sregex_iterator(); ++c) {
      v.push_back((*c)[1]);
    }
    rows.push_back(v);
  }
  return rows;
}

// Σ c_j x^j term by term (the reference for the header's Horner form).
double power_sum(const std::vector<double>& c, double x) {
  double y = 0;
  for (std::size_t j = 0; j < c.size(); ++j) y += c[j] * std::pow(x, static_cast<double>(j));
  return y;
}

class ScaleFactorReportTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "gyrotherm-sf-report-XXXXXX").string();
    ASSERT_NE(::mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
    auto db = storage::Database::open((dir_ / "station.db").string());
    ASSERT_TRUE(db.ok()) << db.error().message;
    db_.emplace(std::move(*db));
  }
  void TearDown() override {
    db_.reset();
    std::error_code ec;
    if (!HasFailure() && !std::getenv("GYROTHERM_KEEP_TEST_DIR")) fs::remove_all(dir_, ec);
  }

  // A completed run with no samples (its report lists that as a problem).
  int64_t completed_run() {
    storage::RunRecord r;
    r.schedule_name = "scale factor";
    r.state = "completed";
    r.orientation = "up";
    auto id = db_->create_run(r);
    EXPECT_TRUE(id.ok()) << id.error().message;
    return id.ok() ? *id : 0;
  }

  RunReport report(int64_t run_id) {
    auto r = collect_run_report(*db_, run_id, fixed_time());
    EXPECT_TRUE(r.ok()) << r.error().message;
    return r.ok() ? std::move(*r) : RunReport{};
  }

  fs::path dir_;
  std::optional<storage::Database> db_;
};

TEST_F(ScaleFactorReportTest, StoredRowsRenderTheSectionWithTheirNumbers) {
  const int64_t run_id = completed_run();
  const test::StoredScaleFactor stored = test::store_scale_factor_rows(*db_, run_id);
  ASSERT_EQ(stored.sequence_fits.size(), 3u);
  const RunReport r = report(run_id);
  ASSERT_TRUE(r.scale_factor.has_value());
  ASSERT_EQ(r.scale_factor->fits.size(), 3u);
  ASSERT_EQ(r.scale_factor->points.size(), stored.points.size());
  const auto files = render_run_files(r, fixed_time());
  const std::string dir = fmt::format("run-{:04}/", run_id);
  const ReportFile* page = find_file(files, dir + "report.html");
  ASSERT_NE(page, nullptr);
  const std::string& html = page->content;
  EXPECT_NE(html.find("<section id=\"scale-factor\">"), std::string::npos);
  EXPECT_NE(html.find("<a href=\"#scale-factor\">Scale factor</a>"), std::string::npos);

  // The sequences' table: the stored figures, rounded for reading.
  const auto rows = table_cells(html, "sf-sequences");
  ASSERT_EQ(rows.size(), 3u) << html;
  for (std::size_t i = 0; i < 3; ++i) {
    SCOPED_TRACE(fmt::format("sequence {}", i + 1));
    const analysis::ScaleFactorFit& f = stored.sequence_fits[i];
    ASSERT_EQ(rows[i].size(), 11u);
    EXPECT_EQ(rows[i][10], "not assessed");  // stored without an assessment
    EXPECT_EQ(rows[i][0], std::to_string(i + 1));
    EXPECT_EQ(rows[i][1], fmt::format("{:.2f}", f.temperature_mean_c));
    EXPECT_EQ(rows[i][2], fmt::format("{:.9f}", f.k));
    EXPECT_EQ(rows[i][3], fmt::format("{:.6g}", f.k_std_error));
    EXPECT_EQ(rows[i][4], fmt::format("{:.4f}", f.bias_dph));
    EXPECT_EQ(rows[i][5], fmt::format("{:.1f}", f.nonlinearity_ppm));
    EXPECT_EQ(rows[i][6], fmt::format("{:.1f}", f.nonlinearity_fs_ppm));
    ASSERT_TRUE(f.asymmetry_ppm.has_value());
    EXPECT_EQ(rows[i][7], fmt::format("{:.1f}", *f.asymmetry_ppm));
    // Sequence 3 has one repetition: no repeatability, a dash.
    EXPECT_EQ(rows[i][8], f.repeatability_ppm ? fmt::format("{:.1f}", *f.repeatability_ppm) : "—");
    EXPECT_EQ(rows[i][9], std::to_string(f.points));
  }
  EXPECT_FALSE(stored.sequence_fits[2].repeatability_ppm.has_value());

  // K(T) and B(T): the coefficients (bias stored in °/s, shown in °/h).
  const auto& over = stored.over_temperature;
  EXPECT_NE(html.find(fmt::format("{:.3f} ppm/°C", over.sf_temperature_coefficient_ppm_per_c)),
            std::string::npos);
  EXPECT_NE(html.find(fmt::format("{:.4f} (°/h)/°C", over.bias_temperature_coefficient_dph_per_c)),
            std::string::npos);
  const auto poly = table_cells(html, "sf-polynomials");
  ASSERT_EQ(poly.size(), 3u);
  for (std::size_t j = 0; j < 3; ++j) {
    EXPECT_EQ(poly[j][1], fmt::format("{:.6g}", over.k_coefficients[j]));
    EXPECT_EQ(poly[j][2], fmt::format("{:.6g}", over.bias_coefficients_dph[j]));
  }
  for (std::size_t j = 0; j < 3; ++j) {
    EXPECT_NEAR(r.scale_factor->bias_coeffs_dph[j], over.bias_coefficients_dph[j],
                1e-15 * std::abs(over.bias_coefficients_dph[j]));
  }

  // The rate points: residuals from each sequence's line equal the
  // library's (to rounding of outputs up to 500 °/s: 1e-12 °/s).
  const ReportFile* points_csv = find_file(files, dir + "scale-factor-points.csv");
  ASSERT_NE(points_csv, nullptr);
  const auto points = csv_records(points_csv->content);
  ASSERT_EQ(points.size(), stored.points.size());
  std::map<std::tuple<int, int, double>, double> library;  // (seq, rep, rate) -> residual
  for (std::size_t s = 0; s < 3; ++s) {
    const auto& rp = stored.sequence_points[s];
    for (std::size_t i = 0; i < rp.size(); ++i) {
      library[{static_cast<int>(s + 1), rp[i].repetition, rp[i].rate_dps}] =
          stored.sequence_fits[s].residuals_dps[i];
    }
  }
  for (const auto& p : points) {
    const auto key = std::make_tuple(std::stoi(p.at("sf_sequence")), std::stoi(p.at("repetition")),
                                     std::stod(p.at("rate_dps")));
    ASSERT_TRUE(library.count(key)) << p.at("rate_dps");
    const double residual_dps = std::stod(p.at("residual_dps"));
    EXPECT_NEAR(residual_dps, library.at(key), 1e-12);
    const double k = stored.sequence_fits[std::get<0>(key) - 1].k;
    EXPECT_NEAR(std::stod(p.at("residual_ppm")), residual_dps / (k * std::get<2>(key)) * 1e6, 1e-9);
    EXPECT_EQ(std::stod(p.at("measured_rate_dps")), std::get<2>(key) * (1 + 2e-7));
  }
  // ... and each sequence's table shows them in °/h.
  const auto seq1 = table_cells(html, "sf-points-1");
  ASSERT_EQ(seq1.size(), 16u);
  EXPECT_EQ(seq1[0][1], "-500.000");  // by repetition, then rate
  EXPECT_EQ(seq1[0][7], fmt::format("{:.4f}", library.at(std::make_tuple(1, 1, -500.0)) * 3600.0));
  EXPECT_EQ(table_cells(html, "sf-points-3").size(), 8u);

  // The fits' CSV reads back exactly.
  const ReportFile* fits_csv = find_file(files, dir + "scale-factor.csv");
  ASSERT_NE(fits_csv, nullptr);
  const auto fits = csv_records(fits_csv->content);
  ASSERT_EQ(fits.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const auto& f = stored.fits[i];
    EXPECT_EQ(std::stoll(fits[i].at("run_id")), run_id);
    EXPECT_EQ(std::stod(fits[i].at("k")), f.k);
    EXPECT_EQ(std::stod(fits[i].at("k_se")), f.k_se);
    EXPECT_EQ(std::stod(fits[i].at("bias_dps")), f.bias_dps);
    EXPECT_EQ(std::stod(fits[i].at("nonlinearity_ppm")), f.nonlinearity_ppm);
    EXPECT_EQ(std::stod(fits[i].at("asymmetry_ppm")), *f.asymmetry_ppm);
    EXPECT_EQ(fits[i].at("repeatability_ppm"),
              f.repeatability_ppm ? fmt::format("{:.17g}", *f.repeatability_ppm) : "");
  }

  // The figures are in the page's data.
  for (const char* id :
       {"chart-sf-k-temperature", "chart-sf-bias-temperature", "chart-sf-nonlinearity"}) {
    EXPECT_NE(html.find(fmt::format("<div class=\"chart\" id=\"{}\">", id)), std::string::npos)
        << id;
    EXPECT_NE(html.find(fmt::format("\"id\":\"{}\"", id)), std::string::npos) << id;
  }
  for (const char* listed :
       {"scale-factor.csv", "scale-factor-points.csv", "scale-factor.json", "scale-factor.h"}) {
    EXPECT_NE(html.find(fmt::format("<li><a href=\"{0}\">{0}</a>", listed)), std::string::npos)
        << listed;
  }
}

TEST_F(ScaleFactorReportTest, KPlotIsRelativeToKAtTheCentreWithTheFittedPolynomial) {
  const int64_t run_id = completed_run();
  const test::StoredScaleFactor stored = test::store_scale_factor_rows(*db_, run_id);
  const RunReport r = report(run_id);
  ASSERT_TRUE(r.scale_factor.has_value());
  const auto plots = scale_factor_plots(*r.scale_factor);
  ASSERT_EQ(plots.size(), 3u);
  const Plot& k = plots[0];
  ASSERT_EQ(k.id, "chart-sf-k-temperature");
  ASSERT_EQ(k.series.size(), 2u);
  const auto& over = stored.over_temperature;
  const double k0 = over.k_coefficients[0];
  ASSERT_EQ(k.series[0].x.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(k.series[0].x[i], stored.fits[i].temperature_c);
    EXPECT_NEAR(k.series[0].y[i], (stored.fits[i].k / k0 - 1) * 1e6, 1e-9);
  }
  // The curve spans the sequences' temperatures and is the polynomial; an
  // order-2 fit through 3 temperatures passes through every K (to 1e-6 ppm).
  const auto& curve = k.series[1];
  ASSERT_EQ(curve.x.size(), 121u);
  EXPECT_EQ(curve.x.front(), stored.fits.front().temperature_c);
  EXPECT_EQ(curve.x.back(), stored.fits.back().temperature_c);
  for (std::size_t i = 0; i < curve.x.size(); i += 10) {
    const double ref =
        (power_sum(over.k_coefficients, curve.x[i] - over.temperature_mean_c) / k0 - 1) * 1e6;
    EXPECT_NEAR(curve.y[i], ref, 1e-6) << "T = " << curve.x[i];
  }
  EXPECT_NEAR(curve.y.front(), k.series[0].y.front(), 1e-6);
  EXPECT_NEAR(curve.y.back(), k.series[0].y.back(), 1e-6);
  // Nonlinearity: both figures per sequence.
  const Plot& n = plots[2];
  ASSERT_EQ(n.series.size(), 2u);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(n.series[0].y[i], stored.fits[i].nonlinearity_ppm);
    EXPECT_EQ(n.series[1].y[i], stored.fits[i].nonlinearity_fs_ppm);
  }
}

TEST_F(ScaleFactorReportTest, WithoutRowsThereIsNoSectionAndTheOtherFilesAreUnchanged) {
  const int64_t with = completed_run();
  const int64_t without = completed_run();
  test::store_scale_factor_rows(*db_, with);
  const RunReport plain = report(without);
  EXPECT_FALSE(plain.scale_factor.has_value());
  const auto plain_files = render_run_files(plain, fixed_time());
  for (const auto& f : plain_files) {
    EXPECT_EQ(f.path.find("scale-factor"), std::string::npos) << f.path;
    EXPECT_EQ(f.content.find("scale-factor"), std::string::npos) << f.path;
    EXPECT_EQ(f.content.find("Scale factor"), std::string::npos) << f.path;
  }

  // The same run with rows: its other files are byte for byte the same;
  // the page only gains the section.
  RunReport r = report(with);
  ASSERT_TRUE(r.scale_factor.has_value());
  const auto with_files = render_run_files(r, fixed_time());
  RunReport stripped = r;
  stripped.scale_factor.reset();
  std::erase_if(stripped.plots, [](const Plot& p) { return p.id.rfind("chart-sf-", 0) == 0; });
  const auto stripped_files = render_run_files(stripped, fixed_time());
  EXPECT_EQ(with_files.size(), stripped_files.size() + 4);
  for (const auto& f : stripped_files) {
    const ReportFile* same = find_file(with_files, f.path);
    ASSERT_NE(same, nullptr) << f.path;
    if (f.path.ends_with("report.html")) {
      EXPECT_EQ(f.content.find("scale-factor"), std::string::npos);
      continue;
    }
    EXPECT_EQ(same->content, f.content) << f.path;
  }

  // The summary: the section and its CSV only when a run has rows.
  CampaignReport c;
  c.runs = {plain};
  for (const auto& f : render_campaign_files(c, fixed_time())) {
    EXPECT_EQ(f.path.find("scale-factor"), std::string::npos) << f.path;
    EXPECT_EQ(f.content.find("Scale factor"), std::string::npos) << f.path;
  }
}

TEST_F(ScaleFactorReportTest, SummaryListsEveryRunsSequencesAndCoefficients) {
  const int64_t a = completed_run();
  const int64_t b = completed_run();
  const int64_t none = completed_run();
  const auto sa = test::store_scale_factor_rows(*db_, a);
  const auto sb = test::store_scale_factor_rows(*db_, b);
  std::vector<RunReport> runs{report(a), report(b), report(none)};
  const CampaignReport c = collect_campaign_report(std::move(runs), fixed_time());
  const auto files = render_campaign_files(c, fixed_time());
  const ReportFile* index = find_file(files, "index.html");
  ASSERT_NE(index, nullptr);
  const auto rows = table_cells(index->content, "sf-sequences");
  ASSERT_EQ(rows.size(), 6u);
  EXPECT_EQ(rows[0][0], std::to_string(a));
  EXPECT_EQ(rows[3][0], std::to_string(b));
  EXPECT_EQ(rows[4][3], fmt::format("{:.9f}", sb.fits[1].k));
  const auto coefficients = table_cells(index->content, "sf-temperature-coefficients");
  ASSERT_EQ(coefficients.size(), 2u);
  EXPECT_EQ(coefficients[0][0], std::to_string(a));
  EXPECT_EQ(coefficients[0][5],
            fmt::format("{:.3f}", sa.over_temperature.sf_temperature_coefficient_ppm_per_c));
  EXPECT_EQ(coefficients[1][6],
            fmt::format("{:.4f}", sb.over_temperature.bias_temperature_coefficient_dph_per_c));
  const ReportFile* csv = find_file(files, "scale-factor.csv");
  ASSERT_NE(csv, nullptr);
  const auto records = csv_records(csv->content);
  ASSERT_EQ(records.size(), 6u);
  EXPECT_EQ(std::stoll(records[5].at("run_id")), b);
  EXPECT_EQ(std::stod(records[5].at("k")), sb.fits[2].k);
}

TEST_F(ScaleFactorReportTest, CoefficientsJsonReadsBack) {
  const int64_t run_id = completed_run();
  const auto stored = test::store_scale_factor_rows(*db_, run_id);
  const auto files = render_run_files(report(run_id), fixed_time());
  const ReportFile* f = find_file(files, fmt::format("run-{:04}/scale-factor.json", run_id));
  ASSERT_NE(f, nullptr);
  const json j = json::parse(f->content);
  const auto& over = stored.over_temperature;
  const json& t = j.at("temperature_fit");
  EXPECT_EQ(t.at("order"), 2);
  EXPECT_EQ(t.at("t_centre_c").get<double>(), over.temperature_mean_c);
  ASSERT_EQ(t.at("k_coefficients").size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(t.at("k_coefficients")[i].get<double>(), over.k_coefficients[i]);
    EXPECT_NEAR(t.at("bias_coefficients_dph")[i].get<double>(), over.bias_coefficients_dph[i],
                1e-15 * std::abs(over.bias_coefficients_dph[i]));
  }
  EXPECT_EQ(t.at("k_ppm_per_c").get<double>(), over.sf_temperature_coefficient_ppm_per_c);
  EXPECT_EQ(t.at("bias_dph_per_c").get<double>(), over.bias_temperature_coefficient_dph_per_c);
  ASSERT_EQ(j.at("sequences").size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const json& s = j.at("sequences")[i];
    EXPECT_EQ(s.at("k").get<double>(), stored.fits[i].k);
    EXPECT_EQ(s.at("temperature_c").get<double>(), stored.fits[i].temperature_c);
    EXPECT_EQ(s.at("bias_dph").get<double>(), stored.fits[i].bias_dps * 3600.0);
    EXPECT_EQ(s.at("n_points"), stored.fits[i].n_points);
  }
  EXPECT_TRUE(j.at("sequences")[2].at("repeatability_ppm").is_null());
  EXPECT_EQ(j.at("runs"), json::array({run_id}));
  EXPECT_EQ(j.at("station"), "Lab 2");
}

TEST_F(ScaleFactorReportTest, ACoefficientListOfTheWrongLengthIsAProblemNotAnError) {
  const int64_t run_id = completed_run();
  auto stored = test::store_scale_factor_rows(*db_, run_id);
  // Storage checks for an array of numbers; two numbers for order 2 pass it.
  stored.temperature_fit.k_coeffs_json = "[1.0000125, 2e-6]";
  ASSERT_TRUE(
      db_->store_scale_factor(run_id, stored.points, stored.fits, stored.temperature_fit).ok());
  const RunReport r = report(run_id);
  ASSERT_TRUE(r.scale_factor.has_value());
  EXPECT_TRUE(r.scale_factor->k_coeffs.empty());
  bool named = false;
  for (const auto& p : r.problems) named |= p.find("k_coeffs_json") != std::string::npos;
  EXPECT_TRUE(named) << "no problem names k_coeffs_json";
  const auto files = render_run_files(r, fixed_time());
  const ReportFile* f = find_file(files, fmt::format("run-{:04}/scale-factor.json", run_id));
  ASSERT_NE(f, nullptr);
  EXPECT_TRUE(json::parse(f->content).at("temperature_fit").is_null());
}

// Runs `cmd` through the shell; its exit status, and stdout + stderr in `log`.
int run_logged(const std::string& cmd, const fs::path& log) {
  return std::system((cmd + " >'" + log.string() + "' 2>&1").c_str());
}

TEST_F(ScaleFactorReportTest, CHeaderCompilesAndEvaluatesThePolynomials) {
  const int64_t run_id = completed_run();
  const auto stored = test::store_scale_factor_rows(*db_, run_id);
  ReportOptions o = fixed_time();
  o.station_name = "Lab */ #error closed /* nested\n#error injected";
  RunReport r = report(run_id);
  r.station_name = o.station_name;
  const auto files = render_run_files(r, o);
  const ReportFile* h = find_file(files, fmt::format("run-{:04}/scale-factor.h", run_id));
  ASSERT_NE(h, nullptr);
  std::ofstream(dir_ / "scale-factor.h") << h->content;
  const double temperatures_c[] = {-25.0, 0.0, 20.0, 47.5, 65.0};
  std::string main_c =
      "#include <stdio.h>\n#include \"scale-factor.h\"\nint main(void) {\n"
      "  const double t[] = {-25.0, 0.0, 20.0, 47.5, 65.0};\n  int i;\n"
      "  for (i = 0; i < 5; ++i) {\n"
      "    printf(\"%.17g %.17g %.17g\\n\", gyrotherm_sf_k_at(t[i]), "
      "gyrotherm_sf_bias_dph_at(t[i]),\n"
      "           gyrotherm_sf_rate_dps(gyrotherm_sf_k_at(t[i]) * 123.5 + "
      "gyrotherm_sf_bias_dph_at(t[i]) / 3600.0, t[i]));\n"
      "  }\n"
      "  printf(\"%d %.17g %.17g\\n\", GYROTHERM_SF_N_SEQUENCES, gyrotherm_sf_table_k[1], "
      "gyrotherm_sf_k_ppm_per_c);\n"
      "  return 0;\n}\n";
  std::ofstream(dir_ / "main.c") << main_c;
  const std::string c99 = fmt::format(
      "cc -std=c99 -Wall -Wextra -pedantic -Werror '{0}/main.c' -o '{0}/sf'", dir_.string());
  ASSERT_EQ(run_logged(c99, dir_ / "cc.log"), 0) << c99 << "\n"
                                                 << testing::read_text(dir_ / "cc.log") << "\n"
                                                 << h->content;
  const std::string cxx = fmt::format(
      "g++ -x c++ -std=c++17 -Wall -Wextra -pedantic -Werror -c '{0}/main.c' -o '{0}/main_cxx.o'",
      dir_.string());
  EXPECT_EQ(run_logged(cxx, dir_ / "cxx.log"), 0) << cxx << "\n"
                                                  << testing::read_text(dir_ / "cxx.log");
  ASSERT_EQ(run_logged(fmt::format("'{}/sf'", dir_.string()), dir_ / "out.txt"), 0);
  std::istringstream out(testing::read_text(dir_ / "out.txt"));
  const auto& over = stored.over_temperature;
  for (double t : temperatures_c) {
    double k = 0, bias_dph = 0, rate = 0;
    out >> k >> bias_dph >> rate;
    const double x = t - over.temperature_mean_c;
    EXPECT_NEAR(k, power_sum(over.k_coefficients, x), 1e-15) << "T = " << t;
    EXPECT_NEAR(bias_dph, power_sum(over.bias_coefficients_dph, x), 1e-12) << "T = " << t;
    EXPECT_NEAR(rate, 123.5, 1e-12) << "T = " << t;
  }
  int n = 0;
  double table_k = 0, ppm_per_c = 0;
  out >> n >> table_k >> ppm_per_c;
  EXPECT_EQ(n, 3);
  EXPECT_EQ(table_k, stored.fits[1].k);
  EXPECT_EQ(ppm_per_c, over.sf_temperature_coefficient_ppm_per_c);
}

}  // namespace
}  // namespace gyrotherm::calibration

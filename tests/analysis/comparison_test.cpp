// Comparison grid (paper Tables II-IV): in-sample and leave-one-run-out
// against numpy (tools/reference/multirun_reference.py, data in
// tests/analysis/data/comparison_grid.txt), the grid's layout, and bad input.
// Tolerances: the uncompensated row (a plain statistic) 1e-10 relative; the
// compensated cells (from fitted values) 1e-9 relative.
#include "gyrotherm/analysis/comparison.h"

#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "multirun_data.h"

namespace gyrotherm::analysis {
namespace {

using testing::load_runs;
using testing::read_reference_lines;
using testing::Tokens;

const char* const kComparisonScript = "tools/reference/multirun_reference.py";

const ComparisonCell* find_cell(const Comparison& c, const std::string& spec) {
  for (const ComparisonCell& cell : c.cells) {
    if (to_string(cell.spec) == spec) return &cell;
  }
  return nullptr;
}

void expect_rel(double actual, double expected, double rel, const std::string& what) {
  EXPECT_NEAR(actual, expected, rel * std::abs(expected)) << what;
}

// Both forms' fit windows from the reference file's derivative_window_s and
// l0_window_s lines (the L0 window is the paper form's).
void read_fit_windows(const std::vector<Tokens>& lines, ComparisonOptions& paper,
                      ComparisonOptions& centred) {
  for (const Tokens& t : lines) {
    if (t[0] == "derivative_window_s") {
      paper.fit.derivative_window_s = centred.fit.derivative_window_s = std::stod(t[1]);
    }
    if (t[0] == "l0_window_s") paper.fit.l0_window_s = std::stod(t[1]);
  }
}

// The reference file's "none" line (n, mean and std of the uncompensated
// rates) against `grid`, to 1e-10 relative; `other` has the same n.
void expect_none_matches(const std::vector<Tokens>& lines, const Comparison& grid,
                         const Comparison& other) {
  for (const Tokens& t : lines) {
    if (t[0] == "none") {
      EXPECT_EQ(grid.none.n, std::stoul(t[1]));
      expect_rel(grid.none.mean_dph, std::stod(t[2]), 1e-10, "none mean");
      expect_rel(grid.none.std_dph, std::stod(t[3]), 1e-10, "none std");
      EXPECT_EQ(other.none.n, grid.none.n);
    }
  }
}

// Each "cell" line of the reference file (form, spec, n, in-sample mean and
// std, LORO mean and std) against the grid of its form; the LORO std to
// `loro_std_rel`, the rest to 1e-9 relative; `expected_cells` such lines.
void expect_cells_match(const std::vector<Tokens>& lines, const Comparison& by_paper,
                        const Comparison& by_centred, double loro_std_rel,
                        std::size_t expected_cells) {
  std::size_t cells = 0;
  for (const Tokens& t : lines) {
    if (t[0] != "cell") continue;
    ++cells;
    const Comparison& c = t[1] == "paper" ? by_paper : by_centred;
    const ComparisonCell* cell = find_cell(c, t[2]);
    ASSERT_NE(cell, nullptr) << t[2];
    const std::string what = t[1] + " " + t[2];
    ASSERT_TRUE(cell->in_sample.has_value()) << what << ": " << cell->in_sample_error;
    ASSERT_TRUE(cell->cross_validated.has_value()) << what << ": " << cell->cross_validated_error;
    EXPECT_EQ(cell->in_sample->n, std::stoul(t[3])) << what;
    EXPECT_EQ(cell->cross_validated->n, std::stoul(t[3])) << what;
    expect_rel(cell->in_sample->mean_dph, std::stod(t[4]), 1e-9, what + " in-sample mean");
    expect_rel(cell->in_sample->std_dph, std::stod(t[5]), 1e-9, what + " in-sample std");
    expect_rel(cell->cross_validated->mean_dph, std::stod(t[6]), 1e-9, what + " LORO mean");
    expect_rel(cell->cross_validated->std_dph, std::stod(t[7]), loro_std_rel, what + " LORO std");
  }
  EXPECT_EQ(cells, expected_cells);
}

TEST(ComparisonReference, GridMatchesNumpy) {
  const std::vector<Tokens> lines = read_reference_lines("comparison_grid.txt", kComparisonScript);
  const std::vector<AnalysisSeries> runs = load_runs(lines);
  ASSERT_EQ(runs.size(), 3u);
  ComparisonOptions paper;  // the raw bins, as comparison_grid.txt
  ComparisonOptions centred;
  paper.form = DriftModelForm::kPaper;
  centred.form = DriftModelForm::kCentered;
  paper.smooth_points = centred.smooth_points = 1;
  read_fit_windows(lines, paper, centred);
  auto by_paper = compare_models(runs, paper);
  ASSERT_TRUE(by_paper.ok()) << by_paper.error().message;
  auto by_centred = compare_models(runs, centred);
  ASSERT_TRUE(by_centred.ok()) << by_centred.error().message;

  expect_none_matches(lines, *by_paper, *by_centred);
  expect_cells_match(lines, *by_paper, *by_centred, 1e-9, 15u);
}

// The default grid smooths each run's compensated output (and the "none"
// row) by Table I's 101-point centred moving average before pooling, as the
// paper's Table II std implies; against numpy (comparison_grid_smoothed.txt).
TEST(ComparisonReference, SmoothedGridMatchesNumpy) {
  const std::vector<Tokens> lines =
      read_reference_lines("comparison_grid_smoothed.txt", kComparisonScript);
  const std::vector<AnalysisSeries> runs = load_runs(lines);
  ASSERT_EQ(runs.size(), 3u);
  ComparisonOptions centred;  // the defaults: smoothed
  ComparisonOptions paper;
  EXPECT_EQ(centred.smooth_points, 101u);
  for (const Tokens& t : lines) {
    if (t[0] == "smooth_points") {
      EXPECT_EQ(centred.smooth_points, std::stoul(t[1]));
    }
  }
  centred.form = DriftModelForm::kCentered;
  paper.form = DriftModelForm::kPaper;
  read_fit_windows(lines, paper, centred);
  auto by_paper = compare_models(runs, paper);
  ASSERT_TRUE(by_paper.ok()) << by_paper.error().message;
  auto by_centred = compare_models(runs, centred);
  ASSERT_TRUE(by_centred.ok()) << by_centred.error().message;

  expect_none_matches(lines, *by_centred, *by_paper);
  // The LORO std of a high order can be large (extrapolation in T): 1e-8.
  expect_cells_match(lines, *by_paper, *by_centred, 1e-8, 24u);
}

// Paper form, raw bins: compensated = L0 + residual, so the in-sample std
// equals the std of the fit's residuals around their mean; the grid's layout.
TEST(Comparison, LayoutAndInSampleFit) {
  const std::vector<Tokens> lines = read_reference_lines("comparison_grid.txt", kComparisonScript);
  const std::vector<AnalysisSeries> runs = load_runs(lines);
  ComparisonOptions options;
  options.form = DriftModelForm::kPaper;
  options.smooth_points = 1;
  options.max_order = 3;
  options.cross_validate = false;
  auto c = compare_models(runs, options);
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c->runs, 3u);
  ASSERT_EQ(c->cells.size(), 9u);
  const char* const expected[] = {"T1",    "T2",       "T3",       "T1+G1",   "T2+G1",
                                  "T3+G1", "T1+R1+G1", "T2+R1+G1", "T3+R1+G1"};
  for (std::size_t i = 0; i < 9; ++i) {
    const ComparisonCell& cell = c->cells[i];
    EXPECT_EQ(to_string(cell.spec), expected[i]);
    EXPECT_EQ(cell.order, static_cast<int>(i % 3) + 1);
    EXPECT_EQ(cell.terms, i < 3 ? TermSet::kT : i < 6 ? TermSet::kTG : TermSet::kTGR);
    ASSERT_TRUE(cell.fit.has_value());
    EXPECT_EQ(cell.fit->spec, cell.spec);
    EXPECT_FALSE(cell.cross_validated.has_value());
    EXPECT_EQ(cell.cross_validated_error, "leave-one-run-out not requested");
  }
  EXPECT_EQ(to_string(TermSet::kT), "T");
  EXPECT_EQ(to_string(TermSet::kTG), "T+G");
  EXPECT_EQ(to_string(TermSet::kTGR), "T+G+R");

  // Direct: rate - drift_terms over all runs, pooled.
  const ComparisonCell& cell = c->cells[7];  // T2+R1+G1
  std::vector<double> all;
  for (const AnalysisSeries& r : runs) {
    auto terms = drift_terms(*cell.fit, r);
    ASSERT_TRUE(terms.ok());
    for (std::size_t i = 0; i < r.rate_dph.size(); ++i) all.push_back(r.rate_dph[i] - (*terms)[i]);
  }
  EXPECT_NEAR(cell.in_sample->mean_dph, mean(all), 1e-12 * std::abs(mean(all)));
  EXPECT_NEAR(cell.in_sample->std_dph, std_ddof1(all), 1e-12 * std_ddof1(all));
  // With the gradient and rate terms in the data, adding them helps.
  EXPECT_LT(c->cells[7].in_sample->std_dph, c->cells[4].in_sample->std_dph);
  EXPECT_LT(c->cells[4].in_sample->std_dph, c->none.std_dph * 1.0);
}

TEST(Comparison, OneRunHasNoCrossValidation) {
  const std::vector<Tokens> lines = read_reference_lines("comparison_grid.txt", kComparisonScript);
  const std::vector<AnalysisSeries> runs = load_runs(lines);
  auto c = compare_models(std::span<const AnalysisSeries>(runs.data(), 1));
  ASSERT_TRUE(c.ok()) << c.error().message;
  ASSERT_EQ(c->cells.size(), 12u);
  for (const ComparisonCell& cell : c->cells) {
    EXPECT_TRUE(cell.in_sample.has_value()) << to_string(cell.spec) << ": " << cell.in_sample_error;
    EXPECT_FALSE(cell.cross_validated.has_value());
    EXPECT_NE(cell.cross_validated_error.find("needs >= 2 runs"), std::string::npos)
        << cell.cross_validated_error;
  }
}

// ---- bad input -------------------------------------------------------------

AnalysisSeries flat_run(std::size_t n, double t0_s, double temp_c, double rate_dph) {
  AnalysisSeries s;
  for (std::size_t i = 0; i < n; ++i) {
    s.t_s.push_back(t0_s + static_cast<double>(i));
    s.top_c.push_back(temp_c + 0.25);
    s.side_c.push_back(temp_c - 0.25);
    s.rate_dph.push_back(rate_dph + 0.01 * static_cast<double>(i % 5));
  }
  return s;
}

TEST(Comparison, BadInputIsAnErrorNamingTheRun) {
  EXPECT_FALSE(compare_models(std::span<const AnalysisSeries>()).ok());

  std::vector<AnalysisSeries> runs = {flat_run(300, 0, 20, 8), flat_run(1, 1e4, 30, 8)};
  auto c = compare_models(runs);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("run 2 has 1 point(s)"), std::string::npos) << c.error().message;

  runs = {flat_run(300, 0, 20, 8), AnalysisSeries{}};
  c = compare_models(runs);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("run 2 has 0 point(s)"), std::string::npos) << c.error().message;

  runs = {flat_run(300, 0, 20, 8), flat_run(300, 1e4, 30, 8)};
  runs[1].top_c[17] = std::nan("");
  c = compare_models(runs);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("run 2: top_c[17] is not finite"), std::string::npos)
      << c.error().message;

  runs = {flat_run(300, 0, 20, 8)};
  runs[0].t_s[5] = runs[0].t_s[4];
  c = compare_models(runs);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("run 1: t_s[5]"), std::string::npos) << c.error().message;

  ComparisonOptions bad;
  bad.max_order = 5;
  std::string why;
  EXPECT_FALSE(bad.is_valid(&why));
  EXPECT_NE(why.find("max_order"), std::string::npos) << why;
  c = compare_models(std::vector<AnalysisSeries>{flat_run(300, 0, 20, 8)}, bad);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("max_order"), std::string::npos) << c.error().message;
  bad = {};
  bad.fit.derivative_window_s = -1;
  EXPECT_FALSE(bad.is_valid(&why));
  EXPECT_NE(why.find("derivative_window_s"), std::string::npos) << why;
  for (std::size_t points : {0u, 100u, 100003u}) {
    bad = {};
    bad.smooth_points = points;
    EXPECT_FALSE(bad.is_valid(&why)) << points;
    EXPECT_NE(why.find("smooth_points"), std::string::npos) << why;
  }
  // A run shorter than the moving average is named.
  runs = {flat_run(300, 0, 20, 8), flat_run(60, 1e4, 30, 8)};
  c = compare_models(runs);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.error().message.find("run 2 has 60 point(s), fewer than the 101-point"),
            std::string::npos)
      << c.error().message;
}

// Constant temperature: every cell keeps its error, no numbers, no NaN; the
// uncompensated row is still there.
TEST(Comparison, ConstantTemperatureGivesCellErrors) {
  const std::vector<AnalysisSeries> runs = {flat_run(400, 0, 25, 8), flat_run(400, 1e4, 25, 8.2)};
  auto c = compare_models(runs);
  ASSERT_TRUE(c.ok()) << c.error().message;
  EXPECT_EQ(c->none.n, 600u);  // 2 x (400 - 100) full 101-point windows
  EXPECT_TRUE(std::isfinite(c->none.std_dph));
  ASSERT_EQ(c->cells.size(), 12u);
  for (const ComparisonCell& cell : c->cells) {
    EXPECT_FALSE(cell.in_sample.has_value()) << to_string(cell.spec);
    EXPECT_FALSE(cell.fit.has_value());
    EXPECT_NE(cell.in_sample_error.find("term T cannot be fitted"), std::string::npos)
        << cell.in_sample_error;
    EXPECT_FALSE(cell.cross_validated.has_value());
    EXPECT_NE(cell.cross_validated_error.find("held out"), std::string::npos)
        << cell.cross_validated_error;
  }
}

// Two runs, each soaked at one temperature: two distinct temperatures
// support T1 but not T2..T4 (a rank-deficient design), which become cell
// errors while T1 is computed.
TEST(Comparison, OrderAboveWhatTheDataSupportsIsACellError) {
  std::vector<AnalysisSeries> runs = {flat_run(400, 0, 10, 8), flat_run(400, 1e4, 40, 8.5)};
  ComparisonOptions options;
  options.form = DriftModelForm::kCentered;
  auto c = compare_models(runs, options);
  ASSERT_TRUE(c.ok()) << c.error().message;
  const ComparisonCell* t1 = find_cell(*c, "T1");
  ASSERT_NE(t1, nullptr);
  ASSERT_TRUE(t1->in_sample.has_value()) << t1->in_sample_error;
  EXPECT_TRUE(std::isfinite(t1->in_sample->std_dph));
  for (const char* spec : {"T2", "T3", "T4"}) {
    const ComparisonCell* cell = find_cell(*c, spec);
    ASSERT_NE(cell, nullptr);
    EXPECT_FALSE(cell->in_sample.has_value()) << spec;
    EXPECT_NE(cell->in_sample_error.find("rank-deficient at term T2"), std::string::npos)
        << spec << ": " << cell->in_sample_error;
  }
  // Each run alone has one temperature: leave-one-run-out cannot fit T at all.
  EXPECT_FALSE(t1->cross_validated.has_value());
  EXPECT_NE(t1->cross_validated_error.find("run 1 held out"), std::string::npos)
      << t1->cross_validated_error;
}

}  // namespace
}  // namespace gyrotherm::analysis

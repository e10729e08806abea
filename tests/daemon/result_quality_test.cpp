// Rate points, spinning and the quality of results, on real SQLite files
// written through the SampleWriter (docs/analysis.md "Rate points",
// "Result quality"; issue "Truth in time" items 3 and 4):
// - the drift fit's series leaves out every stretch where the table was
//   not at rest by its own record, not only the steps that demanded a rate;
// - rate windows lose a guard band at both ends; a point whose samples are
//   not flat is left out of its fit and named;
// - every result carries its coverage and a verdict; a flagged result's C
//   header is exported only with force, then marked.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/calibration/exporter.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/calibration/scale_factor_run.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "integration/temp_dir_test.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

constexpr double kQualityRateHz = 10.0;
constexpr double kQualityBiasDph = 2.0;
constexpr double kQualityK = 1.000123;

struct Step {
  std::string kind;        // soak, rate
  std::string table_mode;  // none, static, rate
  double rate_dps = 0;
  double from_s = 0, to_s = 0;
  int sf_sequence = 0, sf_repetition = 0;
  double setpoint_c = 20.0;
};

// What the station recorded, as functions of station time.
struct Recording {
  double end_s = 0;
  std::function<double(double)> gyro_dph;  // NaN: no sample at t
  std::function<double(double)> temperature_c = [](double t) { return 20.0 + 0.001 * t; };
  // The table's reading at t (1 Hz); nullopt: no table.
  std::function<std::optional<TableSample>(double)> table = [](double) {
    return std::optional<TableSample>();
  };
};

class ResultQualityTest : public testing::TempDirTest {
 protected:
  ResultQualityTest() : TempDirTest("gyrotherm-result-quality") {}

  std::string db_path() const { return (dir_ / "station.db").string(); }

  int64_t make_run(const std::vector<Step>& steps, const Recording& rec,
                   const std::string& config_json) {
    auto db = storage::Database::open(db_path());
    EXPECT_TRUE(db.ok());
    storage::RunRecord run;
    run.schedule_name = "quality";
    run.state = "acquiring";
    run.latitude_deg = 45.0;
    run.orientation = "up";
    run.config_json = config_json;
    auto id = db->create_run(run);
    EXPECT_TRUE(id.ok()) << id.error().message;
    int index = 0;
    for (const Step& s : steps) {
      storage::SegmentRecord seg;
      seg.run_id = *id;
      seg.index = index++;
      seg.kind = s.kind;
      seg.label = fmt::format("{} {:g}", s.kind, s.rate_dps);
      seg.setpoint_c = s.setpoint_c;
      seg.t_start_s = s.from_s;
      seg.t_end_s = s.to_s;
      seg.t_acquire_start_s = s.from_s;
      seg.t_acquire_end_s = s.to_s;
      seg.state = "completed";
      seg.table_mode = s.table_mode;
      if (s.table_mode != "none") seg.table_rate_dps = s.rate_dps;
      seg.sf_sequence = s.sf_sequence;
      seg.sf_repetition = s.sf_repetition;
      auto sid = db->create_segment(seg);
      EXPECT_TRUE(sid.ok());
      seg.id = *sid;
      seg.windows = {{s.from_s, s.to_s}};
      EXPECT_TRUE(db->update_segment(seg).ok());
    }
    auto writer = storage::SampleWriter::start(db_path());
    EXPECT_TRUE(writer.ok());
    std::vector<GyroSample> gyro;
    const auto n = static_cast<int64_t>(std::llround(rec.end_s * kQualityRateHz));
    for (int64_t i = 0; i < n; ++i) {
      GyroSample g;
      g.t_s = static_cast<double>(i) / kQualityRateHz;
      g.rate_dph = rec.gyro_dph(g.t_s);
      if (std::isnan(g.rate_dph)) continue;
      gyro.push_back(g);
    }
    (*writer)->push_gyro(*id, gyro);
    for (double t = 0; t < rec.end_s; t += 1.0) {
      TemperatureSample temp;
      temp.t_s = t;
      temp.setpoint_c = temp.chamber_c = 20.0;
      temp.top_c = rec.temperature_c(t);
      temp.side_c = temp.top_c - 0.05 * (1.0 + std::sin(t / 700.0));
      (*writer)->push_temperature(*id, temp);
      if (auto table = rec.table(t)) {
        table->t_s = t;
        (*writer)->push_table(*id, *table);
      }
    }
    EXPECT_TRUE((*writer)->flush().ok());
    (*writer)->stop();
    EXPECT_TRUE(db->set_run_state(*id, "completed", true).ok());
    return *id;
  }

  storage::Database open() {
    auto db = storage::Database::open(db_path());
    EXPECT_TRUE(db.ok());
    return std::move(*db);
  }
};

TableSample table_reading(double rate_dps, double position_deg, std::string demand_mode) {
  TableSample t;
  t.demand_mode = std::move(demand_mode);
  t.rate_dps = rate_dps;
  t.position_deg = std::fmod(position_deg, 360.0);
  t.mode = rate_dps == 0 ? "position" : "rate";
  t.interlock = "closed";
  return t;
}

// ---------------------------------------------------------- spinning

// Two static soaks whose steps demanded no rate; by its own record the
// table spun at 50 °/s over [500, 560) s and was moved 140° → 230° over
// [1500, 1510) s with its rate reading 0 (a position move). The gyro saw
// both. Neither stretch may reach the drift model's series.
TEST_F(ResultQualityTest, DriftSeriesLeavesOutEveryStretchTheTableWasNotAtRest) {
  const auto spinning = [](double t) { return t >= 500 && t < 560; };
  const auto moving = [](double t) { return t >= 1500 && t < 1510; };
  Recording rec;
  rec.end_s = 2400;
  rec.gyro_dph = [&](double t) {
    double dph = kQualityBiasDph + 0.01 * std::sin(1.7 * t);
    if (spinning(t)) dph += 50.0 * 3600.0;
    if (moving(t)) dph += 9.0 * 3600.0;
    return dph;
  };
  rec.table = [&](double t) {
    if (spinning(t)) return std::optional(table_reading(50.0, 20.0 + 50.0 * (t - 500), "static"));
    if (moving(t)) return std::optional(table_reading(0.0, 140.0 + 9.0 * (t - 1500), "none"));
    // At rest: at 20°, at 140° once the spin stopped there, at 230° after the move.
    const double at_deg = t < 500 ? 20.0 : t < 1500 ? 140.0 : 230.0;
    return std::optional(table_reading(0.0, at_deg, t < 1200 ? "static" : "none"));
  };
  const int64_t run_id = make_run(
      {{"soak", "static", 0.0, 0, 1200}, {"soak", "none", 0.0, 1200, 2400}}, rec,
      R"({"station": {"name": "q"}, "gyro": {"rate_hz": 10}, "table": {"rest_rate_dps": 0.01}})");
  auto db = open();
  auto axis = calibration::first_axis(db, run_id);
  ASSERT_TRUE(axis.ok()) << axis.error().message;
  calibration::RunSeriesCoverage coverage;
  auto series = calibration::run_series(db, run_id, 1.0, *axis, &coverage);
  ASSERT_TRUE(series.ok()) << series.error().message;
  ASSERT_FALSE(series->t_s.empty());
  for (std::size_t i = 0; i < series->t_s.size(); ++i) {
    const double t = series->t_s[i];
    EXPECT_FALSE(t >= 499 && t < 561) << "a bin of the spin at " << t << " s";
    EXPECT_FALSE(t >= 1499 && t < 1511) << "a bin of the move at " << t << " s";
    EXPECT_LT(std::fabs(series->rate_dph[i] - kQualityBiasDph), 0.1) << "at " << t << " s";
  }
  // The stretches left out: from the last reading at rest before to the
  // first after, 10 s wider each side; the rest of the run is kept.
  const std::vector<std::pair<double, double>> want = {{489.0, 571.0}, {1490.0, 1521.0}};
  ASSERT_EQ(coverage.excluded.size(), want.size());
  for (std::size_t i = 0; i < want.size(); ++i) {
    EXPECT_NEAR(coverage.excluded[i].first, want[i].first, 1e-9);
    EXPECT_NEAR(coverage.excluded[i].second, want[i].second, 1e-9);
  }
  // Everything outside them was recorded: full coverage of 2400 − 82 − 31 s.
  EXPECT_NEAR(coverage.coverage.window_s, 2400.0 - 82.0 - 31.0, 1e-9);
  ASSERT_TRUE(coverage.coverage.fraction.has_value());
  EXPECT_NEAR(*coverage.coverage.fraction, 1.0, 1e-3);
}

// ---------------------------------------------------------- rate points

// A scale-factor run (±10 and ±100 °/s, two repetitions, 36 s windows of
// whole turns, 5 s between) whose gyro shows each rate `lag_s(t)` late: the
// start of a window carries the samples of what came before it.
class RatePointTest : public ResultQualityTest {
 protected:
  std::vector<Step> steps() const {
    std::vector<Step> s{{"soak", "static", 0.0, 0, 300}};
    double t = 300;
    for (int rep = 1; rep <= 2; ++rep) {
      for (double rate : {10.0, -10.0, 100.0, -100.0}) {
        s.push_back({"rate", "rate", rate, t, t + 36.0, 1, rep});
        t += 41.0;
      }
    }
    return s;
  }
  int64_t run(const std::function<double(double)>& lag_s, const std::string& config_json) {
    const std::vector<Step> s = steps();
    const auto rate_at = [s](double t) {
      for (const Step& step : s) {
        if (step.kind == "rate" && t >= step.from_s && t < step.to_s) return step.rate_dps;
      }
      return 0.0;
    };
    Recording rec;
    rec.end_s = s.back().to_s + 5;
    rec.gyro_dph = [=](double t) {
      return kQualityK * rate_at(t - lag_s(t)) * 3600.0 + kQualityBiasDph;
    };
    rec.table = [=](double t) {
      return std::optional(table_reading(rate_at(t), std::fmod(rate_at(t) * t, 360.0), "rate"));
    };
    return make_run(s, rec, config_json);
  }
};

constexpr const char* kGuard1s =
    R"({"station": {"name": "q"}, "gyro": {"rate_hz": 10}, "analysis": {"rate_guard_s": 1.0}})";

TEST_F(RatePointTest, TheGuardBandCutsThePreviousRatesSamplesFromEachWindow) {
  // Half a second of the previous rate at the start of every window.
  const int64_t run_id = run([](double) { return 0.5; }, kGuard1s);
  auto db = open();
  auto summary = calibration::analyse_scale_factor(db, run_id);
  ASSERT_TRUE(summary.ok()) << summary.error().message;
  EXPECT_TRUE(summary->problems.empty()) << summary->problems.front();
  EXPECT_TRUE(summary->flagged.empty()) << summary->flagged.front();
  auto fits = db.scale_factor_fits(run_id);
  ASSERT_TRUE(fits.ok());
  ASSERT_EQ(fits->size(), 1u);
  EXPECT_NEAR((*fits)[0].k, kQualityK, 1e-12);  // the lagged samples are gone
  EXPECT_EQ((*fits)[0].guard_s, 1.0);
  EXPECT_EQ((*fits)[0].quality.verdict, "ok");
  auto points = db.scale_factor_points(run_id);
  ASSERT_TRUE(points.ok());
  ASSERT_EQ(points->size(), 8u);
  for (const auto& p : *points) {
    EXPECT_EQ(p.guard_s, 1.0);
    EXPECT_EQ(p.quality.verdict, "ok") << p.rate_dps;
    // 36 s less 2 × 1 s: at 10 °/s (a turn is 36 s) the 34 s left; at
    // 100 °/s whole turns of 3.6 s from the window's start: 9, 32.4 s.
    const double want_s = std::fabs(p.rate_dps) == 10.0 ? 34.0 : 32.4;
    EXPECT_NEAR(p.duration_s, want_s, 1e-9) << p.rate_dps;
    EXPECT_NEAR(p.turns, std::fabs(p.rate_dps) * want_s / 360.0, 1e-9);
    EXPECT_NEAR(static_cast<double>(p.n), want_s * kQualityRateHz, 1.0) << p.rate_dps;
    ASSERT_TRUE(p.quality.coverage.has_value());
    EXPECT_NEAR(*p.quality.coverage, 1.0, 1.0 / 320);
  }
}

TEST_F(RatePointTest, APointThatIsNotFlatIsLeftOutAndNamed) {
  // The third point (100 °/s, repetition 1, segment 4, window [382, 418) s)
  // starts with 3.5 s of the gap before it: 2.5 s remain after the guard.
  const int64_t run_id = run([](double t) { return t >= 382 && t < 418 ? 3.5 : 0.0; }, kGuard1s);
  auto db = open();
  auto summary = calibration::analyse_scale_factor(db, run_id);
  ASSERT_TRUE(summary.ok()) << summary.error().message;
  ASSERT_EQ(summary->problems.size(), 1u);
  EXPECT_THAT(summary->problems[0], HasSubstr("segment 4"));
  EXPECT_THAT(summary->problems[0], HasSubstr("point at 100 °/s, 20.36 °C left out of the fit"));
  EXPECT_THAT(summary->problems[0], HasSubstr("gyro output not flat"));
  auto fits = db.scale_factor_fits(run_id);
  ASSERT_TRUE(fits.ok());
  ASSERT_EQ(fits->size(), 1u);
  EXPECT_EQ((*fits)[0].n_points, 7);
  EXPECT_NEAR((*fits)[0].k, kQualityK, 1e-12);
  auto points = db.scale_factor_points(run_id);
  ASSERT_TRUE(points.ok());
  ASSERT_EQ(points->size(), 8u);  // stored, with why it was left out
  int excluded = 0;
  for (const auto& p : *points) {
    if (!p.quality.excluded()) continue;
    ++excluded;
    EXPECT_EQ(p.rate_dps, 100.0);
    EXPECT_EQ(p.repetition, 1);
    ASSERT_FALSE(p.quality.reasons.empty());
    EXPECT_THAT(p.quality.reasons[0], HasSubstr("gyro output not flat: the first third"));
  }
  EXPECT_EQ(excluded, 1);
}

// ---------------------------------------------------------- quality

TEST_F(ResultQualityTest, ATableIRowOverAWindowWithA30PercentGapIsFlagged) {
  Recording rec;
  rec.end_s = 600;
  rec.gyro_dph = [](double t) {
    return t >= 200 && t < 380 ? std::nan("") : kQualityBiasDph + 0.01 * std::sin(1.7 * t);
  };
  const int64_t run_id = make_run({{"soak", "none", 0.0, 0, 600}}, rec,
                                  R"({"station": {"name": "q"}, "gyro": {"rate_hz": 10}})");
  auto db = open();
  auto summary = calibration::analyse_run(db, run_id, calibration::AnalysisSettings{});
  ASSERT_TRUE(summary.ok()) << summary.error().message;
  auto rows = db.segment_stats(run_id);
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), 1u);
  const storage::ResultQuality& q = (*rows)[0].quality;
  EXPECT_EQ(q.verdict, "flagged");
  EXPECT_EQ(q.samples, 4200);
  EXPECT_DOUBLE_EQ(q.expected, 6000.0);
  ASSERT_TRUE(q.coverage.has_value());
  EXPECT_NEAR(*q.coverage, 0.7, 1e-12);
  ASSERT_TRUE(q.longest_gap_s.has_value());
  EXPECT_NEAR(*q.longest_gap_s, 180.1, 1e-6);
  ASSERT_EQ(q.reasons.size(), 1u);
  EXPECT_THAT(q.reasons[0], HasSubstr("coverage 70.0 % (4200 of 6000 samples expected)"));
  // The Allan deviation of the same window, and the analysis event's list.
  auto allan = db.allan(run_id);
  ASSERT_TRUE(allan.ok());
  ASSERT_EQ(allan->size(), 1u);
  EXPECT_EQ((*allan)[0].quality.verdict, "flagged");
  EXPECT_NEAR(*(*allan)[0].quality.coverage, 0.7, 1e-12);
  ASSERT_FALSE(summary->flagged.empty());
  EXPECT_THAT(summary->flagged[0], HasSubstr("run 1 segment 1 (the unnamed gyro z) Table I: "
                                             "coverage 70.0 %"));
}

// Run A: a drift fit over a run whose gyro recorded 6 % of the time.
// Run B: a scale-factor run whose gyro is wired backwards (sequence 1,
// K < 0) and whose sequence 2 has a point 500 °/s off (nonlinearity
// ~5×10⁷ ppm). All stored flagged; the export leaves their headers out,
// naming why, unless forced, and then marks them.
TEST_F(ResultQualityTest, FlaggedResultsAreStoredFlaggedAndTheirHeadersNeedForce) {
  Recording a;
  a.end_s = 10000;
  a.temperature_c = [](double t) { return 20.0 + 0.001 * t; };
  a.gyro_dph = [](double t) {
    if (std::fmod(t, 1000.0) >= 60.0) return std::nan("");  // 60 s of every 1000
    const double temp_c = 20.0 + 0.001 * t;
    return kQualityBiasDph + 0.5 * (temp_c - 20.0) + 0.01 * std::sin(1.7 * t);
  };
  const int64_t run_a = make_run(
      {{"soak", "none", 0.0, 0, 10000}}, a,
      R"({"station": {"name": "q"}, "gyro": {"rate_hz": 10}, "analysis": {"model": "T2"}})");

  std::vector<Step> steps{{"soak", "static", 0.0, 0, 300}};
  double t = 300;
  for (int seq = 1; seq <= 2; ++seq) {
    for (int rep = 1; rep <= 2; ++rep) {
      for (double rate : {10.0, -10.0, 100.0, -100.0}) {
        steps.push_back({"rate", "rate", rate, t, t + 36.0, seq, rep, seq == 1 ? 20.0 : 40.0});
        t += 41.0;
      }
    }
  }
  const auto step_at = [steps](double time) -> const Step* {
    for (const Step& s : steps) {
      if (s.kind == "rate" && time >= s.from_s && time < s.to_s) return &s;
    }
    return nullptr;
  };
  Recording b;
  b.end_s = t + 5;
  b.temperature_c = [](double time) { return time < 625 ? 20.0 : 40.0; };
  b.gyro_dph = [step_at](double time) {
    const Step* s = step_at(time);
    if (s == nullptr) return kQualityBiasDph;
    double out_dps = (s->sf_sequence == 1 ? -kQualityK : kQualityK) * s->rate_dps;
    if (s->sf_sequence == 2 && s->sf_repetition == 1 && s->rate_dps == 10.0) out_dps += 500.0;
    return out_dps * 3600.0 + kQualityBiasDph;
  };
  b.table = [step_at](double time) {
    const Step* s = step_at(time);
    const double rate = s ? s->rate_dps : 0.0;
    return std::optional(table_reading(rate, std::fmod(rate * time, 360.0), "rate"));
  };
  const int64_t run_b = make_run(steps, b, kGuard1s);

  auto db = open();
  for (int64_t id : {run_a, run_b}) {
    auto summary = calibration::analyse_run(db, id, calibration::AnalysisSettings{});
    ASSERT_TRUE(summary.ok()) << summary.error().message;
  }
  // Stored flagged.
  auto fits = db.fits(run_a);
  ASSERT_TRUE(fits.ok());
  ASSERT_EQ(fits->size(), 2u);  // centred and paper forms
  for (const auto& f : *fits) {
    EXPECT_EQ(f.quality.verdict, "flagged") << f.form;
    ASSERT_TRUE(f.quality.coverage.has_value());
    EXPECT_NEAR(*f.quality.coverage, 0.06, 1e-9);
    ASSERT_FALSE(f.quality.reasons.empty());
    EXPECT_THAT(f.quality.reasons[0], HasSubstr("coverage 6.0 %"));
  }
  auto sf = db.scale_factor_fits(run_b);
  ASSERT_TRUE(sf.ok());
  ASSERT_EQ(sf->size(), 2u);
  EXPECT_LT((*sf)[0].k, 0);
  EXPECT_EQ((*sf)[0].quality.verdict, "flagged");
  EXPECT_THAT((*sf)[0].quality.reasons, ::testing::Contains(HasSubstr("is not positive")));
  EXPECT_GT((*sf)[1].nonlinearity_ppm, 1e7);
  EXPECT_EQ((*sf)[1].quality.verdict, "flagged");
  EXPECT_THAT((*sf)[1].quality.reasons, ::testing::Contains(HasSubstr("nonlinearity")));

  // The export leaves the headers out and says why.
  calibration::ExportRequest request;
  request.run_ids = {run_a, run_b};
  request.directory = (dir_ / "export").string();
  auto out = calibration::write_export(db, request);
  ASSERT_TRUE(out.ok()) << out.error().message;
  const fs::path run_a_dir = dir_ / "export" / fmt::format("run-{:04}", run_a);
  const fs::path run_b_dir = dir_ / "export" / fmt::format("run-{:04}", run_b);
  EXPECT_TRUE(fs::exists(run_a_dir / "drift-fit-centered.json"));
  EXPECT_FALSE(fs::exists(run_a_dir / "drift-fit-centered.h"));
  EXPECT_FALSE(fs::exists(run_a_dir / "drift-fit-paper.h"));
  EXPECT_TRUE(fs::exists(run_b_dir / "scale-factor.json"));
  EXPECT_FALSE(fs::exists(run_b_dir / "scale-factor.h"));
  EXPECT_THAT(out->problems, ::testing::Contains(::testing::AllOf(
                                 HasSubstr("drift-fit-centered.h not written"),
                                 HasSubstr("coverage 6.0 %"), HasSubstr("--force"))));
  EXPECT_THAT(out->problems,
              ::testing::Contains(::testing::AllOf(HasSubstr("scale-factor.h not written"),
                                                   HasSubstr("sequence 1: K = "),
                                                   HasSubstr("sequence 2: nonlinearity"))));
  const std::string page = testing::read_text(run_a_dir / "report.html");
  EXPECT_THAT(page, HasSubstr("<p class=\"flagged\">FLAGGED: coverage 6.0 %"));

  // Forced: written, and the header says it was forced and why.
  request.directory = (dir_ / "forced").string();
  request.report.force_flagged = true;
  auto forced = calibration::write_export(db, request);
  ASSERT_TRUE(forced.ok()) << forced.error().message;
  const std::string drift = testing::read_text(dir_ / "forced" / fmt::format("run-{:04}", run_a) /
                                               "drift-fit-centered.h");
  EXPECT_EQ(drift.rfind("/* FORCED: written with --force although gyrotherm flagged", 0), 0u);
  EXPECT_THAT(drift, HasSubstr(" *   coverage 6.0 %"));
  const std::string scale =
      testing::read_text(dir_ / "forced" / fmt::format("run-{:04}", run_b) / "scale-factor.h");
  EXPECT_EQ(scale.rfind("/* FORCED:", 0), 0u);
  EXPECT_THAT(scale, HasSubstr("sequence 1: K = "));
  EXPECT_THAT(forced->problems, ::testing::Contains(HasSubstr("written with --force")));
}

}  // namespace
}  // namespace gyrotherm

// The run analysis on a station with a rate table, on a real SQLite file
// written through the SampleWriter: Table I takes the static soaks only and
// removes the Earth-rate projection of the table's recorded position; the
// scale factor is fitted from the rate points' windows; the drift fit
// leaves the spinning stretches out.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/calibration/scale_factor_run.h"
#include "gyrotherm/core/units.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "integration/temp_dir_test.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;

constexpr double kLatitudeDeg = 31.9;
constexpr double kHeadingDeg = 30.0;
constexpr double kBiasDph = 2.0;
constexpr double kK = 1.000123;  // the gyro's scale factor in this file's runs
constexpr double kRateHz = 10.0;

class TableAnalysisTest : public testing::TempDirTest {
 protected:
  TableAnalysisTest() : TempDirTest("gyrotherm-table-analysis") {}

  struct Segment {
    std::string kind;
    std::string table_mode;
    double rate_dps = 0;
    double from_s = 0, to_s = 0;
    int sf_sequence = 0;
    int sf_repetition = 0;
  };

  // A run at 20 °C whose gyro reads kK·(table rate) + kBiasDph + the Earth
  // rate's projection on a radial axis at `position_deg`, with the table's
  // record at 1 Hz.
  int64_t make_run(const std::vector<Segment>& segments, double position_deg) {
    const std::string db_path = (dir_ / "station.db").string();
    auto db = storage::Database::open(db_path);
    EXPECT_TRUE(db.ok());
    storage::RunRecord run;
    run.schedule_name = "table run";
    run.state = "acquiring";
    run.latitude_deg = kLatitudeDeg;
    run.orientation = "up";
    run.config_json =
        fmt::format(R"({{"station": {{"name": "t"}}, "table": {{"sensitive_axis": "radial", )"
                    R"("heading_at_zero_deg": {}}}}})",
                    kHeadingDeg);
    auto id = db->create_run(run);
    EXPECT_TRUE(id.ok());
    auto writer = storage::SampleWriter::start(db_path);
    EXPECT_TRUE(writer.ok());
    const double earth_dph = analysis::earth_rate_projection_dph(
        kLatitudeDeg, analysis::SensitiveAxis::kRadial, kHeadingDeg, position_deg);
    int index = 0;
    for (const Segment& s : segments) {
      storage::SegmentRecord rec;
      rec.run_id = *id;
      rec.index = index++;
      rec.kind = s.kind;
      rec.label = s.kind;
      rec.setpoint_c = 20.0;
      rec.t_start_s = s.from_s;
      rec.t_end_s = s.to_s;
      rec.t_acquire_start_s = s.from_s;
      rec.t_acquire_end_s = s.to_s;
      rec.state = "completed";
      rec.table_mode = s.table_mode;
      if (s.table_mode == "rate") rec.table_rate_dps = s.rate_dps;
      rec.sf_sequence = s.sf_sequence;
      rec.sf_repetition = s.sf_repetition;
      auto sid = db->create_segment(rec);
      EXPECT_TRUE(sid.ok());
      rec.id = *sid;
      rec.windows = {{s.from_s, s.to_s}};
      EXPECT_TRUE(db->update_segment(rec).ok());
      std::vector<GyroSample> gyro;
      for (double t = s.from_s; t < s.to_s; t += 1.0 / kRateHz) {
        GyroSample g;
        g.t_s = t;
        g.rate_dph = kK * (s.rate_dps * 3600.0 + earth_dph) + kBiasDph;
        gyro.push_back(g);
      }
      (*writer)->push_gyro(*id, gyro);
      for (double t = s.from_s; t < s.to_s; t += 1.0) {
        TemperatureSample temp;
        temp.t_s = t;
        temp.setpoint_c = temp.chamber_c = 20.0;
        temp.top_c = 20.0 + 0.001 * t;  // a slope, so the drift fit has a temperature to fit
        temp.side_c = temp.top_c;
        (*writer)->push_temperature(*id, temp);
        TableSample table;
        table.t_s = t;
        table.demand_mode = s.table_mode;
        table.demand_rate_dps = s.rate_dps;
        table.rate_dps = s.rate_dps;
        table.position_deg = s.rate_dps == 0 ? position_deg : std::fmod(s.rate_dps * t, 360.0);
        table.mode = s.rate_dps == 0 ? "position" : "rate";
        table.interlock = "closed";
        (*writer)->push_table(*id, table);
      }
    }
    EXPECT_TRUE((*writer)->flush().ok());
    (*writer)->stop();
    EXPECT_TRUE(db->set_run_state(*id, "completed", true).ok());
    return *id;
  }
};

TEST_F(TableAnalysisTest, TableIOfStaticSoaksRemovesTheEarthRateOfTheRecordedPosition) {
  const double position_deg = 20.0;  // heading 50°: 0.64 of the horizontal Earth rate
  const int64_t run_id = make_run({{"soak", "static", 0.0, 0, 600},
                                   {"soak", "rate", 10.0, 600, 1200},  // spinning: not Table I
                                   {"soak", "none", 0.0, 1200, 1800}},
                                  position_deg);
  auto db = storage::Database::open((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok());
  auto soaks = calibration::soak_windows(*db, run_id);
  ASSERT_TRUE(soaks.ok()) << soaks.error().message;
  ASSERT_EQ(soaks->size(), 2u) << "the spinning soak is not a zero-bias soak";
  EXPECT_EQ((*soaks)[0].segment_index, 0);
  EXPECT_EQ((*soaks)[1].segment_index, 2);

  analysis::Table1Options options;  // the up-axis component, which a radial mount replaces
  options.earth_rate_dph = 7.95;
  auto row = calibration::soak_table1(*db, (*soaks)[0], options);
  ASSERT_TRUE(row.ok()) << row.error().message;
  const double expected_earth_dph = units::kEarthRateDph *
                                    std::cos(units::deg_to_rad(kLatitudeDeg)) *
                                    std::cos(units::deg_to_rad(kHeadingDeg + position_deg));
  EXPECT_NEAR(row->earth_rate_dph, expected_earth_dph, 1e-9);
  // The bias with the Earth rate removed is the gyro's own, and the scale
  // factor's share of the Earth rate: (K − 1)·Earth.
  EXPECT_NEAR(row->bias_mean_earth_removed_dph, kBiasDph + (kK - 1.0) * expected_earth_dph, 1e-9);
}

TEST_F(TableAnalysisTest, ScaleFactorFromTheRatePointsWindows) {
  std::vector<Segment> segments{{"soak", "static", 0.0, 0, 300}};
  double t = 300;
  for (int rep = 1; rep <= 2; ++rep) {
    for (double rate : {10.0, -10.0, 100.0, -100.0}) {
      const double dwell_s = 36.0;  // 1 turn at 10 °/s, 10 at 100 °/s
      segments.push_back({"rate", "rate", rate, t, t + dwell_s, 1, rep});
      t += dwell_s + 5;
    }
  }
  const int64_t run_id = make_run(segments, 0.0);
  auto db = storage::Database::open((dir_ / "station.db").string());
  ASSERT_TRUE(db.ok());
  auto summary = calibration::analyse_scale_factor(*db, run_id);
  ASSERT_TRUE(summary.ok()) << summary.error().message;
  EXPECT_EQ(summary->points, 8);
  EXPECT_EQ(summary->sequences, 1);
  EXPECT_TRUE(summary->problems.empty()) << summary->problems.front();
  auto fits = db->scale_factor_fits(run_id);
  ASSERT_TRUE(fits.ok());
  ASSERT_EQ(fits->size(), 1u);
  // Noise-free: the line is the gyro's (its bias and the Earth rate's
  // projection make the intercept).
  EXPECT_NEAR((*fits)[0].k, kK, 1e-12);
  ASSERT_TRUE((*fits)[0].asymmetry_ppm.has_value());
  EXPECT_NEAR(*(*fits)[0].asymmetry_ppm, 0.0, 1e-6);
  ASSERT_TRUE((*fits)[0].repeatability_ppm.has_value());
  EXPECT_NEAR(*(*fits)[0].repeatability_ppm, 0.0, 1e-6);
  EXPECT_NEAR((*fits)[0].temperature_c, 20.0 + 0.001 * 480, 0.2);  // the points' mean
  auto points = db->scale_factor_points(run_id);
  ASSERT_TRUE(points.ok());
  ASSERT_EQ(points->size(), 8u);
  for (const auto& p : *points) {
    EXPECT_NEAR(p.measured_rate_dps, p.rate_dps, 1e-12);
    // The default 1 s guard band at each end: at 100 °/s whole turns are
    // left (9 of 3.6 s), at 10 °/s less than the one turn of 36 s.
    EXPECT_EQ(p.guard_s, 1.0);
    if (std::abs(p.rate_dps) == 100.0) {
      EXPECT_NEAR(p.turns, 9.0, 1e-9);
    } else {
      EXPECT_NEAR(p.turns, 34.0 / 36.0, 1e-9);
    }
  }
  // Each table step's measured means are in its segment.
  auto segs = db->segments(run_id);
  ASSERT_TRUE(segs.ok());
  for (const auto& s : *segs) {
    ASSERT_TRUE(s.table_mean_rate_dps.has_value()) << s.index;
    EXPECT_NEAR(*s.table_mean_rate_dps, s.table_rate_dps.value_or(0.0), 1e-9);
  }
}

}  // namespace
}  // namespace gyrotherm

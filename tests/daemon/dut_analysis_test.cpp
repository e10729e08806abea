// The run analysis and the exports per DUT and axis, on a real SQLite file
// written through the SampleWriter's push_frames: two DUTs in one run with
// different biases and orientations; each DUT axis's Table I recovers its
// own bias with the Earth rate of its own orientation removed, the drift
// fits and Allan records carry the DUT and axis, and the export has files
// per DUT axis whose C headers name the gyro, its model and the run's
// operator.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/calibration/exporter.h"
#include "gyrotherm/calibration/report.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/core/units.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "integration/temp_dir_test.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;

constexpr double kLatitudeDeg = 48.1;
constexpr double kRateHz = 10.0;
constexpr double kBiasAzDph = 1.5;   // SN-A, z up
constexpr double kBiasBzDph = -0.7;  // SN-B, z down
constexpr double kBiasBxDph = 3.25;  // SN-B, x horizontal
// Each soak's 1 s bins carry a ±0.02 °/h ripple (zero mean over whole
// periods of 20 s): the Table I mean is the bias to ~1e-6 °/h.
constexpr double kRippleDph = 0.02;
constexpr double kTolDph = 1e-4;

ChannelSpec rate(const char* name, const char* axis) {
  return {name, "deg/h", ChannelKind::kRate, axis, 1.0};
}

std::string read_file(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

class DutAnalysisTest : public testing::TempDirTest {
 protected:
  DutAnalysisTest() : TempDirTest("gyrotherm-dut-analysis") {}

  std::string db_path() const { return (dir_ / db_name_).string(); }
  std::string db_name_ = "station.db";

  // How SN-B's horizontal x axis sits: without a heading (east–west, no
  // Earth rate), or at heading_deg; with a table at table_position_deg (the
  // DUTs turn with it; the run then has a table, along_table).
  struct Mount {
    std::optional<double> heading_bx_deg;
    std::optional<double> table_position_deg;
  };
  // The Earth rate on SN-B x, written out here: Ω cos φ cos(h + p).
  static double earth_bx_dph(const Mount& m) {
    if (!m.heading_bx_deg) return 0.0;
    return 15.041067 * std::cos(kLatitudeDeg * M_PI / 180.0) *
           std::cos((*m.heading_bx_deg + m.table_position_deg.value_or(0.0)) * M_PI / 180.0);
  }

  // Two soaks (20 and 40 °C, 600 s each) of two DUTs: SN-A (z up) and SN-B
  // (z down, x horizontal), at 10 Hz.
  int64_t make_run(const Mount& mount = {}) {
    auto db = storage::Database::open(db_path());
    EXPECT_TRUE(db.ok()) << db.error().message;
    storage::RunRecord run;
    run.schedule_name = "two gyros";
    run.state = "acquiring";
    run.latitude_deg = kLatitudeDeg;
    run.orientation = "up";
    // A model the two soaks' temperatures can determine.
    run.config_json =
        mount.table_position_deg
            ? R"({"station": {"name": "bench-2"}, "analysis": {"model": "T1"}, )"
              R"("table": {"sensitive_axis": "along_table", "heading_at_zero_deg": 0.0}})"
            : R"({"station": {"name": "bench-2"}, "analysis": {"model": "T1"}})";
    auto id = db->create_run(run);
    EXPECT_TRUE(id.ok()) << id.error().message;
    // The run's metadata as queued (schema v8 columns of runs).
    EXPECT_TRUE(db->exec(fmt::format("UPDATE runs SET operator = 'alice', comment = 'two IMUs, "
                                     "first campaign', tags_json = '[\"qual\",\"lot-7\"]', "
                                     "dut_serials_json = '[\"SN-A\",\"SN-B\"]' WHERE id = {}",
                                     *id))
                    .ok());

    storage::RunDutRecord a;
    a.run_id = *id;
    a.position = 0;
    a.dut = {0, "SN-A", "KVH 1750", ""};
    a.primary_axis = "z";
    a.axes = {"z"};
    a.rate_hz = kRateHz;
    a.config_json = R"({"serial": "SN-A", "orientation": {"z": "up"}, "table_axis": "z"})";
    for (const auto& spec : {rate("gyro_x", "x"), rate("gyro_y", "y"), rate("gyro_z", "z"),
                             ChannelSpec{"temp_c", "degC", ChannelKind::kTemperature, "", 1.0}}) {
      a.channels.push_back({0, 0, 0, static_cast<int>(a.channels.size()), spec});
    }
    storage::RunDutRecord b = a;
    b.position = 1;
    b.dut = {0, "SN-B", "FOG-3", ""};
    b.axes = {"x", "z"};
    b.config_json = R"({"serial": "SN-B", "orientation": {"z": "down", "x": "horizontal"})";
    if (mount.heading_bx_deg) {
      b.config_json += fmt::format(R"(, "heading_deg": {{"x": {}}})", *mount.heading_bx_deg);
    }
    b.config_json += "}";
    auto ra = db->add_run_dut(*id, a);
    auto rb = db->add_run_dut(*id, b);
    EXPECT_TRUE(ra.ok()) << ra.error().message;
    EXPECT_TRUE(rb.ok()) << rb.error().message;

    auto writer = storage::SampleWriter::start(db_path());
    EXPECT_TRUE(writer.ok());
    const double earth_up =
        analysis::earth_rate_component_dph(kLatitudeDeg, analysis::AxisOrientation::kUp);
    int index = 0;
    for (double setpoint : {20.0, 40.0}) {
      const double from_s = index * 700.0, to_s = from_s + 600.0;
      storage::SegmentRecord seg;
      seg.run_id = *id;
      seg.index = index++;
      seg.kind = "soak";
      seg.label = fmt::format("soak {} °C", setpoint);
      seg.setpoint_c = setpoint;
      seg.t_start_s = from_s;
      seg.t_end_s = to_s;
      seg.t_acquire_start_s = from_s;
      seg.t_acquire_end_s = to_s;
      seg.state = "completed";
      auto sid = db->create_segment(seg);
      EXPECT_TRUE(sid.ok());
      seg.id = *sid;
      seg.windows = {{from_s, to_s}};
      EXPECT_TRUE(db->update_segment(seg).ok());
      std::vector<DutFrame> fa, fb;
      const int n = static_cast<int>((to_s - from_s) * kRateHz);
      for (int k = 0; k < n; ++k) {
        const double t = from_s + k / kRateHz;
        const double ripple = kRippleDph * std::sin(2 * M_PI * t / 20.0);
        DutFrame f;
        f.t_s = t;
        f.seq = static_cast<uint32_t>(k % 128);
        f.raw = {};
        f.raw[2] = kBiasAzDph + earth_up + ripple;
        f.raw[3] = setpoint;
        fa.push_back(f);
        DutFrame g = f;
        g.raw[0] = kBiasBxDph + earth_bx_dph(mount) + ripple;  // horizontal
        g.raw[2] = kBiasBzDph - earth_up + ripple;
        fb.push_back(g);
      }
      (*writer)->push_frames(*ra, fa);
      (*writer)->push_frames(*rb, fb);
      for (double t = from_s; t < to_s; t += 1.0) {
        TemperatureSample temp;
        temp.t_s = t;
        temp.setpoint_c = temp.chamber_c = setpoint;
        temp.top_c = setpoint + 0.001 * (t - from_s);
        temp.side_c = temp.top_c - 0.1;
        (*writer)->push_temperature(*id, temp);
        if (mount.table_position_deg) {
          TableSample table;
          table.t_s = t;
          table.demand_mode = "position";
          table.demand_position_deg = *mount.table_position_deg;
          table.position_deg = *mount.table_position_deg;
          table.mode = "position";
          table.interlock = "closed";
          (*writer)->push_table(*id, table);
        }
      }
    }
    EXPECT_TRUE((*writer)->flush().ok());
    (*writer)->stop();
    EXPECT_TRUE(db->set_run_state(*id, "completed", true).ok());
    return *id;
  }
};

TEST_F(DutAnalysisTest, EachDutAxisRecoversItsOwnBiasWithItsOwnEarthRate) {
  const int64_t run_id = make_run();
  auto db = storage::Database::open(db_path());
  ASSERT_TRUE(db.ok());
  auto axes = calibration::analysed_axes(*db, run_id);
  ASSERT_TRUE(axes.ok()) << axes.error().message;
  ASSERT_EQ(axes->size(), 3u);
  EXPECT_EQ((*axes)[0].dut_serial, "SN-A");
  EXPECT_EQ((*axes)[1].dut_serial, "SN-B");
  EXPECT_EQ((*axes)[1].axis, "z") << "the primary axis first";
  EXPECT_EQ((*axes)[2].axis, "x");

  calibration::AnalysisSettings settings;
  settings.model = {.t_order = 1, .r_order = 0, .g_order = 0};
  auto summary = calibration::analyse_run(*db, run_id, settings);
  ASSERT_TRUE(summary.ok()) << summary.error().message;
  EXPECT_EQ(summary->streams, 3);
  EXPECT_EQ(summary->table1_rows, 6);
  EXPECT_EQ(summary->allan_records, 6);

  const double earth_up =
      units::kEarthRateDph * std::sin(units::deg_to_rad(kLatitudeDeg));  // independent of the lib
  const std::map<std::pair<std::string, std::string>, std::pair<double, double>> truth = {
      {{"SN-A", "z"}, {kBiasAzDph, earth_up}},
      {{"SN-B", "z"}, {kBiasBzDph, -earth_up}},
      {{"SN-B", "x"}, {kBiasBxDph, 0.0}}};
  auto rows = db->segment_stats(run_id);
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), 6u);
  for (const auto& row : *rows) {
    const auto it = truth.find({row.dut_serial, row.axis});
    ASSERT_NE(it, truth.end()) << row.dut_serial << " " << row.axis;
    EXPECT_NEAR(row.earth_rate_dph, it->second.second, 1e-9) << row.dut_serial << row.axis;
    EXPECT_NEAR(row.bias_mean_earth_removed_dph, it->second.first, kTolDph)
        << row.dut_serial << " " << row.axis << " step " << row.segment_index + 1;
    EXPECT_EQ(row.n, 600);
  }
  auto allan = db->allan(run_id);
  ASSERT_TRUE(allan.ok());
  for (const auto& a : *allan) EXPECT_TRUE(truth.count({a.dut_serial, a.axis})) << a.dut_serial;
  auto fits = db->fits(run_id);
  ASSERT_TRUE(fits.ok());
  std::map<std::pair<std::string, std::string>, int> fits_per_axis;
  for (const auto& f : *fits) ++fits_per_axis[{f.dut_serial, f.axis}];
  ASSERT_FALSE(fits_per_axis.empty());
  for (const auto& [key, count] : fits_per_axis) {
    EXPECT_TRUE(truth.count(key)) << key.first << " " << key.second;
    EXPECT_EQ(count, fits_per_axis.begin()->second) << "each axis fitted alike";
  }
}

// A horizontal axis with a stored heading: Table I removes Ω cos φ cos h,
// and with a table the DUT turns with it: cos(h + the table's position).
TEST_F(DutAnalysisTest, HorizontalAxisWithAHeadingHasItsEarthRateRemoved) {
  int case_number = 0;
  for (const Mount& mount : {Mount{60.0, std::nullopt}, Mount{200.0, std::nullopt},
                             Mount{60.0, 45.0}, Mount{std::nullopt, 45.0}}) {
    const std::string what =
        fmt::format("heading {} position {}", mount.heading_bx_deg.value_or(-1),
                    mount.table_position_deg.value_or(-1));
    db_name_ = fmt::format("station-{}.db", ++case_number);  // a database per case
    const int64_t run_id = make_run(mount);
    auto db = storage::Database::open(db_path());
    ASSERT_TRUE(db.ok());
    auto axes = calibration::analysed_axes(*db, run_id);
    ASSERT_TRUE(axes.ok()) << axes.error().message;
    ASSERT_EQ(axes->size(), 3u);
    EXPECT_EQ((*axes)[2].heading_deg, mount.heading_bx_deg) << what;
    calibration::AnalysisSettings settings;
    settings.model = {.t_order = 1, .r_order = 0, .g_order = 0};
    auto summary = calibration::analyse_run(*db, run_id, settings);
    ASSERT_TRUE(summary.ok()) << summary.error().message;
    EXPECT_EQ(summary->table1_rows, 6) << what;
    auto rows = db->segment_stats(run_id);
    ASSERT_TRUE(rows.ok());
    int bx_rows = 0;
    for (const auto& row : *rows) {
      if (row.dut_serial != "SN-B" || row.axis != "x") continue;
      ++bx_rows;
      EXPECT_NEAR(row.earth_rate_dph, earth_bx_dph(mount), 1e-9) << what;
      EXPECT_NEAR(row.bias_mean_earth_removed_dph, kBiasBxDph, kTolDph) << what;
    }
    EXPECT_EQ(bx_rows, 2) << what;
  }
  // 60° at latitude 48.1°: 5.0225 °/h (numpy), not the 0 an east–west axis has.
  EXPECT_NEAR(earth_bx_dph({60.0, std::nullopt}), 5.022457105810615, 1e-12);
}

TEST_F(DutAnalysisTest, RunSeriesStreamsEachAxisOwnSamples) {
  const int64_t run_id = make_run();
  auto db = storage::Database::open(db_path());
  ASSERT_TRUE(db.ok());
  auto axes = calibration::analysed_axes(*db, run_id);
  ASSERT_TRUE(axes.ok());
  for (const auto& axis : *axes) {
    auto s = calibration::run_series(*db, run_id, 1.0, axis);
    ASSERT_TRUE(s.ok()) << s.error().message;
    EXPECT_EQ(s->t_s.size(), 1200u) << axis.name();  // 2 soaks x 600 bins of 1 s
  }
}

TEST_F(DutAnalysisTest, ExportHasFilesPerDutAxisAndHeadersNameTheGyro) {
  const int64_t run_id = make_run();
  auto db = storage::Database::open(db_path());
  ASSERT_TRUE(db.ok());
  calibration::AnalysisSettings settings;
  settings.model = {.t_order = 1, .r_order = 0, .g_order = 0};
  auto summary = calibration::analyse_run(*db, run_id, settings);
  ASSERT_TRUE(summary.ok());
  EXPECT_EQ(summary->fit_ids.size(), 6u) << fmt::format("{}", fmt::join(summary->problems, "\n"));
  calibration::ExportRequest request;
  request.run_ids = {run_id};
  request.directory = (dir_ / "export").string();
  request.report.generated_utc = "2026-11-27T04:00:00Z";
  auto out = calibration::write_export(*db, request);
  ASSERT_TRUE(out.ok()) << out.error().message;
  const fs::path root = dir_ / "export";
  const std::string run_dir = fmt::format("run-{:04}", run_id);
  for (const char* sfx : {"-SN-A-z", "-SN-B-z", "-SN-B-x"}) {
    for (const std::string& name :
         {fmt::format("report{}.html", sfx), fmt::format("table1{}.csv", sfx),
          fmt::format("allan{}.csv", sfx), fmt::format("drift-fit-centered{}.json", sfx),
          fmt::format("drift-fit-centered{}.h", sfx), fmt::format("drift-fit-paper{}.h", sfx)}) {
      EXPECT_TRUE(fs::exists(root / run_dir / name)) << name;
    }
    EXPECT_TRUE(fs::exists(root / fmt::format("summary{}.html", sfx))) << sfx;
  }
  EXPECT_TRUE(fs::exists(root / run_dir / "report.html")) << "the run's index of DUT axes";
  EXPECT_TRUE(fs::exists(root / "index.html")) << "the summary across DUTs";
  EXPECT_FALSE(fs::exists(root / run_dir / "drift-fit-centered.h")) << "no unnamed file";

  const std::string header = read_file(root / run_dir / "drift-fit-centered-SN-B-x.h");
  EXPECT_NE(header.find("gyro: SN-B;"), std::string::npos) << header.substr(0, 600);
  EXPECT_NE(header.find("Model: FOG-3; axis: x; operator: alice; tags: qual, lot-7"),
            std::string::npos)
      << header.substr(0, 600);
  EXPECT_NE(header.find(fmt::format("runs: {};", run_id)), std::string::npos);
  EXPECT_EQ(header.find("(no serial)"), std::string::npos);
  const std::string json = read_file(root / run_dir / "drift-fit-centered-SN-A-z.json");
  EXPECT_NE(json.find("\"gyro_serial\": \"SN-A\""), std::string::npos);
  EXPECT_NE(json.find("\"operator\": \"alice\""), std::string::npos);
  const std::string report = read_file(root / run_dir / "report-SN-A-z.html");
  for (const char* text :
       {"SN SN-A (KVH 1750), axis z", "alice", "two IMUs, first campaign", "qual, lot-7"}) {
    EXPECT_NE(report.find(text), std::string::npos) << text;
  }
  const std::string index = read_file(root / "index.html");
  EXPECT_NE(index.find("summary-SN-B-x.html"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm

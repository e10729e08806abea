// The offline analysis commands on runs of several DUTs: the real gyrotherm
// binary on a SQLite file written through SampleWriter::push_frames. Four
// runs (start temperatures −10, 5, 20, 35 °C: soak, ramp of +20 °C, soak)
// of two DUTs, SN-A (z) and SN-B (z primary, x), each axis with its own
// known drift a + b·T. Every command analyses every DUT axis unless
// --dut/--axis name some, each row and fit naming its DUT and axis, and
// each number is its own axis's truth.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <tuple>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using ::testing::HasSubstr;

constexpr int kDutRuns = 4;
constexpr double kDutRunStartC[kDutRuns] = {-10.0, 5.0, 20.0, 35.0};
constexpr double kRateHz = 10.0;
constexpr double kRunS = 1500.0;
// A ±0.02 °/h ripple of period 20 s: zero mean over whole periods, so the
// soaks' means are the drift's own; it gives the fits a residual.
constexpr double kRippleDph = 0.02;

// Each DUT axis's drift, °/h: a + b·T.
struct Drift {
  double a_dph, b_dph_per_c;
};
const std::map<std::pair<std::string, std::string>, Drift> kTruth = {
    {{"SN-A", "z"}, {1.5, 0.2}}, {{"SN-B", "z"}, {-0.7, -0.3}}, {{"SN-B", "x"}, {3.25, 0.1}}};

// The shell: soak at T0 until 400 s, +20 °C by 1000 s, then soak.
double dut_shell_c(double t0_c, double t_s) {
  if (t_s < 400) return t0_c;
  if (t_s < 1000) return t0_c + 20.0 * (t_s - 400) / 600;
  return t0_c + 20.0;
}

ChannelSpec rate(const char* name, const char* axis) {
  return {name, "deg/h", ChannelKind::kRate, axis, 1.0};
}

class CliDutsAnalysisTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / fmt::format("gyrotherm-cli-duts-{}", ::getpid());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    db_path_ = (dir_ / "station.db").string();
    auto db = storage::Database::open(db_path_);
    ASSERT_TRUE(db.ok()) << db.error().message;
    auto writer = storage::SampleWriter::start(db_path_);
    ASSERT_TRUE(writer.ok()) << writer.error().message;
    for (int k = 0; k < kDutRuns; ++k) {
      storage::RunRecord run;
      run.schedule_name = fmt::format("two gyros {}", k);
      run.state = "acquiring";
      run.latitude_deg = 48.1;
      run.orientation = "up";
      run.config_json = R"({"station": {"name": "bench-2"}, "analysis": {"model": "T1"}})";
      run.metadata.operator_name = "alice";
      auto id = db->create_run(run);
      ASSERT_TRUE(id.ok()) << id.error().message;
      storage::RunDutRecord a;
      a.run_id = *id;
      a.position = 0;
      a.dut = {0, "SN-A", "KVH 1750", ""};
      a.primary_axis = "z";
      a.axes = {"z"};
      a.rate_hz = kRateHz;
      a.config_json = R"({"serial": "SN-A", "orientation": {"z": "up"}})";
      for (const auto& spec : {rate("gyro_x", "x"), rate("gyro_y", "y"), rate("gyro_z", "z")}) {
        a.channels.push_back({0, 0, 0, static_cast<int>(a.channels.size()), spec});
      }
      storage::RunDutRecord b = a;
      b.position = 1;
      b.dut = {0, "SN-B", "FOG-3", ""};
      b.axes = {"x", "z"};
      b.config_json = R"({"serial": "SN-B", "orientation": {"z": "down", "x": "horizontal"}})";
      auto ra = db->add_run_dut(*id, a);
      auto rb = db->add_run_dut(*id, b);
      ASSERT_TRUE(ra.ok()) << ra.error().message;
      ASSERT_TRUE(rb.ok()) << rb.error().message;

      int index = 0;
      for (const auto& [kind, from_s, to_s, windows] : std::vector<
               std::tuple<const char*, double, double, std::vector<std::pair<double, double>>>>{
               {"soak", 0.0, 400.0, {{40.0, 380.0}}},
               {"ramp", 400.0, 1000.0, {}},
               {"soak", 1000.0, 1500.0, {{1040.0, 1480.0}}}}) {
        storage::SegmentRecord seg;
        seg.run_id = *id;
        seg.index = index++;
        seg.kind = kind;
        seg.label = fmt::format("{} (step {})", kind, index);
        seg.setpoint_c = dut_shell_c(kDutRunStartC[k], to_s - 1);
        seg.t_start_s = from_s;
        seg.t_end_s = to_s;
        if (!windows.empty()) {
          seg.t_acquire_start_s = windows.front().first;
          seg.t_acquire_end_s = windows.back().second;
        }
        seg.state = "completed";
        auto sid = db->create_segment(seg);
        ASSERT_TRUE(sid.ok()) << sid.error().message;
        seg.id = *sid;
        seg.windows = windows;
        ASSERT_TRUE(db->update_segment(seg).ok());
      }

      std::vector<DutFrame> fa, fb;
      for (int i = 0; i < static_cast<int>(kRunS * kRateHz); ++i) {
        const double t = i / kRateHz;
        const double temp_c = dut_shell_c(kDutRunStartC[k], t);
        const double ripple = kRippleDph * std::sin(2 * M_PI * t / 20.0);
        auto drift = [&](const char* serial, const char* axis) {
          const Drift& d = kTruth.at({serial, axis});
          return d.a_dph + d.b_dph_per_c * temp_c + ripple;
        };
        DutFrame f;
        f.t_s = t;
        f.seq = static_cast<uint32_t>(i % 128);
        f.raw = {};
        f.raw[2] = drift("SN-A", "z");
        fa.push_back(f);
        DutFrame g = f;
        g.raw[0] = drift("SN-B", "x");
        g.raw[2] = drift("SN-B", "z");
        fb.push_back(g);
      }
      (*writer)->push_frames(*ra, fa);
      (*writer)->push_frames(*rb, fb);
      for (double t = 0; t < kRunS; t += 1.0) {
        TemperatureSample temp;
        temp.t_s = t;
        temp.setpoint_c = temp.chamber_c = dut_shell_c(kDutRunStartC[k], t);
        temp.top_c = temp.setpoint_c + 0.05;
        temp.side_c = temp.setpoint_c - 0.05;
        (*writer)->push_temperature(*id, temp);
      }
      ASSERT_TRUE((*writer)->flush().ok());
      ASSERT_TRUE(db->set_run_state(*id, "completed", true).ok());
    }
    (*writer)->stop();
  }
  static void TearDownTestSuite() {
    if (!::testing::UnitTest::GetInstance()->Failed()) fs::remove_all(dir_);
  }

  struct Run {
    int code;
    std::string out, err;
    json parsed() const {
      json j = json::parse(out, nullptr, false);
      EXPECT_FALSE(j.is_discarded()) << "not JSON:\n" << out << err;
      return j;
    }
  };
  static Run cli(const std::vector<std::string>& args) {
    const std::string out = (dir_ / "out.txt").string(), err = (dir_ / "err.txt").string();
    std::string cmd = std::string(GYROTHERM_BIN_DIR) + "/gyrotherm";
    for (const auto& a : args) cmd += " '" + a + "'";
    cmd += " >" + out + " 2>" + err;
    const int st = std::system(cmd.c_str());
    return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, testing::read_text(out), testing::read_text(err)};
  }

  static inline fs::path dir_;
  static inline std::string db_path_;
};

std::pair<std::string, std::string> stream_of(const json& j) {
  return {j.at("dut_serial").get<std::string>(), j.at("axis").get<std::string>()};
}

TEST_F(CliDutsAnalysisTest, StatsGivesEveryDutAxisItsOwnRowsUnlessNamed) {
  const Run all = cli({"stats", "--db", db_path_, "--run", "1", "--json"});
  ASSERT_EQ(all.code, 0) << all.err;
  const json rows = all.parsed();
  ASSERT_EQ(rows.size(), 2u * 3u) << rows.dump(1);  // two soaks × three DUT axes
  std::map<std::pair<std::string, std::string>, int> per_stream;
  for (const json& r : rows) {
    const auto stream = stream_of(r);
    ASSERT_EQ(kTruth.count(stream), 1u) << r.dump();
    ++per_stream[stream];
    const Drift& d = kTruth.at(stream);
    // The soak's own temperature: T0 or T0 + 20 (run 1 starts at −10 °C).
    const double temp_c = r["segment"] == 1 ? kDutRunStartC[0] : kDutRunStartC[0] + 20.0;
    EXPECT_NEAR(r["bias_mean_dph"].get<double>(), d.a_dph + d.b_dph_per_c * temp_c, 1e-3)
        << r.dump();
  }
  EXPECT_EQ(per_stream.size(), 3u);

  const Run text = cli({"stats", "--db", db_path_, "--run", "1"});
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_THAT(text.out, HasSubstr("DUT")) << text.out;
  EXPECT_THAT(text.out, HasSubstr("SN-B")) << text.out;

  const Run one =
      cli({"stats", "--db", db_path_, "--run", "1", "--dut", "SN-B", "--axis", "x", "--json"});
  ASSERT_EQ(one.code, 0) << one.err;
  const json picked = one.parsed();
  ASSERT_EQ(picked.size(), 2u) << picked.dump(1);
  for (const json& r : picked) {
    EXPECT_EQ(stream_of(r), std::make_pair(std::string("SN-B"), std::string("x")));
  }

  // Grouped per DUT axis and set point: 3 DUT axes × 8 set points over the
  // four runs (−10, 10, 5, 25, 20, 40, 35, 55 °C), one soak each.
  const Run grouped = cli({"stats", "--db", db_path_, "--runs", "1-4", "--by-setpoint", "--json"});
  ASSERT_EQ(grouped.code, 0) << grouped.err;
  const json groups = grouped.parsed();
  EXPECT_EQ(groups.size(), 3u * 8u) << groups.dump(1);
  for (const json& g : groups) {
    const Drift& d = kTruth.at(stream_of(g));
    EXPECT_NEAR(g["bias_mean_dph"]["mean"].get<double>(),
                d.a_dph + d.b_dph_per_c * g["setpoint_c"].get<double>(), 1e-3)
        << g.dump();
  }
}

TEST_F(CliDutsAnalysisTest, AllanHasACurvePerSoakAndDutAxis) {
  const Run r = cli({"allan", "--db", db_path_, "--run", "2", "--dut", "SN-B", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json curves = r.parsed();
  ASSERT_EQ(curves.size(), 2u * 2u) << "two soaks × SN-B's z and x";
  std::map<std::string, int> axes;
  for (const json& c : curves) {
    EXPECT_EQ(c["dut_serial"], "SN-B");
    ++axes[c["axis"].get<std::string>()];
  }
  EXPECT_EQ(axes, (std::map<std::string, int>{{"x", 2}, {"z", 2}}));
}

TEST_F(CliDutsAnalysisTest, FitIsPerDutAxisAndItsHeaderNamesTheGyro) {
  const Run all = cli({"fit", "--db", db_path_, "--runs", "1-4", "--json"});
  ASSERT_EQ(all.code, 0) << all.err;
  const json fits = all.parsed();
  ASSERT_TRUE(fits.is_array()) << fits.dump(1);
  ASSERT_EQ(fits.size(), 3u);
  for (const json& f : fits) {
    const Drift& d = kTruth.at(stream_of(f));
    EXPECT_EQ(f["model"], "T1");
    EXPECT_NEAR(f["coefficients"]["T1"].get<double>(), d.b_dph_per_c, 1e-3) << f.dump();
  }
  // Text: a block per DUT axis.
  const Run text = cli({"fit", "--db", db_path_, "--runs", "1-4"});
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_THAT(text.out, HasSubstr("== SN SN-A z")) << text.out;
  EXPECT_THAT(text.out, HasSubstr("== SN SN-B x")) << text.out;

  // A header is one gyro axis: refused for three, written for the one named.
  const std::string header = (dir_ / "sn-b-x.h").string();
  const Run refused = cli({"fit", "--db", db_path_, "--runs", "1-4", "--c-header", header});
  EXPECT_EQ(refused.code, 2);
  EXPECT_THAT(refused.err, HasSubstr("choose one with --dut and --axis")) << refused.err;
  EXPECT_FALSE(fs::exists(header));
  const Run one = cli({"fit", "--db", db_path_, "--runs", "1-4", "--dut", "SN-B", "--axis", "x",
                       "--c-header", header, "--json"});
  ASSERT_EQ(one.code, 0) << one.err << one.out;
  const json fit = one.parsed();
  ASSERT_TRUE(fit.is_object()) << fit.dump(1);
  EXPECT_EQ(stream_of(fit), std::make_pair(std::string("SN-B"), std::string("x")));
  const std::string h = testing::read_text(header);
  EXPECT_THAT(h, HasSubstr("SN-B")) << h;
  EXPECT_THAT(h, HasSubstr("FOG-3")) << h;
  EXPECT_THAT(h, HasSubstr("alice")) << h;
  EXPECT_THAT(h, ::testing::Not(HasSubstr("(no serial)"))) << h;
}

TEST_F(CliDutsAnalysisTest, CompareAndStartModelRunPerDutAxis) {
  const Run cmp = cli({"compare", "--db", db_path_, "--runs", "1-4", "--max-order", "1", "--dut",
                       "SN-A", "--json"});
  ASSERT_EQ(cmp.code, 0) << cmp.err;
  const json c = cmp.parsed();
  ASSERT_TRUE(c.is_object()) << c.dump(1);
  EXPECT_EQ(stream_of(c), std::make_pair(std::string("SN-A"), std::string("z")));
  EXPECT_EQ(c["runs"], 4);

  const Run sm = cli({"start-model", "--db", db_path_, "--runs", "1-4", "--axis", "z", "--json"});
  ASSERT_EQ(sm.code, 0) << sm.err;
  const json models = sm.parsed();
  ASSERT_TRUE(models.is_array()) << models.dump(1);
  ASSERT_EQ(models.size(), 2u) << "SN-A z and SN-B z";
  EXPECT_EQ(models[0]["dut_serial"], "SN-A");
  EXPECT_EQ(models[1]["dut_serial"], "SN-B");
}

TEST_F(CliDutsAnalysisTest, AnUnknownDutOrAxisIsAUsageErrorSayingWhatTheRunsHold) {
  const Run dut = cli({"stats", "--db", db_path_, "--run", "1", "--dut", "SN-Z"});
  EXPECT_EQ(dut.code, 2);
  EXPECT_THAT(dut.err, HasSubstr("--dut SN-Z: not a DUT of run 1")) << dut.err;
  EXPECT_THAT(dut.err, HasSubstr("SN SN-B x")) << dut.err;
  const Run axis = cli({"fit", "--db", db_path_, "--runs", "1-4", "--dut", "SN-A", "--axis", "x"});
  EXPECT_EQ(axis.code, 2);
  EXPECT_THAT(axis.err, HasSubstr("--axis x: not an analysed axis")) << axis.err;
  const std::string csv = (dir_ / "one.csv").string();
  { std::ofstream(csv) << "t_s,rate_dph,top_c,side_c\n0,1,20,20\n1,1,20,20\n"; }
  const Run with_csv = cli({"stats", "--csv", csv, "--dut", "SN-A"});
  EXPECT_EQ(with_csv.code, 2);
  EXPECT_THAT(with_csv.err, HasSubstr("--dut and --axis go with --db")) << with_csv.err;
}

}  // namespace
}  // namespace gyrotherm

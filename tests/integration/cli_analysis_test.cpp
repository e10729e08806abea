// The offline analysis commands as a user runs them: the real gyrotherm
// binary on a SQLite database written through storage::Database and
// SampleWriter, and on CSV files. Its numbers must be exactly those of the
// analysis library (and of the daemon's run_analysis path) on the same data:
// JSON carries 17 significant digits, so doubles compare with ==.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "analysis.h"
#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/comparison.h"
#include "gyrotherm/analysis/csv_window.h"
#include "gyrotherm/analysis/drift_model.h"
#include "gyrotherm/analysis/noise_model.h"
#include "gyrotherm/analysis/scale_factor.h"
#include "gyrotherm/analysis/start_temperature.h"
#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/core/files.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "process.h"
#include "test_files.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using ::testing::HasSubstr;
using testing::read_text;

constexpr double kLatitudeDeg = 31.9;
constexpr int kStoredMaWindow = 51;  // the runs' [analysis] ma_window
constexpr int kRuns = 4;
constexpr double kStartC[kRuns] = {-10.0, 5.0, 20.0, 35.0};
constexpr int kGyroPerRun = 15000;  // 10 Hz over 1500 s
constexpr int kTempsPerRun = 1500;  // 1 Hz
constexpr const char* kAdaptiveStop =
    "target reached: U95 <= 0.05 °/h on every gated axis (1 of them) after 6 min";

// A run: soak at T0 for 400 s, a 600 s ramp of +20 °C, a soak for 500 s.
// The second soak's acquisition is cut in two by a pause.
const std::vector<std::pair<double, double>> kSoak1Windows = {{50.05, 380.05}};
const std::vector<std::pair<double, double>> kSoak2Windows = {{1050.05, 1200.05},
                                                              {1230.05, 1450.05}};

double shell_c(double t0_c, double t_s) {
  if (t_s < 400) return t0_c;
  if (t_s < 1000) return t0_c + 20.0 * (t_s - 400) / 600;
  return t0_c + 20.0;
}
double rate_c_per_s(double t_s) { return t_s >= 400 && t_s < 1000 ? 20.0 / 600 : 0.0; }
double gradient_c(double t_s) { return 0.3 + 6.0 * rate_c_per_s(t_s) + 0.05 * std::sin(t_s / 37); }

struct RunData {
  std::vector<GyroSample> gyro;
  std::vector<TemperatureSample> temps;
};

// Known drift: 8 °/h + a quadratic in T, 30 °/h per °C/s, 0.4 °/h per °C of
// gradient, and white noise of 0.5 °/h.
RunData make_run(int k) {
  std::mt19937_64 rng(1234 + k);
  std::normal_distribution<double> noise(0.0, 0.5);
  RunData d;
  for (int i = 0; i < kTempsPerRun; ++i) {
    const double t = i;
    const double T = shell_c(kStartC[k], t), g = gradient_c(t);
    d.temps.push_back({t, T, T, T + g / 2, T - g / 2});
  }
  for (int i = 0; i < kGyroPerRun; ++i) {
    const double t = i / 10.0;
    const double T = shell_c(kStartC[k], t);
    const double rate = 8.0 + 0.02 * (T - 20) + 0.001 * (T - 20) * (T - 20) +
                        30.0 * rate_c_per_s(t) + 0.4 * gradient_c(t) + noise(rng);
    d.gyro.push_back({t, rate, static_cast<uint8_t>(i % 128), 0x77, 20});
  }
  return d;
}

template <class S>
std::vector<S> in_window(const std::vector<S>& v, double from_s, double to_s) {
  std::vector<S> out;
  for (const auto& s : v) {
    if (s.t_s >= from_s && s.t_s < to_s) out.push_back(s);
  }
  return out;
}

// The analysis series of a soak computed here: each window binned on its own,
// joined (docs/analysis.md; run_analysis.h).
analysis::AnalysisSeries soak_series(const RunData& d,
                                     const std::vector<std::pair<double, double>>& windows) {
  analysis::AnalysisSeries joined;
  for (const auto& [from_s, to_s] : windows) {
    auto part = analysis::make_analysis_series(in_window(d.gyro, from_s, to_s),
                                               in_window(d.temps, from_s, to_s), 1.0);
    EXPECT_TRUE(part) << part.error().message;
    joined.bin_s = part->bin_s;
    for (auto [dst, src] :
         {std::pair{&joined.t_s, &part->t_s}, std::pair{&joined.rate_dph, &part->rate_dph},
          std::pair{&joined.top_c, &part->top_c}, std::pair{&joined.side_c, &part->side_c}}) {
      dst->insert(dst->end(), src->begin(), src->end());
    }
  }
  return joined;
}

analysis::AnalysisSeries run_series(const RunData& d) {
  auto s = analysis::make_analysis_series(d.gyro, d.temps, 1.0);
  EXPECT_TRUE(s) << s.error().message;
  return *s;
}

void write_text(const fs::path& p, const std::string& text) {
  std::ofstream(p, std::ios::binary) << text;
}

// A run as a CSV at the gyro's 10 Hz; each row takes the temperatures of the
// last 1 Hz reading. Numbers with 17 digits so they read back exactly.
std::string run_csv(const RunData& d, double from_s = -1, double to_s = 1e9) {
  std::string out = "t_s,rate_dph,top_c,side_c,comment\n";
  std::size_t ti = 0;
  for (const auto& g : d.gyro) {
    while (ti + 1 < d.temps.size() && d.temps[ti + 1].t_s <= g.t_s) ++ti;
    if (g.t_s < from_s || g.t_s >= to_s) continue;
    out += fmt::format("{:.17g},{:.17g},{:.17g},{:.17g},x\n", g.t_s, g.rate_dph, d.temps[ti].top_c,
                       d.temps[ti].side_c);
  }
  return out;
}

class CliAnalysisTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / fmt::format("gyrotherm-cli-analysis-{}", ::getpid());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    db_path_ = (dir_ / "station.db").string();
    auto db = storage::Database::open(db_path_);
    ASSERT_TRUE(db) << db.error().message;
    auto writer = storage::SampleWriter::start(db_path_);
    ASSERT_TRUE(writer) << writer.error().message;
    for (int k = 0; k < kRuns; ++k) {
      data_.push_back(make_run(k));
      storage::RunRecord run;
      run.schedule_name = fmt::format("run {}", k);
      run.state = "acquiring";
      run.latitude_deg = kLatitudeDeg;
      run.orientation = "up";
      // TOML, as runs stored before schema v6 kept it: still read.
      run.config_toml = fmt::format(
          "[station]\nname = \"test station\"\n[analysis]\nma_window = {}\n", kStoredMaWindow);
      auto id = db->create_run(run);
      ASSERT_TRUE(id) << id.error().message;
      run_ids_.push_back(*id);
      auto segment = [&](int index, const char* kind, double setpoint_c, double from_s, double to_s,
                         const std::vector<std::pair<double, double>>& windows) {
        storage::SegmentRecord s;
        s.run_id = *id;
        s.index = index;
        s.kind = kind;
        s.label = fmt::format("{} {:g} °C (step {})", kind, setpoint_c, index + 1);
        s.setpoint_c = setpoint_c;
        s.t_start_s = from_s;
        s.t_end_s = to_s;
        if (!windows.empty()) {
          s.t_acquire_start_s = windows.front().first;
          s.t_acquire_end_s = windows.back().second;
        }
        s.state = "completed";
        // The second run's last soak was adaptive (docs/schedules.md).
        if (k == 1 && index == 2) s.acquire_stop = kAdaptiveStop;
        auto sid = db->create_segment(s);
        ASSERT_TRUE(sid) << sid.error().message;
        s.id = *sid;
        s.windows = windows;
        ASSERT_TRUE(db->update_segment(s).ok());
      };
      segment(0, "soak", kStartC[k], 0, 400, kSoak1Windows);
      segment(1, "ramp", kStartC[k] + 20, 400, 1000, {});
      segment(2, "soak", kStartC[k] + 20, 1000, 1500, kSoak2Windows);
      (*writer)->push_gyro(*id, data_.back().gyro);
      for (const auto& t : data_.back().temps) (*writer)->push_temperature(*id, t);
      ASSERT_TRUE(db->set_run_state(*id, "completed", true).ok());
    }
    ASSERT_TRUE((*writer)->flush().ok());
    (*writer)->stop();
    ASSERT_EQ((*writer)->stats().gyro_rows, static_cast<uint64_t>(kRuns * kGyroPerRun));
  }
  // GYROTHERM_KEEP_TEST_DIR=1 keeps the database and files for a look by hand.
  static void TearDownTestSuite() {
    if (!::testing::UnitTest::GetInstance()->Failed() && !std::getenv("GYROTHERM_KEEP_TEST_DIR")) {
      fs::remove_all(dir_);
    }
  }

  struct Run {
    int code;
    std::string out, err;
    json parsed() const {
      json j = json::parse(out, nullptr, false);
      EXPECT_FALSE(j.is_discarded()) << "not JSON:\n" << out;
      return j;
    }
  };
  static Run cli(const std::vector<std::string>& args) {
    const std::string out = (dir_ / "out.txt").string(), err = (dir_ / "err.txt").string();
    std::string cmd = std::string(GYROTHERM_BIN_DIR) + "/gyrotherm";
    for (const auto& a : args) cmd += " '" + a + "'";
    cmd += " >" + out + " 2>" + err;
    const int st = std::system(cmd.c_str());
    return {WIFEXITED(st) ? WEXITSTATUS(st) : -1, read_text(out), read_text(err)};
  }
  static std::string file(const std::string& name) { return (dir_ / name).string(); }
  static std::string run_csv_file(int k) {
    const std::string path = file(fmt::format("run{}.csv", k));
    if (!fs::exists(path)) write_text(path, run_csv(data_[k]));
    return path;
  }

  // The series of the CSV files at `paths` in 1 s bins, as `--csv` reads them.
  static void read_csv_series(const std::vector<std::string>& paths,
                              std::vector<analysis::AnalysisSeries>& series) {
    for (const auto& p : paths) {
      auto w = analysis::read_csv_window(p);
      ASSERT_TRUE(w);
      auto s = analysis::csv_analysis_series(*w, 1.0);
      ASSERT_TRUE(s);
      series.push_back(std::move(*s));
    }
  }

  static inline fs::path dir_;
  static inline std::string db_path_;
  static inline std::vector<RunData> data_;
  static inline std::vector<int64_t> run_ids_;
};

double earth_rate() {
  return analysis::earth_rate_component_dph(kLatitudeDeg, analysis::AxisOrientation::kUp);
}

void expect_number(const json& j, const char* key, double expected) {
  ASSERT_TRUE(j.contains(key)) << key << " missing in " << j.dump();
  if (!std::isfinite(expected)) {
    EXPECT_TRUE(j[key].is_null()) << key;
    return;
  }
  ASSERT_TRUE(j[key].is_number()) << key << " = " << j[key].dump();
  EXPECT_EQ(j[key].get<double>(), expected) << key;
}

void expect_row(const json& j, const analysis::Table1Row& r) {
  EXPECT_EQ(j.at("n").get<std::size_t>(), r.n);
  expect_number(j, "duration_s", r.duration_s);
  expect_number(j, "temp_mean_c", r.temp_mean_c);
  expect_number(j, "bias_mean_dph", r.bias_mean_dph);
  expect_number(j, "bias_std_dph", r.bias_std_dph);
  expect_number(j, "bias_std_ma101_dph", r.bias_std_ma_dph);
  expect_number(j, "bias_mean_earth_removed_dph", r.bias_mean_earth_removed_dph);
  // The bias mean's uncertainty: the library's, or its reason for none.
  ASSERT_TRUE(j.contains("bias_u")) << j.dump();
  if (!r.bias_u) {
    EXPECT_TRUE(j["bias_u"].is_null());
    EXPECT_EQ(j.at("bias_u_note").get<std::string>(), r.bias_u_note);
    return;
  }
  ASSERT_TRUE(j["bias_u"].is_object()) << j.dump();
  expect_number(j["bias_u"], "window_s", r.bias_u->window_s);
  expect_number(j["bias_u"], "u_dph", r.bias_u->u_dph);
  expect_number(j["bias_u"], "expanded_dph", r.bias_u->expanded_dph);
  expect_number(j["bias_u"], "k", r.bias_u->k);
  expect_number(j["bias_u"], "dof", r.bias_u->dof);
  expect_number(j["bias_u"], "floor_dph", r.bias_u->floor_dph);
  EXPECT_EQ(j["bias_u"].at("random_walk_dominated").get<bool>(), r.bias_u->random_walk_dominated);
  EXPECT_EQ(j.at("bias_u_note").get<std::string>(), "");
}

// ---------------------------------------------------------------- stats

TEST_F(CliAnalysisTest, StatsOnADatabaseMatchesTheLibraryAndUsesTheRunsSettings) {
  const Run r = cli({"stats", "--db", db_path_, "--runs", "1-2", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  ASSERT_TRUE(j.is_array());
  ASSERT_EQ(j.size(), 4u);  // two runs x two soaks
  analysis::Table1Options o;
  o.ma_window = kStoredMaWindow;    // from the run's stored [analysis]
  o.earth_rate_dph = earth_rate();  // from the run's latitude and orientation
  for (int k = 0; k < 2; ++k) {
    for (int s = 0; s < 2; ++s) {
      const json& w = j[2 * k + s];
      const auto& windows = s == 0 ? kSoak1Windows : kSoak2Windows;
      auto row = analysis::table1_row(soak_series(data_[k], windows), o);
      ASSERT_TRUE(row) << row.error().message;
      SCOPED_TRACE(w.dump());
      EXPECT_EQ(w.at("run_id").get<int64_t>(), run_ids_[k]);
      EXPECT_EQ(w.at("segment").get<int>(), s == 0 ? 1 : 3);
      EXPECT_EQ(w.at("setpoint_c").get<double>(), kStartC[k] + (s == 0 ? 0 : 20));
      EXPECT_EQ(w.at("t_from_s").get<double>(), windows.front().first);
      EXPECT_EQ(w.at("t_to_s").get<double>(), windows.back().second);
      ASSERT_TRUE(row->bias_u) << row->bias_u_note;
      expect_row(w, *row);
      EXPECT_EQ(w.at("ma_window").get<int>(), kStoredMaWindow);
      EXPECT_EQ(w.at("bin_s").get<double>(), 1.0);
      EXPECT_EQ(w.at("earth_rate_dph").get<double>(), earth_rate());
      EXPECT_TRUE(w.at("warnings").empty());
      // Why an adaptive soak ended, null for the fixed ones.
      if (k == 1 && s == 1) {
        EXPECT_EQ(w.at("acquire_stop"), kAdaptiveStop);
      } else {
        EXPECT_TRUE(w.at("acquire_stop").is_null());
      }
    }
  }
  // The daemon's own path gives the same numbers.
  auto db = storage::Database::open_read_only(db_path_);
  ASSERT_TRUE(db);
  auto soaks = calibration::soak_windows(*db, run_ids_[0]);
  ASSERT_TRUE(soaks && soaks->size() == 2u);
  auto rec = calibration::soak_table1(*db, (*soaks)[1], o);
  ASSERT_TRUE(rec) << rec.error().message;
  EXPECT_EQ(j[1].at("bias_std_ma101_dph").get<double>(), rec->bias_std_ma_dph);
  EXPECT_EQ(j[1].at("bias_mean_dph").get<double>(), rec->bias_mean_dph);
}

TEST_F(CliAnalysisTest, StatsBySetpointGroupsTheSoaksOfEveryRunLikeThePapersTableI) {
  // Stored rows of a campaign that repeats 20 °C three times (two runs) and
  // visits 40 °C once; one 20 °C soak was too short for the moving average.
  const std::string db_copy = file("by-setpoint.db");
  fs::copy_file(db_path_, db_copy, fs::copy_options::overwrite_existing);
  struct Stored {
    int run;  // index into run_ids_
    int segment_index;
    double setpoint_c, temp_c, bias_dph, std_dph, std_ma_dph;
  };
  const double nan = std::nan("");
  const std::vector<Stored> stored = {{0, 0, 20.0, 20.3, 7.0, 0.05, 0.006},
                                      {0, 2, 40.0, 40.4, 8.0, 0.06, 0.007},
                                      {1, 0, 20.0, 20.1, 7.2, 0.07, nan},
                                      {1, 2, 20.0, 20.2, 7.4, 0.09, 0.008}};
  {
    auto db = storage::Database::open(db_copy);
    ASSERT_TRUE(db) << db.error().message;
    for (const auto& s : stored) {
      auto segments = db->segments(run_ids_[s.run]);
      ASSERT_TRUE(segments) << segments.error().message;
      storage::SegmentStatsRecord r;
      r.segment_id = segments->at(static_cast<std::size_t>(s.segment_index)).id;
      r.run_id = run_ids_[s.run];
      r.segment_index = s.segment_index;
      r.setpoint_c = s.setpoint_c;
      r.n = 300;
      r.duration_s = 300;
      r.temp_mean_c = s.temp_c;
      r.bias_mean_dph = s.bias_dph;
      r.bias_std_dph = s.std_dph;
      r.bias_std_ma_dph = s.std_ma_dph;
      r.bias_mean_earth_removed_dph = s.bias_dph - 7.9;
      r.earth_rate_dph = 7.9;
      ASSERT_TRUE(db->put_segment_stats(r).ok());
    }
  }
  const std::string runs = fmt::format("{},{}", run_ids_[0], run_ids_[1]);
  const Run r =
      cli({"stats", "--db", db_copy, "--runs", runs, "--stored", "--by-setpoint", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  ASSERT_TRUE(j.is_array()) << r.out;
  ASSERT_EQ(j.size(), 2u) << r.out;
  const json& g20 = j[0];
  EXPECT_EQ(g20.at("setpoint_c").get<double>(), 20.0);
  EXPECT_EQ(g20.at("repetitions").get<int>(), 3);
  EXPECT_EQ(g20.at("soaks"),
            json::parse(fmt::format(R"([{{"run_id":{0},"segment":1}},{{"run_id":{1},"segment":1}},)"
                                    R"({{"run_id":{1},"segment":3}}])",
                                    run_ids_[0], run_ids_[1])));
  // By hand: biases 7.0, 7.2, 7.4 -> mean 7.2, sample std 0.2; temperatures
  // 20.3, 20.1, 20.2 -> 20.2, 0.1; std MA of two soaks 0.006, 0.008 -> 0.007,
  // sqrt(2) x 0.001.
  auto expect_col = [&](const json& g, const char* key, double mean, double std, int n) {
    SCOPED_TRACE(key);
    const json& c = g.at(key);
    EXPECT_NEAR(c.at("mean").get<double>(), mean, 1e-12);
    if (std::isnan(std)) {
      EXPECT_TRUE(c.at("std").is_null()) << c.dump();
    } else {
      EXPECT_NEAR(c.at("std").get<double>(), std, 1e-12);
    }
    EXPECT_EQ(c.at("n").get<int>(), n);
  };
  expect_col(g20, "bias_mean_dph", 7.2, 0.2, 3);
  expect_col(g20, "temp_mean_c", 20.2, 0.1, 3);
  expect_col(g20, "bias_std_ma101_dph", 0.007, std::sqrt(2.0) * 0.001, 2);
  expect_col(g20, "bias_mean_earth_removed_dph", 7.2 - 7.9, 0.2, 3);
  const json& g40 = j[1];
  EXPECT_EQ(g40.at("setpoint_c").get<double>(), 40.0);
  EXPECT_EQ(g40.at("repetitions").get<int>(), 1);
  expect_col(g40, "bias_mean_dph", 8.0, nan, 1);
  // These stored rows carry no uncertainty of their means: nor do their
  // groups, and they say why.
  EXPECT_TRUE(g20.at("bias_mean_u").is_null()) << g20.dump();
  EXPECT_THAT(g20.at("bias_mean_u_note").get<std::string>(),
              HasSubstr("has no uncertainty of its mean"));

  // Text: one line per set point, mean ± std.
  const Run text = cli({"stats", "--db", db_copy, "--runs", runs, "--stored", "--by-setpoint"});
  ASSERT_EQ(text.code, 0) << text.err;
  EXPECT_THAT(text.out, HasSubstr("reps"));
  EXPECT_THAT(text.out, HasSubstr("7.2000 ± 0.2000"));
  EXPECT_THAT(text.out, HasSubstr("± U95 °/h"));
  EXPECT_THAT(text.out, HasSubstr("schedule set point"));

  // Recomputed rows group the same way (here every set point once).
  const Run all = cli({"stats", "--db", db_path_, "--by-setpoint", "--json"});
  ASSERT_EQ(all.code, 0) << all.err;
  const json ja = all.parsed();
  ASSERT_EQ(ja.size(), 2u * kRuns) << all.out;
  // Recomputed rows have their uncertainty, and so their groups: a single
  // soak's group has that soak's (u_dph > 0, the same form as `bias_u`).
  for (const json& g : ja) {
    ASSERT_TRUE(g.at("bias_mean_u").is_object()) << g.dump();
    EXPECT_GT(g.at("bias_mean_u").at("u_dph").get<double>(), 0) << g.dump();
  }
  for (std::size_t i = 1; i < ja.size(); ++i) {
    EXPECT_LT(ja[i - 1].at("setpoint_c").get<double>(), ja[i].at("setpoint_c").get<double>());
  }
  // A CSV file has no set point.
  const Run csv = cli({"stats", "--csv", run_csv_file(0), "--by-setpoint"});
  EXPECT_EQ(csv.code, 2) << csv.out;
  EXPECT_THAT(csv.err, HasSubstr("set point"));
}

TEST_F(CliAnalysisTest, StatsOptionsOverrideTheStoredSettings) {
  const Run r = cli({"stats", "--db", db_path_, "--run", std::to_string(run_ids_[2]), "--ma-window",
                     "101", "--earth-rate-dph", "7.5", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  ASSERT_EQ(j.size(), 2u);
  const analysis::Table1Options o{.bin_s = 1.0, .ma_window = 101, .earth_rate_dph = 7.5};
  auto row = analysis::table1_row(soak_series(data_[2], kSoak1Windows), o);
  ASSERT_TRUE(row);
  expect_row(j[0], *row);
  EXPECT_EQ(j[0].at("ma_window").get<int>(), 101);
  EXPECT_EQ(j[0].at("earth_rate_dph").get<double>(), 7.5);
}

TEST_F(CliAnalysisTest, StatsWithoutARunCoversEveryRunAndPrintsATable) {
  const Run r = cli({"stats", "--db", db_path_});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("bias °/h"));
  EXPECT_THAT(r.out, HasSubstr("std MA °/h"));
  EXPECT_THAT(r.out, HasSubstr(fmt::format("{}-point moving average", kStoredMaWindow)));
  EXPECT_THAT(r.out, HasSubstr("± U95 °/h"));
  EXPECT_THAT(r.out, HasSubstr("95 % interval"));
  // Header, 8 rows, two footnotes, the adaptive soak's end.
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1 + 2 * kRuns + 2 + 1) << r.out;
  EXPECT_THAT(r.out, HasSubstr(fmt::format("run {} segment 3: adaptive soak: {}\n", run_ids_[1],
                                           kAdaptiveStop)));
  EXPECT_EQ(r.out.find("nan"), std::string::npos);
}

TEST_F(CliAnalysisTest, StatsOnACsvMatchesTheLibrary) {
  const std::string path = file("soak1.csv");
  write_text(path, run_csv(data_[0], 50.05, 380.05));
  const Run r =
      cli({"stats", "--csv", path, "--latitude", "31.9", "--orientation", "down", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  ASSERT_EQ(j.size(), 1u);
  auto w = analysis::read_csv_window(path);
  ASSERT_TRUE(w);
  auto series = analysis::csv_analysis_series(*w, 1.0);
  ASSERT_TRUE(series);
  analysis::Table1Options o;
  o.earth_rate_dph = analysis::earth_rate_component_dph(31.9, analysis::AxisOrientation::kDown);
  auto row = analysis::table1_row(*series, o);
  ASSERT_TRUE(row);
  EXPECT_EQ(j[0].at("source").get<std::string>(), path);
  EXPECT_EQ(j[0].at("n").get<std::size_t>(), 330u);
  expect_row(j[0], *row);
  EXPECT_EQ(j[0].at("earth_rate_dph").get<double>(), o.earth_rate_dph);
  EXPECT_EQ(j[0].at("ma_window").get<int>(), 101);
}

TEST_F(CliAnalysisTest, AWindowShorterThanTheMovingAverageIsFlaggedNotFatal) {
  std::string text = "t_s,rate_dph,top_c,side_c\n";
  for (int i = 0; i < 50; ++i) text += fmt::format("{},{},20.5,19.5\n", i, 8 + 0.01 * (i % 7));
  const std::string path = file("short.csv");
  write_text(path, text);
  Run r = cli({"stats", "--csv", path, "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  ASSERT_EQ(j.size(), 1u);
  EXPECT_EQ(j[0].at("n").get<int>(), 50);
  EXPECT_TRUE(j[0].at("bias_std_ma101_dph").is_null());
  EXPECT_TRUE(j[0].at("bias_std_dph").is_number());
  ASSERT_EQ(j[0].at("warnings").size(), 1u);
  EXPECT_THAT(j[0]["warnings"][0].get<std::string>(), HasSubstr("moving average"));
  r = cli({"stats", "--csv", path});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("—"));
  EXPECT_THAT(r.out, HasSubstr("no moving-average std"));
  EXPECT_EQ(r.out.find("nan"), std::string::npos) << r.out;
}

// ---------------------------------------------------------------- allan

void expect_allan(const json& w, const analysis::AllanResult& a) {
  const std::size_t n = a.tau_s.size();
  ASSERT_GT(n, 5u);
  for (const char* key : {"tau_s", "adev_dph", "adev_lo_dph", "adev_hi_dph", "n_terms", "edf"}) {
    ASSERT_TRUE(w.at(key).is_array()) << key;
    EXPECT_EQ(w.at(key).size(), n) << key;
  }
  for (std::size_t i = 0; i < n; ++i) {
    EXPECT_EQ(w["tau_s"][i].get<double>(), a.tau_s[i]);
    EXPECT_EQ(w["adev_dph"][i].get<double>(), a.adev_dph[i]);
    EXPECT_EQ(w["adev_lo_dph"][i].get<double>(), a.adev_lo_dph[i]);
    EXPECT_EQ(w["adev_hi_dph"][i].get<double>(), a.adev_hi_dph[i]);
    EXPECT_EQ(w["n_terms"][i].get<std::size_t>(), a.n_terms[i]);
    EXPECT_EQ(w["edf"][i].get<double>(), a.edf[i]);
    EXPECT_EQ(w.at("noise_alpha").at(i).get<int>(), a.noise_alpha[i]);
  }
  expect_number(w, "tau0_s", a.tau0_s);
  EXPECT_EQ(w.at("n_samples").get<std::size_t>(), a.n_samples);
  for (auto [key, v] : {std::pair{"angle_random_walk_dprh", a.angle_random_walk_dprh},
                        std::pair{"bias_instability_dph", a.bias_instability_dph},
                        std::pair{"bias_instability_tau_s", a.bias_instability_tau_s},
                        std::pair{"rate_random_walk_dphprh", a.rate_random_walk_dphprh}}) {
    ASSERT_TRUE(w.contains(key)) << key;
    if (v) {
      EXPECT_EQ(w[key].get<double>(), *v) << key;
    } else {
      EXPECT_TRUE(w[key].is_null()) << key;
    }
  }
  EXPECT_EQ(w.at("bias_instability_method").get<std::string>(), "minimum / 0.664");
  // Every term with its kind (value, upper_bound, unavailable), as the analysis read it.
  const json& terms = w.at("noise_terms");
  for (auto [key, t] : {std::pair{"angle_random_walk_dprh", &a.noise.angle_random_walk_dprh},
                        std::pair{"bias_instability_dph", &a.noise.bias_instability_dph},
                        std::pair{"rate_random_walk_dphprh", &a.noise.rate_random_walk_dphprh}}) {
    SCOPED_TRACE(key);
    const json& j = terms.at(key);
    EXPECT_EQ(j.at("kind").get<std::string>(), analysis::to_string(t->kind));
    if (t->kind == analysis::NoiseTermKind::kUnavailable) {
      EXPECT_TRUE(j.at("value").is_null());
    } else {
      EXPECT_EQ(j.at("value").get<double>(), t->value);
    }
    if (t->tau_s) {
      EXPECT_EQ(j.at("tau_s").get<double>(), *t->tau_s);
    } else {
      EXPECT_TRUE(j.at("tau_s").is_null());
    }
    EXPECT_EQ(j.at("tau_relation").get<std::string>(), t->tau_relation);
    EXPECT_EQ(j.at("note").get<std::string>(), t->note);
  }
  // The noise model fitted to the curve, and u of the whole record's mean.
  auto model = analysis::fit_noise_model(a.tau_s, a.adev_dph, a.edf);
  ASSERT_TRUE(model.ok()) << model.error().message;
  const json& m = w.at("noise_model");
  EXPECT_TRUE(w.at("noise_model_error").is_null());
  for (auto [key, t] : {std::pair{"angle_random_walk_dprh", &model->angle_random_walk_dprh},
                        std::pair{"bias_instability_dph", &model->bias_instability_dph},
                        std::pair{"rate_random_walk_dphprh", &model->rate_random_walk_dphprh}}) {
    SCOPED_TRACE(key);
    EXPECT_EQ(m.at(key).at("fitted").get<bool>(), t->fitted);
    EXPECT_EQ(m.at(key).at("value").get<double>(), t->value);
    EXPECT_EQ(m.at(key).at("lo").get<double>(), t->lo);
    EXPECT_EQ(m.at(key).at("hi").get<double>(), t->hi);
  }
  auto u = analysis::mean_uncertainty(*model, static_cast<double>(a.n_samples) * a.tau0_s);
  ASSERT_TRUE(u.ok());
  const json& mu = m.at("mean_uncertainty");
  EXPECT_EQ(mu.at("window_s").get<double>(), u->window_s);
  EXPECT_EQ(mu.at("u_dph").get<double>(), u->u_dph);
  EXPECT_EQ(mu.at("expanded_dph").get<double>(), u->expanded_dph);
  EXPECT_EQ(mu.at("floor_dph").get<double>(), u->floor_dph);
  EXPECT_EQ(mu.at("random_walk_dominated").get<bool>(), u->random_walk_dominated);
  // The record's mean is known better than one sample's rate.
  EXPECT_GT(u->u_dph, 0);
  EXPECT_LT(u->u_dph, a.adev_dph.front());
}

TEST_F(CliAnalysisTest, AllanOnADatabaseUsesTheLongestWindowAsRecorded) {
  const Run r = cli({"allan", "--db", db_path_, "--run", std::to_string(run_ids_[1]), "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  ASSERT_EQ(j.size(), 2u);
  // Soak 2: the longer of its two windows.
  const auto [from_s, to_s] = kSoak2Windows[1];
  std::vector<double> t, y;
  for (const auto& g : in_window(data_[1].gyro, from_s, to_s)) {
    t.push_back(g.t_s);
    y.push_back(g.rate_dph);
  }
  auto a = analysis::allan_deviation(t, y);
  ASSERT_TRUE(a) << a.error().message;
  EXPECT_EQ(j[1].at("segment").get<int>(), 3);
  EXPECT_EQ(j[1].at("t_from_s").get<double>(), from_s);
  EXPECT_EQ(j[1].at("taus").get<std::string>(), "octave");
  expect_allan(j[1], *a);
}

// A short soak (150 s of white noise): the curve still falls at its last tau.
// The text gives the bias instability and RRW as bounds with their tau, not a
// dash; a campaign of runs ends with one summary line per soak.
TEST_F(CliAnalysisTest, AllanTextGivesBoundsAndACampaignGetsASummary) {
  const std::string path = file("short.csv");
  write_text(path, run_csv(data_[0], 1050.05, 1200.05));
  auto w = analysis::read_csv_window(path);
  ASSERT_TRUE(w);
  auto a = analysis::allan_deviation(w->t_s, w->rate_dph);
  ASSERT_TRUE(a) << a.error().message;
  const analysis::NoiseTerm& bi = a->noise.bias_instability_dph;
  ASSERT_EQ(bi.kind, analysis::NoiseTermKind::kUpperBound) << bi.note;
  Run r = cli({"allan", "--csv", path});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out,
              HasSubstr(fmt::format(
                  "bias instability   < {:.6g} °/h at τ ≥ {:.6g} s (upper bound: no minimum yet",
                  bi.value, *bi.tau_s)));
  EXPECT_THAT(r.out, HasSubstr(fmt::format("rate random walk   < {:.6g} °/h/√h at τ ≥",
                                           a->noise.rate_random_walk_dphprh.value)));
  EXPECT_EQ(r.out.find("Summary"), std::string::npos) << "one curve, no summary";
  // The noise model's line and u of the record's mean, as the analysis has them.
  auto model = analysis::fit_noise_model(a->tau_s, a->adev_dph, a->edf);
  ASSERT_TRUE(model.ok()) << model.error().message;
  auto u = analysis::mean_uncertainty(*model, static_cast<double>(a->n_samples) * a->tau0_s);
  ASSERT_TRUE(u.ok());
  EXPECT_THAT(r.out, HasSubstr(fmt::format("noise model (95 %)  ARW {:.6g} [{:.6g}, {:.6g}] °/√h",
                                           model->angle_random_walk_dprh.value,
                                           model->angle_random_walk_dprh.lo,
                                           model->angle_random_walk_dprh.hi)));
  EXPECT_THAT(
      r.out, HasSubstr(fmt::format("mean of the {:.6g} s record: u {:.6g} °/h, ±{:.6g} °/h at 95 %",
                                   u->window_s, u->u_dph, u->expanded_dph)));

  const std::string runs = fmt::format("{},{}", run_ids_[0], run_ids_[2]);
  r = cli({"allan", "--db", db_path_, "--runs", runs});
  ASSERT_EQ(r.code, 0) << r.err;
  const std::size_t summary = r.out.find("Summary");
  ASSERT_NE(summary, std::string::npos) << r.out;
  EXPECT_GT(summary, r.out.rfind("rate random walk   ")) << "the summary follows every table";
  const Run j = cli({"allan", "--db", db_path_, "--runs", runs, "--json"});
  ASSERT_EQ(j.code, 0) << j.err;
  const json curves = j.parsed();
  ASSERT_EQ(curves.size(), 4u);  // two soaks of two runs
  std::istringstream lines(r.out.substr(summary));
  std::vector<std::string> rows;
  for (std::string line; std::getline(lines, line);) {
    if (line.rfind("  run ", 0) == 0) rows.push_back(line);
  }
  ASSERT_EQ(rows.size(), curves.size()) << r.out.substr(summary);
  for (std::size_t i = 0; i < curves.size(); ++i) {
    const json& c = curves[i];
    SCOPED_TRACE(rows[i]);
    EXPECT_THAT(rows[i], HasSubstr(fmt::format("run {} segment {}", c.at("run_id").get<int64_t>(),
                                               c.at("segment").get<int>())));
    const json& t = c.at("noise_terms").at("bias_instability_dph");
    const std::string kind = t.at("kind").get<std::string>();
    ASSERT_NE(kind, "unavailable");
    EXPECT_THAT(rows[i], HasSubstr(fmt::format("{}{:.6g} °/h", kind == "upper_bound" ? "< " : "",
                                               t.at("value").get<double>())));
    const json& rrw = c.at("noise_terms").at("rate_random_walk_dphprh");
    EXPECT_THAT(rows[i], HasSubstr(fmt::format("{}{:.6g} °/h/√h",
                                               rrw.at("kind") == "upper_bound" ? "< " : "",
                                               rrw.at("value").get<double>())));
  }
}

TEST_F(CliAnalysisTest, AllanOnACsvWithDecadeTausAndTheTextSaysHowBiasInstabilityIsRead) {
  const std::string path = file("soak2.csv");
  write_text(path, run_csv(data_[3], 1230.05, 1450.05));
  Run r = cli({"allan", "--csv", path, "--taus", "decade", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  ASSERT_EQ(j.size(), 1u);
  auto w = analysis::read_csv_window(path);
  ASSERT_TRUE(w);
  auto a = analysis::allan_deviation(w->t_s, w->rate_dph, {.taus = analysis::TauSet::kDecade});
  ASSERT_TRUE(a);
  EXPECT_EQ(j[0].at("taus").get<std::string>(), "decade");
  expect_allan(j[0], *a);
  r = cli({"allan", "--csv", path});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("minimum / 0.664"));
  EXPECT_THAT(r.out, HasSubstr("angle random walk"));
  r = cli({"allan", "--csv", path, "--taus", "weekly"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("weekly"));
}

// ---------------------------------------------------------------- fit

void expect_fit(const json& j, const analysis::DriftFit& fit) {
  ASSERT_EQ(j.at("coefficients").size(), fit.coefficients.size()) << j.dump(2);
  for (const auto& [k, v] : fit.coefficients) {
    ASSERT_TRUE(j["coefficients"].contains(k)) << k;
    EXPECT_EQ(j["coefficients"][k].get<double>(), v) << k;
    EXPECT_EQ(j["standard_errors"][k].get<double>(), fit.std_errors.at(k)) << k;
  }
  EXPECT_EQ(j.at("n").get<std::size_t>(), fit.n);
  expect_number(j, "residual_std_dph", fit.residual_std_dph);
  expect_number(j, "r_squared", fit.r_squared);
  expect_number(j, "l0_dph", fit.l0_dph);
  expect_number(j, "condition_estimate", fit.condition_estimate);
  EXPECT_EQ(j.at("model").get<std::string>(), analysis::to_string(fit.spec));
  EXPECT_EQ(j.at("form").get<std::string>(), analysis::to_string(fit.form));
}

TEST_F(CliAnalysisTest, FitOnDatabaseRunsMatchesTheLibraryAndTheDaemonAndExports) {
  const std::string runs = fmt::format("{},{}", run_ids_[0], run_ids_[2]);
  const std::string json_path = file("fit.json"), header_path = file("fit.h");
  const Run r =
      cli({"fit", "--db", db_path_, "--runs", runs, "--model", "T2+R1+G1", "--form", "paper",
           "--json", "--coefficients-json", json_path, "--c-header", header_path});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  const std::vector<analysis::AnalysisSeries> series = {run_series(data_[0]), run_series(data_[2])};
  const analysis::DriftModelSpec spec{.t_order = 2, .r_order = 1, .g_order = 1};
  auto fit = analysis::fit_drift_model(series, spec, analysis::DriftModelForm::kPaper);
  ASSERT_TRUE(fit) << fit.error().message;
  expect_fit(j, *fit);
  EXPECT_EQ(j.at("l0_per_run_dph").size(), 2u);
  EXPECT_EQ(j.at("inputs").at("runs"), json({run_ids_[0], run_ids_[2]}));
  // The fit's own consistency: the residual is at least the binned noise
  // (0.5 °/h white at 10 Hz -> ~0.16 °/h in 1 s bins).
  EXPECT_GT(j["residual_std_dph"].get<double>(), 0.1);
  EXPECT_EQ(j.at("parameters").get<int>(), 4);

  auto db = storage::Database::open_read_only(db_path_);
  ASSERT_TRUE(db);
  // The daemon's path: each run's whole series, fitted together, as a record.
  std::vector<analysis::AnalysisSeries> stored;
  for (int64_t id : {run_ids_[0], run_ids_[2]}) {
    auto s = calibration::run_series(*db, id, 1.0);
    ASSERT_TRUE(s) << s.error().message;
    stored.push_back(std::move(*s));
  }
  auto daemon_fit = analysis::fit_drift_model(stored, spec, analysis::DriftModelForm::kPaper);
  ASSERT_TRUE(daemon_fit) << daemon_fit.error().message;
  const auto rec = calibration::fit_record(*daemon_fit, {run_ids_[0], run_ids_[2]}, {}, 1.0);
  EXPECT_EQ(j["coefficients"], json::parse(rec.coefficients_json));
  EXPECT_EQ(j["standard_errors"], json::parse(rec.standard_errors_json));

  const json exported = json::parse(read_text(json_path), nullptr, false);
  ASSERT_FALSE(exported.is_discarded()) << read_text(json_path);
  EXPECT_EQ(exported.at("coefficients"), j["coefficients"]);
  const std::string header = read_text(header_path);
  EXPECT_THAT(header, HasSubstr("static const double"));
  EXPECT_THAT(header, HasSubstr("test station"));
  for (const auto& e : fs::directory_iterator(dir_)) {
    EXPECT_EQ(e.path().filename().string().find(".tmp-"), std::string::npos)
        << "temporary file left: " << e.path();
  }
}

TEST_F(CliAnalysisTest, FitOnCsvFilesCenteredFormHasAnIntercept) {
  const std::string a = run_csv_file(1), b = run_csv_file(3);
  const Run r = cli({"fit", "--csv", a, "--csv", b, "--model", "T3+G1", "--form", "centered",
                     "--derivative-window-s", "90", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  std::vector<analysis::AnalysisSeries> series;
  ASSERT_NO_FATAL_FAILURE(read_csv_series({a, b}, series));
  analysis::DriftFitOptions o;
  o.derivative_window_s = 90;
  auto fit = analysis::fit_drift_model(series, {.t_order = 3, .g_order = 1},
                                       analysis::DriftModelForm::kCentered, o);
  ASSERT_TRUE(fit) << fit.error().message;
  expect_fit(j, *fit);
  EXPECT_TRUE(j["coefficients"].contains("intercept"));
  for (const char* k : {"T1", "T2", "T3", "G1"}) EXPECT_TRUE(j["coefficients"].contains(k)) << k;
  EXPECT_EQ(j.at("inputs").at("csv"), json({a, b}));
  EXPECT_EQ(j.at("inputs").at("derivative_window_s").get<double>(), 90.0);
}

TEST_F(CliAnalysisTest, FitTextOutputListsEveryTerm) {
  const Run r =
      cli({"fit", "--db", db_path_, "--run", std::to_string(run_ids_[0]), "--model", "T1+R1+G1"});
  ASSERT_EQ(r.code, 0) << r.err;
  for (const char* s : {"centred form", "intercept", "T1", "R1", "G1", "residual std", "R²"}) {
    EXPECT_THAT(r.out, HasSubstr(s));
  }
  const Run paper = cli({"fit", "--db", db_path_, "--run", std::to_string(run_ids_[0]), "--model",
                         "T1+R1+G1", "--form", "paper"});
  ASSERT_EQ(paper.code, 0) << paper.err;
  for (const char* s : {"the paper's form", "biased", "L0", "T1", "R1", "G1"}) {
    EXPECT_THAT(paper.out, HasSubstr(s));
  }
}

// Issue 15 item 3: without --form the fit is the centred (unbiased) one, and
// a coefficient within 2 standard errors of zero is warned about (text and
// JSON), exactly as the library finds them.
TEST_F(CliAnalysisTest, FitWithoutFormIsCentredAndWarnsAboutNearZeroCoefficients) {
  const std::string a = run_csv_file(0), b = run_csv_file(2);
  std::vector<analysis::AnalysisSeries> series;
  ASSERT_NO_FATAL_FAILURE(read_csv_series({a, b}, series));
  bool saw_warning = false, saw_clean = false;
  for (const char* model : {"T1+R1+G1", "T4+R2+G2"}) {
    SCOPED_TRACE(model);
    const Run r = cli({"fit", "--csv", a, "--csv", b, "--model", model, "--json"});
    ASSERT_EQ(r.code, 0) << r.err;
    const json j = r.parsed();
    EXPECT_EQ(j.at("form").get<std::string>(), "centered");
    EXPECT_TRUE(j.at("coefficients").contains("intercept"));
    auto fit = analysis::fit_drift_model(series, *analysis::parse_model_spec(model),
                                         analysis::DriftModelForm::kCentered);
    ASSERT_TRUE(fit) << fit.error().message;
    expect_fit(j, *fit);
    const auto near = analysis::near_zero_coefficients(*fit);
    EXPECT_EQ(j.at("near_zero").get<std::vector<std::string>>(), near);
    // Each listed one is within 2 SE, each other one is not.
    for (const auto& [k, v] : fit->coefficients) {
      if (k == "intercept") continue;
      const bool listed = std::find(near.begin(), near.end(), k) != near.end();
      EXPECT_EQ(listed, std::abs(v) < 2 * fit->std_errors.at(k)) << k;
    }
    EXPECT_EQ(j.at("warnings").size(), near.empty() ? 0u : 1u);
    const Run text = cli({"fit", "--csv", a, "--csv", b, "--model", model});
    ASSERT_EQ(text.code, 0) << text.err;
    if (near.empty()) {
      saw_clean = true;
      EXPECT_EQ(text.out.find("warning"), std::string::npos) << text.out;
    } else {
      saw_warning = true;
      EXPECT_THAT(text.out, HasSubstr("warning: " + near.front()));
      EXPECT_THAT(text.out, HasSubstr("within 2 standard errors of zero"));
    }
  }
  EXPECT_TRUE(saw_clean) << "T1+R1+G1 is determined by these runs";
  EXPECT_TRUE(saw_warning) << "T4+R2+G2 has terms these runs do not determine";
}

// ---------------------------------------------------------------- compare

TEST_F(CliAnalysisTest, CompareGridMatchesTheLibraryInSampleAndLeaveOneRunOut) {
  const Run r = cli({"compare", "--db", db_path_, "--runs",
                     fmt::format("{}-{}", run_ids_.front(), run_ids_.back()), "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  std::vector<analysis::AnalysisSeries> series;
  for (const auto& d : data_) series.push_back(run_series(d));
  auto cmp = analysis::compare_models(series);
  ASSERT_TRUE(cmp) << cmp.error().message;
  EXPECT_EQ(j.at("runs").get<std::size_t>(), static_cast<std::size_t>(kRuns));
  EXPECT_EQ(j.at("none").at("mean_dph").get<double>(), cmp->none.mean_dph);
  EXPECT_EQ(j.at("none").at("std_dph").get<double>(), cmp->none.std_dph);
  ASSERT_EQ(j.at("cells").size(), 12u);
  ASSERT_EQ(cmp->cells.size(), 12u);
  for (std::size_t i = 0; i < 12; ++i) {
    const json& c = j["cells"][i];
    const auto& e = cmp->cells[i];
    SCOPED_TRACE(c.dump());
    EXPECT_EQ(c.at("terms").get<std::string>(), analysis::to_string(e.terms));
    EXPECT_EQ(c.at("order").get<int>(), e.order);
    ASSERT_EQ(c.at("in_sample").is_null(), !e.in_sample);
    ASSERT_EQ(c.at("cross_validated").is_null(), !e.cross_validated);
    if (e.in_sample) {
      EXPECT_EQ(c["in_sample"]["mean_dph"].get<double>(), e.in_sample->mean_dph);
      EXPECT_EQ(c["in_sample"]["std_dph"].get<double>(), e.in_sample->std_dph);
    } else {
      EXPECT_FALSE(c.at("in_sample_error").get<std::string>().empty());
    }
    if (e.cross_validated) {
      EXPECT_EQ(c["cross_validated"]["std_dph"].get<double>(), e.cross_validated->std_dph);
    }
  }
  // The known drift has T, G and R parts: each term set does better.
  auto std_of = [&](int cell) { return j["cells"][cell]["in_sample"]["std_dph"].get<double>(); };
  EXPECT_GT(std_of(1), std_of(5));
  EXPECT_GT(std_of(5), std_of(9));
}

TEST_F(CliAnalysisTest, CompareTextIsLaidOutLikeThePapersTables) {
  const Run r = cli({"compare", "--csv", run_csv_file(0), run_csv_file(1), "--max-order", "2"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("101-point centred moving average"));
  const Run raw = cli({"compare", "--csv", run_csv_file(0), run_csv_file(1), "--max-order", "2",
                       "--smooth-points", "1", "--json"});
  ASSERT_EQ(raw.code, 0) << raw.err;
  EXPECT_EQ(raw.parsed().at("smooth_points").get<int>(), 1);
  const Run even = cli({"compare", "--csv", run_csv_file(0), "--smooth-points", "100"});
  EXPECT_EQ(even.code, 2) << even.out;
  EXPECT_THAT(even.err, HasSubstr("--smooth-points"));
  for (const char* s :
       {"Table II", "Table III", "Table IV", "none", "linear", "2 order", "LORO std °/h"}) {
    EXPECT_THAT(r.out, HasSubstr(s));
  }
  EXPECT_EQ(r.out.find("3 order"), std::string::npos);
}

// ---------------------------------------------------------------- start-model

TEST_F(CliAnalysisTest, StartModelMatchesTheLibraryAndExports) {
  const std::string json_path = file("start.json"), header_path = file("start.h");
  const Run r =
      cli({"start-model", "--db", db_path_, "--runs",
           fmt::format("{}-{}", run_ids_.front(), run_ids_.back()), "--model", "T2+R1+G1", "--t0",
           "12.5", "--json", "--coefficients-json", json_path, "--c-header", header_path});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  std::vector<analysis::AnalysisSeries> series;
  for (const auto& d : data_) series.push_back(run_series(d));
  analysis::StartTemperatureOptions o;
  o.spec = {.t_order = 2, .r_order = 1, .g_order = 1};
  auto model = analysis::fit_start_temperature_model(series, o);
  ASSERT_TRUE(model) << model.error().message;
  ASSERT_EQ(j.at("runs").size(), static_cast<std::size_t>(kRuns));
  for (int k = 0; k < kRuns; ++k) {
    EXPECT_EQ(j["runs"][k].at("t0_c").get<double>(), model->t0_c[k]);
    EXPECT_EQ(j["runs"][k].at("run_id").get<int64_t>(), run_ids_[k]);
  }
  ASSERT_EQ(j.at("cubic").size(), model->cubic.size());
  for (const auto& [k, a] : model->cubic) {
    ASSERT_EQ(j["cubic"].at(k).size(), 4u);
    for (int i = 0; i < 4; ++i) EXPECT_EQ(j["cubic"][k][i].get<double>(), a[i]) << k << i;
  }
  auto at = analysis::coefficients_at(*model, 12.5);
  ASSERT_TRUE(at);
  EXPECT_EQ(j.at("at_t0").at("extrapolated").get<bool>(), at->extrapolated);
  for (const auto& [k, v] : at->fit.coefficients) {
    EXPECT_EQ(j["at_t0"]["coefficients"].at(k).get<double>(), v) << k;
  }
  const json exported = json::parse(read_text(json_path), nullptr, false);
  EXPECT_FALSE(exported.is_discarded()) << read_text(json_path);
  const std::string header = read_text(header_path);
  EXPECT_FALSE(header.empty());
  EXPECT_THAT(header, HasSubstr("gyrotherm_start"));
}

// A CSV of the export as rows of fields (no quoted fields in these files).
std::vector<std::vector<std::string>> read_csv_rows(const fs::path& p) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(read_text(p));
  std::string line;
  while (std::getline(in, line)) {
    std::vector<std::string> fields;
    std::string field;
    std::istringstream ls(line);
    while (std::getline(ls, field, ',')) fields.push_back(field);
    if (!line.empty() && line.back() == ',') fields.emplace_back();
    rows.push_back(std::move(fields));
  }
  return rows;
}

// The campaign export of four runs from four start temperatures: the
// numbers in its files are the library's on the same data, exactly (17
// significant digits read back), including the runs' Table I and fits that
// nothing stored (the report computes them) and the eq. 3 model.
TEST_F(CliAnalysisTest, ExportOfFourRunsCarriesTheLibrarysNumbers) {
  const fs::path out = dir_ / "export-4";
  const Run r = cli({"export", "--db", db_path_, "--out", out.string(), "--runs",
                     fmt::format("{}-{}", run_ids_.front(), run_ids_.back()), "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  EXPECT_EQ(j.at("runs").size(), static_cast<std::size_t>(kRuns));
  EXPECT_TRUE(fs::exists(out / "index.html"));

  std::vector<analysis::AnalysisSeries> series;
  for (const auto& d : data_) series.push_back(run_series(d));
  const analysis::DriftModelSpec spec{.t_order = 4, .r_order = 1, .g_order = 1};  // the default

  // Tables II-IV with leave-one-run-out.
  auto cmp = analysis::compare_models(series);
  ASSERT_TRUE(cmp) << cmp.error().message;
  const auto grid = read_csv_rows(out / "comparison.csv");
  ASSERT_EQ(grid.size(), 2 + cmp->cells.size());  // header, "none", the cells
  EXPECT_EQ(std::stod(grid[1].at(5)), cmp->none.std_dph);
  for (std::size_t i = 0; i < cmp->cells.size(); ++i) {
    const auto& row = grid[2 + i];
    const auto& cell = cmp->cells[i];
    EXPECT_EQ(row.at(0), analysis::to_string(cell.terms));
    EXPECT_EQ(std::stoi(row.at(1)), cell.order);
    ASSERT_TRUE(cell.in_sample && cell.cross_validated);
    EXPECT_EQ(std::stod(row.at(5)), cell.in_sample->std_dph) << i;
    EXPECT_EQ(std::stod(row.at(8)), cell.cross_validated->std_dph) << i;
  }

  // The joint fit (the centred form: the default) and the start-temperature model.
  auto joint = analysis::fit_drift_model(series, spec, analysis::DriftModelForm::kCentered);
  ASSERT_TRUE(joint) << joint.error().message;
  const json drift = json::parse(read_text(out / "drift-fit.json"));
  EXPECT_EQ(drift.at("form").get<std::string>(), "centered");
  EXPECT_TRUE(drift.at("coefficients").contains("intercept"));
  EXPECT_THAT(read_text(out / "drift-fit.h"), HasSubstr("Centred form"));
  for (const auto& [name, v] : joint->coefficients) {
    EXPECT_EQ(drift.at("coefficients").at(name).get<double>(), v) << name;
  }
  analysis::StartTemperatureOptions o;
  o.spec = spec;
  auto model = analysis::fit_start_temperature_model(series, o);
  ASSERT_TRUE(model) << model.error().message;
  const json start = json::parse(read_text(out / "start-model.json"));
  for (const auto& [name, a] : model->cubic) {
    for (int i = 0; i < 4; ++i) EXPECT_EQ(start.at("cubic").at(name)[i].get<double>(), a[i]);
  }
  EXPECT_THAT(read_text(out / "start-model.h"), HasSubstr("gyrotherm_start_coefficients"));

  // Each run: Table I and the fit in both forms, computed for the report.
  const auto all_rows = read_csv_rows(out / "table1.csv");
  std::size_t campaign_row = 1;
  for (int k = 0; k < kRuns; ++k) {
    const fs::path run_dir = out / fmt::format("run-{:04}", run_ids_[k]);
    const std::string html = read_text(run_dir / "report.html");
    EXPECT_THAT(html, HasSubstr("computed for this report"));
    const auto rows = read_csv_rows(run_dir / "table1.csv");
    ASSERT_EQ(rows.size(), 3u) << "header and two soaks";
    const std::vector<std::pair<double, double>>* windows[] = {&kSoak1Windows, &kSoak2Windows};
    for (int soak = 0; soak < 2; ++soak) {
      analysis::Table1Options t1;
      t1.ma_window = kStoredMaWindow;
      t1.earth_rate_dph = earth_rate();
      auto expected = analysis::table1_row(soak_series(data_[k], *windows[soak]), t1);
      ASSERT_TRUE(expected) << expected.error().message;
      const auto& row = rows[1 + soak];
      EXPECT_EQ(std::stoll(row.at(0)), run_ids_[k]);
      EXPECT_EQ(std::stoll(row.at(5)), static_cast<long long>(expected->n));
      EXPECT_EQ(std::stod(row.at(7)), expected->bias_mean_dph);
      EXPECT_EQ(std::stod(row.at(8)), expected->bias_mean_earth_removed_dph);
      EXPECT_EQ(std::stod(row.at(9)), expected->bias_std_dph);
      EXPECT_EQ(std::stod(row.at(10)), expected->bias_std_ma_dph);
      EXPECT_EQ(all_rows.at(campaign_row++), row) << "the summary repeats each run's rows";
    }
    for (auto form : {analysis::DriftModelForm::kPaper, analysis::DriftModelForm::kCentered}) {
      auto fit = analysis::fit_drift_model(series[k], spec, form);
      ASSERT_TRUE(fit) << fit.error().message;
      const json exported = json::parse(
          read_text(run_dir / fmt::format("drift-fit-{}.json", analysis::to_string(form))));
      for (const auto& [name, v] : fit->coefficients) {
        EXPECT_EQ(exported.at("coefficients").at(name).get<double>(), v) << name;
        EXPECT_EQ(exported.at("std_errors").at(name).get<double>(), fit->std_errors.at(name));
      }
    }
  }

  // Recorded as a manual export, which leaves the runs to the nightly one.
  auto db = storage::Database::open(db_path_);
  ASSERT_TRUE(db) << db.error().message;
  auto exports = db->exports();
  ASSERT_TRUE(exports) << exports.error().message;
  ASSERT_FALSE(exports->empty());
  EXPECT_EQ(exports->front().kind, "manual");
  EXPECT_EQ(exports->front().state, "done");
  EXPECT_EQ(exports->front().run_ids, run_ids_);
  EXPECT_EQ(exports->front().files.size(), j.at("files").size());
  auto pending = db->runs_not_exported();
  ASSERT_TRUE(pending);
  EXPECT_EQ(*pending, run_ids_);
}

TEST_F(CliAnalysisTest, StartModelNeedsFourStartTemperatures) {
  const Run r = cli(
      {"start-model", "--csv", run_csv_file(0), run_csv_file(1), run_csv_file(2), "--model", "T1"});
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_THAT(r.err, HasSubstr("distinct"));
}

// ---------------------------------------------------------------- bad input

TEST_F(CliAnalysisTest, ACsvWithABadRowIsRefusedNamingLineAndColumn) {
  const std::string path = file("bad.csv");
  write_text(path, "t_s,rate_dph,top_c,side_c\n0,8,20,19\n1,8,20,19\n2,abc,20,19\n3,8,20,19\n");
  const Run r = cli({"stats", "--csv", path, "--json"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr(path + ":4"));
  EXPECT_THAT(r.err, HasSubstr("rate_dph"));
  EXPECT_TRUE(r.out.empty()) << r.out;
}

TEST_F(CliAnalysisTest, ACsvWithNaNIsRefused) {
  const std::string path = file("nan.csv");
  write_text(path, "t_s,rate_dph,top_c,side_c\n0,8,20,19\n1,8,nan,19\n2,8,20,19\n");
  const Run r = cli({"allan", "--csv", path});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr(path + ":3"));
  EXPECT_THAT(r.err, HasSubstr("top_c"));
  EXPECT_THAT(r.err, HasSubstr("not finite"));
}

TEST_F(CliAnalysisTest, UnknownRunsAndBadRunListsAreUsageErrors) {
  Run r = cli({"stats", "--db", db_path_, "--run", "99", "--json"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("unknown run 99"));
  r = cli({"fit", "--db", db_path_, "--runs", fmt::format("{},99", run_ids_[0]), "--model", "T1"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("unknown run 99"));
  for (const auto& [list, named] : std::vector<std::pair<std::string, std::string>>{
           {"1,x", "\"x\""}, {"5-3", "5-3"}, {"1,,2", "empty"}, {"1,1", "twice"}}) {
    r = cli({"compare", "--db", db_path_, "--runs", list});
    EXPECT_EQ(r.code, 2) << list;
    EXPECT_THAT(r.err, HasSubstr(named)) << list;
  }
  r = cli({"fit", "--db", db_path_, "--model", "T1"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("--runs"));
  r = cli({"stats", "--db", file("missing.db")});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("missing.db"));
  r = cli({"stats"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("--db"));
}

TEST_F(CliAnalysisTest, ABadModelSpecIsAUsageError) {
  for (const std::string spec : {"T5", "T1+X2", "T1+T2", ""}) {
    const Run r =
        cli({"fit", "--db", db_path_, "--run", std::to_string(run_ids_[0]), "--model", spec});
    EXPECT_EQ(r.code, 2) << spec;
    EXPECT_THAT(r.err, HasSubstr("--model")) << spec;
    EXPECT_THAT(r.err, HasSubstr(spec)) << spec;
  }
  Run r = cli({"fit", "--csv", run_csv_file(0), "--model", "T1", "--form", "sideways"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("sideways"));
  r = cli({"compare", "--csv", run_csv_file(0), "--max-order", "7"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("--max-order"));
  r = cli({"stats", "--csv", run_csv_file(0), "--orientation", "up"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("--latitude"));
}

TEST_F(CliAnalysisTest, AFitOnConstantTemperatureIsAnAnalysisErrorNamingT) {
  std::string text = "t_s,rate_dph,top_c,side_c\n";
  for (int i = 0; i < 600; ++i) {
    text += fmt::format("{},{},20.5,19.5\n", i, 8 + 0.01 * (i % 7));
  }
  const std::string path = file("constant.csv");
  write_text(path, text);
  const Run r = cli({"fit", "--csv", path, "--model", "T2", "--json"});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr(path));
  EXPECT_THAT(r.err, HasSubstr("term T cannot be fitted"));
  EXPECT_THAT(r.err, HasSubstr("constant"));
  EXPECT_TRUE(r.out.empty()) << r.out;
}

TEST_F(CliAnalysisTest, AnExportFileThatCannotBeWrittenIsAnError) {
  const Run r = cli({"fit", "--csv", run_csv_file(0), "--model", "T1", "--coefficients-json",
                     file("no/such/dir/fit.json")});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("no/such/dir/fit.json"));
}

// ---------------------------------------------------------------- scale-factor

constexpr double kSfRatesDps[] = {1, 5, 10, 50, 100, 200, 500};

// Rate points of a gyro whose output is K(1 ± A/2)·Ω + B (+ for Ω > 0), at
// ±kSfRatesDps, one row per dwell, K of repetition r times (1 + dk·(r − 1.5)).
std::string sf_csv(double k, double a, double b_dps, const std::vector<int>& repetitions, double dk,
                   const std::vector<double>& temperatures_c, double tc_ppm_per_c = 0,
                   double b_tc_dph_per_c = 0) {
  std::string text = "repetition, rate_dps,output_dps,temperature_c,note\n";
  for (double t : temperatures_c) {
    for (int r : repetitions) {
      const double k_t = k * (1 + tc_ppm_per_c * 1e-6 * (t - 25)) * (1 + dk * (r - 1.5));
      const double b_t = b_dps + b_tc_dph_per_c / 3600 * (t - 25);
      for (double sign : {1.0, -1.0}) {
        for (double m : kSfRatesDps) {
          const double w = sign * m;
          text += fmt::format("{},{:.17g},{:.17g},{:.17g},dwell\n", r, w,
                              k_t * (1 + sign * a / 2) * w + b_t, t);
        }
      }
    }
  }
  return text;
}

TEST_F(CliAnalysisTest, ScaleFactorOnACsvRecoversKBAsymmetryAndRepeatability) {
  const double k = 1.0003, a = 250e-6, b_dps = 0.002, dk = 4e-6;
  const std::string path = file("sf.csv");
  write_text(path, sf_csv(k, a, b_dps, {1, 2}, dk, {25.0}));
  Run r = cli({"scale-factor", "--csv", path, "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  const json j = r.parsed();
  EXPECT_EQ(j.at("source"), path);
  EXPECT_EQ(j.at("points").get<std::size_t>(), 28u);
  ASSERT_EQ(j.at("fits").size(), 1u);
  EXPECT_TRUE(j.at("over_temperature").is_null());
  const json& f = j.at("fits")[0];

  // Exactly the library's numbers on the same file.
  auto csv = analysis::read_rate_points_csv(path);
  ASSERT_TRUE(csv) << csv.error().message;
  auto lib = analysis::fit_scale_factor(csv->points);
  ASSERT_TRUE(lib) << lib.error().message;
  expect_number(f, "k", lib->k);
  expect_number(f, "k_std_error", lib->k_std_error);
  expect_number(f, "bias_dps", lib->bias_dps);
  expect_number(f, "bias_dph", lib->bias_dph);
  expect_number(f, "bias_std_error_dph", lib->bias_std_error_dph);
  expect_number(f, "nonlinearity_ppm", lib->nonlinearity_ppm);
  expect_number(f, "nonlinearity_fs_ppm", lib->nonlinearity_fs_ppm);
  expect_number(f, "asymmetry_ppm", *lib->asymmetry_ppm);
  expect_number(f, "repeatability_ppm", *lib->repeatability_ppm);
  ASSERT_EQ(f.at("residuals").size(), 28u);
  for (std::size_t i = 0; i < 28; ++i) {
    EXPECT_EQ(f.at("residuals")[i].at("line").get<std::size_t>(), i + 2);  // after the header
    expect_number(f.at("residuals")[i], "residual_dps", lib->residuals_dps[i]);
  }

  // And the truth. Both repetitions see the same symmetric rates, so the line's
  // slope is the mean K exactly; the asymmetry (|Ω|, even) moves the line's B
  // by K·A/2·mean|Ω| and leaves the split fit's bias at B.
  double mean_abs = 0;
  for (double m : kSfRatesDps) mean_abs += m / 7;
  EXPECT_NEAR(f.at("k").get<double>(), k, 1e-12);
  EXPECT_NEAR(f.at("asymmetry_ppm").get<double>(), 250.0, 1e-9 * 250);
  EXPECT_NEAR(f.at("asymmetry_bias_dps").get<double>(), b_dps, 1e-12);
  EXPECT_NEAR(f.at("bias_dps").get<double>(), b_dps + k * a / 2 * mean_abs, 1e-12);
  EXPECT_NEAR(f.at("bias_dph").get<double>(), (b_dps + k * a / 2 * mean_abs) * 3600, 1e-8);
  // K₁, K₂ = K(1 ∓ dk/2): std (ddof 1) = K·dk/√2, over their mean K.
  EXPECT_NEAR(f.at("repeatability_ppm").get<double>(), dk / std::sqrt(2.0) * 1e6, 1e-6);
  EXPECT_EQ(f.at("repetitions").size(), 2u);
  EXPECT_DOUBLE_EQ(f.at("temperature_c").get<double>(), 25.0);

  // The text gives the same figures and the residual table by file line.
  r = cli({"scale-factor", "--csv", path});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr(fmt::format("K  {:.9f} ±", lib->k)));
  EXPECT_THAT(r.out, HasSubstr(fmt::format("= {:.3f} °/h", lib->bias_dph)));
  EXPECT_THAT(r.out, HasSubstr("asymmetry 250.0 ppm"));
  EXPECT_THAT(r.out, HasSubstr(fmt::format("repeatability {:.2f} ppm over 2 repetitions",
                                           *lib->repeatability_ppm)));
  EXPECT_THAT(r.out,
              HasSubstr(fmt::format("nonlinearity {:.1f} ppm of K·Ω", lib->nonlinearity_ppm)));
  EXPECT_THAT(r.out, HasSubstr("ppm of K·Ω"));
  EXPECT_THAT(r.out, HasSubstr("  29  "));  // the last row's line
}

TEST_F(CliAnalysisTest, ScaleFactorAtSeveralTemperaturesFitsKAndBOverTemperature) {
  const double k = 0.99985, b_dps = -0.001;
  const std::string path = file("sf_temps.csv");
  // No asymmetry here: the line's B is then B(T) itself.
  write_text(path, sf_csv(k, 0, b_dps, {1}, 0, {-10.0, 25.0, 60.0}, 30.0, 0.05));
  Run r = cli({"scale-factor", "--csv", path, "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  json j = r.parsed();
  ASSERT_EQ(j.at("fits").size(), 3u);
  EXPECT_EQ(j.at("fits")[0].at("temperature_c").get<double>(), -10.0);  // increasing T
  EXPECT_EQ(j.at("fits")[2].at("temperature_c").get<double>(), 60.0);
  const json& o = j.at("over_temperature");
  ASSERT_TRUE(o.is_object()) << j.dump(2);
  EXPECT_EQ(o.at("order").get<int>(), 1);
  EXPECT_NEAR(o.at("temperature_mean_c").get<double>(), 25.0, 1e-12);
  EXPECT_NEAR(o.at("sf_temperature_coefficient_ppm_per_c").get<double>(), 30.0, 1e-6);
  EXPECT_NEAR(o.at("bias_temperature_coefficient_dph_per_c").get<double>(), 0.05, 1e-9);
  EXPECT_NEAR(o.at("k_at_mean").get<double>(), k, 1e-12);
  EXPECT_NEAR(o.at("bias_coefficients_dph")[0].get<double>(), b_dps * 3600, 1e-9);
  EXPECT_EQ(o.at("plateaus").size(), 3u);
  // The library on the per-temperature K and B gives the same numbers.
  std::vector<analysis::ScaleFactorAtTemperature> plateaus;
  for (const json& f : j.at("fits")) {
    plateaus.push_back({f.at("temperature_c").get<double>(), f.at("k").get<double>(),
                        f.at("bias_dph").get<double>()});
  }
  auto tf = analysis::fit_scale_factor_over_temperature(plateaus, 1);
  ASSERT_TRUE(tf) << tf.error().message;
  expect_number(o, "sf_temperature_coefficient_ppm_per_c",
                tf->sf_temperature_coefficient_ppm_per_c);
  expect_number(o, "bias_temperature_coefficient_dph_per_c",
                tf->bias_temperature_coefficient_dph_per_c);

  r = cli({"scale-factor", "--csv", path});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("at 3 temperatures"));
  EXPECT_THAT(r.out, HasSubstr("scale-factor temperature coefficient 30.000 ppm/°C"));
  EXPECT_THAT(r.out, HasSubstr("bias temperature coefficient 0.0500 (°/h)/°C"));

  r = cli({"scale-factor", "--csv", path, "--order", "2", "--json"});
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.parsed().at("over_temperature").at("order").get<int>(), 2);
  r = cli({"scale-factor", "--csv", path, "--order", "3"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("--order 3"));
  // Two temperatures cannot carry a quadratic: an analysis error naming why.
  const std::string two = file("sf_two_temps.csv");
  write_text(two, sf_csv(k, 0, b_dps, {1}, 0, {0.0, 50.0}, 30.0, 0.05));
  r = cli({"scale-factor", "--csv", two, "--order", "2"});
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_THAT(r.err, HasSubstr(two));
  EXPECT_THAT(r.err, HasSubstr("distinct temperatures"));
}

TEST_F(CliAnalysisTest, ScaleFactorRefusesABadCsvNamingFileLineAndColumn) {
  const std::string path = file("sf_bad.csv");
  write_text(path, "rate_dps,output_dps\n-10,-10.003\n10,10.002\n50,abc\n100,100.03\n");
  Run r = cli({"scale-factor", "--csv", path, "--json"});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr(path + ":4: column output_dps: 'abc' is not a number"));
  EXPECT_TRUE(r.out.empty()) << r.out;

  write_text(path, "rate_dps,output_dph\n-10,-10.003\n");
  r = cli({"scale-factor", "--csv", path});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr(path + ":1: header lacks column(s) output_dps"));

  write_text(path, "rate_dps,output_dps,repetition\n-10,-10.003,1\n10,10.002,2.5\n");
  r = cli({"scale-factor", "--csv", path});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr(path + ":3: column repetition: 2.5 is not a whole number"));

  // Readable, but one rate only: the analysis fails (exit 1) and says why.
  write_text(path, "rate_dps,output_dps\n100,100.01\n100,100.02\n");
  r = cli({"scale-factor", "--csv", path});
  EXPECT_EQ(r.code, 1);
  EXPECT_THAT(r.err, HasSubstr("2 distinct rates"));

  r = cli({"scale-factor", "--csv", file("no_such.csv")});
  EXPECT_EQ(r.code, 2);
  EXPECT_THAT(r.err, HasSubstr("no_such.csv"));
}

// ---------------------------------------------------------------- helpers

TEST(CliAnalysisHelpers, RunListsAcceptIdsAndRanges) {
  auto ids = cli::parse_run_list(" 3-5, 1 ,9");
  ASSERT_TRUE(ids) << ids.error().message;
  EXPECT_EQ(*ids, (std::vector<int64_t>{3, 4, 5, 1, 9}));
  for (const char* bad : {"", "0", "-1", "1-", "a-3", "2-1", "1,2,2-3", "1.5", "1;2"}) {
    EXPECT_FALSE(cli::parse_run_list(bad)) << bad;
  }
}

TEST(CliAnalysisHelpers, AtomicWriteReplacesTheFile) {
  const fs::path dir = fs::temp_directory_path() / fmt::format("gyrotherm-atomic-{}", ::getpid());
  fs::create_directories(dir);
  const std::string path = (dir / "out.h").string();
  ASSERT_TRUE(write_file_atomically(path, "first").ok());
  ASSERT_TRUE(write_file_atomically(path, "second").ok());
  EXPECT_EQ(read_text(path), "second");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir), fs::directory_iterator()), 1);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace gyrotherm

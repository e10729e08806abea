// End-to-end: calibration reports (docs/reports.md). The simulated station runs
// a short schedule, the daemon stores its analysis, and the exports must carry
// exactly the database's numbers: `gyrotherm export` on demand (CSV and JSON
// read back with ==, the C header compiled), the daemon's nightly job on a
// simulated wall clock (once per slot, also across a restart), the pages in
// headless Chromium, and the command's refusals of bad input.
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/storage/database.h"
#include "station_fixture.h"
#include "test_files.h"

#ifndef GYROTHERM_REPORT_PNG_DIR
#define GYROTHERM_REPORT_PNG_DIR GYROTHERM_BIN_DIR "/.."
#endif

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using testing::ChildProcess;
using ::testing::HasSubstr;
using testing::kTimeScale;
using testing::read_text;
using testing::StationTest;
using testing::wait_until;

// Tests that are not about the nightly job keep it off: its default slot on
// the real wall clock would otherwise fire in a test that runs across 02:00.
constexpr const char* kNoNightly = "[export]\nnightly = false\n";

std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) {
    if (c == '\'') {
      out += "'\\''";
    } else {
      out += c;
    }
  }
  out += '\'';
  return out;
}

// Every regular file under `dir`, relative to it, sorted.
std::vector<std::string> files_under(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.is_regular_file()) out.push_back(fs::relative(e.path(), dir).string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Names in `dir` that start with a dot (a temporary export left behind).
std::vector<std::string> hidden_entries(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (!name.empty() && name[0] == '.') out.push_back(name);
  }
  return out;
}

// ---------------------------------------------------------------- CSV

struct Csv {
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;

  const std::string& at(std::size_t row, const std::string& column) const {
    const auto it = std::find(header.begin(), header.end(), column);
    if (it == header.end() || row >= rows.size() ||
        static_cast<std::size_t>(it - header.begin()) >= rows[row].size()) {
      static const std::string kMissing = "<missing>";
      ADD_FAILURE() << "no column " << column << " in row " << row;
      return kMissing;
    }
    return rows[row][static_cast<std::size_t>(it - header.begin())];
  }
};

// RFC 4180: fields may be quoted, "" inside quotes is a quote.
Csv parse_csv(const std::string& text) {
  Csv csv;
  std::vector<std::string> record;
  std::string field;
  bool quoted = false, any = false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (quoted) {
      if (c == '"' && i + 1 < text.size() && text[i + 1] == '"') {
        field += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        field += c;
      }
      continue;
    }
    any = true;
    if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      record.push_back(std::move(field));
      field.clear();
    } else if (c == '\n') {
      record.push_back(std::move(field));
      field.clear();
      if (csv.header.empty()) {
        csv.header = std::move(record);
      } else {
        csv.rows.push_back(std::move(record));
      }
      record.clear();
      any = false;
    } else if (c != '\r') {
      field += c;
    }
  }
  EXPECT_FALSE(any) << "the CSV does not end with a newline";
  return csv;
}

// A CSV number: nullopt for an empty field; a failure for anything that is
// not a whole number text.
std::optional<double> csv_number(const std::string& field) {
  if (field.empty()) return std::nullopt;
  char* end = nullptr;
  const double v = std::strtod(field.c_str(), &end);
  if (end != field.c_str() + field.size()) {
    ADD_FAILURE() << "\"" << field << "\" is not a number";
    return std::nullopt;
  }
  return v;
}

void expect_exact(const Csv& csv, std::size_t row, const std::string& column, double stored) {
  const auto v = csv_number(csv.at(row, column));
  ASSERT_TRUE(v.has_value()) << column << " is empty, stored " << stored;
  EXPECT_EQ(*v, stored) << column << ": \"" << csv.at(row, column) << "\" vs stored "
                        << fmt::format("{:.17g}", stored);
}

void expect_exact(const Csv& csv, std::size_t row, const std::string& column,
                  std::optional<double> stored) {
  if (!stored) {
    EXPECT_EQ(csv.at(row, column), "") << column << " is NULL in the database";
    return;
  }
  expect_exact(csv, row, column, *stored);
}

void expect_integer(const Csv& csv, std::size_t row, const std::string& column, int64_t stored) {
  EXPECT_EQ(csv.at(row, column), std::to_string(stored)) << column;
}

// The CSV's Table I rows are the database's segment_stats, every column.
void expect_table1(const Csv& csv, const std::vector<storage::SegmentStatsRecord>& stats) {
  EXPECT_THAT(csv.header,
              ::testing::ElementsAre(
                  "run_id", "step", "segment_index", "setpoint_c", "temp_mean_c", "n", "duration_s",
                  "bias_mean_dph", "bias_mean_earth_removed_dph", "bias_std_dph", "bias_std_ma_dph",
                  "earth_rate_dph", "bin_s", "ma_window", "t_from_s", "t_to_s", "computed_utc",
                  "coverage", "coverage_samples", "coverage_expected", "longest_gap_s", "quality",
                  "quality_reasons", "bias_u_dph", "bias_u_expanded_dph", "bias_u_k", "bias_u_dof",
                  "bias_u_floor_dph", "bias_u_random_walk", "bias_u_note"));
  ASSERT_EQ(csv.rows.size(), stats.size());
  for (std::size_t i = 0; i < stats.size(); ++i) {
    const auto& s = stats[i];
    SCOPED_TRACE(fmt::format("Table I row {} (segment {})", i, s.segment_index));
    expect_integer(csv, i, "run_id", s.run_id);
    expect_integer(csv, i, "step", s.segment_index + 1);
    expect_integer(csv, i, "segment_index", s.segment_index);
    expect_exact(csv, i, "setpoint_c", s.setpoint_c);
    expect_exact(csv, i, "temp_mean_c", s.temp_mean_c);
    expect_integer(csv, i, "n", s.n);
    expect_exact(csv, i, "duration_s", s.duration_s);
    expect_exact(csv, i, "bias_mean_dph", s.bias_mean_dph);
    expect_exact(csv, i, "bias_mean_earth_removed_dph", s.bias_mean_earth_removed_dph);
    expect_exact(csv, i, "bias_std_dph", s.bias_std_dph);
    expect_exact(csv, i, "bias_std_ma_dph", s.bias_std_ma_dph);
    expect_exact(csv, i, "earth_rate_dph", s.earth_rate_dph);
    expect_exact(csv, i, "bin_s", s.bin_s);
    expect_integer(csv, i, "ma_window", s.ma_window);
    expect_exact(csv, i, "t_from_s", s.t_from_s);
    expect_exact(csv, i, "t_to_s", s.t_to_s);
    EXPECT_EQ(csv.at(i, "computed_utc"), s.computed_utc);
    expect_exact(csv, i, "coverage", s.quality.coverage);
    expect_integer(csv, i, "coverage_samples", s.quality.samples);
    expect_exact(csv, i, "longest_gap_s", s.quality.longest_gap_s);
    EXPECT_EQ(csv.at(i, "quality"), s.quality.verdict);
    // The bias mean's uncertainty, as stored: every soak of these runs has one.
    ASSERT_TRUE(s.bias_u) << s.bias_u_note;
    expect_exact(csv, i, "bias_u_dph", s.bias_u->u_dph);
    expect_exact(csv, i, "bias_u_expanded_dph", s.bias_u->expanded_dph);
    expect_exact(csv, i, "bias_u_k", s.bias_u->k);
    expect_exact(csv, i, "bias_u_dof", s.bias_u->dof);
    expect_exact(csv, i, "bias_u_floor_dph", s.bias_u->floor_dph);
    EXPECT_EQ(csv.at(i, "bias_u_random_walk"), s.bias_u->random_walk_dominated ? "1" : "0");
    EXPECT_EQ(csv.at(i, "bias_u_note"), "");
  }
}

// Exact equality of two JSON objects of numbers (coefficients, std errors).
void expect_same_numbers(const json& exported, const json& stored, const std::string& what) {
  ASSERT_TRUE(exported.is_object()) << what << ": " << exported.dump();
  ASSERT_TRUE(stored.is_object()) << what << ": " << stored.dump();
  std::vector<std::string> exported_keys, stored_keys;
  for (const auto& [k, v] : exported.items()) exported_keys.push_back(k);
  for (const auto& [k, v] : stored.items()) stored_keys.push_back(k);
  std::sort(exported_keys.begin(), exported_keys.end());
  std::sort(stored_keys.begin(), stored_keys.end());
  EXPECT_EQ(exported_keys, stored_keys) << what;
  for (const auto& [k, v] : stored.items()) {
    if (!exported.contains(k)) continue;
    ASSERT_TRUE(exported[k].is_number()) << what << " " << k << " = " << exported[k].dump();
    EXPECT_EQ(exported[k].get<double>(), v.get<double>())
        << what << " " << k << ": " << exported[k].dump() << " vs stored " << v.dump();
  }
}

// The events the daemon recorded about exports (kind "export", or errors
// that mention one), straight from the events table: they have no run.
struct ExportEvent {
  bool has_run = false;
  std::string kind, message;
};
std::vector<ExportEvent> export_events(const fs::path& db_path) {
  std::vector<ExportEvent> out;
  sqlite3* db = nullptr;
  if (sqlite3_open_v2(db_path.c_str(), &db, SQLITE_OPEN_READONLY, nullptr) != SQLITE_OK) {
    ADD_FAILURE() << "cannot open " << db_path << ": " << sqlite3_errmsg(db);
    sqlite3_close(db);
    return out;
  }
  sqlite3_busy_timeout(db, 5000);
  sqlite3_stmt* st = nullptr;
  const char* sql =
      "SELECT run_id IS NOT NULL, kind, message FROM events "
      "WHERE kind = 'export' OR message LIKE '%export%' ORDER BY id";
  if (sqlite3_prepare_v2(db, sql, -1, &st, nullptr) != SQLITE_OK) {
    ADD_FAILURE() << "events query: " << sqlite3_errmsg(db);
  } else {
    int rc;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
      ExportEvent e;
      e.has_run = sqlite3_column_int(st, 0) != 0;
      e.kind = reinterpret_cast<const char*>(sqlite3_column_text(st, 1));
      e.message = reinterpret_cast<const char*>(sqlite3_column_text(st, 2));
      out.push_back(std::move(e));
    }
    if (rc != SQLITE_DONE) ADD_FAILURE() << "events query: " << sqlite3_errmsg(db);
  }
  sqlite3_finalize(st);
  sqlite3_close(db);
  return out;
}

// ---------------------------------------------------------------- fixture

class ReportTest : public StationTest {
 protected:
  static void TearDownTestSuite() {
    if (!golden_dir_.empty() && !::testing::UnitTest::GetInstance()->Failed()) {
      std::error_code ec;
      fs::remove_all(golden_dir_, ec);
    }
  }

  fs::path db_path() const { return dir_ / "station.db"; }

  // [export]: the nightly export into `reports` at 00:45 UTC.
  void append_nightly_export(const fs::path& reports) {
    append_config(
        fmt::format("[export]\nnightly = true\ndirectory = \"{}\"\nlocal_time = "
                    "\"00:45\"\ntime_zone = \"UTC0\"\n",
                    reports.string()));
  }

  struct CliRun {
    int code = -1;
    std::string out, err;
    json parsed() const {
      json j = json::parse(out, nullptr, false);
      EXPECT_FALSE(j.is_discarded()) << "not JSON:\n" << out << "\nstderr:\n" << err;
      return j;
    }
  };
  // The real `gyrotherm` binary; a hung command is killed after 120 s.
  CliRun cli(const std::vector<std::string>& args) {
    const fs::path out = dir_ / "cli.out", err = dir_ / "cli.err";
    std::string cmd = fmt::format("timeout -k 5 120 {}", shell_quote(bin("gyrotherm")));
    for (const auto& a : args) cmd += fmt::format(" {}", shell_quote(a));
    cmd += fmt::format(" >{} 2>{}", shell_quote(out.string()), shell_quote(err.string()));
    const int st = std::system(cmd.c_str());
    CliRun r{WIFEXITED(st) ? WEXITSTATUS(st) : -1, read_text(out), read_text(err)};
    EXPECT_NE(r.code, 124) << "gyrotherm did not finish in 120 s: " << cmd;
    return r;
  }

  // Runs the fixture's schedule with the daemon left running, and waits
  // until the daemon stored run 1's analysis (its "analysis" event).
  void run_schedule_until_analysed() {
    start_sim();
    start_daemon();
    ASSERT_TRUE(wait_until([&] { return status().has_value(); }, std::chrono::seconds(30)))
        << daemon_->log();
    auto db = storage::Database::open_read_only(db_path().string());
    ASSERT_TRUE(db.ok()) << db.error().message;
    std::string last_state;
    const bool analysed = wait_until(
        [&] {
          auto run = db->run(1);
          if (run) last_state = run->state;
          auto events = db->events(1);
          return events && std::any_of(events->begin(), events->end(),
                                       [](const auto& e) { return e.kind == "analysis"; });
        },
        std::chrono::seconds(180));
    ASSERT_TRUE(analysed) << "no analysis of run 1 within 180 s (run state " << last_state << ")\n"
                          << daemon_->log();
    auto run = db->run(1);
    ASSERT_TRUE(run.ok()) << run.error().message;
    ASSERT_EQ(run->state, "completed");
  }

  // dir_/station.db: one completed run of the fixture's schedule with the
  // daemon's analysis stored, made once per process and copied.
  void use_completed_run_db() {
    if (!golden_error_) golden_error_ = make_golden();
    ASSERT_EQ(*golden_error_, "") << "the shared completed run could not be made";
    for (const char* name : {"station.db", "station.db-wal", "station.db-shm"}) {
      if (fs::exists(golden_dir_ / name)) fs::copy_file(golden_dir_ / name, dir_ / name);
    }
  }

  // dir_/station.db without samples: run 1 completed, run 2 still going.
  // Enough for the refusals, which come before anything is exported.
  void use_small_db() {
    auto db = storage::Database::open(db_path().string());
    ASSERT_TRUE(db.ok()) << db.error().message;
    for (const char* state : {"completed", "acquiring"}) {
      storage::RunRecord run;
      run.schedule_name = "small";
      run.state = state;
      run.latitude_deg = testing::kLatitudeDeg;
      run.orientation = "up";
      auto id = db->create_run(run);
      ASSERT_TRUE(id.ok()) << id.error().message;
      if (std::string(state) == "completed") {
        ASSERT_TRUE(db->set_run_state(*id, state, true).ok());
      }
    }
  }

  static std::string make_golden() {
    golden_dir_ = fs::temp_directory_path() / fmt::format("gyrotherm-report-golden-{}", ::getpid());
    fs::remove_all(golden_dir_);
    fs::create_directories(golden_dir_);
    const std::string bin_dir = GYROTHERM_BIN_DIR;
    const std::string config = (golden_dir_ / "station.toml").string();
    std::ofstream(config) << testing::station_config(golden_dir_, testing::free_tcp_port()) << "\n"
                          << kNoNightly;
    std::ofstream(golden_dir_ / "schedule.toml") << testing::kSchedule;
    ChildProcess sim({bin_dir + "/gyrotherm-sim", "--config", config, "--time-scale",
                      fmt::format("{}", kTimeScale)},
                     (golden_dir_ / "sim.log").string());
    if (!wait_until([&] { return fs::exists(golden_dir_ / "endpoints.toml"); },
                    std::chrono::seconds(20))) {
      return "the simulator wrote no endpoints:\n" + sim.log();
    }
    ChildProcess daemon(
        {bin_dir + "/gyrothermd", "--config", config, "--time-scale", fmt::format("{}", kTimeScale),
         "--schedule", (golden_dir_ / "schedule.toml").string(), "--exit-when-done"},
        (golden_dir_ / "daemon.log").string());
    const auto code = daemon.wait(std::chrono::seconds(180));
    if (!code) return "the daemon did not finish the schedule in 180 s:\n" + daemon.log();
    if (*code != 0) return fmt::format("the daemon exited {}:\n{}", *code, daemon.log());
    auto db = storage::Database::open_read_only((golden_dir_ / "station.db").string());
    if (!db) return db.error().message;
    auto run = db->run(1);
    if (!run || run->state != "completed") return "run 1 did not complete:\n" + daemon.log();
    auto fits = db->fits(1);
    auto allan = db->allan(1);
    auto stats = db->segment_stats(1);
    if (!fits || fits->size() != 2 || !allan || allan->size() != 2 || !stats ||
        stats->size() != 2) {
      return "run 1's analysis is not stored (2 fits, 2 Allan records, 2 Table I rows):\n" +
             daemon.log();
    }
    return "";
  }

  static inline fs::path golden_dir_;
  static inline std::optional<std::string> golden_error_;
};

// ---------------------------------------------------------------- export

TEST_F(ReportTest, ExportCarriesTheDatabaseNumbers) {
  append_config(kNoNightly);
  run_schedule_until_analysed();
  if (HasFatalFailure()) return;

  const fs::path out_dir = dir_ / "export";
  const CliRun r = cli(
      {"export", "--db", db_path().string(), "--out", out_dir.string(), "--runs", "1", "--json"});
  ASSERT_EQ(r.code, 0) << r.err << r.out;
  const json printed = r.parsed();
  EXPECT_EQ(printed.at("runs"), json::array({1}));
  EXPECT_EQ(printed.at("directory"), out_dir.string());
  ASSERT_TRUE(fs::is_directory(out_dir));
  EXPECT_EQ(hidden_entries(dir_), std::vector<std::string>{}) << "a temporary export was left";

  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto stats = db->segment_stats(1);
  ASSERT_TRUE(stats.ok()) << stats.error().message;
  ASSERT_EQ(stats->size(), 2u);
  auto allan = db->allan(1);
  ASSERT_TRUE(allan.ok()) << allan.error().message;
  ASSERT_EQ(allan->size(), 2u);
  auto fits = db->fits(1);
  ASSERT_TRUE(fits.ok()) << fits.error().message;
  ASSERT_EQ(fits->size(), 2u);

  {
    SCOPED_TRACE("run-0001/table1.csv");
    expect_table1(parse_csv(read_text(out_dir / "run-0001/table1.csv")), *stats);
  }
  {
    SCOPED_TRACE("table1.csv (every run)");
    expect_table1(parse_csv(read_text(out_dir / "table1.csv")), *stats);
  }

  {
    SCOPED_TRACE("run-0001/allan.csv");
    const Csv csv = parse_csv(read_text(out_dir / "run-0001/allan.csv"));
    ASSERT_EQ(csv.rows.size(), allan->size());
    for (std::size_t i = 0; i < allan->size(); ++i) {
      const auto& a = (*allan)[i];
      SCOPED_TRACE(fmt::format("Allan row {} (segment {})", i, a.segment_index));
      expect_integer(csv, i, "run_id", a.run_id);
      expect_integer(csv, i, "segment_index", a.segment_index);
      expect_integer(csv, i, "step", a.segment_index + 1);
      EXPECT_EQ(csv.at(i, "taus"), a.taus);
      expect_exact(csv, i, "tau0_s", a.tau0_s);
      expect_integer(csv, i, "n_samples", a.n_samples);
      expect_exact(csv, i, "angle_random_walk_dprh", a.angle_random_walk_dprh);
      expect_exact(csv, i, "bias_instability_dph", a.bias_instability_dph);
      expect_exact(csv, i, "bias_instability_tau_s", a.bias_instability_tau_s);
      expect_exact(csv, i, "rate_random_walk_dphprh", a.rate_random_walk_dphprh);
      expect_exact(csv, i, "t_from_s", a.t_from_s);
      expect_exact(csv, i, "t_to_s", a.t_to_s);
      // Each term's kind and bound, as recomputed from the stored curve.
      const analysis::AllanNoiseTerms terms = analysis::allan_noise_terms(
          static_cast<std::size_t>(a.n_samples), a.tau0_s, a.tau_s, a.adev_dph);
      const std::tuple<const char*, const char*, const analysis::NoiseTerm*> columns[] = {
          {"angle_random_walk_kind", "angle_random_walk_bound_dprh", &terms.angle_random_walk_dprh},
          {"bias_instability_kind", "bias_instability_bound_dph", &terms.bias_instability_dph},
          {"rate_random_walk_kind", "rate_random_walk_bound_dphprh",
           &terms.rate_random_walk_dphprh}};
      for (const auto& [kind_column, bound_column, term] : columns) {
        EXPECT_EQ(csv.at(i, kind_column), analysis::to_string(term->kind)) << kind_column;
        if (term->kind == analysis::NoiseTermKind::kUpperBound) {
          expect_exact(csv, i, bound_column, term->value);
        } else {
          EXPECT_EQ(csv.at(i, bound_column), "") << bound_column;
        }
      }
      // White noise over a short soak: the curve still falls at its last tau,
      // so the bias instability is a bound, sigma(tau_max) / 0.664 at tau >= tau_max.
      EXPECT_EQ(csv.at(i, "bias_instability_kind"), "upper_bound");
      ASSERT_FALSE(a.adev_dph.empty());
      expect_exact(csv, i, "bias_instability_bound_dph", a.adev_dph.back() / 0.664);
      expect_exact(csv, i, "bias_instability_bound_tau_s", a.tau_s.back());
    }
    // White noise only: the ARW is there, so the comparison saw a number.
    EXPECT_TRUE((*allan)[0].angle_random_walk_dprh.has_value());
    // The page shows the bound, not a dash.
    const std::string page = read_text(out_dir / "run-0001/report.html");
    EXPECT_THAT(page, ::testing::HasSubstr(fmt::format(
                          "&lt; {:.5f}</td><td class=\"num\">≥ {:.0f}</td>",
                          (*allan)[0].adev_dph.back() / 0.664, (*allan)[0].tau_s.back())));
  }

  for (const char* form : {"paper", "centered"}) {
    SCOPED_TRACE(fmt::format("drift-fit-{}.json", form));
    const auto stored = std::find_if(fits->begin(), fits->end(),
                                     [&](const storage::FitRecord& f) { return f.form == form; });
    ASSERT_NE(stored, fits->end()) << "no stored " << form << " fit";
    const json j = json::parse(read_text(out_dir / fmt::format("run-0001/drift-fit-{}.json", form)),
                               nullptr, false);
    ASSERT_FALSE(j.is_discarded());
    EXPECT_EQ(j.at("model"), stored->model);
    EXPECT_EQ(j.at("form"), stored->form);
    EXPECT_EQ(j.at("n").get<int64_t>(), stored->n);
    EXPECT_EQ(j.at("residual_std_dph").get<double>(), stored->residual_std_dph);
    EXPECT_EQ(j.at("r_squared").get<double>(), stored->r_squared);
    expect_same_numbers(j.at("coefficients"), json::parse(stored->coefficients_json),
                        "coefficients");
    expect_same_numbers(j.at("std_errors"), json::parse(stored->standard_errors_json),
                        "std_errors");
  }

  // Recorded: one manual export of run 1, done, listing what is on disk.
  const std::vector<std::string> on_disk = files_under(out_dir);
  for (const char* expected :
       {"index.html", "table1.csv", "run-0001/report.html", "run-0001/table1.csv",
        "run-0001/allan.csv", "run-0001/drift-fit-paper.json", "run-0001/drift-fit-paper.h"}) {
    EXPECT_TRUE(std::binary_search(on_disk.begin(), on_disk.end(), std::string(expected)))
        << expected << " is not in the export";
  }
  auto exports = db->exports();
  ASSERT_TRUE(exports.ok()) << exports.error().message;
  ASSERT_EQ(exports->size(), 1u);
  const auto& e = exports->front();
  EXPECT_EQ(e.kind, "manual");
  EXPECT_EQ(e.state, "done") << e.message;
  EXPECT_EQ(e.run_ids, std::vector<int64_t>{1});
  EXPECT_EQ(e.directory, out_dir.string());
  EXPECT_FALSE(e.slot_unix_s.has_value());
  EXPECT_EQ(e.files, on_disk);
  EXPECT_EQ(printed.at("export_id").get<int64_t>(), e.id);
  EXPECT_EQ(printed.at("files").get<std::vector<std::string>>(), on_disk);

  // The running daemon lists it.
  const json listed = get_json("/api/v1/exports");
  ASSERT_TRUE(listed.is_array()) << listed.dump() << "\n" << daemon_->log();
  ASSERT_EQ(listed.size(), 1u) << listed.dump();
  EXPECT_EQ(listed[0].at("id"), e.id);
  EXPECT_EQ(listed[0].at("kind"), "manual");
  EXPECT_EQ(listed[0].at("state"), "done");
  EXPECT_EQ(listed[0].at("run_ids"), json::array({1}));
  EXPECT_EQ(listed[0].at("directory"), out_dir.string());
  EXPECT_EQ(listed[0].at("files").get<std::vector<std::string>>(), on_disk);

  // The C headers compile as C99 with every warning an error.
  const std::string cc = testing::find_program("cc");
  ASSERT_FALSE(cc.empty()) << "no C compiler (cc) on PATH";
  for (const char* form : {"paper", "centered"}) {
    SCOPED_TRACE(fmt::format("drift-fit-{}.h", form));
    const std::string header = fmt::format("drift-fit-{}.h", form);
    const std::string text = read_text(out_dir / "run-0001" / header);
    std::smatch m;
    ASSERT_TRUE(std::regex_search(text, m, std::regex(R"(static inline double (\w+)_terms\()")))
        << text;
    const fs::path c_dir = dir_ / fmt::format("cc-{}", form);
    fs::create_directories(c_dir);
    write(c_dir / "main.c", fmt::format("#include \"{0}\"\n"
                                        "double drift_dph(void);\n"
                                        "double drift_dph(void) {{ return {1}_terms(20.0, "
                                        "0.001, 0.5); }}\n",
                                        header, m[1].str()));
    const std::string cmd = fmt::format(
        "{} -std=c99 -Wall -Wextra -pedantic -Werror -I{} -c {} -o {} 2>{}", cc,
        shell_quote((out_dir / "run-0001").string()), shell_quote((c_dir / "main.c").string()),
        shell_quote((c_dir / "main.o").string()), shell_quote((c_dir / "cc.log").string()));
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd << "\n" << read_text(c_dir / "cc.log");
  }
}

// ---------------------------------------------------------------- nightly

TEST_F(ReportTest, NightlyExportByTheDaemon) {
  // The station's wall clock starts at midnight UTC and runs at the time
  // scale; the slot is 45 station minutes later, after the ~20 minutes the
  // schedule takes.
  constexpr const char* kWallStart = "2026-06-10T00:00:00Z";
  constexpr const char* kAfterSlot = "2026-06-10T01:30:00Z";  // before the next, 06-11 00:45
  const fs::path reports = dir_ / "reports";
  append_nightly_export(reports);
  const auto start_unix_s = parse_utc_iso(kWallStart);
  ASSERT_TRUE(start_unix_s.ok());
  const double slot_unix_s = *start_unix_s + 45 * 60;

  start_sim();
  start_daemon({"--wall-start", kWallStart});

  json nightly;
  const bool exported = wait_until(
      [&] {
        const json list = get_json("/api/v1/exports");
        if (!list.is_array()) return false;
        for (const auto& e : list) {
          if (e.value("kind", "") == "nightly" && e.value("state", "") != "writing") {
            nightly = e;
            return true;
          }
        }
        return false;
      },
      std::chrono::seconds(120));
  ASSERT_TRUE(exported) << "no nightly export within 120 s (slot at 45 station min = "
                        << 45 * 60 / kTimeScale << " s)\n"
                        << daemon_->log();
  EXPECT_EQ(nightly.at("state"), "done") << nightly.dump();
  EXPECT_EQ(nightly.at("run_ids"), json::array({1}))
      << "the run completed before the slot must be in it: " << nightly.dump();
  EXPECT_EQ(nightly.at("slot_unix_s").get<double>(), slot_unix_s);
  EXPECT_EQ(nightly.at("slot_local"), "2026-06-10 00:45 UTC+00:00");
  const fs::path dir = nightly.at("directory").get<std::string>();
  EXPECT_EQ(dir, reports / "2026-06-10");
  EXPECT_TRUE(fs::is_regular_file(dir / "index.html")) << dir;
  EXPECT_TRUE(fs::is_regular_file(dir / "run-0001/report.html")) << dir;
  EXPECT_EQ(nightly.at("files").get<std::vector<std::string>>(), files_under(dir));
  EXPECT_EQ(hidden_entries(reports), std::vector<std::string>{}) << "a temporary export was left";

  // The daemon recorded an "export" event (no run: the events table).
  ASSERT_TRUE(
      wait_until([&] { return !export_events(db_path()).empty(); }, std::chrono::seconds(10)));
  auto events = export_events(db_path());
  ASSERT_EQ(events.size(), 1u);
  EXPECT_EQ(events[0].kind, "export") << events[0].message;
  EXPECT_FALSE(events[0].has_run);
  EXPECT_THAT(events[0].message,
              HasSubstr(fmt::format("nightly export {}", nightly.at("id").get<int64_t>())));

  // A restart after the slot, before the next: nothing is exported again.
  daemon_->signal(SIGTERM);
  const auto stopped = daemon_->wait(std::chrono::seconds(30));
  ASSERT_TRUE(stopped.has_value()) << daemon_->log();
  EXPECT_EQ(*stopped, 0) << daemon_->log();
  start_daemon({"--wall-start", kAfterSlot}, /*with_schedule=*/false);
  // 20 station minutes of the restarted daemon (its nightly job polls at
  // start and then every wall second: several polls).
  json last_list, last_status;
  const bool watched = wait_until(
      [&] {
        last_list = get_json("/api/v1/exports");
        if (last_list.is_array() && last_list.size() != 1) return true;  // fails below
        auto s = status();
        if (!s) return false;
        last_status = *s;
        return last_list.is_array() && last_status.value("t_station_s", 0.0) >= 20 * 60;
      },
      std::chrono::seconds(60));
  ASSERT_TRUE(watched) << "the restarted daemon did not run 20 station minutes in 60 s: "
                       << last_status.dump() << "\n"
                       << daemon_->log();
  ASSERT_TRUE(last_list.is_array());
  EXPECT_EQ(last_list.size(), 1u) << "exported again after the restart: " << last_list.dump();

  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  auto exports = db->exports();
  ASSERT_TRUE(exports.ok()) << exports.error().message;
  EXPECT_EQ(exports->size(), 1u);
  EXPECT_EQ(export_events(db_path()).size(), 1u);
  EXPECT_EQ(files_under(reports).size(), files_under(dir).size())
      << "a second export directory appeared in " << reports;
}

// Down over the slot: the run completes, the daemon stops before 00:45 and
// comes back at 03:00; it exports the missed slot once, at start.
TEST_F(ReportTest, NightlyExportCatchesUpAfterDowntime) {
  constexpr const char* kWallStart = "2026-06-10T00:00:00Z";
  constexpr const char* kBackAt = "2026-06-10T03:00:00Z";
  const fs::path reports = dir_ / "reports";
  append_nightly_export(reports);
  const auto start_unix_s = parse_utc_iso(kWallStart);
  ASSERT_TRUE(start_unix_s.ok());

  start_sim();
  start_daemon({"--wall-start", kWallStart});
  ASSERT_TRUE(wait_until([&] { return status().has_value(); }, std::chrono::seconds(30)))
      << daemon_->log();
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok()) << db.error().message;
  ASSERT_TRUE(wait_until(
      [&] {
        auto run = db->run(1);
        return run && run->state == "completed";
      },
      std::chrono::seconds(120)))
      << daemon_->log();
  daemon_->signal(SIGTERM);
  const auto stopped = daemon_->wait(std::chrono::seconds(30));
  ASSERT_TRUE(stopped.has_value()) << daemon_->log();
  EXPECT_EQ(*stopped, 0) << daemon_->log();
  auto before = db->exports();
  ASSERT_TRUE(before.ok()) << before.error().message;
  ASSERT_TRUE(before->empty()) << "the daemon stopped after the slot (a loaded machine?); "
                               << before->size() << " export(s) already\n"
                               << daemon_->log();

  start_daemon({"--wall-start", kBackAt}, /*with_schedule=*/false);
  json nightly;
  ASSERT_TRUE(wait_until(
      [&] {
        const json list = get_json("/api/v1/exports");
        if (!list.is_array() || list.empty()) return false;
        nightly = list;
        return list[0].value("state", "") != "writing";
      },
      std::chrono::seconds(60)))
      << daemon_->log();
  ASSERT_EQ(nightly.size(), 1u) << nightly.dump();
  EXPECT_EQ(nightly[0].at("kind"), "nightly");
  EXPECT_EQ(nightly[0].at("state"), "done") << nightly.dump();
  EXPECT_EQ(nightly[0].at("run_ids"), json::array({1}));
  EXPECT_EQ(nightly[0].at("slot_unix_s").get<double>(), *start_unix_s + 45 * 60)
      << "the missed slot, not the restart time";
  EXPECT_TRUE(fs::is_regular_file(reports / "2026-06-10/run-0001/report.html"));
  EXPECT_EQ(hidden_entries(reports), std::vector<std::string>{});
}

// ---------------------------------------------------------------- browser

TEST_F(ReportTest, ReportRendersInChromium) {
  const fs::path source_dir = GYROTHERM_SOURCE_DIR;
  const fs::path script = source_dir / "tests/browser/report.mjs";
  const testing::BrowserTools tools = testing::browser_tools(source_dir.string());
  if (!tools.missing.empty()) GTEST_FAIL() << tools.missing;
  const std::string& node = tools.node;

  use_completed_run_db();
  if (HasFatalFailure()) return;
  // No selection: the completed runs no nightly export took yet.
  const fs::path out_dir = dir_ / "export";
  const CliRun r = cli({"export", "--db", db_path().string(), "--out", out_dir.string(), "--json"});
  ASSERT_EQ(r.code, 0) << r.err << r.out;
  EXPECT_EQ(r.parsed().at("runs"), json::array({1}));

  const std::regex chart_div(R"re(<div class="chart" id="([A-Za-z0-9_-]+)")re");
  for (const auto& [page, png_name] : {std::pair{"run-0001/report.html", "report-run-0001.png"},
                                       std::pair{"index.html", "report-index.png"}}) {
    SCOPED_TRACE(page);
    const fs::path html = out_dir / page;
    const std::string text = read_text(html);
    const auto charts = static_cast<int>(std::distance(
        std::sregex_iterator(text.begin(), text.end(), chart_div), std::sregex_iterator()));
    EXPECT_GT(charts, 0) << "no <div class=\"chart\"> in " << html;
    const fs::path png = fs::weakly_canonical(fs::path(GYROTHERM_REPORT_PNG_DIR) / png_name);
    fs::remove(png);
    ChildProcess browser(
        {node, script.string(), "--html", html.string(), "--screenshot", png.string(),
         "--timeout-s", "60", "--expect-charts", std::to_string(charts)},
        (dir_ / fmt::format("browser-{}.log", png_name)).string());
    const auto code = browser.wait(std::chrono::seconds(120));
    ASSERT_TRUE(code.has_value()) << "the browser test did not finish in 120 s\n" << browser.log();
    EXPECT_EQ(*code, 0) << browser.log();
    ASSERT_TRUE(fs::exists(png)) << "no screenshot at " << png << "\n" << browser.log();
    EXPECT_GT(fs::file_size(png), 10u * 1024) << png << " is too small to be the report";
    std::printf("report screenshot (%d charts): %s\n", charts, png.c_str());
  }
}

// ---------------------------------------------------------------- bad input

TEST_F(ReportTest, ExportRefusesAnUnknownRun) {
  use_small_db();
  if (HasFatalFailure()) return;
  const fs::path out_dir = dir_ / "export";
  const CliRun r =
      cli({"export", "--db", db_path().string(), "--out", out_dir.string(), "--runs", "1,7"});
  EXPECT_EQ(r.code, 2) << r.out << r.err;
  EXPECT_THAT(r.err, HasSubstr("run 7"));
  EXPECT_FALSE(fs::exists(out_dir));
  // A run still going is refused the same way.
  const CliRun going =
      cli({"export", "--db", db_path().string(), "--out", out_dir.string(), "--runs", "2"});
  EXPECT_EQ(going.code, 2) << going.out << going.err;
  EXPECT_THAT(going.err, HasSubstr("run 2"));
  EXPECT_FALSE(fs::exists(out_dir));
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok());
  auto exports = db->exports();
  ASSERT_TRUE(exports.ok());
  EXPECT_TRUE(exports->empty());
}

TEST_F(ReportTest, ExportRefusesRunsWithSince) {
  use_small_db();
  if (HasFatalFailure()) return;
  const fs::path out_dir = dir_ / "export";
  const CliRun r = cli({"export", "--db", db_path().string(), "--out", out_dir.string(), "--runs",
                        "1", "--since", "2026-01-01"});
  EXPECT_EQ(r.code, 2) << r.out << r.err;
  EXPECT_THAT(r.err, HasSubstr("--since"));
  EXPECT_THAT(r.err, HasSubstr("--runs"));
  EXPECT_FALSE(fs::exists(out_dir));
}

TEST_F(ReportTest, ExportRefusesABadSinceDate) {
  use_small_db();
  if (HasFatalFailure()) return;
  const fs::path out_dir = dir_ / "export";
  for (const char* bad : {"2026-13-01", "yesterday", "2026-06-10T25:00"}) {
    SCOPED_TRACE(bad);
    const CliRun r =
        cli({"export", "--db", db_path().string(), "--out", out_dir.string(), "--since", bad});
    EXPECT_EQ(r.code, 2) << r.out << r.err;
    EXPECT_THAT(r.err, HasSubstr("--since"));
    EXPECT_THAT(r.err, HasSubstr(bad));
    EXPECT_FALSE(fs::exists(out_dir));
  }
}

TEST_F(ReportTest, ExportRefusesANonEmptyOutputDirectory) {
  use_small_db();
  if (HasFatalFailure()) return;
  const fs::path out_dir = dir_ / "export";
  fs::create_directories(out_dir / "sub");
  write(out_dir / "notes.txt", "keep me\n");
  write(out_dir / "sub/data.csv", "a,b\n1,2\n");
  const CliRun r =
      cli({"export", "--db", db_path().string(), "--out", out_dir.string(), "--runs", "1"});
  EXPECT_EQ(r.code, 2) << r.out << r.err;
  EXPECT_THAT(r.err, HasSubstr(out_dir.string()));
  EXPECT_THAT(r.err, HasSubstr("not an empty directory"));
  // Left untouched, and nothing beside it.
  EXPECT_EQ(files_under(out_dir), (std::vector<std::string>{"notes.txt", "sub/data.csv"}));
  EXPECT_EQ(read_text(out_dir / "notes.txt"), "keep me\n");
  EXPECT_EQ(read_text(out_dir / "sub/data.csv"), "a,b\n1,2\n");
  EXPECT_EQ(hidden_entries(dir_), std::vector<std::string>{});
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok());
  auto exports = db->exports();
  ASSERT_TRUE(exports.ok());
  EXPECT_TRUE(exports->empty()) << "a refused export was recorded";

  // A file where the directory should be: refused too.
  const fs::path file_out = dir_ / "a-file";
  write(file_out, "x");
  const CliRun f =
      cli({"export", "--db", db_path().string(), "--out", file_out.string(), "--runs", "1"});
  EXPECT_EQ(f.code, 2) << f.out << f.err;
  EXPECT_EQ(read_text(file_out), "x");
}

TEST_F(ReportTest, ExportRefusesAMissingDatabase) {
  const fs::path missing = dir_ / "no-such.db";
  const fs::path out_dir = dir_ / "export";
  const CliRun r =
      cli({"export", "--db", missing.string(), "--out", out_dir.string(), "--runs", "1"});
  EXPECT_EQ(r.code, 2) << r.out << r.err;
  EXPECT_THAT(r.err, HasSubstr(missing.string()));
  EXPECT_FALSE(fs::exists(missing)) << "the command created the database";
  EXPECT_FALSE(fs::exists(out_dir));
}

TEST_F(ReportTest, ExportSinceSelectsRunsByTheirEndTime) {
  use_completed_run_db();
  if (HasFatalFailure()) return;
  {
    // Run 1 (completed) ended 2026-03-10 12:00 UTC; beside it a completed
    // run that ended a day earlier and an interrupted one that ended later.
    auto db = storage::Database::open(db_path().string());
    ASSERT_TRUE(db.ok()) << db.error().message;
    ASSERT_TRUE(db->exec("UPDATE runs SET ended_utc = '2026-03-10T12:00:00Z' WHERE id = 1").ok());
    auto one = db->run(1);
    ASSERT_TRUE(one.ok());
    for (const auto& [state, ended] : {std::pair{"completed", "2026-03-09T12:00:00Z"},
                                       std::pair{"interrupted", "2026-03-11T12:00:00Z"}}) {
      storage::RunRecord run = *one;
      run.state = state;
      run.queue_id.reset();
      run.schedule_id.reset();
      run.resume_json.clear();
      run.uuid.clear();  // a new run: create_run gives it its own (schema v10)
      auto id = db->create_run(run);
      ASSERT_TRUE(id.ok()) << id.error().message;
      ASSERT_TRUE(db->set_run_state(*id, state, true).ok());
      ASSERT_TRUE(
          db->exec(fmt::format("UPDATE runs SET ended_utc = '{}' WHERE id = {}", ended, *id)).ok());
    }
  }
  int k = 0;
  for (const char* since :
       {"2026-03-10", "2026-03-10T12:00:00Z", "2026-03-10T13:00+01:00", "2026-03-10T11:59:59.5Z"}) {
    SCOPED_TRACE(since);
    const fs::path out_dir = dir_ / fmt::format("export-{}", k++);
    const CliRun r = cli({"export", "--db", db_path().string(), "--out", out_dir.string(),
                          "--since", since, "--json"});
    ASSERT_EQ(r.code, 0) << r.out << r.err;
    EXPECT_EQ(r.parsed().at("runs"), json::array({1}));
    EXPECT_TRUE(fs::is_regular_file(out_dir / "run-0001/report.html"));
    EXPECT_FALSE(fs::exists(out_dir / "run-0002")) << "the run that ended before --since";
    EXPECT_FALSE(fs::exists(out_dir / "run-0003")) << "a run that did not complete";
  }
  for (const char* since : {"2026-03-10T12:00:01Z", "2026-03-10T12:30:00+00:00"}) {
    SCOPED_TRACE(since);
    const fs::path out_dir = dir_ / fmt::format("export-{}", k++);
    const CliRun r = cli({"export", "--db", db_path().string(), "--out", out_dir.string(),
                          "--since", since, "--json"});
    ASSERT_EQ(r.code, 0) << r.out << r.err;
    const json j = r.parsed();
    EXPECT_EQ(j.at("runs"), json::array());
    EXPECT_TRUE(j.at("export_id").is_null());
    EXPECT_FALSE(fs::exists(out_dir)) << "nothing to export, nothing written";
  }
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok());
  auto exports = db->exports();
  ASSERT_TRUE(exports.ok());
  ASSERT_EQ(exports->size(), 4u);
  for (const auto& e : *exports) {
    EXPECT_EQ(e.kind, "manual");
    EXPECT_EQ(e.state, "done") << e.message;
    EXPECT_EQ(e.run_ids, std::vector<int64_t>{1});
  }
}

// `--out DIR/` names DIR: the export goes there (its temporary directory
// beside it, not inside), and the record says so.
TEST_F(ReportTest, ExportIntoADirectoryGivenWithATrailingSlash) {
  use_completed_run_db();
  if (HasFatalFailure()) return;
  const fs::path out_dir = dir_ / "export";
  const CliRun r = cli({"export", "--db", db_path().string(), "--out", out_dir.string() + "/",
                        "--runs", "1", "--json"});
  ASSERT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_TRUE(fs::is_regular_file(out_dir / "run-0001/report.html"));
  EXPECT_EQ(hidden_entries(out_dir), std::vector<std::string>{});
  auto db = storage::Database::open_read_only(db_path().string());
  ASSERT_TRUE(db.ok());
  auto exports = db->exports();
  ASSERT_TRUE(exports.ok());
  ASSERT_EQ(exports->size(), 1u);
  EXPECT_EQ(exports->front().state, "done") << exports->front().message;
  EXPECT_EQ(exports->front().directory, out_dir.string());
}

}  // namespace
}  // namespace gyrotherm

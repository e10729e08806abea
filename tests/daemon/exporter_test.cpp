// Calibration exports (exporter.h): the nightly job on a virtual wall clock
// across daylight-saving changes, downtime, restarts, empty slots,
// interrupted and failed exports; manual exports; the atomic layout of an
// export directory. The reference instants are computed by hand (commented).
#include "gyrotherm/calibration/exporter.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <stdlib.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <csignal>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/storage/sample_writer.h"
#include "scale_factor_rows.h"
#include "test_files.h"
#include "test_time.h"
#include "utc_time.h"

namespace gyrotherm::calibration {
namespace {

namespace fs = std::filesystem;

using test::utc;

config::TimeZone berlin() {
  auto z = config::TimeZone::posix("CET-1CEST,M3.5.0,M10.5.0/3");
  EXPECT_TRUE(z.ok()) << z.error().message;
  return *z;
}

// Every regular file under `dir`, relative to it, sorted.
std::vector<std::string> files_on_disk(const fs::path& dir) {
  std::vector<std::string> out;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    if (e.is_regular_file()) out.push_back(fs::relative(e.path(), dir).string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Every path under `dir` whose name contains ".partial-".
std::vector<std::string> partial_dirs(const fs::path& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(dir, ec);
       !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    if (it->path().filename().string().find(".partial-") != std::string::npos) {
      out.push_back(it->path().string());
    }
  }
  return out;
}

class ExporterTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "gyrotherm-exporter-XXXXXX").string();
    ASSERT_NE(::mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
    db_path_ = (dir_ / "station.db").string();
    root_ = (dir_ / "reports").string();
    auto db = storage::Database::open(db_path_);
    ASSERT_TRUE(db.ok()) << db.error().message;
    db_.emplace(std::move(*db));
  }
  void TearDown() override {
    db_.reset();
    std::error_code ec;
    // A failed test keeps its directory; GYROTHERM_KEEP_TEST_DIR=1 keeps every one.
    if (!HasFailure() && !std::getenv("GYROTHERM_KEEP_TEST_DIR")) fs::remove_all(dir_, ec);
  }

  storage::Database& db() { return *db_; }

  // A completed run with one soak segment and no samples.
  int64_t complete_run(const std::string& name = "paper-table1") {
    storage::RunRecord r;
    r.schedule_name = name;
    r.state = "acquiring";
    r.orientation = "up";
    auto id = db().create_run(r);
    EXPECT_TRUE(id.ok()) << id.error().message;
    if (!id.ok()) return 0;
    storage::SegmentRecord s;
    s.run_id = *id;
    s.index = 0;
    s.kind = "soak";
    s.label = "soak 20 °C (step 1)";
    s.setpoint_c = 20;
    s.t_start_s = 0;
    s.t_acquire_start_s = 0;
    s.t_acquire_end_s = 300;
    s.t_end_s = 300;
    s.state = "completed";
    auto sid = db().create_segment(s);
    EXPECT_TRUE(sid.ok()) << sid.error().message;
    Status st = db().set_run_state(*id, "completed", true);
    EXPECT_TRUE(st.ok()) << st.error().message;
    return *id;
  }

  NightlyOptions options(config::LocalTimeOfDay at, config::TimeZone zone) const {
    NightlyOptions o;
    o.at = at;
    o.zone = std::move(zone);
    o.directory = root_;
    o.report.generated_utc = "2026-11-21T00:00:00.000Z";
    return o;
  }

  std::unique_ptr<NightlyExporter> exporter(const WallClock& clock, NightlyOptions o,
                                            NightlyExporter::Done done = {}) {
    auto e = NightlyExporter::create(db_path_, clock, std::move(o), nullptr, std::move(done));
    EXPECT_TRUE(e.ok()) << e.error().message;
    return e ? std::move(*e) : nullptr;
  }

  // The nightly exports, oldest first.
  std::vector<storage::ExportRecord> nightly_exports() {
    auto all = db().exports();
    EXPECT_TRUE(all.ok()) << all.error().message;
    std::vector<storage::ExportRecord> out;
    if (!all.ok()) return out;
    for (auto it = all->rbegin(); it != all->rend(); ++it) {
      if (it->kind == "nightly") out.push_back(*it);
    }
    return out;
  }

  storage::ExportRecord record(int64_t id) {
    auto e = db().export_record(id);
    EXPECT_TRUE(e.ok() && e->has_value()) << "export " << id;
    return e.ok() && e->has_value() ? **e : storage::ExportRecord{};
  }

  std::vector<int64_t> not_exported() {
    auto ids = db().runs_not_exported();
    EXPECT_TRUE(ids.ok()) << ids.error().message;
    return ids.ok() ? *ids : std::vector<int64_t>{};
  }

  // The record of a nightly export of `run_id` for Saturday 2026-11-21's
  // 02:00 slot, for a test to record as begun: what a crash during it leaves.
  storage::ExportRecord crashed_export(int64_t run_id, const config::TimeZone& zone) const {
    storage::ExportRecord r;
    r.kind = "nightly";
    r.slot_unix_s = utc(2026, 11, 21, 2);
    r.slot_local = local_time_label(*r.slot_unix_s, zone);
    r.directory = (fs::path(root_) / "2026-11-21").string();
    r.run_ids = {run_id};
    return r;
  }

  // poll() that must not fail; the export made, if any.
  static std::optional<ExportOutcome> poll_ok(NightlyExporter& e) {
    auto r = e.poll();
    EXPECT_TRUE(r.ok()) << r.error().message;
    return r.ok() ? *r : std::nullopt;
  }

  fs::path dir_;
  std::string db_path_;
  std::string root_;
  std::optional<storage::Database> db_;
};

// An export a poll made, and when.
struct Made {
  double at_unix_s;
  ExportOutcome outcome;
};

// Walks `clock` from `from` to `to` in steps of `step_s` and polls at each
// instant, after `before_poll(t)`.
template <class F>
std::vector<Made> walk(NightlyExporter& e, ManualWallClock& clock, double from, double to,
                       double step_s, F before_poll) {
  std::vector<Made> made;
  for (double t = from; t <= to; t += step_s) {
    clock.set(t);
    before_poll(t);
    auto r = e.poll();
    EXPECT_TRUE(r.ok()) << r.error().message;
    if (r.ok() && *r) made.push_back({t, **r});
  }
  return made;
}

TEST_F(ExporterTest, SpringForwardOneExportPerDayAtTheRightInstants) {
  const config::TimeZone zone = berlin();
  const double start = utc(2026, 3, 27, 12);
  ManualWallClock clock(start);
  auto e = exporter(clock, options({2, 30}, zone));

  // 2026-03-28 02:30 CET = 01:30 UTC; 2026-03-29: 02:30 does not exist, the
  // export runs at the end of the gap, 03:00 CEST = 01:00 UTC; then 02:30
  // CEST = 00:30 UTC.
  const std::vector<double> want_at = {utc(2026, 3, 28, 1, 30), utc(2026, 3, 29, 1, 0),
                                       utc(2026, 3, 30, 0, 30), utc(2026, 3, 31, 0, 30)};
  const std::vector<std::string> want_dir = {"2026-03-28", "2026-03-29", "2026-03-30",
                                             "2026-03-31"};
  const std::vector<std::string> want_label = {
      "2026-03-28 02:30 UTC+01:00", "2026-03-29 03:00 UTC+02:00", "2026-03-30 02:30 UTC+02:00",
      "2026-03-31 02:30 UTC+02:00"};

  // Runs complete at 12:00 UTC every day, and around the gap-day slot: just
  // before it (in that export) and just after it (in the next one).
  std::set<double> completions;
  for (int d = 0; d <= 4; ++d) completions.insert(start + d * 86400.0);
  completions.insert(utc(2026, 3, 28, 1, 25));
  completions.insert(utc(2026, 3, 29, 0, 55));
  completions.insert(utc(2026, 3, 29, 1, 5));
  std::vector<int64_t> pending;
  std::vector<std::vector<int64_t>> expected_runs;  // per slot: the runs completed before it
  const auto made = walk(*e, clock, start, utc(2026, 3, 31, 12), 300, [&](double t) {
    if (completions.count(t)) pending.push_back(complete_run());
    if (std::find(want_at.begin(), want_at.end(), t) != want_at.end()) {
      expected_runs.push_back(pending);
      pending.clear();
    }
  });

  ASSERT_EQ(made.size(), want_at.size());
  ASSERT_EQ(expected_runs.size(), want_at.size());
  const auto records = nightly_exports();
  ASSERT_EQ(records.size(), want_at.size());
  std::set<int64_t> seen;
  for (std::size_t i = 0; i < made.size(); ++i) {
    SCOPED_TRACE(want_dir[i]);
    EXPECT_EQ(made[i].at_unix_s, want_at[i]);
    EXPECT_EQ(fs::path(made[i].outcome.directory).filename().string(), want_dir[i]);
    EXPECT_TRUE(fs::is_regular_file(fs::path(made[i].outcome.directory) / "index.html"));
    const auto& rec = records[i];
    EXPECT_EQ(rec.id, made[i].outcome.export_id);
    EXPECT_EQ(rec.state, "done");
    ASSERT_TRUE(rec.slot_unix_s.has_value());
    EXPECT_EQ(*rec.slot_unix_s, want_at[i]);
    EXPECT_EQ(rec.slot_local, want_label[i]);
    EXPECT_EQ(rec.run_ids, expected_runs[i]);
    EXPECT_FALSE(rec.run_ids.empty());
    for (int64_t id : rec.run_ids) EXPECT_TRUE(seen.insert(id).second) << "run " << id << " twice";
  }
  // The gap-day export holds the run completed 5 min before it, not the one
  // 5 min after.
  EXPECT_EQ(records[1].run_ids.size(), 2u);
  EXPECT_EQ(records[2].run_ids.size(), 2u);
  // The run completed on the last day waits for the next slot.
  EXPECT_EQ(not_exported(), pending);
  EXPECT_EQ(pending.size(), 1u);
}

TEST_F(ExporterTest, FallBackExportsOnceAtTheEarlierInstant) {
  const config::TimeZone zone = berlin();
  const double start = utc(2026, 10, 24, 12);
  ManualWallClock clock(start);
  auto e = exporter(clock, options({2, 30}, zone));
  const auto made = walk(*e, clock, start, utc(2026, 10, 26, 12), 300, [&](double t) {
    if (std::fmod(t - start, 43200.0) == 0) complete_run();  // 12:00 and 00:00 UTC
  });
  // 2026-10-25: 02:30 CEST = 00:30 UTC, and again 02:30 CET = 01:30 UTC: once,
  // at 00:30 UTC. Monday 02:30 CET = 01:30 UTC.
  ASSERT_EQ(made.size(), 2u);
  EXPECT_EQ(made[0].at_unix_s, utc(2026, 10, 25, 0, 30));
  EXPECT_EQ(fs::path(made[0].outcome.directory).filename().string(), "2026-10-25");
  EXPECT_EQ(made[1].at_unix_s, utc(2026, 10, 26, 1, 30));
  EXPECT_EQ(fs::path(made[1].outcome.directory).filename().string(), "2026-10-26");
  const auto records = nightly_exports();
  ASSERT_EQ(records.size(), 2u);
  EXPECT_EQ(records[0].slot_local, "2026-10-25 02:30 UTC+02:00");
  // Completed at 10-24 12:00 and 10-25 00:00; then 10-25 12:00 and 10-26 00:00.
  EXPECT_EQ(records[0].run_ids.size(), 2u);
  EXPECT_EQ(records[1].run_ids.size(), 2u);
  EXPECT_TRUE(fs::is_directory(fs::path(root_) / "2026-10-25"));
  EXPECT_FALSE(fs::exists(fs::path(root_) / "2026-10-25-2"));
}

TEST_F(ExporterTest, DowntimeOverTheSlotGivesOneCatchUpExport) {
  const config::TimeZone zone = berlin();  // November: CET, UTC+1
  // Friday 2026-11-20 10:00 local; polled hourly until 23:00 local.
  ManualWallClock clock(utc(2026, 11, 20, 9));
  auto e = exporter(clock, options({2, 0}, zone));
  int64_t before = 0;
  const auto made =
      walk(*e, clock, utc(2026, 11, 20, 9), utc(2026, 11, 20, 22), 3600, [&](double t) {
        if (t == utc(2026, 11, 20, 14)) before = complete_run();
      });
  EXPECT_TRUE(made.empty());
  e.reset();  // daemon down over Saturday 02:00 local
  const int64_t during = complete_run();

  // Saturday 03:00 local: one export, for the 02:00 slot, with both runs.
  clock.set(utc(2026, 11, 21, 2));
  e = exporter(clock, options({2, 0}, zone));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  auto rec = record(out->export_id);
  EXPECT_EQ(rec.state, "done");
  EXPECT_EQ(*rec.slot_unix_s, utc(2026, 11, 21, 1));
  EXPECT_EQ(rec.run_ids, (std::vector<int64_t>{before, during}));
  EXPECT_EQ(fs::path(out->directory).filename().string(), "2026-11-21");
  EXPECT_FALSE(poll_ok(*e).has_value());
  EXPECT_EQ(nightly_exports().size(), 1u);

  // Down from Saturday 03:00 until Tuesday 05:00 local: three slots missed,
  // ONE export, for Tuesday's.
  e.reset();
  const int64_t sunday = complete_run();
  const int64_t monday = complete_run();
  clock.set(utc(2026, 11, 24, 4));
  e = exporter(clock, options({2, 0}, zone));
  out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  rec = record(out->export_id);
  EXPECT_EQ(*rec.slot_unix_s, utc(2026, 11, 24, 1));
  EXPECT_EQ(rec.slot_local, "2026-11-24 02:00 UTC+01:00");
  EXPECT_EQ(rec.run_ids, (std::vector<int64_t>{sunday, monday}));
  EXPECT_EQ(fs::path(out->directory).filename().string(), "2026-11-24");
  EXPECT_FALSE(poll_ok(*e).has_value());
  clock.advance(3600);
  EXPECT_FALSE(poll_ok(*e).has_value());
  EXPECT_EQ(nightly_exports().size(), 2u);
  EXPECT_TRUE(not_exported().empty());
}

TEST_F(ExporterTest, RestartAfterAnExportDoesNotExportAgain) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  ManualWallClock clock(utc(2026, 11, 20, 12));
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  const int64_t first = complete_run();
  clock.set(utc(2026, 11, 21, 2));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  EXPECT_EQ(record(out->export_id).run_ids, std::vector<int64_t>{first});

  // Restarted ten minutes after the slot: nothing to do, nothing twice.
  e.reset();
  clock.set(utc(2026, 11, 21, 2, 10));
  e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  EXPECT_EQ(e->next_slot_unix_s(), utc(2026, 11, 22, 2));
  const int64_t second = complete_run();
  const auto made =
      walk(*e, clock, utc(2026, 11, 21, 2, 10), utc(2026, 11, 22, 3), 300, [](double) {});
  ASSERT_EQ(made.size(), 1u);
  EXPECT_EQ(made[0].at_unix_s, utc(2026, 11, 22, 2));
  EXPECT_EQ(record(made[0].outcome.export_id).run_ids, std::vector<int64_t>{second});
  EXPECT_EQ(nightly_exports().size(), 2u);
}

TEST_F(ExporterTest, FirstStartExportsFromTheFirstSlotAfterIt) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  const int64_t old_run = complete_run();  // completed before the feature existed
  const double first_start = utc(2026, 11, 20, 12);
  ManualWallClock clock(first_start);
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  auto since = db().meta("nightly_export_since_unix_s");
  ASSERT_TRUE(since.ok() && since->has_value());
  EXPECT_DOUBLE_EQ(std::strtod((*since)->c_str(), nullptr), first_start);

  // A restart before the first slot keeps the first start.
  e.reset();
  clock.set(utc(2026, 11, 20, 18));
  e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  since = db().meta("nightly_export_since_unix_s");
  ASSERT_TRUE(since.ok() && since->has_value());
  EXPECT_DOUBLE_EQ(std::strtod((*since)->c_str(), nullptr), first_start);

  const auto made =
      walk(*e, clock, utc(2026, 11, 20, 18), utc(2026, 11, 21, 12), 300, [](double) {});
  ASSERT_EQ(made.size(), 1u);
  EXPECT_EQ(made[0].at_unix_s, utc(2026, 11, 21, 2));
  EXPECT_EQ(record(made[0].outcome.export_id).run_ids, std::vector<int64_t>{old_run});
}

TEST_F(ExporterTest, FirstStartDownOverTheFirstSlotCatchesUp) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  ManualWallClock clock(utc(2026, 11, 20, 12));
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  e.reset();
  const int64_t run = complete_run();
  clock.set(utc(2026, 11, 22, 9));
  e = exporter(clock, options({2, 0}, zone));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  const auto rec = record(out->export_id);
  EXPECT_EQ(*rec.slot_unix_s, utc(2026, 11, 22, 2));
  EXPECT_EQ(rec.run_ids, std::vector<int64_t>{run});
  EXPECT_FALSE(poll_ok(*e).has_value());
}

TEST_F(ExporterTest, SlotWithoutNewRunIsRecordedWithoutFiles) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  ManualWallClock clock(utc(2026, 11, 20, 12));
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  const int64_t first = complete_run();
  clock.set(utc(2026, 11, 21, 2));
  ASSERT_TRUE(poll_ok(*e).has_value());

  // Saturday night: nothing completed since.
  clock.set(utc(2026, 11, 22, 2));
  auto empty = poll_ok(*e);
  ASSERT_TRUE(empty.has_value());
  EXPECT_TRUE(empty->files.empty());
  const auto rec = record(empty->export_id);
  EXPECT_EQ(rec.state, "done");
  EXPECT_TRUE(rec.run_ids.empty());
  EXPECT_TRUE(rec.files.empty());
  EXPECT_EQ(rec.message, "no run completed since the last export");
  EXPECT_EQ(*rec.slot_unix_s, utc(2026, 11, 22, 2));
  EXPECT_FALSE(fs::exists(rec.directory)) << rec.directory;
  EXPECT_FALSE(fs::exists(fs::path(root_) / "2026-11-22"));
  EXPECT_FALSE(poll_ok(*e).has_value());

  const int64_t second = complete_run();
  clock.set(utc(2026, 11, 23, 2, 5));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  EXPECT_EQ(record(out->export_id).run_ids, std::vector<int64_t>{second});
  EXPECT_EQ(fs::path(out->directory).filename().string(), "2026-11-23");
  EXPECT_TRUE(fs::is_regular_file(fs::path(out->directory) / "index.html"));
  const auto records = nightly_exports();
  ASSERT_EQ(records.size(), 3u);
  EXPECT_EQ(records[0].run_ids, std::vector<int64_t>{first});
}

TEST_F(ExporterTest, InterruptedExportNotWrittenIsWrittenOnTheNextPoll) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  const int64_t a = complete_run();
  // The crash: recorded (state writing) for Saturday's slot, nothing on disk.
  const storage::ExportRecord crashed = crashed_export(a, zone);
  auto id = db().begin_export(crashed);
  ASSERT_TRUE(id.ok()) << id.error().message;
  const int64_t b = complete_run();

  // Back on Sunday at 03:00: Saturday's export is written, then Sunday's made.
  ManualWallClock clock(utc(2026, 11, 22, 3));
  std::vector<Result<ExportOutcome>> done;
  auto e = exporter(clock, options({2, 0}, zone),
                    [&](storage::Database&, const Result<ExportOutcome>& r) { done.push_back(r); });
  auto out = poll_ok(*e);
  const auto rec = record(*id);
  EXPECT_EQ(rec.state, "done") << rec.message;
  EXPECT_EQ(rec.run_ids, std::vector<int64_t>{a});
  EXPECT_EQ(rec.directory, crashed.directory);
  ASSERT_FALSE(rec.files.empty());
  EXPECT_EQ(files_on_disk(crashed.directory), rec.files);
  EXPECT_TRUE(fs::is_regular_file(fs::path(crashed.directory) / fmt::format("run-{:04}", a) /
                                  "report.html"));
  ASSERT_EQ(done.size(), 2u);
  ASSERT_TRUE(done[0].ok()) << done[0].error().message;
  EXPECT_EQ(done[0]->export_id, *id);

  ASSERT_TRUE(out.has_value());
  EXPECT_NE(out->export_id, *id);
  EXPECT_EQ(record(out->export_id).run_ids, std::vector<int64_t>{b});
  EXPECT_EQ(nightly_exports().size(), 2u);
  EXPECT_FALSE(poll_ok(*e).has_value());
  EXPECT_EQ(record(*id).files, rec.files);  // not written twice
  EXPECT_TRUE(partial_dirs(dir_).empty());
}

TEST_F(ExporterTest, InterruptedExportAlreadyRenamedIsMarkedDone) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  const int64_t a = complete_run();
  const storage::ExportRecord crashed = crashed_export(a, zone);
  auto id = db().begin_export(crashed);
  ASSERT_TRUE(id.ok()) << id.error().message;
  // The crash came after the rename, before the record: the files are there.
  const fs::path run_dir = fs::path(crashed.directory) / fmt::format("run-{:04}", a);
  fs::create_directories(run_dir);
  std::ofstream(fs::path(crashed.directory) / "index.html") << "index written before the crash";
  std::ofstream(run_dir / "report.html") << "report written before the crash";

  ManualWallClock clock(utc(2026, 11, 21, 3));
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());  // nothing else is due
  const auto rec = record(*id);
  EXPECT_EQ(rec.state, "done");
  EXPECT_EQ(rec.files,
            (std::vector<std::string>{"index.html", fmt::format("run-{:04}/report.html", a)}));
  // Left as it was: not written again.
  EXPECT_EQ(testing::read_text(fs::path(crashed.directory) / "index.html"),
            "index written before the crash");
  EXPECT_EQ(files_on_disk(crashed.directory), rec.files);
  EXPECT_TRUE(not_exported().empty());
  EXPECT_EQ(nightly_exports().size(), 1u);
}

TEST_F(ExporterTest, WriteFailureMarksTheExportFailedAndFreesItsRuns) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  // The export root is under a regular file: it cannot be created.
  const fs::path blocker = dir_ / "blocker";
  std::ofstream(blocker) << "not a directory";
  NightlyOptions o = options({2, 0}, zone);
  o.directory = (blocker / "reports").string();
  ManualWallClock clock(utc(2026, 11, 20, 12));
  std::vector<Result<ExportOutcome>> done;
  auto e = exporter(clock, o,
                    [&](storage::Database&, const Result<ExportOutcome>& r) { done.push_back(r); });
  EXPECT_FALSE(poll_ok(*e).has_value());
  const int64_t run = complete_run();

  clock.set(utc(2026, 11, 21, 2));
  auto r = e->poll();
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find(o.directory), std::string::npos) << r.error().message;
  ASSERT_EQ(done.size(), 1u);
  EXPECT_FALSE(done[0].ok());
  auto records = nightly_exports();
  ASSERT_EQ(records.size(), 1u);
  EXPECT_EQ(records[0].state, "failed");
  EXPECT_NE(records[0].message.find(o.directory), std::string::npos) << records[0].message;
  EXPECT_TRUE(records[0].files.empty());
  EXPECT_TRUE(partial_dirs(dir_).empty());
  EXPECT_EQ(not_exported(), std::vector<int64_t>{run});
  // The failed slot is not retried at once.
  EXPECT_FALSE(poll_ok(*e).has_value());

  // Fixed by the next night: its export takes the run.
  fs::remove(blocker);
  clock.set(utc(2026, 11, 22, 2));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  EXPECT_EQ(record(out->export_id).run_ids, std::vector<int64_t>{run});
  EXPECT_EQ(record(out->export_id).state, "done");
  EXPECT_TRUE(not_exported().empty());
}

// A failure while the files are written removes the temporary directory
// with what it holds. Here the file size limit (RLIMIT_FSIZE, SIGXFSZ
// ignored) lets the small CSV files through and stops each report page
// (> 80 kB: it inlines uPlot) with EFBIG. The limit is set once the export is
// about to be collected and lifted in `done`; the database's WAL, truncated
// first, stays below it.
TEST_F(ExporterTest, WriteFailureInsideTheTemporaryDirectoryLeavesNothing) {
  constexpr rlim_t kLimitBytes = 60'000;
  const config::TimeZone zone = config::TimeZone::fixed(0);
  ManualWallClock clock(utc(2026, 11, 20, 12));
  rlimit saved{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &saved), 0);
  const auto old_handler = std::signal(SIGXFSZ, SIG_IGN);
  bool arm = false, limited = false;
  const auto restore = [&] {
    if (limited) ::setrlimit(RLIMIT_FSIZE, &saved);
    limited = false;
  };
  std::vector<Result<ExportOutcome>> done;
  auto made = NightlyExporter::create(
      db_path_, clock, options({2, 0}, zone),
      [&] {
        if (!arm) return;
        EXPECT_TRUE(db().exec("PRAGMA wal_checkpoint(TRUNCATE)").ok());
        rlimit tight = saved;
        tight.rlim_cur = kLimitBytes;
        limited = ::setrlimit(RLIMIT_FSIZE, &tight) == 0;
      },
      [&](storage::Database&, const Result<ExportOutcome>& r) {
        restore();
        done.push_back(r);
      });
  ASSERT_TRUE(made.ok()) << made.error().message;
  NightlyExporter& e = **made;
  EXPECT_FALSE(poll_ok(e).has_value());
  const int64_t run = complete_run();
  clock.set(utc(2026, 11, 21, 2));
  arm = true;
  auto r = e.poll();
  restore();
  std::signal(SIGXFSZ, old_handler);
  ASSERT_EQ(done.size(), 1u);
  ASSERT_FALSE(r.ok()) << "the limit did not stop the export";
  const std::string target = (fs::path(root_) / "2026-11-21").string();
  EXPECT_NE(r.error().message.find(target), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("report.html"), std::string::npos) << r.error().message;
  EXPECT_TRUE(partial_dirs(dir_).empty());
  EXPECT_FALSE(fs::exists(target));
  EXPECT_TRUE(fs::is_empty(root_));
  auto records = nightly_exports();
  ASSERT_EQ(records.size(), 1u);
  EXPECT_EQ(records[0].state, "failed");
  EXPECT_EQ(records[0].message, r.error().message);
  EXPECT_EQ(not_exported(), std::vector<int64_t>{run});
}

TEST_F(ExporterTest, DirectoryIsNamedByTheLocalDateAndNeverReused) {
  // UTC+05:30: 2026-11-21 02:00 local is 2026-11-20 20:30 UTC.
  const config::TimeZone zone = config::TimeZone::fixed(19800);
  // Someone's files already where the export would go.
  fs::create_directories(fs::path(root_) / "2026-11-21");
  std::ofstream(fs::path(root_) / "2026-11-21" / "notes.txt") << "someone's notes";
  ManualWallClock clock(utc(2026, 11, 20, 12));
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  complete_run();
  clock.set(utc(2026, 11, 20, 20, 30));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  EXPECT_EQ(out->directory, (fs::path(root_) / "2026-11-21-2").string());
  EXPECT_EQ(record(out->export_id).slot_local, "2026-11-21 02:00 UTC+05:30");
  EXPECT_TRUE(fs::is_regular_file(fs::path(out->directory) / "index.html"));
  EXPECT_EQ(files_on_disk(fs::path(root_) / "2026-11-21"), std::vector<std::string>{"notes.txt"});
}

TEST_F(ExporterTest, ManualExportsLeaveTheNightlySelectionAlone) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  const int64_t a = complete_run(), b = complete_run();
  ExportRequest manual;
  manual.kind = "manual";
  manual.run_ids = {a, b};
  manual.directory = (dir_ / "manual").string();
  auto m = write_export(db(), manual);
  ASSERT_TRUE(m.ok()) << m.error().message;
  EXPECT_EQ(record(m->export_id).kind, "manual");
  EXPECT_EQ(record(m->export_id).state, "done");
  EXPECT_EQ(files_on_disk(manual.directory), m->files);
  EXPECT_EQ(not_exported(), (std::vector<int64_t>{a, b}));

  // An existing empty directory is fine.
  const fs::path empty_dir = dir_ / "empty";
  fs::create_directories(empty_dir);
  manual.directory = empty_dir.string();
  manual.run_ids = {a};
  auto into_empty = write_export(db(), manual);
  ASSERT_TRUE(into_empty.ok()) << into_empty.error().message;
  EXPECT_EQ(files_on_disk(empty_dir), into_empty->files);

  // A non-empty one is refused and left untouched.
  const fs::path busy = dir_ / "busy";
  fs::create_directories(busy);
  std::ofstream(busy / "notes.txt") << "someone's notes";
  manual.directory = busy.string();
  auto refused = write_export(db(), manual);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find(busy.string()), std::string::npos)
      << refused.error().message;
  EXPECT_NE(refused.error().message.find("not an empty directory"), std::string::npos)
      << refused.error().message;
  EXPECT_EQ(files_on_disk(busy), std::vector<std::string>{"notes.txt"});
  EXPECT_EQ(testing::read_text(busy / "notes.txt"), "someone's notes");
  EXPECT_TRUE(partial_dirs(dir_).empty());

  // The nightly export still takes both runs.
  ManualWallClock clock(utc(2026, 11, 20, 12));
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  clock.set(utc(2026, 11, 21, 2));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  EXPECT_EQ(record(out->export_id).run_ids, (std::vector<int64_t>{a, b}));
  EXPECT_TRUE(not_exported().empty());
}

// A run with samples: one 20 °C soak, 300 s of gyro at 10 Hz and
// temperatures at 1 Hz, so its report has a Table I row and plots.
int64_t run_with_samples(storage::Database& db, const std::string& db_path) {
  storage::RunRecord r;
  r.schedule_name = "short soak";
  r.state = "acquiring";
  r.orientation = "up";
  r.latitude_deg = 48.1;
  auto id = db.create_run(r);
  EXPECT_TRUE(id.ok()) << id.error().message;
  storage::SegmentRecord s;
  s.run_id = *id;
  s.kind = "soak";
  s.label = "soak 20 °C (step 1)";
  s.setpoint_c = 20;
  s.t_acquire_start_s = 0;
  s.t_acquire_end_s = 300;
  s.t_end_s = 300;
  s.state = "completed";
  s.windows = {{0, 300}};
  auto sid = db.create_segment(s);
  EXPECT_TRUE(sid.ok()) << sid.error().message;
  s.id = *sid;
  EXPECT_TRUE(db.update_segment(s).ok());
  auto writer = storage::SampleWriter::start(db_path);
  EXPECT_TRUE(writer.ok()) << writer.error().message;
  std::vector<GyroSample> gyro;
  for (int i = 0; i < 3000; ++i) {
    const double t = i / 10.0;
    gyro.push_back({t, 8.0 + 0.3 * std::sin(t / 7.0) + 0.1 * ((i * 7919) % 13 - 6) / 6.0,
                    static_cast<uint8_t>(i % 128), 0x77, 20});
  }
  (*writer)->push_gyro(*id, gyro);
  for (int i = 0; i < 300; ++i) {
    const double T = 20.0 + 0.01 * std::sin(i / 30.0);
    (*writer)->push_temperature(*id, {static_cast<double>(i), 20.0, T, T + 0.1, T - 0.1});
  }
  EXPECT_TRUE((*writer)->flush().ok());
  (*writer)->stop();
  EXPECT_TRUE(db.set_run_state(*id, "completed", true).ok());
  return *id;
}

TEST_F(ExporterTest, ExportDirectoryLayoutMatchesTheRecord) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  const int64_t with_samples = run_with_samples(db(), db_path_);
  const int64_t without = complete_run();
  ManualWallClock clock(utc(2026, 11, 20, 12));
  auto e = exporter(clock, options({2, 0}, zone));
  EXPECT_FALSE(poll_ok(*e).has_value());
  clock.set(utc(2026, 11, 21, 2));
  auto out = poll_ok(*e);
  ASSERT_TRUE(out.has_value());
  const fs::path dir = out->directory;
  EXPECT_EQ(dir, fs::path(root_) / "2026-11-21");

  // Only the export directory in the root: no hidden temporary left.
  std::vector<std::string> in_root;
  for (const auto& entry : fs::directory_iterator(root_)) {
    in_root.push_back(entry.path().filename().string());
  }
  EXPECT_EQ(in_root, std::vector<std::string>{"2026-11-21"});
  EXPECT_TRUE(partial_dirs(dir_).empty());

  const auto on_disk = files_on_disk(dir);
  EXPECT_EQ(out->files, on_disk);
  const auto rec = record(out->export_id);
  EXPECT_EQ(rec.files, on_disk);
  EXPECT_EQ(rec.directory, dir.string());
  EXPECT_EQ(rec.run_ids, (std::vector<int64_t>{with_samples, without}));
  const std::set<std::string> files(on_disk.begin(), on_disk.end());
  for (const char* top : {"index.html", "table1.csv"}) {
    EXPECT_TRUE(files.count(top)) << top;
  }
  for (int64_t id : {with_samples, without}) {
    for (const char* name : {"report.html", "table1.csv", "allan.csv", "allan-curves.csv"}) {
      const std::string path = fmt::format("run-{:04}/{}", id, name);
      EXPECT_TRUE(files.count(path)) << path;
    }
  }
  for (const auto& f : on_disk) {
    EXPECT_NE(fs::path(f).filename().string().front(), '.') << f;  // no temporary file
    EXPECT_GT(fs::file_size(dir / f), 0u) << f;
  }

  // The run with samples has its Table I row; the other is listed as a problem.
  const std::string table1 =
      testing::read_text(dir / fmt::format("run-{:04}", with_samples) / "table1.csv");
  EXPECT_EQ(std::count(table1.begin(), table1.end(), '\n'), 2) << table1;
  const std::string index = testing::read_text(dir / "index.html");
  EXPECT_NE(index.find(fmt::format("run-{:04}/report.html", with_samples)), std::string::npos);
  EXPECT_NE(index.find(fmt::format("run-{:04}/report.html", without)), std::string::npos);
  bool problem_named = false;
  for (const auto& p : out->problems) {
    if (p.find(fmt::format("run {}", without)) != std::string::npos) problem_named = true;
  }
  EXPECT_TRUE(problem_named) << "no problem names run " << without;
  const std::string report =
      testing::read_text(dir / fmt::format("run-{:04}", with_samples) / "report.html");
  EXPECT_NE(report.find("chart-"), std::string::npos);
}

// A run with scale-factor rows gets its scale-factor files, on disk and in
// the record; a run without gets none, and the summary's CSV has the rows.
TEST_F(ExporterTest, ScaleFactorFilesOnlyForARunWithScaleFactorRows) {
  const int64_t with = complete_run("scale factor");
  const int64_t without = complete_run();
  const gyrotherm::test::StoredScaleFactor stored =
      gyrotherm::test::store_scale_factor_rows(db(), with);
  ASSERT_EQ(stored.fits.size(), 3u);
  ExportRequest manual;
  manual.run_ids = {with, without};
  manual.directory = (dir_ / "manual").string();
  auto out = write_export(db(), manual);
  ASSERT_TRUE(out.ok()) << out.error().message;
  const auto on_disk = files_on_disk(manual.directory);
  EXPECT_EQ(record(out->export_id).files, on_disk);
  std::set<std::string> scale_factor_files;
  for (const auto& f : on_disk) {
    if (f.find("scale-factor") != std::string::npos) scale_factor_files.insert(f);
  }
  const std::string run_dir = fmt::format("run-{:04}/", with);
  EXPECT_EQ(scale_factor_files,
            (std::set<std::string>{"scale-factor.csv", run_dir + "scale-factor-points.csv",
                                   run_dir + "scale-factor.csv", run_dir + "scale-factor.h",
                                   run_dir + "scale-factor.json"}));
  const fs::path dir = manual.directory;
  // The summary's CSV: one line per sequence, K to the last bit.
  const std::string csv = testing::read_text(dir / "scale-factor.csv");
  std::istringstream lines(csv);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line.rfind("run_id,sf_sequence,temperature_c,k,", 0), 0u) << line;
  for (const auto& f : stored.fits) {
    ASSERT_TRUE(std::getline(lines, line)) << csv;
    std::vector<std::string> fields;
    std::stringstream ls(line);
    for (std::string x; std::getline(ls, x, ',');) fields.push_back(x);
    ASSERT_GE(fields.size(), 4u) << line;
    EXPECT_EQ(std::stoll(fields[0]), with);
    EXPECT_EQ(std::stoi(fields[1]), f.sf_sequence);
    EXPECT_EQ(std::stod(fields[3]), f.k);
  }
  EXPECT_FALSE(std::getline(lines, line)) << csv;
  EXPECT_NE(testing::read_text(dir / run_dir / "report.html").find("id=\"scale-factor\""),
            std::string::npos);
  EXPECT_EQ(testing::read_text(dir / fmt::format("run-{:04}", without) / "report.html")
                .find("scale-factor"),
            std::string::npos);
}

TEST_F(ExporterTest, ThreadExportsWhenTheClockReachesTheSlot) {
  const config::TimeZone zone = config::TimeZone::fixed(0);
  ManualWallClock clock(utc(2026, 11, 20, 12));
  NightlyOptions o = options({2, 0}, zone);
  o.poll_wall_s = 0.005;
  std::mutex mu;
  std::condition_variable cv;
  std::vector<Result<ExportOutcome>> done;
  auto e = exporter(clock, o, [&](storage::Database&, const Result<ExportOutcome>& r) {
    std::lock_guard lock(mu);
    done.push_back(r);
    cv.notify_all();
  });
  const int64_t run = complete_run();
  e->start();
  // The thread's first poll records the first start.
  const auto deadline = std::chrono::steady_clock::now() + testing::scaled(std::chrono::seconds(5));
  bool started = false;
  while (!started && std::chrono::steady_clock::now() < deadline) {
    auto since = db().meta("nightly_export_since_unix_s");
    started = since.ok() && since->has_value();
    if (!started) std::this_thread::yield();
  }
  ASSERT_TRUE(started) << "the thread never polled";
  clock.set(utc(2026, 11, 21, 2, 1));
  {
    std::unique_lock lock(mu);
    ASSERT_TRUE(cv.wait_until(lock, deadline, [&] { return !done.empty(); }))
        << "no export within 5 s";
  }
  e->stop();
  std::lock_guard lock(mu);
  ASSERT_EQ(done.size(), 1u);
  ASSERT_TRUE(done[0].ok()) << done[0].error().message;
  EXPECT_EQ(record(done[0]->export_id).run_ids, std::vector<int64_t>{run});
  EXPECT_EQ(nightly_exports().size(), 1u);
}

TEST(NightlyOptions, Validity) {
  std::string why;
  EXPECT_TRUE(NightlyOptions{}.is_valid(&why)) << why;
  NightlyOptions o;
  o.at = {24, 0};
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_NE(why.find("at = 24:00 is not a time of day"), std::string::npos) << why;
  o = {};
  o.at = {2, 60};
  EXPECT_FALSE(o.is_valid(nullptr));
  o = {};
  o.directory.clear();
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_NE(why.find("directory"), std::string::npos) << why;
  o = {};
  o.poll_wall_s = 0;
  EXPECT_FALSE(o.is_valid(&why));
  EXPECT_NE(why.find("poll_wall_s = 0 must be"), std::string::npos) << why;
  // create() refuses them with the message.
  ManualWallClock clock(0);
  auto e = NightlyExporter::create("unused.db", clock, o, nullptr, nullptr);
  ASSERT_FALSE(e.ok());
  EXPECT_NE(e.error().message.find("invalid nightly export options: poll_wall_s"),
            std::string::npos)
      << e.error().message;
}

}  // namespace
}  // namespace gyrotherm::calibration

// Calibration exports (docs/reports.md): the reports of some runs written into
// one directory, atomically, and recorded in the database; and the nightly
// job that makes one every day at [export] local_time (nightly.h) for the
// runs completed since the last one.
//
// An export is recorded (state "writing", with its runs) before anything is
// written, so a crash leaves a record the next start finishes; its files go
// into a hidden temporary directory next to the target, which is renamed
// into place once complete (a reader sees the whole export or nothing), and
// the record then becomes "done" with the list of files. A nightly slot and
// a run can each be in only one nightly export (storage enforces it), so
// nothing is exported twice.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/calibration/report.h"
#include "gyrotherm/config/nightly.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::calibration {

struct ExportRequest {
  std::string kind = "manual";  // nightly, manual
  std::optional<double> slot_unix_s;
  std::string slot_local;
  std::vector<int64_t> run_ids;  // ascending; may be empty (a nightly slot with no new run)
  std::string directory;         // the export's directory: must not exist, or be empty
  ReportOptions report;
};

struct ExportOutcome {
  int64_t export_id = 0;
  std::string directory;
  std::vector<std::string> files;  // relative to directory
  std::vector<std::string> problems;
};

// Records, collects, renders, writes, renames into place, records done.
// With no runs, only the record is written (no directory). A failure after
// the record exists marks it "failed" with the reason (its runs are then
// free for the next export). Errors name the directory or the run.
Result<ExportOutcome> write_export(storage::Database& db, const ExportRequest& request);

// The export's directory for a nightly slot: <root>/<local date of the
// slot>, with "-2", "-3"... when that exists already.
std::string nightly_directory(const std::string& root, double slot_unix_s,
                              const config::TimeZone& zone);
// "2026-03-29 03:00 UTC+02:00": a slot as people read it.
std::string local_time_label(double unix_s, const config::TimeZone& zone);

struct NightlyOptions {
  config::LocalTimeOfDay at;
  config::TimeZone zone = config::TimeZone::system_local();
  std::string directory = "reports";  // [export] directory
  ReportOptions report;
  double poll_wall_s = 1.0;  // how often the thread looks at the wall clock

  // False with a message naming the field when `at` is no time of day
  // (00:00 … 23:59), directory is empty or poll_wall_s is not positive and
  // finite.
  bool is_valid(std::string* why) const;
};

class NightlyExporter {
 public:
  // Called after each export with the exporter's own connection (to record
  // an event) and the outcome.
  using Done = std::function<void(storage::Database&, const Result<ExportOutcome>&)>;
  // `before_export` runs before each export (the daemon drains its analysis
  // queue, so a run completed just before the slot has its results stored);
  // `done` after each (events, SSE). Both may be empty. Error (permanent)
  // when the options are not valid (is_valid).
  static Result<std::unique_ptr<NightlyExporter>> create(std::string db_path,
                                                         const WallClock& clock,
                                                         NightlyOptions options,
                                                         std::function<void()> before_export,
                                                         Done done);
  ~NightlyExporter();  // stops the thread

  // One step, on the caller's thread: finishes nightly exports a crash left
  // "writing" (on the first poll), then makes the export due now, if any (one catch-up export
  // when slots were missed). Returns the outcome of the export made now, or
  // nullopt when none was due. Not concurrent with the thread.
  Result<std::optional<ExportOutcome>> poll();
  // The next slot after the clock's now.
  double next_slot_unix_s() const;

  void start();  // a thread that polls every poll_wall_s (a minute after a failure)
  void stop();

 private:
  NightlyExporter(std::string db_path, const WallClock& clock, NightlyOptions options,
                  std::function<void()> before_export, Done done);
  Result<storage::Database*> database();
  Status finish_interrupted(storage::Database& db);

  std::string db_path_;
  const WallClock& clock_;
  NightlyOptions options_;
  std::function<void()> before_export_;
  Done done_;
  std::optional<storage::Database> db_;
  bool recovered_ = false;  // interrupted exports finished (first poll)
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace gyrotherm::calibration

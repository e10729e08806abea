// Post-step and post-run analysis off the control thread.
//
// When a soak's acquisition window closes the daemon submits a Table I job;
// when a run completes, a run job (Allan deviation per soak, drift-model fits
// of the run; run_analysis.h). The worker waits until the samples are
// committed (SampleWriter::flush on its own thread), reads them through its
// own connection, computes and stores. Acquisition never waits for it: jobs
// queue, one runs at a time.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <variant>
#include <vector>

#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm::calibration {

struct Table1Job {
  int64_t run_id = 0;
  int64_t segment_id = 0;
  int segment_index = 0;
  double setpoint_c = 0;
  double t_from_s = 0;  // acquisition span, station s since run start
  double t_to_s = 0;
  // The acquisition windows inside the span (pauses and suspensions cut
  // out); empty = the whole span. Each window is binned on its own and the
  // series are joined.
  std::vector<std::pair<double, double>> windows;
};

// Everything analyse_run() computes for a completed run.
struct RunJob {
  int64_t run_id = 0;
};

// Reads the window from `db`, computes the Table I row of every DUT axis of
// the run (analysed_axes), stores them and returns the first (the first
// DUT's primary axis), each with its quality under `rules`. Errors name
// the run and segment (and the DUT).
Result<storage::SegmentStatsRecord> compute_table1(storage::Database& db, const Table1Job& job,
                                                   const analysis::Table1Options& options,
                                                   const analysis::QualityRules& rules = {});

class AnalysisWorker {
 public:
  struct Callbacks {
    std::function<void(const Table1Job&, const Result<storage::SegmentStatsRecord>&)> table1_done;
    // Called on the worker thread with the worker's own connection (to record
    // an event about the run).
    std::function<void(storage::Database&, const RunJob&, const Result<RunAnalysisSummary>&)>
        run_done;
    // Called on the worker thread before a Table I row is computed: returns
    // once the gyro stream has handed over the run's samples up to `until_s`
    // (run seconds), or after a bounded wait. A soak ends on the station
    // clock, while its last samples may still be on the line (a reader behind
    // on a loaded machine). Unset: no wait.
    std::function<void(int64_t run_id, double until_s)> await_gyro;
  };

  // `wall` stamps the rows it stores (not owned; outlives the worker).
  AnalysisWorker(std::string db_path, storage::SampleSink& writer, AnalysisSettings settings,
                 Callbacks callbacks, const WallClock& wall = system_wall_clock());
  ~AnalysisWorker();  // finishes queued jobs, then stops

  void submit(Table1Job job);
  void submit(RunJob job);
  // Blocks until every job submitted so far is done.
  void drain();
  void stop();

 private:
  using Job = std::variant<Table1Job, RunJob>;
  void push(Job job);
  void run();

  std::string db_path_;
  storage::SampleSink& writer_;
  const WallClock& wall_;
  AnalysisSettings settings_;
  Callbacks callbacks_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Job> jobs_;
  int busy_ = 0;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace gyrotherm::calibration

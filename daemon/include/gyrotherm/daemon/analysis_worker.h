// Post-step analysis off the control thread.
//
// When a soak's acquisition window closes the daemon submits a job; the
// worker waits until the window's samples are committed (SampleWriter::flush
// on its own thread), reads them through its own connection, computes the
// Table I row and stores it. Acquisition never waits for it.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm::daemon {

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

// Reads the window from `db`, computes the Table I row, stores it and
// returns it. Errors name the run and segment.
Result<storage::SegmentStatsRecord> compute_table1(storage::Database& db, const Table1Job& job,
                                                   const analysis::Table1Options& options);

class AnalysisWorker {
 public:
  using Done = std::function<void(const Table1Job&, const Result<storage::SegmentStatsRecord>&)>;

  AnalysisWorker(std::string db_path, storage::SampleWriter& writer,
                 analysis::Table1Options options, Done on_done);
  ~AnalysisWorker();  // finishes queued jobs, then stops

  void submit(Table1Job job);
  // Blocks until every job submitted so far is done.
  void drain();
  void stop();

 private:
  void run();

  std::string db_path_;
  storage::SampleWriter& writer_;
  analysis::Table1Options options_;
  Done on_done_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Table1Job> jobs_;
  int busy_ = 0;
  bool stop_ = false;
  std::thread thread_;
};

}  // namespace gyrotherm::daemon

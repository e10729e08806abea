// SampleWriter: batched, asynchronous insertion of gyro, temperature and
// rate-table samples.
//
// Acquisition threads push samples into an in-memory batch (a mutex and a
// vector append; never a disk wait); a writer thread with its own connection
// commits the batch in one transaction at least every commit_interval (wall
// time), so a crash loses at most the last uncommitted interval. If the disk
// stalls, the batch grows up to max_pending samples, after which the oldest
// pending samples are dropped and counted (acquisition is never blocked);
// gyro samples go first, then table samples, temperatures (one a second)
// only when nothing else is left to drop. The batch being committed counts as pending.
// A failing commit is retried on the next interval; the error is kept for
// the health report. A writer thread that stops on an exception counts as
// failing for good (stats().thread_failed).
//
// The writer keeps per-run state (each DUT's open chunks, a few hundred KB
// per run) until the run is closed (close_run) and its samples are
// committed.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::storage {

struct SampleWriterOptions {
  std::chrono::milliseconds commit_interval{500};  // wall time between commits
  std::size_t max_pending = 4'000'000;             // samples held before dropping

  // False with a message naming the field when commit_interval is not
  // positive or max_pending is 0.
  bool is_valid(std::string* why) const;
};

struct SampleWriterStats {
  uint64_t gyro_rows = 0;         // committed frames (every DUT; push_gyro and push_frames)
  uint64_t channel_samples = 0;   // committed channel values (frames x channels)
  uint64_t chunks = 0;            // sample_chunks rows written or extended
  uint64_t temperature_rows = 0;  // committed
  uint64_t table_rows = 0;        // committed (rate table)
  uint64_t commits = 0;
  uint64_t commit_failures = 0;
  uint64_t consecutive_failures = 0;  // failed commits since the last successful one
  uint64_t dropped = 0;               // samples dropped because the queue was full
                                      // (or still uncommitted when stop() failed)
  uint64_t rejected = 0;              // refused at push: t_s not finite, or pushed after stop()
  uint64_t duplicates = 0;            // ignored at commit: (run_id, t_s) already stored
  std::size_t pending = 0;            // samples waiting for the next commit
  double last_commit_ms = 0;          // duration of the last commit, wall ms
  double max_commit_ms = 0;
  std::string last_error;  // of the most recent failed commit; kept after recovery
  // The writer thread stopped on an exception: nothing is committed any
  // more (last_error says why; consecutive_failures stays above 0).
  bool thread_failed = false;
  std::size_t runs_held = 0;  // runs the writer keeps state for (not yet closed and committed)
};

// Where the station's samples go: the SampleWriter below, or, in the
// station's unit tests, a double that makes commits fail as on a full disk.
class SampleSink {
 public:
  virtual ~SampleSink() = default;
  // Thread-safe; t_s must already be relative to the run's start.
  virtual void push_gyro(int64_t run_id, std::span<const GyroSample> samples) = 0;
  virtual void push_temperature(int64_t run_id, const TemperatureSample& sample) = 0;
  virtual void push_table(int64_t run_id, const TableSample& sample) = 0;
  // One DUT's frames (t_s relative to the run's start) into its channels'
  // chunks; `dut` is what Database::add_run_dut returned for the run.
  virtual void push_frames(const RunDutRecord& dut, std::span<const DutFrame> frames) = 0;
  // Blocks until everything pushed before the call is committed (or the
  // commit failed): the commit's status.
  virtual Status flush() = 0;
  // Nothing more will be pushed for the run: its state is released once its
  // pending samples are committed (or dropped). Does not wait.
  virtual void close_run(int64_t run_id) = 0;
  virtual void stop() = 0;  // commits what is pending; idempotent
  virtual SampleWriterStats stats() const = 0;
};

class SampleWriter final : public SampleSink {
 public:
  // Opens its own connection to `db_path` (created/migrated as by
  // Database::open) and starts the writer thread.
  // `on_commit`, if set, is called on the writer thread after each
  // successful commit of rows with its wall duration (a latency histogram).
  static Result<std::unique_ptr<SampleWriter>> start(
      const std::string& db_path, SampleWriterOptions options = {},
      std::function<void(double seconds)> on_commit = {});
  ~SampleWriter() override;  // stop()

  // Thread-safe; t_s must already be relative to the run's start. A sample
  // with a non-finite t_s is refused (stats().rejected); one whose
  // (run_id, t_s) is already stored is ignored at commit (stats().duplicates).
  void push_gyro(int64_t run_id, std::span<const GyroSample> samples) override;
  void push_temperature(int64_t run_id, const TemperatureSample& sample) override;
  void push_table(int64_t run_id, const TableSample& sample) override;
  // push_gyro stores into the run's first DUT (created as serial "" with
  // channels rate/status/temp_c when the run has none) so older callers and
  // tests keep working.
  void push_frames(const RunDutRecord& dut, std::span<const DutFrame> frames) override;

  // Blocks until everything pushed before the call is committed (or the
  // commit failed). Returns the commit's status; on failure the rows stay
  // pending for the next attempt. After stop(): Ok if nothing is pending.
  // After the writer thread failed: its error, always.
  Status flush() override;
  // Released by the writer thread at its next round (stats().runs_held).
  // Samples of the run pushed later are stored as before, in new chunks.
  void close_run(int64_t run_id) override;
  // Commits what is pending and stops the thread. Idempotent.
  void stop() override;

  SampleWriterStats stats() const override;

 private:
  SampleWriter() = default;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace gyrotherm::storage

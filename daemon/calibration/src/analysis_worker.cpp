#include "gyrotherm/calibration/analysis_worker.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <optional>

#include "gyrotherm/core/clock.h"

namespace gyrotherm::calibration {

Result<storage::SegmentStatsRecord> compute_table1(storage::Database& db, const Table1Job& job,
                                                   const analysis::Table1Options& options,
                                                   const analysis::QualityRules& rules) {
  SoakWindow soak;
  soak.run_id = job.run_id;
  soak.segment_id = job.segment_id;
  soak.segment_index = job.segment_index;
  soak.setpoint_c = job.setpoint_c;
  soak.t_from_s = job.t_from_s;
  soak.t_to_s = job.t_to_s;
  soak.windows = job.windows;
  if (soak.windows.empty()) soak.windows.emplace_back(job.t_from_s, job.t_to_s);
  auto axes = analysed_axes(db, job.run_id);
  if (!axes) return axes.error();
  // Every DUT axis of the run; the first's row (the first DUT's primary
  // axis) is returned. Another axis that cannot be computed is logged; the
  // run's analysis at its end lists it among its problems.
  std::optional<Result<storage::SegmentStatsRecord>> first;
  for (const AnalysedAxis& axis : *axes) {
    auto rec = soak_table1(db, soak, options, axis, rules);
    if (rec) {
      if (auto st = db.put_segment_stats(*rec); !st) {
        return Error::Transient(fmt::format("run {} segment {}: {}", job.run_id,
                                            job.segment_index + 1, st.error().message));
      }
    } else if (first) {
      spdlog::warn("Table I: {}", rec.error().message);
    }
    if (!first) first = std::move(rec);
  }
  return std::move(*first);
}

AnalysisWorker::AnalysisWorker(std::string db_path, storage::SampleSink& writer,
                               AnalysisSettings settings, Callbacks callbacks,
                               const WallClock& wall)
    : db_path_(std::move(db_path)),
      writer_(writer),
      wall_(wall),
      settings_(std::move(settings)),
      callbacks_(std::move(callbacks)),
      thread_([this] { run(); }) {}

AnalysisWorker::~AnalysisWorker() { stop(); }

void AnalysisWorker::submit(Table1Job job) { push(std::move(job)); }
void AnalysisWorker::submit(RunJob job) { push(job); }

void AnalysisWorker::push(Job job) {
  {
    std::lock_guard lock(mu_);
    jobs_.push_back(std::move(job));
  }
  cv_.notify_all();
}

void AnalysisWorker::drain() {
  std::unique_lock lock(mu_);
  cv_.wait(lock, [this] { return jobs_.empty() && busy_ == 0; });
}

void AnalysisWorker::stop() {
  {
    std::lock_guard lock(mu_);
    if (stop_) return;
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void AnalysisWorker::run() {
  std::optional<storage::Database> db;
  for (;;) {
    Job job;
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
      if (jobs_.empty()) return;  // stopping, nothing left
      job = std::move(jobs_.front());
      jobs_.pop_front();
      ++busy_;
    }
    Status opened = Status::Ok();
    if (auto* t1 = std::get_if<Table1Job>(&job); t1 && callbacks_.await_gyro) {
      callbacks_.await_gyro(t1->run_id, t1->t_to_s);
    }
    (void)writer_.flush();  // the job's samples must be committed first
    if (!db) {
      auto d = storage::Database::open(db_path_, wall_);
      if (d) {
        db.emplace(std::move(*d));
      } else {
        opened = d.error();
      }
    }
    if (auto* t1 = std::get_if<Table1Job>(&job)) {
      Result<storage::SegmentStatsRecord> result =
          opened.ok() ? Error::Transient("not computed")
                      : Result<storage::SegmentStatsRecord>(opened.error());
      try {
        if (db) result = compute_table1(*db, *t1, settings_.table1, settings_.quality);
      } catch (const std::exception& e) {
        result = Error::Permanent(fmt::format("run {} segment {}: analysis failed: {}", t1->run_id,
                                              t1->segment_index + 1, e.what()));
      }
      if (callbacks_.table1_done) callbacks_.table1_done(*t1, result);
    } else if (auto* rj = std::get_if<RunJob>(&job); rj && db) {
      Result<RunAnalysisSummary> result = Error::Transient("not computed");
      try {
        result = analyse_run(*db, rj->run_id, settings_);
      } catch (const std::exception& e) {
        result = Error::Permanent(fmt::format("run {}: analysis failed: {}", rj->run_id, e.what()));
      }
      if (callbacks_.run_done) callbacks_.run_done(*db, *rj, result);
    } else if (rj) {
      spdlog::error("run {}: analysis not computed: {}", rj->run_id, opened.error().message);
    }
    {
      std::lock_guard lock(mu_);
      --busy_;
    }
    cv_.notify_all();
  }
}

}  // namespace gyrotherm::calibration

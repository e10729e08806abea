#include "gyrotherm/daemon/analysis_worker.h"

#include <fmt/format.h>

#include "gyrotherm/core/clock.h"

namespace gyrotherm::daemon {

Result<storage::SegmentStatsRecord> compute_table1(storage::Database& db, const Table1Job& job,
                                                   const analysis::Table1Options& options) {
  const std::string where = fmt::format("run {} segment {}", job.run_id, job.segment_index + 1);
  std::vector<std::pair<double, double>> windows = job.windows;
  if (windows.empty()) windows.emplace_back(job.t_from_s, job.t_to_s);
  analysis::AnalysisSeries joined;
  for (const auto& [from_s, to_s] : windows) {
    auto gyro = db.gyro_samples(job.run_id, from_s, to_s);
    if (!gyro) return Error::Transient(fmt::format("{}: {}", where, gyro.error().message));
    if (gyro->empty() && windows.size() > 1) continue;  // a window shorter than a sample
    auto temps = db.temperature_samples(job.run_id, from_s, to_s);
    if (!temps) return Error::Transient(fmt::format("{}: {}", where, temps.error().message));
    auto part = analysis::make_analysis_series(*gyro, *temps, options.bin_s);
    if (!part) {
      return Error::Permanent(fmt::format("{} window [{:.1f}, {:.1f}) s: {}", where, from_s, to_s,
                                          part.error().message));
    }
    joined.bin_s = part->bin_s;
    joined.binned = part->binned;
    for (auto [dst, src] :
         {std::pair{&joined.t_s, &part->t_s}, std::pair{&joined.rate_dph, &part->rate_dph},
          std::pair{&joined.top_c, &part->top_c}, std::pair{&joined.side_c, &part->side_c}}) {
      dst->insert(dst->end(), src->begin(), src->end());
    }
  }
  auto* series = &joined;
  auto row = analysis::table1_row(*series, options);
  if (!row) return Error::Permanent(fmt::format("{}: {}", where, row.error().message));

  storage::SegmentStatsRecord rec;
  rec.segment_id = job.segment_id;
  rec.run_id = job.run_id;
  rec.segment_index = job.segment_index;
  rec.setpoint_c = job.setpoint_c;
  rec.n = static_cast<int64_t>(row->n);
  rec.duration_s = row->duration_s;
  rec.temp_mean_c = row->temp_mean_c;
  rec.bias_mean_dph = row->bias_mean_dph;
  rec.bias_std_dph = row->bias_std_dph;
  rec.bias_std_ma_dph = row->bias_std_ma_dph;
  rec.bias_mean_earth_removed_dph = row->bias_mean_earth_removed_dph;
  rec.bin_s = options.bin_s;
  rec.ma_window = static_cast<int>(options.ma_window);
  rec.earth_rate_dph = options.earth_rate_dph;
  rec.t_from_s = job.t_from_s;
  rec.t_to_s = job.t_to_s;
  rec.computed_utc = wall_time_utc_iso();
  if (auto st = db.put_segment_stats(rec); !st) {
    return Error::Transient(fmt::format("{}: {}", where, st.error().message));
  }
  return rec;
}

AnalysisWorker::AnalysisWorker(std::string db_path, storage::SampleWriter& writer,
                               analysis::Table1Options options, Done on_done)
    : db_path_(std::move(db_path)),
      writer_(writer),
      options_(options),
      on_done_(std::move(on_done)),
      thread_([this] { run(); }) {}

AnalysisWorker::~AnalysisWorker() { stop(); }

void AnalysisWorker::submit(Table1Job job) {
  {
    std::lock_guard lock(mu_);
    jobs_.push_back(job);
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
    Table1Job job;
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
      if (jobs_.empty()) return;  // stopping, nothing left
      job = jobs_.front();
      jobs_.pop_front();
      ++busy_;
    }
    Result<storage::SegmentStatsRecord> result = Error::Transient("not computed");
    try {
      (void)writer_.flush();  // the window's samples must be committed first
      if (!db) {
        auto opened = storage::Database::open(db_path_);
        if (opened)
          db.emplace(std::move(*opened));
        else
          result = opened.error();
      }
      if (db) result = compute_table1(*db, job, options_);
    } catch (const std::exception& e) {
      result = Error::Permanent(fmt::format("run {} segment {}: analysis failed: {}", job.run_id,
                                            job.segment_index + 1, e.what()));
    }
    if (on_done_) on_done_(job, result);
    {
      std::lock_guard lock(mu_);
      --busy_;
    }
    cv_.notify_all();
  }
}

}  // namespace gyrotherm::daemon

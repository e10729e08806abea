// StationQueries: the read and queue-edit half of the station's control
// interface (the HTTP thread's side). It answers from its own database
// connection, under its own lock, and never waits on the control loop or a
// device: runs, their records and samples, DUT history, and the queue's
// list, additions, removals and moves. What the control loop must learn of
// an edit goes through StationQueries::Links (the waiting count, a wake-up,
// the running run's metadata in the status).
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "gyrotherm/config/config.h"
#include "gyrotherm/station/control.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::station {

// The meta key whose value, when set, is why the queue is held.
inline constexpr const char* kQueueHoldKey = "queue_hold";

class StationQueries {
 public:
  // What the queries share with the control loop.
  struct Links {
    // Queue entries waiting: changed here by read-modify-write only.
    std::atomic<int>& queue_length;
    const std::atomic<bool>& queue_held;
    // An entry was queued: the control loop may start it now.
    std::function<void()> wake;
    // Run `run_id`'s metadata changed (the status shows the running run's).
    std::function<void(int64_t run_id, const storage::RunMetadata& metadata)> metadata_changed;
  };

  // `config` must outlive the queries.
  StationQueries(const config::StationConfig& config, storage::Database db, Links links);

  Reply queue_list();
  Reply enqueue(const QueueRequest& request);
  Reply queue_remove(int64_t id);
  Reply queue_move(int64_t id, int position);

  Reply runs();
  Reply run(int64_t id);
  Reply run_with_duts(int64_t id);
  Reply edit_run(int64_t id, const MetadataEdit& edit, const std::string& changed_by);
  Reply run_events(int64_t id);
  Reply run_stats(int64_t id);
  Reply run_stats_filtered(int64_t id, const StatsQuery& query);
  Reply run_fits(int64_t id);
  Reply run_allan(int64_t id);
  Reply run_scale_factor(int64_t id);
  Reply run_channel_samples(int64_t id, const SamplesQuery& query);
  Reply fit(int64_t id);
  Reply exports();
  Reply duts();
  Reply dut_history(const std::string& serial);

 private:
  template <class Fetch>
  Reply run_records(int64_t id, Fetch fetch);
  // `answer` (reads of db_) in one read transaction, so an answer of
  // several reads shows one committed state (Database::read_consistently):
  // the analysis thread commits a run's results meanwhile. Needs mu_.
  template <class Answer>
  Reply consistently(Answer answer);
  // nullopt when queue entry `id` is waiting; else the refusal (404, or 409
  // with `when_running` for the running entry). Needs mu_.
  std::optional<Reply> unless_queued(int64_t id, std::string_view when_running);

  const config::StationConfig& config_;
  Links links_;
  std::mutex mu_;
  storage::Database db_;  // the HTTP thread's connection (mu_)
};

}  // namespace gyrotherm::station

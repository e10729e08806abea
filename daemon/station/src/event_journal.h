// EventJournal: what the station writes of a run besides its samples and
// its checkpoint: events (the events table and the stream), the run's state
// and its segments (a row per execution of a step). What the database
// refuses (disk full) is kept here and written, in order, once it takes
// writes again: events first, then segment updates, then the run's state.
// Events from other threads (post_event) wait here for the control loop.
//
// Threads and locking: post_event() is thread-safe (posted_mu_, which
// guards the posted events only); everything else runs on the control
// thread (or where the control thread is gone: Station::stop()) with the
// station's run lock (the Station's run_mu_) held, which guards the rest of
// this class and the database connection it writes on (Links::db). An
// event's message goes to the status under the station's status lock
// (Links::status_mu, the Station's mu_), taken last.
#pragma once

#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/station/run_clock.h"
#include "gyrotherm/station/status.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::station {

// A step's segment record: row `id` of run `run_id`, step `index`, in `state`.
storage::SegmentRecord segment_record(int64_t id, int64_t run_id, std::size_t index,
                                      const schedules::PlanStep& step,
                                      const schedules::StepTimes& times, std::string state);

class EventJournal {
 public:
  // What the journal shares with the rest of the station.
  struct Links {
    const Clock& clock;  // station time: an event's run time
    const WallClock& wall;
    // The current run (its id, and its start for an event's time).
    const RunClock& run_clock;
    // The control thread's connection (the Station's run_mu_).
    storage::Database& db;
    // Each event, live (StationHooks::publish); may be empty.
    std::function<void(std::string_view event, const nlohmann::json& data)> publish;
    // The station's status lock and the snapshot (its last event).
    std::mutex& status_mu;
    StatusSnapshot& snapshot;
    // A run's sequencer exists: its checkpoints carry the segment records
    // a failed step-change transaction left.
    std::function<bool()> run_in_progress;
  };

  explicit EventJournal(Links links);

  // An event under the current run, if any: written (or kept), published,
  // and the status's last event.
  void add_event(const std::string& kind, const std::string& from, const std::string& to,
                 const std::string& message);
  // An event from another part of the daemon (the lab relay: kind "lab"):
  // thread-safe, never blocks; recorded (events table, stream) by the
  // control loop at its next tick, under the run in progress if any.
  void post_event(const std::string& kind, const std::string& message);
  // Control thread (run_mu_): the events post_event() queued, in order.
  void record_posted_events();
  // Writes, in order, what a failing database refused: events, the run's
  // state, segment updates. Stops at the first failure (tried again next tick).
  void record_unrecorded();
  // The run's state to write (record_unrecorded()).
  void keep_run_state(int64_t run_id, std::string state, bool terminal);
  // A segment's record to write (record_unrecorded()), by its id.
  void keep_segment(const storage::SegmentRecord& seg);

  // The current run's segment rows, by step index (0: none yet).
  void begin_segments(std::vector<int64_t> ids);
  // A new execution of step `index`: its row is created anew.
  void start_segment(std::size_t index, const schedules::PlanStep& step, double t_s);
  // The row of step `index`'s execution, created (running, from `t_s`) if
  // it has none; 0 when it cannot be.
  int64_t segment_id(std::size_t index, const schedules::PlanStep& step, double t_s);

  // The sequencer's tick (`tick`), with the segments it ends and starts
  // written in one transaction with the checkpoint that says so
  // (`checkpoint`: written, or the error). False when that transaction
  // failed and was rolled back: tried again, together, next tick.
  bool tick_with_checkpoint(const std::function<void()>& tick,
                            const std::function<Status()>& checkpoint);

 private:
  void keep_unrecorded(const storage::EventRecord& ev);
  // Segments only; false while one is left unwritten.
  bool record_segments();
  // The run's state kept unwritten, if any; false when it is still unwritten.
  bool record_run_state();

  Links links_;
  std::vector<int64_t> segment_ids_;
  // What the database refused (disk full): kept and written in order by
  // record_unrecorded() once it takes writes again.
  static constexpr std::size_t kMaxUnrecordedEvents = 10000;
  std::deque<storage::EventRecord> unrecorded_events_;
  uint64_t unrecorded_events_dropped_ = 0;
  struct UnrecordedRunState {
    int64_t run_id;
    std::string state;
    bool terminal;
  };
  std::optional<UnrecordedRunState> unrecorded_run_state_;
  std::map<int64_t, storage::SegmentRecord> unrecorded_segments_;  // by segment id
  bool run_state_failing_ = false, segment_failing_ = false;
  // Inside tick_with_checkpoint(), and after its transaction failed while
  // the run goes on: segment records wait for the next one (with a
  // checkpoint).
  bool defer_segment_records_ = false;
  bool segments_with_checkpoint_ = false;

  // post_event(): events from other threads (the lab relay), recorded by
  // the control loop at its next tick. Bounded: the oldest are dropped.
  static constexpr std::size_t kMaxPostedEvents = 1000;
  std::mutex posted_mu_;
  std::deque<std::pair<std::string, std::string>> posted_events_;  // (kind, message)
  uint64_t posted_events_dropped_ = 0;
};

}  // namespace gyrotherm::station

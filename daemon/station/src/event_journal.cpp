#include "event_journal.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <nlohmann/json.hpp>

#include "gyrotherm/station/control.h"

namespace gyrotherm::station {

storage::SegmentRecord segment_record(int64_t id, int64_t run_id, std::size_t index,
                                      const schedules::PlanStep& step,
                                      const schedules::StepTimes& times, std::string state) {
  storage::SegmentRecord seg;
  seg.id = id;
  seg.run_id = run_id;
  seg.index = static_cast<int>(index);
  seg.kind = std::string(schedules::to_string(step.kind));
  seg.label = step.label;
  seg.setpoint_c = step.setpoint_c;
  seg.ramp_rate_c_per_min = step.rate_c_per_min;
  seg.t_start_s = times.start_s;
  seg.t_settled_s = times.settled_s;
  seg.t_acquire_start_s = times.acquire_start_s;
  seg.t_acquire_end_s = times.acquire_end_s;
  seg.t_end_s = times.end_s;
  seg.paused_s = times.held_s;
  seg.state = std::move(state);
  for (const auto& w : times.windows) seg.windows.emplace_back(w.from_s, w.to_s);
  seg.table_mode = std::string(schedules::to_string(step.table.mode));
  if (step.table.mode == schedules::TableDemandMode::kRate) {
    seg.table_rate_dps = step.table.rate_dps;
  } else if (step.table.mode == schedules::TableDemandMode::kStatic) {
    seg.table_rate_dps = 0.0;
    seg.table_position_deg = step.table.position_deg;
  }
  seg.turns = step.turns;
  seg.dwell_s = step.dwell_s;
  seg.sf_sequence = step.sf_sequence;
  seg.sf_repetition = step.sf_repetition;
  seg.acquire_stop = times.acquire_stop;
  return seg;
}

EventJournal::EventJournal(Links links) : links_(std::move(links)) {}

void EventJournal::add_event(const std::string& kind, const std::string& from,
                             const std::string& to, const std::string& message) {
  storage::EventRecord ev;
  const int64_t run_id = links_.run_clock.load().run_id;
  if (run_id != 0) ev.run_id = run_id;
  ev.t_s = run_id != 0 ? (links_.clock.now_s() - links_.run_clock.load().t0_s) : 0.0;
  ev.wall_utc = utc_iso(links_.wall);
  ev.kind = kind;
  ev.from_state = from;
  ev.to_state = to;
  ev.message = message;
  record_unrecorded();
  if (!unrecorded_events_.empty()) {
    keep_unrecorded(ev);
  } else if (auto r = links_.db.add_event(ev); !r) {
    spdlog::error("event not recorded yet (kept, written when the database takes writes): {}",
                  r.error().message);
    keep_unrecorded(ev);
  } else {
    ev.id = *r;
  }
  if (links_.publish) {
    nlohmann::json j = to_json(ev);
    j["run_id"] = ev.run_id ? nlohmann::json(*ev.run_id) : nlohmann::json(nullptr);
    links_.publish("event", j);
  }
  std::lock_guard lock(links_.status_mu);
  links_.snapshot.last_event = message;
}

void EventJournal::post_event(const std::string& kind, const std::string& message) {
  std::lock_guard lock(posted_mu_);
  if (posted_events_.size() >= kMaxPostedEvents) {
    posted_events_.pop_front();
    ++posted_events_dropped_;
  }
  posted_events_.emplace_back(kind, message);
}

// Control thread (run_mu_): the events post_event() queued, in order.
void EventJournal::record_posted_events() {
  std::deque<std::pair<std::string, std::string>> events;
  uint64_t dropped = 0;
  {
    std::lock_guard lock(posted_mu_);
    events.swap(posted_events_);
    std::swap(dropped, posted_events_dropped_);
  }
  if (dropped > 0) {
    add_event("error", "", "",
              fmt::format("{} posted events dropped (more than {} waited for the control loop)",
                          dropped, kMaxPostedEvents));
  }
  for (const auto& [kind, message] : events) add_event(kind, "", "", message);
}

void EventJournal::keep_unrecorded(const storage::EventRecord& ev) {
  if (unrecorded_events_.size() >= kMaxUnrecordedEvents) {
    ++unrecorded_events_dropped_;
    spdlog::error("event dropped ({} so far): {} events already wait for the database",
                  unrecorded_events_dropped_, unrecorded_events_.size());
    return;
  }
  unrecorded_events_.push_back(ev);
}

// Writes, in order, what a failing database refused: events, the run's
// state, segment updates. Stops at the first failure (tried again next tick).
void EventJournal::record_unrecorded() {
  while (!unrecorded_events_.empty()) {
    if (!links_.db.add_event(unrecorded_events_.front())) return;
    unrecorded_events_.pop_front();
    if (unrecorded_events_.empty()) spdlog::info("events kept while the database failed: written");
  }
  if (!defer_segment_records_ && !(segments_with_checkpoint_ && links_.run_in_progress())) {
    (void)record_segments();
  }
  // A run's end is written after its steps' last records (inside a
  // sequencer tick, with them: tick_with_checkpoint): neither a reader nor a crash
  // finds a completed run with a step still running.
  if (unrecorded_run_state_ && unrecorded_run_state_->terminal && !unrecorded_segments_.empty()) {
    return;
  }
  (void)record_run_state();
}

bool EventJournal::record_run_state() {
  if (!unrecorded_run_state_) return true;
  const auto& u = *unrecorded_run_state_;
  if (auto st = links_.db.set_run_state(u.run_id, u.state, u.terminal); !st) {
    if (!run_state_failing_) spdlog::error("run state not written yet: {}", st.error().message);
    run_state_failing_ = true;
    return false;
  }
  run_state_failing_ = false;
  unrecorded_run_state_.reset();
  return true;
}

bool EventJournal::record_segments() {
  for (auto it = unrecorded_segments_.begin(); it != unrecorded_segments_.end();) {
    if (auto st = links_.db.update_segment(it->second); !st) {
      if (!segment_failing_) spdlog::error("segment not written yet: {}", st.error().message);
      segment_failing_ = true;
      return false;
    }
    segment_failing_ = false;
    it = unrecorded_segments_.erase(it);
  }
  return true;
}

int64_t EventJournal::segment_id(std::size_t index, const schedules::PlanStep& step, double t_s) {
  if (index >= segment_ids_.size()) return 0;
  if (segment_ids_[index] != 0) return segment_ids_[index];
  schedules::StepTimes times;
  times.start_s = t_s;
  storage::SegmentRecord seg =
      segment_record(0, links_.run_clock.load().run_id, index, step, times, "running");
  auto id = links_.db.create_segment(seg);
  if (!id) {
    spdlog::error("{}", id.error().message);
    return 0;
  }
  segment_ids_[index] = *id;
  return *id;
}

void EventJournal::keep_run_state(int64_t run_id, std::string state, bool terminal) {
  unrecorded_run_state_ = UnrecordedRunState{run_id, std::move(state), terminal};
}

void EventJournal::keep_segment(const storage::SegmentRecord& seg) {
  unrecorded_segments_[seg.id] = seg;
}

void EventJournal::begin_segments(std::vector<int64_t> ids) { segment_ids_ = std::move(ids); }

void EventJournal::start_segment(std::size_t index, const schedules::PlanStep& step, double t_s) {
  if (index < segment_ids_.size()) segment_ids_[index] = 0;  // a new execution of the step
  (void)segment_id(index, step, t_s);
}

bool EventJournal::tick_with_checkpoint(const std::function<void()>& tick,
                                        const std::function<Status()>& checkpoint) {
  // A soak's end flushes the sample writer (on_step_finished) outside any
  // transaction of ours; the step's end, the next step's start and the
  // checkpoint are then written in one: a crash leaves all or none (the
  // next step's row itself is created at its start, and a resume closes a
  // stray one).
  defer_segment_records_ = true;
  tick();
  defer_segment_records_ = false;
  if (unrecorded_segments_.empty()) {
    segments_with_checkpoint_ = false;
    record_unrecorded();  // a run's end the tick held back for its steps
    return true;
  }
  const auto kept = unrecorded_segments_;
  const auto kept_run_state = unrecorded_run_state_;
  const Status st = links_.db.atomically([&]() -> Status {
    if (!record_segments()) return Error::Transient("a segment was not written");
    if (!record_run_state()) return Error::Transient("the run's state was not written");
    return checkpoint();
  });
  segments_with_checkpoint_ = !st;
  if (!st) {
    // Rolled back: tried again, together, next tick.
    unrecorded_segments_ = kept;
    unrecorded_run_state_ = kept_run_state;
    if (!segment_failing_) spdlog::error("step change not written yet: {}", st.error().message);
    segment_failing_ = true;
    return false;
  }
  return true;
}

}  // namespace gyrotherm::station

#include "run_lifecycle.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>

#include "dut_acquisition.h"
#include "event_journal.h"
#include "gyrotherm/config/run_config.h"
#include "gyrotherm/core/paced_clock.h"
#include "gyrotherm/station/station_queries.h"
#include "plant_io.h"

namespace gyrotherm::station {
namespace {

using schedules::RunState;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

}  // namespace

// Where an interrupted run resumes (resume_point()).
struct RunLifecycle::ResumePoint {
  storage::QueueEntry entry;
  schedules::Plan plan;
  schedules::SequencerSnapshot snap;
  // Run seconds: where the run goes on, and how far its acquisition is
  // credited (the last committed gyro sample).
  double t_resume_s = 0;
  double data_until_s = 0;
  // The run's segment rows as stored, and whether the checkpointed step had
  // ended already (reopen_segments()).
  std::vector<storage::SegmentRecord> segments;
  bool step_finished_already = false;
};

RunLifecycle::RunLifecycle(Links links) : links_(std::move(links)) {}

double RunLifecycle::run_time_s() const {
  return links_.clock.now_s() - links_.run_clock.load().t0_s;
}

void RunLifecycle::make_sequencer(schedules::Plan plan) {
  // Valid: Station::create checked them.
  sequencer_ = std::make_unique<schedules::Sequencer>(
      std::move(plan), config::sequencer_options(links_.config),
      static_cast<schedules::SequencerObserver&>(*this));
}

void RunLifecycle::recover() {
  if (auto hold = links_.db.meta(kQueueHoldKey); hold && *hold) {
    hold_reason_ = **hold;
    links_.queue_held.store(true);
    spdlog::info("queue held: {}", *hold_reason_);
  }
  count_queue();
  resume_interrupted_run();
  submit_missing_analyses();
}

void RunLifecycle::show_run(int64_t run_id, const std::string& schedule_name,
                            const storage::RunMetadata& metadata) {
  std::lock_guard lock(links_.status_mu);
  StatusSnapshot& s = links_.snapshot;
  s.run_id = run_id;
  s.schedule_name = schedule_name;
  s.run_operator = metadata.operator_name;
  s.run_comment = metadata.comment;
  s.run_tags = metadata.tags;
}

// ---------------------------------------------------------------- the run's ticks

double RunLifecycle::tick(double now_s, const schedules::Readings& r) {
  const double t_run_s = now_s - links_.run_clock.load().t0_s;
  TableControl* table = links_.table;
  const uint64_t tick = links_.control_ticks;
  if (sequencer_->state() == RunState::kAborting) {
    // The table stops before the chamber heads for its safe set point.
    if (table) table->make_safe(links_.wall.monotonic_s());
    if (links_.plant.write_setpoint(sequencer_->setpoint_c(), true, tick)) {
      sequencer_->safe_state_reached(t_run_s);
    }
  } else {
    if (table) tend_table(t_run_s);
    watch_acquisition(t_run_s);
    if (acquire_watch_.done()) {
      schedules::Readings judged = r;
      judged.acquisition_done = acquire_watch_.done();
      tick_sequencer(t_run_s, judged);
    } else {
      tick_sequencer(t_run_s, r);
    }
    watch_settle(t_run_s, r);
    if (table && !sequencer_->finished()) drive_table();
    // At the run's end the table stops before the chamber heads for its
    // safe set point (its servo goes off once at rest, ticks later).
    if (table && sequencer_->finished()) table->make_safe(links_.wall.monotonic_s());
    // Failing: retried next tick.
    (void)links_.plant.write_setpoint(sequencer_->setpoint_c(), false, tick);
  }
  if (table) {
    if (auto sample = table->sample(t_run_s)) links_.writer.push_table(current_run_id(), *sample);
  }
  TemperatureSample ts;
  ts.t_s = t_run_s;
  ts.setpoint_c = sequencer_->setpoint_c();
  ts.chamber_c = r.chamber_c.value_or(kNaN);
  ts.top_c = r.top_c.value_or(kNaN);
  ts.side_c = r.side_c.value_or(kNaN);
  links_.writer.push_temperature(current_run_id(), ts);
  checkpoint(false);
  return t_run_s;
}

void RunLifecycle::end_if_finished() {
  if (sequencer_ && sequencer_->finished()) end_run();
}

void RunLifecycle::interrupt(const std::string& reason) {
  if (sequencer_ && !sequencer_->finished()) {
    sequencer_->interrupt(run_time_s(), reason);
    checkpoint(true);
    end_run();
  }
}

void RunLifecycle::tick_sequencer(double t_run_s, const schedules::Readings& r) {
  const bool written = links_.journal.tick_with_checkpoint(
      [&] { sequencer_->tick(t_run_s, r); },
      [&]() -> Status {
        checkpoint(true);
        if (checkpoint_failing_) return Error::Transient("the checkpoint was not written");
        return Status::Ok();
      });
  if (!written) checkpoint_state_.clear();  // rolled back: checkpointed again next tick
}

void RunLifecycle::watch_acquisition(double t_run_s) {
  const std::size_t index = sequencer_->step_index();
  const auto& steps = sequencer_->plan().steps;
  const bool running = !sequencer_->finished() && sequencer_->state() != RunState::kAborting;
  const schedules::PlanStep* step =
      running && index < steps.size() && steps[index].kind == schedules::StepKind::kSoak
          ? &steps[index]
          : nullptr;
  const bool acquiring = step && step->adaptive && sequencer_->state() == RunState::kAcquiring;
  std::vector<std::pair<double, double>> windows;
  if (acquiring) {
    const schedules::SequencerSnapshot snap = sequencer_->snapshot(t_run_s);
    for (const auto& w : snap.times.windows) windows.emplace_back(w.from_s, w.to_s);
    if (snap.window_open_s) windows.emplace_back(*snap.window_open_s, t_run_s);
  }
  acquire_watch_.tick(t_run_s, index, step, acquiring, windows,
                      [this](std::span<const std::pair<double, double>> w) {
                        return links_.duts.gated_seconds(w);
                      });
}

void RunLifecycle::watch_settle(double t_run_s, const schedules::Readings& r) {
  std::optional<std::size_t> settling;
  analysis::SettleGate gate;
  const std::size_t index = sequencer_->step_index();
  const auto& steps = sequencer_->plan().steps;
  if (!sequencer_->finished() && sequencer_->state() != RunState::kAborting &&
      index < steps.size() && steps[index].kind == schedules::StepKind::kSoak &&
      sequencer_->gate_progress(t_run_s)) {
    const schedules::PlanStep& step = steps[index];
    settling = index;
    gate = {.setpoint_c = step.setpoint_c,
            .tolerance_c = step.tolerance_c,
            .stability_c_per_min = step.stability_c_per_min,
            .window_s = step.stability_window_s};
  }
  std::optional<double> shell_c;
  if (r.top_c && r.side_c) shell_c = (*r.top_c + *r.side_c) / 2;
  settle_watch_.tick(t_run_s, settling, gate, shell_c, r.chamber_c);
}

void RunLifecycle::fill_status(StatusSnapshot& s) const {
  s.queue_length = std::max(0, links_.queue_length.load());
  s.queue_held = hold_reason_.has_value();
  s.queue_hold_reason = hold_reason_.value_or("");
  s.interlocks.clear();
  if (!sequencer_) return;
  s.state = std::string(to_string(sequencer_->state()));
  s.paused = sequencer_->paused();
  for (const auto& c : sequencer_->tripped()) {
    s.interlocks.push_back({std::string(to_string(c.kind)), c.message});
  }
  const auto idx = sequencer_->step_index();
  const auto& steps = sequencer_->plan().steps;
  s.step_index = static_cast<int>(idx);
  s.step_count = static_cast<int>(steps.size());
  s.step_label = idx < steps.size() ? steps[idx].label : "";
  s.setpoint_c = sequencer_->setpoint_c();
}

Progress RunLifecycle::progress(double t_run_s) {
  constexpr double kQueueScanWallS = 5;
  const int queued = links_.queue_length.load();
  const double wall_s = links_.wall.monotonic_s();
  if (queued != queue_scanned_length_ || wall_s >= queue_scan_due_wall_s_) {
    queue_scanned_length_ = queued;
    queue_scan_due_wall_s_ = wall_s + kQueueScanWallS;
    if (auto entries = links_.db.queue_entries()) {
      std::vector<schedules::QueueDurations::Entry> waiting;
      for (const auto& e : *entries) {
        if (e.state == "queued") {
          waiting.push_back(
              {e.id, e.toml_text, e.source_path.empty() ? e.schedule_name : e.source_path});
        }
      }
      // Each queued run starts where the one before left the chamber.
      queue_planned_ = queue_durations_.update(waiting, config::station_limits(links_.config),
                                               links_.config.station.safe_setpoint_c);
    }
    // The chamber's prior, read with the queue: a settle ends a soak's
    // settling, not often.
    if (auto settles = links_.db.recent_settles_s(schedules::kMaxPriorSettles)) {
      settle_prior_ = schedules::settle_prior(std::move(*settles));
    } else {
      spdlog::error("{}", settles.error().message);
    }
  }
  if (!sequencer_) return to_progress(schedules::queue_progress(queue_planned_, settle_prior_));
  return to_progress(schedules::run_progress(sequencer_->plan(), sequencer_->snapshot(t_run_s),
                                             sequencer_->gate_progress(t_run_s), queue_planned_,
                                             settle_watch_.forecast(t_run_s), settle_prior_,
                                             acquire_watch_.forecast(t_run_s)));
}

// ---------------------------------------------------------------- the table

schedules::TableDemand RunLifecycle::table_demand() const {
  if (!sequencer_ || sequencer_->finished() || sequencer_->paused() ||
      !sequencer_->tripped().empty() || sequencer_->state() == RunState::kAborting) {
    return {};
  }
  return sequencer_->table_demand();
}

void RunLifecycle::drive_table() {
  TableControl& table = *links_.table;
  const schedules::TableDemand demand = table_demand();
  const bool moves =
      demand.mode == schedules::TableDemandMode::kRate || demand.position_deg.has_value();
  if (!moves && table.safing()) return;
  if (!moves && !table.at_rest()) {
    table.make_safe(links_.wall.monotonic_s());
  } else {
    table.drive(demand, links_.wall.monotonic_s());
  }
}

void RunLifecycle::tend_table(double t_run_s) {
  TableControl& table = *links_.table;
  if (auto what = table.take_interruption()) {
    const bool respin = links_.config.table->respin_after_fault;
    links_.journal.add_event(
        "table", "", "",
        fmt::format("table: {}; {}", *what,
                    respin ? "the station spins it up again ([table] respin_after_fault); "
                             "acquisition waits for the rate"
                           : "the run pauses with the table at rest"));
    sequencer_->table_interrupted(t_run_s, "the table was taken off its demand");
    if (!respin && !sequencer_->paused()) {
      (void)sequencer_->pause(
          t_run_s,
          fmt::format("table: {}; it stays at rest until `gyrotherm resume` spins it up again "
                      "([table] respin_after_fault = false)",
                      *what));
    }
  }
  const auto tripped = sequencer_->tripped();
  const bool fault_holds =
      std::any_of(tripped.begin(), tripped.end(), [](const schedules::InterlockCondition& c) {
        return c.kind == schedules::InterlockKind::kTableFault;
      });
  if (fault_holds) {
    if (auto message = table.reset_latched_fault(links_.clock.now_s())) {
      spdlog::info("{}", *message);
      links_.journal.add_event("table", "", "", *message);
    }
  }
}

// ---------------------------------------------------------------- the queue

void RunLifecycle::count_queue() {
  auto entries = links_.db.queue_entries();
  if (!entries) return;
  links_.queue_length.store(static_cast<int>(std::count_if(
      entries->begin(), entries->end(), [](const auto& e) { return e.state == "queued"; })));
}

// Says what the queue does after the current run failed, once per run, and
// before the run's failed state is recorded: whoever sees the run failed
// sees the queue's answer too. An abort (or a stop) has already held it,
// whatever ignore_failures says.
void RunLifecycle::answer_failed_run() {
  if (queue_answered_ || !entry_) return;
  queue_answered_ = true;
  const int64_t run_id = current_run_id();
  if (hold_reason_) {
    links_.journal.add_event(
        "queue", "", "",
        fmt::format("run {} failed; the queue stays held ({})", run_id, *hold_reason_));
  } else if (!entry_->ignore_failures) {
    hold_queue(fmt::format("run {} failed ({}); resume releases the queue", run_id, last_reason_));
  } else {
    links_.journal.add_event("queue", "", "",
                             fmt::format("run {} failed; the queue goes on with the next entry "
                                         "(ignore_failures)",
                                         run_id));
  }
}

void RunLifecycle::hold_queue(const std::string& reason) {
  hold_reason_ = reason;
  // Stored before the flag rises: the queue's answer reads both.
  if (auto st = links_.db.set_meta(kQueueHoldKey, reason); !st) {
    spdlog::error("{}", st.error().message);
  }
  links_.queue_held.store(true);
  links_.journal.add_event("queue", "", "", "queue held: " + reason);
  spdlog::info("queue held: {}", reason);
}

void RunLifecycle::release_queue() {
  hold_reason_.reset();
  // The flag falls before the stored hold goes (the reverse of hold_queue):
  // the queue's answer, which counts either, never says held without why.
  links_.queue_held.store(false);
  if (auto st = links_.db.delete_meta(kQueueHoldKey); !st) spdlog::error("{}", st.error().message);
  links_.journal.add_event("queue", "", "", "queue released");
}

// ---------------------------------------------------------------- start and resume

void RunLifecycle::start_next_run(double now_s) {
  // queue_length > 0: an entry was added and not yet taken or removed. It
  // may be a little behind the database (an add counted just after its
  // commit), never ahead for long: the next tick sees it.
  if (hold_reason_ || links_.queue_length.load() <= 0) return;
  storage::Database& db = links_.db;
  auto entries = db.queue_entries();
  if (!entries) {
    spdlog::error("{}", entries.error().message);
    return;
  }
  auto it = std::find_if(entries->begin(), entries->end(),
                         [](const auto& e) { return e.state == "queued"; });
  if (it == entries->end()) return;
  storage::QueueEntry entry = *it;
  const std::string source = entry.source_path.empty() ? entry.schedule_name : entry.source_path;
  const config::StationConfig& config = links_.config;

  storage::RunRecord rec;
  rec.schedule_name = entry.schedule_name;
  rec.state = "queued";
  rec.started_utc = utc_iso(links_.wall);
  rec.time_scale = links_.clock.time_scale();
  rec.latitude_deg = config.station.latitude_deg;
  rec.orientation = std::string(analysis::to_string(config.station.orientation));
  // The configuration in force (loaded at start-up), not the file as it is
  // on disk now.
  rec.config_json = config::run_config_json(config).dump();
  // One transaction: an entry removed meanwhile starts no run and leaves no
  // run row behind.
  auto id = db.queue_start_run(entry.id, rec);
  if (!id) {
    spdlog::error("cannot start run of {}: {}", entry.schedule_name, id.error().message);
    return;
  }
  if (!*id) return;  // removed (or moved on) since it was read; the next tick looks again
  const int64_t run_id = **id;
  links_.queue_length.fetch_sub(1);
  queue_scanned_length_ = -1;  // the queue's planned time: without this entry, at the next tick
  links_.busy.store(true);
  links_.duts.register_run_duts(db, run_id, entry.metadata.dut_serials);
  links_.run_clock.publish(run_id, now_s);
  entry_ = entry;
  show_run(run_id, entry.schedule_name, entry.metadata);

  // Checked again: the station config may have changed since it was queued.
  auto plan = schedules::parse_schedule(entry.toml_text, source, config::station_limits(config));
  if (!plan) {
    links_.journal.add_event(
        "error", "queued", "failed",
        "schedule refused at start (station limits changed?):\n" + plan.error().message);
    last_reason_ = "schedule refused at start";
    answer_failed_run();
    (void)db.set_run_state(run_id, "failed", true);
    end_run();
    return;
  }
  spdlog::info("run {}: {} ({} steps)", run_id, plan->name, plan->steps.size());
  if (links_.table) links_.table->begin_run();
  links_.journal.begin_segments(std::vector<int64_t>(plan->steps.size(), 0));
  // The control thread writes the snapshot: it reads it without the lock.
  const double start_sp = links_.plant.last_written_setpoint_c().value_or(
      links_.snapshot.chamber_c.value_or(config.station.safe_setpoint_c));
  make_sequencer(std::move(*plan));
  sequencer_->start(0.0, start_sp);
  checkpoint(true);
}

// Completed runs whose analysis never ran (the daemon stopped between the end
// of the run and its analysis) get it now.
void RunLifecycle::submit_missing_analyses() {
  auto runs = links_.db.runs();
  if (!runs) return;
  for (const auto& r : *runs) {
    if (r.state != "completed") continue;
    auto events = links_.db.events(r.id);
    if (!events) continue;
    const bool done =
        std::any_of(events->begin(), events->end(),
                    [](const storage::EventRecord& e) { return e.kind == "analysis"; });
    if (!done) {
      spdlog::info("run {}: completed without its analysis; computing it now", r.id);
      links_.analysis.submit(calibration::RunJob{r.id});
    }
  }
}

void RunLifecycle::resume_interrupted_run() {
  storage::Database& db = links_.db;
  auto runs = db.runs();
  if (!runs) {
    spdlog::error("{}", runs.error().message);
    return;
  }
  // Runs that never reached an end: the newest resumes, older ones (there
  // should be none) are closed.
  std::vector<storage::RunRecord> open;
  for (const auto& r : *runs) {
    if (r.state != "completed" && r.state != "failed") open.push_back(r);
  }
  if (open.empty()) return;
  for (std::size_t i = 0; i + 1 < open.size(); ++i) {
    links_.run_clock.publish(open[i].id, 0.0);
    links_.journal.add_event("state", open[i].state, "interrupted",
                             "closed at start-up: a newer run exists");
    (void)db.set_run_state(open[i].id, "interrupted", true);
  }
  const storage::RunRecord& run = open.back();
  links_.run_clock.publish(run.id, 0.0);  // for the events below; its start once known
  auto at = resume_point(run);
  if (!at) {
    const std::string& why = at.error().message;
    links_.journal.add_event("state", run.state, "interrupted", "not resumed: " + why);
    (void)db.set_run_state(run.id, "interrupted", true);
    if (run.queue_id) (void)db.queue_finish(*run.queue_id, "interrupted");
    spdlog::warn("run {} not resumed: {}", run.id, why);
    links_.run_clock.publish(0, 0.0);
    return;
  }
  const schedules::SequencerSnapshot& snap = at->snap;
  links_.journal.begin_segments(reopen_segments(run, *at));
  entry_ = at->entry;
  links_.busy.store(true);
  links_.duts.register_run_duts(db, run.id, entry_->metadata.dut_serials);
  // A soak is credited for what each DUT stored: read back from the step's start.
  links_.duts.seed_coverage(db, run.id, snap.times.start_s);
  links_.run_clock.publish(run.id, links_.clock.now_s() - at->t_resume_s);
  show_run(run.id, run.schedule_name, run.metadata);
  const std::size_t steps = at->plan.steps.size();
  const std::string reason = fmt::format(
      "daemon restarted: run resumes at step {} of {} after {:.1f} min of station time down "
      "(was {})",
      std::min(snap.step_index + 1, steps), steps, (at->t_resume_s - snap.t_s) / 60.0, run.state);
  spdlog::info("run {}: {}", run.id, reason);
  make_sequencer(std::move(at->plan));
  if (links_.table) links_.table->begin_run();
  links_.journal.add_event("resume", "", "", reason);
  links_.plant.forget_setpoint();
  sequencer_->restore(snap, at->t_resume_s, at->data_until_s, reason);
  if (at->step_finished_already) {
    links_.journal.add_event(
        "resume", "", "",
        fmt::format("step {} had ended before the daemon stopped (its last checkpoint was "
                    "older): it is not run again; the run goes on with the next step",
                    snap.step_index + 1));
    sequencer_->continue_after_finished_step(at->t_resume_s);
    // restore() re-announced that step as running: its record stays as it
    // was written when it ended.
    for (const auto& seg : at->segments) {
      if (seg.index == static_cast<int>(snap.step_index) && seg.state == "completed") {
        links_.journal.keep_segment(seg);
      }
    }
    links_.journal.record_unrecorded();
  }
  (void)db.set_run_state(run.id, to_string(sequencer_->state()), false);
  checkpoint(true);
}

Result<RunLifecycle::ResumePoint> RunLifecycle::resume_point(const storage::RunRecord& run) {
  storage::Database& db = links_.db;
  const Clock& clock = links_.clock;
  if (!run.queue_id) return Error::Permanent("it did not come from the queue");
  auto entry = db.queue_entry(*run.queue_id);
  if (!entry || !*entry) return Error::Permanent("its queue entry is gone");
  if (run.resume_json.empty() || !run.checkpoint_wall_unix_s) {
    return Error::Permanent("the daemon stopped before the run's first checkpoint");
  }
  auto plan = schedules::parse_schedule((*entry)->toml_text, (*entry)->source_path,
                                        config::station_limits(links_.config));
  if (!plan) return Error::Permanent("its schedule is refused now:\n" + plan.error().message);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(run.resume_json);
  } catch (const nlohmann::json::exception& e) {
    return Error::Permanent(fmt::format("its checkpoint is unreadable: {}", e.what()));
  }
  auto snap = schedules::snapshot_from_json(j);
  if (!snap) return Error::Permanent(snap.error().message);

  // The downtime in station time; never before a committed sample. On the
  // simulator's clock that wrote the checkpoint it is exact; else from wall
  // time at the time scale.
  const double down_wall_s = std::max(0.0, links_.wall.unix_now_s() - *run.checkpoint_wall_unix_s);
  double t_resume_s = snap->t_s + down_wall_s * clock.time_scale();
  if (const PacedClock* paced = as_paced(clock);
      paced && j.contains("clock_epoch") && j.contains("clock_at_checkpoint_s")) {
    try {
      if (j.at("clock_epoch").get<uint64_t>() == paced->epoch()) {
        t_resume_s =
            snap->t_s + std::max(0.0, clock.now_s() - j.at("clock_at_checkpoint_s").get<double>());
      }
    } catch (const nlohmann::json::exception&) {
      // An unreadable clock mark: the wall-time estimate stands.
    }
  }
  // Acquisition is credited up to the last committed gyro sample only: the
  // samples after it died uncommitted with the daemon, and Table I is made of
  // gyro samples (the temperatures, committed each control tick, can reach
  // well past a lagging gyro stream). Run seconds.
  double data_until_s = -std::numeric_limits<double>::infinity();
  if (auto last_gyro = db.last_gyro_sample_t_s(run.id); !last_gyro) {
    // Cannot tell: trust the checkpoint's clock rather than drop the run.
    spdlog::error(
        "run {}: last committed gyro sample unknown ({}); acquisition credited up to the "
        "checkpoint",
        run.id, last_gyro.error().message);
    data_until_s = snap->t_s;
  } else if (*last_gyro) {
    data_until_s = **last_gyro;
  }
  // The run resumes after every committed sample, gyro or temperature.
  if (auto last = db.last_sample_t_s(run.id); last && *last) {
    t_resume_s = std::max(t_resume_s, **last + 1e-3);
  }
  ResumePoint at;
  at.entry = std::move(**entry);
  at.plan = std::move(*plan);
  at.snap = std::move(*snap);
  at.t_resume_s = t_resume_s;
  at.data_until_s = data_until_s;
  return at;
}

std::vector<int64_t> RunLifecycle::reopen_segments(const storage::RunRecord& run, ResumePoint& at) {
  const std::size_t step = at.snap.step_index;
  std::vector<int64_t> segment_ids(at.plan.steps.size(), 0);
  if (auto segs = links_.db.segments(run.id)) {
    at.segments = std::move(*segs);
    for (const auto& seg : at.segments) {
      if (seg.index >= 0 && static_cast<std::size_t>(seg.index) < segment_ids.size()) {
        segment_ids[static_cast<std::size_t>(seg.index)] = seg.id;
      }
    }
  }
  // The checkpoint may be older than the step's end: the daemon died after
  // the step was recorded finished and before the checkpoint said so. That
  // step is not run again; the run goes on with the next.
  at.step_finished_already =
      step < segment_ids.size() &&
      std::any_of(at.segments.begin(), at.segments.end(), [&](const storage::SegmentRecord& seg) {
        return seg.id == segment_ids[step] && seg.state == "completed";
      });
  // Segments still "running" that are not the step resumed died with the
  // daemon (e.g. the next step's, started after that checkpoint).
  for (auto seg : at.segments) {
    const bool resumed =
        !at.step_finished_already && step < segment_ids.size() && seg.id == segment_ids[step];
    if (seg.state != "running" || resumed) continue;
    seg.state = "aborted";
    if (!seg.t_end_s) seg.t_end_s = std::max(seg.t_start_s, at.snap.t_s);
    if (auto st = links_.db.update_segment(seg); !st) {
      spdlog::error("run {}: segment {} not closed: {}", run.id, seg.id, st.error().message);
    }
    if (seg.index >= 0 && static_cast<std::size_t>(seg.index) < segment_ids.size() &&
        segment_ids[static_cast<std::size_t>(seg.index)] == seg.id) {
      segment_ids[static_cast<std::size_t>(seg.index)] = 0;
    }
  }
  return segment_ids;
}

// ---------------------------------------------------------------- checkpoint and end

void RunLifecycle::checkpoint(bool force) {
  if (!sequencer_) return;
  const double wall_s = links_.wall.monotonic_s();
  // A new state or a new step is checkpointed at once; the rest once a wall second.
  const std::string state =
      fmt::format("{}#{}", to_string(sequencer_->state()), sequencer_->step_index());
  if (!force && state == checkpoint_state_ && wall_s - last_checkpoint_wall_s_ < 1.0) return;
  const double t_run_s = run_time_s();
  nlohmann::json snap = to_json(sequencer_->snapshot(t_run_s));
  if (const PacedClock* paced = as_paced(links_.clock)) {
    // A simulator's clock outlives this process: the downtime of a restart
    // is then read off it exactly, not estimated from wall time.
    snap["clock_epoch"] = paced->epoch();
    snap["clock_at_checkpoint_s"] = links_.clock.now_s();
  }
  const std::string json = snap.dump();
  if (auto st = links_.db.set_run_checkpoint(current_run_id(), json, links_.wall.unix_now_s());
      !st) {
    // Tried again next tick; logged once per failing spell.
    if (!checkpoint_failing_) spdlog::error("run checkpoint not written: {}", st.error().message);
    checkpoint_failing_ = true;
    return;
  }
  if (checkpoint_failing_) spdlog::info("run checkpoint written again");
  checkpoint_failing_ = false;
  checkpoint_state_ = state;
  last_checkpoint_wall_s_ = wall_s;
}

void RunLifecycle::end_run() {
  const RunState final_state = sequencer_ ? sequencer_->state() : RunState::kFailed;
  const int64_t run_id = current_run_id();
  // The table stops first; its servo goes off once it is at rest (ticks).
  if (links_.table) links_.table->make_safe(links_.wall.monotonic_s());
  const double safe_c = links_.config.station.safe_setpoint_c;
  const Status chamber_safe = links_.plant.write_setpoint(safe_c, true, links_.control_ticks);
  links_.plant.owe_safe_setpoint(!chamber_safe);
  if (!chamber_safe && run_id != 0) {
    links_.journal.add_event(
        "error", "", "",
        fmt::format("run {} ended without the chamber taking the safe set point {:g} °C "
                    "({}); the station writes it every control tick until it does",
                    run_id, safe_c, chamber_safe.error().message));
  }
  // A completed run's last samples may still be on the line (a reader behind
  // on a loaded machine): they are waited for, a bounded time, before no
  // batch is stored under the run any more; the flush then holds all of its
  // samples before its analysis reads them.
  if (final_state == RunState::kCompleted && run_id != 0) {
    if (!links_.duts.await_gyro(run_id, run_time_s(), kAwaitGyro)) {
      spdlog::warn("run {}: the gyro stream had not reached the run's end after {} ms", run_id,
                   kAwaitGyro.count());
    }
  }
  links_.run_clock.close_samples();
  const Status flushed = links_.writer.flush();
  if (!flushed && run_id != 0) note_samples_not_committed(run_id, final_state, flushed.error());
  if (run_id != 0) links_.writer.close_run(run_id);
  if (entry_ && final_state != RunState::kInterrupted) {
    if (auto st = links_.db.queue_finish(entry_->id, to_string(final_state)); !st) {
      spdlog::error("{}", st.error().message);
    }
    if (final_state == RunState::kFailed) answer_failed_run();
  }
  queue_answered_ = false;
  if (final_state == RunState::kCompleted && run_id != 0 && flushed) {
    links_.analysis.submit(calibration::RunJob{run_id});
  }
  if (stop_after_current_ && final_state != RunState::kInterrupted) {
    stop_after_current_ = false;
    if (!hold_reason_) {
      hold_queue(fmt::format("stopped after run {} by the operator ({}); resume releases the queue",
                             run_id, stop_reason_));
    }
  }
  links_.run_clock.publish(0, 0.0);
  settle_watch_.forget();
  acquire_watch_.forget();
  sequencer_.reset();
  entry_.reset();
  checkpoint_state_.clear();
  // No checkpoint transaction comes for this run any more: what it left
  // unwritten (its steps' last records, then its end) goes now if it can.
  links_.journal.record_unrecorded();
  {
    std::lock_guard lock(links_.status_mu);
    StatusSnapshot& s = links_.snapshot;
    s.run_id.reset();
    s.run_operator.clear();
    s.run_comment.clear();
    s.run_tags.clear();
    s.step_index.reset();
    s.step_label.clear();
    s.state = "idle";
    s.paused = false;
    s.interlocks.clear();
  }
  links_.busy.store(false);
}

// The run's last samples could not be committed at its end (the commit's
// error, or the writer stopped): said in its events, and a completed run is
// not analysed as if its data were whole. The "analysis" event also keeps a
// restart from analysing it (submit_missing_analyses).
void RunLifecycle::note_samples_not_committed(int64_t run_id, RunState final_state,
                                              const Error& e) {
  const storage::SampleWriterStats ws = links_.writer.stats();
  const std::string why = fmt::format(
      "the final commit of its samples failed ({} samples not stored): {}", ws.pending, e.message);
  spdlog::error("run {}: {}", run_id, why);
  links_.journal.add_event("error", "", "", fmt::format("run {}: {}", run_id, why));
  if (final_state == RunState::kCompleted) {
    links_.journal.add_event(
        "analysis", "", "",
        fmt::format("analysis not run: the run's samples are incomplete ({}); analyse it "
                    "offline once its data are checked (gyrotherm allan, fit)",
                    why));
  }
}

// ---------------------------------------------------------------- the sequencer's observer

void RunLifecycle::on_state(RunState from, RunState to, double t_s, const std::string& reason) {
  spdlog::info("run {} t={:.0f} s: {} -> {}: {}", current_run_id(), t_s, to_string(from),
               to_string(to), reason);
  last_reason_ = reason;
  if (links_.publish) {
    const int64_t run_id = current_run_id();
    links_.publish("state", {{"run_id", run_id != 0 ? nlohmann::json(run_id) : nlohmann::json()},
                             {"from", to_string(from)},
                             {"to", to_string(to)},
                             {"t_s", t_s},
                             {"reason", reason}});
  }
  links_.journal.add_event("state", std::string(to_string(from)), std::string(to_string(to)),
                           reason);
  if (to == RunState::kFailed) answer_failed_run();
  links_.journal.keep_run_state(current_run_id(), std::string(to_string(to)),
                                schedules::is_terminal(to));
  links_.journal.record_unrecorded();
}

void RunLifecycle::on_interlock(schedules::InterlockKind kind, bool tripped, double t_s,
                                const std::string& message) {
  (void)kind;
  (void)t_s;
  if (tripped) {
    spdlog::warn("run {}: {}", current_run_id(), message);
  } else {
    spdlog::info("run {}: {}", current_run_id(), message);
  }
  links_.journal.add_event("interlock", "", "", message);
}

void RunLifecycle::on_step_started(std::size_t index, const schedules::PlanStep& step, double t_s) {
  links_.journal.start_segment(index, step, t_s);
  links_.duts.forget_coverage_before(t_s);
}

void RunLifecycle::on_step_changed(std::size_t index, const schedules::PlanStep& step,
                                   const schedules::StepTimes& times) {
  const int64_t id = links_.journal.segment_id(index, step, times.start_s);
  if (id == 0) return;
  links_.journal.keep_segment(segment_record(id, current_run_id(), index, step, times, "running"));
  links_.journal.record_unrecorded();
}

void RunLifecycle::on_step_finished(std::size_t index, const schedules::PlanStep& step,
                                    const schedules::StepTimes& times, bool completed) {
  const int64_t run_id = current_run_id();
  const int64_t id = links_.journal.segment_id(index, step, times.start_s);
  if (id == 0) return;
  // A soak's samples are committed before the step is recorded finished: a
  // crash after this never leaves a finished soak without its tail.
  if (completed && step.kind == schedules::StepKind::kSoak) {
    if (Status st = links_.writer.flush(); !st) {
      spdlog::error("run {}: the samples of step {} not committed at its end: {}", run_id,
                    index + 1, st.error().message);
    }
  }
  links_.journal.keep_segment(
      segment_record(id, run_id, index, step, times, completed ? "completed" : "aborted"));
  if (!times.acquire_stop.empty()) {
    const std::string message =
        fmt::format("{} (step {}): acquisition ended after {:.1f} min: {}", step.label, index + 1,
                    times.acquired_s() / 60.0, times.acquire_stop);
    spdlog::info("run {}: {}", run_id, message);
    links_.journal.add_event("acquisition", "", "", message);
  }
  links_.journal.record_unrecorded();
  // Table I is of static soaks only: a soak with the table spinning is not
  // a zero-bias measurement.
  if (completed && step.kind == schedules::StepKind::kSoak &&
      step.table.mode != schedules::TableDemandMode::kRate && !times.windows.empty()) {
    calibration::Table1Job job{run_id,
                               id,
                               static_cast<int>(index),
                               step.setpoint_c,
                               times.windows.front().from_s,
                               times.windows.back().to_s,
                               {}};
    for (const auto& w : times.windows) job.windows.emplace_back(w.from_s, w.to_s);
    links_.analysis.submit(std::move(job));
  }
}

// ---------------------------------------------------------------- run controls

Reply RunLifecycle::control(std::string_view action, const std::string& reason) {
  const bool running = sequencer_ && !sequencer_->finished();
  if (action == "pause") {
    if (!running) return Reply::refused(Refusal::Kind::kConflict, "no run in progress to pause");
    if (auto st = sequencer_->pause(run_time_s(), reason); !st) {
      return Reply::refused(Refusal::Kind::kConflict, st.error().message);
    }
    checkpoint(true);
    return Reply::ok({{"ok", true},
                      {"message", fmt::format("run {} paused; set point held at {:.2f} °C",
                                              current_run_id(), sequencer_->setpoint_c())}});
  }
  if (action == "resume") {
    std::vector<std::string> done;
    if (running && sequencer_->paused()) {
      if (auto st = sequencer_->resume(run_time_s(), reason); !st) {
        return Reply::refused(Refusal::Kind::kConflict, st.error().message);
      }
      checkpoint(true);
      done.push_back(fmt::format("run {} resumed", current_run_id()));
    }
    if (hold_reason_) {
      release_queue();
      done.push_back("queue released");
    }
    if (done.empty()) {
      return Reply::refused(Refusal::Kind::kConflict,
                            "nothing is paused and the queue is not held");
    }
    std::string message = done[0];
    if (done.size() > 1) message += "; " + done[1];
    return Reply::ok({{"ok", true}, {"message", message}});
  }
  if (action == "abort") {
    if (!running) return Reply::refused(Refusal::Kind::kConflict, "no run in progress to abort");
    if (sequencer_->state() == RunState::kAborting) {
      return Reply::refused(Refusal::Kind::kConflict, "the run is already aborting");
    }
    sequencer_->abort(run_time_s(), "aborted by the operator (" + reason + ")");
    hold_queue(
        fmt::format("run {} aborted by the operator; resume releases the queue", current_run_id()));
    checkpoint(true);
    return Reply::ok(
        {{"ok", true},
         {"message", fmt::format("run {} aborting; chamber to the safe set point {:g} °C",
                                 current_run_id(), links_.config.station.safe_setpoint_c)}});
  }
  if (action == "stop") {
    if (running) {
      stop_after_current_ = true;
      stop_reason_ = reason;
      const std::string message =
          fmt::format("the queue holds after run {} completes ({})", current_run_id(), reason);
      links_.journal.add_event("operator", "", "", message);
      spdlog::info("{}", message);
      return Reply::ok({{"ok", true}, {"message", message}});
    }
    if (hold_reason_) return Reply::refused(Refusal::Kind::kConflict, "the queue is already held");
    hold_queue("stopped by the operator (" + reason + "); resume releases the queue");
    return Reply::ok({{"ok", true}, {"message", "queue held"}});
  }
  return Reply::refused(Refusal::Kind::kNotFound, fmt::format("no control action '{}'", action));
}

}  // namespace gyrotherm::station

// RunLifecycle: a run from the queue entry it starts from to its end. It
// takes the next queued entry when the station is idle (or, at start-up,
// resumes the run a crash or a stop interrupted, or closes it), owns the
// run's sequencer and drives it each control tick together with the rate
// table and the chamber's set point, writes the run's checkpoint, hears the
// sequencer (state changes, steps, interlocks: events, segments, Table I
// jobs), answers the operator's run controls (pause, resume, abort, stop),
// holds and releases the queue, and ends the run (safe states, its last
// samples, the queue's answer, its analysis).
//
// Threads and locking: everything runs with the station's run lock held
// (the Station's run_mu_), on the control thread, or on the thread that
// starts or stops the station, or on the HTTP thread for control(). The
// run's and the queue's figures go to the snapshot under the station's
// status lock (Links::status_mu, the Station's mu_), taken last. The queue
// counters other threads read (Links::queue_length, queue_held, busy) are
// atomics; the waiting count changes only by read-modify-write.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>

#include "acquire_watch.h"
#include "gyrotherm/calibration/analysis_worker.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/schedules/progress.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/station/control.h"
#include "gyrotherm/station/run_clock.h"
#include "gyrotherm/station/status.h"
#include "gyrotherm/station/table_control.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "settle_watch.h"

namespace gyrotherm::station {

class DutAcquisition;
class EventJournal;
class PlantIo;

class RunLifecycle final : private schedules::SequencerObserver {
 public:
  // What the run shares with the rest of the station.
  struct Links {
    const config::StationConfig& config;
    const Clock& clock;  // station time: the run's time
    const WallClock& wall;
    // The control thread's connection (the run lock).
    storage::Database& db;
    storage::SampleSink& writer;
    calibration::AnalysisWorker& analysis;
    PlantIo& plant;
    DutAcquisition& duts;
    TableControl* table;  // nullptr: no table
    EventJournal& journal;
    // The run's id and start, for the DUTs' readers and the events.
    RunClock& run_clock;
    // State changes, live (StationHooks::publish); may be empty.
    std::function<void(std::string_view event, const nlohmann::json& data)> publish;
    // The queue's waiting entries and hold, and whether a run is taken and
    // not over: read by the HTTP thread (StationQueries, Station::idle()).
    std::atomic<int>& queue_length;
    std::atomic<bool>& queue_held;
    std::atomic<bool>& busy;
    // The control ticks counted by the station: a set point is written at
    // most once in each (PlantIo::write_setpoint).
    const uint64_t& control_ticks;
    // The station's status lock and the snapshot it guards.
    std::mutex& status_mu;
    StatusSnapshot& snapshot;
  };

  explicit RunLifecycle(Links links);

  // At start(), before any other thread changes the queue: the queue's hold
  // as the database keeps it, the waiting entries counted, the interrupted
  // run resumed (or closed), and the completed runs whose analysis never
  // ran analysed now.
  void recover();

  // A run's sequencer exists (from its start to its end).
  bool active() const { return sequencer_ != nullptr; }
  int64_t current_run_id() const { return links_.run_clock.load().run_id; }
  // Station seconds since the current run's start.
  double run_time_s() const;

  // Idle: starts the next queued entry's run, unless the queue is held or
  // empty.
  void start_next_run(double now_s);
  // A control tick of the active run: the table tended and driven, the
  // sequencer's tick, the chamber's set point, the table's and the
  // temperatures' samples, the checkpoint. Returns the run's time.
  double tick(double now_s, const schedules::Readings& r);
  // Ends the run once its sequencer has finished (after the tick's status).
  void end_if_finished();
  // The daemon stops: a run in progress is interrupted, checkpointed and ended.
  void interrupt(const std::string& reason);

  // The run's and the queue's figures of the status (the status lock held).
  void fill_status(StatusSnapshot& s) const;
  // The run's and the queue's progress now (docs/schedules.md).
  Progress progress(double t_run_s);

  // The operator's run controls: pause, resume, abort, stop. Refused with
  // kNotFound for any other action.
  Reply control(std::string_view action, const std::string& reason);
  // A run in progress is paused (for the table reset's answer).
  bool paused() const { return sequencer_ && !sequencer_->finished() && sequencer_->paused(); }

 private:
  void make_sequencer(schedules::Plan plan);
  // The snapshot's run fields, for the run `run_id` now taken.
  void show_run(int64_t run_id, const std::string& schedule_name,
                const storage::RunMetadata& metadata);
  void end_run();
  void checkpoint(bool force);
  // The sequencer's tick, with the segments it ends and starts written in
  // one transaction with the checkpoint that says so.
  void tick_sequencer(double t_run_s, const schedules::Readings& r);
  // Hands the tick's shell temperature to the settle watch while a soak
  // waits for its gate.
  void watch_settle(double t_run_s, const schedules::Readings& r);
  // An adaptive soak acquiring: its gated axes judged (AcquireWatch) before
  // the sequencer's tick, which may end the soak on the judgement.
  void watch_acquisition(double t_run_s);
  void note_samples_not_committed(int64_t run_id, schedules::RunState final_state, const Error& e);
  void answer_failed_run();
  void hold_queue(const std::string& reason);
  void release_queue();
  void count_queue();
  void submit_missing_analyses();

  // Resuming at start-up (recover()), in its steps.
  void resume_interrupted_run();
  // Where an interrupted run resumes, read from its checkpoint and its
  // stored samples; an error says why it cannot.
  struct ResumePoint;
  Result<ResumePoint> resume_point(const storage::RunRecord& run);
  // The run's segment rows by step, those that died with the daemon
  // closed; whether the checkpointed step had ended already.
  std::vector<int64_t> reopen_segments(const storage::RunRecord& run, ResumePoint& at);

  // A run's table, before the sequencer's tick: an interruption holds the
  // acquisition (and pauses the run unless [table] respin_after_fault); a
  // latched fault holding the run is reset.
  void tend_table(double t_run_s);
  // The table's demand now: the step's, or at rest while the run is held
  // (paused, an interlock tripped) or aborting.
  schedules::TableDemand table_demand() const;
  // The table driven to the demand (or brought to rest), after the tick.
  void drive_table();

  // SequencerObserver
  void on_state(schedules::RunState from, schedules::RunState to, double t_s,
                const std::string& reason) override;
  void on_step_started(std::size_t index, const schedules::PlanStep& step, double t_s) override;
  void on_step_changed(std::size_t index, const schedules::PlanStep& step,
                       const schedules::StepTimes& times) override;
  void on_interlock(schedules::InterlockKind kind, bool tripped, double t_s,
                    const std::string& message) override;
  void on_step_finished(std::size_t index, const schedules::PlanStep& step,
                        const schedules::StepTimes& times, bool completed) override;

  Links links_;

  std::unique_ptr<schedules::Sequencer> sequencer_;
  std::optional<storage::QueueEntry> entry_;  // the queue entry being run
  std::string last_reason_;                   // of the last state change
  bool stop_after_current_ = false;
  bool queue_answered_ = false;             // answer_failed_run() spoke for the current run
  std::string stop_reason_;                 // the operator's, for the hold message
  std::optional<std::string> hold_reason_;  // queue held
  std::string checkpoint_state_;
  double last_checkpoint_wall_s_ = -1e9;
  bool checkpoint_failing_ = false;
  // The queued entries' planned durations for the status's progress: read
  // again when their count changed, otherwise every few wall seconds.
  schedules::QueueDurations queue_durations_;
  schedules::PlannedDuration queue_planned_;
  int queue_scanned_length_ = -1;
  double queue_scan_due_wall_s_ = 0;
  // The station's past settles, read with the queue (schedules::settle_prior).
  std::optional<schedules::SettlePrior> settle_prior_;
  // The forecast of the current soak's settle, for the progress.
  SettleWatch settle_watch_;
  AcquireWatch acquire_watch_;
};

}  // namespace gyrotherm::station

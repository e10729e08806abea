// Station: the daemon's wiring of devices, sequencer, storage and analysis.
//
// Threads: the control loop (Modbus polling, sequencer ticks, set point
// writes, temperature samples) runs on its own thread at one tick per
// [control] tick_s of station time; the GyroReader thread timestamps and
// hands samples to the SampleWriter; the writer commits on its thread; the
// AnalysisWorker computes Table I rows when soaks end. status() is
// thread-safe and cheap (the HTTP thread calls it).
//
// Device errors after start-up are counted, logged on change and reported
// in status(); they never stop the daemon.
#pragma once

#include <atomic>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/analysis/stability.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/daemon/analysis_worker.h"
#include "gyrotherm/daemon/config.h"
#include "gyrotherm/daemon/status.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/modbus_device.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm::daemon {

class Station final : private schedules::SequencerObserver {
 public:
  // Opens the database (creating/migrating it), the sample writer and the
  // devices' clients. Fails (permanent) when the database cannot be opened;
  // unreachable devices are not an error here (they are retried).
  static Result<std::unique_ptr<Station>> create(StationConfig config, const Clock& clock);
  ~Station() override;

  // Starts the gyro reader and the control loop.
  void start();
  // Interrupts a run in progress (its state becomes "interrupted"), drives
  // the chamber to the safe set point, commits everything and joins the
  // threads. Idempotent.
  void stop(const std::string& reason);

  // Queues a validated plan; runs start in order when the station is idle.
  void enqueue(schedules::Plan plan);
  schedules::StationLimits limits() const;

  StatusSnapshot status() const;
  // True when no run is active and nothing is queued.
  bool idle() const;
  const StationConfig& config() const { return config_; }

 private:
  Station(StationConfig config, const Clock& clock, storage::Database db,
          std::unique_ptr<storage::SampleWriter> writer);

  void control_loop();
  void tick();
  void start_run(schedules::Plan plan, double now_s);
  void end_run();
  void write_setpoint(double setpoint_c, bool force);
  void on_gyro_samples(std::span<const GyroSample> samples);
  void add_event(const std::string& kind, const std::string& from, const std::string& to,
                 const std::string& message);

  // SequencerObserver
  void on_state(schedules::RunState from, schedules::RunState to, double t_s,
                const std::string& reason) override;
  void on_step_started(std::size_t index, const schedules::PlanStep& step, double t_s) override;
  void on_acquisition_started(std::size_t index, const schedules::StepTimes& times) override;
  void on_step_finished(std::size_t index, const schedules::PlanStep& step,
                        const schedules::StepTimes& times, bool completed) override;

  StationConfig config_;
  const Clock& clock_;
  storage::Database db_;  // control-thread connection
  std::unique_ptr<storage::SampleWriter> writer_;
  std::unique_ptr<AnalysisWorker> analysis_;
  std::unique_ptr<drivers::ModbusDevice> chamber_;
  std::unique_ptr<drivers::ModbusDevice> probes_;
  std::unique_ptr<drivers::GyroReader> gyro_;
  const double started_wall_s_;

  // Control-thread state.
  std::unique_ptr<schedules::Sequencer> sequencer_;
  std::vector<int64_t> segment_ids_;
  std::optional<double> last_written_setpoint_c_;
  int ticks_since_setpoint_write_ = 0;
  bool chamber_ok_ = true, probes_ok_ = true;
  analysis::StabilityWindow shell_rate_window_{60.0};

  // Shared with the gyro reader thread.
  std::atomic<int64_t> run_id_{0};  // 0: no run
  std::atomic<double> run_t0_s_{0};
  // A plan has been taken from pending_ and its run is not over.
  std::atomic<bool> busy_{false};

  mutable std::mutex mu_;  // guards the fields below
  std::deque<schedules::Plan> pending_;
  StatusSnapshot snapshot_;
  double gyro_window_start_s_ = -1;
  double gyro_window_sum_ = 0;
  int64_t gyro_window_n_ = 0;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread control_thread_;
};

}  // namespace gyrotherm::daemon

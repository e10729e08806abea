// Station: the daemon's wiring of devices, queue, sequencer, storage and
// analysis, and its control loop. Each part is a room of its own, which
// the station makes, links and ticks:
//   PlantIo         (src/plant_io.h)        the chamber and shell probes
//   DutAcquisition  (src/dut_acquisition.h) the DUTs, their readers to the writer
//   TableControl    (table_control.h)       the rate table's safe states
//   EventJournal    (src/event_journal.h)   events, run states, segments
//   RunLifecycle    (src/run_lifecycle.h)   a run from its queue entry to
//                                           its end; the queue's hold
//   StationQueries  (station_queries.h)     the reads and queue edits of
//                                           the control interface
//
// Threads: the control loop (device polling, the run's tick, the status)
// runs on its own thread at one tick per [control] tick_s of station time;
// each DUT's reader thread timestamps and hands frames to the SampleWriter;
// the writer commits on its thread; the AnalysisWorker computes Table I
// rows when soaks end. The HTTP thread calls status() (a copy of the
// snapshot the control loop keeps) and the StationControl methods.
//
// The queue lives in the database (storage::Database queue_*), so it
// survives restarts; whether it is held (after `stop`, an abort or a failed
// run) is the meta key 'queue_hold'. A run's sequencer snapshot is written
// with the run about once a wall second; start() resumes the run a crash or
// a stop interrupted (Sequencer::restore), with the downtime converted to
// station time by the time scale.
//
// Locking: run_mu_ guards the run (RunLifecycle), the journal, the
// control-thread database connection and the control tick count;
// StationQueries' lock its connection; mu_ guards the status snapshot.
// Order: run_mu_, the queries' lock, mu_. DutAcquisition has its own locks
// (its header); its status figures are under mu_ too. The run's id and
// start time go to the gyro reader together (RunClock). The count of
// waiting queue entries changes only by read-modify-write, by the thread
// that changed the queue in the database (HTTP: add, remove; control:
// start), never by storing a count read earlier.
//
// Device errors after start-up are counted, logged on change and reported
// in status(); they never stop the daemon.
#pragma once

#include <atomic>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/analysis/stability.h"
#include "gyrotherm/calibration/analysis_worker.h"
#include "gyrotherm/calibration/exporter.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/station/control.h"
#include "gyrotherm/station/run_clock.h"
#include "gyrotherm/station/station_queries.h"
#include "gyrotherm/station/status.h"
#include "gyrotherm/station/table_control.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm {
class PacedClock;
}

namespace gyrotherm::station {

class DutAcquisition;
class EventJournal;
class PlantIo;
class RunLifecycle;

// What the station tells the rest of the daemon; each optional.
struct StationHooks {
  // Latencies as they happen, for the metrics' histograms: each Modbus
  // request (device "chamber" or "probes") and each database commit, in
  // seconds. Called from the control and writer threads; thread-safe.
  std::function<void(std::string_view device, double seconds)> observe_modbus;
  std::function<void(double seconds)> observe_commit;
  // Live events for /api/v1/stream: "state", "event", "stats" with their
  // JSON. Called from the control and analysis threads; must not block.
  std::function<void(std::string_view event, const nlohmann::json& data)> publish;
  // The lab relay's state for the status (docs/lab.md); unset or nullopt:
  // the station has no [lab]. Called by status(); thread-safe, must not block.
  std::function<std::optional<lab::RelayStatus>()> lab_status;
};

// The station's devices, owned by the station. devices_from_config() builds
// the real ones; tests hand fakes.
struct StationDevices {
  std::unique_ptr<drivers::Chamber> chamber;
  std::unique_ptr<drivers::ShellProbes> probes;
  // One source per [[dut]], in config order.
  std::vector<std::unique_ptr<drivers::DutSource>> duts;
  // Per-DUT shell probes, by DUT index ([[dut]] probes); missing = none.
  std::vector<std::unique_ptr<drivers::ShellProbes>> dut_probes;
  // The rate table; nullptr when the config has no [table].
  std::unique_ptr<drivers::RateTable> table;
};

// The devices a station config names: its chamber and probe module over
// Modbus, each DUT on its serial line (timestamped on `clock`), the DUTs'
// own probes and, with a [table], its rate table. Request
// latencies go to hooks.observe_modbus. Permanent error for an unknown gyro
// protocol (the config loader has checked it).
Result<StationDevices> devices_from_config(const config::StationConfig& config, const Clock& clock,
                                           const StationHooks& hooks = {});

// The clocks the station reads (not owned; they outlive it).
struct StationClocks {
  const Clock& station;  // station time: the control loop, runs, samples
  // Wall time: event and run stamps (storage included), checkpoint times and
  // a run's downtime across a restart, device silence in wall seconds.
  const WallClock& wall = system_wall_clock();
  // The nightly export's wall clock when it is simulated (gyrothermd
  // --wall-start); nullptr: `wall`.
  const WallClock* nightly = nullptr;
};

class Station final : public StationControl {
 public:
  // Opens the database (creating/migrating it) and the sample writer, and
  // takes the devices (all three are needed). Fails (permanent) when the
  // database cannot be opened; unreachable devices are not an error here
  // (they are retried).
  // `samples`: where samples go; nullptr (the daemon): a SampleWriter on
  // the config's database.
  static Result<std::unique_ptr<Station>> create(
      config::StationConfig config, StationDevices devices, StationClocks clocks,
      StationHooks hooks = {}, std::unique_ptr<storage::SampleSink> samples = nullptr);
  ~Station() override;

  // Resumes an interrupted run (or closes it), starts the gyro source, the
  // nightly export and, with kOwnThread, the control loop: one tick() per
  // [control] tick_s of station time. kCaller: whoever started the station
  // calls tick() (the unit tests, stepping a manual clock).
  enum class ControlLoop { kOwnThread, kCaller };
  void start(ControlLoop loop = ControlLoop::kOwnThread);
  // One control tick: reads the devices, claims the next queue entry when
  // idle, advances the run's sequencer, writes the set point, records the
  // temperatures and the checkpoint. Only from the control loop's thread
  // (or, with ControlLoop::kCaller, one caller at a time).
  void tick();
  // Interrupts a run in progress (its state becomes "interrupted"), drives
  // the chamber to the safe set point, commits everything and joins the
  // threads. Idempotent.
  void stop(const std::string& reason);

  StatusSnapshot status() const;
  // An event from another part of the daemon (the lab relay: kind "lab"):
  // thread-safe, never blocks; recorded (events table, stream) by the
  // control loop at its next tick, under the run in progress if any.
  void post_event(const std::string& kind, const std::string& message);
  // True when no run is active and nothing will start by itself (the queue
  // is empty or held).
  bool idle() const;
  const config::StationConfig& config() const { return config_; }
  // Counts the control loop's ticks (one per [control] tick_s of station
  // time): the service watchdog's liveness check.
  uint64_t heartbeat() const { return heartbeat_.load(std::memory_order_relaxed); }

  // StationControl (thread-safe).
  Reply queue_list() override;
  Reply queue_add(const std::string& toml_text, const std::string& source,
                  bool ignore_failures) override;
  Reply queue_remove(int64_t id) override;
  Reply queue_move(int64_t id, int position) override;
  Reply control(std::string_view action, const std::string& reason) override;
  Reply runs() override;
  Reply run(int64_t id) override;
  Reply run_events(int64_t id) override;
  Reply run_stats(int64_t id) override;
  Reply run_samples(int64_t id, const SamplesQuery& query) override;
  Reply run_fits(int64_t id) override;
  Reply run_allan(int64_t id) override;
  Reply run_scale_factor(int64_t id) override;
  Reply fit(int64_t id) override;
  Reply exports() override;
  // Run metadata and DUT history (the end of station.cpp).
  Reply enqueue(const QueueRequest& request) override;
  Reply run_with_duts(int64_t id) override;
  Reply edit_run(int64_t id, const MetadataEdit& edit, const std::string& changed_by) override;
  Reply run_stats_filtered(int64_t id, const StatsQuery& query) override;
  Reply run_channel_samples(int64_t id, const SamplesQuery& query) override;
  Reply duts() override;
  Reply dut_history(const std::string& serial) override;

 private:
  Station(config::StationConfig config, StationDevices devices, StationClocks clocks,
          StationHooks hooks, storage::Database db, storage::Database api_db,
          std::unique_ptr<storage::SampleSink> writer);

  void control_loop();
  void paced_control_loop(const PacedClock& clock);
  schedules::Readings read_devices(double now_s);
  // The tick's figures in the status: the devices', the run's and the queue's.
  void publish_status(double now_s, double t_run_s, const schedules::Readings& r);
  void start_nightly_export();
  void note_storage_file();
  // Idle: the table's safe state once, and the safe set point until the
  // chamber takes it (PlantIo::keep_safe).
  void keep_idle_safe();
  // Stops the table (the safe state's first move) and waits, a bounded wall
  // time, for it to come to rest and open its interlock: at shutdown, when
  // no control loop is left to finish the safe state.
  void make_table_safe_now();
  // The operator's table-reset (run_mu_ held).
  Reply reset_table_faults(const std::string& reason);

  config::StationConfig config_;
  const Clock& clock_;
  const WallClock& wall_;
  const WallClock& nightly_wall_;
  StationHooks hooks_;
  std::mutex run_mu_;
  storage::Database db_;  // control-thread connection (run_mu_)
  std::unique_ptr<storage::SampleSink> writer_;
  std::unique_ptr<calibration::AnalysisWorker> analysis_;
  std::unique_ptr<calibration::NightlyExporter> nightly_;  // [export] nightly
  // The chamber and shell probes (readings, set point, health); made in
  // the constructor.
  std::unique_ptr<PlantIo> plant_;
  // The DUTs (their frames, coverage, status figures and probes); made in
  // the constructor.
  std::unique_ptr<DutAcquisition> duts_;
  std::unique_ptr<drivers::RateTable> table_device_;
  std::unique_ptr<TableControl> table_;  // nullptr: no table
  const double started_wall_s_;          // wall_.monotonic_s() at create()

  // Control ticks (and the stop) counted, so a set point is written at most
  // once in each (PlantIo::write_setpoint). run_mu_.
  uint64_t control_ticks_ = 0;
  // Events, the run's state and its segment records (and what the
  // database refused of them); made in the constructor.
  std::unique_ptr<EventJournal> journal_;
  // The run: start, resume, ticks, checkpoints, controls, end; the queue's
  // hold (run_mu_); made in the constructor.
  std::unique_ptr<RunLifecycle> run_;

  // Control-thread only.
  // Station and wall time of the last moment the sample writer's commits
  // were not failing.
  double storage_ok_s_ = 0, storage_ok_wall_s_ = 0;
  // The database file deleted or replaced (Database::check_file): what
  // happened; storage fails until a restart. Reported once; its WAL released.
  std::optional<std::string> storage_file_error_;
  bool storage_file_reported_ = false, storage_file_released_ = false;
  analysis::StabilityWindow shell_rate_window_{60.0};
  std::atomic<int> queue_length_{0};
  std::atomic<bool> queue_held_{false};
  std::atomic<uint64_t> heartbeat_{0};

  // Shared with the gyro reader thread.
  RunClock run_clock_;
  // A plan has been taken from pending_ and its run is not over.
  std::atomic<bool> busy_{false};

  mutable std::mutex mu_;  // guards the fields below
  StatusSnapshot snapshot_;
  std::condition_variable wake_;
  bool stopping_ = false;
  std::thread control_thread_;

  // Last: its links refer to the queue counters, wake_, mu_ and snapshot_.
  StationQueries queries_;
};

}  // namespace gyrotherm::station

// DutAcquisition: the station's DUTs, from their sources to the writer. It
// owns each DUT's source and own probes and what the station knows of them
// live (DutLive): the frames each reader thread hands over, stamped with the
// run and handed to the sample writer; the run seconds they cover, for the
// soaks' data accounting; their silence, for the gyro_lost interlock; their
// figures in the status; their registration in a run; and their probes,
// read once a control tick.
//
// Threads: on_dut_frames() runs on each DUT's reader thread; await_gyro() on
// the control or the analysis thread; the rest on the control thread (or,
// before start() and after stop(), on the thread that made the station).
//
// Locking, per DUT: layout_mu its run layouts, coverage_mu its coverage;
// handed_mu_ (this class's) every DUT's last batch handed to the writer. The
// status figures and the snapshot they go to are under the station's status
// lock (Links::status_mu, the Station's mu_). The database connection the
// registration and the coverage's read-back use is passed in by the caller,
// who holds the run lock (the Station's run_mu_) for it. Order: the run
// clock's lock, then layout_mu, coverage_mu or handed_mu_ (one at a time),
// then the status lock; layout_mu, then an event's locks (Links::add_event).
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/schedules/coverage.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/station/run_clock.h"
#include "gyrotherm/station/status.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm::station {

// How long (wall) a soak's Table I and a completed run's end wait for the
// gyro samples of their last station seconds to come off the line
// (DutAcquisition::await_gyro).
inline constexpr std::chrono::milliseconds kAwaitGyro{2000};

// How a DUT is named in messages: its serial, or its position when unnamed.
std::string dut_name(const config::DutSection& dut);

class DutAcquisition {
 public:
  // What the acquisition shares with the rest of the station.
  struct Links {
    const Clock& clock;  // station time: frames' arrival
    const WallClock& wall;
    // The current run, published by the control thread (start_next_run).
    RunClock& run_clock;
    storage::SampleSink& writer;
    // The station's status lock and the snapshot it guards: the DUTs'
    // status figures are under it too.
    std::mutex& status_mu;
    StatusSnapshot& snapshot;
    // An event in the journal, now (control thread, the run lock held).
    std::function<void(const std::string& kind, const std::string& message)> add_event;
    // An event recorded by the control loop at its next tick (thread-safe).
    std::function<void(const std::string& kind, const std::string& message)> post_event;
  };

  // One source per [[dut]] of `config` (which must outlive this), in config
  // order; `probes`, by DUT index, its own probes (missing or nullptr:
  // none). Publishes each DUT's status.
  DutAcquisition(const config::StationConfig& config,
                 std::vector<std::unique_ptr<drivers::DutSource>> sources,
                 std::vector<std::unique_ptr<drivers::ShellProbes>> probes, Links links);

  // At start(): every DUT counts as heard at `now_s` (wall `wall_s`), and
  // its own probes connect.
  void prepare(double now_s, double wall_s);
  // The sources' reader threads start (their frames: on_dut_frames) and stop.
  void start_sources();
  void stop_sources();

  // Each DUT's silence in the readings (read_devices): `silent(since_s,
  // since_wall_s)` is the silence in station time of a stream last heard
  // then. A DUT that is not required is marked lost (and found) here.
  void read_silence(schedules::Readings& r,
                    const std::function<double(double since_s, double since_wall_s)>& silent);
  // The sources' health into the status (the first's is "the gyro").
  void add_health(StatusSnapshot& s) const;

  // The soak's data accounting (schedules::Readings::data_covered_s and
  // data_reached_at_s) over the DUTs of the current run; run seconds.
  double data_covered_s(double from_s, double to_s);
  std::optional<double> data_reached_at_s(double from_s, double need_s);
  // A step started at `t_s`: the coverage (and the 1 s means) before it are
  // forgotten.
  void forget_coverage_before(double t_s);
  // The 1 s means (run seconds, whole seconds from the run's start) of each
  // rate axis of the DUTs of the current run that are required and not lost,
  // inside `windows` (from_s, to_s): the adaptive soaks' data (AcquireWatch).
  struct AxisSeconds {
    std::string name;  // "<serial> <axis>"
    std::vector<double> rate_dph;
  };
  std::vector<AxisSeconds> gated_seconds(std::span<const std::pair<double, double>> windows);
  // After a restart: each DUT's coverage of the run from `from_s` on, read
  // back from its committed samples (`db`: the run lock's connection).
  void seed_coverage(storage::Database& db, int64_t run_id, double from_s);
  // Registers every DUT in run `run_id` (run_duts, channels): before the
  // run's clock is published, so no frame comes under a run without its DUTs.
  // Registers in the run the DUTs `serials` names (empty: every one).
  void register_run_duts(storage::Database& db, int64_t run_id,
                         const std::vector<std::string>& serials);
  // Reads them without run_mu_; the events to record (kind "device") are
  // returned for the caller to add under run_mu_.
  std::vector<std::string> read_dut_probes(double now_s);
  // Waits, up to `max_wait` (wall), until every DUT's frames of `run_id` up to
  // `until_s` (run seconds) have been handed to the writer. False on timeout.
  bool await_gyro(int64_t run_id, double until_s, std::chrono::milliseconds max_wait);

 private:
  // One DUT: its source, its own probes, what the status shows of it, and
  // its registration in the current run.
  struct DutLive {
    std::size_t index = 0;
    const config::DutSection* cfg = nullptr;  // config_.duts[index]
    std::unique_ptr<drivers::DutSource> source;
    std::unique_ptr<drivers::ShellProbes> probes;  // nullptr: none of its own
    bool probes_failing = false;                   // control thread: said in the events
    std::vector<std::size_t> rate_channels;        // raw[] indices of its rate axes
    int primary_channel = -1, temp_channel = -1;
    std::atomic<double> last_s{0};  // station time of the last frame
    std::atomic<double> last_wall_s{0};
    // A frame has arrived since start(): only then can a gyro_lost trip
    // restored from a checkpoint clear.
    std::atomic<bool> heard{false};
    // Not required and silent past its timeout: left out of the gyro_lost
    // interlock and of the soaks' data accounting until it speaks again.
    std::atomic<bool> lost{false};
    // Recorded in the current run: the run's entry named it (`queue add
    // --dut`) or named none. One that is not is left out of the run's
    // storage, its soaks' data accounting and the gyro_lost interlock.
    std::atomic<bool> in_run{true};
    // The DUT in the current run (Database::add_run_dut), set by the control
    // thread before the run's clock is published; the frames' channels, and
    // apart the channels of its own probes (probe_top_c, probe_side_c).
    std::mutex layout_mu;
    std::shared_ptr<const storage::RunDutRecord> layout, probe_layout;
    // coverage_mu: the run seconds its frames handed to the writer cover in
    // run coverage_run_id (a soak is credited for those, not for the clock).
    std::mutex coverage_mu;
    int64_t coverage_run_id = 0;
    std::optional<schedules::CoverageSpans> coverage;
    // bins_mu: the run's 1 s means per rate axis from the current step's
    // start (gated_seconds): bin_t_s the whole run second each starts at;
    // the open second's sums apart.
    std::mutex bins_mu;
    int64_t bins_run_id = 0;
    std::vector<double> bin_t_s;
    std::vector<std::vector<double>> bin_mean_dph;  // per rate axis; NaN: no value that second
    double bin_open_s = -1;
    std::vector<double> bin_sum;
    std::vector<int64_t> bin_n;
    // handed_mu_:
    int64_t handed_run_id = 0;
    double handed_until_s = 0;
    // The status lock (Links::status_mu): the status figures, means over
    // whole station seconds.
    double window_start_s = -1;
    std::vector<double> window_sum;
    std::vector<int64_t> window_n;
    int64_t window_frames = 0;
    std::vector<std::optional<double>> rates_dph;
    std::optional<double> temp_c;
    double samples_per_s = 0;
  };
  void on_dut_frames(DutLive& dut, std::span<const DutFrame> frames);
  // The run's frames (run seconds) into the DUT's 1 s means.
  void bin_seconds(DutLive& dut, int64_t run_id, std::span<const DutFrame> rel);
  void publish_dut_status(const DutLive& dut);

  const config::StationConfig& config_;
  Links links_;
  std::vector<std::unique_ptr<DutLive>> duts_;  // by [[dut]] index
  // Each DUT's last batch handed to the writer: run and run time of its
  // last frame (DutLive::handed_*, under handed_mu_; await_gyro).
  std::mutex handed_mu_;
  std::condition_variable handed_cv_;
};

}  // namespace gyrotherm::station

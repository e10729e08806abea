#include "gyrotherm/station/station.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <sys/statvfs.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>

#include "dut_acquisition.h"
#include "event_journal.h"
#include "gyrotherm/calibration/run_analysis.h"
#include "gyrotherm/config/run_config.h"
#include "gyrotherm/core/paced_clock.h"
#include "gyrotherm/drivers/dut_link.h"
#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/modbus_devices.h"
#include "gyrotherm/drivers/rate_tables.h"
#include "plant_io.h"

namespace gyrotherm::station {
namespace {

using schedules::RunState;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// How long (wall) a soak's Table I and a completed run's end wait for the
// gyro samples of their last station seconds to come off the line.
constexpr std::chrono::milliseconds kAwaitGyro{2000};

}  // namespace

Result<StationDevices> devices_from_config(const config::StationConfig& config, const Clock& clock,
                                           const StationHooks& hooks) {
  auto chamber =
      std::make_unique<drivers::ModbusChamber>(config.chamber.endpoint, config.chamber.map);
  auto probes = std::make_unique<drivers::ModbusProbes>(config.probes.endpoint, config.probes.top,
                                                        config.probes.side);
  if (auto observe = hooks.observe_modbus) {
    chamber->set_latency_observer([observe](double s) { observe("chamber", s); });
    probes->set_latency_observer([observe](double s) { observe("probes", s); });
  }
  StationDevices devices;
  devices.chamber = std::move(chamber);
  devices.probes = std::move(probes);
  for (const config::DutSection& dut : config.duts) {
    auto source = drivers::make_dut_source(dut.link, clock);
    if (!source) {
      return Error::Permanent(fmt::format("DUT {}: {}", dut_name(dut), source.error().message));
    }
    devices.duts.push_back(std::move(*source));
    std::unique_ptr<drivers::ShellProbes> own;
    if (dut.probes) {
      drivers::RegisterSpec top = config.probes.top, side = config.probes.side;
      top.address = config.probes.top.address +
                    static_cast<uint16_t>(dut.probes->top_channel - config.probes.top_channel);
      side.address = config.probes.side.address +
                     static_cast<uint16_t>(dut.probes->side_channel - config.probes.side_channel);
      own = std::make_unique<drivers::ModbusProbes>(config.probes.endpoint, top, side);
    }
    devices.dut_probes.push_back(std::move(own));
  }
  if (config.table) {
    const drivers::TableLimits declared{config.table->max_rate_dps, config.table->max_accel_dps2,
                                        std::nullopt};
    auto table = drivers::make_rate_table(config.table->connection, declared, "table");
    if (!table) return table.error();
    devices.table = std::move(*table);
  }
  return devices;
}

Result<std::unique_ptr<Station>> Station::create(config::StationConfig config,
                                                 StationDevices devices, StationClocks clocks,
                                                 StationHooks hooks,
                                                 std::unique_ptr<storage::SampleSink> samples) {
  if (!devices.chamber || !devices.probes) {
    return Error::Permanent("station: a chamber and a probe module are needed");
  }
  if (config.duts.empty()) return Error::Permanent("station: the config names no DUT");
  // Checked here, before any run: a run's sequencer is made mid-way through
  // starting it, where a refusal could only fail the run.
  if (std::string why; !config::sequencer_options(config).is_valid(&why)) {
    return Error::Permanent("station: invalid sequencer options: " + why);
  }
  if (devices.duts.size() != config.duts.size()) {
    return Error::Permanent(fmt::format("station: {} DUT sources for {} [[dut]] entries",
                                        devices.duts.size(), config.duts.size()));
  }
  if (config.table.has_value() != (devices.table != nullptr)) {
    return Error::Permanent(config.table
                                ? "station: the config has a [table] but no table was given"
                                : "station: a table was given but the config has no [table]");
  }
  // The first connection checks the whole file before anything writes to it
  // (it reads it all: seconds per GB).
  const auto check_start = std::chrono::steady_clock::now();
  auto db =
      storage::Database::open(config.storage.db_path, clocks.wall, storage::OpenCheck::kQuick);
  if (!db) return db.error();
  spdlog::info(
      "database {}: PRAGMA quick_check ok ({:.1f} s)", config.storage.db_path,
      std::chrono::duration<double>(std::chrono::steady_clock::now() - check_start).count());
  auto api_db = storage::Database::open(config.storage.db_path, clocks.wall);
  if (!api_db) return api_db.error();
  if (!samples) {
    storage::SampleWriterOptions wopt;
    wopt.commit_interval =
        std::chrono::milliseconds(static_cast<int64_t>(config.storage.commit_interval_s * 1000));
    auto writer = storage::SampleWriter::start(config.storage.db_path, wopt, hooks.observe_commit);
    if (!writer) return writer.error();
    samples = std::move(*writer);
  }
  return std::unique_ptr<Station>(new Station(std::move(config), std::move(devices), clocks,
                                              std::move(hooks), std::move(*db), std::move(*api_db),
                                              std::move(samples)));
}

Station::Station(config::StationConfig config, StationDevices devices, StationClocks clocks,
                 StationHooks hooks, storage::Database db, storage::Database api_db,
                 std::unique_ptr<storage::SampleSink> writer)
    : config_(std::move(config)),
      clock_(clocks.station),
      wall_(clocks.wall),
      nightly_wall_(clocks.nightly ? *clocks.nightly : clocks.wall),
      hooks_(std::move(hooks)),
      db_(std::move(db)),
      writer_(std::move(writer)),
      table_device_(std::move(devices.table)),
      started_wall_s_(wall_.monotonic_s()),
      queries_(config_, std::move(api_db),
               StationQueries::Links{queue_length_, queue_held_, [this] { wake_.notify_all(); },
                                     [this](int64_t run_id, const storage::RunMetadata& metadata) {
                                       std::lock_guard lock(mu_);
                                       if (snapshot_.run_id != run_id) return;
                                       // The running run: the status shows the edit at once.
                                       snapshot_.run_operator = metadata.operator_name;
                                       snapshot_.run_comment = metadata.comment;
                                       snapshot_.run_tags = metadata.tags;
                                     }}) {
  journal_ = std::make_unique<EventJournal>(
      EventJournal::Links{clock_, wall_, run_clock_, db_, hooks_.publish, mu_, snapshot_,
                          [this] { return sequencer_ != nullptr; }});
  plant_ = std::make_unique<PlantIo>(
      std::move(devices.chamber), std::move(devices.probes),
      PlantIo::Links{clock_, mu_, snapshot_,
                     [this](const std::string& kind, const std::string& message) {
                       journal_->add_event(kind, "", "", message);
                     }});
  duts_ = std::make_unique<DutAcquisition>(
      config_, std::move(devices.duts), std::move(devices.dut_probes),
      DutAcquisition::Links{clock_, wall_, run_clock_, *writer_, mu_, snapshot_,
                            [this](const std::string& kind, const std::string& message) {
                              journal_->add_event(kind, "", "", message);
                            },
                            [this](const std::string& kind, const std::string& message) {
                              post_event(kind, message);
                            }});
  if (table_device_) table_ = std::make_unique<TableControl>(*table_device_, *config_.table);
  calibration::AnalysisWorker::Callbacks callbacks;
  callbacks.await_gyro = [this](int64_t run_id, double until_s) {
    if (!duts_->await_gyro(run_id, until_s, kAwaitGyro)) {
      spdlog::warn(
          "run {}: Table I computed without the gyro samples after t = {:.1f} s (the stream had "
          "not reached the soak's end after {} ms)",
          run_id, until_s, kAwaitGyro.count());
    }
  };
  callbacks.table1_done = [publish = hooks_.publish](const calibration::Table1Job& job,
                                                     const Result<storage::SegmentStatsRecord>& r) {
    if (r && publish) publish("stats", to_json(*r));
    if (r) {
      spdlog::info(
          "run {} segment {}: Table I row stored: n={} T={:.2f} °C bias={:.4f} °/h "
          "std={:.4f} std(MA{})={:.4f}",
          job.run_id, job.segment_index + 1, r->n, r->temp_mean_c, r->bias_mean_dph,
          r->bias_std_dph, r->ma_window, r->bias_std_ma_dph);
    } else {
      spdlog::error("Table I row not computed: {}", r.error().message);
    }
  };
  callbacks.run_done = [publish = hooks_.publish, &wall = wall_](
                           storage::Database& db, const calibration::RunJob& job,
                           const Result<calibration::RunAnalysisSummary>& r) {
    storage::EventRecord ev;
    ev.run_id = job.run_id;
    if (auto last = db.last_sample_t_s(job.run_id); last && *last) ev.t_s = **last;
    ev.wall_utc = utc_iso(wall);
    ev.kind = "analysis";
    if (r) {
      std::string fits;
      for (int64_t id : r->fit_ids) fits += fmt::format("{}#{}", fits.empty() ? "" : ", ", id);
      ev.message = fmt::format(
          "analysis stored: {} Table I row(s), {} Allan deviation(s), {} fit(s){}{}",
          r->table1_rows, r->allan_records, r->fit_ids.size(),
          fits.empty() ? "" : " (" + fits + ")", r->problems.empty() ? "" : "; not computed: ");
      for (std::size_t i = 0; i < r->problems.size(); ++i) {
        ev.message += (i ? "; " : "") + r->problems[i];
      }
      if (!r->flagged.empty()) ev.message += "; FLAGGED: ";
      for (std::size_t i = 0; i < r->flagged.size(); ++i) {
        ev.message += (i ? "; " : "") + r->flagged[i];
      }
    } else {
      ev.message = "analysis failed: " + r.error().message;
    }
    spdlog::info("run {}: {}", job.run_id, ev.message);
    if (auto id = db.add_event(ev); !id) {
      spdlog::error("event not recorded: {}", id.error().message);
    } else {
      ev.id = *id;
    }
    if (publish) {
      nlohmann::json j = to_json(ev);
      j["run_id"] = job.run_id;
      publish("event", j);
      if (r) {
        publish("analysis", {{"run_id", job.run_id},
                             {"table1_rows", r->table1_rows},
                             {"allan_records", r->allan_records},
                             {"fit_ids", r->fit_ids},
                             {"problems", r->problems},
                             {"flagged", r->flagged}});
      }
    }
  };
  analysis_ = std::make_unique<calibration::AnalysisWorker>(config_.storage.db_path, *writer_,
                                                            calibration::analysis_settings(config_),
                                                            std::move(callbacks), wall_);
  snapshot_.station_name = config_.station.name;
  snapshot_.time_scale = clock_.time_scale();
  snapshot_.clock = as_paced(clock_) ? "sim" : "scaled";
}

Station::~Station() { stop("daemon shutting down"); }

void Station::make_sequencer(schedules::Plan plan) {
  // Valid: Station::create checked them.
  sequencer_ =
      std::make_unique<schedules::Sequencer>(std::move(plan), config::sequencer_options(config_),
                                             static_cast<schedules::SequencerObserver&>(*this));
}

void Station::start(ControlLoop loop) {
  for (drivers::PolledDevice* dev : std::initializer_list<drivers::PolledDevice*>{
           &plant_->chamber(), &plant_->probes(), table_device_.get()}) {
    if (!dev) continue;
    if (auto st = dev->connect(); !st) {
      spdlog::warn("{}: {} (will keep retrying)", dev->name(), st.error().message);
    }
  }
  const double now_s = clock_.now_s();
  const double wall_s = wall_.monotonic_s();
  plant_->prepare(now_s, wall_s);
  storage_ok_s_ = now_s;
  storage_ok_wall_s_ = wall_s;
  duts_->prepare(now_s, wall_s);
  {
    std::lock_guard lock(run_mu_);
    if (auto hold = db_.meta(kQueueHoldKey); hold && *hold) {
      hold_reason_ = **hold;
      queue_held_.store(true);
      spdlog::info("queue held: {}", *hold_reason_);
    }
    count_queue();
    resume_interrupted_run();
    submit_missing_analyses();
  }
  duts_->start_sources();
  if (loop == ControlLoop::kOwnThread) control_thread_ = std::thread([this] { control_loop(); });
  start_nightly_export();
}

void Station::start_nightly_export() {
  const config::ExportSection& e = config_.export_;
  if (!e.nightly) return;
  calibration::NightlyOptions options;
  if (auto at = config::parse_local_time_of_day(e.local_time)) options.at = *at;  // checked at load
  if (!e.time_zone.empty()) {
    if (auto zone = config::TimeZone::posix(e.time_zone)) options.zone = *zone;
  }
  options.directory = e.directory;
  options.report.station_name = config_.station.name;
  const config::TimeZone zone = options.zone;
  const WallClock& wall = nightly_wall_;
  auto done = [publish = hooks_.publish, &stamp = wall_](
                  storage::Database& db, const Result<calibration::ExportOutcome>& r) {
    storage::EventRecord ev;
    ev.wall_utc = utc_iso(stamp);
    ev.kind = "export";
    if (r) {
      ev.message =
          r->files.empty()
              ? fmt::format("nightly export {}: no run completed since the last one", r->export_id)
              : fmt::format("nightly export {}: {} files in {}{}", r->export_id, r->files.size(),
                            r->directory,
                            r->problems.empty() ? "" : " (with problems; see the report)");
    } else {
      ev.kind = "error";
      ev.message = "nightly export failed: " + r.error().message;
    }
    if (auto id = db.add_event(ev); id) ev.id = *id;
    if (publish) {
      publish("event", to_json(ev));
      if (r) {
        publish("export", {{"export_id", r->export_id},
                           {"directory", r->directory},
                           {"files", r->files.size()},
                           {"problems", r->problems}});
      }
    }
  };
  auto nightly = calibration::NightlyExporter::create(
      config_.storage.db_path, wall, std::move(options), [this] { analysis_->drain(); },
      std::move(done));
  if (!nightly) {
    // The config reader checked each of them: this is a bug, not a setting.
    spdlog::error("nightly export not started: {}", nightly.error().message);
    return;
  }
  nightly_ = std::move(*nightly);
  spdlog::info("nightly export at {} ({}) into {}; next {}", e.local_time,
               e.time_zone.empty() ? "system time zone" : e.time_zone, e.directory,
               calibration::local_time_label(nightly_->next_slot_unix_s(), zone));
  nightly_->start();
}

void Station::stop(const std::string& reason) {
  {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    stopping_ = true;
  }
  wake_.notify_all();
  if (control_thread_.joinable()) control_thread_.join();
  {
    // The control thread is gone: finish the run and the chamber from here.
    std::lock_guard lock(run_mu_);
    if (sequencer_ && !sequencer_->finished()) {
      sequencer_->interrupt(run_time_s(), reason);
      checkpoint(true);
      end_run();
    }
  }
  // The table stops before the chamber heads for its safe set point; its
  // servo goes off once it is at rest (make_table_safe_now(), after). A
  // table the idle station had made safe is left alone: a jog from its
  // panel is not the station's to stop.
  const bool table_owed = table_ && (table_->safing() || table_->owes_safe_state());
  if (table_owed) table_->make_safe(wall_.monotonic_s());
  const double safe_c = config_.station.safe_setpoint_c;
  Status chamber_safe;
  {
    std::lock_guard lock(run_mu_);
    ++control_ticks_;  // a write of its own, whatever the last tick tried
    chamber_safe = plant_->write_setpoint(safe_c, true, control_ticks_);
    if (!chamber_safe) {
      journal_->add_event(
          "error", "", "",
          fmt::format("daemon stopping: the chamber did not take the safe set point {:g} °C "
                      "({}); set it at the controller",
                      safe_c, chamber_safe.error().message));
    }
  }
  if (table_owed) make_table_safe_now();
  duts_->stop_sources();
  if (nightly_) nightly_->stop();
  analysis_->stop();
  writer_->stop();
  if (chamber_safe) {
    spdlog::info("stopped ({}); chamber set point {:g} °C written", reason, safe_c);
  } else {
    spdlog::error(
        "stopped ({}); the chamber did NOT take the safe set point {:g} °C ({}); it holds what it "
        "had{}: set it at the controller",
        reason, safe_c, chamber_safe.error().message,
        plant_->last_written_setpoint_c()
            ? fmt::format(" (last written: {:g} °C)", *plant_->last_written_setpoint_c())
            : std::string());
  }
}

bool Station::idle() const {
  return !busy_.load() && (queue_length_.load() <= 0 || queue_held_.load());
}

double Station::run_time_s() const { return clock_.now_s() - run_clock_.load().t0_s; }

void Station::control_loop() {
  const double tick_s = config_.control.tick_s;
  const auto min_wall = std::chrono::duration<double>(config_.control.min_tick_wall_s);
  if (const PacedClock* paced = as_paced(clock_)) return paced_control_loop(*paced);
  std::optional<std::chrono::steady_clock::time_point> previous_start;
  double previous_station_s = 0;
  for (;;) {
    const auto wall_start = std::chrono::steady_clock::now();
    const double station_s = clock_.now_s();
    if (previous_start) {
      // A stall: the process was stopped or starved. Station time went on;
      // soaks are credited only for what the DUTs' samples cover, so that
      // stretch is not, and the log says so.
      const double gap_wall_s = std::chrono::duration<double>(wall_start - *previous_start).count();
      const double period_wall_s = std::max(min_wall.count(), tick_s / clock_.time_scale());
      if (gap_wall_s > std::max(2.0, 10.0 * period_wall_s)) {
        const std::string message = fmt::format(
            "the control loop did not run for {:.1f} s of wall time ({:.0f} s of station time): "
            "the daemon was stopped or starved; acquisition is credited only where the DUTs' "
            "samples were stored",
            gap_wall_s, station_s - previous_station_s);
        spdlog::warn("{}", message);
        post_event("stall", message);
      }
    }
    previous_start = wall_start;
    previous_station_s = station_s;
    try {
      tick();
    } catch (const std::exception& e) {
      spdlog::error("control loop: {}", e.what());
    }
    heartbeat_.fetch_add(1, std::memory_order_relaxed);
    const auto period = std::max<std::chrono::duration<double>>(
        min_wall, std::chrono::duration<double>(tick_s / clock_.time_scale()));
    std::unique_lock lock(mu_);
    if (wake_.wait_until(lock,
                         wall_start + std::chrono::duration_cast<std::chrono::nanoseconds>(period),
                         [this] { return stopping_; })) {
      return;
    }
  }
}

// On a simulator's clock the loop ticks once per tick_s of station time,
// whenever that is reached in wall time, and marks each tick consumed: the
// simulator never runs more than its lead past the last tick.
void Station::paced_control_loop(const PacedClock& clock) {
  const double tick_s = config_.control.tick_s;
  std::unique_ptr<ClockConsumer> slot = clock.consumer("control loop");
  if (!slot) spdlog::error("control loop: no slot left on the simulator's clock; it will not wait");
  for (;;) {
    const double t_tick_s = clock.now_s();
    try {
      tick();
    } catch (const std::exception& e) {
      spdlog::error("control loop: {}", e.what());
    }
    heartbeat_.fetch_add(1, std::memory_order_relaxed);
    if (slot) slot->consumed(t_tick_s);
    for (;;) {
      {
        std::lock_guard lock(mu_);
        if (stopping_) return;
      }
      // Short waits: stop() is noticed within one.
      // (1 µs short: the simulator's steps reach t + tick_s only within
      // rounding, and it runs no further before this tick's mark)
      if (clock.wait_until(t_tick_s + tick_s - 1e-6, std::chrono::milliseconds(20))) break;
    }
  }
}

schedules::Readings Station::read_devices(double now_s) {
  schedules::Readings r;
  plant_->read(r);
  const double wall_s = wall_.monotonic_s();
  // Silence in station time, once it is also min_silent_wall_s of wall time.
  const double min_wall_s = config_.control.min_silent_wall_s;
  auto silent = [&](double since_s, double since_wall_s) {
    return wall_s - since_wall_s >= min_wall_s ? std::max(0.0, now_s - since_s) : 0.0;
  };
  plant_->record_silence(now_s, wall_s, silent, r);
  duts_->read_silence(r, silent);
  if (table_) table_->read(now_s, wall_s, min_wall_s, r);
  const storage::SampleWriterStats ws = writer_->stats();
  r.storage_committed = ws.commits > 0;
  // The database file deleted or replaced under the daemon: storage fails
  // from then on (a stat; db_ is only read here).
  if (!storage_file_error_) {
    if (Status f = db_.check_file(); !f) storage_file_error_ = f.error().message;
  }
  if (ws.consecutive_failures == 0 && !ws.thread_failed && !storage_file_error_) {
    storage_ok_s_ = now_s;
    storage_ok_wall_s_ = wall_s;
  }
  r.data_covered_s = [this](double from_s, double to_s) {
    return duts_->data_covered_s(from_s, to_s);
  };
  r.data_reached_at_s = [this](double from_s, double need_s) {
    return duts_->data_reached_at_s(from_s, need_s);
  };
  r.storage_failing_s = silent(storage_ok_s_, storage_ok_wall_s_);
  if (r.storage_failing_s > 0) {
    r.storage_error = storage_file_error_.value_or(ws.last_error);
    r.storage_pending = ws.pending;
  }
  return r;
}

// Once: the event, and the old file's write-ahead log emptied into it so it
// is not replayed into whatever file the path names at the next start
// (retried each tick while another connection holds it off).
void Station::note_storage_file() {
  if (!storage_file_error_ || storage_file_released_) return;
  if (!storage_file_reported_) {
    storage_file_reported_ = true;
    const std::string message = fmt::format(
        "{}. Samples, events and results are no longer stored; the run holds (storage_failing) "
        "and fails after its grace. Restore the file if it was not meant to go (docs/"
        "operations.md \"The database file deleted or replaced\"), then restart gyrothermd",
        *storage_file_error_);
    spdlog::error("{}", message);
    journal_->add_event("error", "", "", message);
  }
  if (Status st = db_.release_wal(); st) {
    storage_file_released_ = true;
  } else {
    spdlog::warn("{} (tried again next tick)", st.error().message);
  }
}

void Station::tick() {
  const double now_s = clock_.now_s();
  const schedules::Readings r = read_devices(now_s);
  const std::vector<std::string> probe_events = duts_->read_dut_probes(now_s);
  std::optional<double> shell_c;
  if (r.top_c && r.side_c) {
    shell_c = (*r.top_c + *r.side_c) / 2.0;
    shell_rate_window_.push(now_s, *shell_c);
  }

  std::lock_guard run_lock(run_mu_);
  {
    std::lock_guard lock(mu_);
    if (stopping_) return;
  }
  ++control_ticks_;
  journal_->record_unrecorded();
  journal_->record_posted_events();
  for (const auto& message : probe_events) journal_->add_event("device", "", "", message);
  note_storage_file();
  plant_->note_links(now_s);
  if (!sequencer_ && !storage_file_error_) start_next_run(now_s);  // no run into a lost file
  if (!sequencer_) keep_idle_safe();

  double t_run_s = 0;
  if (sequencer_) {
    t_run_s = now_s - run_clock_.load().t0_s;
    if (sequencer_->state() == RunState::kAborting) {
      // The table stops before the chamber heads for its safe set point.
      if (table_) table_->make_safe(wall_.monotonic_s());
      if (plant_->write_setpoint(sequencer_->setpoint_c(), true, control_ticks_)) {
        sequencer_->safe_state_reached(t_run_s);
      }
    } else {
      if (table_) tend_table(t_run_s);
      tick_sequencer(t_run_s, r);
      if (table_ && !sequencer_->finished()) {
        const schedules::TableDemand demand = table_demand();
        const bool moves =
            demand.mode == schedules::TableDemandMode::kRate || demand.position_deg.has_value();
        if (moves || !table_->safing()) {
          if (!moves && !table_->at_rest()) {
            table_->make_safe(wall_.monotonic_s());
          } else {
            table_->drive(demand, wall_.monotonic_s());
          }
        }
      }
      // At the run's end the table stops before the chamber heads for its
      // safe set point (its servo goes off once at rest, ticks later).
      if (table_ && sequencer_->finished()) table_->make_safe(wall_.monotonic_s());
      // Failing: retried next tick.
      (void)plant_->write_setpoint(sequencer_->setpoint_c(), false, control_ticks_);
    }
    if (table_) {
      if (auto sample = table_->sample(t_run_s)) writer_->push_table(current_run_id(), *sample);
    }
    TemperatureSample ts;
    ts.t_s = t_run_s;
    ts.setpoint_c = sequencer_->setpoint_c();
    ts.chamber_c = r.chamber_c.value_or(kNaN);
    ts.top_c = r.top_c.value_or(kNaN);
    ts.side_c = r.side_c.value_or(kNaN);
    writer_->push_temperature(current_run_id(), ts);
    checkpoint(false);
  }

  const Progress run_progress = progress(t_run_s);
  {
    std::lock_guard lock(mu_);
    StatusSnapshot& s = snapshot_;
    s.progress = run_progress;
    s.t_station_s = now_s;
    s.t_run_s = t_run_s;
    s.chamber_c = r.chamber_c;
    s.top_c = r.top_c;
    s.side_c = r.side_c;
    s.gradient_c =
        (r.top_c && r.side_c) ? std::optional<double>(*r.top_c - *r.side_c) : std::nullopt;
    const double rate = shell_rate_window_.slope_per_s();
    s.temp_rate_c_per_min = std::isfinite(rate) ? std::optional<double>(rate * 60.0) : std::nullopt;
    s.queue_length = std::max(0, queue_length_.load());
    s.queue_held = hold_reason_.has_value();
    s.queue_hold_reason = hold_reason_.value_or("");
    s.interlocks.clear();
    if (sequencer_) {
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
  }
  if (table_) {
    table_->finish_safe_state(wall_.monotonic_s());
    std::lock_guard lock(mu_);
    snapshot_.table = table_->status();
  }
  if (sequencer_ && sequencer_->finished()) end_run();
}

Progress Station::progress(double t_run_s) {
  constexpr double kQueueScanWallS = 5;
  const int queued = queue_length_.load();
  if (queued != queue_scanned_length_ || wall_.monotonic_s() >= queue_scan_due_wall_s_) {
    queue_scanned_length_ = queued;
    queue_scan_due_wall_s_ = wall_.monotonic_s() + kQueueScanWallS;
    if (auto entries = db_.queue_entries()) {
      std::vector<schedules::QueueDurations::Entry> waiting;
      for (const auto& e : *entries) {
        if (e.state == "queued") {
          waiting.push_back(
              {e.id, e.toml_text, e.source_path.empty() ? e.schedule_name : e.source_path});
        }
      }
      // Each queued run starts where the one before left the chamber.
      queue_planned_ = queue_durations_.update(waiting, config::station_limits(config_),
                                               config_.station.safe_setpoint_c);
    }
  }
  if (!sequencer_) {
    schedules::RunProgress idle;
    idle.queue_fixed_s = queue_planned_.fixed_s;
    idle.queue_settles = queue_planned_.settles;
    return to_progress(idle);
  }
  return to_progress(schedules::run_progress(sequencer_->plan(), sequencer_->snapshot(t_run_s),
                                             sequencer_->gate_progress(t_run_s), queue_planned_));
}

schedules::TableDemand Station::table_demand() const {
  if (!sequencer_ || sequencer_->finished() || sequencer_->paused() ||
      !sequencer_->tripped().empty() || sequencer_->state() == RunState::kAborting) {
    return {};
  }
  return sequencer_->table_demand();
}

void Station::make_table_safe_now() {
  if (!table_) return;
  // Real waiting, whatever the clocks: 100 ms polls, 30 s at most for the
  // table to come to rest, 1 s without an answer.
  constexpr int kPolls = 300;
  constexpr int kSilentPolls = 10;
  constexpr auto kPoll = std::chrono::milliseconds(100);
  const double min_silent_wall_s = config_.control.min_silent_wall_s;
  schedules::Readings r;
  table_->read(clock_.now_s(), wall_.monotonic_s(), min_silent_wall_s, r);
  // What the last reading showed, for a message that says no more than it.
  auto last_seen = [&] {
    const auto& s = table_->last_state();
    if (!s) return std::string("it never answered since the daemon started");
    return fmt::format("last seen at {:+.3f} °/s, mode {}, interlock {}", s->rate_dps,
                       drivers::to_string(s->mode), drivers::to_string(s->interlock));
  };
  if (!table_->answering()) {
    table_->make_safe(wall_.monotonic_s());  // a stop all the same, if the line takes it
    spdlog::error(
        "table: no answer at shutdown ({}); its state is unknown ({}): check the table at its "
        "controller",
        table_->last_error(), last_seen());
    return;
  }
  table_->make_safe(wall_.monotonic_s());
  int silent_polls = 0;
  for (int poll = 0;; ++poll) {
    const double wall_s = wall_.monotonic_s();
    table_->read(clock_.now_s(), wall_s, min_silent_wall_s, r);
    silent_polls = table_->answering() ? 0 : silent_polls + 1;
    if (silent_polls == kSilentPolls) {
      spdlog::error(
          "table: stopped answering at shutdown ({}); its state is unknown ({}): check the table "
          "at its controller",
          table_->last_error(), last_seen());
      break;
    }
    table_->finish_safe_state(wall_s);
    if (!table_->safing()) break;
    if (poll == kPolls) {
      const std::string wait = fmt::format("{} s", kPolls * kPoll.count() / 1000);
      if (table_->stop_sent()) {
        spdlog::error("table: not at rest after {} ({}); stop sent, the servo left on", wait,
                      last_seen());
      } else {
        spdlog::error("table: did not take the stop in {} ({}; {}): check the table", wait,
                      table_->last_error(), last_seen());
      }
      break;
    }
    std::this_thread::sleep_for(kPoll);
  }
}

void Station::keep_idle_safe() {
  if (table_ && !table_->safing() && table_->answering() && table_->owes_safe_state()) {
    table_->make_safe(wall_.monotonic_s());
  }
  plant_->keep_safe(config_.station.safe_setpoint_c, control_ticks_);
}

void Station::tend_table(double t_run_s) {
  if (auto what = table_->take_interruption()) {
    const bool respin = config_.table->respin_after_fault;
    journal_->add_event(
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
    if (auto message = table_->reset_latched_fault(clock_.now_s())) {
      spdlog::info("{}", *message);
      journal_->add_event("table", "", "", *message);
    }
  }
}

// ---------------------------------------------------------------- queue and runs

void Station::count_queue() {
  auto entries = db_.queue_entries();
  if (!entries) return;
  queue_length_.store(static_cast<int>(std::count_if(
      entries->begin(), entries->end(), [](const auto& e) { return e.state == "queued"; })));
}

// Says what the queue does after the current run failed, once per run, and
// before the run's failed state is recorded: whoever sees the run failed
// sees the queue's answer too. An abort (or a stop) has already held it,
// whatever ignore_failures says.
void Station::answer_failed_run() {
  if (queue_answered_ || !entry_) return;
  queue_answered_ = true;
  const int64_t run_id = current_run_id();
  if (hold_reason_) {
    journal_->add_event(
        "queue", "", "",
        fmt::format("run {} failed; the queue stays held ({})", run_id, *hold_reason_));
  } else if (!entry_->ignore_failures) {
    hold_queue(fmt::format("run {} failed ({}); resume releases the queue", run_id, last_reason_));
  } else {
    journal_->add_event("queue", "", "",
                        fmt::format("run {} failed; the queue goes on with the next entry "
                                    "(ignore_failures)",
                                    run_id));
  }
}

void Station::hold_queue(const std::string& reason) {
  hold_reason_ = reason;
  queue_held_.store(true);
  if (auto st = db_.set_meta(kQueueHoldKey, reason); !st) spdlog::error("{}", st.error().message);
  journal_->add_event("queue", "", "", "queue held: " + reason);
  spdlog::info("queue held: {}", reason);
}

void Station::release_queue() {
  hold_reason_.reset();
  queue_held_.store(false);
  if (auto st = db_.delete_meta(kQueueHoldKey); !st) spdlog::error("{}", st.error().message);
  journal_->add_event("queue", "", "", "queue released");
}

void Station::start_next_run(double now_s) {
  // queue_length_ > 0: an entry was added and not yet taken or removed. It
  // may be a little behind the database (an add counted just after its
  // commit), never ahead for long: the next tick sees it.
  if (hold_reason_ || queue_length_.load() <= 0) return;
  auto entries = db_.queue_entries();
  if (!entries) {
    spdlog::error("{}", entries.error().message);
    return;
  }
  auto it = std::find_if(entries->begin(), entries->end(),
                         [](const auto& e) { return e.state == "queued"; });
  if (it == entries->end()) return;
  storage::QueueEntry entry = *it;
  const std::string source = entry.source_path.empty() ? entry.schedule_name : entry.source_path;

  storage::RunRecord rec;
  rec.schedule_name = entry.schedule_name;
  rec.state = "queued";
  rec.started_utc = utc_iso(wall_);
  rec.time_scale = clock_.time_scale();
  rec.latitude_deg = config_.station.latitude_deg;
  rec.orientation = std::string(analysis::to_string(config_.station.orientation));
  // The configuration in force (loaded at start-up), not the file as it is
  // on disk now.
  rec.config_json = config::run_config_json(config_).dump();
  // One transaction: an entry removed meanwhile starts no run and leaves no
  // run row behind.
  auto id = db_.queue_start_run(entry.id, rec);
  if (!id) {
    spdlog::error("cannot start run of {}: {}", entry.schedule_name, id.error().message);
    return;
  }
  if (!*id) return;  // removed (or moved on) since it was read; the next tick looks again
  const int64_t run_id = **id;
  queue_length_.fetch_sub(1);
  queue_scanned_length_ = -1;  // the queue's planned time: without this entry, at the next tick
  busy_.store(true);
  duts_->register_run_duts(db_, run_id, entry.metadata.dut_serials);
  run_clock_.publish(run_id, now_s);
  entry_ = entry;
  {
    std::lock_guard lock(mu_);
    snapshot_.run_id = run_id;
    snapshot_.schedule_name = entry.schedule_name;
    snapshot_.run_operator = entry.metadata.operator_name;
    snapshot_.run_comment = entry.metadata.comment;
    snapshot_.run_tags = entry.metadata.tags;
  }

  // Checked again: the station config may have changed since it was queued.
  auto plan = schedules::parse_schedule(entry.toml_text, source, config::station_limits(config_));
  if (!plan) {
    journal_->add_event(
        "error", "queued", "failed",
        "schedule refused at start (station limits changed?):\n" + plan.error().message);
    last_reason_ = "schedule refused at start";
    answer_failed_run();
    (void)db_.set_run_state(run_id, "failed", true);
    end_run();
    return;
  }
  spdlog::info("run {}: {} ({} steps)", run_id, plan->name, plan->steps.size());
  if (table_) table_->begin_run();
  journal_->begin_segments(std::vector<int64_t>(plan->steps.size(), 0));
  const double start_sp = plant_->last_written_setpoint_c().value_or(
      snapshot_.chamber_c.value_or(config_.station.safe_setpoint_c));
  make_sequencer(std::move(*plan));
  sequencer_->start(0.0, start_sp);
  checkpoint(true);
}

// Completed runs whose analysis never ran (the daemon stopped between the end
// of the run and its analysis) get it now.
void Station::submit_missing_analyses() {
  auto runs = db_.runs();
  if (!runs) return;
  for (const auto& r : *runs) {
    if (r.state != "completed") continue;
    auto events = db_.events(r.id);
    if (!events) continue;
    const bool done =
        std::any_of(events->begin(), events->end(),
                    [](const storage::EventRecord& e) { return e.kind == "analysis"; });
    if (!done) {
      spdlog::info("run {}: completed without its analysis; computing it now", r.id);
      analysis_->submit(calibration::RunJob{r.id});
    }
  }
}

void Station::resume_interrupted_run() {
  auto runs = db_.runs();
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
    run_clock_.publish(open[i].id, 0.0);
    journal_->add_event("state", open[i].state, "interrupted",
                        "closed at start-up: a newer run exists");
    (void)db_.set_run_state(open[i].id, "interrupted", true);
  }
  const storage::RunRecord& run = open.back();
  run_clock_.publish(run.id, 0.0);  // for the events below; its start once known
  auto give_up = [&](const std::string& why) {
    journal_->add_event("state", run.state, "interrupted", "not resumed: " + why);
    (void)db_.set_run_state(run.id, "interrupted", true);
    if (run.queue_id) (void)db_.queue_finish(*run.queue_id, "interrupted");
    spdlog::warn("run {} not resumed: {}", run.id, why);
    run_clock_.publish(0, 0.0);
  };
  if (!run.queue_id) return give_up("it did not come from the queue");
  auto entry = db_.queue_entry(*run.queue_id);
  if (!entry || !*entry) return give_up("its queue entry is gone");
  if (run.resume_json.empty() || !run.checkpoint_wall_unix_s) {
    return give_up("the daemon stopped before the run's first checkpoint");
  }
  auto plan = schedules::parse_schedule((*entry)->toml_text, (*entry)->source_path,
                                        config::station_limits(config_));
  if (!plan) return give_up("its schedule is refused now:\n" + plan.error().message);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(run.resume_json);
  } catch (const nlohmann::json::exception& e) {
    return give_up(fmt::format("its checkpoint is unreadable: {}", e.what()));
  }
  auto snap = schedules::snapshot_from_json(j);
  if (!snap) return give_up(snap.error().message);

  // The downtime in station time; never before a committed sample. On the
  // simulator's clock that wrote the checkpoint it is exact; else from wall
  // time at the time scale.
  const double down_wall_s = std::max(0.0, wall_.unix_now_s() - *run.checkpoint_wall_unix_s);
  double t_resume_s = snap->t_s + down_wall_s * clock_.time_scale();
  if (const PacedClock* paced = as_paced(clock_);
      paced && j.contains("clock_epoch") && j.contains("clock_at_checkpoint_s")) {
    try {
      if (j.at("clock_epoch").get<uint64_t>() == paced->epoch()) {
        t_resume_s =
            snap->t_s + std::max(0.0, clock_.now_s() - j.at("clock_at_checkpoint_s").get<double>());
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
  if (auto last_gyro = db_.last_gyro_sample_t_s(run.id); !last_gyro) {
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
  if (auto last = db_.last_sample_t_s(run.id); last && *last) {
    t_resume_s = std::max(t_resume_s, **last + 1e-3);
  }
  std::vector<int64_t> segment_ids(plan->steps.size(), 0);
  std::vector<storage::SegmentRecord> segments;
  if (auto segs = db_.segments(run.id)) {
    segments = std::move(*segs);
    for (const auto& seg : segments) {
      if (seg.index >= 0 && static_cast<std::size_t>(seg.index) < segment_ids.size()) {
        segment_ids[static_cast<std::size_t>(seg.index)] = seg.id;
      }
    }
  }
  // The checkpoint may be older than the step's end: the daemon died after
  // the step was recorded finished and before the checkpoint said so. That
  // step is not run again; the run goes on with the next.
  const bool step_finished_already =
      snap->step_index < segment_ids.size() &&
      std::any_of(segments.begin(), segments.end(), [&](const storage::SegmentRecord& seg) {
        return seg.id == segment_ids[snap->step_index] && seg.state == "completed";
      });
  // Segments still "running" that are not the step resumed died with the
  // daemon (e.g. the next step's, started after that checkpoint).
  for (auto seg : segments) {
    const bool resumed = !step_finished_already && snap->step_index < segment_ids.size() &&
                         seg.id == segment_ids[snap->step_index];
    if (seg.state != "running" || resumed) continue;
    seg.state = "aborted";
    if (!seg.t_end_s) seg.t_end_s = std::max(seg.t_start_s, snap->t_s);
    if (auto st = db_.update_segment(seg); !st) {
      spdlog::error("run {}: segment {} not closed: {}", run.id, seg.id, st.error().message);
    }
    if (seg.index >= 0 && static_cast<std::size_t>(seg.index) < segment_ids.size() &&
        segment_ids[static_cast<std::size_t>(seg.index)] == seg.id) {
      segment_ids[static_cast<std::size_t>(seg.index)] = 0;
    }
  }
  journal_->begin_segments(std::move(segment_ids));
  entry_ = **entry;
  busy_.store(true);
  duts_->register_run_duts(db_, run.id, entry_->metadata.dut_serials);
  // A soak is credited for what each DUT stored: read back from the step's start.
  duts_->seed_coverage(db_, run.id, snap->times.start_s);
  run_clock_.publish(run.id, clock_.now_s() - t_resume_s);
  {
    std::lock_guard lock(mu_);
    snapshot_.run_id = run.id;
    snapshot_.schedule_name = run.schedule_name;
    snapshot_.run_operator = run.metadata.operator_name;
    snapshot_.run_comment = run.metadata.comment;
    snapshot_.run_tags = run.metadata.tags;
  }
  const std::string reason = fmt::format(
      "daemon restarted: run resumes at step {} of {} after {:.1f} min of station time down "
      "(was {})",
      std::min(snap->step_index + 1, plan->steps.size()), plan->steps.size(),
      (t_resume_s - snap->t_s) / 60.0, run.state);
  spdlog::info("run {}: {}", run.id, reason);
  make_sequencer(std::move(*plan));
  if (table_) table_->begin_run();
  journal_->add_event("resume", "", "", reason);
  plant_->forget_setpoint();
  sequencer_->restore(*snap, t_resume_s, data_until_s, reason);
  if (step_finished_already) {
    journal_->add_event(
        "resume", "", "",
        fmt::format("step {} had ended before the daemon stopped (its last checkpoint was "
                    "older): it is not run again; the run goes on with the next step",
                    snap->step_index + 1));
    sequencer_->continue_after_finished_step(t_resume_s);
    // restore() re-announced that step as running: its record stays as it
    // was written when it ended.
    for (const auto& seg : segments) {
      if (seg.index == static_cast<int>(snap->step_index) && seg.state == "completed") {
        journal_->keep_segment(seg);
      }
    }
    journal_->record_unrecorded();
  }
  (void)db_.set_run_state(run.id, to_string(sequencer_->state()), false);
  checkpoint(true);
}

void Station::checkpoint(bool force) {
  if (!sequencer_) return;
  const double wall_s = wall_.monotonic_s();
  // A new state or a new step is checkpointed at once; the rest once a wall second.
  const std::string state =
      fmt::format("{}#{}", to_string(sequencer_->state()), sequencer_->step_index());
  if (!force && state == checkpoint_state_ && wall_s - last_checkpoint_wall_s_ < 1.0) return;
  const double t_run_s = run_time_s();
  nlohmann::json snap = to_json(sequencer_->snapshot(t_run_s));
  if (const PacedClock* paced = as_paced(clock_)) {
    // A simulator's clock outlives this process: the downtime of a restart
    // is then read off it exactly, not estimated from wall time.
    snap["clock_epoch"] = paced->epoch();
    snap["clock_at_checkpoint_s"] = clock_.now_s();
  }
  const std::string json = snap.dump();
  if (auto st = db_.set_run_checkpoint(current_run_id(), json, wall_.unix_now_s()); !st) {
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

void Station::end_run() {
  const RunState final_state = sequencer_ ? sequencer_->state() : RunState::kFailed;
  const int64_t run_id = current_run_id();
  // The table stops first; its servo goes off once it is at rest (ticks).
  if (table_) table_->make_safe(wall_.monotonic_s());
  const double safe_c = config_.station.safe_setpoint_c;
  const Status chamber_safe = plant_->write_setpoint(safe_c, true, control_ticks_);
  plant_->owe_safe_setpoint(!chamber_safe);
  if (!chamber_safe && run_id != 0) {
    journal_->add_event(
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
    if (!duts_->await_gyro(run_id, run_time_s(), kAwaitGyro)) {
      spdlog::warn("run {}: the gyro stream had not reached the run's end after {} ms", run_id,
                   kAwaitGyro.count());
    }
  }
  run_clock_.close_samples();
  const Status flushed = writer_->flush();
  if (!flushed && run_id != 0) note_samples_not_committed(run_id, final_state, flushed.error());
  if (run_id != 0) writer_->close_run(run_id);
  if (entry_ && final_state != RunState::kInterrupted) {
    if (auto st = db_.queue_finish(entry_->id, to_string(final_state)); !st) {
      spdlog::error("{}", st.error().message);
    }
    if (final_state == RunState::kFailed) answer_failed_run();
  }
  queue_answered_ = false;
  if (final_state == RunState::kCompleted && run_id != 0 && flushed) {
    analysis_->submit(calibration::RunJob{run_id});
  }
  if (stop_after_current_ && final_state != RunState::kInterrupted) {
    stop_after_current_ = false;
    if (!hold_reason_) {
      hold_queue(fmt::format("stopped after run {} by the operator ({}); resume releases the queue",
                             run_id, stop_reason_));
    }
  }
  run_clock_.publish(0, 0.0);
  sequencer_.reset();
  entry_.reset();
  checkpoint_state_.clear();
  // No checkpoint transaction comes for this run any more: what it left
  // unwritten (its steps' last records, then its end) goes now if it can.
  journal_->record_unrecorded();
  {
    std::lock_guard lock(mu_);
    snapshot_.run_id.reset();
    snapshot_.run_operator.clear();
    snapshot_.run_comment.clear();
    snapshot_.run_tags.clear();
    snapshot_.step_index.reset();
    snapshot_.step_label.clear();
    snapshot_.state = "idle";
    snapshot_.paused = false;
    snapshot_.interlocks.clear();
  }
  busy_.store(false);
}

// The run's last samples could not be committed at its end (the commit's
// error, or the writer stopped): said in its events, and a completed run is
// not analysed as if its data were whole. The "analysis" event also keeps a
// restart from analysing it (submit_missing_analyses).
void Station::note_samples_not_committed(int64_t run_id, RunState final_state, const Error& e) {
  const storage::SampleWriterStats ws = writer_->stats();
  const std::string why = fmt::format(
      "the final commit of its samples failed ({} samples not stored): {}", ws.pending, e.message);
  spdlog::error("run {}: {}", run_id, why);
  journal_->add_event("error", "", "", fmt::format("run {}: {}", run_id, why));
  if (final_state == RunState::kCompleted) {
    journal_->add_event(
        "analysis", "", "",
        fmt::format("analysis not run: the run's samples are incomplete ({}); analyse it "
                    "offline once its data are checked (gyrotherm allan, fit)",
                    why));
  }
}

// ---------------------------------------------------------------- gyro, status, events

StatusSnapshot Station::status() const {
  StatusSnapshot s;
  {
    std::lock_guard lock(mu_);
    s = snapshot_;
  }
  s.uptime_s = wall_.monotonic_s() - started_wall_s_;
  // The chamber's and probes' health are the snapshot's (read_devices()):
  // their drivers hold their lock through a Modbus request.
  duts_->add_health(s);
  s.storage = writer_->stats();
  // The database's file system (a statvfs: microseconds, no disk access).
  std::filesystem::path dir = std::filesystem::path(config_.storage.db_path).parent_path();
  if (dir.empty()) dir = ".";
  if (struct statvfs fs{}; statvfs(dir.c_str(), &fs) == 0) {
    s.storage_free_bytes = static_cast<int64_t>(fs.f_bavail) * static_cast<int64_t>(fs.f_frsize);
    s.storage_size_bytes = static_cast<int64_t>(fs.f_blocks) * static_cast<int64_t>(fs.f_frsize);
  }
  if (hooks_.lab_status) s.lab = hooks_.lab_status();
  return s;
}

void Station::post_event(const std::string& kind, const std::string& message) {
  journal_->post_event(kind, message);
}

void Station::tick_sequencer(double t_run_s, const schedules::Readings& r) {
  const bool written =
      journal_->tick_with_checkpoint([&] { sequencer_->tick(t_run_s, r); },
                                     [&]() -> Status {
                                       checkpoint(true);
                                       if (checkpoint_failing_) {
                                         return Error::Transient("the checkpoint was not written");
                                       }
                                       return Status::Ok();
                                     });
  if (!written) checkpoint_state_.clear();  // rolled back: checkpointed again next tick
}

void Station::on_state(RunState from, RunState to, double t_s, const std::string& reason) {
  spdlog::info("run {} t={:.0f} s: {} -> {}: {}", current_run_id(), t_s, to_string(from),
               to_string(to), reason);
  last_reason_ = reason;
  if (hooks_.publish) {
    const int64_t run_id = current_run_id();
    hooks_.publish("state", {{"run_id", run_id != 0 ? nlohmann::json(run_id) : nlohmann::json()},
                             {"from", to_string(from)},
                             {"to", to_string(to)},
                             {"t_s", t_s},
                             {"reason", reason}});
  }
  journal_->add_event("state", std::string(to_string(from)), std::string(to_string(to)), reason);
  if (to == RunState::kFailed) answer_failed_run();
  journal_->keep_run_state(current_run_id(), std::string(to_string(to)),
                           schedules::is_terminal(to));
  journal_->record_unrecorded();
}

void Station::on_interlock(schedules::InterlockKind kind, bool tripped, double t_s,
                           const std::string& message) {
  (void)kind;
  (void)t_s;
  if (tripped) {
    spdlog::warn("run {}: {}", current_run_id(), message);
  } else {
    spdlog::info("run {}: {}", current_run_id(), message);
  }
  journal_->add_event("interlock", "", "", message);
}

void Station::on_step_started(std::size_t index, const schedules::PlanStep& step, double t_s) {
  journal_->start_segment(index, step, t_s);
  duts_->forget_coverage_before(t_s);
}

void Station::on_step_changed(std::size_t index, const schedules::PlanStep& step,
                              const schedules::StepTimes& times) {
  const int64_t id = journal_->segment_id(index, step, times.start_s);
  if (id == 0) return;
  journal_->keep_segment(segment_record(id, current_run_id(), index, step, times, "running"));
  journal_->record_unrecorded();
}

void Station::on_step_finished(std::size_t index, const schedules::PlanStep& step,
                               const schedules::StepTimes& times, bool completed) {
  const int64_t run_id = current_run_id();
  const int64_t id = journal_->segment_id(index, step, times.start_s);
  if (id == 0) return;
  // A soak's samples are committed before the step is recorded finished: a
  // crash after this never leaves a finished soak without its tail.
  if (completed && step.kind == schedules::StepKind::kSoak) {
    if (Status st = writer_->flush(); !st) {
      spdlog::error("run {}: the samples of step {} not committed at its end: {}", run_id,
                    index + 1, st.error().message);
    }
  }
  journal_->keep_segment(
      segment_record(id, run_id, index, step, times, completed ? "completed" : "aborted"));
  journal_->record_unrecorded();
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
    analysis_->submit(std::move(job));
  }
}

// ---------------------------------------------------------------- StationControl
//
// The reads and queue edits are StationQueries' (station_queries.h); the
// run controls take the run's lock.

Reply Station::control(std::string_view action, const std::string& reason_in) {
  const std::string reason = reason_in.empty() ? "operator" : reason_in;
  std::lock_guard lock(run_mu_);
  const bool running = sequencer_ && !sequencer_->finished();
  auto log_command = [&](const std::string& message) {
    journal_->add_event("operator", "", "", message);
    spdlog::info("{}", message);
  };
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
    wake_.notify_all();
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
                                 current_run_id(), config_.station.safe_setpoint_c)}});
  }
  if (action == "stop") {
    if (running) {
      stop_after_current_ = true;
      stop_reason_ = reason;
      const std::string message =
          fmt::format("the queue holds after run {} completes ({})", current_run_id(), reason);
      log_command(message);
      return Reply::ok({{"ok", true}, {"message", message}});
    }
    if (hold_reason_) return Reply::refused(Refusal::Kind::kConflict, "the queue is already held");
    hold_queue("stopped by the operator (" + reason + "); resume releases the queue");
    return Reply::ok({{"ok", true}, {"message", "queue held"}});
  }
  if (action == "table-reset") {
    if (!table_device_) {
      return Reply::refused(Refusal::Kind::kConflict,
                            "this station has no rate table ([table] in the station config)");
    }
    // The driver serialises its requests with the control loop's.
    if (auto st = table_device_->reset_faults(); !st) {
      return Reply::refused(Refusal::Kind::kUnavailable,
                            fmt::format("table fault reset not done: {}", st.error().message));
    }
    log_command(fmt::format("table: fault reset by the operator ({})", reason));
    return Reply::ok(
        {{"ok", true},
         {"message",
          fmt::format("{}: fault reset sent; the table_fault interlock clears at the "
                      "next reading without a fault{}",
                      table_device_->name(),
                      running && sequencer_->paused() ? "; `gyrotherm resume` goes on" : "")}});
  }
  return Reply::refused(Refusal::Kind::kNotFound, fmt::format("no control action '{}'", action));
}

Reply Station::queue_list() { return queries_.queue_list(); }
Reply Station::queue_add(const std::string& toml_text, const std::string& source,
                         bool ignore_failures) {
  return queries_.enqueue(QueueRequest{toml_text, source, ignore_failures, {}});
}
Reply Station::enqueue(const QueueRequest& request) { return queries_.enqueue(request); }
Reply Station::queue_remove(int64_t id) { return queries_.queue_remove(id); }
Reply Station::queue_move(int64_t id, int position) { return queries_.queue_move(id, position); }
Reply Station::runs() { return queries_.runs(); }
Reply Station::run(int64_t id) { return queries_.run(id); }
Reply Station::run_with_duts(int64_t id) { return queries_.run_with_duts(id); }
Reply Station::edit_run(int64_t id, const MetadataEdit& edit, const std::string& changed_by) {
  return queries_.edit_run(id, edit, changed_by);
}
Reply Station::run_events(int64_t id) { return queries_.run_events(id); }
Reply Station::run_stats(int64_t id) { return queries_.run_stats(id); }
Reply Station::run_stats_filtered(int64_t id, const StatsQuery& query) {
  return queries_.run_stats_filtered(id, query);
}
Reply Station::run_fits(int64_t id) { return queries_.run_fits(id); }
Reply Station::run_allan(int64_t id) { return queries_.run_allan(id); }
Reply Station::run_scale_factor(int64_t id) { return queries_.run_scale_factor(id); }
Reply Station::run_samples(int64_t id, const SamplesQuery& query) {
  return queries_.run_channel_samples(id, query);  // no dut/channel: the first DUT's primary axis
}
Reply Station::run_channel_samples(int64_t id, const SamplesQuery& query) {
  return queries_.run_channel_samples(id, query);
}
Reply Station::fit(int64_t id) { return queries_.fit(id); }
Reply Station::exports() { return queries_.exports(); }
Reply Station::duts() { return queries_.duts(); }
Reply Station::dut_history(const std::string& serial) { return queries_.dut_history(serial); }

}  // namespace gyrotherm::station

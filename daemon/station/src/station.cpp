#include "gyrotherm/station/station.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <sys/statvfs.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <nlohmann/json.hpp>

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
#include "run_lifecycle.h"

namespace gyrotherm::station {
namespace {

// What the analysis worker tells the station: it waits for a soak's last
// gyro samples, logs and publishes each Table I row, and records each run's
// analysis in its events.
calibration::AnalysisWorker::Callbacks analysis_callbacks(
    DutAcquisition& duts,
    const std::function<void(std::string_view, const nlohmann::json&)>& publish,
    const WallClock& wall) {
  calibration::AnalysisWorker::Callbacks callbacks;
  callbacks.await_gyro = [&duts](int64_t run_id, double until_s) {
    if (!duts.await_gyro(run_id, until_s, kAwaitGyro)) {
      spdlog::warn(
          "run {}: Table I computed without the gyro samples after t = {:.1f} s (the stream had "
          "not reached the soak's end after {} ms)",
          run_id, until_s, kAwaitGyro.count());
    }
  };
  callbacks.table1_done = [publish](const calibration::Table1Job& job,
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
  callbacks.run_done = [publish, &wall](storage::Database& db, const calibration::RunJob& job,
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
  return callbacks;
}

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
                          [this] { return run_ && run_->active(); }});
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
  analysis_ = std::make_unique<calibration::AnalysisWorker>(
      config_.storage.db_path, *writer_, calibration::analysis_settings(config_),
      analysis_callbacks(*duts_, hooks_.publish, wall_), wall_);
  run_ = std::make_unique<RunLifecycle>(
      RunLifecycle::Links{config_, clock_, wall_, db_, *writer_, *analysis_, *plant_, *duts_,
                          table_.get(), *journal_, run_clock_, hooks_.publish, queue_length_,
                          queue_held_, busy_, control_ticks_, mu_, snapshot_});
  snapshot_.station_name = config_.station.name;
  snapshot_.time_scale = clock_.time_scale();
  snapshot_.clock = as_paced(clock_) ? "sim" : "scaled";
}

Station::~Station() { stop("daemon shutting down"); }

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
    run_->recover();
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
    run_->interrupt(reason);
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
  if (r.top_c && r.side_c) shell_rate_window_.push(now_s, (*r.top_c + *r.side_c) / 2.0);

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
  if (!run_->active() && !storage_file_error_)
    run_->start_next_run(now_s);  // no run into a lost file
  if (!run_->active()) keep_idle_safe();
  const double t_run_s = run_->active() ? run_->tick(now_s, r) : 0.0;
  publish_status(now_s, t_run_s, r);
  if (table_) {
    table_->finish_safe_state(wall_.monotonic_s());
    std::lock_guard lock(mu_);
    snapshot_.table = table_->status();
  }
  run_->end_if_finished();
}

void Station::publish_status(double now_s, double t_run_s, const schedules::Readings& r) {
  const Progress run_progress = run_->progress(t_run_s);
  std::lock_guard lock(mu_);
  StatusSnapshot& s = snapshot_;
  s.progress = run_progress;
  s.t_station_s = now_s;
  s.t_run_s = t_run_s;
  s.chamber_c = r.chamber_c;
  s.top_c = r.top_c;
  s.side_c = r.side_c;
  s.gradient_c = (r.top_c && r.side_c) ? std::optional<double>(*r.top_c - *r.side_c) : std::nullopt;
  const double rate = shell_rate_window_.slope_per_s();
  s.temp_rate_c_per_min = std::isfinite(rate) ? std::optional<double>(rate * 60.0) : std::nullopt;
  run_->fill_status(s);
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

// ---------------------------------------------------------------- StationControl
//
// The reads and queue edits are StationQueries' (station_queries.h); the
// run controls take the run's lock.

Reply Station::control(std::string_view action, const std::string& reason_in) {
  const std::string reason = reason_in.empty() ? "operator" : reason_in;
  std::lock_guard lock(run_mu_);
  if (action == "table-reset") return reset_table_faults(reason);
  Reply reply = run_->control(action, reason);
  // A queue released: the control loop starts its next entry now.
  if (action == "resume") wake_.notify_all();
  return reply;
}

Reply Station::reset_table_faults(const std::string& reason) {
  if (!table_device_) {
    return Reply::refused(Refusal::Kind::kConflict,
                          "this station has no rate table ([table] in the station config)");
  }
  // The driver serialises its requests with the control loop's.
  if (auto st = table_device_->reset_faults(); !st) {
    return Reply::refused(Refusal::Kind::kUnavailable,
                          fmt::format("table fault reset not done: {}", st.error().message));
  }
  const std::string message = fmt::format("table: fault reset by the operator ({})", reason);
  journal_->add_event("operator", "", "", message);
  spdlog::info("{}", message);
  return Reply::ok(
      {{"ok", true},
       {"message",
        fmt::format("{}: fault reset sent; the table_fault interlock clears at the "
                    "next reading without a fault{}",
                    table_device_->name(), run_->paused() ? "; `gyrotherm resume` goes on" : "")}});
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

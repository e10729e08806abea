// The station on a bench: a real Station (its database a real SQLite file,
// its samples through a real SampleWriter that a test can make fail as on a
// full disk) with fake devices and manual clocks, ticked by the test. No process, no
// socket, no pty: an hour of schedule runs in well under a second.
//
// The fakes share one FakePlant: the chamber's air follows its set point and
// the gyro's shell follows the air, each as a first-order lag; the gyro
// sends a constant rate plus a temperature term at its output rate. A test
// makes a device fall silent, raise an alarm or serve °F through the plant.
#pragma once

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <spdlog/sinks/ringbuffer_sink.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <span>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/devices.h"
#include "gyrotherm/station/station.h"
#include "gyrotherm/storage/sample_writer.h"
#include "integration/temp_dir_test.h"
#include "station/fake_table.h"

namespace gyrotherm::testing {

// The physics behind the fake devices. Thread-safe (the station's status()
// reads health from the HTTP thread in the daemon; here from the test).
class FakePlant {
 public:
  struct State {
    double air_c = 23.0;
    double shell_c = 23.0;
    double setpoint_c = 23.0;  // as written (°C; the plant converts °F)
    double air_tau_s = 20.0;
    double shell_tau_s = 40.0;
    bool chamber_silent = false;
    bool probes_silent = false;
    bool chamber_alarm = false;
    bool fahrenheit = false;            // the controller serves °F
    double side_offset_c = 0;           // added to the side probe
    std::optional<double> force_air_c;  // the air stays here whatever the set point
    bool refuse_setpoint = false;       // answers, but refuses set point writes
    int setpoint_writes = 0;            // taken
    int setpoint_write_attempts = 0;    // sent, silent or refused included
    // Set point writes ("setpoint 23") and table commands ("table stop"),
    // in the order they happened.
    std::vector<std::string> log;
    // Each set point write taken, with when (to order it against a table
    // peer's own log).
    std::vector<std::pair<double, std::chrono::steady_clock::time_point>> setpoints_at;
  };

  void advance(double dt_s) {
    std::lock_guard lock(mu_);
    if (s_.force_air_c) {
      s_.air_c = *s_.force_air_c;
    } else {
      s_.air_c += (s_.setpoint_c - s_.air_c) * (1 - std::exp(-dt_s / s_.air_tau_s));
    }
    s_.shell_c += (s_.air_c - s_.shell_c) * (1 - std::exp(-dt_s / s_.shell_tau_s));
  }
  template <class F>
  void change(F&& f) {
    std::lock_guard lock(mu_);
    f(s_);
  }
  State state() const {
    std::lock_guard lock(mu_);
    return s_;
  }

 private:
  mutable std::mutex mu_;
  State s_;
};

// Like a ModbusDevice, it holds its lock through each request, health()
// included; block() makes the next requests wait (a controller that does
// not answer within the response timeout) until release().
class FakeChamber final : public drivers::Chamber {
 public:
  explicit FakeChamber(std::shared_ptr<FakePlant> plant) : plant_(std::move(plant)) {}
  const std::string& name() const override { return name_; }
  Status connect() override { return Status::Ok(); }
  drivers::DeviceHealth health() const override {
    std::lock_guard io(io_mu_);
    std::lock_guard lock(mu_);
    return health_;
  }
  void block() {
    std::lock_guard lock(gate_mu_);
    blocked_ = true;
  }
  void release() {
    {
      std::lock_guard lock(gate_mu_);
      blocked_ = false;
    }
    gate_cv_.notify_all();
  }
  // A request is waiting in block().
  bool waiting() const { return waiting_.load(); }

  Result<drivers::UnitsReading> units() override {
    auto io = request();
    if (auto e = silent()) return *e;
    const bool f = plant_->state().fahrenheit;
    return drivers::UnitsReading{
        f ? drivers::TemperatureUnit::kFahrenheit : drivers::TemperatureUnit::kCelsius,
        f ? "units register = 30" : "units register = 15", f ? 30.0 : 15.0};
  }
  Result<double> process_value() override {
    auto io = request();
    if (auto e = silent()) return *e;
    const auto s = plant_->state();
    return s.fahrenheit ? s.air_c * 1.8 + 32 : s.air_c;
  }
  Result<double> setpoint() override {
    auto io = request();
    if (auto e = silent()) return *e;
    const auto s = plant_->state();
    return s.fahrenheit ? s.setpoint_c * 1.8 + 32 : s.setpoint_c;
  }
  Status write_setpoint(double value) override {
    auto io = request();
    plant_->change([](FakePlant::State& s) { ++s.setpoint_write_attempts; });
    if (auto e = silent()) return *e;
    if (plant_->state().refuse_setpoint) {
      return Error::Transient("chamber: set point write refused (fake: exception 4)");
    }
    plant_->change([&](FakePlant::State& s) {
      s.setpoint_c = s.fahrenheit ? (value - 32) / 1.8 : value;
      ++s.setpoint_writes;
      s.log.push_back(fmt::format("setpoint {:g}", s.setpoint_c));
      s.setpoints_at.emplace_back(s.setpoint_c, std::chrono::steady_clock::now());
    });
    return Status::Ok();
  }
  bool has_alarm() const override { return true; }
  Result<bool> alarm() override {
    auto io = request();
    if (auto e = silent()) return *e;
    return plant_->state().chamber_alarm;
  }

 private:
  std::unique_lock<std::mutex> request() {
    std::unique_lock io(io_mu_);
    std::unique_lock gate(gate_mu_);
    waiting_ = blocked_;
    gate_cv_.wait(gate, [this] { return !blocked_; });
    waiting_ = false;
    return io;
  }

  std::optional<Error> silent() {
    std::lock_guard lock(mu_);
    ++health_.requests;
    if (!plant_->state().chamber_silent) {
      health_.connected = true;
      return std::nullopt;
    }
    ++health_.errors;
    health_.connected = false;
    health_.last_error = "chamber: no answer (fake)";
    return Error::Transient(health_.last_error);
  }

  std::shared_ptr<FakePlant> plant_;
  std::string name_ = "chamber";
  mutable std::mutex io_mu_;  // held through a request
  mutable std::mutex mu_;
  drivers::DeviceHealth health_;
  std::mutex gate_mu_;
  std::condition_variable gate_cv_;
  bool blocked_ = false;
  std::atomic<bool> waiting_{false};
};

class FakeProbes final : public drivers::ShellProbes {
 public:
  explicit FakeProbes(std::shared_ptr<FakePlant> plant) : plant_(std::move(plant)) {}
  const std::string& name() const override { return name_; }
  Status connect() override { return Status::Ok(); }
  drivers::DeviceHealth health() const override { return {}; }
  Result<double> top_c() override {
    const auto s = plant_->state();
    if (s.probes_silent) return Error::Transient("probes: no answer (fake)");
    return s.shell_c;
  }
  Result<double> side_c() override {
    const auto s = plant_->state();
    if (s.probes_silent) return Error::Transient("probes: no answer (fake)");
    return s.shell_c + s.side_offset_c;
  }

 private:
  std::shared_ptr<FakePlant> plant_;
  std::string name_ = "probes";
};

// Sends samples when the test says so (emit_until), on the test's thread.
// The station's one DUT: a gyro whose channels are its rate (on `axis`, the
// config's primary axis), status and internal temperature, in that raw[]
// order.
class FakeGyro final : public drivers::DutSource {
 public:
  FakeGyro(std::shared_ptr<FakePlant> plant, double rate_hz, const std::string& axis = "z")
      : plant_(std::move(plant)), rate_hz_(rate_hz) {
    channels_ = {{"rate", "deg/h", ChannelKind::kRate, axis.empty() ? "z" : axis, 1.0},
                 {"status", "", ChannelKind::kStatus, "", 1.0},
                 {"temp_c", "degC", ChannelKind::kTemperature, "", 1.0}};
  }
  const std::vector<ChannelSpec>& channels() const override { return channels_; }
  void start(Sink sink) override { sink_ = std::move(sink); }
  void stop() override { sink_ = nullptr; }
  drivers::GyroReaderHealth health() const override { return {}; }

  // Frames from the last one sent up to `t_s` (station seconds), unless
  // muted: then they are lost (the stream resumes at `t_s`).
  void emit_until(double t_s) {
    if (k_ < 0) {
      t0_s_ = t_s;
      k_ = 0;
    }
    std::vector<DutFrame> batch;
    const double shell_c = plant_->state().shell_c;
    // Times as t0 + k / rate: no rounding accumulates, so the last frame of
    // a tick lands exactly on the clock.
    for (; t0_s_ + static_cast<double>(k_) / rate_hz_ <= t_s; ++k_) {
      DutFrame f;
      f.t_s = t0_s_ + static_cast<double>(k_) / rate_hz_;
      f.seq = static_cast<uint8_t>(seq_++ & 0x7f);
      if (walk_dphprh > 0) walk_dph_ += walk_dphprh / 60.0 / std::sqrt(rate_hz_) * normal_(rng_);
      f.raw[0] = bias_dph + drift_dph_per_c * (shell_c - 23.0) + walk_dph_ +
                 (noise_dph > 0 ? noise_dph * normal_(rng_) : 0.0);
      f.raw[1] = 0;
      f.raw[2] = static_cast<double>(std::lround(shell_c));
      batch.push_back(f);
    }
    if (muted) return;
    if (sink_ && !batch.empty()) sink_(batch);
  }

  bool muted = false;
  double bias_dph = 1.5;
  double drift_dph_per_c = 0.01;
  // Seeded noise (0: none): white, std per frame, and a rate random walk of
  // K °/h/√h.
  double noise_dph = 0;
  double walk_dphprh = 0;

 private:
  std::shared_ptr<FakePlant> plant_;
  double rate_hz_;
  std::vector<ChannelSpec> channels_;
  double t0_s_ = 0;
  int64_t k_ = -1;
  int seq_ = 0;
  Sink sink_;
  std::mt19937_64 rng_{20261130};
  std::normal_distribution<double> normal_;
  double walk_dph_ = 0;
};

// The station's samples go to a real SampleWriter through this; while
// `full` is set its commits fail as on a full disk: pushes are held, flush()
// fails, stats() shows the failing commits and what waits. Cleared, the held
// samples go to the writer in order.
class FullDiskSink final : public storage::SampleSink {
 public:
  explicit FullDiskSink(std::unique_ptr<storage::SampleWriter> writer)
      : writer_(std::move(writer)) {}

  void set_full(bool full) {
    std::lock_guard lock(mu_);
    full_ = full;
    if (full_) return;
    for (auto& [run_id, g] : held_gyro_) writer_->push_gyro(run_id, std::span(&g, 1));
    for (auto& [run_id, t] : held_temperatures_) writer_->push_temperature(run_id, t);
    for (auto& [run_id, t] : held_table_) writer_->push_table(run_id, t);
    for (auto& [dut, f] : held_frames_) writer_->push_frames(dut, std::span(&f, 1));
    held_frames_.clear();
    held_gyro_.clear();
    held_temperatures_.clear();
    held_table_.clear();
    failures_ = 0;
  }
  void push_gyro(int64_t run_id, std::span<const GyroSample> samples) override {
    std::lock_guard lock(mu_);
    if (!full_) return writer_->push_gyro(run_id, samples);
    for (const auto& g : samples) held_gyro_.emplace_back(run_id, g);
  }
  void push_temperature(int64_t run_id, const TemperatureSample& sample) override {
    std::lock_guard lock(mu_);
    if (!full_) return writer_->push_temperature(run_id, sample);
    held_temperatures_.emplace_back(run_id, sample);
  }
  void push_table(int64_t run_id, const TableSample& sample) override {
    std::lock_guard lock(mu_);
    if (!full_) return writer_->push_table(run_id, sample);
    held_table_.emplace_back(run_id, sample);
  }
  void push_frames(const storage::RunDutRecord& dut, std::span<const DutFrame> frames) override {
    std::lock_guard lock(mu_);
    if (!full_) return writer_->push_frames(dut, frames);
    for (const auto& f : frames) held_frames_.emplace_back(dut, f);
  }
  Status flush() override {
    {
      std::lock_guard lock(mu_);
      if (full_) return Error::Transient(kFull);
    }
    return writer_->flush();
  }
  void close_run(int64_t run_id) override { writer_->close_run(run_id); }
  void stop() override { writer_->stop(); }
  storage::SampleWriterStats stats() const override {
    std::lock_guard lock(mu_);
    storage::SampleWriterStats s = writer_->stats();
    if (full_) {
      s.consecutive_failures = s.commit_failures = ++failures_;
      s.last_error = kFull;
      s.pending +=
          held_gyro_.size() + held_temperatures_.size() + held_table_.size() + held_frames_.size();
    }
    return s;
  }

 private:
  static constexpr const char* kFull = "database or disk is full (bench)";
  std::unique_ptr<storage::SampleWriter> writer_;
  mutable std::mutex mu_;
  bool full_ = false;
  mutable uint64_t failures_ = 0;
  std::vector<std::pair<int64_t, GyroSample>> held_gyro_;
  std::vector<std::pair<int64_t, TemperatureSample>> held_temperatures_;
  std::vector<std::pair<int64_t, TableSample>> held_table_;
  std::vector<std::pair<storage::RunDutRecord, DutFrame>> held_frames_;
};

// What the default logger writes while it lives (the station's log).
// Create it before the rig opens its station and let it go after the
// station stopped: the logger's sinks are not changed while threads log.
class LogCapture {
 public:
  LogCapture() : sink_(std::make_shared<spdlog::sinks::ringbuffer_sink_mt>(4096)) {
    spdlog::default_logger()->sinks().push_back(sink_);
  }
  ~LogCapture() {
    auto& sinks = spdlog::default_logger()->sinks();
    sinks.erase(std::remove(sinks.begin(), sinks.end(), sink_), sinks.end());
  }
  LogCapture(const LogCapture&) = delete;
  LogCapture& operator=(const LogCapture&) = delete;
  std::string text() const {
    std::string out;
    for (const auto& line : sink_->last_formatted()) out += line;
    return out;
  }

 private:
  std::shared_ptr<spdlog::sinks::ringbuffer_sink_mt> sink_;
};

// A minimal station config for the rig: 1 s control ticks, no wall-time
// floor on device silence (the wall clock is manual), a safe set point of
// 21 °C (apart from the plant's 23 °C start, so a test can tell them).
inline std::string rig_config_toml(const std::string& db_path) {
  return "[station]\nname = \"bench\"\nlatitude_deg = 31.9\nsafe_setpoint_c = 21.0\n"
         "[chamber]\nport = 1502\n[probes]\nport = 1502\n[gyro]\ndevice = \"/dev/null\"\n"
         "rate_hz = 10\n"
         "[storage]\ndb = \"" +
         db_path +
         "\"\ncommit_interval_s = 0.05\n"
         "[control]\ntick_s = 1.0\nmin_silent_wall_s = 0\n";
}

// A rig's station and its devices; step() is one control tick.
class StationRig {
 public:
  // `config_toml`: a whole station config (rig_config_toml() by default).
  explicit StationRig(const std::filesystem::path& dir, std::string config_toml = {})
      : db_path_((dir / "station.db").string()),
        config_toml_(config_toml.empty() ? rig_config_toml(db_path_) : std::move(config_toml)) {}

  // Creates and starts a station over the database (ControlLoop::kCaller).
  void open() {
    auto cfg = config::parse_station_config(config_toml_, "rig.toml");
    ASSERT_TRUE(cfg.ok()) << cfg.error().message;
    station::StationDevices devices;
    auto chamber = std::make_unique<FakeChamber>(plant);
    chamber_ = chamber.get();
    devices.chamber = std::move(chamber);
    devices.probes = std::make_unique<FakeProbes>(plant);
    if (dut_plant) {
      devices.dut_probes.push_back(std::make_unique<FakeProbes>(dut_plant));
    }
    auto gyro =
        std::make_unique<FakeGyro>(plant, cfg->gyro.format.rate_hz, cfg->duts.front().primary_axis);
    gyro_ = gyro.get();
    devices.duts.push_back(std::move(gyro));
    if (cfg->table && make_table) {
      devices.table = make_table();
    } else if (cfg->table) {
      table.on_command = [plant = plant](const std::string& what) {
        plant->change([&](FakePlant::State& s) { s.log.push_back("table " + what); });
      };
      devices.table = std::make_unique<FakeTableHandle>(table);
    }
    station::StationHooks hooks;
    hooks.publish = [this](std::string_view event, const nlohmann::json& data) {
      {
        std::lock_guard lock(published_mu_);
        published_.push_back(std::string(event) + " " + data.dump());
      }
      if (on_publish) on_publish(event, data);
    };
    hooks.lab_status = lab_status;
    storage::SampleWriterOptions wopt;
    wopt.commit_interval = std::chrono::milliseconds(20);
    auto writer = storage::SampleWriter::start(cfg->storage.db_path, wopt, on_commit);
    ASSERT_TRUE(writer.ok()) << writer.error().message;
    auto sink = std::make_unique<FullDiskSink>(std::move(*writer));
    disk_ = sink.get();
    auto st = station::Station::create(*cfg, std::move(devices), {clock, wall}, std::move(hooks),
                                       std::move(sink));
    ASSERT_TRUE(st.ok()) << st.error().message;
    station = std::move(*st);
    station->start(station::Station::ControlLoop::kCaller);
  }
  // Stops the station (a run in progress is interrupted) and drops it.
  void close() {
    // At shutdown the station waits (wall time) for a spinning table to come
    // to rest: the fake table moves meanwhile.
    std::atomic<bool> stopped{false};
    std::thread mover([&] {
      while (!stopped) {
        table.advance(0.1);
        std::this_thread::sleep_for(std::chrono::milliseconds(2));
      }
    });
    if (station) station->stop("rig closed");
    stopped = true;
    mover.join();
    station.reset();
    gyro_ = nullptr;
    disk_ = nullptr;
    chamber_ = nullptr;
  }
  ~StationRig() { close(); }

  FakeGyro& gyro() { return *gyro_; }
  FullDiskSink& disk() { return *disk_; }
  FakeChamber& chamber() { return *chamber_; }

  // One control tick after `dt_s` station (and wall) seconds.
  void step(double dt_s = 1.0) {
    clock.advance(dt_s);
    wall.advance(dt_s);
    plant->advance(dt_s);
    table.advance(dt_s);
    if (gyro_) gyro_->emit_until(clock.now_s());
    station->tick();
  }
  // Ticks until `done()` or `max_station_s` of station time; true when done.
  bool step_until(const std::function<bool()>& done, double max_station_s, double dt_s = 1.0) {
    for (double t = 0; t <= max_station_s; t += dt_s) {
      if (done()) return true;
      step(dt_s);
    }
    return done();
  }

  // A schedule queued through the station's control interface.
  int64_t queue(const std::string& toml_text, bool ignore_failures = false) {
    auto r = station->queue_add(toml_text, "bench.toml", ignore_failures);
    EXPECT_FALSE(r.refusal) << r.refusal->message;
    return r.refusal ? 0 : r.body.at("id").get<int64_t>();
  }
  std::string state() const { return station->status().state; }
  nlohmann::json reply(const station::Reply& r) const {
    EXPECT_FALSE(r.refusal) << (r.refusal ? r.refusal->message : "");
    return r.body;
  }
  nlohmann::json events(int64_t run_id) { return reply(station->run_events(run_id)); }
  // Whether an event of `kind` whose message contains `text` is recorded.
  bool has_event(int64_t run_id, std::string_view kind, std::string_view text) {
    for (const auto& e : events(run_id)) {
      if (e.value("kind", "") == kind && e.value("message", "").find(text) != std::string::npos) {
        return true;
      }
    }
    return false;
  }
  std::vector<std::string> published() {
    std::lock_guard lock(published_mu_);
    return published_;
  }

  const std::string& db_path() const { return db_path_; }

  std::shared_ptr<FakePlant> plant = std::make_shared<FakePlant>();
  // Set before open(): the first DUT gets shell probes of its own over this
  // plant (its probes_silent silences them).
  std::shared_ptr<FakePlant> dut_plant;
  FakeTable table;  // the station's when the config has a [table] (and no make_table)
  // Set before open(): the station's table instead of the fake (a real
  // driver against a peer).
  std::function<std::unique_ptr<drivers::RateTable>()> make_table;
  // Called after each publication is recorded, on the publishing thread.
  std::function<void(std::string_view event, const nlohmann::json& data)> on_publish;
  // StationHooks::lab_status of the station open() creates (unset: no [lab]).
  std::function<std::optional<lab::RelayStatus>()> lab_status;
  // Called on the sample writer's thread after each commit (set before
  // open(); one that throws stops the writer thread).
  std::function<void(double seconds)> on_commit;
  ManualClock clock{1000.0, 1.0};
  ManualWallClock wall{1.8e9};
  std::unique_ptr<station::Station> station;

 private:
  std::string db_path_;
  std::string config_toml_;
  FakeGyro* gyro_ = nullptr;
  FullDiskSink* disk_ = nullptr;
  FakeChamber* chamber_ = nullptr;
  std::mutex published_mu_;
  std::vector<std::string> published_;
};

}  // namespace gyrotherm::testing

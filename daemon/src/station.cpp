#include "gyrotherm/daemon/station.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

namespace gyrotherm::daemon {
namespace {

using schedules::RunState;

double steady_now_s() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

std::string read_text(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

}  // namespace

Result<std::unique_ptr<Station>> Station::create(StationConfig config, const Clock& clock) {
  auto db = storage::Database::open(config.storage.db_path);
  if (!db) return db.error();
  storage::SampleWriterOptions wopt;
  wopt.commit_interval =
      std::chrono::milliseconds(static_cast<int64_t>(config.storage.commit_interval_s * 1000));
  auto writer = storage::SampleWriter::start(config.storage.db_path, wopt);
  if (!writer) return writer.error();
  return std::unique_ptr<Station>(
      new Station(std::move(config), clock, std::move(*db), std::move(*writer)));
}

Station::Station(StationConfig config, const Clock& clock, storage::Database db,
                 std::unique_ptr<storage::SampleWriter> writer)
    : config_(std::move(config)),
      clock_(clock),
      db_(std::move(db)),
      writer_(std::move(writer)),
      started_wall_s_(steady_now_s()) {
  analysis::Table1Options topt;
  topt.bin_s = config_.analysis.bin_s;
  topt.ma_window = static_cast<std::size_t>(config_.analysis.ma_window);
  topt.earth_rate_dph =
      analysis::earth_rate_component_dph(config_.station.latitude_deg, config_.station.orientation);
  analysis_ = std::make_unique<AnalysisWorker>(
      config_.storage.db_path, *writer_, topt,
      [](const Table1Job& job, const Result<storage::SegmentStatsRecord>& r) {
        if (r) {
          spdlog::info(
              "run {} segment {}: Table I row stored: n={} T={:.2f} °C bias={:.4f} °/h "
              "std={:.4f} std(MA{})={:.4f}",
              job.run_id, job.segment_index + 1, r->n, r->temp_mean_c, r->bias_mean_dph,
              r->bias_std_dph, r->ma_window, r->bias_std_ma_dph);
        } else {
          spdlog::error("Table I row not computed: {}", r.error().message);
        }
      });
  chamber_ = std::make_unique<drivers::ModbusDevice>("chamber", config_.chamber.endpoint);
  probes_ = std::make_unique<drivers::ModbusDevice>("probes", config_.probes.endpoint);
  auto parser = drivers::make_frame_parser(config_.gyro.protocol);
  gyro_ = std::make_unique<drivers::GyroReader>(
      config_.gyro.serial, config_.gyro.format, std::move(*parser), clock_,
      [this](std::span<const GyroSample> s) { on_gyro_samples(s); });
  snapshot_.station_name = config_.station.name;
  snapshot_.time_scale = clock_.time_scale();
}

Station::~Station() { stop("daemon shutting down"); }

schedules::StationLimits Station::limits() const {
  return {config_.station.min_temp_c, config_.station.max_temp_c,
          config_.station.max_ramp_c_per_min};
}

void Station::start() {
  for (auto* dev : {chamber_.get(), probes_.get()}) {
    if (auto st = dev->connect(); !st) {
      spdlog::warn("{}: {} (will keep retrying)", dev->name(), st.error().message);
    }
  }
  gyro_->start();
  control_thread_ = std::thread([this] { control_loop(); });
}

void Station::enqueue(schedules::Plan plan) {
  {
    std::lock_guard lock(mu_);
    pending_.push_back(std::move(plan));
  }
  wake_.notify_all();
}

bool Station::idle() const {
  std::lock_guard lock(mu_);
  return pending_.empty() && !busy_.load();
}

void Station::stop(const std::string& reason) {
  {
    std::lock_guard lock(mu_);
    if (stopping_) return;
    stopping_ = true;
  }
  wake_.notify_all();
  if (control_thread_.joinable()) control_thread_.join();
  // The control thread is gone: finish the run and the chamber from here.
  if (sequencer_ && !sequencer_->finished()) {
    sequencer_->interrupt(clock_.now_s() - run_t0_s_.load(), reason);
    end_run();
  }
  write_setpoint(config_.station.safe_setpoint_c, true);
  gyro_->stop();
  analysis_->stop();
  writer_->stop();
  spdlog::info("stopped ({}); chamber set point {:g} °C", reason, config_.station.safe_setpoint_c);
}

void Station::control_loop() {
  const double tick_s = config_.control.tick_s;
  const auto min_wall = std::chrono::duration<double>(config_.control.min_tick_wall_s);
  for (;;) {
    const auto wall_start = std::chrono::steady_clock::now();
    try {
      tick();
    } catch (const std::exception& e) {
      spdlog::error("control loop: {}", e.what());
    }
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

void Station::tick() {
  const double now_s = clock_.now_s();
  schedules::Readings r;
  auto read = [](drivers::ModbusDevice& dev, const drivers::RegisterSpec& spec, bool& ok,
                 std::optional<double>& out) {
    auto v = dev.read(spec);
    if (v) {
      out = *v;
      if (!ok) spdlog::info("{}: readings back", dev.name());
      ok = true;
    } else {
      if (ok) spdlog::warn("{}", v.error().message);
      ok = false;
    }
  };
  read(*chamber_, config_.chamber.map.process_value, chamber_ok_, r.chamber_c);
  read(*probes_, config_.probes.top, probes_ok_, r.top_c);
  if (r.top_c) read(*probes_, config_.probes.side, probes_ok_, r.side_c);

  std::optional<double> shell_c;
  if (r.top_c && r.side_c) {
    shell_c = (*r.top_c + *r.side_c) / 2.0;
    shell_rate_window_.push(now_s, *shell_c);
  }

  if (!sequencer_) {
    std::optional<schedules::Plan> next;
    {
      std::lock_guard lock(mu_);
      if (!pending_.empty() && !stopping_) {
        next = std::move(pending_.front());
        pending_.pop_front();
        busy_.store(true);
      }
    }
    if (next) start_run(std::move(*next), now_s);
  }

  double t_run_s = 0;
  if (sequencer_) {
    t_run_s = now_s - run_t0_s_.load();
    sequencer_->tick(t_run_s, r);
    write_setpoint(sequencer_->setpoint_c(), false);
    TemperatureSample ts;
    ts.t_s = t_run_s;
    ts.setpoint_c = sequencer_->setpoint_c();
    ts.chamber_c = r.chamber_c.value_or(kNaN);
    ts.top_c = r.top_c.value_or(kNaN);
    ts.side_c = r.side_c.value_or(kNaN);
    writer_->push_temperature(run_id_.load(), ts);
  }

  {
    std::lock_guard lock(mu_);
    StatusSnapshot& s = snapshot_;
    s.t_station_s = now_s;
    s.t_run_s = t_run_s;
    s.chamber_c = r.chamber_c;
    s.top_c = r.top_c;
    s.side_c = r.side_c;
    s.gradient_c =
        (r.top_c && r.side_c) ? std::optional<double>(*r.top_c - *r.side_c) : std::nullopt;
    const double rate = shell_rate_window_.slope_per_s();
    s.temp_rate_c_per_min = std::isfinite(rate) ? std::optional<double>(rate * 60.0) : std::nullopt;
    if (sequencer_) {
      s.state = std::string(to_string(sequencer_->state()));
      const auto idx = sequencer_->step_index();
      const auto& steps = sequencer_->plan().steps;
      s.step_index = static_cast<int>(idx);
      s.step_count = static_cast<int>(steps.size());
      s.step_label = idx < steps.size() ? steps[idx].label : "";
      s.setpoint_c = sequencer_->setpoint_c();
    }
  }
  if (sequencer_ && sequencer_->finished()) end_run();
}

void Station::write_setpoint(double setpoint_c, bool force) {
  ++ticks_since_setpoint_write_;
  const bool changed =
      !last_written_setpoint_c_ || std::abs(*last_written_setpoint_c_ - setpoint_c) > 1e-4;
  // Re-assert the set point now and then: a controller that was power-cycled
  // or changed by hand comes back to the schedule.
  if (!force && !changed && ticks_since_setpoint_write_ < 30) return;
  ticks_since_setpoint_write_ = 0;
  if (auto st = chamber_->write(config_.chamber.map.setpoint, setpoint_c); st) {
    last_written_setpoint_c_ = setpoint_c;
  } else {
    last_written_setpoint_c_.reset();  // retry next tick
    if (chamber_ok_) spdlog::warn("{}", st.error().message);
  }
}

void Station::start_run(schedules::Plan plan, double now_s) {
  storage::RunRecord rec;
  rec.schedule_name = plan.name;
  rec.state = "queued";
  rec.started_utc = wall_time_utc_iso();
  rec.time_scale = clock_.time_scale();
  rec.latitude_deg = config_.station.latitude_deg;
  rec.orientation = std::string(analysis::to_string(config_.station.orientation));
  rec.config_json = read_text(config_.source_path);
  auto id = db_.create_run(rec);
  if (!id) {
    spdlog::error("cannot start run of {}: {}", plan.name, id.error().message);
    busy_.store(false);
    return;
  }
  spdlog::info("run {}: {} ({} steps)", *id, plan.name, plan.steps.size());
  segment_ids_.assign(plan.steps.size(), 0);
  const double start_sp = last_written_setpoint_c_.value_or(
      snapshot_.chamber_c.value_or(config_.station.safe_setpoint_c));
  {
    std::lock_guard lock(mu_);
    snapshot_.run_id = *id;
    snapshot_.schedule_name = plan.name;
  }
  run_t0_s_.store(now_s);
  run_id_.store(*id);
  sequencer_ = std::make_unique<schedules::Sequencer>(
      std::move(plan), schedules::SequencerOptions{config_.station.safe_setpoint_c},
      static_cast<schedules::SequencerObserver&>(*this));
  sequencer_->start(0.0, start_sp);
}

void Station::end_run() {
  write_setpoint(sequencer_->setpoint_c(), true);
  run_id_.store(0);
  (void)writer_->flush();
  sequencer_.reset();
  std::lock_guard lock(mu_);
  snapshot_.run_id.reset();
  snapshot_.step_index.reset();
  snapshot_.step_label.clear();
  snapshot_.state = "idle";
  busy_.store(false);
}

void Station::on_gyro_samples(std::span<const GyroSample> samples) {
  const int64_t run_id = run_id_.load();
  if (run_id != 0) {
    thread_local std::vector<GyroSample> rel;
    rel.assign(samples.begin(), samples.end());
    const double t0 = run_t0_s_.load();
    for (auto& s : rel) s.t_s -= t0;
    writer_->push_gyro(run_id, rel);
  }
  std::lock_guard lock(mu_);
  for (const auto& s : samples) {
    if (gyro_window_start_s_ < 0 || s.t_s < gyro_window_start_s_) {
      gyro_window_start_s_ = std::floor(s.t_s);
      gyro_window_sum_ = 0;
      gyro_window_n_ = 0;
    }
    if (s.t_s >= gyro_window_start_s_ + 1.0) {
      if (gyro_window_n_ > 0) {
        snapshot_.gyro_rate_dph = gyro_window_sum_ / static_cast<double>(gyro_window_n_);
        snapshot_.gyro_samples_per_s = static_cast<double>(gyro_window_n_);
      }
      gyro_window_start_s_ = std::floor(s.t_s);
      gyro_window_sum_ = 0;
      gyro_window_n_ = 0;
    }
    gyro_window_sum_ += s.rate_dph;
    ++gyro_window_n_;
  }
}

StatusSnapshot Station::status() const {
  StatusSnapshot s;
  {
    std::lock_guard lock(mu_);
    s = snapshot_;
  }
  s.uptime_s = steady_now_s() - started_wall_s_;
  s.chamber = chamber_->health();
  s.probes = probes_->health();
  s.gyro = gyro_->health();
  s.storage = writer_->stats();
  return s;
}

void Station::add_event(const std::string& kind, const std::string& from, const std::string& to,
                        const std::string& message) {
  storage::EventRecord ev;
  const int64_t run_id = run_id_.load();
  if (run_id != 0) ev.run_id = run_id;
  ev.t_s = run_id != 0 ? clock_.now_s() - run_t0_s_.load() : 0.0;
  ev.wall_utc = wall_time_utc_iso();
  ev.kind = kind;
  ev.from_state = from;
  ev.to_state = to;
  ev.message = message;
  if (auto r = db_.add_event(ev); !r) spdlog::error("event not recorded: {}", r.error().message);
  std::lock_guard lock(mu_);
  snapshot_.last_event = message;
}

void Station::on_state(RunState from, RunState to, double t_s, const std::string& reason) {
  spdlog::info("run {} t={:.0f} s: {} -> {}: {}", run_id_.load(), t_s, to_string(from),
               to_string(to), reason);
  add_event("state", std::string(to_string(from)), std::string(to_string(to)), reason);
  if (auto st = db_.set_run_state(run_id_.load(), to_string(to), schedules::is_terminal(to)); !st) {
    spdlog::error("{}", st.error().message);
  }
}

void Station::on_step_started(std::size_t index, const schedules::PlanStep& step, double t_s) {
  storage::SegmentRecord seg;
  seg.run_id = run_id_.load();
  seg.index = static_cast<int>(index);
  seg.kind = std::string(schedules::to_string(step.kind));
  seg.label = step.label;
  seg.setpoint_c = step.setpoint_c;
  seg.ramp_rate_c_per_min = step.rate_c_per_min;
  seg.t_start_s = t_s;
  seg.state = "running";
  auto id = db_.create_segment(seg);
  if (!id) {
    spdlog::error("{}", id.error().message);
    return;
  }
  segment_ids_[index] = *id;
}

namespace {
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
  seg.state = std::move(state);
  return seg;
}
}  // namespace

void Station::on_acquisition_started(std::size_t index, const schedules::StepTimes& times) {
  const auto& step = sequencer_->plan().steps[index];
  if (auto st = db_.update_segment(
          segment_record(segment_ids_[index], run_id_.load(), index, step, times, "running"));
      !st) {
    spdlog::error("{}", st.error().message);
  }
}

void Station::on_step_finished(std::size_t index, const schedules::PlanStep& step,
                               const schedules::StepTimes& times, bool completed) {
  const int64_t run_id = run_id_.load();
  if (auto st = db_.update_segment(segment_record(segment_ids_[index], run_id, index, step, times,
                                                  completed ? "completed" : "aborted"));
      !st) {
    spdlog::error("{}", st.error().message);
  }
  if (completed && step.kind == schedules::StepKind::kSoak && times.acquire_start_s &&
      times.acquire_end_s) {
    analysis_->submit(Table1Job{run_id, segment_ids_[index], static_cast<int>(index),
                                step.setpoint_c, *times.acquire_start_s, *times.acquire_end_s});
  }
}

}  // namespace gyrotherm::daemon

#include "gyrotherm/sim/simulator.h"

#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <limits>
#include <nlohmann/json.hpp>
#include <thread>

#include "gyrotherm/analysis/table1.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/core/files.h"
#include "gyrotherm/drivers/kvh1750.h"
#include "gyrotherm/sim/aero_server.h"
#include "gyrotherm/sim/control_server.h"
#include "gyrotherm/sim/table_server.h"

namespace gyrotherm::sim {
namespace {

constexpr double kMaxStepS = 0.1;
constexpr double kMinSetpointC = -100.0;
constexpr double kMaxSetpointC = 200.0;
constexpr auto kTick = std::chrono::milliseconds(2);
// Work done per tick before the loop yields to publish registers and write
// frames, when the simulation cannot keep up with the clock.
constexpr auto kTickBudget = std::chrono::milliseconds(50);

// SplitMix64: independent seeds for the plant, the gyro and the faults.
std::size_t pending_frames_limit(const SimulatorOptions& o, double rate_hz) {
  if (o.pending_frames_limit > 0) return o.pending_frames_limit;
  // Five wall seconds of frames: a reader descheduled on a busy machine
  // catches up instead of losing samples (a real UART loses them sooner).
  const double five_wall_seconds = 5.0 * o.time_scale * rate_hz;
  return static_cast<std::size_t>(std::clamp(five_wall_seconds, 256.0, 1e7));
}

// The probe readings no finer than the probe registers can hold: an integer
// register's resolution is its scale (0.1 °C for int16 x 0.1).
SimulatorOptions honest_probe_quantum(SimulatorOptions o, const config::StationConfig& config) {
  for (const auto* spec : {&config.probes.top, &config.probes.side}) {
    if (spec->type != drivers::RegisterType::kFloat32) {
      o.thermal.probe_quantum_c = std::max(o.thermal.probe_quantum_c, std::abs(spec->scale));
    }
  }
  return o;
}

bool is_one_of(double v, std::initializer_list<uint16_t> values) {
  return std::any_of(values.begin(), values.end(), [&](uint16_t x) { return v == x; });
}

// A serial as a file-name part: what is not [A-Za-z0-9._-] becomes '_'.
std::string file_safe(std::string_view serial) {
  std::string out(serial);
  for (char& c : out) {
    const bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
                    c == '.' || c == '_' || c == '-';
    if (!ok) c = '_';
  }
  return out;
}

// The static soak temperatures the truth lists: every 5 °C over the
// station's range.
std::vector<double> static_temps_c(const config::StationSection& station) {
  std::vector<double> temps;
  for (double t = std::ceil(station.min_temp_c / 5.0) * 5.0; t <= station.max_temp_c + 1e-9;
       t += 5.0) {
    temps.push_back(t);
  }
  return temps;
}

// A DUT probe channel's register on the probe module: the profile's channel
// register; with custom registers, the top register's layout at that address.
Result<drivers::RegisterSpec> dut_probe_spec(const config::ProbesSection& probes, int channel) {
  if (probes.profile == "custom") {
    drivers::RegisterSpec spec = probes.top;
    spec.address = channel;
    spec.read_only = true;
    return spec;
  }
  return drivers::probe_channel_spec(probes.profile, channel);
}

bool same_register(const drivers::RegisterSpec& a, const drivers::RegisterSpec& b) {
  return a.function == b.function && a.address == b.address;
}

}  // namespace

Result<std::unique_ptr<Simulator>> Simulator::create(const config::StationConfig& config,
                                                     const SimulatorOptions& options,
                                                     const Clock* clock) {
  if (std::string why; !options.is_valid(&why)) return Error::Permanent(why);
  if (config.chamber.endpoint.unit_id == config.probes.endpoint.unit_id) {
    return Error::Permanent(fmt::format(
        "{}: chamber and probes share Modbus unit id {}; the simulator serves both on one "
        "port and needs distinct unit_id values",
        config.source_path, config.chamber.endpoint.unit_id));
  }
  if (config.chamber.map.setpoint.function != drivers::RegisterFunction::kHolding) {
    return Error::Permanent(fmt::format(
        "{}: the chamber set point register must be a holding register", config.source_path));
  }
  if (config.table && config.table->sensitive_axis != "along_table" &&
      config.table->sensitive_axis != "radial") {
    return Error::Permanent(
        fmt::format("{}: [table] sensitive_axis = '{}' must be along_table or radial",
                    config.source_path, config.table->sensitive_axis));
  }
  SimulatorOptions honest = honest_probe_quantum(options, config);
  const std::vector<config::DutSection> duts = simulated_duts(config);
  if (duts.empty()) return Error::Permanent(config.source_path + ": no DUT to simulate");
  std::optional<TableMount> mount;
  if (honest.serve_table || config.table) {
    TableMount m;
    m.latitude_deg = config.station.latitude_deg;
    m.full_scale_dps = honest.table.max_rate_dps;
    if (config.table) {
      m.axis = config.table->sensitive_axis == "radial" ? SensitiveAxis::kRadial
                                                        : SensitiveAxis::kAlongTable;
      m.heading_at_zero_deg = config.table->heading_at_zero_deg;
    }
    mount = m;
  }
  std::vector<std::unique_ptr<Dut>> sims;
  std::vector<drivers::RegisterSpec> probe_registers = {config.probes.top, config.probes.side};
  for (std::size_t p = 0; p < duts.size(); ++p) {
    config::DutSection dut = duts[p];
    // --rate-hz HZ for every DUT, SERIAL=HZ for one: the rate it is served
    // at, which its truth and the endpoints name.
    dut.link.rate_hz = dut_rate_hz(honest, dut);
    const int position = static_cast<int>(p);
    const DutSimParams params = resolve_dut_params(honest, dut, position);
    for (std::size_t i = 0; i < 3; ++i) {
      if (std::string why; !params.axes[i].is_valid(&why)) {
        return Error::Permanent(fmt::format("{}: [simulator.dut.{}.{}]: {}", config.source_path,
                                            dut.serial, kAxisNames[i], why));
      }
    }
    const uint64_t base = 16 + 4 * p;
    std::array<uint64_t, 3> axis_seeds{};
    for (std::size_t i = 0; i < 3; ++i) axis_seeds[i] = derive_seed(honest.seed, base + i);
    // The first DUT's primary axis draws from the stream the single gyro had.
    if (const int primary = primary_axis_index(dut); p == 0 && primary >= 0) {
      axis_seeds[static_cast<std::size_t>(primary)] = derive_seed(honest.seed, 2);
    }
    auto model = DutModel::create(dut, position, params, config.station, mount, honest.scale_factor,
                                  axis_seeds, derive_seed(honest.seed, base + 3));
    if (!model.ok()) {
      return Error::Permanent(fmt::format("{}: {}", config.source_path, model.error().message));
    }
    DutShell shell(honest.thermal, params.case_params, params.probe_offset_c,
                   derive_seed(honest.seed, 1000 + p));
    // The nominal frame size, for the stream's counters: one frame encoded by a copy.
    std::vector<uint8_t> sample;
    DutModel copy = *model;
    (void)copy.next_frame(shell.truth(), {}, sample);
    auto d = std::make_unique<Dut>(std::move(model).value(), std::move(shell), sample.size(),
                                   pending_frames_limit(honest, dut.link.rate_hz));
    d->probe_readings = d->shell.readings();
    d->fault_rng.seed(p == 0 ? derive_seed(honest.seed, 3) : derive_seed(honest.seed, 2000 + p));
    if (!honest.gyro_link.empty()) {
      d->link =
          p == 0 ? honest.gyro_link
                 : fmt::format("{}-{}", honest.gyro_link,
                               dut.serial.empty() ? std::to_string(p + 1) : file_safe(dut.serial));
    }
    if (dut.probes) {
      auto top = dut_probe_spec(config.probes, dut.probes->top_channel);
      auto side = dut_probe_spec(config.probes, dut.probes->side_channel);
      if (!top.ok() || !side.ok()) {
        return Error::Permanent(fmt::format("{}: DUT '{}' probes: {}", config.source_path,
                                            dut.serial,
                                            (!top.ok() ? top.error() : side.error()).message));
      }
      // A channel some other probe already uses is that probe: it is not
      // served twice (the station's pair wins, then earlier DUTs).
      auto unused = [&](const drivers::RegisterSpec& r) {
        return std::none_of(probe_registers.begin(), probe_registers.end(),
                            [&](const drivers::RegisterSpec& x) { return same_register(x, r); });
      };
      if (unused(*top)) {
        d->probe_top = *top;
        probe_registers.push_back(*top);
      }
      if (unused(*side)) {
        d->probe_side = *side;
        probe_registers.push_back(*side);
      }
    }
    sims.push_back(std::move(d));
  }
  return std::unique_ptr<Simulator>(
      new Simulator(config, std::move(honest), clock, std::move(sims)));
}

Simulator::Simulator(config::StationConfig config, SimulatorOptions options, const Clock* clock,
                     std::vector<std::unique_ptr<Dut>> duts)
    : config_(std::move(config)),
      options_(std::move(options)),
      own_clock_(clock ? nullptr : std::make_unique<ScaledClock>(options_.time_scale)),
      clock_(clock ? clock : own_clock_.get()),
      chamber_unit_(config_.chamber.endpoint.unit_id),
      probes_unit_(config_.probes.endpoint.unit_id),
      plant_(resolve_thermal_params(options_), derive_seed(options_.seed, 1)),
      duts_(std::move(duts)),
      setpoint_c_(options_.thermal.initial_temp_c),
      forced_chamber_c_(std::numeric_limits<double>::quiet_NaN()) {
  chamber_units_.store(options_.chamber_units);
  const bool table_served = options_.serve_table || config_.table.has_value();
  if (table_served) table_.emplace(options_.table, derive_seed(options_.seed, 4));
  for (const auto& d : duts_) step_s_ = std::min(step_s_, d->model.sample_period_s());
  step_s_ = std::min(step_s_, kMaxStepS);
  // Today's keys: the first DUT's primary axis; then every DUT.
  const Dut& first = *duts_.front();
  nlohmann::json truth = nlohmann::json::parse(
      first.model.axis_model(first.model.primary_axis()).truth_json(options_.seed));
  truth["duts"] = nlohmann::json::array();
  const std::vector<double> temps = static_temps_c(config_.station);
  truth["static_temps_c"] = temps;
  for (const auto& d : duts_)
    truth["duts"].push_back(d->model.truth(d->shell, temps, table_served));
  // [simulator.randomize]: the ranges; what was drawn is in "duts".
  nlohmann::json ranges = nlohmann::json::object();
  const RandomizeRanges& rr = options_.randomize;
  for (const auto& [key, range] :
       {std::pair{"white_noise_dph", &rr.white_noise_dph},
        std::pair{"bias_instability_dph", &rr.bias_instability_dph},
        std::pair{"rate_random_walk_dph_per_sqrt_h", &rr.rate_random_walk_dph_per_sqrt_h},
        std::pair{"case_tau_s", &rr.case_tau_s}, std::pair{"air_tau_s", &rr.air_tau_s},
        std::pair{"control_noise_c", &rr.control_noise_c}}) {
    if (*range) ranges[key] = {(*range)->lo, (*range)->hi};
  }
  truth["randomize"] = ranges;
  // The chamber's plant as it runs (drawn values included).
  const ThermalParams& plant = plant_.params();
  truth["chamber"] = {{"air_tau_s", plant.air_tau_s},
                      {"control_noise_c", plant.control_noise_c},
                      {"control_noise_tau_s", plant.control_noise_tau_s},
                      {"max_ramp_c_per_min", plant.max_ramp_c_per_min}};
  truth_json_ = truth.dump(2) + "\n";
  status_.setpoint_c = options_.thermal.initial_temp_c;
  status_.truth = plant_.truth();
  status_.readings = plant_.readings();
}

Simulator::~Simulator() { stop(); }

Status Simulator::start() {
  std::lock_guard life(life_mu_);
  if (thread_.joinable()) return Status::Ok();

  const auto& map = config_.chamber.map;
  ModbusServer::Options server_options;
  server_options.host = options_.modbus_host;
  server_options.port = options_.modbus_port;
  ModbusServer::Device chamber{chamber_unit_, {map.setpoint, map.process_value}, {}};
  for (const auto* extra : {&map.ramp_rate, &map.ramp_action, &map.ramp_scale}) {
    if (*extra) chamber.registers.push_back(**extra);
  }
  if (map.alarm) chamber.registers.push_back(map.alarm->reg);  // read-only (config)
  if (map.units) {
    drivers::RegisterSpec units = map.units->reg;
    units.read_only = true;  // set at the controller (menus), not by a client
    chamber.registers.push_back(units);
  }
  chamber.accept_write = [this](const drivers::RegisterSpec& spec, double value) {
    const auto& map = config_.chamber.map;
    const auto same = [&](const std::optional<drivers::RegisterSpec>& r) {
      return r && r->function == spec.function && r->address == spec.address;
    };
    if (spec.function == map.setpoint.function && spec.address == map.setpoint.address) {
      const double c = drivers::to_celsius(value, chamber_units_.load());
      const bool ok = std::isfinite(c) && c >= kMinSetpointC && c <= kMaxSetpointC;
      if (!ok) {
        std::lock_guard lock(sim_mu_);
        ++status_.setpoint_writes_rejected;
      }
      return ok;
    }
    namespace w = drivers::watlow;
    if (same(map.ramp_action)) {
      return is_one_of(value, {w::kOff, w::kStartup, w::kSetPointChange, w::kBoth});
    }
    if (same(map.ramp_scale)) return is_one_of(value, {w::kMinutes, w::kHours});
    if (same(map.ramp_rate)) return std::isfinite(value) && value >= 0;
    return true;
  };
  ModbusServer::Device probes{probes_unit_, {config_.probes.top, config_.probes.side}, {}};
  for (const auto& d : duts_) {
    for (const auto* r : {&d->probe_top, &d->probe_side}) {
      if (*r) probes.registers.push_back(**r);
    }
  }
  server_options.devices = {chamber, probes};
  server_options.on_write = [this](int unit_id) { on_modbus_write(unit_id); };
  auto server = ModbusServer::start(std::move(server_options));
  if (!server.ok()) return server.error();
  server_ = std::move(server).value();
  modbus_port_.store(server_->port());

  // Initial image: the controller's set point and ramp settings (ramping
  // off, as an F4T ships), then the plant.
  {
    const auto unit = chamber_units_.load();
    (void)server_->set(chamber_unit_, map.setpoint,
                       drivers::from_celsius(setpoint_c_.load(), unit));
    if (map.units) (void)server_->set(chamber_unit_, map.units->reg, map.units->encode(unit));
    if (map.ramp_rate) {
      // A rate (per minute): °F/min = 1.8 °C/min.
      const double per_c = unit == drivers::TemperatureUnit::kCelsius ? 1.0 : 1.8;
      (void)server_->set(chamber_unit_, *map.ramp_rate, plant_.params().max_ramp_c_per_min * per_c);
    }
  }
  if (map.ramp_action) (void)server_->set(chamber_unit_, *map.ramp_action, drivers::watlow::kOff);
  if (map.ramp_scale) {
    (void)server_->set(chamber_unit_, *map.ramp_scale, drivers::watlow::kMinutes);
  }
  if (map.alarm) (void)server_->set(chamber_unit_, map.alarm->reg, map.alarm->quiet_value());
  publish_registers();

  auto fail = [&](Error e) -> Status {
    control_.reset();  // never served: no command can be waiting for life_mu_
    table_server_.reset();
    aero_server_.reset();
    acl_serial_server_.reset();
    aero_tcp_server_.reset();
    release_modbus_server();
    std::lock_guard lock(stream_mu_);
    for (auto& d : duts_) d->stream.close();
    return e;
  };
  {
    std::lock_guard lock(stream_mu_);
    for (std::size_t i = 0; i < duts_.size(); ++i) {
      if (Status s = duts_[i]->stream.open(); !s.ok()) return fail(s.error());
      if (Status s = point_gyro_link_locked(i); !s.ok()) return fail(s.error());
    }
  }
  if (table_) {
    TableServer::Options table_options;
    table_options.host = options_.modbus_host;
    table_options.port = options_.table_port;
    table_options.handler = [this](std::string_view line) {
      return frame_acl_reply(table_acl(line), options_.table.reply_header);
    };
    auto table_server = TableServer::start(std::move(table_options));
    if (!table_server.ok()) return fail(table_server.error());
    table_server_ = std::move(table_server).value();
    auto aero = AeroServer::start([this](std::string_view line) {
      std::lock_guard lock(sim_mu_);
      return handle_aero_line(*table_, line);
    });
    if (!aero.ok()) return fail(aero.error());
    aero_server_ = std::move(aero).value();
    // Each protocol on the other transport too ([table] transport): ACL on
    // a pty (TM-9411's RS-232 interface) and AERO over TCP (a serial device
    // server), the same table behind both.
    auto acl_serial = AeroServer::start([this](std::string_view line) {
      return frame_acl_reply(table_acl(line), options_.table.reply_header);
    });
    if (!acl_serial.ok()) return fail(acl_serial.error());
    acl_serial_server_ = std::move(acl_serial).value();
    TableServer::Options aero_tcp_options;
    aero_tcp_options.host = options_.modbus_host;
    aero_tcp_options.handler = [this](std::string_view line) {
      std::lock_guard lock(sim_mu_);
      return handle_aero_line(*table_, line);
    };
    auto aero_tcp = TableServer::start(std::move(aero_tcp_options));
    if (!aero_tcp.ok()) return fail(aero_tcp.error());
    aero_tcp_server_ = std::move(aero_tcp).value();
    apply_table_link_faults();
  }
  if (!options_.control_socket.empty()) {
    ControlServer::Options control_options;
    control_options.path = options_.control_socket;
    auto control = ControlServer::open(std::move(control_options));
    if (!control.ok()) return fail(control.error());
    control_ = std::move(control).value();
  }
  if (!options_.truth_file.empty()) {
    if (Status s = write_file_creating_folders(options_.truth_file, truth_json_); !s.ok()) {
      return fail(Error::Permanent("cannot write the truth file: " + s.error().message));
    }
  }
  if (options_.shared_clock && own_clock_ && !options_.endpoints_file.empty()) {
    auto map = SharedClockMap::create(options_.endpoints_file + ".clock", options_.time_scale, 0.0);
    if (!map.ok()) return fail(map.error());
    shared_clock_ = std::make_unique<SharedClockOwner>(std::move(map).value());
  }
  {
    std::lock_guard lock(sim_mu_);
    t0_s_ = clock_->now_s();
    status_.running = true;
    if (shared_clock_) status_.clock_file = shared_clock_->path();
  }
  {
    std::lock_guard lock(wake_mu_);
    stopping_ = false;
  }
  thread_ = std::thread([this] { run(); });
  if (!options_.endpoints_file.empty()) {
    if (Status s = write_endpoints_file(); !s.ok()) {
      {
        std::lock_guard lock(wake_mu_);
        stopping_ = true;
      }
      wake_cv_.notify_all();
      thread_.join();
      std::lock_guard lock(sim_mu_);
      status_.running = false;
      return fail(Error::Permanent("cannot write the endpoints file: " + s.error().message));
    }
    wrote_endpoints_ = true;
  }
  // Last: a command may need life_mu_, which start() holds.
  if (control_)
    control_->serve([this](std::string_view line) { return handle_control_line(*this, line); });
  return Status::Ok();
}

void Simulator::stop() {
  // The control server first, without life_mu_: a command it is running may
  // be waiting for it.
  std::unique_ptr<ControlServer> control;
  {
    std::lock_guard life(life_mu_);
    control = std::move(control_);
  }
  control.reset();

  std::lock_guard life(life_mu_);
  if (!thread_.joinable()) return;
  {
    std::lock_guard lock(wake_mu_);
    stopping_ = true;
  }
  wake_cv_.notify_all();
  thread_.join();
  release_modbus_server();
  table_server_.reset();  // their threads take sim_mu_ only
  aero_server_.reset();
  acl_serial_server_.reset();
  aero_tcp_server_.reset();
  {
    std::lock_guard lock(stream_mu_);
    for (auto& d : duts_) d->stream.close();
  }
  std::error_code ec;
  if (wrote_endpoints_) {
    std::filesystem::remove(options_.endpoints_file, ec);
    wrote_endpoints_ = false;
  }
  if (shared_clock_) {
    std::filesystem::remove(shared_clock_->path(), ec);
    shared_clock_.reset();
  }
  for (const auto& d : duts_) {
    if (!d->link.empty()) std::filesystem::remove(d->link, ec);
  }
  std::lock_guard lock(sim_mu_);
  status_.running = false;
}

void Simulator::release_modbus_server() {
  if (!server_) return;
  // Its thread first: a write it is answering calls on_modbus_write(), which
  // reads server_. Released while that thread still ran, the pointer was
  // already null there (a segfault on SIGTERM while a client wrote).
  server_->stop();
  server_.reset();
}

Status Simulator::point_gyro_link_locked(std::size_t i) {
  const Dut& d = *duts_[i];
  if (d.link.empty()) return Status::Ok();
  namespace fs = std::filesystem;
  const GyroStream& stream = d.stream;
  const fs::path link(d.link);
  const fs::path tmp = link.string() + ".tmp";
  std::error_code ec;
  if (link.has_parent_path()) fs::create_directories(link.parent_path(), ec);
  fs::remove(tmp, ec);
  fs::create_symlink(stream.slave_path(), tmp, ec);
  if (!ec) fs::rename(tmp, link, ec);  // atomic: readers never see no link
  if (ec) {
    return Error::Permanent(
        fmt::format("cannot point {} at {}: {}", link.string(), stream.slave_path(), ec.message()));
  }
  return Status::Ok();
}

Status Simulator::write_endpoints_file() {
  return config::write_sim_endpoints(options_.endpoints_file, endpoints());
}

config::SimEndpoints Simulator::endpoints() const {
  config::SimEndpoints ep;
  ep.modbus_host = options_.modbus_host;
  ep.modbus_port = modbus_port_.load();
  {
    std::lock_guard lock(stream_mu_);
    ep.gyro_device = device_locked(0);
    for (std::size_t i = 0; i < duts_.size(); ++i) {
      ep.dut_devices.emplace_back(duts_[i]->model.dut().serial, device_locked(i));
      ep.dut_rates_hz.emplace_back(duts_[i]->model.dut().serial,
                                   duts_[i]->model.dut().link.rate_hz);
    }
  }
  ep.pid = static_cast<long>(::getpid());
  ep.control_socket = options_.control_socket;
  ep.time_scale = clock_->time_scale();
  if (shared_clock_) ep.clock_file = shared_clock_->path();
  if (table_server_) ep.table_port = table_server_->port();
  if (aero_server_) ep.table_device = aero_server_->device();
  if (acl_serial_server_) ep.table_acl_device = acl_serial_server_->device();
  if (aero_tcp_server_) ep.table_aero_port = aero_tcp_server_->port();
  return ep;
}

std::string Simulator::device_locked(std::size_t i) const {
  const Dut& d = *duts_[i];
  return d.link.empty() ? d.stream.slave_path() : d.link;
}

std::vector<std::string> Simulator::dut_serials() const {
  std::vector<std::string> serials;
  for (const auto& d : duts_) serials.push_back(d->model.dut().serial);
  return serials;
}

std::optional<std::size_t> Simulator::find_dut(std::string_view serial) const {
  for (std::size_t i = 0; i < duts_.size(); ++i) {
    if (duts_[i]->model.dut().serial == serial) return i;
  }
  return std::nullopt;
}

SimulatorStatus Simulator::status() const {
  std::lock_guard life(life_mu_);
  SimulatorStatus s;
  {
    std::lock_guard lock(sim_mu_);
    s = status_;
  }
  s.duts.resize(duts_.size());
  {
    std::lock_guard lock(sim_mu_);
    for (std::size_t i = 0; i < duts_.size(); ++i) {
      const Dut& d = *duts_[i];
      DutSimStatus& ds = s.duts[i];
      ds.serial = d.model.dut().serial;
      ds.shell = d.shell.truth();
      if (d.probe_top || d.probe_side) ds.probe_readings = d.probe_readings;
      ds.has_probe_top = d.probe_top.has_value();
      ds.has_probe_side = d.probe_side.has_value();
      ds.probe_top_stalled = d.probe_stalled[0].load();
      ds.probe_side_stalled = d.probe_stalled[1].load();
      ds.last_rates_dph = d.model.last().rate_dph;
      ds.frames_generated = d.frames_generated;
      ds.frames_fault_dropped = d.frames_fault_dropped;
      ds.frames_fault_corrupted = d.frames_fault_corrupted;
    }
  }
  {
    std::lock_guard lock(stream_mu_);
    for (std::size_t i = 0; i < duts_.size(); ++i) {
      const Dut& d = *duts_[i];
      DutSimStatus& ds = s.duts[i];
      ds.device = device_locked(i);
      ds.stream = d.stream.stats();
      ds.pty_open = d.stream.is_open();
      ds.pty_held = d.stream.held();
    }
  }
  for (std::size_t i = 0; i < duts_.size(); ++i) {
    s.duts[i].frame_corruption_rate = duts_[i]->corruption_rate.load();
    s.duts[i].frame_drop_rate = duts_[i]->drop_rate.load();
  }
  s.stream = s.duts[0].stream;
  s.setpoint_c = setpoint_c_.load();
  s.ramp_limit_c_per_min = ramp_limit_c_per_min_.load();
  SimulatorFaults& f = s.faults;
  if (server_) {
    s.modbus = server_->stats();
    f.modbus_down = server_->down();
    f.modbus_reply_delay_s = server_->reply_delay_s();
  }
  f.pty_open = s.duts[0].pty_open;
  f.pty_held = s.duts[0].pty_held;
  f.frame_corruption_rate = s.duts[0].frame_corruption_rate;
  f.frame_drop_rate = s.duts[0].frame_drop_rate;
  f.top_stalled = stalled_[0].load();
  f.side_stalled = stalled_[1].load();
  f.chamber_alarm = chamber_alarm_.load();
  f.chamber_units = chamber_units_.load();
  if (const double forced = forced_chamber_c_.load(); !std::isnan(forced)) {
    f.chamber_forced_c = forced;
  }
  if (table_) {
    TableStatus& t = s.table;
    t.served = true;
    {
      std::lock_guard lock(sim_mu_);
      t.state = table_->state();
    }
    t.hung = table_hung_.load();
    t.disconnected = table_disconnected_.load();
    if (table_server_) {
      t.port = table_server_->port();
      const TableServerStats stats = table_server_->stats();
      t.acl_requests = stats.requests;
      t.acl_unanswered = stats.unanswered;
      t.acl_refused_connections = stats.refused_connections;
    }
    if (aero_server_) {
      t.device = aero_server_->device();
      t.aero_requests = aero_server_->requests();
    }
    if (acl_serial_server_) {
      t.acl_device = acl_serial_server_->device();
      t.acl_serial_requests = acl_serial_server_->requests();
    }
    if (aero_tcp_server_) {
      t.aero_port = aero_tcp_server_->port();
      t.aero_tcp_requests = aero_tcp_server_->stats().requests;
    }
  }
  return s;
}

void Simulator::run() {
  if (shared_clock_) return run_paced();
  std::unique_lock lock(wake_mu_);
  while (!stopping_) {
    lock.unlock();
    advance_to(clock_->now_s() - t0_s_);
    publish_registers();
    (void)write_batches();
    lock.lock();
    wake_cv_.wait_for(lock, kTick, [this] { return stopping_; });
  }
}

bool Simulator::write_batches() {
  std::lock_guard stream_lock(stream_mu_);
  bool all_taken = true;
  for (auto& d : duts_) {
    if (d->model.ascii()) {
      d->stream.write_frames(d->batch, d->batch_sizes);
    } else {
      d->stream.write_frames(d->batch);
    }
    d->batch.clear();
    d->batch_sizes.clear();
    if (!d->stream.is_open() || d->stream.held()) continue;
    d->stream.flush();
    if (d->stream.stats().pending_bytes > 0 && d->stream.stats().readers != 0) all_taken = false;
  }
  return all_taken;
}

// Station time is this loop's: it advances at most time_scale x wall time,
// never past what the daemon's consumers allow (their slowest mark plus the
// lead, SharedClockOwner::limit_s()), and is published only once every open
// line has taken its frames up to it. A busy machine slows it down; it never
// runs ahead of the streams or of the daemon. Time the loop did not run is
// not made up afterwards.
void Simulator::run_paced() {
  using steady = std::chrono::steady_clock;
  const double scale = options_.time_scale;
  auto wall_prev = steady::now();
  // A line whose reader takes nothing while the daemon is attached (its
  // reader is not running) holds the clock this long at most.
  constexpr auto kLineWaitMax = std::chrono::seconds(2);
  std::optional<steady::time_point> line_wait_since;
  // Station seconds the loop may still run: scaled wall time accumulates
  // here across iterations (one iteration's wall time times a low scale is
  // less than a step), at most a quarter wall second's worth.
  double credit_s = 0;
  double t_s = 0;
  {
    std::lock_guard lock(sim_mu_);
    t_s = status_.t_s;
  }
  shared_clock_->publish(t_s);
  for (;;) {
    {
      std::lock_guard lock(wake_mu_);
      if (stopping_) return;
    }
    const auto wall_now = steady::now();
    const double wall_dt_s = std::chrono::duration<double>(wall_now - wall_prev).count();
    wall_prev = wall_now;

    // Frames still waiting for a line: nothing new until they are taken.
    if (!write_batches() && shared_clock_->consumer_attached()) {
      if (!line_wait_since) line_wait_since = wall_now;
      if (wall_now - *line_wait_since < kLineWaitMax) {
        std::lock_guard lock(sim_mu_);
        status_.clock_line_wait_wall_s += wall_dt_s;
        std::this_thread::sleep_for(std::chrono::microseconds(500));
        continue;
      }
    } else {
      line_wait_since.reset();
    }
    {
      std::lock_guard lock(sim_mu_);
      t_s = status_.t_s;
    }
    shared_clock_->publish(t_s);

    const double limit_s = shared_clock_->limit_s();
    // Without a daemon on this clock the simulation keeps up with scaled
    // wall time, as on its own clock (a daemon on a scaled clock expects
    // that), from where the last daemon let it go; with one it runs no
    // further than the daemon allows and never makes up lost time.
    double target_s;
    if (std::isinf(limit_s)) {
      if (!free_running_) {
        free_offset_s_ = (clock_->now_s() - t0_s_) - t_s;
        free_running_ = true;
      }
      target_s = clock_->now_s() - t0_s_ - free_offset_s_;
    } else {
      free_running_ = false;
      credit_s = std::min(credit_s + wall_dt_s * scale, 0.25 * scale);
      target_s = std::min(t_s + credit_s, limit_s);
    }
    if (target_s >= t_s + step_s_ - 1e-9) {
      const double from_s = t_s;
      advance_to(target_s);
      publish_registers();
      double advanced_to_s = 0;
      {
        std::lock_guard lock(sim_mu_);
        advanced_to_s = status_.t_s;
      }
      credit_s = std::max(0.0, credit_s - (advanced_to_s - from_s));
      if (write_batches()) t_s = advanced_to_s;
      shared_clock_->publish(t_s);
    }
    if (limit_s < t_s + step_s_ - 1e-9) {
      // Held: the daemon has not caught up. Woken by its next mark.
      const auto held_from = steady::now();
      shared_clock_->wait_for_consumers(std::chrono::milliseconds(20));
      std::lock_guard lock(sim_mu_);
      status_.clock_held_wall_s += std::chrono::duration<double>(steady::now() - held_from).count();
    } else {
      std::unique_lock lock(wake_mu_);
      wake_cv_.wait_for(lock, kTick, [this] { return stopping_; });
    }
  }
}

void Simulator::advance_to(double target_s) {
  std::lock_guard lock(sim_mu_);
  const double step_s = step_s_;
  const double setpoint_c = setpoint_c_.load();
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  plant_.set_ramp_limit_c_per_min(ramp_limit_c_per_min_.load());
  if (const double forced = forced_chamber_c_.load(); std::isnan(forced)) {
    plant_.force_air_c(std::nullopt);
  } else {
    plant_.force_air_c(forced);
  }
  struct Faults {
    double corruption, drop;
  };
  std::vector<Faults> faults;
  faults.reserve(duts_.size());
  for (const auto& d : duts_) faults.push_back({d->corruption_rate.load(), d->drop_rate.load()});

  const auto budget_end = std::chrono::steady_clock::now() + kTickBudget;
  int64_t done = 0;
  // (with a little slack: a target of 298.0 reached in steps of 0.1 is 2980
  // steps, though 2980 * 0.1 is 298.00000000000006)
  while (static_cast<double>(steps_ + 1) * step_s <= target_s + 1e-9) {
    plant_.step(step_s, setpoint_c);
    TableInput table_input;
    if (table_) {
      table_->step(step_s);
      table_input.rate_dps = table_->rate_dps();  // the true rate, not the measured one
      table_input.position_deg = table_->unwrapped_position_deg();
    }
    ++steps_;
    const double t_s = static_cast<double>(steps_) * step_s;
    for (std::size_t i = 0; i < duts_.size(); ++i) {
      Dut& d = *duts_[i];
      d.shell.step(step_s, plant_.truth());
      if (!d.probe_stalled[0].load()) d.probe_readings.top_c = d.shell.readings().top_c;
      if (!d.probe_stalled[1].load()) d.probe_readings.side_c = d.shell.readings().side_c;
      const double period_s = d.model.sample_period_s();
      const bool ascii = d.model.ascii();
      while (static_cast<double>(d.next_frame) * period_s <= t_s + 1e-9) {
        ++d.next_frame;
        ++d.frames_generated;
        const std::size_t begin = d.batch.size();
        (void)d.model.next_frame(d.shell.truth(), table_input, d.batch);
        if (faults[i].drop > 0 && uniform(d.fault_rng) < faults[i].drop) {
          d.batch.resize(begin);  // its sequence number is used: the reader sees a gap
          ++d.frames_fault_dropped;
          continue;
        }
        const std::size_t size = d.batch.size() - begin;
        if (faults[i].corruption > 0 && uniform(d.fault_rng) < faults[i].corruption) {
          uint8_t* frame = d.batch.data() + begin;
          if (ascii) {
            // A character no field, delimiter or checksum can hold, before
            // the line's terminator: the line no longer parses.
            const std::size_t body = size > 2 ? size - 2 : 1;
            const std::size_t index = d.fault_rng() % body;
            frame[index] = frame[index] == '~' ? '^' : '~';
          } else {
            // One byte after the header changes; CRC-32 catches every such error.
            const std::size_t index = 4 + d.fault_rng() % (size - 4);
            frame[index] ^= static_cast<uint8_t>(1 + d.fault_rng() % 255);
          }
          ++d.frames_fault_corrupted;
        }
        if (ascii) d.batch_sizes.push_back(size);
      }
    }
    if ((++done & 255) == 0 && std::chrono::steady_clock::now() > budget_end) break;
  }
  status_.t_s = static_cast<double>(steps_) * step_s;
  status_.lag_s = std::max(0.0, target_s - status_.t_s - step_s);
  status_.truth = plant_.truth();
  if (!stalled_[0].load()) status_.readings.top_c = plant_.readings().top_c;
  if (!stalled_[1].load()) status_.readings.side_c = plant_.readings().side_c;
  const Dut& first = *duts_.front();
  status_.last_rate_dph =
      first.model.last().rate_dph[static_cast<std::size_t>(first.model.primary_axis())];
  status_.frames_generated = first.frames_generated;
  status_.frames_fault_dropped = first.frames_fault_dropped;
  status_.frames_fault_corrupted = first.frames_fault_corrupted;
}

void Simulator::publish_registers() {
  double air_c, top_c, side_c;
  std::vector<ProbeReadings> dut_readings;
  {
    std::lock_guard lock(sim_mu_);
    air_c = status_.truth.air_c;
    top_c = status_.readings.top_c;
    side_c = status_.readings.side_c;
    for (const auto& d : duts_) dut_readings.push_back(d->probe_readings);
  }
  for (std::size_t i = 0; i < duts_.size(); ++i) {
    const Dut& d = *duts_[i];
    if (d.probe_top) (void)server_->set(probes_unit_, *d.probe_top, dut_readings[i].top_c);
    if (d.probe_side) (void)server_->set(probes_unit_, *d.probe_side, dut_readings[i].side_c);
  }
  // A value that does not fit its register (e.g. int16 x 0.1 beyond 3276.7)
  // leaves the register as it was.
  {
    std::lock_guard lock(units_mu_);
    (void)server_->set(chamber_unit_, config_.chamber.map.process_value,
                       drivers::from_celsius(air_c, chamber_units_.load()));
  }
  (void)server_->set(probes_unit_, config_.probes.top, top_c);
  (void)server_->set(probes_unit_, config_.probes.side, side_c);
  if (const auto& alarm = config_.chamber.map.alarm) {
    std::lock_guard lock(alarm_mu_);
    (void)server_->set(chamber_unit_, alarm->reg,
                       chamber_alarm_.load() ? alarm->alarm_value() : alarm->quiet_value());
  }
}

void Simulator::on_modbus_write(int unit_id) {
  if (unit_id != chamber_unit_) return;
  const auto& map = config_.chamber.map;
  std::lock_guard units_lock(units_mu_);
  const auto unit = chamber_units_.load();
  // The server took only set points within range (accept_write).
  const auto requested = server_->get(chamber_unit_, map.setpoint);
  const double current = setpoint_c_.load();
  if (requested.ok()) {
    const double requested_c = drivers::to_celsius(*requested, unit);
    // A write of the same value, or of another register, reads back the set
    // point through a float round trip: not a change.
    if (std::abs(requested_c - current) > 1e-4) {
      setpoint_c_.store(requested_c);
      std::lock_guard lock(sim_mu_);
      ++status_.setpoint_writes;
    }
  }
  if (map.ramp_action && map.ramp_rate) {
    namespace w = drivers::watlow;
    const auto action = server_->get(chamber_unit_, *map.ramp_action);
    const auto rate = server_->get(chamber_unit_, *map.ramp_rate);
    double scale = w::kMinutes;
    if (map.ramp_scale) {
      if (auto s = server_->get(chamber_unit_, *map.ramp_scale); s.ok()) scale = *s;
    }
    // Set Point Change and Both ramp on a set point change; Off and Startup
    // (power-up only) do not.
    double limit_c_per_min = 0;  // the plant's own limit
    if (action.ok() && rate.ok() && is_one_of(*action, {w::kSetPointChange, w::kBoth}) &&
        std::isfinite(*rate) && *rate > 0) {
      const double per_c = unit == drivers::TemperatureUnit::kCelsius ? 1.0 : 1.8;
      const double rate_c = *rate / per_c;
      limit_c_per_min = scale == w::kMinutes ? rate_c : rate_c / 60.0;
    }
    ramp_limit_c_per_min_.store(limit_c_per_min);
  }
}

void Simulator::set_setpoint_c(double setpoint_c) {
  std::lock_guard life(life_mu_);
  std::lock_guard units_lock(units_mu_);
  setpoint_c_.store(setpoint_c);
  if (server_) {
    (void)server_->set(chamber_unit_, config_.chamber.map.setpoint,
                       drivers::from_celsius(setpoint_c, chamber_units_.load()));
  }
}

void Simulator::set_chamber_units(drivers::TemperatureUnit unit) {
  std::lock_guard life(life_mu_);
  std::lock_guard units_lock(units_mu_);
  const auto before = chamber_units_.exchange(unit);
  const auto& map = config_.chamber.map;
  if (!server_ || !map.units || before == unit) return;
  (void)server_->set(chamber_unit_, map.units->reg, map.units->encode(unit));
  (void)server_->set(chamber_unit_, map.setpoint, drivers::from_celsius(setpoint_c_.load(), unit));
  if (map.ramp_rate) {
    if (auto rate = server_->get(chamber_unit_, *map.ramp_rate); rate.ok()) {
      const double factor = unit == drivers::TemperatureUnit::kFahrenheit ? 1.8 : 1 / 1.8;
      (void)server_->set(chamber_unit_, *map.ramp_rate, *rate * factor);
    }
  }
  double air_c;
  {
    std::lock_guard lock(sim_mu_);
    air_c = status_.truth.air_c;
  }
  (void)server_->set(chamber_unit_, map.process_value, drivers::from_celsius(air_c, unit));
}

void Simulator::set_frame_corruption_rate(double p, std::size_t dut) {
  if (dut >= duts_.size()) return;
  duts_[dut]->corruption_rate.store(std::clamp(std::isfinite(p) ? p : 0.0, 0.0, 1.0));
}

void Simulator::set_frame_drop_rate(double p, std::size_t dut) {
  if (dut >= duts_.size()) return;
  duts_[dut]->drop_rate.store(std::clamp(std::isfinite(p) ? p : 0.0, 0.0, 1.0));
}

void Simulator::set_modbus_down(bool down) {
  std::lock_guard life(life_mu_);
  if (server_) server_->set_down(down);
}

void Simulator::set_modbus_reply_delay_s(double wall_s) {
  std::lock_guard life(life_mu_);
  if (server_) server_->set_reply_delay_s(wall_s);
}

void Simulator::close_pty(std::size_t dut) {
  if (dut >= duts_.size()) return;
  std::lock_guard lock(stream_mu_);
  // The stable link goes first, as udev's /dev/serial/by-id/... goes with an
  // unplugged adapter: left in place it named a pseudo-terminal number that
  // is free once the pty closes, and a reader reopening the link could get
  // another process's line (another simulator's gyro) under the same number.
  // reopen_pty() points it at the new pty.
  if (const std::string& link = duts_[dut]->link; !link.empty()) {
    std::error_code ec;
    std::filesystem::remove(link, ec);
  }
  duts_[dut]->stream.close();
}

void Simulator::hold_pty(bool held, std::size_t dut) {
  if (dut >= duts_.size()) return;
  std::lock_guard lock(stream_mu_);
  GyroStream& stream = duts_[dut]->stream;
  stream.set_held(held);
  if (!held) stream.flush();
}

Status Simulator::reopen_pty(std::size_t dut) {
  if (dut >= duts_.size()) {
    return Error::Permanent(
        fmt::format("no DUT number {} (the simulator has {})", dut + 1, duts_.size()));
  }
  std::lock_guard life(life_mu_);
  {
    std::lock_guard lock(stream_mu_);
    if (Status s = duts_[dut]->stream.open(); !s.ok()) return s;
    if (Status s = point_gyro_link_locked(dut); !s.ok()) return s;
  }
  if (wrote_endpoints_) return write_endpoints_file();
  return Status::Ok();
}

void Simulator::stall_probe(ProbeRole role, bool stalled) {
  stalled_[role == ProbeRole::kTop ? 0 : 1].store(stalled);
}

Status Simulator::stall_dut_probe(std::size_t dut, ProbeRole role, bool stalled) {
  if (dut >= duts_.size()) {
    return Error::Permanent(
        fmt::format("no DUT number {} (the simulator has {})", dut + 1, duts_.size()));
  }
  Dut& d = *duts_[dut];
  const bool top = role == ProbeRole::kTop;
  const std::string& serial = d.model.dut().serial;
  if (!(top ? d.probe_top : d.probe_side)) {
    const auto& probes = d.model.dut().probes;
    if (!probes) {
      return Error::Permanent(fmt::format(
          "DUT '{}' has no probes of its own (its [[dut]] has no probes = {{ top_channel, "
          "side_channel }}); 'probe stall {}' without a serial stalls the station's",
          serial, top ? "top" : "side"));
    }
    return Error::Permanent(fmt::format(
        "the {} probe of DUT '{}' is channel {}, which another probe (the station's or an "
        "earlier DUT's) serves: stall that one",
        top ? "top" : "side", serial, top ? probes->top_channel : probes->side_channel));
  }
  d.probe_stalled[top ? 0 : 1].store(stalled);
  return Status::Ok();
}

void Simulator::set_chamber_alarm(bool raised) {
  std::lock_guard life(life_mu_);
  std::lock_guard lock(alarm_mu_);
  chamber_alarm_.store(raised);
  // At once, not at the next tick: a read right after the command sees it.
  if (const auto& alarm = config_.chamber.map.alarm; server_ && alarm) {
    (void)server_->set(chamber_unit_, alarm->reg,
                       raised ? alarm->alarm_value() : alarm->quiet_value());
  }
}

void Simulator::force_chamber_c(std::optional<double> target_c) {
  double forced = std::numeric_limits<double>::quiet_NaN();
  if (target_c && std::isfinite(*target_c)) {
    forced = std::clamp(*target_c, kMinSetpointC, kMaxSetpointC);
  }
  forced_chamber_c_.store(forced);
}

}  // namespace gyrotherm::sim

namespace gyrotherm::sim {

AclReply Simulator::table_acl(std::string_view line) {
  std::lock_guard lock(sim_mu_);
  if (!table_) return AclReply{kAclRefused, ""};
  return handle_acl_line(*table_, acl_state_, line);
}

void Simulator::table_fault() {
  std::lock_guard lock(sim_mu_);
  if (table_) table_->trip("injected fault (control socket: table fault)");
}

void Simulator::table_hang(bool hung) {
  std::lock_guard life(life_mu_);
  table_hung_.store(hung);
  apply_table_link_faults();
}

void Simulator::table_disconnect(bool disconnected) {
  std::lock_guard life(life_mu_);
  table_disconnected_.store(disconnected);
  apply_table_link_faults();
}

void Simulator::apply_table_link_faults() {
  const bool hung = table_hung_.load();
  const bool disconnected = table_disconnected_.load();
  // A TCP server can refuse its clients; a serial line can only go silent.
  for (TableServer* tcp : {table_server_.get(), aero_tcp_server_.get()}) {
    if (!tcp) continue;
    tcp->set_hung(hung);
    tcp->set_disconnected(disconnected);
  }
  for (AeroServer* line : {aero_server_.get(), acl_serial_server_.get()}) {
    if (line) line->set_silent(hung || disconnected);
  }
}

void Simulator::table_clear() {
  table_hang(false);
  table_disconnect(false);
}

}  // namespace gyrotherm::sim

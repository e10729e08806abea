// Helpers shared by the simulator's in-process tests: waiting on a condition
// with a deadline, a libmodbus client, and a fixture running the demo
// station's simulator in a temporary directory.
#pragma once

#include <gtest/gtest.h>
#include <modbus/modbus.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "gyrotherm/drivers/registers.h"
#include "gyrotherm/sim/simulator.h"
#include "test_time.h"

namespace gyrotherm::sim::test_util {

using namespace std::chrono_literals;
using SteadyClock = std::chrono::steady_clock;

// Polls `pred` until it holds or `timeout` (wall, stretched by
// GYROTHERM_TEST_TIME_FACTOR) passes.
template <class Pred>
bool wait_for(Pred pred, std::chrono::milliseconds timeout = 3000ms) {
  return gyrotherm::testing::wait_for_condition(pred, timeout, 1ms);
}

class ModbusClient {
 public:
  ModbusClient(int port, int unit_id, double response_timeout_s = 1.0) {
    ctx_ = modbus_new_tcp("127.0.0.1", port);
    modbus_set_slave(ctx_, unit_id);
    const auto us = static_cast<uint32_t>(response_timeout_s * 1e6);
    modbus_set_response_timeout(ctx_, us / 1000000, us % 1000000);
    connect();
  }
  ~ModbusClient() {
    modbus_close(ctx_);
    modbus_free(ctx_);
  }
  bool connect() {
    modbus_close(ctx_);
    return modbus_connect(ctx_) == 0;
  }
  void set_unit(int unit_id) { modbus_set_slave(ctx_, unit_id); }

  // Value, or nullopt with errno set by libmodbus.
  std::optional<double> read(const drivers::RegisterSpec& spec) {
    uint16_t words[2];
    const int n = spec.function == drivers::RegisterFunction::kHolding
                      ? modbus_read_registers(ctx_, spec.address, spec.word_count(), words)
                      : modbus_read_input_registers(ctx_, spec.address, spec.word_count(), words);
    if (n != spec.word_count()) return std::nullopt;
    return drivers::decode_register(spec, std::span<const uint16_t>(words, n));
  }
  bool write(const drivers::RegisterSpec& spec, double value) {
    auto words = drivers::encode_register(spec, value);
    if (!words.ok()) return false;
    return modbus_write_registers(ctx_, spec.address, static_cast<int>(words->size()),
                                  words->data()) == static_cast<int>(words->size());
  }

 private:
  modbus_t* ctx_;
};

// The demo station's simulator, in a fresh temporary directory per test
// (tests may run in parallel), with its control socket there too.
class SimFixture : public ::testing::Test {
 protected:
  void SetUp() override {
    char dir_template[] = "/tmp/gyrotherm-sim-test-XXXXXX";
    ASSERT_NE(::mkdtemp(dir_template), nullptr);
    dir_ = dir_template;
    auto config = config::load_station_config(GYROTHERM_SOURCE_DIR "/config/demo.toml");
    ASSERT_TRUE(config.ok()) << config.error().message;
    config_ = *config;
    SimulatorOverrides overrides;
    overrides.time_scale = 100;
    overrides.endpoints_file = dir_ + "/endpoints.toml";
    overrides.truth_file = dir_ + "/truth.json";
    auto options = read_simulator_options(config_, overrides);
    ASSERT_TRUE(options.ok()) << options.error().message;
    options_ = *options;
    // The demo station has a rate table; these tests serve one only when
    // they ask for it (config_.table and options_.serve_table).
    config_.table.reset();
    options_.serve_table = false;
    options_.gyro_link = dir_ + "/gyro-pty";  // per test: tests may run in parallel
    options_.control_socket = dir_ + "/sim.sock";
  }
  void TearDown() override {
    sim_.reset();
    std::filesystem::remove_all(dir_);
  }
  void start(const Clock* clock = nullptr) {
    auto sim = Simulator::create(config_, options_, clock);
    ASSERT_TRUE(sim.ok()) << sim.error().message;
    sim_ = std::move(sim).value();
    Status s = sim_->start();
    ASSERT_TRUE(s.ok()) << s.error().message;
  }
  int port() const { return sim_->endpoints().modbus_port; }
  int chamber_unit() const { return config_.chamber.endpoint.unit_id; }
  int probes_unit() const { return config_.probes.endpoint.unit_id; }

  std::string dir_;
  config::StationConfig config_;
  SimulatorOptions options_;
  // For tests that step time by hand: start(&manual_clock_). A member, not a
  // local of the test, so it outlives the simulator's threads (sim_ stops in
  // TearDown, after the test body has returned).
  ManualClock manual_clock_;
  std::unique_ptr<Simulator> sim_;
};

}  // namespace gyrotherm::sim::test_util

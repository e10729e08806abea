// gyrotherm-sim: the simulated station (DESIGN.md §8). Thin main: options,
// signals, printing; the Simulator class does the work.
#include <fmt/format.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <cstdio>
#include <string>

#include "gyrotherm/core/toml_reader.h"
#include "gyrotherm/daemon/config.h"
#include "gyrotherm/sim/options.h"
#include "gyrotherm/sim/simulator.h"

namespace {

constexpr int kExitRuntime = 1;
constexpr int kExitUsage = 2;  // bad command line or configuration

}  // namespace

int main(int argc, char** argv) {
  using namespace gyrotherm;
  CLI::App app{
      "gyrotherm-sim: simulated thermal test station. Serves the chamber controller and the "
      "probe module over Modbus TCP on 127.0.0.1 and streams KVH 1750 gyro frames on a pty."};
  std::string config_path;
  double time_scale = 1.0;
  std::string endpoints_file;
  std::string truth_file;
  uint64_t seed = 0;
  double rate_hz = 0;
  app.add_option("--config", config_path, "station config (TOML) with a [simulator] section")
      ->required();
  auto* time_scale_opt = app.add_option("--time-scale", time_scale,
                                        "station seconds per wall second (the daemon's too)");
  auto* endpoints_opt =
      app.add_option("--endpoints", endpoints_file,
                     "where to write the opened endpoints ([simulator] endpoints_file)");
  auto* truth_opt = app.add_option("--truth", truth_file,
                                   "where to write the model truth ([simulator] truth_file)");
  auto* seed_opt = app.add_option("--seed", seed, "random seed ([simulator] seed)");
  auto* rate_opt = app.add_option("--rate-hz", rate_hz, "gyro output rate, Hz ([gyro] rate_hz)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : kExitUsage;
  }

  sim::SimulatorOverrides overrides;
  if (*time_scale_opt) overrides.time_scale = time_scale;
  if (*endpoints_opt) overrides.endpoints_file = endpoints_file;
  if (*truth_opt) overrides.truth_file = truth_file;
  if (*seed_opt) overrides.seed = seed;
  if (*rate_opt) overrides.rate_hz = rate_hz;

  auto config = daemon::load_station_config(config_path);
  if (!config.ok()) {
    // Report the [simulator] problems too, so one run lists every error.
    std::string message = config.error().message;
    TomlErrors ignored(config_path);
    if (auto root = parse_toml_file(config_path, ignored)) {
      if (auto* table = root->get_as<toml::table>("simulator")) {
        daemon::StationConfig partial;
        partial.source_path = config_path;
        partial.simulator_table = std::move(*table);  // a move keeps source lines
        if (auto o = sim::read_simulator_options(partial, overrides); !o.ok()) {
          message += o.error().message;
        }
      }
    }
    std::fprintf(stderr, "gyrotherm-sim: bad configuration:\n%s", message.c_str());
    return kExitUsage;
  }
  auto options = sim::read_simulator_options(*config, overrides);
  if (!options.ok()) {
    std::fprintf(stderr, "gyrotherm-sim: bad configuration:\n%s", options.error().message.c_str());
    return kExitUsage;
  }

  // Signals are taken synchronously below; every thread started from here on
  // inherits the mask.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);
  signal(SIGPIPE, SIG_IGN);

  auto simulator = sim::Simulator::create(*config, *options);
  if (!simulator.ok()) {
    std::fprintf(stderr, "gyrotherm-sim: bad configuration:\n%s\n",
                 simulator.error().message.c_str());
    return kExitUsage;
  }
  sim::Simulator& s = **simulator;
  if (Status st = s.start(); !st.ok()) {
    std::fprintf(stderr, "gyrotherm-sim: cannot start: %s\n", st.error().message.c_str());
    return kExitRuntime;
  }
  const auto ep = s.endpoints();
  fmt::print("modbus {}:{}\n", ep.modbus_host, ep.modbus_port);
  fmt::print("gyro {}\n", ep.gyro_device);
  if (!s.truth_file().empty()) fmt::print("truth {}\n", s.truth_file());
  if (!s.endpoints_file().empty()) fmt::print("endpoints {}\n", s.endpoints_file());
  std::fflush(stdout);

  int signal_number = 0;
  while (sigwait(&stop_signals, &signal_number) != 0) {
  }
  s.stop();
  const auto st = s.status();
  fmt::print(stderr,
             "gyrotherm-sim: stopped by signal {} at station time {:.1f} s; frames generated {}, "
             "written {}, dropped (slow reader) {}\n",
             signal_number, st.t_s, st.frames_generated, st.stream.frames_queued,
             st.stream.frames_dropped_full);
  return 0;
}

// gyrotherm-sim: the simulated station (docs/simulator.md). Thin main: options,
// signals, printing; the Simulator class does the work.
//
//   gyrotherm-sim --config FILE [...]                    run the station
//   gyrotherm-sim ctl (--socket PATH | --endpoints FILE) COMMAND...
//                                                        one fault-injection command
#include <fmt/format.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "gyrotherm/config/config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/core/toml_reader.h"
#include "gyrotherm/sim/control_server.h"
#include "gyrotherm/sim/options.h"
#include "gyrotherm/sim/simulator.h"

namespace {

constexpr int kExitRuntime = 1;
constexpr int kExitUsage = 2;  // bad command line or configuration

// `gyrotherm-sim ctl ...`: exit 0 on "ok", 1 on "error", 2 on a usage or
// connection problem.
int run_ctl(int argc, char** argv) {
  using namespace gyrotherm;
  CLI::App app{
      "gyrotherm-sim ctl: send one fault-injection command to a running gyrotherm-sim "
      "and print its reply (docs/simulator.md). Exit status: 0 ok, 1 error reply, 2 "
      "usage or connection failure.",
      "gyrotherm-sim ctl"};
  std::string socket_path;
  std::string endpoints_path;
  double timeout_s = 5.0;
  auto* socket_opt = app.add_option("--socket", socket_path,
                                    "the simulator's control socket ([simulator] "
                                    "control_socket)");
  auto* endpoints_opt = app.add_option("--endpoints", endpoints_path,
                                       "take the socket path from this endpoints file");
  socket_opt->excludes(endpoints_opt);
  app.add_option("--timeout", timeout_s, "seconds to wait for the reply")
      ->check(CLI::Range(0.1, 3600.0));
  app.footer("COMMAND is one of (send 'help' for the list as JSON):\n" + [] {
    std::size_t width = 0;
    for (const auto& h : sim::control_commands()) width = std::max(width, std::strlen(h.usage));
    std::string list;
    for (const auto& h : sim::control_commands()) {
      list += fmt::format("  {:<{}} {}\n", h.usage, width, h.description);
    }
    return list;
  }());
  app.prefix_command();  // everything from COMMAND on is the command, "-5" included
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : kExitUsage;
  }
  std::vector<std::string> words = app.remaining();
  if (!words.empty() && words.front() == "--") words.erase(words.begin());
  if (words.empty()) {
    std::fprintf(stderr, "gyrotherm-sim ctl: no command (try 'help')\n%s", app.help().c_str());
    return kExitUsage;
  }
  if (!*socket_opt && !*endpoints_opt) {
    std::fprintf(stderr, "gyrotherm-sim ctl: give --socket PATH or --endpoints FILE\n");
    return kExitUsage;
  }
  if (*endpoints_opt) {
    auto ep = config::read_sim_endpoints(endpoints_path);
    if (!ep.ok()) {
      std::fprintf(stderr, "gyrotherm-sim ctl: %s\n", ep.error().message.c_str());
      return kExitUsage;
    }
    if (ep->control_socket.empty()) {
      std::fprintf(stderr,
                   "gyrotherm-sim ctl: %s names no control_socket (set [simulator] "
                   "control_socket in the station config)\n",
                   endpoints_path.c_str());
      return kExitUsage;
    }
    socket_path = ep->control_socket;
  }
  std::string command;
  for (const auto& w : words) command += (command.empty() ? "" : " ") + w;
  const auto timeout = std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000));
  auto reply = sim::send_control_command(socket_path, command, timeout);
  if (!reply.ok()) {
    std::fprintf(stderr, "gyrotherm-sim ctl: %s\n", reply.error().message.c_str());
    return kExitUsage;
  }
  std::printf("%s\n", reply->c_str());
  if (*reply == "ok" || reply->rfind("ok ", 0) == 0) return 0;
  if (reply->rfind("error", 0) == 0) return kExitRuntime;
  std::fprintf(stderr, "gyrotherm-sim ctl: unexpected reply\n");
  return kExitUsage;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace gyrotherm;
  if (argc >= 2 && std::strcmp(argv[1], "ctl") == 0) return run_ctl(argc - 1, argv + 1);

  CLI::App app{
      "gyrotherm-sim: simulated thermal test station. Serves the chamber controller and the "
      "probe module over Modbus TCP on 127.0.0.1 and streams each device under test's frames "
      "(KVH 1750 or ASCII lines) on its own pty; "
      "with a rate table, serves it over ACL (TCP) and the AERO grammar (a second pty)."};
  app.footer(
      "Fault injection while it runs: gyrotherm-sim ctl --socket PATH COMMAND... "
      "(gyrotherm-sim ctl --help).");
  std::string config_path;
  double time_scale = 1.0;
  std::string endpoints_file;
  std::string truth_file;
  std::string control_socket;
  uint64_t seed = 0;
  std::vector<std::string> rate_hz;
  int table_port = 0;
  app.add_option("--config", config_path, "station config (TOML) with a [simulator] section")
      ->required();
  auto* time_scale_opt = app.add_option("--time-scale", time_scale,
                                        "station seconds per wall second (the daemon's too)");
  auto* endpoints_opt =
      app.add_option("--endpoints", endpoints_file,
                     "where to write the opened endpoints ([simulator] endpoints_file)");
  auto* truth_opt = app.add_option("--truth", truth_file,
                                   "where to write the model truth ([simulator] truth_file)");
  auto* control_opt =
      app.add_option("--control-socket", control_socket,
                     "Unix socket for fault-injection commands ([simulator] control_socket)");
  auto* seed_opt = app.add_option("--seed", seed, "random seed ([simulator] seed)");
  app.add_option("--rate-hz", rate_hz,
                 "output rate, Hz: HZ for every DUT, SERIAL=HZ for one (wins over HZ); "
                 "repeatable ([[dut]] rate_hz)")
      ->allow_extra_args(false);
  auto* table_port_opt =
      app.add_option("--table-port", table_port,
                     "the rate table's ACL TCP port, 0 = any free ([simulator] table_port)")
          ->check(CLI::Range(0, 65535));
  bool scaled_clock = false;
  app.add_flag("--scaled-clock", scaled_clock,
               "scale wall time alone, without the shared clock file the daemon follows (two "
               "clocks: a loaded machine misplaces samples above x10; for comparisons only)");
  bool serve_table = false;
  app.add_flag("--table", serve_table,
               "serve a rate table even without a [table] section in the station config");
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
  if (*control_opt) overrides.control_socket = control_socket;
  if (*seed_opt) overrides.seed = seed;
  if (Status st = sim::parse_rate_hz_options(rate_hz, overrides); !st.ok()) {
    std::fprintf(stderr, "gyrotherm-sim: %s\n", st.error().message.c_str());
    return kExitUsage;
  }
  if (*table_port_opt) overrides.table_port = table_port;
  overrides.serve_table = serve_table;
  overrides.scaled_clock = scaled_clock;

  auto config = config::load_station_config(config_path);
  if (!config.ok()) {
    // Report the [simulator] problems too, so one run lists every error.
    std::string message = config.error().message;
    TomlErrors ignored(config_path);
    if (auto root = parse_toml_file(config_path, ignored)) {
      if (auto* table = root->get_as<toml::table>("simulator")) {
        config::StationConfig partial;
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
  // A serial the station has no DUT for is a command-line error.
  if (const std::string why =
          sim::unknown_rate_hz_serial(overrides.dut_rate_hz, sim::simulated_duts(*config));
      !why.empty()) {
    std::fprintf(stderr, "gyrotherm-sim: %s\n", why.c_str());
    return kExitUsage;
  }
  for (const std::string& warning : config->warnings) {
    std::fprintf(stderr, "gyrotherm-sim: warning: %s\n", warning.c_str());
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
  if (ep.dut_devices.size() > 1) {
    for (const auto& [serial, device] : ep.dut_devices) fmt::print("dut {} {}\n", serial, device);
  }
  for (const auto& [serial, hz] : ep.dut_rates_hz) {
    fmt::print("rate {} {:g} Hz\n", serial.empty() ? "(gyro)" : serial, hz);
  }
  if (ep.table_port != 0) fmt::print("table acl {}:{}\n", ep.modbus_host, ep.table_port);
  if (!ep.table_device.empty()) fmt::print("table aero {}\n", ep.table_device);
  if (!ep.table_acl_device.empty()) fmt::print("table acl-serial {}\n", ep.table_acl_device);
  if (ep.table_aero_port != 0) {
    fmt::print("table aero-tcp {}:{}\n", ep.modbus_host, ep.table_aero_port);
  }
  if (!s.truth_file().empty()) fmt::print("truth {}\n", s.truth_file());
  if (!ep.control_socket.empty()) fmt::print("control {}\n", ep.control_socket);
  if (!ep.clock_file.empty()) fmt::print("clock {}\n", ep.clock_file);
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

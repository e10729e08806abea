// gyrothermd: the station daemon. Thin: parse arguments, load the config,
// wire Station + HTTP server, wait for a signal. Under systemd (Type=notify)
// it reports READY, STOPPING and, while the control loop ticks, WATCHDOG;
// without NOTIFY_SOCKET those calls do nothing.
#include <fmt/format.h>
#include <signal.h>
#include <spdlog/spdlog.h>
#include <systemd/sd-daemon.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <thread>

#include "gyrotherm/api/api.h"
#include "gyrotherm/api/http_message.h"
#include "gyrotherm/api/http_server.h"
#include "gyrotherm/api/metrics.h"
#include "gyrotherm/api/web_assets.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/config/sim_endpoints.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/files.h"
#include "gyrotherm/core/shared_clock.h"
#include "gyrotherm/core/time_scale.h"
#include "gyrotherm/core/toml_errors.h"
#include "gyrotherm/lab/relay.h"
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/station/station.h"
#include "gyrotherm/station/station_lock.h"
#include "gyrotherm/storage/database.h"

namespace {

// A start-up step that failed: the message for stderr and the exit code (2:
// an option, the config or a file is wrong; 1: something at run time).
struct Exit {
  int code;
  std::string message;
};

int fail(const Exit& exit) {
  std::cerr << exit.message;
  return exit.code;
}

// The parts streamed into one string, as std::cerr prints them.
template <class... Parts>
std::string text(const Parts&... parts) {
  std::ostringstream os;
  (os << ... << parts);
  return os.str();
}

// The command line.
struct Args {
  std::string config_path, db_path, schedule_path, wall_start, log_level = "info";
  double time_scale = 1.0;
  bool time_scale_given = false;  // else the simulator's, when it has a clock file
  double endpoints_wait_s = 30.0;
  bool exit_when_done = false;
  std::string clock_mode = "auto";
};

// Parses the command line into `args`; an exit code when the daemon stops
// there (--help: 0; a usage error: 2, as a bad config).
std::optional<int> parse_args(int argc, char** argv, Args& args) {
  CLI::App app{"gyrothermd: FOG thermal test station daemon"};
  app.add_option("--config", args.config_path, "station config (TOML)")->required();
  app.add_option("--db", args.db_path, "database file (overrides [storage] db)");
  app.add_option("--schedule", args.schedule_path, "queue this schedule file at start-up");
  auto* time_scale_opt =
      app.add_option("--time-scale", args.time_scale,
                     "station seconds per wall second (simulation; on the simulator's clock "
                     "its own unless given, and at most: a busy machine runs slower)")
          ->check(CLI::Range(gyrotherm::kMinTimeScale, gyrotherm::kMaxTimeScale));
  app.add_option("--wall-start", args.wall_start,
                 "simulation: the nightly export's wall clock starts at this ISO-8601 instant "
                 "(e.g. 2026-03-29T00:40:00Z) and runs at --time-scale");
  app.add_flag("--exit-when-done", args.exit_when_done,
               "exit 0 once the queue is empty and no run is active (scripts, tests)");
  app.add_option("--clock", args.clock_mode,
                 "station time: 'auto' (default) is 'sim' when the simulator's endpoints name "
                 "a clock file, else 'scaled'; 'sim' reads it from the simulator's clock file "
                 "(one clock for both; the simulator waits for this daemon); 'scaled' scales "
                 "wall time on its own (refused above x" +
                     fmt::format("{:g}", gyrotherm::kMaxScaledSimTimeScale) +
                     " against a simulator: a loaded machine misplaces samples)")
      ->check(CLI::IsMember({"auto", "sim", "scaled"}));
  app.add_option("--endpoints-wait", args.endpoints_wait_s,
                 "seconds to wait for the simulator's endpoints file");
  app.add_option("--log-level", args.log_level, "trace, debug, info, warn, error")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "error"}));
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help exits 0; every usage error exits 2, as a bad config does.
    return app.exit(e) == 0 ? 0 : 2;
  }
  args.time_scale_given = time_scale_opt->count() > 0;
  return std::nullopt;
}

// [simulator] endpoints_file: waits for the simulator's endpoints, points
// the config's devices at them and picks the station clock: the simulator's
// clock file (into `shared_clock_map`) unless --clock scaled, at the
// simulator's time scale unless one was given (then they must agree).
std::optional<Exit> connect_simulator(
    Args& args, gyrotherm::config::StationConfig& config,
    std::unique_ptr<gyrotherm::SharedClockMap>& shared_clock_map) {
  if (args.clock_mode == "sim" && config.simulator.endpoints_file.empty()) {
    return Exit{2, text("gyrothermd: --clock sim needs a simulator: ", args.config_path,
                        " has no [simulator] endpoints_file\n")};
  }
  if (!config.simulator.endpoints_file.empty()) {
    const std::string& file = config.simulator.endpoints_file;
    const auto deadline =
        std::chrono::steady_clock::now() +
        std::chrono::milliseconds(static_cast<int64_t>(args.endpoints_wait_s * 1000));
    gyrotherm::Result<gyrotherm::config::SimEndpoints> ep = gyrotherm::Error::Transient("not read");
    while (!(ep = gyrotherm::config::read_sim_endpoints(file)) &&
           std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    if (!ep) {
      return Exit{
          1,
          text("gyrothermd: no simulator endpoints in ", file, " after ", args.endpoints_wait_s,
               " s (is gyrotherm-sim running with the same config?):\n", ep.error().message, "\n")};
    }
    if (args.clock_mode == "sim" && ep->clock_file.empty()) {
      return Exit{2, text("gyrothermd: --clock sim, but the simulator's endpoints (", file,
                          ") name no clock file (a simulator started with --scaled-clock?)\n")};
    }
    if (args.clock_mode != "scaled" && !ep->clock_file.empty()) {
      auto map = gyrotherm::SharedClockMap::open(ep->clock_file);
      if (!map) {
        return Exit{1, text("gyrothermd: ", map.error().message, "\n")};
      }
      // The simulator's scale unless one was given (then they must agree).
      if (!args.time_scale_given) args.time_scale = ep->time_scale > 0 ? ep->time_scale : 1.0;
      shared_clock_map = std::move(*map);
    } else if (args.time_scale > gyrotherm::kMaxScaledSimTimeScale && args.clock_mode != "scaled") {
      // A simulator without a clock file (started with --scaled-clock, or
      // an older one, or a test's in-process one): two clocks it asked for.
      spdlog::warn(
          "--time-scale {:g} against a simulator without a clock file: two clocks, and above "
          "x{:g} a loaded machine puts samples in the wrong windows; run the simulator without "
          "--scaled-clock",
          args.time_scale, gyrotherm::kMaxScaledSimTimeScale);
    } else if (args.time_scale > gyrotherm::kMaxScaledSimTimeScale) {
      // Two clocks asked of the daemon: refused where a loaded machine
      // makes them wrong.
      return Exit{
          2,
          text(fmt::format(
              "gyrothermd: --time-scale {:g} with a scaled clock against a simulator is refused: "
              "above x{:g} a loaded machine puts samples in the wrong windows (reader latency in "
              "wall seconds becomes station seconds). Run the simulator with its clock (without "
              "--scaled-clock) and the daemon with --clock auto or sim, or use --time-scale {:g} "
              "or less\n",
              args.time_scale, gyrotherm::kMaxScaledSimTimeScale,
              gyrotherm::kMaxScaledSimTimeScale))};
    }
    if (const std::string why =
            gyrotherm::config::sim_time_scale_mismatch(*ep, args.time_scale, file);
        !why.empty()) {
      return Exit{2, text("gyrothermd: ", why, "\n")};
    }
    gyrotherm::config::apply_sim_endpoints(config, *ep);
    if (const std::string why = gyrotherm::config::sim_dut_devices_mismatch(config, *ep, file);
        !why.empty()) {
      return Exit{2, text("gyrothermd: ", why, "\n")};
    }
    spdlog::info("simulated station: modbus {}:{}, gyro {}", ep->modbus_host, ep->modbus_port,
                 ep->gyro_device);
  }
  return std::nullopt;
}

// --schedule's file, checked against the station's limits; its text into
// `text_out` (nothing without --schedule).
std::optional<Exit> read_schedule(const Args& args, const gyrotherm::config::StationConfig& config,
                                  std::string& text_out) {
  if (!args.schedule_path.empty()) {
    auto p = gyrotherm::schedules::load_schedule(args.schedule_path,
                                                 gyrotherm::config::station_limits(config));
    if (!p) {
      return Exit{2, text("gyrothermd: schedule refused, nothing queued:\n", p.error().message)};
    }
    auto file_text = gyrotherm::read_bounded_file(args.schedule_path, gyrotherm::kMaxTomlFileBytes);
    if (!file_text) {
      return Exit{2, text("gyrothermd: ", file_text.error().message, "\n")};
    }
    text_out = std::move(*file_text);
  }
  return std::nullopt;
}

// [lab] (docs/lab.md): the database is bound to the station id before
// anything writes to it, so every result from now on is queued in its
// outbox (the first binding queues the history). One database, one id.
// The relay (into `relay`; none without [lab]) posts its events to the
// station `relay_events_to` points at, once it does.
std::optional<Exit> make_relay(const gyrotherm::config::StationConfig& config,
                               std::atomic<gyrotherm::station::Station*>& relay_events_to,
                               std::unique_ptr<gyrotherm::lab::Relay>& relay) {
  if (const auto& lab = config.lab) {
    const std::string& db = config.storage.db_path;
    auto database = gyrotherm::storage::Database::open(db);
    if (!database) {
      return Exit{1, text("gyrothermd: ", database.error().message, "\n")};
    }
    auto bound = database->lab_station_id();
    if (!bound) {
      return Exit{1, text("gyrothermd: ", bound.error().message, "\n")};
    }
    if (*bound && **bound != lab->station_id) {
      return Exit{
          2, text(fmt::format(
                 "gyrothermd: [lab] station_id is \"{}\" but database {} belongs to lab station "
                 "\"{}\" (a database belongs to one station: fix station_id, or give this station "
                 "its own database)\n",
                 lab->station_id, db, **bound))};
    }
    if (auto st = database->lab_bind(lab->station_id); !st) {
      return Exit{st.error().transient ? 1 : 2,
                  text("gyrothermd: [lab] binding database ", db, " to station ", lab->station_id,
                       ": ", st.error().message, "\n")};
    }
    gyrotherm::lab::RelayOptions options;
    options.station_id = lab->station_id;
    options.db_path = db;
    if (lab->relay) {
      auto conninfo = gyrotherm::config::lab_conninfo(*lab);
      if (!conninfo) {
        return Exit{2, text("gyrothermd: ", conninfo.error().message, "\n")};
      }
      options.conninfo = std::move(*conninfo);
    }  // else "": the relay only counts the outbox (state "disabled")
    options.batch_records = lab->batch_records;
    options.batch_bytes = lab->batch_bytes;
    options.poll_s = lab->poll_s;
    options.retry_min_s = lab->retry_min_s;
    options.retry_max_s = lab->retry_max_s;
    options.connect_timeout_s = lab->connect_timeout_s;
    options.statement_timeout_s = lab->statement_timeout_s;
    options.lock_timeout_s = lab->lock_timeout_s;
    options.on_event = [&relay_events_to](const std::string& message) {
      spdlog::info("{}", message);
      if (gyrotherm::station::Station* s = relay_events_to.load()) s->post_event("lab", message);
    };
    auto created = gyrotherm::lab::Relay::create(std::move(options));
    if (!created) {
      return Exit{2, text("gyrothermd: ", created.error().message, "\n")};
    }
    relay = std::move(*created);
  }
  return std::nullopt;
}

// Waits for SIGINT or SIGTERM (blocked in every thread, taken here) or,
// with `exit_when_done`, for the station to be idle; returns why it stopped.
std::string run_until_stopped(gyrotherm::station::Station& station,
                              const gyrotherm::config::StationConfig& config,
                              const gyrotherm::Clock& clock, const sigset_t& signals,
                              bool exit_when_done) {
  // The watchdog is fed at half its interval while the control loop ticks.
  // A loop that has not ticked for the interval (or three tick periods, if
  // longer) is stalled: the pings stop and systemd restarts the daemon.
  using steady = std::chrono::steady_clock;
  uint64_t watchdog_usec = 0;
  const bool watchdog = sd_watchdog_enabled(0, &watchdog_usec) > 0;
  const auto watchdog_every = std::chrono::microseconds(watchdog_usec / 2);
  const auto tick_period = std::chrono::duration<double>(
      std::max(config.control.min_tick_wall_s, config.control.tick_s / clock.time_scale()));
  const auto stall_after = std::max<std::chrono::duration<double>>(
      std::chrono::microseconds(watchdog_usec), 3 * tick_period);
  uint64_t heartbeat = station.heartbeat();
  auto heartbeat_at = steady::now();
  auto last_ping = steady::time_point{};
  bool stalled = false;

  for (;;) {
    timespec wait{0, 100'000'000};
    const int sig = sigtimedwait(&signals, nullptr, &wait);
    if (sig == SIGINT || sig == SIGTERM) {
      return sig == SIGINT ? "SIGINT" : "SIGTERM";
    }
    if (exit_when_done && station.idle()) {
      return "queue done";
    }
    if (!watchdog) continue;
    const auto now = steady::now();
    if (const uint64_t h = station.heartbeat(); h != heartbeat) {
      heartbeat = h;
      heartbeat_at = now;
      if (stalled) spdlog::warn("watchdog: the control loop ticks again; pings resumed");
      stalled = false;
    } else if (!stalled && now - heartbeat_at > stall_after) {
      stalled = true;
      spdlog::error(
          "watchdog: the control loop has not ticked for {:.1f} s; no more watchdog pings, "
          "systemd will restart the daemon",
          std::chrono::duration<double>(now - heartbeat_at).count());
    }
    if (!stalled && now - last_ping >= watchdog_every) {
      sd_notify(0, "WATCHDOG=1");
      last_ping = now;
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  if (const std::optional<int> code = parse_args(argc, argv, args)) return *code;
  spdlog::set_level(spdlog::level::from_str(args.log_level));
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");

  auto config = gyrotherm::config::load_station_config(args.config_path);
  if (!config) {
    std::cerr << "gyrothermd: bad config:\n" << config.error().message;
    return 2;
  }
  for (const std::string& warning : config->warnings) spdlog::warn("config: {}", warning);
  if (!args.db_path.empty()) config->storage.db_path = args.db_path;
  if (auto dir =
          gyrotherm::config::check_database_directory(*config, args.db_path.empty() ? "" : "--db");
      !dir) {
    std::cerr << "gyrothermd: bad config:\n" << dir.error().message << "\n";
    return 2;
  }
  // One daemon per station database; the CLI's commissioning commands look
  // at this lock and keep off the devices while it is held.
  auto station_lock = gyrotherm::station::StationLock::acquire(config->storage.db_path);
  if (!station_lock) {
    std::cerr << "gyrothermd: " << station_lock.error().message << "\n";
    return 1;
  }

  std::unique_ptr<gyrotherm::SharedClockMap> shared_clock_map;
  if (auto exit = connect_simulator(args, *config, shared_clock_map)) return fail(*exit);

  // --schedule is checked here too, so a bad file stops the daemon before it
  // starts anything; the queue checks it again when it is added.
  std::string schedule_text;
  if (auto exit = read_schedule(args, *config, schedule_text)) return fail(*exit);

  // The relay's events go to the station's event log once it exists (the
  // relay starts after the station).
  std::atomic<gyrotherm::station::Station*> relay_events_to{nullptr};
  std::unique_ptr<gyrotherm::lab::Relay> relay;
  if (auto exit = make_relay(*config, relay_events_to, relay)) return fail(*exit);

  // Signals are taken by sigwait() below, never by the worker threads.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  // One clock for a simulated station: the simulator's, which it runs no
  // further than one control tick past this daemon's slowest consumer.
  std::optional<gyrotherm::ScaledClock> scaled_clock;
  std::optional<gyrotherm::SharedStationClock> shared_clock;
  if (shared_clock_map) {
    const std::string clock_path = shared_clock_map->path();
    shared_clock.emplace(std::move(shared_clock_map), config->control.tick_s);
    spdlog::info("station time: the simulator's clock ({}), at most x{:g}", clock_path,
                 shared_clock->time_scale());
  } else {
    scaled_clock.emplace(args.time_scale);
  }
  const gyrotherm::Clock& clock =
      shared_clock ? static_cast<const gyrotherm::Clock&>(*shared_clock) : *scaled_clock;
  std::optional<gyrotherm::StationWallClock> wall_clock;
  if (!args.wall_start.empty()) {
    auto start = gyrotherm::parse_utc_iso(args.wall_start);
    if (!start) {
      std::cerr << "gyrothermd: --wall-start: " << start.error().message << "\n";
      return 2;
    }
    wall_clock.emplace(clock, *start);
  }
  // Declared in the order they may be torn down in reverse: the station
  // publishes into the stream and observes into the metrics; the server
  // serves all three.
  gyrotherm::api::Metrics metrics;
  gyrotherm::station::Station* station_ptr = nullptr;
  // The status's and the metrics' bodies, built from the station's snapshot
  // at most every kBodyMaxAgeS of real time whatever the request rate, and
  // shared by every reader (docs/api.md "How fresh the status is").
  constexpr double kBodyMaxAgeS = 0.05;
  std::optional<gyrotherm::api::BodyCache> status_body;
  std::optional<gyrotherm::api::BodyCache> metrics_body;
  gyrotherm::api::EventStreamOptions stream_options;
  stream_options.queue_bytes = static_cast<std::size_t>(config->api.stream_queue_bytes);
  stream_options.max_clients = config->api.max_stream_clients;
  stream_options.status_json = [&status_body] { return *status_body->get(); };
  gyrotherm::api::EventStream stream(stream_options);
  gyrotherm::station::StationHooks hooks;
  hooks.observe_modbus = [&metrics](std::string_view device, double seconds) {
    metrics.observe_modbus(device, seconds);
  };
  hooks.observe_commit = [&metrics](double seconds) { metrics.observe_commit(seconds); };
  hooks.publish = [&stream, r = relay.get()](std::string_view event, const nlohmann::json& data) {
    stream.publish(event, gyrotherm::api::json_text(data));
    // Something was committed that the lab relays: send it now, not at the next poll.
    if (r && event != "status") r->nudge();
  };
  if (relay) {
    hooks.lab_status = [r = relay.get()] { return std::optional(r->status()); };
  }
  auto devices = gyrotherm::station::devices_from_config(*config, clock, hooks);
  if (!devices) {
    std::cerr << "gyrothermd: " << devices.error().message << "\n";
    return 1;
  }
  const gyrotherm::station::StationClocks clocks{clock, gyrotherm::system_wall_clock(),
                                                 wall_clock ? &*wall_clock : nullptr};
  auto station = gyrotherm::station::Station::create(*config, std::move(*devices), clocks, hooks);
  if (!station) {
    std::cerr << "gyrothermd: " << station.error().message << "\n";
    return 1;
  }
  station_ptr = station->get();

  const std::string web_root =
      config->api.web_root.empty() ? gyrotherm::api::default_web_root() : config->api.web_root;
  auto web = gyrotherm::api::WebAssets::load(web_root);
  if (!web) {
    spdlog::warn("dashboard not served: {}", web.error().message);
  }
  gyrotherm::api::HttpServer* server_ptr = nullptr;
  auto auth_limiter =
      gyrotherm::api::AuthLimiter::create({.max_failures = config->api.max_auth_failures});
  if (!auth_limiter) {
    std::cerr << "gyrothermd: " << auth_limiter.error().message << "\n";
    return 1;
  }
  status_body.emplace(
      [s = station_ptr] {
        return gyrotherm::api::json_text(gyrotherm::station::to_json(s->status()));
      },
      kBodyMaxAgeS);
  gyrotherm::api::ApiContext api;
  api.status = [s = station_ptr] { return s->status(); };
  api.status_body = &*status_body;
  api.control = station_ptr;
  api.tokens = config->api.tokens;
  api.read_tokens = config->api.read_tokens;
  api.reads_need_token = config->api.read_access == "token";
  api.auth_limiter = auth_limiter->get();
  api.web = web ? &*web : nullptr;
  api.metrics = [&] {
    gyrotherm::api::ServerFigures f;
    if (server_ptr) {
      const auto h = server_ptr->stats();
      f.http_requests = h.requests;
      f.http_refused_connections = h.refused_connections;
      f.http_bad_requests = h.bad_requests;
      f.http_connections = h.connections;
    }
    f.stream_clients = stream.clients();
    f.stream_clients_dropped = stream.dropped();
    return metrics.scrape(station_ptr->status(), f);
  };
  metrics_body.emplace(api.metrics, kBodyMaxAgeS);
  api.metrics_body = &*metrics_body;
  gyrotherm::api::HttpServerOptions http_options;
  http_options.bind = config->api.bind;
  http_options.port = config->api.port;
  http_options.read_timeout =
      std::chrono::milliseconds(static_cast<int64_t>(config->api.read_timeout_s * 1000));
  http_options.max_connections = config->api.max_connections;
  http_options.header_limit = static_cast<std::size_t>(config->api.max_header_bytes);
  http_options.body_limit = static_cast<std::size_t>(config->api.max_body_bytes);
  http_options.stream = &stream;
  http_options.stream_gate = [&api](const gyrotherm::api::HttpRequest& r, std::string_view peer) {
    return gyrotherm::api::check_access(r, api, peer);
  };
  if (auto warning = gyrotherm::config::api_exposure_warning(config->api))
    spdlog::warn("{}", *warning);
  auto http = gyrotherm::api::HttpServer::create(
      http_options, [&api](const gyrotherm::api::HttpRequest& r, std::string_view peer) {
        return gyrotherm::api::handle_api_request(r, api, peer);
      });
  if (!http) {
    std::cerr << "gyrothermd: " << http.error().message << "\n";
    return 1;
  }
  server_ptr = http->get();
  (*station)->start();
  if (relay) {
    // Set before start(): the relay thread reads it.
    relay_events_to = station_ptr;
    relay->start();
  }
  // The command line's schedule is queued before the API serves anyone, so
  // it comes before whatever a client queues as soon as the daemon answers.
  if (!args.schedule_path.empty()) {
    const auto added = (*station)->queue_add(schedule_text, args.schedule_path, false);
    if (added.refusal) {
      spdlog::error("--schedule {}: {}", args.schedule_path, added.refusal->message);
      for (const auto& line : added.refusal->details) spdlog::error("  {}", line);
    }
  }
  (*http)->start();
  station_lock->note_api(fmt::format("http://{}:{}", config->api.bind, (*http)->port()));
  spdlog::info(
      "gyrothermd: station \"{}\", database {}, API http://{}:{}/api/v1/status, time "
      "scale {:g}",
      config->station.name, config->storage.db_path, config->api.bind, (*http)->port(),
      args.time_scale);

  sd_notifyf(0, "READY=1\nSTATUS=station \"%s\", API http://%s:%d/", config->station.name.c_str(),
             config->api.bind.c_str(), (*http)->port());

  const std::string reason =
      run_until_stopped(**station, *config, clock, signals, args.exit_when_done);
  spdlog::info("gyrothermd: stopping ({})", reason);
  sd_notifyf(0, "STOPPING=1\nSTATUS=stopping (%s)", reason.c_str());
  (*http)->stop();
  // The station first: the chamber to its safe set point and the table
  // stopped, whatever the lab database does. Then the relay: a batch in
  // flight is cancelled (bounded: docs/operations.md "Stop"); its events go
  // to the journal only, the station's event log being closed.
  (*station)->stop("daemon stopped: " + reason);
  relay_events_to = nullptr;
  if (relay) relay->stop();
  return 0;
}

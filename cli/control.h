// Daemon control from the command line: `status`, `queue add|list|remove|move`,
// `pause`, `resume`, `abort`, `stop`, `runs`, `run ID`, `edit-run ID`,
// `duts`, `dut SERIAL` as thin clients of the REST API (docs/api.md), plus
// the pure formatters (daemon JSON in, text out) behind their human output.
// `runs`, `run ID`, `duts` and `dut SERIAL` read a database file instead
// when given one (--db FILE, or --config FILE and its [storage] db), opened
// read-only, with the daemon's own JSON (docs/cli.md).
//
// Exit codes: 0 done; 1 the daemon could not be reached, refused the token or
// answered 4xx/5xx (its `error` and `errors` go to stderr); 2 usage (bad URL,
// unreadable schedule file). The token is sent only with mutations and is
// never printed.
#pragma once

#include <cstdint>
#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

namespace CLI {
class App;
}

namespace gyrotherm::cli {

inline constexpr const char* kDefaultDaemonUrl = "http://127.0.0.1:8750";

// Options every daemon command takes.
struct DaemonOptions {
  std::string url = kDefaultDaemonUrl;  // --url, else env GYROTHERM_URL
  std::string token;                    // --token, else env GYROTHERM_TOKEN
  bool json = false;                    // print the daemon's JSON answer as is
};

// `queue add --operator --comment --tag... --dut...`: sent only when given.
struct QueueMetadata {
  std::string operator_name;
  std::string comment;
  std::vector<std::string> tags;
  std::vector<std::string> duts;
};

// Registers the daemon-control subcommands on `app`; after parsing, run()
// executes the one chosen. Holds the parsed values, so it must outlive parsing.
class ControlCommands {
 public:
  explicit ControlCommands(CLI::App& app);
  ~ControlCommands();
  ControlCommands(const ControlCommands&) = delete;
  ControlCommands& operator=(const ControlCommands&) = delete;

  // The exit code when one of these subcommands was chosen, nullopt
  // otherwise. `json` is the top-level --json flag.
  std::optional<int> run(bool json);

 private:
  struct Parsed;
  std::unique_ptr<Parsed> parsed_;
};

// The database file the commands that read one use: `db_path` (--db), or
// the [storage] db of the station config `config_path` (--config). A
// permanent error when both or neither are given, or the config is bad.
struct DatabaseChoice {
  std::string path;
  bool given = false;  // false: neither option (the caller's default applies)
};
Result<DatabaseChoice> choose_database(const std::string& db_path, const std::string& config_path);

// ---- formatters: pure, never throw on missing or mistyped fields ("—").

// Station seconds as h:mm:ss (hours unbounded, fraction dropped); "—" for
// null or non-numeric.
std::string format_station_time(const nlohmann::json& t_s);
// A run's events (GET /api/v1/runs/{id}/events, or the lab's) as a table of
// time, kind, state transition and message, every line after `indent`;
// "  none" when there are none.
std::string format_events(const nlohmann::json& events, std::string_view indent = "");
// "2026-11-21T05:38:43.120Z" → "2026-11-21 05:38:43"; "—" for null.
std::string format_utc(const nlohmann::json& utc);

// GET /api/v1/status → a summary of the station.
std::string format_status(const nlohmann::json& status);
// GET /api/v1/queue (also the answer of a move) → hold line and a table.
std::string format_queue(const nlohmann::json& queue);
// POST /api/v1/queue 201 → one line naming the new entry.
std::string format_queued(const nlohmann::json& entry);
// GET /api/v1/runs → a table, newest first as given.
std::string format_runs(const nlohmann::json& runs);
// GET /api/v1/runs/{id} and /events → the run, its metadata and DUTs, its
// segments, its events.
std::string format_run(const nlohmann::json& run, const nlohmann::json& events);
// The metadata and DUT lines of a run (GET /api/v1/runs/{id}, PATCH answer).
std::string format_run_metadata(const nlohmann::json& run);
// GET /api/v1/duts → a table (serial, model, first seen, runs).
std::string format_duts(const nlohmann::json& duts);
// GET /api/v1/duts/{serial} → the DUT, then a table per run: its segments
// with set point, mean temperature and Table I bias and σ per axis; the
// scale factor per sequence and axis; then the DUT's drift fits.
std::string format_dut_history(const nlohmann::json& history);

// What to tell the user about a non-2xx answer: the daemon's `error`, then
// each of `errors` on its own line; the token, if any, is blanked out.
// `token_sent` picks the 401 wording.
std::string format_http_error(int status, const std::string& body, bool token_sent,
                              const std::string& token = "");

// `text` with every token the user may have given blanked out: the value of
// GYROTHERM_TOKEN and the argument after (or `=` part of) anything in `args`
// that starts with "--tok" (so a mistyped --tokne still hides its value).
std::string redact_tokens(std::string text, const std::vector<std::string>& args);

}  // namespace gyrotherm::cli

#include "control.h"

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <variant>
#include <vector>

#include "gyrotherm/cli/http_client.h"
#include "gyrotherm/config/config.h"
#include "gyrotherm/core/files.h"
#include "gyrotherm/core/toml_errors.h"
#include "gyrotherm/schedules/progress.h"
#include "gyrotherm/station/control.h"
#include "gyrotherm/storage/database.h"
#include "output.h"

namespace gyrotherm::cli {

using nlohmann::json;

namespace {

constexpr const char* kDash = "—";

// ---------------------------------------------------------------- JSON access

const json& field(const json& j, const char* key) {
  static const json kNull;
  if (!j.is_object()) return kNull;
  const auto it = j.find(key);
  return it == j.end() ? kNull : *it;
}

// The first of `keys` present and not null (the status snapshot has had two
// spellings: `schedule_name` / `schedule`, `step_index` / `step.index`).
const json& first_of(const json& j, std::initializer_list<const char*> keys) {
  for (const char* k : keys) {
    if (!field(j, k).is_null()) return field(j, k);
  }
  return field(j, "");
}

std::optional<double> number(const json& v) {
  if (!v.is_number()) return std::nullopt;
  const double d = v.get<double>();
  return std::isfinite(d) ? std::optional<double>(d) : std::nullopt;
}

std::string text(const json& v) {
  if (v.is_string()) return v.get<std::string>().empty() ? kDash : v.get<std::string>();
  if (v.is_number_integer()) return v.dump();
  if (v.is_number()) return fmt::format("{:g}", v.get<double>());
  if (v.is_boolean()) return v.get<bool>() ? "yes" : "no";
  if (v.is_null()) return kDash;
  return v.dump();
}

std::string fixed(const json& v, int decimals, std::string_view unit = "") {
  const auto d = number(v);
  if (!d) return kDash;
  return unit.empty() ? fmt::format("{:.{}f}", *d, decimals)
                      : fmt::format("{:.{}f} {}", *d, decimals, unit);
}

bool truthy(const json& v) { return v.is_boolean() && v.get<bool>(); }

// "a, b, c"; "—" for none.
std::string listed(const json& items) {
  if (!items.is_array() || items.empty()) return kDash;
  std::string out;
  for (const auto& i : items) out += (out.empty() ? "" : ", ") + text(i);
  return out;
}

// ---------------------------------------------------------------- tables

// "label       value" lines of a summary.
std::string labelled(std::string_view label, std::string_view value) {
  return fmt::format("{:<12}{}\n", label, value);
}

// ---------------------------------------------------------------- talking to the daemon

// Checks and tidies --url; nullopt (after saying why) when it is unusable.
std::optional<std::string> base_url(const std::string& url) {
  std::string u = url;
  while (!u.empty() && u.back() == '/') u.pop_back();
  if (u.rfind("http://", 0) != 0 || u.size() <= 7) {
    fail(fmt::format("--url \"{}\" is not an http:// URL (e.g. {})", url, kDefaultDaemonUrl), 2);
    return std::nullopt;
  }
  return u;
}

struct Answer {
  int status = 0;
  std::string body;
};

struct Request {
  std::string method;
  std::string path;  // under the base URL, e.g. "/api/v1/queue"
  std::string body;  // empty: none
};

// Sends one request, with the token when there is one (reads need it when
// the daemon's [api] read_access is "token"). When the URL is unusable or the daemon cannot be
// reached, says so and gives the exit code instead of an answer.

std::variant<Answer, int> send(const DaemonOptions& o, const Request& r) {
  const auto base = base_url(o.url);
  if (!base) return 2;
  const std::string url = *base + r.path;
  auto res = cli::http_request(r.method, url, r.body, o.token);
  if (!res) {
    // The client's message is "METHOD URL: reason"; keep the reason.
    std::string reason = res.error().message;
    const std::string prefix = r.method + " " + url + ": ";
    if (reason.rfind(prefix, 0) == 0) reason = reason.substr(prefix.size());
    return fail(
        fmt::format("cannot reach the daemon at {} ({}); is gyrothermd running? "
                    "(set --url or GYROTHERM_URL)",
                    *base, reason));
  }
  return Answer{res->status, std::move(res->body)};
}

// Prints an answer: the body as is with --json (whatever the status, so a
// script sees `errors` too), else `format` of it; a non-2xx answer also gets
// its error on stderr and exit code 1.
int finish(const DaemonOptions& o, const Answer& a,
           const std::function<std::string(const json&)>& format) {
  if (o.json && !a.body.empty()) {
    std::cout << a.body;
    if (a.body.back() != '\n') std::cout << '\n';
  }
  if (a.status < 200 || a.status > 299) {
    return fail(format_http_error(a.status, a.body, !o.token.empty(), o.token));
  }
  if (o.json) return 0;
  const json j = json::parse(a.body, nullptr, false);
  if (j.is_discarded()) return fail("the daemon's answer is not valid JSON");
  std::cout << format(j);
  return 0;
}

int exchange(const DaemonOptions& o, const Request& r,
             const std::function<std::string(const json&)>& format) {
  auto a = send(o, r);
  if (const int* code = std::get_if<int>(&a)) return *code;
  return finish(o, std::get<Answer>(a), format);
}

int cmd_queue_add(const DaemonOptions& o, const std::string& path, bool ignore_failures,
                  const QueueMetadata& metadata) {
  // Bounded, and only a regular file: /dev/zero is refused, not read forever.
  auto text = read_bounded_file(path, kMaxTomlFileBytes);
  if (!text) return fail(text.error().message, 2);
  json body = {{"schedule_toml", *text}, {"source", path}, {"ignore_failures", ignore_failures}};
  // Only what was given: the daemon's defaults (every configured DUT) stay.
  if (!metadata.operator_name.empty()) body["operator"] = metadata.operator_name;
  if (!metadata.comment.empty()) body["comment"] = metadata.comment;
  if (!metadata.tags.empty()) body["tags"] = metadata.tags;
  if (!metadata.duts.empty()) body["duts"] = metadata.duts;
  const int code = exchange(o, {"POST", "/api/v1/queue", body.dump()}, format_queued);
  if (code != 0 || o.json) return code;
  // Queued onto a held queue, the entry waits: say so and what releases it.
  auto queue = send(o, {"GET", "/api/v1/queue", ""});
  if (const Answer* a = std::get_if<Answer>(&queue); a && a->status == 200) {
    const json q = json::parse(a->body, nullptr, false);
    if (truthy(field(q, "held"))) {
      const json& reason = field(q, "hold_reason");
      std::cout << (reason.is_string() && !reason.get<std::string>().empty()
                        ? fmt::format("the queue is held ({}): the entry waits until gyrotherm "
                                      "resume releases the queue\n",
                                      reason.get<std::string>())
                        : std::string("the queue is held: the entry waits until gyrotherm resume "
                                      "releases the queue\n"));
    }
  }
  return 0;
}

int cmd_control(const DaemonOptions& o, const std::string& action, const std::string& reason) {
  const std::string body = reason.empty() ? "" : json({{"reason", reason}}).dump();
  return exchange(o, {"POST", "/api/v1/control/" + action, body}, [](const json& j) {
    const auto& m = field(j, "message");
    return (m.is_string() ? m.get<std::string>() : std::string("done")) + "\n";
  });
}

// The run and then its events; --json prints the run object with an added
// "events" array.
int cmd_run(const DaemonOptions& o, int64_t id) {
  const std::string path = fmt::format("/api/v1/runs/{}", id);
  const Request run_req{"GET", path, ""};
  const Request events_req{"GET", path + "/events", ""};
  auto run = send(o, run_req);
  if (const int* code = std::get_if<int>(&run)) return *code;
  const Answer& run_answer = std::get<Answer>(run);
  if (run_answer.status < 200 || run_answer.status > 299) {
    return finish(o, run_answer, nullptr);
  }
  auto events = send(o, events_req);
  if (const int* code = std::get_if<int>(&events)) return *code;
  const Answer& events_answer = std::get<Answer>(events);
  if (events_answer.status < 200 || events_answer.status > 299) {
    return finish(o, events_answer, nullptr);
  }
  json run_json = json::parse(run_answer.body, nullptr, false);
  const json events_json = json::parse(events_answer.body, nullptr, false);
  if (run_json.is_discarded() || events_json.is_discarded()) {
    return fail("the daemon's answer is not valid JSON");
  }
  if (o.json) {
    if (run_json.is_object()) run_json["events"] = events_json;
    std::cout << run_json.dump(2) << "\n";
    return 0;
  }
  std::cout << format_run(run_json, events_json);
  return 0;
}

// `runs` and `run ID` on a database file, answering as the daemon would.
int offline_runs(const std::string& db_path, bool as_json) {
  auto db = storage::Database::open_read_only(db_path);
  if (!db) return fail(db.error().message, 2);
  auto runs = db->runs();
  if (!runs) return fail(runs.error().message);
  json out = json::array();
  for (auto it = runs->rbegin(); it != runs->rend(); ++it) out.push_back(station::to_json(*it));
  std::cout << (as_json ? out.dump(2) + "\n" : format_runs(out));
  return 0;
}

int offline_run(const std::string& db_path, int64_t id, bool as_json) {
  auto db = storage::Database::open_read_only(db_path);
  if (!db) return fail(db.error().message, 2);
  auto run = station::run_detail_json(*db, id);
  if (!run) {
    return fail(run.error().transient ? run.error().message
                                      : fmt::format("no run {} in {}", id, db_path));
  }
  auto events = db->events(id);
  if (!events) return fail(events.error().message);
  json run_json = std::move(*run);
  json events_json = json::array();
  for (const auto& e : *events) events_json.push_back(station::to_json(e));
  if (as_json) {
    run_json["events"] = std::move(events_json);
    std::cout << run_json.dump(2) << "\n";
    return 0;
  }
  std::cout << format_run(run_json, events_json);
  return 0;
}

// "a, b,c" -> {"a", "b", "c"}: items trimmed, empty ones dropped (so "" is
// the empty list).
std::vector<std::string> split_list(const std::string& text) {
  std::vector<std::string> out;
  std::size_t start = 0;
  while (start <= text.size()) {
    std::size_t end = text.find(',', start);
    if (end == std::string::npos) end = text.size();
    std::string item = text.substr(start, end - start);
    const auto first = item.find_first_not_of(" \t");
    const auto last = item.find_last_not_of(" \t");
    if (first != std::string::npos) out.push_back(item.substr(first, last - first + 1));
    start = end + 1;
  }
  return out;
}

// `edit-run`: PATCH /api/v1/runs/{id} with the fields given.
int cmd_edit_run(const DaemonOptions& o, int64_t id, const json& body) {
  if (body.empty()) {
    return fail("edit-run: give at least one of --operator, --comment, --tags, --duts", 2);
  }
  return exchange(o, {"PATCH", fmt::format("/api/v1/runs/{}", id), body.dump()},
                  [id](const json& run) {
                    return fmt::format(
                               "run {}: metadata saved (an event of kind metadata "
                               "records the change)\n",
                               id) +
                           format_run_metadata(run);
                  });
}

// "/api/v1/duts/SERIAL" with the serial percent-encoded (a serial may hold
// spaces or slashes).
std::string dut_path(const std::string& serial) {
  std::string out = "/api/v1/duts/";
  for (unsigned char c : serial) {
    if (std::isalnum(c) || c == '-' || c == '_' || c == '.' || c == '~') {
      out += static_cast<char>(c);
    } else {
      out += fmt::format("%{:02X}", c);
    }
  }
  return out;
}

// `dut SERIAL` and `duts` on a database file, answering as the daemon would.
int offline_dut(const std::string& db_path, const std::string& serial, bool as_json) {
  auto db = storage::Database::open_read_only(db_path);
  if (!db) return fail(db.error().message, 2);
  auto history = station::dut_history_json(*db, serial);
  if (!history) {
    return fail(history.error().transient
                    ? history.error().message
                    : fmt::format("{} in {} (gyrotherm duts --db {} lists them)",
                                  history.error().message, db_path, db_path));
  }
  std::cout << (as_json ? history->dump(2) + "\n" : format_dut_history(*history));
  return 0;
}

int offline_duts(const std::string& db_path, bool as_json) {
  auto db = storage::Database::open_read_only(db_path);
  if (!db) return fail(db.error().message, 2);
  auto duts = station::duts_json(*db);
  if (!duts) return fail(duts.error().message);
  std::cout << (as_json ? duts->dump(2) + "\n" : format_duts(*duts));
  return 0;
}

// A whole number >= min for CLI11, refused in words ("-1 is not a
// position (0 = next, 1, 2, …)") instead of CLI11's range bounds.
CLI::Validator whole_number(int64_t min, std::string what) {
  return CLI::Validator(
      [min, what](std::string& text) -> std::string {
        int64_t v = 0;
        const char* end = text.data() + text.size();
        const auto [ptr, ec] = std::from_chars(text.data(), end, v);
        if (ec == std::errc() && ptr == end && v >= min) return "";
        return fmt::format("{} is not {}", text.size() > 40 ? text.substr(0, 40) + "…" : text,
                           what);
      },
      min == 0 ? "INTEGER >= 0" : "INTEGER >= 1");
}

std::string env_or(const char* name, const std::string& fallback) {
  const char* v = std::getenv(name);
  return v && *v ? std::string(v) : fallback;
}

}  // namespace

// ---------------------------------------------------------------- command line

struct ControlCommands::Parsed {
  DaemonOptions options;
  CLI::App* status = nullptr;
  CLI::App* queue_add = nullptr;
  CLI::App* queue_list = nullptr;
  CLI::App* queue_remove = nullptr;
  CLI::App* queue_move = nullptr;
  std::vector<std::pair<std::string, CLI::App*>> actions;
  CLI::App* runs = nullptr;
  CLI::App* run = nullptr;
  CLI::App* edit_run = nullptr;
  CLI::App* dut = nullptr;
  CLI::App* duts = nullptr;
  QueueMetadata metadata;  // queue add
  // edit-run: given or not (an empty value clears the field).
  CLI::Option* edit_operator = nullptr;
  CLI::Option* edit_comment = nullptr;
  CLI::Option* edit_tags = nullptr;
  CLI::Option* edit_duts = nullptr;
  std::string tags_list, duts_list;
  std::string serial;
  std::string schedule_path;
  std::string db_path, config_path;  // runs, run: read this database, not the daemon
  bool ignore_failures = false;
  int64_t id = 0;
  int64_t position = 0;
  std::string reason;
};

ControlCommands::ControlCommands(CLI::App& app) : parsed_(std::make_unique<Parsed>()) {
  Parsed& p = *parsed_;
  p.options.url = env_or("GYROTHERM_URL", kDefaultDaemonUrl);
  p.options.token = env_or("GYROTHERM_TOKEN", "");
  auto common = [&p](CLI::App* cmd) {
    cmd->add_option("--url", p.options.url,
                    fmt::format("daemon URL (env GYROTHERM_URL, default {})", kDefaultDaemonUrl));
    cmd->add_option("--token", p.options.token, "API token for changes (env GYROTHERM_TOKEN)");
    cmd->add_flag("--json", p.options.json, "print the daemon's JSON answer as is");
    return cmd;
  };

  p.status = common(app.add_subcommand("status", "the daemon's status"));

  auto* queue = app.add_subcommand("queue", "the daemon's schedule queue");
  queue->require_subcommand(1);
  p.queue_add = common(queue->add_subcommand("add", "validate and queue a schedule file"));
  p.queue_add->add_option("file", p.schedule_path, "schedule file (TOML)")->required();
  p.queue_add->add_flag("--ignore-failures", p.ignore_failures,
                        "keep the queue going when this run fails");
  p.queue_add->add_option("--operator", p.metadata.operator_name,
                          "who runs it (kept with the run)");
  p.queue_add->add_option("--comment", p.metadata.comment, "why, or anything to remember");
  p.queue_add->add_option("--tag", p.metadata.tags, "a free tag (repeat for more)")
      ->allow_extra_args(false);
  p.queue_add
      ->add_option("--dut", p.metadata.duts,
                   "serial of a [[dut]] to record (repeat for more; default: every configured "
                   "DUT)")
      ->allow_extra_args(false);
  p.queue_list = common(queue->add_subcommand("list", "the running and waiting entries"));
  p.queue_remove = common(queue->add_subcommand("remove", "remove a waiting entry"));
  const CLI::Validator entry_id = whole_number(1, "a queue entry id (1, 2, …)");
  p.queue_remove->add_option("id", p.id, "queue entry id")->required()->check(entry_id);
  p.queue_move = common(queue->add_subcommand("move", "move a waiting entry"));
  p.queue_move->add_option("id", p.id, "queue entry id")->required()->check(entry_id);
  p.queue_move->add_option("position", p.position, "new position (0 = next)")
      ->required()
      ->check(whole_number(0, "a position (0 = next, 1, 2, …)"));

  const std::pair<const char*, const char*> actions[] = {
      {"pause", "hold the set point and stop the acquisition clock"},
      {"resume", "end a pause, or release a held queue"},
      {"abort", "end the current run: chamber to the safe set point, queue held"},
      {"stop", "let the current run complete, then hold the queue"},
  };
  for (const auto& [name, help] : actions) {
    auto* cmd = common(app.add_subcommand(name, help));
    cmd->add_option("--reason", p.reason, "text for the event log");
    p.actions.emplace_back(name, cmd);
  }

  p.runs = common(app.add_subcommand("runs", "runs recorded by the daemon, newest first"));
  p.run = common(app.add_subcommand("run", "one run: its segments and events"));
  p.run->add_option("id", p.id, "run id")->required()->check(whole_number(1, "a run id (1, 2, …)"));
  p.edit_run = common(app.add_subcommand(
      "edit-run", "change a run's operator, comment, tags or DUT serials (recorded as an event)"));
  p.edit_run->add_option("id", p.id, "run id")
      ->required()
      ->check(whole_number(1, "a run id (1, 2, …)"));
  p.edit_operator =
      p.edit_run->add_option("--operator", p.metadata.operator_name, "who ran it (\"\" clears it)");
  p.edit_comment = p.edit_run->add_option("--comment", p.metadata.comment, "the comment");
  p.edit_tags = p.edit_run->add_option(
      "--tags", p.tags_list, "the tags, comma-separated (replace the run's; \"\" = none)");
  p.edit_duts = p.edit_run->add_option("--duts", p.duts_list,
                                       "the DUT serials, comma-separated (replace the run's)");

  p.dut = common(app.add_subcommand(
      "dut",
      "everything one DUT has been through: its runs, segments, Table I, scale factor, fits"));
  p.dut->add_option("serial", p.serial, "the DUT's serial number")->required();
  p.duts = common(app.add_subcommand("duts", "every DUT the station has recorded"));

  for (CLI::App* cmd : {p.runs, p.run, p.dut, p.duts}) {
    auto* db = cmd->add_option("--db", p.db_path, "read this database file instead of the daemon");
    auto* config = cmd->add_option("--config", p.config_path,
                                   "read the database of this station config ([storage] db)");
    db->excludes(config);
  }
}

ControlCommands::~ControlCommands() = default;

std::optional<int> ControlCommands::run(bool json_flag) {
  Parsed& p = *parsed_;
  DaemonOptions o = p.options;
  o.json = o.json || json_flag;
  if (*p.status) return exchange(o, {"GET", "/api/v1/status", ""}, format_status);
  if (*p.queue_add) return cmd_queue_add(o, p.schedule_path, p.ignore_failures, p.metadata);
  if (*p.queue_list) return exchange(o, {"GET", "/api/v1/queue", ""}, format_queue);
  if (*p.queue_remove) {
    return exchange(o, {"DELETE", fmt::format("/api/v1/queue/{}", p.id), ""}, [](const json& j) {
      return fmt::format("removed queue entry {}\n", text(field(j, "removed")));
    });
  }
  if (*p.queue_move) {
    const std::string body = nlohmann::json({{"position", p.position}}).dump();
    return exchange(o, {"POST", fmt::format("/api/v1/queue/{}/move", p.id), body}, format_queue);
  }
  for (const auto& [name, cmd] : p.actions) {
    if (*cmd) return cmd_control(o, name, p.reason);
  }
  if (*p.runs || *p.run) {
    auto db = choose_database(p.db_path, p.config_path);
    if (!db) return fail(db.error().message, 2);
    if (db->given)
      return *p.runs ? offline_runs(db->path, o.json) : offline_run(db->path, p.id, o.json);
    if (*p.runs) return exchange(o, {"GET", "/api/v1/runs", ""}, format_runs);
    return cmd_run(o, p.id);
  }
  if (*p.edit_run) {
    json body = json::object();
    if (p.edit_operator->count() > 0) body["operator"] = p.metadata.operator_name;
    if (p.edit_comment->count() > 0) body["comment"] = p.metadata.comment;
    if (p.edit_tags->count() > 0) body["tags"] = split_list(p.tags_list);
    if (p.edit_duts->count() > 0) body["duts"] = split_list(p.duts_list);
    return cmd_edit_run(o, p.id, body);
  }
  if (*p.dut || *p.duts) {
    auto db = choose_database(p.db_path, p.config_path);
    if (!db) return fail(db.error().message, 2);
    if (db->given) {
      return *p.dut ? offline_dut(db->path, p.serial, o.json) : offline_duts(db->path, o.json);
    }
    if (*p.duts) return exchange(o, {"GET", "/api/v1/duts", ""}, format_duts);
    return exchange(o, {"GET", dut_path(p.serial), ""}, format_dut_history);
  }
  return std::nullopt;
}

// ---------------------------------------------------------------- formatters

std::string format_station_time(const json& t_s) {
  const auto t = number(t_s);
  if (!t) return kDash;
  const auto s = static_cast<int64_t>(std::floor(std::fabs(*t)));
  return fmt::format("{}{}:{:02}:{:02}", *t < 0 ? "-" : "", s / 3600, s / 60 % 60, s % 60);
}

std::string format_events(const json& events, std::string_view indent) {
  if (!events.is_array() || events.empty()) return "  none\n";
  std::vector<std::vector<std::string>> rows;
  for (const auto& e : events) {
    const json& from = field(e, "from_state");
    const json& to = field(e, "to_state");
    const bool has_from = from.is_string() && !from.get<std::string>().empty();
    const bool has_to = to.is_string() && !to.get<std::string>().empty();
    std::string transition;
    if (has_from || has_to) {
      transition = fmt::format("{} → {}", has_from ? from.get<std::string>() : "",
                               has_to ? to.get<std::string>() : "");
    }
    const json& message = field(e, "message");
    rows.push_back({format_station_time(field(e, "t_s")), text(field(e, "kind")), transition,
                    message.is_string() ? message.get<std::string>() : std::string()});
  }
  return table({"time", "kind", "from → to", "message"},
               {Align::kRight, Align::kLeft, Align::kLeft, Align::kLeft}, rows, indent);
}

std::string format_utc(const json& utc) {
  if (!utc.is_string()) return kDash;
  const auto s = utc.get<std::string>();
  if (s.size() >= 19 && s[10] == 'T') return s.substr(0, 10) + " " + s.substr(11, 8);
  return s.empty() ? kDash : s;
}

namespace {

// "2 h 10 min + 2 settles" (a time that excludes settles of unknown length).
std::string fixed_and_settles(const json& fixed_s, const json& settles) {
  std::string out = schedules::format_duration(number(fixed_s).value_or(0));
  const int n = static_cast<int>(number(settles).value_or(0));
  if (n > 0) out += fmt::format(" + {} settle{}", n, n == 1 ? "" : "s");
  return out;
}

// A settling soak's forecast: ", gate in 42 min (P10 30 min – P90 1 h 5 min)",
// ", gate holds on the shell now", ", gate forecast: not enough curvature
// yet"; a fit whose final value is still so uncertain that most draws never
// pass is said so; "" without a forecast.
std::string format_settle(const json& f) {
  if (!f.is_object()) return "";
  const std::string verdict = text(field(f, "verdict"));
  const auto p10 = number(field(f, "p10_s")), p50 = number(field(f, "p50_s")),
             p90 = number(field(f, "p90_s"));
  if (verdict == "predicted" && p10) {
    const std::string hi = p90 ? schedules::format_duration(*p90) : "beyond 48 h";
    if (!p50) {
      return fmt::format(", gate forecast too uncertain yet (P10 {}, median beyond 48 h)",
                         schedules::format_duration(*p10));
    }
    return fmt::format(", gate in {} (P10 {} – P90 {})", schedules::format_duration(*p50),
                       schedules::format_duration(*p10), hi);
  }
  if (verdict == "holds_now") return ", gate holds on the shell now";
  if (verdict == "not_enough_curvature") return ", gate forecast: not enough curvature yet";
  if (verdict == "never_within_tolerance") {
    return ", gate forecast: the shell settles outside the tolerance (" + text(field(f, "note")) +
           ")";
  }
  return "";
}

// An adaptive soak's judgement: ", U95 0.041 °/h → 0.03 (widest: 17-0042 z),
// target in ~6 min", ", target reached on every axis", ", target out of reach
// on 17-0042 z (floor = …)"; "" without one.
std::string format_acquire(const json& a) {
  if (!a.is_object() || !field(a, "axes").is_array() || field(a, "axes").empty()) return "";
  const auto target = number(field(a, "target_u95_dph")).value_or(0);
  const auto acquired = number(field(a, "acquired_s")).value_or(0);
  std::optional<double> widest;
  std::string widest_name, out_of_reach, no_model;
  bool all_reached = true;
  for (const json& axis : field(a, "axes")) {
    const std::string verdict = text(field(axis, "verdict"));
    const std::string name = text(field(axis, "name"));
    if (verdict != "reached") all_reached = false;
    if (verdict == "out_of_reach") out_of_reach += (out_of_reach.empty() ? "" : ", ") + name;
    if (verdict == "no_model") no_model += (no_model.empty() ? "" : ", ") + name;
    if (const auto u = number(field(axis, "u95_dph")); u && (!widest || *u > *widest)) {
      widest = u;
      widest_name = name;
    }
  }
  if (all_reached) return fmt::format(", target U95 {:g} °/h reached on every axis", target);
  std::string out =
      widest ? fmt::format(", U95 {:.3g} → {:g} °/h (widest: {})", *widest, target, widest_name)
             : fmt::format(", target U95 {:g} °/h", target);
  if (!out_of_reach.empty()) return out + ", out of reach on " + out_of_reach;
  if (!no_model.empty()) return out + ", no noise model yet for " + no_model;
  if (const auto planned = number(field(a, "planned_s"))) {
    return out + fmt::format(", target in ~{}",
                             schedules::format_duration(std::max(0.0, *planned - acquired)));
  }
  return out + ", target not projected within the cap";
}

// The progress line (docs/schedules.md, "Planned duration and progress"):
// "acquiring 42% · run ends in 2 h 10 min", "settling, gate 4 min of 10 min ·
// run ≥ 2 h 10 min + 2 settles". Empty without a progress object.
std::string format_progress(const json& p) {
  if (!p.is_object()) return "";
  std::string step = text(field(p, "phase"));
  const auto fraction = number(field(p, "step_fraction"));
  const auto held = number(field(p, "gate_held_s"));
  const auto needed = number(field(p, "gate_needed_s"));
  if (fraction) step += fmt::format(" {:.0f}%", std::floor(*fraction * 100));
  if (held && needed) {
    step += fmt::format(", gate {} of {}", schedules::format_duration(*held),
                        schedules::format_duration(*needed));
  }
  step += format_settle(field(p, "settle"));
  step += format_acquire(field(p, "acquire"));
  if (const auto eta = number(field(p, "run_eta_s"))) {
    std::string band;
    if (const auto lo = number(field(p, "run_eta_p10_s"))) {
      const auto hi = number(field(p, "run_eta_p90_s"));
      std::string from;
      const int past = static_cast<int>(number(field(p, "prior_settles")).value_or(0));
      if (past > 0) from = fmt::format("; settles from the chamber's last {}", past);
      band = fmt::format(" (P10 {} – P90 {}{})", schedules::format_duration(*lo),
                         hi ? schedules::format_duration(*hi) : "beyond 48 h", from);
    }
    return fmt::format("{} · run ends in {}{}", step, schedules::format_duration(*eta), band);
  }
  return fmt::format(
      "{} · run ≥ {}", step,
      fixed_and_settles(field(p, "run_remaining_fixed_s"), field(p, "run_settles_remaining")));
}

// One DUT of status.duts: "17-0042  KVH 1750  x +8.012  y −0.002  z 0.010 °/h
// (primary z)  41.2 °C  1000 samples/s  connected".
std::string format_dut(const json& d) {
  std::string rates;
  const json& r = field(d, "rates_dph");
  if (r.is_object()) {
    for (const auto& [axis, v] : r.items()) {
      rates += fmt::format("{}{} {}", rates.empty() ? "" : "  ", axis, fixed(v, 3));
    }
  }
  const json& health = field(d, "health");
  std::string link = truthy(field(health, "connected")) ? "connected" : "DISCONNECTED";
  if (const json& err = field(health, "last_error");
      !truthy(field(health, "connected")) && err.is_string() && !err.get<std::string>().empty()) {
    link += " (" + err.get<std::string>() + ")";
  }
  return fmt::format("{}  {}  {} °/h (primary {})  {}  {} samples/s  {}", text(field(d, "serial")),
                     text(field(d, "model")), rates.empty() ? std::string(kDash) : rates,
                     text(field(d, "primary_axis")), fixed(field(d, "temp_c"), 1, "°C"),
                     fixed(field(d, "samples_per_s"), 0), link);
}

}  // namespace

std::string format_status(const json& j) {
  std::string out;
  const auto& station = first_of(j, {"station", "station_name"});
  if (!station.is_null()) out += labelled("station", text(station));

  std::string state = text(field(j, "state"));
  if (truthy(field(j, "paused")) && state != "paused") state += " (paused)";
  out += labelled("state", state);

  if (!field(j, "run_id").is_null()) {
    out += labelled("run", fmt::format("{}  {}", text(field(j, "run_id")),
                                       text(first_of(j, {"schedule_name", "schedule"}))));
    // Who runs it (docs/api.md "Run metadata"), when the daemon says.
    if (const json& m = field(j, "run_metadata"); m.is_object()) {
      std::string who = text(field(m, "operator"));
      if (field(m, "tags").is_array() && !field(m, "tags").empty()) {
        who += fmt::format("  (tags: {})", listed(field(m, "tags")));
      }
      out += labelled("operator", who);
    }
    // Flat per docs/api.md, or nested as {"step": {"index", "count", "label"}}.
    const json& step = field(j, "step");
    auto pick = [&](const char* flat, const char* nested) -> const json& {
      return field(j, flat).is_null() ? field(step, nested) : field(j, flat);
    };
    const auto index = number(pick("step_index", "index"));
    out += labelled(
        "step",
        fmt::format("{}/{}  {}",
                    index ? std::to_string(static_cast<int64_t>(*index) + 1) : std::string(kDash),
                    text(pick("step_count", "count")), text(pick("step_label", "label"))));
    if (const std::string progress = format_progress(field(j, "progress")); !progress.empty()) {
      out += labelled("progress", progress);
    }
    // The run's comment (its operator and tags are on the "operator" line).
    if (const json& c = field(field(j, "run_metadata"), "comment");
        c.is_string() && !c.get<std::string>().empty()) {
      out += labelled("comment", c.get<std::string>());
    }
  }
  out += labelled("set point", fixed(field(j, "setpoint_c"), 2, "°C"));
  out += labelled("chamber", fixed(field(j, "chamber_c"), 2, "°C"));
  out += labelled("top / side", fmt::format("{} / {}  (gradient {})", fixed(field(j, "top_c"), 2),
                                            fixed(field(j, "side_c"), 2, "°C"),
                                            fixed(field(j, "gradient_c"), 2, "°C")));
  out += labelled("temp rate", fixed(field(j, "temp_rate_c_per_min"), 3, "°C/min"));
  out +=
      labelled("gyro", fmt::format("{}  ({} samples/s)", fixed(field(j, "gyro_rate_dph"), 3, "°/h"),
                                   fixed(field(j, "gyro_samples_per_s"), 0)));
  if (const json& duts = field(j, "duts"); duts.is_array()) {
    bool first = true;
    for (const auto& d : duts) {
      out += labelled(first ? "duts" : "", format_dut(d));
      first = false;
    }
  }

  const json& interlocks = field(j, "interlocks");
  if (!interlocks.is_array() || interlocks.empty()) {
    out += labelled("interlocks", "none");
  } else {
    bool first = true;
    for (const auto& i : interlocks) {
      std::string line = fmt::format("{}: {}", text(field(i, "kind")), text(field(i, "message")));
      if (number(field(i, "since_s"))) {
        line += fmt::format(" (since {})", format_station_time(field(i, "since_s")));
      }
      out += labelled(first ? "interlocks" : "", line);
      first = false;
    }
  }

  std::string queue = fmt::format("{} waiting", text(field(j, "queue_length")));
  if (const json& p = field(j, "progress");
      number(field(j, "queue_length")).value_or(0) > 0 && p.is_object()) {
    queue += ", ≥ " + fixed_and_settles(field(p, "queue_fixed_s"), field(p, "queue_settles"));
    const auto eta = number(field(p, "queue_eta_s"));
    const auto lo = number(field(p, "queue_eta_p10_s")), hi = number(field(p, "queue_eta_p90_s"));
    if (eta && lo && hi && number(field(p, "queue_settles")).value_or(0) > 0) {
      queue += fmt::format(", ~{} with the chamber's past settles (P10 {} – P90 {})",
                           schedules::format_duration(*eta), schedules::format_duration(*lo),
                           schedules::format_duration(*hi));
    }
  }
  if (truthy(field(j, "queue_held"))) {
    const json& reason = field(j, "queue_hold_reason");
    queue += reason.is_string() && !reason.get<std::string>().empty()
                 ? fmt::format(", held: {}", reason.get<std::string>())
                 : std::string(", held");
  }
  out += labelled("queue", queue);
  // [lab] (docs/lab.md): the relay's state, what waits and why.
  if (const json& lab = field(j, "lab"); lab.is_object()) {
    std::string line =
        fmt::format("{}: {}", text(field(lab, "station_id")), text(field(lab, "state")));
    if (number(field(lab, "retry_in_s"))) {
      line += fmt::format(" (retry in {})", fixed(field(lab, "retry_in_s"), 1, "s"));
    }
    line += fmt::format(", {} pending", text(field(lab, "pending")));
    if (number(field(lab, "oldest_pending_age_s")).value_or(0) > 0) {
      line +=
          fmt::format(" (oldest {} ago)", format_station_time(field(lab, "oldest_pending_age_s")));
    }
    line += fmt::format(", {} sent", text(field(lab, "sent_total")));
    if (number(field(lab, "last_lag_s"))) {
      line += fmt::format(", lag {}", fixed(field(lab, "last_lag_s"), 3, "s"));
    }
    if (const json& e = field(lab, "last_error"); e.is_string() && !e.get<std::string>().empty()) {
      line += ": " + e.get<std::string>();
    }
    out += labelled("lab", line);
  }

  out += labelled(
      "time", fmt::format("station {}, run {}, time scale {}×",
                          format_station_time(field(j, "t_station_s")),
                          format_station_time(field(j, "t_run_s")), text(field(j, "time_scale"))));
  out += labelled("uptime", format_station_time(field(j, "uptime_s")) + " (wall)");
  const json& last = field(j, "last_event");
  if (!last.is_null() && !(last.is_string() && last.get<std::string>().empty())) {
    out += labelled("last event", last.is_object() ? fmt::format("{} {}", text(field(last, "kind")),
                                                                 text(field(last, "message")))
                                                   : text(last));
  }

  const json& devices = field(j, "devices");
  if (devices.is_object()) {
    // Chamber, probes, gyro first, in the station's order; anything else after.
    std::vector<std::string> names;
    for (const char* known : {"chamber", "probes", "gyro"}) {
      if (devices.contains(known)) names.emplace_back(known);
    }
    for (const auto& [name, d] : devices.items()) {
      if (std::find(names.begin(), names.end(), name) == names.end()) names.push_back(name);
    }
    bool first = true;
    for (const auto& name : names) {
      const json& d = devices[name];
      std::string health = truthy(field(d, "connected")) ? "connected" : "DISCONNECTED";
      const json& err = field(d, "last_error");
      if (!truthy(field(d, "connected")) && err.is_string() && !err.get<std::string>().empty()) {
        health += " (" + err.get<std::string>() + ")";
      }
      if (!field(d, "frames_ok").is_null()) {
        health += fmt::format("; {} frames, {} CRC failures, {} sequence gaps",
                              text(field(d, "frames_ok")), text(field(d, "crc_failures")),
                              text(field(d, "sequence_gaps")));
      } else if (!field(d, "errors").is_null()) {
        health += fmt::format("; {} errors", text(field(d, "errors")));
      }
      out += labelled(first ? "devices" : "", fmt::format("{:<8} {}", name, health));
      first = false;
    }
  }
  return out;
}

std::string format_queue(const json& q) {
  std::string out;
  if (truthy(field(q, "held"))) {
    const json& reason = field(q, "hold_reason");
    out += reason.is_string() && !reason.get<std::string>().empty()
               ? fmt::format("queue held: {} (gyrotherm resume releases it)\n",
                             reason.get<std::string>())
               : "queue held (gyrotherm resume releases it)\n";
  }
  std::vector<std::vector<std::string>> rows;
  auto row = [&](const std::string& position, const json& e) {
    rows.push_back({position, text(field(e, "id")), text(field(e, "schedule_name")),
                    text(field(e, "steps")), text(field(e, "ignore_failures")),
                    format_utc(field(e, "added_utc"))});
  };
  const json& current = field(q, "current");
  if (current.is_object()) row(fmt::format("run {}", text(field(current, "run_id"))), current);
  const json& entries = field(q, "entries");
  if (entries.is_array()) {
    for (const auto& e : entries) {
      if (current.is_object() && field(e, "id") == field(current, "id")) continue;
      row(text(field(e, "position")), e);
    }
  }
  if (rows.empty()) return out + "queue empty\n";
  return out + table({"pos", "id", "schedule", "steps", "ignore failures", "added (UTC)"},
                     {Align::kRight, Align::kRight, Align::kLeft, Align::kRight, Align::kLeft,
                      Align::kLeft},
                     rows);
}

std::string format_queued(const json& e) {
  const json& steps = field(e, "steps");
  return fmt::format("queued entry {}: {} ({} step{}) at position {}{}\n", text(field(e, "id")),
                     text(field(e, "schedule_name")), text(steps), steps == 1 ? "" : "s",
                     text(field(e, "position")),
                     truthy(field(e, "ignore_failures")) ? ", failures ignored" : "");
}

namespace {

// A result's quality (docs/api.md) as a table column: ok, FLAGGED,
// excluded, or a dash when not assessed or absent.
std::string quality_mark(const json& quality) {
  const json& verdict = field(quality, "verdict");
  if (!verdict.is_string() || verdict == "unassessed") return kDash;
  return verdict == "flagged" ? "FLAGGED" : verdict.get<std::string>();
}

std::string quality_reasons(const json& quality) {
  std::vector<std::string> out;
  for (const auto& r :
       field(quality, "reasons").is_array() ? field(quality, "reasons") : json::array()) {
    if (r.is_string()) out.push_back(r.get<std::string>());
  }
  return fmt::format("{}", fmt::join(out, "; "));
}

}  // namespace

std::string format_runs(const json& runs) {
  if (!runs.is_array() || runs.empty()) return "no runs\n";
  std::vector<std::vector<std::string>> rows;
  for (const auto& r : runs) {
    rows.push_back({text(field(r, "id")), text(field(r, "schedule_name")), text(field(r, "state")),
                    format_utc(field(r, "started_utc")), format_utc(field(r, "ended_utc"))});
  }
  return table({"id", "schedule", "state", "started (UTC)", "ended (UTC)"},
               {Align::kRight, Align::kLeft, Align::kLeft, Align::kLeft, Align::kLeft}, rows);
}

std::string format_run(const json& run, const json& events) {
  std::string out = fmt::format("run {}  {}  {}\n", text(field(run, "id")),
                                text(field(run, "schedule_name")), text(field(run, "state")));
  out += labelled("started", format_utc(field(run, "started_utc")) + " UTC");
  out += labelled("ended", field(run, "ended_utc").is_null()
                               ? std::string(kDash)
                               : format_utc(field(run, "ended_utc")) + " UTC");
  out += labelled("queue entry", text(field(run, "queue_id")));
  out += labelled("time scale", text(field(run, "time_scale")) + "×");
  out += format_run_metadata(run);

  out += "\nsegments (times: station h:mm:ss since the run started)\n";
  const json& segments = field(run, "segments");
  if (!segments.is_array() || segments.empty()) {
    out += "  none\n";
  } else {
    std::vector<std::vector<std::string>> rows;
    for (const auto& s : segments) {
      const auto index = number(field(s, "index"));
      const json& from = field(s, "t_acquire_start_s");
      std::string acquire = kDash;
      if (!from.is_null()) {
        acquire = format_station_time(from) + "–" +
                  (field(s, "t_acquire_end_s").is_null()
                       ? std::string("")
                       : format_station_time(field(s, "t_acquire_end_s")));
      }
      rows.push_back({index ? std::to_string(static_cast<int64_t>(*index) + 1) : kDash,
                      text(field(s, "kind")), text(field(s, "label")),
                      fixed(field(s, "setpoint_c"), 2), fixed(field(s, "ramp_rate_c_per_min"), 2),
                      format_station_time(field(s, "t_start_s")),
                      format_station_time(field(s, "t_settled_s")), acquire,
                      format_station_time(field(s, "t_end_s")),
                      format_station_time(field(s, "paused_s")), text(field(s, "state"))});
    }
    out += table(
        {"#", "kind", "label", "set °C", "°C/min", "start", "settled", "acquire", "end", "paused",
         "state"},
        {Align::kRight, Align::kLeft, Align::kLeft, Align::kRight, Align::kRight, Align::kRight,
         Align::kRight, Align::kLeft, Align::kRight, Align::kRight, Align::kLeft},
        rows);
  }

  out += "\nevents\n";
  out += format_events(events);
  return out;
}

namespace {

// One DUT in a run: "17-0042  KVH 1750, axes x y z (primary z), 1000 Hz, 8 channels".
std::string dut_line(const json& d) {
  std::string axes;
  for (const auto& a : field(d, "axes").is_array() ? field(d, "axes") : json::array()) {
    axes += (axes.empty() ? "" : " ") + text(a);
  }
  std::string line =
      field(d, "serial").is_string() && !field(d, "serial").get<std::string>().empty()
          ? field(d, "serial").get<std::string>()
          : std::string("(no serial)");
  if (!field(d, "model").is_null() && text(field(d, "model")) != kDash) {
    line += "  " + text(field(d, "model"));
  }
  if (!axes.empty())
    line += fmt::format(", axes {} (primary {})", axes, text(field(d, "primary_axis")));
  if (number(field(d, "rate_hz"))) line += fmt::format(", {:g} Hz", *number(field(d, "rate_hz")));
  if (field(d, "channels").is_array()) {
    const auto n = field(d, "channels").size();
    line += fmt::format(", {} channel{}", n, n == 1 ? "" : "s");
  }
  return line;
}

// The axis a result row is of: its own, else the DUT's primary axis.
std::string row_axis(const json& row, const json& dut) {
  const json& axis = field(row, "axis");
  if (axis.is_string() && !axis.get<std::string>().empty()) return axis.get<std::string>();
  const json& primary = field(dut, "primary_axis");
  return primary.is_string() && !primary.get<std::string>().empty() ? primary.get<std::string>()
                                                                    : std::string("rate");
}

// A comment for a labelled line: its later lines indented under the first;
// "—" for none.
std::string comment_text(const json& comment) {
  if (!comment.is_string() || comment.get<std::string>().empty()) return kDash;
  std::string c = comment.get<std::string>();
  for (auto pos = c.find('\n'); pos != std::string::npos; pos = c.find('\n', pos + 1)) {
    c.insert(pos + 1, std::string(12, ' '));
  }
  return c;
}

}  // namespace

std::string format_run_metadata(const json& run) {
  const json& m = field(run, "metadata");
  std::string out;
  out += labelled("operator", text(field(m, "operator")));
  out += labelled("comment", comment_text(field(m, "comment")));
  out += labelled("tags", listed(field(m, "tags")));
  const json& duts = field(run, "duts");
  if (duts.is_array() && !duts.empty()) {
    bool first = true;
    for (const auto& d : duts) {
      out += labelled(first ? "DUTs" : "", dut_line(d));
      first = false;
    }
  } else {
    // Not started yet, or recorded before DUTs: the serials asked for.
    out += labelled("DUTs", listed(field(m, "duts")));
  }
  return out;
}

std::string format_duts(const json& duts) {
  if (!duts.is_array() || duts.empty()) return "no DUTs recorded\n";
  std::vector<std::vector<std::string>> rows;
  for (const auto& d : duts) {
    const json& serial = field(d, "serial");
    rows.push_back(
        {serial.is_string() && serial.get<std::string>().empty() ? std::string("(no serial)")
                                                                 : text(serial),
         text(field(d, "model")), format_utc(field(d, "first_seen_utc")), text(field(d, "runs"))});
  }
  return table({"serial", "model", "first seen (UTC)", "runs"},
               {Align::kLeft, Align::kLeft, Align::kLeft, Align::kRight}, rows);
}

std::string format_dut_history(const json& h) {
  const json& serial = field(h, "serial");
  std::string out = fmt::format(
      "DUT {}  {}\n",
      serial.is_string() && serial.get<std::string>().empty() ? "(no serial)" : text(serial),
      text(field(h, "model")));
  out += labelled("first seen", format_utc(field(h, "first_seen_utc")) + " UTC");
  const json& runs = field(h, "runs");
  out += labelled("runs", runs.is_array() ? std::to_string(runs.size()) : kDash);
  for (const auto& r : runs.is_array() ? runs : json::array()) {
    const json& dut = field(r, "dut");
    out += fmt::format("\nrun {}  {}  {}  started {} UTC\n", text(field(r, "id")),
                       text(field(r, "schedule_name")), text(field(r, "state")),
                       format_utc(field(r, "started_utc")));
    const json& m = field(r, "metadata");
    out += labelled("operator", text(field(m, "operator")));
    if (field(m, "comment").is_string() && !field(m, "comment").get<std::string>().empty()) {
      out += labelled("comment", comment_text(field(m, "comment")));
    }
    if (field(m, "tags").is_array() && !field(m, "tags").empty()) {
      out += labelled("tags", listed(field(m, "tags")));
    }
    if (dut.is_object()) out += labelled("as", dut_line(dut));

    // Table I per segment, one bias and σ column pair per axis (in the
    // DUT's axis order, then any other axis the rows name).
    // Copies that outlive the loops below (rows are pointed at).
    const json stats = field(r, "stats").is_array() ? field(r, "stats") : json::array();
    std::vector<std::string> axes;
    for (const auto& a : field(dut, "axes").is_array() ? field(dut, "axes") : json::array()) {
      if (a.is_string()) axes.push_back(a.get<std::string>());
    }
    std::vector<std::string> used;
    for (const auto& row : stats) {
      const std::string axis = row_axis(row, dut);
      if (std::find(used.begin(), used.end(), axis) == used.end()) used.push_back(axis);
    }
    std::vector<std::string> columns;
    for (const auto& a : axes) {
      if (std::find(used.begin(), used.end(), a) != used.end()) columns.push_back(a);
    }
    for (const auto& a : used) {
      if (std::find(columns.begin(), columns.end(), a) == columns.end()) columns.push_back(a);
    }
    std::vector<std::string> header = {"#", "kind", "set °C", "T mean °C"};
    std::vector<Align> align = {Align::kRight, Align::kLeft, Align::kRight, Align::kRight};
    for (const auto& a : columns) {
      header.push_back(a + " bias °/h");
      header.push_back(a + " σ °/h");
      align.push_back(Align::kRight);
      align.push_back(Align::kRight);
    }
    header.push_back("state");
    align.push_back(Align::kLeft);
    std::vector<std::vector<std::string>> rows;
    const json& segments = field(r, "segments");
    for (const auto& s : segments.is_array() ? segments : json::array()) {
      const json& index = field(s, "index");
      const auto i = number(index);
      std::string temp = kDash;
      std::vector<std::string> row = {i ? std::to_string(static_cast<int64_t>(*i) + 1) : kDash,
                                      text(field(s, "kind")), fixed(field(s, "setpoint_c"), 2), ""};
      for (const auto& a : columns) {
        const json* hit = nullptr;
        for (const auto& st : stats) {
          if (field(st, "segment_index") == index && row_axis(st, dut) == a) hit = &st;
        }
        if (hit && temp == kDash) temp = fixed(field(*hit, "temp_mean_c"), 2);
        row.push_back(hit ? fixed(field(*hit, "bias_mean_dph"), 4) : kDash);
        row.push_back(hit ? fixed(field(*hit, "bias_std_dph"), 4) : kDash);
      }
      row[3] = temp;
      row.push_back(text(field(s, "state")));
      rows.push_back(std::move(row));
    }
    if (rows.empty()) {
      out += "  no segments\n";
    } else {
      out += table(header, align, rows, "  ");
    }

    const json& sf = field(r, "scale_factor");
    if (sf.is_array() && !sf.empty()) {
      std::vector<std::vector<std::string>> sf_rows;
      for (const auto& f : sf) {
        sf_rows.push_back(
            {text(field(f, "sf_sequence")), row_axis(f, dut), fixed(field(f, "temperature_c"), 2),
             fixed(field(f, "k"), 7), fixed(field(f, "nonlinearity_ppm"), 1),
             fixed(field(f, "asymmetry_ppm"), 1), fixed(field(f, "repeatability_ppm"), 1),
             fixed(field(f, "bias_dph"), 3), quality_mark(field(f, "quality"))});
      }
      out += "  scale factor\n";
      out += table({"seq", "axis", "T °C", "K", "nonlin ppm", "asym ppm", "repeat ppm", "bias °/h",
                    "quality"},
                   {Align::kRight, Align::kLeft, Align::kRight, Align::kRight, Align::kRight,
                    Align::kRight, Align::kRight, Align::kRight, Align::kLeft},
                   sf_rows, "  ");
      for (const auto& f : sf) {
        if (quality_mark(field(f, "quality")) != "FLAGGED") continue;
        out += fmt::format("  sequence {}: FLAGGED: {}\n", text(field(f, "sf_sequence")),
                           quality_reasons(field(f, "quality")));
      }
    }
    for (const auto& st : stats) {
      if (quality_mark(field(st, "quality")) != "FLAGGED") continue;
      const auto i = number(field(st, "segment_index"));
      out += fmt::format("  segment {} {}: Table I FLAGGED: {}\n",
                         i ? std::to_string(static_cast<int64_t>(*i) + 1) : kDash,
                         row_axis(st, dut), quality_reasons(field(st, "quality")));
    }
  }
  const json& fits = field(h, "fits");
  if (fits.is_array() && !fits.empty()) {
    std::vector<std::vector<std::string>> rows;
    for (const auto& f : fits) {
      rows.push_back({text(field(f, "id")), text(field(f, "axis")), text(field(f, "model")),
                      text(field(f, "form")), listed(field(f, "run_ids")),
                      fixed(field(f, "residual_std_dph"), 4), fixed(field(f, "r_squared"), 4),
                      format_utc(field(f, "computed_utc")), quality_mark(field(f, "quality"))});
    }
    out += "\ndrift fits\n";
    out += table(
        {"id", "axis", "model", "form", "runs", "residual °/h", "R²", "computed (UTC)", "quality"},
        {Align::kRight, Align::kLeft, Align::kLeft, Align::kLeft, Align::kLeft, Align::kRight,
         Align::kRight, Align::kLeft, Align::kLeft},
        rows);
    for (const auto& f : fits) {
      if (quality_mark(field(f, "quality")) != "FLAGGED") continue;
      out += fmt::format("fit {}: FLAGGED: {}\n", text(field(f, "id")),
                         quality_reasons(field(f, "quality")));
    }
  }
  return out;
}

Result<DatabaseChoice> choose_database(const std::string& db_path, const std::string& config_path) {
  if (!db_path.empty() && !config_path.empty()) {
    return Error::Permanent("give --db FILE or --config FILE, not both");
  }
  DatabaseChoice choice;
  if (!config_path.empty()) {
    auto cfg = config::load_station_config(config_path);
    if (!cfg) return Error::Permanent("bad station config:\n" + cfg.error().message);
    choice.path = cfg->storage.db_path;
  } else {
    choice.path = db_path;
  }
  choice.given = !choice.path.empty();
  if (choice.given) {
    std::error_code ec;
    if (!std::filesystem::is_regular_file(choice.path, ec)) {
      return Error::Permanent(fmt::format(
          "{}: no such database{}", choice.path,
          config_path.empty() ? std::string() : fmt::format(" ([storage] db of {})", config_path)));
    }
  }
  return choice;
}

std::string redact_tokens(std::string text, const std::vector<std::string>& args) {
  std::vector<std::string> secrets;
  if (const char* env = std::getenv("GYROTHERM_TOKEN"); env && *env) secrets.emplace_back(env);
  for (std::size_t i = 0; i < args.size(); ++i) {
    if (args[i].rfind("--tok", 0) != 0) continue;
    if (const auto eq = args[i].find('='); eq != std::string::npos) {
      secrets.push_back(args[i].substr(eq + 1));
    } else if (i + 1 < args.size()) {
      secrets.push_back(args[i + 1]);
    }
  }
  for (const auto& secret : secrets) {
    if (secret.empty()) continue;
    for (auto pos = text.find(secret); pos != std::string::npos; pos = text.find(secret, pos)) {
      text.replace(pos, secret.size(), "***");
    }
  }
  return text;
}

std::string format_http_error(int status, const std::string& body, bool token_sent,
                              const std::string& token) {
  std::string msg;
  if (status == 401) {
    msg = token_sent ? "the daemon refused the token (set --token or GYROTHERM_TOKEN)"
                     : "the daemon needs a token for this (set --token or GYROTHERM_TOKEN)";
  } else {
    const json j = json::parse(body, nullptr, false);
    const json& error = field(j, "error");
    if (error.is_string()) {
      msg = error.get<std::string>();
      const json& errors = field(j, "errors");
      if (errors.is_array()) {
        for (const auto& e : errors)
          msg += "\n" + (e.is_string() ? e.get<std::string>() : e.dump());
      }
    } else {
      std::string first_line = body.substr(0, body.find('\n'));
      if (first_line.size() > 200) first_line = first_line.substr(0, 200) + "…";
      msg = first_line.empty() ? fmt::format("the daemon answered HTTP {}", status)
                               : fmt::format("the daemon answered HTTP {}: {}", status, first_line);
    }
  }
  if (!token.empty()) {
    for (auto pos = msg.find(token); pos != std::string::npos; pos = msg.find(token, pos)) {
      msg.replace(pos, token.size(), "***");
    }
  }
  return msg;
}

}  // namespace gyrotherm::cli

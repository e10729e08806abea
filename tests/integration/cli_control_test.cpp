// The gyrotherm CLI's daemon-control commands: the real binary against an
// in-process HTTP server on loopback that records each request and answers
// canned JSON per docs/api.md; and the pure formatters behind their output.
#include <fcntl.h>
#include <fmt/format.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>

#include "control.h"
#include "gyrotherm/api/http_message.h"
#include "gyrotherm/api/http_server.h"
#include "gyrotherm/station/control.h"
#include "gyrotherm/storage/database.h"
#include "process.h"
#include "station_fixture.h"
#include "temp_dir_test.h"
#include "test_files.h"

extern char** environ;

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
namespace http = boost::beast::http;
using nlohmann::json;
using ::testing::ContainsRegex;
using ::testing::HasSubstr;
using ::testing::Not;

constexpr const char* kToken = "s3cret-T0ken-4a7f";

// ---------------------------------------------------------------- a fake daemon

class FakeDaemon {
 public:
  struct Seen {
    std::string method, target, body, authorization;
  };

  FakeDaemon() {
    api::HttpServerOptions options;
    options.port = 0;
    auto server = api::HttpServer::create(
        options, [this](const api::HttpRequest& req) { return handle(req); });
    if (!server) throw std::runtime_error(server.error().message);
    server_ = std::move(*server);
    server_->start();
  }

  void answer(const std::string& method, const std::string& target, int status, json body) {
    std::lock_guard lock(mu_);
    canned_[{method, target}] = {status, body.dump()};
  }
  std::vector<Seen> seen() {
    std::lock_guard lock(mu_);
    return seen_;
  }
  void forget() {
    std::lock_guard lock(mu_);
    seen_.clear();
  }
  std::string url() const { return fmt::format("http://127.0.0.1:{}", server_->port()); }

 private:
  api::HttpResponse handle(const api::HttpRequest& req) {
    std::lock_guard lock(mu_);
    Seen s{std::string(req.method_string()), std::string(req.target()), req.body(),
           std::string(req[http::field::authorization])};
    seen_.push_back(s);
    const auto it = canned_.find({s.method, s.target});
    if (it == canned_.end()) {
      return api::error_response(req, http::status::not_found, "no such resource: " + s.target);
    }
    auto res =
        api::json_response(req, static_cast<http::status>(it->second.first), it->second.second);
    if (it->second.first == 401) res.set(http::field::www_authenticate, "Bearer");
    return res;
  }

  std::mutex mu_;
  std::map<std::pair<std::string, std::string>, std::pair<int, std::string>> canned_;
  std::vector<Seen> seen_;
  std::unique_ptr<api::HttpServer> server_;
};

// Canned answers, shaped as docs/api.md says.
json entry(int64_t id, int position, const std::string& name, int steps, bool ignore_failures) {
  return {{"id", id},
          {"position", position},
          {"schedule_name", name},
          {"source", "config/schedules/" + name + ".toml"},
          {"steps", steps},
          {"ignore_failures", ignore_failures},
          {"added_utc", "2026-11-21T05:38:43.120Z"},
          {"state", "queued"}};
}

json queue_answer() {
  json current = entry(7, 0, "paper-table1", 32, false);
  current["state"] = "running";
  current["run_id"] = 12;
  return {{"held", false},
          {"hold_reason", ""},
          {"current", current},
          {"entries", {entry(8, 0, "demo", 3, true), entry(9, 1, "paper-ramp", 1, false)}}};
}

json status_answer() {
  return {{"state", "acquiring"},
          {"run_id", 12},
          {"schedule_name", "paper-table1"},
          {"step_index", 2},
          {"step_count", 32},
          {"step_label", "soak 20 °C"},
          {"setpoint_c", 20.0},
          {"chamber_c", 20.04},
          {"top_c", 20.01},
          {"side_c", 19.98},
          {"gradient_c", 0.03},
          {"temp_rate_c_per_min", 0.004},
          {"gyro_rate_dph", 8.0771},
          {"gyro_samples_per_s", 100.0},
          {"paused", true},
          {"interlocks",
           {{{"kind", "probe_disagreement"},
             {"message", "top and side differ by 2.4 °C"},
             {"since_s", 3725.0}}}},
          {"queue_length", 2},
          {"queue_held", true},
          {"queue_hold_reason", "stop requested"},
          {"uptime_s", 600.0},
          {"time_scale", 1000.0},
          {"t_station_s", 3800.5},
          {"t_run_s", 3700.0},
          {"last_event", "paused: operator"},
          {"progress",
           {{"phase", "acquiring"},
            {"step_elapsed_s", 2550.0},
            {"step_planned_s", 6000.0},
            {"step_fraction", 0.425},
            {"gate_held_s", nullptr},
            {"gate_needed_s", nullptr},
            {"run_remaining_fixed_s", 7800.0},
            {"run_settles_remaining", 2},
            {"run_eta_s", nullptr},
            {"queue_fixed_s", 43200.0},
            {"queue_settles", 8}}},
          {"run_metadata", {{"operator", "ana"}, {"comment", ""}, {"tags", {"cold", "lot-7"}}}},
          {"duts",
           {{{"serial", "17-0042"},
             {"model", "KVH 1750"},
             {"primary_axis", "z"},
             {"rates_dph", {{"x", 8.0123}, {"y", -0.0021}, {"z", nullptr}}},
             {"temp_c", 41.23},
             {"samples_per_s", 1000.0},
             {"health", {{"connected", true}, {"last_error", ""}}}}}}};
}

json run_answer() {
  return {{"id", 12},
          {"schedule_name", "demo"},
          {"state", "completed"},
          {"started_utc", "2026-11-21T05:38:43.120Z"},
          {"ended_utc", "2026-11-21T07:01:02.000Z"},
          {"queue_id", 7},
          {"time_scale", 1000},
          {"segments",
           {{{"index", 0},
             {"kind", "soak"},
             {"label", "soak 20 °C"},
             {"setpoint_c", 20.0},
             {"ramp_rate_c_per_min", nullptr},
             {"t_start_s", 0.0},
             {"t_settled_s", 1800.0},
             {"t_acquire_start_s", 1800.0},
             {"t_acquire_end_s", 3000.0},
             {"t_end_s", 3000.0},
             {"paused_s", 0.0},
             {"state", "completed"},
             {"windows", {{1800.0, 3000.0}}}}}}};
}

json events_answer() {
  return {{{"id", 1},
           {"t_s", 0.0},
           {"wall_utc", "2026-11-21T05:38:43.120Z"},
           {"kind", "state"},
           {"from_state", "queued"},
           {"to_state", "settling"},
           {"message", "soak 20 °C"}},
          {{"id", 2},
           {"t_s", 1800.4},
           {"wall_utc", "2026-11-21T05:38:45.000Z"},
           {"kind", "state"},
           {"from_state", "settling"},
           {"to_state", "acquiring"},
           {"message", "stability gate held"}},
          {{"id", 3},
           {"t_s", 3000.0},
           {"wall_utc", "2026-11-21T05:38:46.000Z"},
           {"kind", "state"},
           {"from_state", "acquiring"},
           {"to_state", "completed"},
           {"message", "all steps done"}}};
}

// ---------------------------------------------------------------- the binary

struct CliRun {
  int code = -1;
  std::string out, err;
};

// Runs gyrotherm with `args` in an environment without GYROTHERM_* except
// `env`; waits up to 20 s. Every run is checked for the token leaking.
CliRun run_gyrotherm(const fs::path& dir, std::vector<std::string> args,
                     std::vector<std::string> env = {}) {
  const std::string out_path = (dir / "out.txt").string();
  const std::string err_path = (dir / "err.txt").string();
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, out_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                   0644);
  posix_spawn_file_actions_addopen(&actions, 2, err_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                   0644);
  args.insert(args.begin(), std::string(GYROTHERM_BIN_DIR) + "/gyrotherm");
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  for (char** e = environ; *e; ++e) {
    if (std::string_view(*e).rfind("GYROTHERM_", 0) != 0) env.emplace_back(*e);
  }
  std::vector<char*> envp;
  for (auto& e : env) envp.push_back(e.data());
  envp.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  CliRun r;
  if (rc != 0) {
    ADD_FAILURE() << "posix_spawn " << argv[0] << ": " << rc;
    return r;
  }
  int status = 0;
  const bool exited = testing::wait_until([&] { return ::waitpid(pid, &status, WNOHANG) == pid; },
                                          std::chrono::seconds(20));
  if (!exited) {
    ::kill(pid, SIGKILL);
    ::waitpid(pid, &status, 0);
    ADD_FAILURE() << "gyrotherm did not finish within 20 s";
  }
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  r.out = testing::read_text(out_path);
  r.err = testing::read_text(err_path);
  EXPECT_THAT(r.out, Not(HasSubstr(kToken)));
  EXPECT_THAT(r.err, Not(HasSubstr(kToken)));
  return r;
}

class CliControlTest : public testing::TempDirTest {
 protected:
  CliControlTest() : TempDirTest("gyrotherm-cli-control") {}

  using Run = CliRun;
  Run cli(std::vector<std::string> args, std::vector<std::string> env = {}) {
    return run_gyrotherm(dir_, std::move(args), std::move(env));
  }

  // --url and --token of the fake daemon, after `args`.
  std::vector<std::string> to(const FakeDaemon& d, std::vector<std::string> args) {
    args.insert(args.end(), {"--url", d.url(), "--token", kToken});
    return args;
  }
};

// A URL nothing listens on.
std::string dead_url() { return fmt::format("http://127.0.0.1:{}", testing::free_tcp_port()); }

TEST_F(CliControlTest, EachCommandSendsItsRequest) {
  FakeDaemon d;
  d.answer("POST", "/api/v1/queue", 201, entry(8, 1, "demo", 3, true));
  d.answer("GET", "/api/v1/queue", 200, queue_answer());
  d.answer("DELETE", "/api/v1/queue/9", 200, {{"removed", 9}});
  d.answer("POST", "/api/v1/queue/9/move", 200, queue_answer());
  for (const char* action : {"pause", "resume", "abort", "stop"}) {
    d.answer("POST", fmt::format("/api/v1/control/{}", action), 200,
             {{"ok", true}, {"message", fmt::format("{} done", action)}});
  }
  d.answer("GET", "/api/v1/status", 200, status_answer());
  d.answer("GET", "/api/v1/runs", 200, json::array({run_answer()}));
  d.answer("GET", "/api/v1/runs/12", 200, run_answer());
  d.answer("GET", "/api/v1/runs/12/events", 200, events_answer());

  const std::string schedule_text = "name = \"demo\"\n[[step]]\ntype = \"hold\"\n";
  const std::string schedule = (dir_ / "demo.toml").string();
  std::ofstream(schedule) << schedule_text;

  struct Case {
    std::vector<std::string> args;
    std::string method, target;
    json body;         // null: no body
    std::string says;  // in the human output
  };
  const std::vector<Case> cases = {
      {{"queue", "add", schedule, "--ignore-failures"},
       "POST",
       "/api/v1/queue",
       {{"schedule_toml", schedule_text}, {"source", schedule}, {"ignore_failures", true}},
       "queued entry 8: demo (3 steps) at position 1, failures ignored"},
      {{"queue", "add", schedule},
       "POST",
       "/api/v1/queue",
       {{"schedule_toml", schedule_text}, {"source", schedule}, {"ignore_failures", false}},
       "queued entry 8"},
      {{"queue", "list"}, "GET", "/api/v1/queue", nullptr, "paper-ramp"},
      {{"queue", "remove", "9"}, "DELETE", "/api/v1/queue/9", nullptr, "removed queue entry 9"},
      {{"queue", "move", "9", "0"},
       "POST",
       "/api/v1/queue/9/move",
       {{"position", 0}},
       "paper-ramp"},
      {{"pause", "--reason", "door opened"},
       "POST",
       "/api/v1/control/pause",
       {{"reason", "door opened"}},
       "pause done"},
      {{"resume"}, "POST", "/api/v1/control/resume", nullptr, "resume done"},
      {{"abort", "--reason", "gyro cable"},
       "POST",
       "/api/v1/control/abort",
       {{"reason", "gyro cable"}},
       "abort done"},
      {{"stop"}, "POST", "/api/v1/control/stop", nullptr, "stop done"},
      {{"status"}, "GET", "/api/v1/status", nullptr, "acquiring (paused)"},
      {{"runs"}, "GET", "/api/v1/runs", nullptr, "completed"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(fmt::format("{}", fmt::join(c.args, " ")));
    d.forget();
    const Run r = cli(to(d, c.args));
    EXPECT_EQ(r.code, 0) << r.err;
    EXPECT_THAT(r.out, HasSubstr(c.says));
    const auto seen = d.seen();
    // queue add then asks whether the queue is held (to say so).
    const bool add = c.args[0] == "queue" && c.args[1] == "add";
    ASSERT_EQ(seen.size(), add ? 2u : 1u);
    if (add) {
      EXPECT_EQ(seen[1].target, "/api/v1/queue");
    }
    EXPECT_EQ(seen[0].method, c.method);
    EXPECT_EQ(seen[0].target, c.target);
    if (c.body.is_null()) {
      EXPECT_EQ(seen[0].body, "");
    } else {
      EXPECT_EQ(json::parse(seen[0].body), c.body);
    }
    // The token goes with every request: reads need it when the daemon's
    // [api] read_access is "token".
    EXPECT_EQ(seen[0].authorization, fmt::format("Bearer {}", kToken));
  }

  d.forget();
  const Run run = cli(to(d, {"run", "12"}));
  EXPECT_EQ(run.code, 0) << run.err;
  const auto seen = d.seen();
  ASSERT_EQ(seen.size(), 2u);
  EXPECT_EQ(seen[0].target, "/api/v1/runs/12");
  EXPECT_EQ(seen[1].target, "/api/v1/runs/12/events");
  EXPECT_EQ(seen[0].authorization, fmt::format("Bearer {}", kToken));
  EXPECT_THAT(run.out, HasSubstr("0:30:00  state  settling → acquiring   stability gate held"));
}

TEST_F(CliControlTest, JsonPrintsTheDaemonsAnswerAsIs) {
  FakeDaemon d;
  d.answer("GET", "/api/v1/queue", 200, queue_answer());
  d.answer("GET", "/api/v1/runs/12", 200, run_answer());
  d.answer("GET", "/api/v1/runs/12/events", 200, events_answer());
  const Run list = cli(to(d, {"queue", "list", "--json"}));
  ASSERT_EQ(list.code, 0) << list.err;
  EXPECT_EQ(list.out, queue_answer().dump() + "\n");
  auto top_level = to(d, {"queue", "list"});
  top_level.insert(top_level.begin(), "--json");
  EXPECT_EQ(cli(top_level).out, list.out) << "the top-level --json too";
  EXPECT_THAT(cli(to(d, {"queue", "list"})).out, HasSubstr("paper-ramp")) << "without: a table";

  // `run ID`: the run with its events added.
  const Run run = cli(to(d, {"run", "12", "--json"}));
  ASSERT_EQ(run.code, 0) << run.err;
  json want = run_answer();
  want["events"] = events_answer();
  EXPECT_EQ(json::parse(run.out), want);
}

TEST_F(CliControlTest, EnvironmentGivesUrlAndTokenAndFlagsOverrideIt) {
  FakeDaemon d;
  d.answer("POST", "/api/v1/control/pause", 200, {{"ok", true}, {"message", "paused"}});
  const std::string env_url = "GYROTHERM_URL=" + d.url();
  const std::string env_token = std::string("GYROTHERM_TOKEN=") + kToken;

  const Run from_env = cli({"pause"}, {env_url, env_token});
  EXPECT_EQ(from_env.code, 0) << from_env.err;
  ASSERT_EQ(d.seen().size(), 1u);
  EXPECT_EQ(d.seen()[0].authorization, fmt::format("Bearer {}", kToken));

  d.forget();
  const Run token_flag = cli({"pause", "--token", "other-token"}, {env_url, env_token});
  EXPECT_EQ(token_flag.code, 0) << token_flag.err;
  ASSERT_EQ(d.seen().size(), 1u);
  EXPECT_EQ(d.seen()[0].authorization, "Bearer other-token");

  d.forget();
  const Run url_flag = cli({"pause", "--url", d.url()}, {"GYROTHERM_URL=" + dead_url(), env_token});
  EXPECT_EQ(url_flag.code, 0) << url_flag.err;
  EXPECT_EQ(d.seen().size(), 1u);

  d.forget();
  const std::string dead = dead_url();
  const Run url_flag_dead = cli({"pause", "--url", dead}, {env_url, env_token});
  EXPECT_EQ(url_flag_dead.code, 1);
  EXPECT_THAT(url_flag_dead.err, HasSubstr(dead));
  EXPECT_TRUE(d.seen().empty());
}

TEST_F(CliControlTest, DaemonErrorsAreReportedWithExitCodeOne) {
  FakeDaemon d;
  d.answer("POST", "/api/v1/control/resume", 401, {{"error", "missing or wrong token"}});
  d.answer("DELETE", "/api/v1/queue/99", 404, {{"error", "no queue entry 99"}});
  d.answer("POST", "/api/v1/queue/7/move", 409, {{"error", "queue entry 7 is running; use abort"}});
  d.answer("POST", "/api/v1/control/pause", 409, {{"error", "nothing to pause: no run"}});
  d.answer("GET", "/api/v1/runs/5", 404, {{"error", "no run 5"}});
  const json refused = {{"error", "schedule refused, nothing queued"},
                        {"errors",
                         {"bad.toml:3: step[0].setpoint_c: 75 °C is outside [-20, 60] °C",
                          "bad.toml:8: step[1].rate_c_per_min: 9 °C/min exceeds 5 °C/min"}}};
  d.answer("POST", "/api/v1/queue", 422, refused);

  const Run unauthorized = cli(to(d, {"resume"}));
  EXPECT_EQ(unauthorized.code, 1);
  EXPECT_THAT(unauthorized.err,
              HasSubstr("the daemon refused the token (set --token or GYROTHERM_TOKEN)"));
  const Run no_token = cli({"resume", "--url", d.url()});
  EXPECT_EQ(no_token.code, 1);
  EXPECT_THAT(no_token.err, HasSubstr("(set --token or GYROTHERM_TOKEN)"));

  const Run unknown = cli(to(d, {"queue", "remove", "99"}));
  EXPECT_EQ(unknown.code, 1);
  EXPECT_THAT(unknown.err, HasSubstr("no queue entry 99"));
  const Run no_run = cli(to(d, {"run", "5"}));
  EXPECT_EQ(no_run.code, 1);
  EXPECT_THAT(no_run.err, HasSubstr("no run 5"));
  EXPECT_EQ(d.seen().back().target, "/api/v1/runs/5") << "no events asked for a missing run";

  const Run running = cli(to(d, {"queue", "move", "7", "2"}));
  EXPECT_EQ(running.code, 1);
  EXPECT_THAT(running.err, HasSubstr("queue entry 7 is running; use abort"));
  const Run nothing = cli(to(d, {"pause"}));
  EXPECT_EQ(nothing.code, 1);
  EXPECT_THAT(nothing.err, HasSubstr("nothing to pause: no run"));

  const std::string bad = (dir_ / "bad.toml").string();
  std::ofstream(bad) << "[[step]]\ntype = \"soak\"\nsetpoint_c = 75\n";
  const Run rejected = cli(to(d, {"queue", "add", bad}));
  EXPECT_EQ(rejected.code, 1);
  EXPECT_THAT(rejected.err, HasSubstr("schedule refused, nothing queued\n"));
  EXPECT_THAT(rejected.err,
              HasSubstr("\nbad.toml:3: step[0].setpoint_c: 75 °C is outside [-20, 60] °C\n"));
  EXPECT_THAT(rejected.err,
              HasSubstr("\nbad.toml:8: step[1].rate_c_per_min: 9 °C/min exceeds 5 °C/min\n"));
  EXPECT_EQ(rejected.out, "");
  const Run rejected_json = cli(to(d, {"queue", "add", bad, "--json"}));
  EXPECT_EQ(rejected_json.code, 1);
  EXPECT_EQ(json::parse(rejected_json.out), refused) << "scripts get the errors too";
}

TEST_F(CliControlTest, UnreachableDaemonNamesTheUrl) {
  const std::string url = dead_url();
  for (const auto& args : std::vector<std::vector<std::string>>{
           {"status"}, {"queue", "list"}, {"stop", "--token", kToken}, {"run", "3"}}) {
    auto with_url = args;
    with_url.insert(with_url.end(), {"--url", url});
    const Run r = cli(with_url);
    EXPECT_EQ(r.code, 1) << args[0];
    EXPECT_THAT(r.err, HasSubstr("cannot reach the daemon at " + url));
    EXPECT_THAT(r.err, HasSubstr("is gyrothermd running?"));
  }
}

TEST_F(CliControlTest, UsageErrorsExitTwo) {
  FakeDaemon d;
  EXPECT_EQ(cli(to(d, {"queue", "move", "7"})).code, 2);
  EXPECT_EQ(cli(to(d, {"queue", "remove", "seven"})).code, 2);
  EXPECT_EQ(cli(to(d, {"queue", "move", "7", "-1"})).code, 2);
  EXPECT_EQ(cli(to(d, {"queue"})).code, 2);
  EXPECT_EQ(cli(to(d, {"run"})).code, 2);
  const Run missing = cli(to(d, {"queue", "add", (dir_ / "nope.toml").string()}));
  EXPECT_EQ(missing.code, 2);
  EXPECT_THAT(missing.err, HasSubstr("nope.toml: cannot open"));
  const Run bad_url = cli({"status", "--url", "ftp://127.0.0.1:8750"});
  EXPECT_EQ(bad_url.code, 2);
  EXPECT_THAT(bad_url.err, HasSubstr("not an http:// URL"));
  // CLI11 echoes stray arguments; a token among them is blanked (cli() checks).
  const Run typo = cli({"pause", "--tokn", kToken, "--url", d.url()});
  EXPECT_EQ(typo.code, 2);
  EXPECT_THAT(typo.err, HasSubstr("***"));
  EXPECT_EQ(cli({"pause", "--token", kToken, "--token", kToken}).code, 2);
  EXPECT_EQ(cli({"pause", kToken}, {std::string("GYROTHERM_TOKEN=") + kToken}).code, 2);
  EXPECT_TRUE(d.seen().empty()) << "nothing sent on a usage error";
  EXPECT_EQ(cli({"queue", "add", "--help"}).code, 0);
}

// A schedule queued while the queue is held waits: the CLI says why and that
// resume releases the queue (it only said "queued entry N").
TEST_F(CliControlTest, QueueAddOntoAHeldQueueSaysResumeReleasesIt) {
  FakeDaemon d;
  d.answer("POST", "/api/v1/queue", 201, entry(8, 0, "demo", 1, false));
  json held = queue_answer();
  held["held"] = true;
  held["hold_reason"] = "stopped by the operator (weekend)";
  held["current"] = nullptr;
  d.answer("GET", "/api/v1/queue", 200, held);
  const std::string schedule = (dir_ / "demo.toml").string();
  std::ofstream(schedule) << "name = \"demo\"\n";
  const Run r = cli(to(d, {"queue", "add", schedule}));
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_EQ(r.out,
            "queued entry 8: demo (1 step) at position 0\n"
            "the queue is held (stopped by the operator (weekend)): the entry waits until "
            "gyrotherm resume releases the queue\n");
  // Not held: nothing more is said.
  d.answer("GET", "/api/v1/queue", 200, queue_answer());
  const Run free = cli(to(d, {"queue", "add", schedule}));
  EXPECT_EQ(free.out, "queued entry 8: demo (1 step) at position 0\n");
}

// A bad number is refused in words: `queue move 3 -1` printed CLI11's range
// bound, a 300-digit number.
TEST_F(CliControlTest, BadNumbersAreRefusedInWords) {
  FakeDaemon d;
  struct Case {
    std::vector<std::string> args;
    std::string says;
  };
  for (const auto& c : std::vector<Case>{
           {{"queue", "move", "3", "-1"}, "position: -1 is not a position (0 = next, 1, 2, …)"},
           {{"queue", "move", "0", "1"}, "id: 0 is not a queue entry id (1, 2, …)"},
           {{"queue", "remove", "-4"}, "id: -4 is not a queue entry id (1, 2, …)"},
           {{"run", "0"}, "id: 0 is not a run id (1, 2, …)"},
           {{"queue", "move", "3", "1e400"}, "position: 1e400 is not a position"}}) {
    SCOPED_TRACE(fmt::format("{}", fmt::join(c.args, " ")));
    const Run r = cli(to(d, c.args));
    EXPECT_EQ(r.code, 2);
    EXPECT_THAT(r.err, HasSubstr(c.says));
    EXPECT_LT(r.err.size(), 400u) << r.err;
    int digits = 0, longest = 0;
    for (char ch : r.err) longest = std::max(longest, digits = std::isdigit(ch) ? digits + 1 : 0);
    EXPECT_LT(longest, 20) << r.err;
  }
  EXPECT_TRUE(d.seen().empty());
}

// `runs` and `run ID` read a database file when given one (--db FILE, or
// --config FILE naming it in [storage] db): no daemon needed. They used to
// work only while a daemon ran.
TEST_F(CliControlTest, RunsAndRunReadTheDatabaseFileOffline) {
  const std::string db_path = (dir_ / "station.db").string();
  {
    auto db = storage::Database::open(db_path);
    ASSERT_TRUE(db.ok()) << db.error().message;
    for (const char* name : {"monday", "tuesday"}) {
      storage::RunRecord run;
      run.schedule_name = name;
      run.state = "completed";
      run.started_utc = "2026-11-21T05:38:43.120Z";
      auto id = db->create_run(run);
      ASSERT_TRUE(id.ok()) << id.error().message;
      storage::SegmentRecord seg;
      seg.run_id = *id;
      seg.index = 0;
      seg.kind = "soak";
      seg.label = "soak 20 °C";
      seg.setpoint_c = 20;
      ASSERT_TRUE(db->create_segment(seg).ok());
      storage::EventRecord ev;
      ev.run_id = *id;
      ev.t_s = 1800.4;
      ev.kind = "state";
      ev.from_state = "settling";
      ev.to_state = "acquiring";
      ev.message = std::string("stability gate held in ") + name;
      ASSERT_TRUE(db->add_event(ev).ok());
    }
  }
  std::string cfg;
  {
    cfg = testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/config/station.toml");
    const std::string from = "\"/var/lib/gyrotherm/station.db\"";
    const auto pos = cfg.find(from);
    ASSERT_NE(pos, std::string::npos);
    cfg.replace(pos, from.size(), "\"" + db_path + "\"");
  }
  const std::string cfg_path = (dir_ / "station.toml").string();
  std::ofstream(cfg_path) << cfg;
  const std::string url = dead_url();  // nothing listens: the file is read

  for (const auto& source :
       std::vector<std::vector<std::string>>{{"--db", db_path}, {"--config", cfg_path}}) {
    SCOPED_TRACE(source[0]);
    auto args = std::vector<std::string>{"runs", "--url", url};
    args.insert(args.end(), source.begin(), source.end());
    const Run runs = cli(args);
    ASSERT_EQ(runs.code, 0) << runs.err;
    EXPECT_THAT(runs.out, ContainsRegex("\n +2 +tuesday +completed"));
    EXPECT_LT(runs.out.find("tuesday"), runs.out.find("monday")) << "newest first\n" << runs.out;

    args = {"run", "1", "--url", url};
    args.insert(args.end(), source.begin(), source.end());
    const Run run = cli(args);
    ASSERT_EQ(run.code, 0) << run.err;
    EXPECT_THAT(run.out, HasSubstr("run 1  monday  completed"));
    EXPECT_THAT(run.out, HasSubstr("soak 20 °C"));
    EXPECT_THAT(run.out, HasSubstr("settling → acquiring  stability gate held in monday"));

    args = {"run", "1", "--json", "--url", url};
    args.insert(args.end(), source.begin(), source.end());
    const Run j = cli(args);
    ASSERT_EQ(j.code, 0) << j.err;
    const json answer = json::parse(j.out);
    EXPECT_EQ(answer["schedule_name"], "monday");
    EXPECT_EQ(answer["segments"].size(), 1u);
    EXPECT_EQ(answer["events"][0]["message"], "stability gate held in monday");

    args = {"run", "9", "--url", url};
    args.insert(args.end(), source.begin(), source.end());
    const Run missing = cli(args);
    EXPECT_EQ(missing.code, 1);
    EXPECT_THAT(missing.err, HasSubstr("no run 9"));
  }
  const Run both = cli({"runs", "--db", db_path, "--config", cfg_path});
  EXPECT_EQ(both.code, 2);
  const Run nofile = cli({"runs", "--db", (dir_ / "none.db").string()});
  EXPECT_EQ(nofile.code, 2);
  EXPECT_THAT(nofile.err, HasSubstr("none.db"));
}

// ---------------------------------------------------------------- formatters

TEST(CliFormat, StationTimeAsHoursMinutesSeconds) {
  EXPECT_EQ(cli::format_station_time(0.0), "0:00:00");
  EXPECT_EQ(cli::format_station_time(59.99), "0:00:59");
  EXPECT_EQ(cli::format_station_time(3725.9), "1:02:05");
  EXPECT_EQ(cli::format_station_time(360000), "100:00:00");
  EXPECT_EQ(cli::format_station_time(-5.0), "-0:00:05");
  EXPECT_EQ(cli::format_station_time(nullptr), "—");
  EXPECT_EQ(cli::format_station_time("12"), "—");
  EXPECT_EQ(cli::format_utc("2026-11-21T05:38:43.120Z"), "2026-11-21 05:38:43");
  EXPECT_EQ(cli::format_utc(nullptr), "—");
}

TEST(CliFormat, QueueTable) {
  json q = queue_answer();
  EXPECT_EQ(cli::format_queue(q),
            "   pos  id  schedule      steps  ignore failures  added (UTC)\n"
            "run 12   7  paper-table1     32  no               2026-11-21 05:38:43\n"
            "     0   8  demo              3  yes              2026-11-21 05:38:43\n"
            "     1   9  paper-ramp        1  no               2026-11-21 05:38:43\n");
  q["held"] = true;
  q["hold_reason"] = "run 11 failed";
  q["current"] = nullptr;
  q["entries"] = json::array();
  EXPECT_EQ(cli::format_queue(q),
            "queue held: run 11 failed (gyrotherm resume releases it)\nqueue empty\n");
}

TEST(CliFormat, RunsTable) {
  json running = run_answer();
  running["id"] = 13;
  running["state"] = "acquiring";
  running["ended_utc"] = nullptr;
  EXPECT_EQ(cli::format_runs(json::array({running, run_answer()})),
            "id  schedule  state      started (UTC)        ended (UTC)\n"
            "13  demo      acquiring  2026-11-21 05:38:43  —\n"
            "12  demo      completed  2026-11-21 05:38:43  2026-11-21 07:01:02\n");
  EXPECT_EQ(cli::format_runs(json::array()), "no runs\n");
}

TEST(CliFormat, RunShowsSegmentsAndEventsInOrder) {
  const std::string text = cli::format_run(run_answer(), events_answer());
  EXPECT_THAT(text, HasSubstr("run 12  demo  completed\n"));
  EXPECT_THAT(text, HasSubstr("ended       2026-11-21 07:01:02 UTC\n"));
  EXPECT_THAT(text, HasSubstr("1  soak  soak 20 °C   20.00       —  0:00:00  0:30:00  "
                              "0:30:00–0:50:00  0:50:00  0:00:00  completed\n"));
  const auto first = text.find("0:00:00  state  queued → settling      soak 20 °C\n");
  const auto second = text.find("0:30:00  state  settling → acquiring   stability gate held\n");
  const auto third = text.find("0:50:00  state  acquiring → completed  all steps done\n");
  ASSERT_NE(first, std::string::npos) << text;
  ASSERT_NE(second, std::string::npos) << text;
  ASSERT_NE(third, std::string::npos) << text;
  EXPECT_LT(first, second);
  EXPECT_LT(second, third);
  EXPECT_THAT(cli::format_run({{"id", 1}}, json::array()), HasSubstr("events\n  none\n"));
}

TEST(CliFormat, StatusSummary) {
  const std::string text = cli::format_status(status_answer());
  EXPECT_THAT(text, HasSubstr("state       acquiring (paused)\n"));
  EXPECT_THAT(text, HasSubstr("run         12  paper-table1\n"));
  EXPECT_THAT(text, HasSubstr("step        3/32  soak 20 °C\n"));
  EXPECT_THAT(text, HasSubstr("gyro        8.077 °/h  (100 samples/s)\n"));
  EXPECT_THAT(text,
              HasSubstr("interlocks  probe_disagreement: top and side differ by 2.4 °C (since "
                        "1:02:05)\n"));
  EXPECT_THAT(text, HasSubstr("queue       2 waiting, ≥ 12 h + 8 settles, held: stop requested\n"));
  EXPECT_THAT(text, HasSubstr("progress    acquiring 42% · run ≥ 2 h 10 min + 2 settles\n"));
  EXPECT_THAT(text, HasSubstr("operator    ana  (tags: cold, lot-7)\n"));
  EXPECT_THAT(text, HasSubstr("duts        17-0042  KVH 1750  x 8.012  y -0.002  z — °/h (primary "
                              "z)  41.2 °C  1000 samples/s  connected\n"));
  // Settling: the gate's progress and no ETA; the last settle done: an ETA.
  json settling = status_answer();
  settling["progress"]["phase"] = "settling";
  settling["progress"]["step_fraction"] = nullptr;
  settling["progress"]["gate_held_s"] = 240.0;
  settling["progress"]["gate_needed_s"] = 600.0;
  EXPECT_THAT(cli::format_status(settling),
              HasSubstr("progress    settling, gate 4 min of 10 min · run ≥ 2 h 10 min + 2 "
                        "settles\n"));
  // A forecast of the settle: the gate's time with its band; the last
  // settle forecast: the run's end with its band, or an open one.
  settling["progress"]["settle"] = {{"verdict", "predicted"}, {"note", "fit"},   {"p10_s", 1200.0},
                                    {"p50_s", 1800.0},        {"p90_s", 3000.0}, {"age_s", 20.0}};
  EXPECT_THAT(cli::format_status(settling),
              HasSubstr("progress    settling, gate 4 min of 10 min, gate in 30 min (P10 20 min "
                        "– P90 50 min) · run ≥ 2 h 10 min + 2 settles\n"));
  settling["progress"]["run_settles_remaining"] = 1;
  settling["progress"]["run_eta_s"] = 9600.0;
  settling["progress"]["run_eta_p10_s"] = 9000.0;
  settling["progress"]["run_eta_p90_s"] = nullptr;
  EXPECT_THAT(cli::format_status(settling),
              HasSubstr("· run ends in 2 h 40 min (P10 2 h 30 min – P90 beyond 48 h)\n"));
  json unsure = settling;
  unsure["progress"]["settle"]["p50_s"] = nullptr;
  unsure["progress"]["settle"]["p90_s"] = nullptr;
  EXPECT_THAT(cli::format_status(unsure),
              HasSubstr(", gate forecast too uncertain yet (P10 20 min, median beyond 48 h) ·"));
  // The chamber's prior completes it: the band says from how many settles;
  // the queue's time too.
  json prior = settling;
  prior["progress"]["run_eta_p90_s"] = 11000.0;
  prior["progress"]["prior_settles"] = 12;
  prior["progress"]["queue_eta_s"] = 50400.0;
  prior["progress"]["queue_eta_p10_s"] = 46800.0;
  prior["progress"]["queue_eta_p90_s"] = 57600.0;
  const std::string with_prior = cli::format_status(prior);
  EXPECT_THAT(with_prior, HasSubstr("· run ends in 2 h 40 min (P10 2 h 30 min – P90 3 h 3 min; "
                                    "settles from the chamber's last 12)\n"));
  EXPECT_THAT(with_prior, HasSubstr("queue       2 waiting, ≥ 12 h + 8 settles, ~14 h with the "
                                    "chamber's past settles (P10 13 h – P90 16 h)"));
  settling["progress"]["settle"] = {{"verdict", "not_enough_curvature"},
                                    {"note", "3 bins"},
                                    {"p10_s", nullptr},
                                    {"p50_s", nullptr},
                                    {"p90_s", nullptr},
                                    {"age_s", 5.0}};
  EXPECT_THAT(cli::format_status(settling),
              HasSubstr(", gate forecast: not enough curvature yet ·"));
  json last = status_answer();
  last["progress"]["run_settles_remaining"] = 0;
  last["progress"]["run_eta_s"] = 3000.0;
  EXPECT_THAT(cli::format_status(last),
              HasSubstr("progress    acquiring 42% · run ends in 50 min\n"));
  // An adaptive soak judged: the widest axis's U95 against the target and
  // when it is projected to get there; out of reach; every axis there.
  json adaptive = last;
  const auto axis = [](const char* name, const char* verdict, json u95) {
    return json{{"name", name},       {"verdict", verdict}, {"u95_dph", std::move(u95)},
                {"reach_s", nullptr}, {"floor_dph", 0.0},   {"note", "n"}};
  };
  adaptive["progress"]["acquire"] = {{"target_u95_dph", 0.03},
                                     {"min_s", 120.0},
                                     {"max_s", 3600.0},
                                     {"acquired_s", 240.0},
                                     {"planned_s", 600.0},
                                     {"axes", json::array({axis("17-0042 x", "reached", 0.02),
                                                           axis("17-0042 z", "continue", 0.041)})},
                                     {"age_s", 30.0}};
  EXPECT_THAT(cli::format_status(adaptive),
              HasSubstr("progress    acquiring 42%, U95 0.041 → 0.03 °/h (widest: 17-0042 z), "
                        "target in ~6 min · run ends in 50 min\n"));
  adaptive["progress"]["acquire"]["axes"][1]["verdict"] = "out_of_reach";
  EXPECT_THAT(cli::format_status(adaptive), HasSubstr(", out of reach on 17-0042 z ·"));
  adaptive["progress"]["acquire"]["axes"][1]["verdict"] = "reached";
  EXPECT_THAT(cli::format_status(adaptive),
              HasSubstr("acquiring 42%, target U95 0.03 °/h reached on every axis ·"));
  EXPECT_THAT(text, HasSubstr("time        station 1:03:20, run 1:01:40, time scale 1000×\n"));

  json without_since = status_answer();
  without_since["interlocks"][0].erase("since_s");
  EXPECT_THAT(cli::format_status(without_since),
              HasSubstr("interlocks  probe_disagreement: top and side differ by 2.4 °C\n"));

  // Idle, nothing known yet: no run lines, dashes, no exception.
  const std::string idle = cli::format_status({{"state", "idle"}, {"run_id", nullptr}});
  EXPECT_THAT(idle, HasSubstr("state       idle\n"));
  EXPECT_THAT(idle, Not(HasSubstr("\nrun ")));
  EXPECT_THAT(idle, HasSubstr("chamber     —\n"));
  EXPECT_THAT(idle, HasSubstr("interlocks  none\n"));
  EXPECT_NO_THROW(cli::format_status(json::array()));
  EXPECT_THAT(idle, Not(HasSubstr("\nlab "))) << "no [lab]: no line";

  // [lab]: the relay's state, what waits and why.
  json with_lab = {{"state", "idle"}};
  with_lab["lab"] = {{"station_id", "ST01"},        {"state", "backoff"},
                     {"retry_in_s", 4.0},           {"pending", 12},
                     {"oldest_pending_age_s", 330}, {"sent_total", 1234},
                     {"last_lag_s", nullptr},       {"last_error", "connection refused"}};
  EXPECT_THAT(cli::format_status(with_lab),
              HasSubstr("lab         ST01: backoff (retry in 4.0 s), 12 pending (oldest "));
  EXPECT_THAT(cli::format_status(with_lab), HasSubstr("1234 sent: connection refused\n"));
}

TEST(CliFormat, RedactTokens) {
  EXPECT_EQ(cli::redact_tokens("not expected: abc123 x", {"pause", "--token", "abc123", "x"}),
            "not expected: *** x");
  EXPECT_EQ(cli::redact_tokens("not expected: --tokn abc123", {"--tokn", "abc123"}),
            "not expected: --tokn ***");
  EXPECT_EQ(cli::redact_tokens("not expected: abc123", {"--token=abc123"}), "not expected: ***");
  EXPECT_EQ(cli::redact_tokens("nothing secret", {"--token"}), "nothing secret");
}

TEST(CliFormat, HttpErrors) {
  EXPECT_EQ(cli::format_http_error(422,
                                   R"({"error": "schedule refused, nothing queued",
                                       "errors": ["a.toml:3: x: bad", "a.toml:9: y: worse"]})",
                                   true),
            "schedule refused, nothing queued\na.toml:3: x: bad\na.toml:9: y: worse");
  EXPECT_EQ(cli::format_http_error(401, R"({"error": "wrong token"})", true),
            "the daemon refused the token (set --token or GYROTHERM_TOKEN)");
  EXPECT_EQ(cli::format_http_error(502, "<html>Bad Gateway</html>", false),
            "the daemon answered HTTP 502: <html>Bad Gateway</html>");
  EXPECT_EQ(cli::format_http_error(500, "", false), "the daemon answered HTTP 500");
  EXPECT_EQ(cli::format_http_error(400, R"({"error": "token abc123 is odd"})", true, "abc123"),
            "token *** is odd");
}

// ---------------------------------------------------------------- run metadata and DUT history

json metadata_answer(const std::string& op, json tags) {
  return {
      {"operator", op}, {"comment", "after the\nre-splice"}, {"tags", tags}, {"duts", {"17-0042"}}};
}

json run_dut_answer() {
  return {{"serial", "17-0042"},
          {"model", "KVH 1750"},
          {"position", 0},
          {"primary_axis", "z"},
          {"axes", {"x", "z"}},
          {"rate_hz", 1000},
          {"channels",
           {{{"name", "gyro_x"}, {"unit", "deg/h"}, {"kind", "rate"}, {"axis", "x"}},
            {{"name", "gyro_z"}, {"unit", "deg/h"}, {"kind", "rate"}, {"axis", "z"}}}}};
}

json history_answer() {
  json run = run_answer();
  run["metadata"] = metadata_answer("Ana Müller", {"campaign-7"});
  run["dut"] = run_dut_answer();
  json ramp = run["segments"][0];
  ramp["index"] = 1;
  ramp["kind"] = "ramp";
  ramp["setpoint_c"] = 40.0;
  run["segments"].push_back(ramp);
  auto row = [](const char* axis, double bias, double std) {
    return json{{"segment_index", 0},     {"dut_serial", "17-0042"}, {"axis", axis},
                {"temp_mean_c", 20.0213}, {"bias_mean_dph", bias},   {"bias_std_dph", std}};
  };
  run["stats"] = {row("x", 1.20314, 0.01172), row("z", 7.95123, 0.01191)};
  run["allan"] = json::array();
  run["scale_factor"] = {{{"dut_serial", "17-0042"},
                          {"axis", "z"},
                          {"sf_sequence", 1},
                          {"temperature_c", 20.1},
                          {"k", 1.00015},
                          {"nonlinearity_ppm", 41.0},
                          {"asymmetry_ppm", 30.2},
                          {"repeatability_ppm", nullptr},
                          {"bias_dph", 7.56}}};
  return {{"serial", "17-0042"},
          {"model", "KVH 1750"},
          {"first_seen_utc", "2026-11-20T05:38:43.120Z"},
          {"runs", {run}},
          {"fits",
           {{{"id", 4},
             {"dut_serial", "17-0042"},
             {"axis", "z"},
             {"run_ids", {12}},
             {"model", "T2+R1+G1"},
             {"form", "centered"},
             {"residual_std_dph", 0.0301},
             {"r_squared", 0.9812},
             {"computed_utc", "2026-11-21T08:00:00.000Z"}}}}};
}

TEST_F(CliControlTest, MetadataAndDutCommandsSendTheirRequests) {
  FakeDaemon d;
  d.answer("POST", "/api/v1/queue", 201, entry(8, 1, "demo", 3, false));
  d.answer("GET", "/api/v1/queue", 200, queue_answer());
  json edited = run_answer();
  edited["metadata"] = metadata_answer("Bo Lind", {"a", "b"});
  edited["duts"] = json::array({run_dut_answer()});
  d.answer("PATCH", "/api/v1/runs/12", 200, edited);
  d.answer("GET", "/api/v1/runs/12", 200, edited);
  d.answer("GET", "/api/v1/runs/12/events", 200, events_answer());
  d.answer(
      "GET", "/api/v1/duts", 200,
      {{{"serial", ""}, {"model", ""}, {"first_seen_utc", "2026-01-02T03:04:05.000Z"}, {"runs", 3}},
       {{"serial", "17-0042"},
        {"model", "KVH 1750"},
        {"first_seen_utc", "2026-11-20T05:38:43.120Z"},
        {"runs", 1}}});
  d.answer("GET", "/api/v1/duts/SN%2017%2F42", 200, history_answer());
  d.answer(
      "GET", "/api/v1/duts/17-0043", 404,
      {{"error", "no DUT with serial '17-0043' (GET /api/v1/duts lists them)"}, {"status", 404}});
  const std::string schedule = (dir_ / "demo.toml").string();
  std::ofstream(schedule) << "name = \"demo\"\n";

  struct Case {
    std::vector<std::string> args;
    std::string method, target;
    json body;         // null: no body
    std::string says;  // in the human output
  };
  const std::vector<Case> cases = {
      {{"queue", "add", schedule, "--operator", "Ana Müller", "--tag", "campaign-7", "--comment",
        "after the re-splice", "--tag", "week 1", "--dut", "17-0042", "--dut", "17-0050"},
       "POST",
       "/api/v1/queue",
       {{"schedule_toml", "name = \"demo\"\n"},
        {"source", schedule},
        {"ignore_failures", false},
        {"operator", "Ana Müller"},
        {"comment", "after the re-splice"},
        {"tags", {"campaign-7", "week 1"}},
        {"duts", {"17-0042", "17-0050"}}},
       "queued entry 8"},
      {{"edit-run", "12", "--operator", "Bo Lind", "--tags", "a, b,", "--duts", ""},
       "PATCH",
       "/api/v1/runs/12",
       {{"operator", "Bo Lind"}, {"tags", {"a", "b"}}, {"duts", json::array()}},
       "run 12: metadata saved"},
      {{"edit-run", "12", "--comment", ""},
       "PATCH",
       "/api/v1/runs/12",
       {{"comment", ""}},
       "operator    Bo Lind\ncomment     after the\n            re-splice\ntags        a, b\n"},
      {{"duts"}, "GET", "/api/v1/duts", nullptr, "(no serial)"},
      {{"dut", "SN 17/42"}, "GET", "/api/v1/duts/SN%2017%2F42", nullptr, "DUT 17-0042  KVH 1750"},
  };
  for (const auto& c : cases) {
    SCOPED_TRACE(fmt::format("{}", fmt::join(c.args, " ")));
    d.forget();
    const Run r = cli(to(d, c.args));
    EXPECT_EQ(r.code, 0) << r.err;
    EXPECT_THAT(r.out, HasSubstr(c.says));
    const auto seen = d.seen();
    ASSERT_GE(seen.size(), 1u);
    EXPECT_EQ(seen[0].method, c.method);
    EXPECT_EQ(seen[0].target, c.target);
    EXPECT_EQ(seen[0].authorization, std::string("Bearer ") + kToken);
    if (c.body.is_null()) {
      EXPECT_EQ(seen[0].body, "");
    } else {
      EXPECT_EQ(json::parse(seen[0].body), c.body);
    }
  }

  // `run ID` shows the metadata and the DUTs.
  const Run run = cli(to(d, {"run", "12"}));
  ASSERT_EQ(run.code, 0) << run.err;
  EXPECT_THAT(run.out, HasSubstr("operator    Bo Lind\n"));
  EXPECT_THAT(run.out, HasSubstr("tags        a, b\n"));
  EXPECT_THAT(
      run.out,
      HasSubstr("DUTs        17-0042  KVH 1750, axes x z (primary z), 1000 Hz, 2 channels\n"));

  // Nothing to change: usage, no request.
  d.forget();
  const Run nothing = cli(to(d, {"edit-run", "12"}));
  EXPECT_EQ(nothing.code, 2);
  EXPECT_THAT(nothing.err, HasSubstr("give at least one of --operator, --comment, --tags, --duts"));
  EXPECT_TRUE(d.seen().empty());

  // An unknown serial: the daemon's message, exit 1.
  const Run unknown = cli(to(d, {"dut", "17-0043"}));
  EXPECT_EQ(unknown.code, 1);
  EXPECT_THAT(unknown.err, HasSubstr("no DUT with serial '17-0043'"));
  // --json: the daemon's answer as is.
  const Run j = cli(to(d, {"dut", "SN 17/42", "--json"}));
  ASSERT_EQ(j.code, 0) << j.err;
  EXPECT_EQ(json::parse(j.out), history_answer());
}

TEST(CliFormat, StatusNamesWhoRunsTheRun) {
  json status = status_answer();
  status.erase("run_metadata");
  EXPECT_THAT(cli::format_status(status), Not(HasSubstr("\noperator ")));
  status["run_metadata"] = {{"operator", "Ana Müller"}, {"comment", ""}, {"tags", {"c7", "w1"}}};
  EXPECT_THAT(cli::format_status(status), HasSubstr("operator    Ana Müller  (tags: c7, w1)\n"));
}

TEST(CliFormat, DutHistoryIsATablePerRunWithBiasPerAxis) {
  const std::string text = cli::format_dut_history(history_answer());
  EXPECT_THAT(text, HasSubstr("DUT 17-0042  KVH 1750\nfirst seen  2026-11-20 05:38:43 UTC\n"
                              "runs        1\n"));
  EXPECT_THAT(text,
              HasSubstr("\nrun 12  demo  completed  started 2026-11-21 05:38:43 UTC\n"
                        "operator    Ana Müller\ncomment     after the\n            re-splice\n"
                        "tags        campaign-7\n"));
  // One bias and σ pair per axis, in the DUT's axis order; the ramp has none.
  EXPECT_THAT(text, ContainsRegex("#  kind  set °C  T mean °C  x bias °/h  x σ °/h  z bias °/h  "
                                  "z σ °/h  state\n"));
  EXPECT_THAT(text, ContainsRegex("1  soak   20.00      20.02      1.2031   0.0117      7.9512 "
                                  "  0.0119  completed\n"));
  EXPECT_THAT(text, ContainsRegex("2  ramp   40.00          —           —        —           —  "
                                  "      —  completed\n"));
  EXPECT_THAT(text, HasSubstr("scale factor\n"));
  // A quality column ("—": the answer has none, as from an older daemon).
  EXPECT_THAT(text, ContainsRegex("1  z     20.10  1.0001500        41.0      30.2           —  "
                                  "   7.560  —\n"));
  EXPECT_THAT(text, HasSubstr("drift fits\n"));
  EXPECT_THAT(text, ContainsRegex("4  z     T2\\+R1\\+G1  centered  12          0.0301  0.9812"));
  // Flagged results: the column says so and a line gives the reasons.
  json flagged = history_answer();
  const json bad = {{"verdict", "flagged"},
                    {"reasons", {"coverage 6.0 % (600 of 10000 samples expected) is under 99 %"}}};
  flagged["fits"][0]["quality"] = bad;
  flagged["runs"][0]["scale_factor"][0]["quality"] = bad;
  flagged["runs"][0]["stats"][1]["quality"] = bad;
  const std::string marked = cli::format_dut_history(flagged);
  EXPECT_THAT(marked, ContainsRegex("7.560  FLAGGED\n"));
  EXPECT_THAT(marked, HasSubstr("  sequence 1: FLAGGED: coverage 6.0 % (600 of 10000"));
  EXPECT_THAT(marked, HasSubstr("  segment 1 z: Table I FLAGGED: coverage 6.0 %"));
  EXPECT_THAT(marked, ContainsRegex("0.9812  2026-11-21 08:00:00  FLAGGED\n"));
  EXPECT_THAT(marked, HasSubstr("fit 4: FLAGGED: coverage 6.0 %"));
  // Whatever is missing or mistyped prints as "—", never throws.
  EXPECT_THAT(cli::format_dut_history({{"runs", {{{"stats", 5}}}}}), HasSubstr("no segments"));
  EXPECT_EQ(cli::format_duts(json::array()), "no DUTs recorded\n");
}

// A database with two runs of DUT 17-0042 (one with 17-0050 too), as the
// records are stored: `dut` and `duts` read it without a daemon.
TEST_F(CliControlTest, DutAndDutsReadTheDatabaseFileOffline) {
  const std::string db_path = (dir_ / "station.db").string();
  std::vector<int64_t> run_ids;
  {
    auto db = storage::Database::open(db_path);
    ASSERT_TRUE(db.ok()) << db.error().message;
    for (int i = 0; i < 2; ++i) {
      storage::RunRecord run;
      run.schedule_name = i == 0 ? "monday" : "tuesday";
      run.state = "completed";
      run.started_utc = fmt::format("2026-11-2{}T05:38:43.120Z", i + 1);
      auto id = db->create_run(run);
      ASSERT_TRUE(id.ok()) << id.error().message;
      run_ids.push_back(*id);
      for (const char* serial : {"17-0042", "17-0050"}) {
        if (i == 1 && std::string(serial) == "17-0050") continue;
        storage::RunDutRecord d;
        d.position = std::string(serial) == "17-0042" ? 0 : 1;
        d.dut.serial = serial;
        d.dut.model = "KVH 1750";
        d.primary_axis = "z";
        d.axes = {"x", "z"};
        d.rate_hz = 1000;
        for (const char* axis : {"x", "z"}) {
          storage::ChannelRecord c;
          c.index = static_cast<int>(d.channels.size());
          c.spec = {fmt::format("gyro_{}", axis), "deg/h", ChannelKind::kRate, axis, 1.0};
          d.channels.push_back(c);
        }
        auto added = db->add_run_dut(*id, d);
        ASSERT_TRUE(added.ok()) << added.error().message;
      }
      storage::SegmentRecord seg;
      seg.run_id = *id;
      seg.index = 0;
      seg.kind = "soak";
      seg.label = "soak 20 °C";
      seg.setpoint_c = 20;
      seg.state = "completed";
      auto seg_id = db->create_segment(seg);
      ASSERT_TRUE(seg_id.ok()) << seg_id.error().message;
      for (const char* serial : {"17-0042", "17-0050"}) {
        if (i == 1 && std::string(serial) == "17-0050") continue;
        for (const auto& [axis, bias] : {std::pair<const char*, double>{"x", 1.25 + i},
                                         std::pair<const char*, double>{"z", 7.75 + i}}) {
          storage::SegmentStatsRecord st;
          st.segment_id = *seg_id;
          st.run_id = *id;
          st.dut_serial = serial;
          st.axis = axis;
          st.segment_index = 0;
          st.setpoint_c = 20;
          st.n = 600;
          st.temp_mean_c = 20.5;
          st.bias_mean_dph = std::string(serial) == "17-0042" ? bias : -bias;
          st.bias_std_dph = 0.125;
          ASSERT_TRUE(db->put_segment_stats(st).ok());
        }
      }
      storage::RunMetadata m;
      m.operator_name = i == 0 ? "Ana Müller" : "Bo Lind";
      m.tags = {"campaign-7"};
      m.dut_serials = {"17-0042"};
      ASSERT_TRUE(db->set_run_metadata(*id, m, "cli").ok());
    }
  }
  const std::string url = dead_url();  // nothing listens: the file is read

  const Run duts = cli({"duts", "--db", db_path, "--url", url});
  ASSERT_EQ(duts.code, 0) << duts.err;
  EXPECT_THAT(duts.out, ContainsRegex("17-0042 +KVH 1750 +[0-9-]+ [0-9:]+ +2\n"));
  EXPECT_THAT(duts.out, ContainsRegex("17-0050 +KVH 1750 +[0-9-]+ [0-9:]+ +1\n"));

  const Run history = cli({"dut", "17-0042", "--db", db_path, "--url", url});
  ASSERT_EQ(history.code, 0) << history.err;
  EXPECT_THAT(history.out, HasSubstr("DUT 17-0042  KVH 1750\n"));
  EXPECT_THAT(history.out, HasSubstr("runs        2\n"));
  EXPECT_THAT(history.out, HasSubstr("run 1  monday  completed"));
  EXPECT_THAT(history.out, HasSubstr("operator    Ana Müller\n"));
  EXPECT_THAT(history.out, HasSubstr("run 2  tuesday  completed"));
  EXPECT_THAT(history.out, HasSubstr("operator    Bo Lind\n"));
  // This DUT's biases only (17-0050's are negative), per axis.
  EXPECT_THAT(history.out, ContainsRegex("1  soak   20.00      20.50      1.2500   0.1250      "
                                         "7.7500   0.1250  completed\n"));
  EXPECT_THAT(history.out, ContainsRegex("1  soak   20.00      20.50      2.2500   0.1250      "
                                         "8.7500   0.1250  completed\n"));
  EXPECT_THAT(history.out, Not(HasSubstr("-1.2500")));

  const Run j = cli({"dut", "17-0050", "--json", "--db", db_path, "--url", url});
  ASSERT_EQ(j.code, 0) << j.err;
  const json h = json::parse(j.out);
  EXPECT_EQ(h["serial"], "17-0050");
  ASSERT_EQ(h["runs"].size(), 1u) << "17-0050 was in the first run only";
  EXPECT_EQ(h["runs"][0]["id"], run_ids[0]);
  EXPECT_EQ(h["runs"][0]["dut"]["position"], 1);
  EXPECT_EQ(h["runs"][0]["metadata"]["operator"], "Ana Müller");
  ASSERT_EQ(h["runs"][0]["stats"].size(), 2u);
  for (const auto& row : h["runs"][0]["stats"]) {
    EXPECT_EQ(row["dut_serial"], "17-0050");
    EXPECT_LT(row["bias_mean_dph"].get<double>(), 0);
  }
  // The same JSON as the daemon would answer.
  {
    auto db = storage::Database::open_read_only(db_path);
    ASSERT_TRUE(db.ok()) << db.error().message;
    auto expected = station::dut_history_json(*db, "17-0050");
    ASSERT_TRUE(expected.ok()) << expected.error().message;
    EXPECT_EQ(h, *expected);
  }

  const Run missing = cli({"dut", "17-0043", "--db", db_path, "--url", url});
  EXPECT_EQ(missing.code, 1);
  EXPECT_THAT(missing.err, HasSubstr("no DUT with serial '17-0043'"));
  EXPECT_THAT(missing.err, HasSubstr(db_path));
  const Run nofile = cli({"dut", "17-0042", "--db", (dir_ / "none.db").string()});
  EXPECT_EQ(nofile.code, 2);
  EXPECT_THAT(nofile.err, HasSubstr("none.db"));
}

// The real daemon (and simulator): metadata given with `queue add` reaches
// the run, `edit-run` changes it with an audit event, `run ID`, `duts` and
// `dut` show it, from the daemon and from its database file.
class CliStationTest : public testing::StationTest {
 protected:
  CliRun cli(std::vector<std::string> args) {
    args.insert(args.end(), {"--url", url("")});
    const CliRun r =
        run_gyrotherm(dir_, std::move(args), {std::string("GYROTHERM_TOKEN=") + kToken});
    EXPECT_THAT(r.out + r.err, Not(HasSubstr(kToken)));
    return r;
  }
  std::optional<json> cli_json(std::vector<std::string> args) {
    args.push_back("--json");
    const CliRun r = cli(std::move(args));
    if (r.code != 0) {
      ADD_FAILURE() << r.err;
      return std::nullopt;
    }
    return json::parse(r.out, nullptr, false);
  }
};

TEST_F(CliStationTest, MetadataRoundTripQueueRunEditEventHistory) {
  start_sim();
  start_daemon({}, /*with_schedule=*/false);
  ASSERT_TRUE(testing::wait_until([&] { return status().has_value(); }, std::chrono::seconds(30)))
      << daemon_->log();

  // A serial the station has not configured: refused, nothing queued.
  const CliRun refused =
      cli({"queue", "add", (dir_ / "schedule.toml").string(), "--dut", "17-9999"});
  EXPECT_EQ(refused.code, 1);
  EXPECT_THAT(refused.err, HasSubstr("no DUT with serial '17-9999'"));
  EXPECT_THAT(refused.err, HasSubstr("duts"));
  const auto queue = get_json("/api/v1/queue");
  ASSERT_TRUE(queue.is_object());
  EXPECT_TRUE(queue["entries"].empty() && queue["current"].is_null()) << queue.dump();

  const CliRun added =
      cli({"queue", "add", (dir_ / "schedule.toml").string(), "--operator", "Ana Müller",
           "--comment", "round trip", "--tag", "campaign-7", "--tag", "week-1"});
  ASSERT_EQ(added.code, 0) << added.err;
  int64_t run_id = 0;
  ASSERT_TRUE(testing::wait_until(
      [&] {
        const auto s = status();
        if (!s || !(*s)["run_id"].is_number_integer()) return false;
        run_id = (*s)["run_id"].get<int64_t>();
        return true;
      },
      std::chrono::seconds(60)))
      << daemon_->log();
  const std::string id = std::to_string(run_id);

  auto run = cli_json({"run", id});
  ASSERT_TRUE(run && run->is_object());
  EXPECT_EQ((*run)["metadata"]["operator"], "Ana Müller");
  EXPECT_EQ((*run)["metadata"]["comment"], "round trip");
  EXPECT_EQ((*run)["metadata"]["tags"], json({"campaign-7", "week-1"}));
  ASSERT_EQ((*run)["duts"].size(), 1u) << "[gyro] is the station's one DUT";
  const std::string serial = (*run)["duts"][0]["serial"].get<std::string>();
  const CliRun shown = cli({"run", id});
  EXPECT_THAT(shown.out, HasSubstr("operator    Ana Müller\n"));
  EXPECT_THAT(shown.out, HasSubstr("tags        campaign-7, week-1\n"));

  const CliRun edited =
      cli({"edit-run", id, "--operator", "Bo Lind", "--tags", "repeat", "--comment", ""});
  ASSERT_EQ(edited.code, 0) << edited.err;
  EXPECT_THAT(edited.out, HasSubstr("operator    Bo Lind\n"));
  run = cli_json({"run", id});
  ASSERT_TRUE(run && run->is_object());
  EXPECT_EQ((*run)["metadata"]["operator"], "Bo Lind");
  EXPECT_EQ((*run)["metadata"]["comment"], "");
  EXPECT_EQ((*run)["metadata"]["tags"], json({"repeat"}));
  // The audit event: kind metadata, who, old -> new.
  int metadata_events = 0;
  for (const auto& e : (*run)["events"]) {
    if (e["kind"] != "metadata") continue;
    ++metadata_events;
    const std::string message = e["message"].get<std::string>();
    EXPECT_THAT(message, HasSubstr("Ana Müller"));
    EXPECT_THAT(message, HasSubstr("Bo Lind"));
    EXPECT_THAT(message, HasSubstr("api"));
  }
  EXPECT_EQ(metadata_events, 1) << run->dump(2);
  // Without the token: refused, unchanged.
  const CliRun no_token =
      run_gyrotherm(dir_, {"edit-run", id, "--operator", "Eve", "--url", url("")}, {});
  EXPECT_EQ(no_token.code, 1);
  EXPECT_EQ(get_json("/api/v1/runs/" + id)["metadata"]["operator"], "Bo Lind");

  // The DUT's history, from the daemon and from the database file (the
  // daemon still writing it).
  const auto duts = cli_json({"duts"});
  ASSERT_TRUE(duts && duts->is_array());
  bool listed = false;
  for (const auto& d : *duts) listed |= d["serial"] == serial && d["runs"].get<int64_t>() >= 1;
  EXPECT_TRUE(listed) << duts->dump();
  const std::string db = (dir_ / "station.db").string();
  const auto offline = cli_json({"dut", serial, "--db", db});
  ASSERT_TRUE(offline && offline->is_object());
  ASSERT_FALSE((*offline)["runs"].empty());
  EXPECT_EQ((*offline)["runs"].back()["id"], run_id);
  EXPECT_EQ((*offline)["runs"].back()["metadata"]["operator"], "Bo Lind");
  if (!serial.empty()) {  // the REST route names a DUT by a non-empty serial
    // The run goes on meanwhile: compare what does not change.
    const auto online = cli_json({"dut", serial});
    ASSERT_TRUE(online && online->is_object());
    EXPECT_EQ((*online)["runs"].back()["id"], run_id);
    EXPECT_EQ((*online)["runs"].back()["metadata"], (*offline)["runs"].back()["metadata"]);
  }
  const CliRun offline_run = cli({"run", id, "--db", db});
  EXPECT_THAT(offline_run.out, HasSubstr("operator    Bo Lind\n"));
}

}  // namespace
}  // namespace gyrotherm

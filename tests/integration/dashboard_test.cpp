// End-to-end: the dashboard in a real browser. The simulated station runs a
// schedule; headless Chromium (tests/browser/dashboard.mjs, playwright-core)
// loads http://127.0.0.1:PORT/ from gyrothermd, waits for the live values to
// move, and leaves a screenshot in the build folder for a human to look at.
// A station whose reads need a token: the page asks for one, then goes live.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <iterator>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "station_fixture.h"
#include "test_files.h"

#ifndef GYROTHERM_DASHBOARD_PNG
#define GYROTHERM_DASHBOARD_PNG GYROTHERM_BIN_DIR "/../dashboard.png"
#endif

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using testing::StationTest;
using testing::wait_until;
using json = nlohmann::json;

// A ramp to look at, then a long acquisition so the run is still going when
// the browser looks (600 station min = 3 wall min at the fixture's scale).
constexpr const char* kDashboardSchedule = R"(
name = "dashboard"
[[step]]
type = "soak"
setpoint_c = 23.0
stability_window_min = 1
acquire_min = 2
[[step]]
type = "ramp"
target_c = 30.0
rate_c_per_min = 2.0
[[step]]
type = "soak"
setpoint_c = 30.0
stability_window_min = 2
acquire_min = 600
)";

class DashboardTest : public StationTest {
 protected:
  // Runs tests/browser/dashboard.mjs against the daemon's page (with
  // `extra` arguments); the screenshot goes to `png`.
  void run_browser(const fs::path& png, std::vector<std::string> extra = {}) {
    const fs::path source_dir = GYROTHERM_SOURCE_DIR;
    const fs::path script = source_dir / "tests/browser/dashboard.mjs";
    const testing::BrowserTools tools = testing::browser_tools(source_dir.string());
    if (!tools.missing.empty()) GTEST_FAIL() << tools.missing;
    fs::remove(png);
    std::vector<std::string> argv{tools.node,     script.string(), "--url",       url("/"),
                                  "--screenshot", png.string(),    "--timeout-s", "60"};
    argv.insert(argv.end(), extra.begin(), extra.end());
    testing::ChildProcess browser(argv, (dir_ / "browser.log").string());
    const auto code = browser.wait(std::chrono::seconds(120));
    ASSERT_TRUE(code.has_value()) << "the browser test did not finish in 120 s\n" << browser.log();
    EXPECT_EQ(*code, 0) << browser.log() << "\ndaemon log:\n" << daemon_->log();
    ASSERT_TRUE(fs::exists(png)) << "no screenshot at " << png << "\n" << browser.log();
    EXPECT_GT(fs::file_size(png), 10u * 1024) << png << " is too small to be the dashboard";
    std::printf("dashboard screenshot: %s\n", png.c_str());
  }
};

TEST_F(DashboardTest, LiveInHeadlessChromium) {
  write(dir_ / "schedule.toml", kDashboardSchedule);
  start_sim();
  start_daemon();
  // Past the ramp, acquiring at 30 °C: both plots have a story to show.
  json last;
  ASSERT_TRUE(wait_until(
      [&] {
        auto s = status();
        if (!s) return false;
        last = *s;
        return last["state"] == "acquiring" && last["step"]["index"] == 2;
      },
      std::chrono::seconds(60)))
      << "last status: " << last.dump() << "\ndaemon log:\n"
      << daemon_->log();
  // The station's progress: the last soak acquires 600 min and no settle is
  // left, so the run has an ETA, the acquisition's rest; the queue is empty.
  const json& progress = last["progress"];
  EXPECT_EQ(progress["phase"], "acquiring") << progress.dump();
  EXPECT_DOUBLE_EQ(progress["step_planned_s"].get<double>(), 36000.0);
  EXPECT_EQ(progress["run_settles_remaining"], 0);
  EXPECT_TRUE(progress["gate_held_s"].is_null());
  ASSERT_TRUE(progress["run_eta_s"].is_number()) << progress.dump();
  EXPECT_GT(progress["run_eta_s"].get<double>(), 0.0);
  EXPECT_NEAR(progress["run_eta_s"].get<double>() + progress["step_elapsed_s"].get<double>(),
              36000.0, 1e-6);
  EXPECT_NEAR(progress["step_fraction"].get<double>(),
              progress["step_elapsed_s"].get<double>() / 36000.0, 1e-12);
  EXPECT_DOUBLE_EQ(progress["queue_fixed_s"].get<double>(), 0.0) << last.dump();

  const auto page = call("GET", "/");
  ASSERT_TRUE(page && page->status == 200)
      << "gyrothermd does not serve the dashboard at / (is the gyrotherm_web target built?)\n"
      << daemon_->log();
  run_browser(fs::weakly_canonical(fs::path(GYROTHERM_DASHBOARD_PNG)));
}

// [api] read_access = "token": the page asks for a token, then goes live with
// it in the Authorization header (the stream read through fetch()).
TEST_F(DashboardTest, AsksForATokenWhenReadsNeedOne) {
  constexpr const char* kReadToken = "dashboard-read-token-0123456789";
  std::string config = testing::read_text(dir_ / "station.toml");
  const auto api = config.find("[api]\n");
  ASSERT_NE(api, std::string::npos);
  config.insert(api + 6,
                fmt::format("read_access = \"token\"\nread_tokens = [\"{}\"]\n", kReadToken));
  write(dir_ / "station.toml", config);
  write(dir_ / "schedule.toml", kDashboardSchedule);
  start_sim();
  start_daemon();
  ASSERT_TRUE(wait_until(
      [&] {
        auto r = call("GET", "/api/v1/status", "", kReadToken);
        return r && r->status == 200;
      },
      std::chrono::seconds(30)))
      << daemon_->log();
  const auto anonymous = call("GET", "/api/v1/status", "", "");
  ASSERT_TRUE(anonymous && anonymous->status == 401) << "reads do not need a token";
  run_browser(fs::weakly_canonical(fs::path(GYROTHERM_DASHBOARD_PNG))
                  .replace_filename("dashboard-token.png"),
              {"--token", kReadToken});
}

// The rate-table card against statuses the browser test feeds the page
// itself (tests/browser/dashboard_table.mjs; no daemon): at rate, an
// interlock fault while the table is safing, and a station without a table.
TEST(DashboardPage, RateTableCardFollowsTheStatus) {
  const fs::path source_dir = GYROTHERM_SOURCE_DIR;
  const testing::BrowserTools tools = testing::browser_tools(source_dir.string());
  if (!tools.missing.empty()) GTEST_FAIL() << tools.missing;
  const fs::path png = fs::weakly_canonical(fs::path(GYROTHERM_DASHBOARD_PNG))
                           .replace_filename("dashboard-table.png");
  fs::remove(png);
  const fs::path log =
      fs::temp_directory_path() / fmt::format("gyrotherm-dashboard-table-{}.log", ::getpid());
  testing::ChildProcess browser(
      {tools.node, (source_dir / "tests/browser/dashboard_table.mjs").string(), "--screenshot",
       png.string(), "--timeout-s", "30"},
      log.string());
  const auto code = browser.wait(std::chrono::seconds(90));
  ASSERT_TRUE(code.has_value()) << "the browser test did not finish in 90 s\n" << browser.log();
  EXPECT_EQ(*code, 0) << browser.log();
  EXPECT_TRUE(fs::exists(png)) << "no screenshot at " << png << "\n" << browser.log();
  if (!::testing::Test::HasFailure()) fs::remove(log);
}

// The DUT cards, the history plot's DUT and channel chooser and the progress
// bars against statuses the browser test feeds the page itself
// (tests/browser/dashboard_duts.mjs; no daemon): three DUTs, the samples
// route asked for the chosen DUT and channel, the stability gate's bar while
// settling, then the step's bar and the run's ETA.
TEST(DashboardPage, DutCardsChannelChooserAndProgress) {
  const fs::path source_dir = GYROTHERM_SOURCE_DIR;
  const testing::BrowserTools tools = testing::browser_tools(source_dir.string());
  if (!tools.missing.empty()) GTEST_FAIL() << tools.missing;
  const fs::path png = fs::weakly_canonical(fs::path(GYROTHERM_DASHBOARD_PNG))
                           .replace_filename("dashboard-duts.png");
  fs::remove(png);
  const fs::path log =
      fs::temp_directory_path() / fmt::format("gyrotherm-dashboard-duts-{}.log", ::getpid());
  testing::ChildProcess browser(
      {tools.node, (source_dir / "tests/browser/dashboard_duts.mjs").string(), "--screenshot",
       png.string(), "--timeout-s", "30"},
      log.string());
  const auto code = browser.wait(std::chrono::seconds(90));
  ASSERT_TRUE(code.has_value()) << "the browser test did not finish in 90 s\n" << browser.log();
  EXPECT_EQ(*code, 0) << browser.log();
  EXPECT_TRUE(fs::exists(png)) << "no screenshot at " << png << "\n" << browser.log();
  if (!::testing::Test::HasFailure()) fs::remove(log);
}

}  // namespace
}  // namespace gyrotherm

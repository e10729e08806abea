// The safe state's order with the real table drivers against controllers
// written from the vendors' public manuals (tests/support/acl_peer.h on
// loopback TCP, aero_peer.h on a real pty), not from our simulator: at the
// normal end of a run, on abort and at shutdown the table is stopped before
// the chamber gets its safe set point, and (ACL) only then is the servo
// turned off and the operator panel handed back. The peers log every
// command they receive with when; the rig's chamber logs each set point
// write with when; the test orders the two logs by time.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include "acl_peer.h"
#include "aero_peer.h"
#include "gyrotherm/drivers/acutrol_table.h"
#include "gyrotherm/drivers/aero_table.h"
#include "station/station_rig.h"

namespace gyrotherm::testing {
namespace {

using Clock = std::chrono::steady_clock;

// The rig's safe set point is 21 °C, apart from the schedules' 23 °C.
constexpr double kSafeC = 21.0;

constexpr const char* kSpin = R"(
name = "spin 2 min"
[[step]]
type = "hold"
setpoint_c = 23.0
duration_min = 2
table_rate_dps = 100.0
)";

std::string acl_config(const std::string& db_path, int port) {
  return rig_config_toml(db_path) +
         "[table]\nprofile = \"acutrol\"\nhost = \"127.0.0.1\"\nport = " + std::to_string(port) +
         "\nmax_rate_dps = 500\nmax_accel_dps2 = 100\nrest_rate_dps = 0.01\n";
}

std::string aero_config(const std::string& db_path, const std::string& device) {
  return rig_config_toml(db_path) + "[table]\nprofile = \"aero\"\ndevice = \"" + device +
         "\"\nmax_rate_dps = 500\nmax_accel_dps2 = 100\nrest_rate_dps = 0.01\n";
}

// One timeline: the peer's commands and the chamber's set point writes
// from `since` on, in the order they happened.
struct Event {
  std::string what;
  Clock::time_point at;
};

template <class Entries>
std::vector<Event> timeline(const Entries& table_log, const FakePlant::State& plant,
                            Clock::time_point since) {
  std::vector<Event> out;
  for (const auto& e : table_log) {
    if (e.at >= since) out.push_back({e.command, e.at});
  }
  for (const auto& [setpoint_c, at] : plant.setpoints_at) {
    if (at >= since) out.push_back({"setpoint " + std::to_string(std::lround(setpoint_c)), at});
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const Event& a, const Event& b) { return a.at < b.at; });
  return out;
}

std::string text(const std::vector<Event>& events) {
  std::string out;
  for (const auto& e : events) out += "  " + e.what + "\n";
  return out;
}

// Index of the first event that is `what` (or starts with it, `prefix`).
std::optional<std::size_t> first(const std::vector<Event>& events, const std::string& what,
                                 bool prefix = false) {
  for (std::size_t i = 0; i < events.size(); ++i) {
    if (prefix ? events[i].what.rfind(what, 0) == 0 : events[i].what == what) return i;
  }
  return std::nullopt;
}

// ACL: `:M:O 1` (mode off: stop), the safe set point, `:I:O 1` (servo
// off), `:U:L OFF` (panel released), in that order, and no rate demand
// after the stop.
void expect_acl_order(const std::vector<Event>& events) {
  const std::string all = text(events);
  const auto stop = first(events, ":M:O 1");
  const auto safe = first(events, "setpoint 21");
  const auto off = first(events, ":I:O 1");
  const auto release = first(events, ":U:L OFF");
  ASSERT_TRUE(stop && safe && off && release) << all;
  EXPECT_LT(*stop, *safe) << all;
  EXPECT_LT(*safe, *off) << all;
  EXPECT_LT(*off, *release) << all;
  for (std::size_t i = *stop; i < events.size(); ++i) {
    EXPECT_NE(events[i].what.rfind(":D:R", 0), 0u) << "a rate demand after the stop\n" << all;
  }
}

// AERO: `STO` before the safe set point, and no `JOG` after it (the
// Aerosmith has no servo-off or panel command: docs/table.md).
void expect_aero_order(const std::vector<Event>& events) {
  const std::string all = text(events);
  const auto stop = first(events, "STO");
  const auto safe = first(events, "setpoint 21");
  ASSERT_TRUE(stop && safe) << all;
  EXPECT_LT(*stop, *safe) << all;
  for (std::size_t i = *stop; i < events.size(); ++i) {
    EXPECT_NE(events[i].what.rfind("JOG", 0), 0u) << "a rate demand after the stop\n" << all;
  }
}

class StationTablePeersTest : public TempDirTest {
 protected:
  StationTablePeersTest() : TempDirTest("gyrotherm-station-peers") {}

  std::unique_ptr<StationRig> acl_rig(AclPeer& peer) {
    auto rig = std::make_unique<StationRig>(dir_, acl_config(dir_ / "station.db", peer.port()));
    rig->make_table = [&peer] {
      drivers::TableConnection c;
      c.profile = "acutrol";
      c.host = "127.0.0.1";
      c.port = peer.port();
      c.timeout_s = 1.0;
      return std::make_unique<drivers::AcutrolTable>(c, "turntable");
    };
    rig->open();
    return rig;
  }
  std::unique_ptr<StationRig> aero_rig(AeroPeer& peer) {
    auto rig = std::make_unique<StationRig>(dir_, aero_config(dir_ / "station.db", peer.device()));
    rig->make_table = [&peer] {
      drivers::TableConnection c;
      c.profile = "aero";
      c.device = peer.device();
      c.timeout_s = 1.0;
      return std::make_unique<drivers::AeroTable>(
          c, drivers::TableLimits{500.0, 100.0, std::nullopt}, "turntable");
    };
    rig->open();
    return rig;
  }
  template <class Peer>
  void until_spinning(StationRig& rig, const Peer& peer) {
    ASSERT_TRUE(rig.step_until([&] { return std::abs(peer.state().rate_dps - 100.0) < 1e-9; }, 600))
        << "peer rate " << peer.state().rate_dps << ", state " << rig.state();
  }
  // Ticks until the run is over, then 10 ticks more (the servo goes off
  // once the table is at rest).
  void until_idle(StationRig& rig) {
    ASSERT_TRUE(rig.step_until([&] { return !rig.station->status().run_id; }, 600));
    for (int i = 0; i < 10; ++i) rig.step();
  }
};

TEST_F(StationTablePeersTest, AclAtTheNormalEnd) {
  AclPeer peer;
  auto rig = acl_rig(peer);
  rig->queue(kSpin);
  until_spinning(*rig, peer);
  const auto since = Clock::now();
  until_idle(*rig);
  expect_acl_order(timeline(peer.log(), rig->plant->state(), since));
  EXPECT_EQ(peer.state().interlock, AclPeer::Interlock::kOpen);
  EXPECT_FALSE(peer.state().lockout) << "the operator panel is handed back";
  EXPECT_EQ(rig->plant->state().setpoint_c, kSafeC);
}

TEST_F(StationTablePeersTest, AclOnAbort) {
  AclPeer peer;
  auto rig = acl_rig(peer);
  rig->queue(kSpin);
  until_spinning(*rig, peer);
  const auto since = Clock::now();
  ASSERT_FALSE(rig->station->control("abort", "bench").refusal);
  until_idle(*rig);
  expect_acl_order(timeline(peer.log(), rig->plant->state(), since));
  EXPECT_FALSE(peer.state().lockout);
  EXPECT_EQ(rig->plant->state().setpoint_c, kSafeC);
}

TEST_F(StationTablePeersTest, AclAtShutdown) {
  AclPeer peer;
  auto rig = acl_rig(peer);
  rig->queue(kSpin);
  until_spinning(*rig, peer);
  const auto since = Clock::now();
  rig->close();
  expect_acl_order(timeline(peer.log(), rig->plant->state(), since));
  EXPECT_EQ(peer.state().interlock, AclPeer::Interlock::kOpen);
  EXPECT_FALSE(peer.state().lockout);
  EXPECT_EQ(peer.state().rate_dps, 0.0);
  EXPECT_EQ(rig->plant->state().setpoint_c, kSafeC);
}

TEST_F(StationTablePeersTest, AeroAtTheNormalEndOnAbortAndAtShutdown) {
  for (const std::string how : {"end", "abort", "shutdown"}) {
    SCOPED_TRACE(how);
    AeroPeer::Options o;
    o.decimals = AeroPeer::Decimals::kRefuse;
    AeroPeer peer(o);
    auto rig = aero_rig(peer);
    rig->queue(kSpin);
    until_spinning(*rig, peer);
    const auto since = Clock::now();
    if (how == "abort") {
      ASSERT_FALSE(rig->station->control("abort", "bench").refusal);
    }
    if (how == "shutdown") {
      rig->close();
    } else {
      until_idle(*rig);
    }
    expect_aero_order(timeline(peer.log(), rig->plant->state(), since));
    EXPECT_EQ(peer.state().rate_dps, 0.0);
    EXPECT_EQ(rig->plant->state().setpoint_c, kSafeC);
    rig.reset();
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
}

}  // namespace
}  // namespace gyrotherm::testing

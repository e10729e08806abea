// The DUT registry (schema v8): duts, run_duts, channels, and the
// resolution of a StreamKey to one DUT and axis of a run.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

RunRecord a_run(const std::string& name = "campaign") {
  RunRecord r;
  r.schedule_name = name;
  r.state = "ramping";
  r.started_utc = "2026-11-21T05:38:43.120Z";
  r.orientation = "up";
  return r;
}

// A KVH 1750 as the contract declares its channels (drivers/dut_link.h).
RunDutRecord kvh(const std::string& serial, int position, const std::string& primary = "z") {
  RunDutRecord d;
  d.position = position;
  d.dut.serial = serial;
  d.dut.model = "KVH 1750";
  d.dut.first_seen_utc = "2026-11-21T05:38:44.000Z";
  d.config_json = R"({"serial":")" + serial + R"(","protocol":"kvh1750"})";
  d.primary_axis = primary;
  d.axes = {"x", "y", "z"};
  d.rate_hz = 1000;
  d.seq_modulo = 128;
  const double k = 180.0 / 3.141592653589793 * 3600.0 * 1000.0;
  const auto add = [&](std::string name, std::string unit, ChannelKind kind, std::string axis,
                       double scale) {
    ChannelRecord c;
    c.index = static_cast<int>(d.channels.size());
    c.spec = ChannelSpec{std::move(name), std::move(unit), kind, std::move(axis), scale};
    d.channels.push_back(std::move(c));
  };
  add("gyro_x", "deg/h", ChannelKind::kRate, "x", k);
  add("gyro_y", "deg/h", ChannelKind::kRate, "y", k);
  add("gyro_z", "deg/h", ChannelKind::kRate, "z", k);
  add("accel_x", "g", ChannelKind::kAccel, "x", 1);
  add("accel_y", "g", ChannelKind::kAccel, "y", 1);
  add("accel_z", "g", ChannelKind::kAccel, "z", 1);
  add("status", "", ChannelKind::kStatus, "", 1);
  add("temp_c", "degC", ChannelKind::kTemperature, "", 1);
  return d;
}

TEST(Duts, RegisterAndReadBackEveryField) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run());
  const RunDutRecord in = kvh("17-0042", 0, "y");
  auto added = db.add_run_dut(run, in);
  ASSERT_TRUE(added.ok()) << added.error().message;
  EXPECT_GT(added->dut.id, 0);
  EXPECT_EQ(added->run_id, run);

  auto duts = db.run_duts(run);
  ASSERT_TRUE(duts.ok()) << duts.error().message;
  ASSERT_EQ(duts->size(), 1u);
  const RunDutRecord& d = duts->front();
  EXPECT_EQ(d.run_id, run);
  EXPECT_EQ(d.position, 0);
  EXPECT_EQ(d.dut.id, added->dut.id);
  EXPECT_EQ(d.dut.serial, "17-0042");
  EXPECT_EQ(d.dut.model, "KVH 1750");
  EXPECT_EQ(d.dut.first_seen_utc, "2026-11-21T05:38:44.000Z");
  EXPECT_EQ(d.config_json, in.config_json);
  EXPECT_EQ(d.primary_axis, "y");
  EXPECT_EQ(d.axes, (std::vector<std::string>{"x", "y", "z"}));
  EXPECT_EQ(d.rate_hz, 1000);
  EXPECT_EQ(d.seq_modulo, 128u);
  ASSERT_EQ(d.channels.size(), in.channels.size());
  for (std::size_t i = 0; i < d.channels.size(); ++i) {
    SCOPED_TRACE(in.channels[i].spec.name);
    EXPECT_GT(d.channels[i].id, 0);
    EXPECT_EQ(d.channels[i].run_id, run);
    EXPECT_EQ(d.channels[i].dut_id, d.dut.id);
    EXPECT_EQ(d.channels[i].index, static_cast<int>(i));
    EXPECT_EQ(d.channels[i].spec.name, in.channels[i].spec.name);
    EXPECT_EQ(d.channels[i].spec.unit, in.channels[i].spec.unit);
    EXPECT_EQ(d.channels[i].spec.kind, in.channels[i].spec.kind);
    EXPECT_EQ(d.channels[i].spec.axis, in.channels[i].spec.axis);
    EXPECT_EQ(d.channels[i].spec.scale, in.channels[i].spec.scale);
    EXPECT_EQ(d.channels[i].id, added->channels[i].id);
  }
  // What sqlite3 users see.
  EXPECT_EQ(query_text(db.handle(), "SELECT kind FROM channels WHERE name = 'temp_c'"),
            "temperature");
  EXPECT_EQ(query_text(db.handle(), "SELECT axes_json FROM run_duts"), R"(["x","y","z"])");

  auto one = db.dut("17-0042");
  ASSERT_TRUE(one.ok()) << one.error().message;
  ASSERT_TRUE(one->has_value());
  EXPECT_EQ((*one)->id, d.dut.id);
  EXPECT_FALSE(db.dut("17-0043")->has_value());
}

TEST(Duts, RegisteringTwiceReturnsTheFirstRegistration) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run());
  auto first = db.add_run_dut(run, kvh("17-0042", 0));
  ASSERT_TRUE(first.ok()) << first.error().message;
  RunDutRecord again = kvh("17-0042", 0);
  again.primary_axis = "x";  // a resumed run keeps what it started with
  auto second = db.add_run_dut(run, again);
  ASSERT_TRUE(second.ok()) << second.error().message;
  EXPECT_EQ(second->dut.id, first->dut.id);
  EXPECT_EQ(second->primary_axis, "z");
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM run_duts"), 1);
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM channels"), 8);
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM duts"), 1);
}

TEST(Duts, OneRegistryAcrossRunsOrderedBySerialAndPositions) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run1 = *db.create_run(a_run("one"));
  const int64_t run2 = *db.create_run(a_run("two"));
  RunDutRecord unnamed;  // an old-style [gyro]: no serial, no model
  unnamed.primary_axis = "z";
  ASSERT_TRUE(db.add_run_dut(run1, kvh("B-2", 1)).ok());
  ASSERT_TRUE(db.add_run_dut(run1, kvh("A-1", 0)).ok());
  ASSERT_TRUE(db.add_run_dut(run1, unnamed).ok() == false);  // position 0 is A-1's
  unnamed.position = 2;
  ASSERT_TRUE(db.add_run_dut(run1, unnamed).ok());
  // The same serial in a later run, now with a model given: one registry
  // row, first seen kept, model updated; an empty model does not erase it.
  RunDutRecord later = kvh("B-2", 0);
  later.dut.model = "KVH 1750 rev B";
  later.dut.first_seen_utc = "2026-12-01T00:00:00.000Z";
  ASSERT_TRUE(db.add_run_dut(run2, later).ok());
  RunDutRecord no_model = kvh("A-1", 1);
  no_model.dut.model = "";
  ASSERT_TRUE(db.add_run_dut(run2, no_model).ok());

  auto all = db.duts();
  ASSERT_TRUE(all.ok()) << all.error().message;
  ASSERT_EQ(all->size(), 3u);
  EXPECT_EQ((*all)[0].serial, "");
  EXPECT_EQ((*all)[1].serial, "A-1");
  EXPECT_EQ((*all)[1].model, "KVH 1750");
  EXPECT_EQ((*all)[2].serial, "B-2");
  EXPECT_EQ((*all)[2].model, "KVH 1750 rev B");
  EXPECT_EQ((*all)[2].first_seen_utc, "2026-11-21T05:38:44.000Z");

  auto in1 = *db.run_duts(run1);
  ASSERT_EQ(in1.size(), 3u);
  EXPECT_EQ(in1[0].dut.serial, "A-1");
  EXPECT_EQ(in1[1].dut.serial, "B-2");
  EXPECT_EQ(in1[2].dut.serial, "");
  EXPECT_TRUE(in1[2].channels.empty());
  EXPECT_EQ(in1[2].config_json, "{}");
  EXPECT_EQ(in1[2].rate_hz, 0);
  auto in2 = *db.run_duts(run2);
  ASSERT_EQ(in2.size(), 2u);
  EXPECT_EQ(in2[0].dut.serial, "B-2");
  EXPECT_EQ(in2[1].dut.serial, "A-1");
  EXPECT_TRUE(db.run_duts(run2 + 1)->empty());
}

TEST(Duts, BadRegistrationsAreRefusedByName) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run());
  const auto refused = [&](int64_t run_id, const RunDutRecord& d, const std::string& needle) {
    auto r = db.add_run_dut(run_id, d);
    if (r.ok()) return ::testing::AssertionFailure() << "accepted";
    if (r.error().message.find(needle) == std::string::npos) {
      return ::testing::AssertionFailure() << r.error().message;
    }
    if (r.error().message.find("station.db") == std::string::npos) {
      return ::testing::AssertionFailure() << "no file named: " << r.error().message;
    }
    return ::testing::AssertionSuccess();
  };
  EXPECT_TRUE(refused(run + 7, kvh("X", 0), fmt::format("run {}: no such run", run + 7)));
  RunDutRecord twice = kvh("X", 0);
  twice.channels[3].spec.name = "gyro_x";
  twice.channels[3].index = 0;
  EXPECT_TRUE(refused(run, twice, "channel name 'gyro_x' is used twice"));
  RunDutRecord bad_json = kvh("X", 0);
  bad_json.config_json = "[1]";
  EXPECT_TRUE(refused(run, bad_json, "config_json is not a JSON object"));
  RunDutRecord bad_index = kvh("X", 0);
  bad_index.channels[2].index = 5;
  EXPECT_TRUE(refused(run, bad_index, "channel 'gyro_z' has index 5 but is number 2"));
  RunDutRecord other_run = kvh("X", 0);
  other_run.run_id = run + 1;
  EXPECT_TRUE(refused(run, other_run, fmt::format("belongs to run {}", run + 1)));
  ASSERT_TRUE(db.add_run_dut(run, kvh("X", 0)).ok());
  EXPECT_TRUE(refused(run, kvh("Y", 0), "position 0 is DUT 'X''s"));
  // Nothing of the refused ones was kept.
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM duts"), 1);
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM channels"), 8);
}

// Inside a transaction of the caller (the sample writer's), registration is
// part of that transaction: it goes with a rollback.
TEST(Duts, RegistrationNestsInTheCallersTransaction) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run());
  ASSERT_TRUE(db.exec("BEGIN IMMEDIATE").ok());
  auto added = db.add_run_dut(run, kvh("N-1", 0));
  ASSERT_TRUE(added.ok()) << added.error().message;
  EXPECT_FALSE(db.add_run_dut(run, kvh("N-2", 0)).ok());  // position taken: its savepoint only
  EXPECT_EQ(db.run_duts(run)->size(), 1u);
  ASSERT_TRUE(db.exec("ROLLBACK").ok());
  EXPECT_TRUE(db.run_duts(run)->empty());
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM duts"), 0);
}

TEST(Duts, ResolveStream) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run());
  auto none = db.resolve_stream(run, {});
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.error().message.find(fmt::format("run {} has no DUTs", run)), std::string::npos)
      << none.error().message;

  RunDutRecord second = kvh("B-2", 1, "x");
  second.axes = {"x"};
  ASSERT_TRUE(db.add_run_dut(run, second).ok());
  ASSERT_TRUE(db.add_run_dut(run, kvh("A-1", 0, "y")).ok());

  auto first = db.resolve_stream(run, {});
  ASSERT_TRUE(first.ok()) << first.error().message;
  EXPECT_EQ(first->first.dut.serial, "A-1");
  EXPECT_EQ(first->second, "y");
  EXPECT_EQ(first->first.channels.size(), 8u);

  auto b = db.resolve_stream(run, {"B-2", ""});
  ASSERT_TRUE(b.ok()) << b.error().message;
  EXPECT_EQ(b->first.dut.serial, "B-2");
  EXPECT_EQ(b->second, "x");
  // z is not analysed but B-2 has a rate channel about it.
  auto bz = db.resolve_stream(run, {"B-2", "z"});
  ASSERT_TRUE(bz.ok()) << bz.error().message;
  EXPECT_EQ(bz->second, "z");
  auto az = db.resolve_stream(run, {"", "z"});
  ASSERT_TRUE(az.ok()) << az.error().message;
  EXPECT_EQ(az->first.dut.serial, "A-1");
  EXPECT_EQ(az->second, "z");

  auto unknown = db.resolve_stream(run, {"C-3", ""});
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.error().message.find(
                fmt::format("run {} has no DUT 'C-3' (its DUTs: 'A-1', 'B-2')", run)),
            std::string::npos)
      << unknown.error().message;
  auto accel_only = db.resolve_stream(run, {"A-1", "w"});
  ASSERT_FALSE(accel_only.ok());
  EXPECT_NE(accel_only.error().message.find("DUT 'A-1' of run " + std::to_string(run) +
                                            " has no rate axis 'w' (its axes: x, y, z)"),
            std::string::npos)
      << accel_only.error().message;
}

}  // namespace
}  // namespace gyrotherm::storage

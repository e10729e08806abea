// The lab's central schema against a private PostgreSQL cluster: the
// versioned migrations, station and reader registration, the relay's batch
// upsert (idempotent, newest outbox seq wins, tombstones), row-level
// security refusing another station's id, the typed views over realistic
// payloads (as the station's outbox triggers write them), and a server
// outage mid-session.
#include "gyrotherm/lab/central.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "gyrotherm/lab/pg.h"
#include "gyrotherm/storage/database.h"
#include "support/pg_cluster.h"
#include "test_time.h"

namespace gyrotherm::lab {
namespace {

using json = nlohmann::json;
using storage::OutboxRecord;
using testing::PgCluster;
using testing::PgClusterTest;

constexpr const char* kRun1 = "0f8c3c1e-4a5b-4c6d-8e7f-0123456789ab";
constexpr const char* kRun2 = "9a1b2c3d-4e5f-4a6b-9c7d-8e9fa0b1c2d3";
const std::string kNil(storage::kNilUuid);

OutboxRecord record(int64_t seq, std::string kind, std::string run_uuid, std::string local_id,
                    const json& payload, bool deleted = false) {
  OutboxRecord r;
  r.seq = seq;
  r.kind = std::move(kind);
  r.run_uuid = std::move(run_uuid);
  r.local_id = std::move(local_id);
  r.deleted = deleted;
  r.payload_json = deleted ? "{}" : payload.dump();
  r.committed_unix_s = 1772395200.25 + static_cast<double>(seq);  // 2026-03-01T20:00:00.25Z + seq s
  return r;
}

OutboxRecord tombstone(int64_t seq, std::string kind, std::string run_uuid, std::string local_id) {
  return record(seq, std::move(kind), std::move(run_uuid), std::move(local_id), json::object(),
                true);
}

json run_payload(int64_t id, const std::string& uuid, const std::string& comment = "cold soak") {
  return {{"id", id},
          {"schedule_name", "paper-cold"},
          {"state", "completed"},
          {"started_utc", "2026-03-01T20:00:00Z"},
          {"ended_utc", "2026-03-02T06:00:00Z"},
          {"time_scale", 1.0},
          {"latitude_deg", 52.1},
          {"orientation", "up"},
          {"config_json", json::object({{"station", json::object({{"name", "st-a"}})}})},
          {"queue_id", 3},
          {"schedule_id", 2},
          {"operator", "ana"},
          {"comment", comment},
          {"tags_json", json::array({"night", "cold"})},
          {"dut_serials_json", json::array({"17-0042", "17-0043"})},
          {"uuid", uuid}};
}

class CentralTest : public PgClusterTest {
 protected:
  void SetUp() override {
    PgClusterTest::SetUp();
    if (IsSkipped() || HasFatalFailure()) return;
    // Roles are cluster-wide: named after this test's database.
    role_a_ = dbname_ + "_a";
    role_b_ = dbname_ + "_b";
    role_reader_ = dbname_ + "_r";
  }

  PgConnection connect(const std::string& user = PgCluster::kAdmin) {
    auto pg = PgConnection::connect(conninfo(user));
    EXPECT_TRUE(pg.ok()) << (pg.ok() ? "" : pg.error().message);
    if (!pg.ok()) throw std::runtime_error("cannot connect as " + user);
    return std::move(pg).value();
  }

  // A migrated database with stations st-a (role_a_) and st-b (role_b_).
  PgConnection setup_stations() {
    auto admin = connect();
    auto v = migrate_central(admin);
    EXPECT_TRUE(v.ok()) << v.error().message;
    auto a = add_station(admin, "st-a", role_a_, "bench A");
    EXPECT_TRUE(a.ok()) << a.error().message;
    auto b = add_station(admin, "st-b", role_b_, "bench B");
    EXPECT_TRUE(b.ok()) << b.error().message;
    return admin;
  }

  static std::string scalar(PgConnection& pg, const std::string& sql,
                            const std::vector<std::optional<std::string>>& params = {}) {
    auto r = pg.exec_params(sql, params);
    EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message) << "\n" << sql;
    if (!r.ok() || r->rows.empty() || r->rows[0].empty()) return "<no row>";
    return r->rows[0][0].value_or("<null>");
  }

  // Rows of `sql` as maps column -> text ("<null>" for NULL).
  static std::vector<std::map<std::string, std::string>> rows(PgConnection& pg,
                                                              const std::string& sql) {
    auto r = pg.exec(sql);
    EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message) << "\n" << sql;
    std::vector<std::map<std::string, std::string>> out;
    if (!r.ok()) return out;
    for (const auto& row : r->rows) {
      auto& m = out.emplace_back();
      for (size_t c = 0; c < row.size(); ++c) m[r->columns[c]] = row[c].value_or("<null>");
    }
    return out;
  }

  static PushResult push(PgConnection& pg, const std::string& station,
                         const std::vector<OutboxRecord>& batch) {
    auto r = push_batch(pg, station, batch);
    EXPECT_TRUE(r.ok()) << (r.ok() ? "" : r.error().message);
    return r.ok() ? *r : PushResult{-1, -1, -1};
  }

  std::string role_a_, role_b_, role_reader_;
};

void expect_counts(const PushResult& r, int64_t upserted, int64_t redelivered, int64_t stale) {
  EXPECT_EQ(r.upserted, upserted);
  EXPECT_EQ(r.redelivered, redelivered);
  EXPECT_EQ(r.stale, stale);
}

// --- migrations ------------------------------------------------------------

TEST_F(CentralTest, MigrateCreatesTheCurrentVersionAndTwiceIsANoOp) {
  auto pg = connect();
  auto before = central_schema_version(pg);
  ASSERT_TRUE(before.ok()) << before.error().message;
  EXPECT_EQ(*before, 0);

  auto v = migrate_central(pg);
  ASSERT_TRUE(v.ok()) << v.error().message;
  EXPECT_EQ(*v, 4);
  EXPECT_EQ(kCentralSchemaVersion, 4);
  EXPECT_EQ(*central_schema_version(pg), 4);
  EXPECT_EQ(scalar(pg, "SELECT count(*) FROM lab.schema_migrations"), "4");
  const std::string applied = scalar(pg, "SELECT max(applied_at) FROM lab.schema_migrations");
  EXPECT_EQ(scalar(pg,
                   "SELECT count(*) FROM pg_roles WHERE rolname IN "
                   "('gyrotherm_station', 'gyrotherm_reader') AND NOT rolcanlogin"),
            "2");

  auto again = migrate_central(pg);
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(*again, 4);
  EXPECT_EQ(scalar(pg, "SELECT count(*) FROM lab.schema_migrations"), "4");
  EXPECT_EQ(scalar(pg, "SELECT max(applied_at) FROM lab.schema_migrations"), applied);
}

TEST_F(CentralTest, NewerSchemaIsRefusedNamingBothVersions) {
  auto pg = connect();
  ASSERT_TRUE(migrate_central(pg).ok());
  ASSERT_TRUE(pg.exec("INSERT INTO lab.schema_migrations(version, description) "
                      "VALUES (99, 'from the future')")
                  .ok());
  EXPECT_EQ(*central_schema_version(pg), 99);
  auto v = migrate_central(pg);
  ASSERT_FALSE(v.ok());
  EXPECT_FALSE(v.error().transient);
  EXPECT_NE(v.error().message.find("version 99"), std::string::npos) << v.error().message;
  EXPECT_NE(v.error().message.find("version 4 "), std::string::npos) << v.error().message;
  // Nothing was touched, and the connection is usable (the transaction ended):
  // versions 1 to 4 and 99.
  EXPECT_EQ(scalar(pg, "SELECT count(*) FROM lab.schema_migrations"), "5");
}

TEST_F(CentralTest, ConcurrentMigrationsBothSucceedOneApplies) {
  // A third session holds the migration lock until both migrations are
  // waiting on it, so they really start together.
  auto holder = connect();
  ASSERT_TRUE(holder.exec("BEGIN; SELECT pg_advisory_xact_lock(29104238963630434)").ok());
  auto pg1 = connect();
  auto pg2 = connect();
  Result<int> r1 = Error::Permanent("not run");
  Result<int> r2 = Error::Permanent("not run");
  std::thread t1([&] { r1 = migrate_central(pg1); });
  std::thread t2([&] { r2 = migrate_central(pg2); });
  auto watcher = connect();
  const bool both_waiting = testing::wait_for_condition(
      [&] {
        return scalar(watcher,
                      "SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' "
                      "AND NOT granted") == "2";
      },
      std::chrono::seconds(20), std::chrono::milliseconds(10));
  EXPECT_TRUE(both_waiting);
  ASSERT_TRUE(holder.exec("COMMIT").ok());
  t1.join();
  t2.join();
  ASSERT_TRUE(r1.ok()) << r1.error().message;
  ASSERT_TRUE(r2.ok()) << r2.error().message;
  EXPECT_EQ(*r1, 4);
  EXPECT_EQ(*r2, 4);
  EXPECT_EQ(scalar(watcher, "SELECT count(*) FROM lab.schema_migrations"), "4");
  EXPECT_EQ(scalar(watcher, "SELECT count(*) FROM pg_views WHERE schemaname = 'lab'"), "11");
}

TEST_F(CentralTest, RegistrationNeedsTheSchema) {
  auto pg = connect();
  auto s = add_station(pg, "st-a", role_a_);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("migrate"), std::string::npos) << s.error().message;
}

// --- registration ----------------------------------------------------------

TEST_F(CentralTest, AddStationCreatesTheLoginRoleAndTheMapping) {
  auto pg = connect();
  ASSERT_TRUE(migrate_central(pg).ok());
  EXPECT_EQ(scalar(pg, "SELECT count(*) FROM pg_roles WHERE rolname = $1", {role_a_}), "0");
  auto s = add_station(pg, "st-a", role_a_, "bench A");
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(scalar(pg, "SELECT rolcanlogin FROM pg_roles WHERE rolname = $1", {role_a_}), "t");
  EXPECT_EQ(scalar(pg, "SELECT pg_has_role($1, 'gyrotherm_station', 'MEMBER')", {role_a_}), "t");
  EXPECT_EQ(scalar(pg,
                   "SELECT db_role || '|' || description FROM lab.stations "
                   "WHERE station_id = 'st-a'"),
            role_a_ + "|bench A");

  // The same pair again: nothing changes.
  auto again = add_station(pg, "st-a", role_a_, "other words");
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_EQ(scalar(pg, "SELECT description FROM lab.stations"), "bench A");

  // The id taken by another role, the role by another id: errors naming both.
  auto id_taken = add_station(pg, "st-a", role_b_);
  ASSERT_FALSE(id_taken.ok());
  EXPECT_NE(id_taken.error().message.find("st-a"), std::string::npos);
  EXPECT_NE(id_taken.error().message.find(role_a_), std::string::npos) << id_taken.error().message;
  EXPECT_NE(id_taken.error().message.find(role_b_), std::string::npos) << id_taken.error().message;
  auto role_taken = add_station(pg, "st-z", role_a_);
  ASSERT_FALSE(role_taken.ok());
  EXPECT_NE(role_taken.error().message.find("st-z"), std::string::npos);
  EXPECT_NE(role_taken.error().message.find("st-a"), std::string::npos)
      << role_taken.error().message;
  EXPECT_EQ(scalar(pg, "SELECT count(*) FROM lab.stations"), "1");
  EXPECT_EQ(scalar(pg, "SELECT count(*) FROM pg_roles WHERE rolname = $1", {role_b_}), "0")
      << "a refused registration creates no role";

  auto bad_id = add_station(pg, "-bad id", role_b_);
  ASSERT_FALSE(bad_id.ok());
  EXPECT_NE(bad_id.error().message.find("-bad id"), std::string::npos);
  // A role that would bypass row-level security is no station's role.
  auto super = add_station(pg, "st-s", PgCluster::kAdmin);
  ASSERT_FALSE(super.ok());
  EXPECT_NE(super.error().message.find("superuser"), std::string::npos) << super.error().message;

  // An existing plain role is reused.
  ASSERT_TRUE(pg.exec("CREATE ROLE " + role_b_ + " LOGIN").ok());
  ASSERT_TRUE(add_station(pg, "st-b", role_b_).ok());
  EXPECT_EQ(scalar(pg, "SELECT pg_has_role($1, 'gyrotherm_station', 'MEMBER')", {role_b_}), "t");
}

// --- the batch upsert ------------------------------------------------------

TEST_F(CentralTest, StationPushesItsOwnRecordsAndAReplayOnlyCountsRedeliveries) {
  auto admin = setup_stations();
  auto st = connect(role_a_);
  const std::vector<OutboxRecord> batch = {
      record(1, "run", kRun1, "7", run_payload(7, kRun1)),
      record(2, "dut", kNil, "3", {{"id", 3}, {"serial", "17-0042"}, {"model", "KVH 1750"}}),
      record(3, "run_dut", kRun1, "7/3",
             {{"run_id", 7}, {"dut_id", 3}, {"position", 0}, {"primary_axis", "z"}}),
  };
  expect_counts(push(st, "st-a", batch), 3, 0, 0);
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.records WHERE station_id = 'st-a'"), "3");
  EXPECT_EQ(scalar(admin,
                   "SELECT last_seq || '/' || batches || '/' || records "
                   "FROM lab.relay_progress WHERE station_id = 'st-a'"),
            "3/1/3");
  EXPECT_EQ(scalar(admin,
                   "SELECT to_char(station_committed_at AT TIME ZONE 'UTC', "
                   "'YYYY-MM-DD HH24:MI:SS.MS') FROM lab.records WHERE kind = 'run'"),
            "2026-03-01 20:00:01.250");
  const std::string central_at =
      scalar(admin, "SELECT central_committed_at FROM lab.records WHERE kind = 'run'");
  const std::string payload = scalar(admin, "SELECT payload FROM lab.records WHERE kind = 'run'");

  // At least once: the same batch again (the relay crashed before its ack).
  // Nothing changes but the redelivery counts and the progress counters.
  expect_counts(push(st, "st-a", batch), 0, 3, 0);
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.records"), "3");
  EXPECT_EQ(scalar(admin, "SELECT sum(redeliveries) FROM lab.records"), "3");
  EXPECT_EQ(scalar(admin, "SELECT central_committed_at FROM lab.records WHERE kind = 'run'"),
            central_at);
  EXPECT_EQ(scalar(admin, "SELECT payload FROM lab.records WHERE kind = 'run'"), payload);
  EXPECT_EQ(scalar(admin,
                   "SELECT last_seq || '/' || batches || '/' || records "
                   "FROM lab.relay_progress WHERE station_id = 'st-a'"),
            "3/2/6");
}

TEST_F(CentralTest, NewerSeqReplacesOlderSeqIsStale) {
  auto admin = setup_stations();
  auto st = connect(role_a_);
  expect_counts(push(st, "st-a", {record(5, "run", kRun1, "7", run_payload(7, kRun1, "first"))}), 1,
                0, 0);
  expect_counts(push(st, "st-a", {record(7, "run", kRun1, "7", run_payload(7, kRun1, "second"))}),
                1, 0, 0);
  EXPECT_EQ(scalar(admin, "SELECT payload->>'comment' || '/' || outbox_seq FROM lab.records"),
            "second/7");
  // An older version arriving late (a replay from before the update).
  expect_counts(push(st, "st-a", {record(5, "run", kRun1, "7", run_payload(7, kRun1, "first"))}), 0,
                0, 1);
  EXPECT_EQ(scalar(admin,
                   "SELECT payload->>'comment' || '/' || outbox_seq || '/' || redeliveries "
                   "FROM lab.records"),
            "second/7/0");
  // The progress mark never goes back.
  EXPECT_EQ(scalar(admin, "SELECT last_seq || '/' || batches FROM lab.relay_progress"), "7/3");
}

TEST_F(CentralTest, SameKeyTwiceInABatchKeepsTheLast) {
  auto admin = setup_stations();
  auto st = connect(role_a_);
  const std::vector<OutboxRecord> batch = {
      record(10, "run", kRun1, "7", run_payload(7, kRun1, "queued")),
      record(11, "run", kRun2, "8", run_payload(8, kRun2)),
      record(12, "run", kRun1, "7", run_payload(7, kRun1, "finished")),
  };
  expect_counts(push(st, "st-a", batch), 2, 0, 0);
  EXPECT_EQ(scalar(admin,
                   "SELECT payload->>'comment' || '/' || outbox_seq FROM lab.records "
                   "WHERE local_id = '7'"),
            "finished/12");
  EXPECT_EQ(scalar(admin, "SELECT last_seq || '/' || records FROM lab.relay_progress"), "12/3");
}

TEST_F(CentralTest, TombstoneHidesTheRowALaterInsertRestoresIt) {
  auto admin = setup_stations();
  auto st = connect(role_a_);
  push(st, "st-a", {record(1, "run", kRun1, "7", run_payload(7, kRun1))});
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.runs"), "1");
  expect_counts(push(st, "st-a", {tombstone(2, "run", kRun1, "7")}), 1, 0, 0);
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.runs"), "0");
  EXPECT_EQ(scalar(admin, "SELECT deleted || '/' || payload::text FROM lab.records"), "true/{}");
  // The tombstone replayed: a redelivery, still deleted.
  expect_counts(push(st, "st-a", {tombstone(2, "run", kRun1, "7")}), 0, 1, 0);
  // The older insert arriving late stays hidden.
  expect_counts(push(st, "st-a", {record(1, "run", kRun1, "7", run_payload(7, kRun1))}), 0, 0, 1);
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.runs"), "0");
  // Inserted again later (same key): back.
  expect_counts(push(st, "st-a", {record(3, "run", kRun1, "7", run_payload(7, kRun1, "again"))}), 1,
                0, 0);
  EXPECT_EQ(scalar(admin, "SELECT comment FROM lab.runs"), "again");
  EXPECT_EQ(scalar(admin, "SELECT deleted FROM lab.records"), "f");
}

TEST_F(CentralTest, EmptyBatchWritesNothing) {
  auto admin = setup_stations();
  auto st = connect(role_a_);
  expect_counts(push(st, "st-a", {}), 0, 0, 0);
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.relay_progress"), "0");
}

// --- refusals --------------------------------------------------------------

TEST_F(CentralTest, AnotherStationsIdIsRefusedAndNothingIsWritten) {
  auto admin = setup_stations();
  const std::string secret = "Pa55-w0rd-not-shown";
  auto st = PgConnection::connect(conninfo(role_a_) + " password=" + secret);
  ASSERT_TRUE(st.ok()) << st.error().message;
  push(*st, "st-a", {record(1, "run", kRun1, "7", run_payload(7, kRun1))});

  // Role A claiming station B's id.
  const std::vector<OutboxRecord> batch = {
      record(2, "run", kRun2, "8", run_payload(8, kRun2)),
      record(3, "segment", kRun2, "11", {{"id", 11}, {"run_id", 8}, {"idx", 0}}),
  };
  auto r = push_batch(*st, "st-b", batch);
  ASSERT_FALSE(r.ok());
  EXPECT_FALSE(r.error().transient);
  EXPECT_EQ(st->last_sqlstate(), "42501");
  const std::string& m = r.error().message;
  EXPECT_NE(m.find("refused station id 'st-b' for role '" + role_a_ + "'"), std::string::npos) << m;
  EXPECT_NE(m.find("registered to role '" + role_b_ + "'"), std::string::npos) << m;
  EXPECT_NE(m.find("row-level security"), std::string::npos) << m;
  EXPECT_EQ(m.find(secret), std::string::npos) << m;

  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.records"), "1");
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.relay_progress WHERE station_id = 'st-b'"),
            "0");
  EXPECT_EQ(scalar(admin,
                   "SELECT last_seq || '/' || batches FROM lab.relay_progress "
                   "WHERE station_id = 'st-a'"),
            "1/1");
  // The connection is still usable for the station's own rows.
  expect_counts(push(*st, "st-a", batch), 2, 0, 0);
}

TEST_F(CentralTest, UnregisteredIdIsRefused) {
  auto admin = setup_stations();
  auto st = connect(role_a_);
  const std::vector<OutboxRecord> batch = {record(1, "run", kRun1, "7", run_payload(7, kRun1))};
  auto r = push_batch(st, "ghost", batch);
  ASSERT_FALSE(r.ok());
  EXPECT_FALSE(r.error().transient);
  EXPECT_NE(r.error().message.find("refused station id 'ghost'"), std::string::npos)
      << r.error().message;
  EXPECT_NE(r.error().message.find("not registered"), std::string::npos) << r.error().message;
  // Through a role row-level security does not restrict (the owner), the
  // foreign key refuses it.
  auto as_admin = push_batch(admin, "ghost", batch);
  ASSERT_FALSE(as_admin.ok());
  EXPECT_FALSE(as_admin.error().transient);
  EXPECT_EQ(admin.last_sqlstate(), "23503");
  EXPECT_NE(as_admin.error().message.find("not registered"), std::string::npos)
      << as_admin.error().message;
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.records"), "0");
  EXPECT_EQ(scalar(admin, "SELECT count(*) FROM lab.relay_progress"), "0");
}

TEST_F(CentralTest, ABadRecordRollsBackTheWholeBatch) {
  auto admin = setup_stations();
  auto st = connect(role_a_);
  push(st, "st-a", {record(1, "run", kRun1, "7", run_payload(7, kRun1))});
  std::vector<OutboxRecord> batch = {
      record(2, "run", kRun1, "7", run_payload(7, kRun1, "changed")),
      record(3, "run", kRun2, "8", run_payload(8, kRun2)),
  };
  batch[1].payload_json = "{not json";
  auto r = push_batch(st, "st-a", batch);
  ASSERT_FALSE(r.ok());
  EXPECT_FALSE(r.error().transient);
  EXPECT_NE(r.error().message.find("outbox seq 2 to 3"), std::string::npos) << r.error().message;
  EXPECT_EQ(scalar(admin, "SELECT string_agg(payload->>'comment', ',') FROM lab.records"),
            "cold soak");
  EXPECT_EQ(scalar(admin, "SELECT last_seq || '/' || batches FROM lab.relay_progress"), "1/1");
}

TEST_F(CentralTest, StationSeesAndChangesOnlyItsOwnRows) {
  auto admin = setup_stations();
  auto a = connect(role_a_);
  auto b = connect(role_b_);
  push(a, "st-a", {record(1, "run", kRun1, "7", run_payload(7, kRun1))});
  push(b, "st-b", {record(1, "run", kRun2, "7", run_payload(7, kRun2))});
  EXPECT_EQ(scalar(a, "SELECT string_agg(station_id, ',') FROM lab.records"), "st-a");
  EXPECT_EQ(scalar(a, "SELECT string_agg(station_id, ',') FROM lab.relay_progress"), "st-a");
  auto upd = a.exec("UPDATE lab.records SET payload = '{}' WHERE station_id = 'st-b'");
  ASSERT_TRUE(upd.ok()) << upd.error().message;  // no row visible, none changed
  EXPECT_EQ(scalar(admin, "SELECT payload->>'comment' FROM lab.records WHERE station_id = 'st-b'"),
            "cold soak");
  auto del = a.exec("DELETE FROM lab.records");
  ASSERT_FALSE(del.ok());
  EXPECT_EQ(a.last_sqlstate(), "42501");
  auto views = a.exec("SELECT * FROM lab.runs");
  ASSERT_FALSE(views.ok()) << "stations do not read the views";
  EXPECT_EQ(a.last_sqlstate(), "42501");
}

TEST_F(CentralTest, ReaderReadsViewsButCannotWrite) {
  auto admin = setup_stations();
  auto s = add_reader(admin, role_reader_);
  ASSERT_TRUE(s.ok()) << s.error().message;
  ASSERT_TRUE(add_reader(admin, role_reader_).ok()) << "twice: no-op";
  EXPECT_EQ(scalar(admin, "SELECT pg_has_role($1, 'gyrotherm_reader', 'MEMBER')", {role_reader_}),
            "t");
  auto st = connect(role_a_);
  push(st, "st-a", {record(1, "run", kRun1, "7", run_payload(7, kRun1))});

  auto reader = connect(role_reader_);
  for (const char* view :
       {"runs", "run_duts", "segments", "table1", "allan", "fits", "scale_factor_fits",
        "scale_factor_temperature_fits", "events", "exports", "station_overview", "records",
        "stations", "relay_progress", "schema_migrations"}) {
    auto r = reader.exec(std::string("SELECT * FROM lab.") + view);
    EXPECT_TRUE(r.ok()) << view << ": " << (r.ok() ? "" : r.error().message);
  }
  EXPECT_EQ(scalar(reader, "SELECT count(*) FROM lab.runs"), "1");
  auto insert = reader.exec(
      "INSERT INTO lab.records(station_id, run_uuid, kind, local_id, outbox_seq, payload, "
      "station_committed_at) VALUES ('st-a', gen_random_uuid(), 'run', '99', 1, '{}', now())");
  ASSERT_FALSE(insert.ok());
  EXPECT_FALSE(insert.error().transient);
  EXPECT_EQ(reader.last_sqlstate(), "42501");
  const std::vector<OutboxRecord> batch = {record(2, "run", kRun2, "8", run_payload(8, kRun2))};
  auto pushed = push_batch(reader, "st-a", batch);
  ASSERT_FALSE(pushed.ok());
  EXPECT_EQ(reader.last_sqlstate(), "42501");
  EXPECT_NE(pushed.error().message.find("refused station id 'st-a' for role '" + role_reader_),
            std::string::npos)
      << pushed.error().message;
  auto update = reader.exec("UPDATE lab.stations SET description = 'x'");
  ASSERT_FALSE(update.ok());
  EXPECT_EQ(reader.last_sqlstate(), "42501");
}

// --- the views -------------------------------------------------------------

// Every view of docs/lab.md (the brief's list), its columns in order, typed.
TEST_F(CentralTest, ViewsHaveTheDocumentedColumnsAndTypes) {
  auto pg = connect();
  ASSERT_TRUE(migrate_central(pg).ok());
  const std::string t = "text", u = "uuid", i = "bigint", f = "double precision", j = "jsonb",
                    b = "boolean", ts = "timestamp with time zone";
  const std::vector<std::pair<std::string, std::vector<std::pair<std::string, std::string>>>>
      views = {
          {"runs",
           {{"station_id", t},
            {"run_uuid", u},
            {"local_run_id", i},
            {"schedule_name", t},
            {"state", t},
            {"started_utc", t},
            {"ended_utc", t},
            {"operator", t},
            {"comment", t},
            {"tags", j},
            {"dut_serials", j},
            {"time_scale", f},
            {"central_committed_at", ts}}},
          {"run_duts",
           {{"station_id", t},
            {"run_uuid", u},
            {"local_run_id", i},
            {"dut_serial", t},
            {"model", t},
            {"position", i},
            {"primary_axis", t},
            {"axes", j},
            {"rate_hz", f}}},
          {"segments",
           {{"station_id", t},
            {"run_uuid", u},
            {"local_segment_id", i},
            {"idx", i},
            {"kind", t},
            {"label", t},
            {"setpoint_c", f},
            {"state", t},
            {"t_start_s", f},
            {"t_end_s", f},
            {"table_mode", t},
            {"table_rate_dps", f},
            {"acquire_stop", t}}},
          {"table1", {{"station_id", t},          {"run_uuid", u},
                      {"dut_serial", t},          {"axis", t},
                      {"segment_id", i},          {"segment_index", i},
                      {"setpoint_c", f},          {"n", i},
                      {"duration_s", f},          {"temp_mean_c", f},
                      {"bias_mean_dph", f},       {"bias_std_dph", f},
                      {"bias_std_ma_dph", f},     {"bias_mean_earth_removed_dph", f},
                      {"earth_rate_dph", f},      {"ma_window", i},
                      {"computed_utc", t},        {"coverage", f},
                      {"longest_gap_s", f},       {"quality", t},
                      {"quality_reasons", j},     {"bias_u_dph", f},
                      {"bias_u_expanded_dph", f}, {"bias_u_k", f},
                      {"bias_u_dof", f},          {"bias_u_floor_dph", f},
                      {"bias_u_random_walk", b},  {"bias_u_note", t}}},
          {"allan",
           {{"station_id", t},
            {"run_uuid", u},
            {"local_id", i},
            {"dut_serial", t},
            {"axis", t},
            {"segment_index", i},
            {"taus", t},
            {"n_samples", i},
            {"angle_random_walk_dprh", f},
            {"bias_instability_dph", f},
            {"bias_instability_tau_s", f},
            {"rate_random_walk_dphprh", f},
            {"curve", j},
            {"computed_utc", t},
            {"coverage", f},
            {"longest_gap_s", f},
            {"quality", t},
            {"quality_reasons", j}}},
          {"fits",
           {{"station_id", t},
            {"run_uuid", u},
            {"fit_local_id", i},
            {"model", t},
            {"form", t},
            {"dut_serial", t},
            {"axis", t},
            {"n", i},
            {"coefficients", j},
            {"standard_errors", j},
            {"residual_std_dph", f},
            {"r_squared", f},
            {"computed_utc", t},
            {"coverage", f},
            {"longest_gap_s", f},
            {"quality", t},
            {"quality_reasons", j}}},
          {"scale_factor_fits",
           {{"station_id", t},
            {"run_uuid", u},
            {"dut_serial", t},
            {"axis", t},
            {"sf_sequence", i},
            {"temperature_c", f},
            {"k", f},
            {"k_se", f},
            {"bias_dps", f},
            {"nonlinearity_ppm", f},
            {"asymmetry_ppm", f},
            {"repeatability_ppm", f},
            {"n_points", i},
            {"coverage", f},
            {"longest_gap_s", f},
            {"quality", t},
            {"quality_reasons", j}}},
          {"scale_factor_temperature_fits",
           {{"station_id", t},
            {"run_uuid", u},
            {"dut_serial", t},
            {"axis", t},
            {"poly_order", i},
            {"t_centre_c", f},
            {"k_ppm_per_c", f},
            {"bias_dph_per_c", f},
            {"k_coeffs", j},
            {"bias_coeffs", j}}},
          {"events",
           {{"station_id", t},
            {"run_uuid", u},
            {"local_id", i},
            {"t_s", f},
            {"wall_utc", t},
            {"kind", t},
            {"from_state", t},
            {"to_state", t},
            {"message", t}}},
          {"exports",
           {{"station_id", t},
            {"local_id", i},
            {"kind", t},
            {"state", t},
            {"directory", t},
            {"files", j},
            {"started_utc", t},
            {"finished_utc", t},
            {"message", t}}},
          {"station_overview",
           {{"station_id", t},
            {"db_role", t},
            {"description", t},
            {"registered_at", ts},
            {"last_seq", i},
            {"last_batch_at", ts},
            {"batches", i},
            {"records", i},
            {"runs", i}}},
      };
  for (const auto& [view, columns] : views) {
    auto r = pg.exec_params(
        "SELECT column_name, data_type FROM information_schema.columns "
        "WHERE table_schema = 'lab' AND table_name = $1 ORDER BY ordinal_position",
        {view});
    ASSERT_TRUE(r.ok()) << r.error().message;
    std::vector<std::pair<std::string, std::string>> found;
    for (const auto& row : r->rows) found.emplace_back(*row[0], *row[1]);
    EXPECT_EQ(found, columns) << "lab." << view;
  }
  EXPECT_EQ(scalar(pg, "SELECT count(*) FROM information_schema.views WHERE table_schema = 'lab'"),
            std::to_string(views.size()));
}

// A realistic relay of one station: every relayed kind with payloads as
// the outbox triggers write them (json_object of every column, *_json
// embedded), read back through the views as a reader.
TEST_F(CentralTest, ViewsReadRealisticPayloads) {
  auto admin = setup_stations();
  ASSERT_TRUE(add_reader(admin, role_reader_).ok());
  auto st = connect(role_a_);
  int64_t seq = 0;
  std::vector<OutboxRecord> batch;
  auto add = [&](const char* kind, const std::string& uuid, const std::string& local_id,
                 const json& payload) {
    batch.push_back(record(++seq, kind, uuid, local_id, payload));
  };
  add("dut", kNil, "3",
      {{"id", 3},
       {"serial", "17-0042"},
       {"model", "KVH 1750"},
       {"first_seen_utc", "2026-02-01T10:00:00Z"}});
  add("dut", kNil, "4",
      {{"id", 4}, {"serial", "T-9"}, {"model", ""}, {"first_seen_utc", "2026-02-01T10:00:00Z"}});
  add("run", kRun1, "7", run_payload(7, kRun1));
  json run8 = run_payload(8, kRun2);
  run8["state"] = "acquiring";
  run8["ended_utc"] = nullptr;
  run8["time_scale"] = 60.0;
  add("run", kRun2, "8", run8);
  add("run_dut", kRun1, "7/3",
      {{"run_id", 7},
       {"dut_id", 3},
       {"position", 0},
       {"primary_axis", "z"},
       {"axes_json", json::array({"x", "y", "z"})},
       {"rate_hz", 1000.0},
       {"seq_modulo", 128},
       {"config_json", {{"serial", "17-0042"}, {"port", "/dev/ttyUSB0"}}}});
  add("run_dut", kRun1, "7/4",
      {{"run_id", 7},
       {"dut_id", 4},
       {"position", 1},
       {"primary_axis", "x"},
       {"axes_json", json::array({"x"})},
       {"rate_hz", nullptr},
       {"seq_modulo", 0},
       {"config_json", json::object()}});
  add("channel", kRun1, "31",
      {{"id", 31},
       {"run_id", 7},
       {"dut_id", 3},
       {"idx", 0},
       {"name", "gyro_x"},
       {"unit", "deg/h"},
       {"kind", "rate"},
       {"axis", "x"},
       {"scale", 1.0}});
  add("segment", kRun1, "11",
      {{"id", 11},
       {"run_id", 7},
       {"idx", 2},
       {"kind", "soak"},
       {"label", "-40 C"},
       {"setpoint_c", -40.0},
       {"ramp_rate_c_per_min", nullptr},
       {"t_start_s", 3600.5},
       {"t_settled_s", 4000.0},
       {"t_acquire_start_s", 4000.0},
       {"t_acquire_end_s", 7200.0},
       {"t_end_s", 7200.25},
       {"paused_s", 0.0},
       {"state", "completed"},
       {"table_mode", "rate"},
       {"table_rate_dps", -10.5},
       {"table_position_deg", nullptr},
       {"table_mean_rate_dps", -10.4999},
       {"table_mean_position_deg", nullptr},
       {"turns", 88},
       {"dwell_s", 3016.0},
       {"sf_sequence", 1},
       {"sf_repetition", 2}});
  add("table1", kRun1, "11/17-0042/z",
      {{"segment_id", 11},
       {"run_id", 7},
       {"dut_serial", "17-0042"},
       {"axis", "z"},
       {"segment_index", 2},
       {"setpoint_c", -40.0},
       {"n", 3600},
       {"duration_s", 3600.0},
       {"temp_mean_c", -39.87},
       {"bias_mean_dph", 0.512},
       {"bias_std_dph", 0.0123},
       {"bias_std_ma_dph", 0.0041},
       {"bias_mean_earth_removed_dph", -9.488},
       {"bin_s", 1.0},
       {"ma_window", 100},
       {"earth_rate_dph", 10.0},
       {"t_from_s", 4000.0},
       {"t_to_s", 7200.0},
       {"computed_utc", "2026-03-02T06:10:00Z"},
       {"bias_u_dph", 0.00031},
       {"bias_u_expanded_dph", 0.00062},
       {"bias_u_k", 2.01},
       {"bias_u_dof", 48.5},
       {"bias_u_floor_dph", 0.0001},
       {"bias_u_random_walk", 1},
       {"bias_u_note", ""}});
  add("allan", kRun1, "5",
      {{"id", 5},
       {"run_id", 7},
       {"segment_id", 11},
       {"segment_index", 2},
       {"t_from_s", 4000.0},
       {"t_to_s", 7200.0},
       {"taus", "octave"},
       {"tau0_s", 0.001},
       {"n_samples", 3200000},
       {"curve_json",
        {{"tau_s", json::array({1.0, 2.0})},
         {"adev_dph", json::array({0.1, 0.07})},
         {"adev_lo_dph", json::array({0.09, 0.06})},
         {"adev_hi_dph", json::array({0.11, 0.08})}}},
       {"angle_random_walk_dprh", 0.0021},
       {"bias_instability_dph", 0.05},
       {"bias_instability_tau_s", 120.0},
       {"rate_random_walk_dphprh", nullptr},
       {"bias_instability_method", "minimum / 0.664"},
       {"inputs_json", json::object({{"bin_s", 1.0}})},
       {"computed_utc", "2026-03-02T06:11:00Z"},
       {"dut_serial", "17-0042"},
       {"axis", "z"}});
  add("fit", kNil, "9",
      {{"id", 9},
       {"model", "T4+R1+G1"},
       {"form", "paper"},
       {"n", 1200},
       {"coefficients_json", {{"T1", 0.01}, {"G1", -0.002}}},
       {"standard_errors_json", {{"T1", 0.001}, {"G1", 0.0002}}},
       {"residual_std_dph", 0.03},
       {"r_squared", 0.987},
       {"inputs_json", json::object({{"windows", json::array()}})},
       {"computed_utc", "2026-03-02T07:00:00Z"},
       {"dut_serial", "17-0042"},
       {"axis", "z"}});
  add("fit_run", kRun1, "7/9", {{"run_id", 7}, {"fit_id", 9}});
  add("fit_run", kRun2, "8/9", {{"run_id", 8}, {"fit_id", 9}});
  add("sf_point", kRun1, "40",
      {{"id", 40},
       {"run_id", 7},
       {"segment_id", 11},
       {"sf_sequence", 1},
       {"repetition", 2},
       {"rate_dps", -10.5},
       {"measured_rate_dps", -10.4999},
       {"output_dps", -10.501},
       {"n", 3016000},
       {"temperature_c", 25.1},
       {"duration_s", 3016.0},
       {"turns", 88.0},
       {"dut_serial", "17-0042"},
       {"axis", "z"}});
  add("sf_fit", kRun1, "7/1/17-0042/z",
      {{"run_id", 7},
       {"sf_sequence", 1},
       {"dut_serial", "17-0042"},
       {"axis", "z"},
       {"temperature_c", 25.1},
       {"k", 1.000123},
       {"k_se", 1e-6},
       {"bias_dps", 0.0003},
       {"nonlinearity_ppm", 12.5},
       {"nonlinearity_fs_ppm", 3.1},
       {"asymmetry_ppm", nullptr},
       {"repeatability_ppm", 4.2},
       {"n_points", 14},
       {"created_utc", "2026-03-02T07:05:00Z"},
       {"guard_s", 1.0},
       {"coverage_samples", 600},
       {"coverage_expected", 10000.0},
       {"coverage", 0.06},
       {"longest_gap_s", 540.25},
       {"quality", "flagged"},
       {"quality_reasons_json", json::array({"coverage 6.0 % (600 of 10000 samples expected) "
                                             "is under 99 %"})}});
  add("sf_temperature_fit", kRun1, "7/17-0042/z",
      {{"run_id", 7},
       {"dut_serial", "17-0042"},
       {"axis", "z"},
       {"poly_order", 2},
       {"t_centre_c", 20.0},
       {"k_coeffs_json", json::array({1.0001, 2e-6, 1e-9})},
       {"bias_coeffs_json", json::array({0.0003, 1e-5, 0.0})},
       {"k_ppm_per_c", 2.0},
       {"bias_dph_per_c", 0.036},
       {"created_utc", "2026-03-02T07:06:00Z"}});
  add("event", kRun1, "100",
      {{"id", 100},
       {"run_id", 7},
       {"t_s", 12.5},
       {"wall_utc", "2026-03-01T20:00:12Z"},
       {"kind", "state"},
       {"from_state", "ramping"},
       {"to_state", "settling"},
       {"message", "stable within 0.1 C"}});
  add("event", kNil, "101",
      {{"id", 101},
       {"run_id", nullptr},
       {"t_s", 0.0},
       {"wall_utc", "2026-03-01T19:59:00Z"},
       {"kind", "info"},
       {"from_state", nullptr},
       {"to_state", nullptr},
       {"message", "daemon started"}});
  add("export", kNil, "2",
      {{"id", 2},
       {"kind", "nightly"},
       {"slot_unix_s", 1772416800.0},
       {"slot_local", "2026-03-02 03:00 CET"},
       {"state", "done"},
       {"directory", "/var/lib/gyrotherm/exports/2026-03-02"},
       {"files_json", json::array({"table1.csv", "report.html"})},
       {"started_utc", "2026-03-02T02:00:00Z"},
       {"finished_utc", "2026-03-02T02:00:09Z"},
       {"message", "2 runs"}});
  add("export_run", kRun1, "2/7", {{"export_id", 2}, {"run_id", 7}});
  // Odd values: a number column holding text, an infinite REAL as SQLite writes it.
  add("table1", kRun1, "11/17-0042/x",
      {{"segment_id", 11},
       {"run_id", 7},
       {"dut_serial", "17-0042"},
       {"axis", "x"},
       {"segment_index", 2},
       {"setpoint_c", "n/a"},
       {"n", 3600},
       {"computed_utc", "x"}});
  batch.back().payload_json =
      R"({"segment_id":11,"run_id":7,"dut_serial":"17-0042","axis":"x","segment_index":2,)"
      R"("setpoint_c":"n/a","n":3600,"bias_std_dph":9.0e+999,"computed_utc":"x"})";
  expect_counts(push(st, "st-a", batch), static_cast<int64_t>(batch.size()), 0, 0);

  auto reader = connect(role_reader_);
  auto runs = rows(reader, "SELECT * FROM lab.runs ORDER BY local_run_id");
  ASSERT_EQ(runs.size(), 2u);
  EXPECT_EQ(runs[0]["station_id"], "st-a");
  EXPECT_EQ(runs[0]["run_uuid"], kRun1);
  EXPECT_EQ(runs[0]["local_run_id"], "7");
  EXPECT_EQ(runs[0]["schedule_name"], "paper-cold");
  EXPECT_EQ(runs[0]["state"], "completed");
  EXPECT_EQ(runs[0]["started_utc"], "2026-03-01T20:00:00Z");
  EXPECT_EQ(runs[0]["ended_utc"], "2026-03-02T06:00:00Z");
  EXPECT_EQ(runs[0]["operator"], "ana");
  EXPECT_EQ(runs[0]["comment"], "cold soak");
  EXPECT_EQ(runs[0]["tags"], R"(["night", "cold"])");
  EXPECT_EQ(runs[0]["dut_serials"], R"(["17-0042", "17-0043"])");
  EXPECT_EQ(runs[0]["time_scale"], "1");
  EXPECT_EQ(runs[1]["ended_utc"], "<null>");
  EXPECT_EQ(runs[1]["time_scale"], "60");
  EXPECT_EQ(runs[1]["state"], "acquiring");

  auto duts = rows(reader, "SELECT * FROM lab.run_duts ORDER BY position");
  ASSERT_EQ(duts.size(), 2u);
  EXPECT_EQ(duts[0]["run_uuid"], kRun1);
  EXPECT_EQ(duts[0]["local_run_id"], "7");
  EXPECT_EQ(duts[0]["dut_serial"], "17-0042");
  EXPECT_EQ(duts[0]["model"], "KVH 1750");
  EXPECT_EQ(duts[0]["position"], "0");
  EXPECT_EQ(duts[0]["primary_axis"], "z");
  EXPECT_EQ(duts[0]["axes"], R"(["x", "y", "z"])");
  EXPECT_EQ(duts[0]["rate_hz"], "1000");
  EXPECT_EQ(duts[1]["dut_serial"], "T-9");
  EXPECT_EQ(duts[1]["rate_hz"], "<null>");

  auto segs = rows(reader, "SELECT * FROM lab.segments");
  ASSERT_EQ(segs.size(), 1u);
  EXPECT_EQ(segs[0]["local_segment_id"], "11");
  EXPECT_EQ(segs[0]["idx"], "2");
  EXPECT_EQ(segs[0]["kind"], "soak");
  EXPECT_EQ(segs[0]["label"], "-40 C");
  EXPECT_EQ(segs[0]["setpoint_c"], "-40");
  EXPECT_EQ(segs[0]["state"], "completed");
  EXPECT_EQ(segs[0]["t_start_s"], "3600.5");
  EXPECT_EQ(segs[0]["t_end_s"], "7200.25");
  EXPECT_EQ(segs[0]["table_mode"], "rate");
  EXPECT_EQ(segs[0]["table_rate_dps"], "-10.5");

  auto t1 = rows(reader, "SELECT * FROM lab.table1 ORDER BY axis DESC");
  ASSERT_EQ(t1.size(), 2u);
  EXPECT_EQ(t1[0]["dut_serial"], "17-0042");
  EXPECT_EQ(t1[0]["axis"], "z");
  EXPECT_EQ(t1[0]["segment_id"], "11");
  EXPECT_EQ(t1[0]["segment_index"], "2");
  EXPECT_EQ(t1[0]["setpoint_c"], "-40");
  EXPECT_EQ(t1[0]["n"], "3600");
  EXPECT_EQ(t1[0]["duration_s"], "3600");
  EXPECT_EQ(t1[0]["temp_mean_c"], "-39.87");
  EXPECT_EQ(t1[0]["bias_mean_dph"], "0.512");
  EXPECT_EQ(t1[0]["bias_std_dph"], "0.0123");
  EXPECT_EQ(t1[0]["bias_std_ma_dph"], "0.0041");
  EXPECT_EQ(t1[0]["bias_mean_earth_removed_dph"], "-9.488");
  EXPECT_EQ(t1[0]["earth_rate_dph"], "10");
  EXPECT_EQ(t1[0]["ma_window"], "100");
  EXPECT_EQ(t1[0]["computed_utc"], "2026-03-02T06:10:00Z");
  EXPECT_EQ(t1[0]["bias_u_dph"], "0.00031");
  EXPECT_EQ(t1[0]["bias_u_expanded_dph"], "0.00062");
  EXPECT_EQ(t1[0]["bias_u_k"], "2.01");
  EXPECT_EQ(t1[0]["bias_u_dof"], "48.5");
  EXPECT_EQ(t1[0]["bias_u_floor_dph"], "0.0001");
  EXPECT_EQ(t1[0]["bias_u_random_walk"], "t");
  EXPECT_EQ(t1[0]["bias_u_note"], "");
  // A row relayed before the station's v13: no uncertainty.
  EXPECT_EQ(t1[1]["bias_u_dph"], "<null>");
  EXPECT_EQ(t1[1]["bias_u_note"], "");
  EXPECT_EQ(t1[1]["setpoint_c"], "<null>") << "text in a number column reads as NULL";
  EXPECT_EQ(t1[1]["bias_std_dph"], "Infinity");
  EXPECT_EQ(t1[1]["duration_s"], "<null>");

  auto allan = rows(reader, "SELECT * FROM lab.allan");
  ASSERT_EQ(allan.size(), 1u);
  EXPECT_EQ(allan[0]["local_id"], "5");
  EXPECT_EQ(allan[0]["dut_serial"], "17-0042");
  EXPECT_EQ(allan[0]["taus"], "octave");
  EXPECT_EQ(allan[0]["n_samples"], "3200000");
  EXPECT_EQ(allan[0]["angle_random_walk_dprh"], "0.0021");
  EXPECT_EQ(allan[0]["bias_instability_dph"], "0.05");
  EXPECT_EQ(allan[0]["bias_instability_tau_s"], "120");
  EXPECT_EQ(allan[0]["rate_random_walk_dphprh"], "<null>");
  EXPECT_EQ(scalar(reader, "SELECT curve->'adev_dph'->>1 FROM lab.allan"), "0.07");

  auto fits = rows(reader, "SELECT * FROM lab.fits ORDER BY run_uuid");
  ASSERT_EQ(fits.size(), 2u) << "one row per fit and run";
  EXPECT_EQ(fits[0]["run_uuid"], kRun1);
  EXPECT_EQ(fits[1]["run_uuid"], kRun2);
  EXPECT_EQ(fits[0]["fit_local_id"], "9");
  EXPECT_EQ(fits[0]["model"], "T4+R1+G1");
  EXPECT_EQ(fits[0]["form"], "paper");
  EXPECT_EQ(fits[0]["n"], "1200");
  EXPECT_EQ(fits[0]["residual_std_dph"], "0.03");
  EXPECT_EQ(fits[0]["r_squared"], "0.987");
  EXPECT_EQ(scalar(reader, "SELECT (coefficients->>'G1')::float8 FROM lab.fits LIMIT 1"), "-0.002");

  auto sf = rows(reader, "SELECT * FROM lab.scale_factor_fits");
  ASSERT_EQ(sf.size(), 1u);
  EXPECT_EQ(sf[0]["sf_sequence"], "1");
  EXPECT_EQ(sf[0]["temperature_c"], "25.1");
  EXPECT_EQ(sf[0]["k"], "1.000123");
  EXPECT_EQ(sf[0]["k_se"], "1e-06");
  EXPECT_EQ(sf[0]["bias_dps"], "0.0003");
  EXPECT_EQ(sf[0]["nonlinearity_ppm"], "12.5");
  EXPECT_EQ(sf[0]["asymmetry_ppm"], "<null>");
  EXPECT_EQ(sf[0]["repeatability_ppm"], "4.2");
  EXPECT_EQ(sf[0]["n_points"], "14");
  // The result's quality (station schema v11; lab schema v2).
  EXPECT_EQ(sf[0]["quality"], "flagged");
  EXPECT_EQ(sf[0]["coverage"], "0.06");
  EXPECT_EQ(sf[0]["longest_gap_s"], "540.25");
  EXPECT_EQ(sf[0]["quality_reasons"],
            R"(["coverage 6.0 % (600 of 10000 samples expected) is under 99 %"])");
  // A row relayed before the station's v11 has none: not assessed.
  EXPECT_EQ(t1[0]["quality"], "unassessed");
  EXPECT_EQ(t1[0]["quality_reasons"], "[]");
  EXPECT_EQ(t1[0]["coverage"], "<null>");
  EXPECT_EQ(fits[0]["quality"], "unassessed");
  EXPECT_EQ(allan[0]["quality"], "unassessed");

  auto sft = rows(reader, "SELECT * FROM lab.scale_factor_temperature_fits");
  ASSERT_EQ(sft.size(), 1u);
  EXPECT_EQ(sft[0]["poly_order"], "2");
  EXPECT_EQ(sft[0]["t_centre_c"], "20");
  EXPECT_EQ(sft[0]["k_ppm_per_c"], "2");
  EXPECT_EQ(sft[0]["bias_dph_per_c"], "0.036");
  EXPECT_EQ(sft[0]["k_coeffs"], "[1.0001, 0.000002, 0.000000001]");
  EXPECT_EQ(scalar(reader,
                   "SELECT jsonb_array_length(bias_coeffs) FROM "
                   "lab.scale_factor_temperature_fits"),
            "3");

  auto events = rows(reader, "SELECT * FROM lab.events ORDER BY local_id");
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[0]["run_uuid"], kRun1);
  EXPECT_EQ(events[0]["t_s"], "12.5");
  EXPECT_EQ(events[0]["kind"], "state");
  EXPECT_EQ(events[0]["from_state"], "ramping");
  EXPECT_EQ(events[0]["to_state"], "settling");
  EXPECT_EQ(events[0]["message"], "stable within 0.1 C");
  EXPECT_EQ(events[1]["run_uuid"], "<null>") << "outside a run";
  EXPECT_EQ(events[1]["from_state"], "<null>");
  EXPECT_EQ(events[1]["wall_utc"], "2026-03-01T19:59:00Z");

  auto exports = rows(reader, "SELECT * FROM lab.exports");
  ASSERT_EQ(exports.size(), 1u);
  EXPECT_EQ(exports[0]["local_id"], "2");
  EXPECT_EQ(exports[0]["kind"], "nightly");
  EXPECT_EQ(exports[0]["state"], "done");
  EXPECT_EQ(exports[0]["directory"], "/var/lib/gyrotherm/exports/2026-03-02");
  EXPECT_EQ(exports[0]["files"], R"(["table1.csv", "report.html"])");
  EXPECT_EQ(exports[0]["finished_utc"], "2026-03-02T02:00:09Z");
  EXPECT_EQ(exports[0]["message"], "2 runs");

  auto overview = rows(reader, "SELECT * FROM lab.station_overview ORDER BY station_id");
  ASSERT_EQ(overview.size(), 2u);
  EXPECT_EQ(overview[0]["station_id"], "st-a");
  EXPECT_EQ(overview[0]["db_role"], role_a_);
  EXPECT_EQ(overview[0]["description"], "bench A");
  EXPECT_EQ(overview[0]["last_seq"], std::to_string(seq));
  EXPECT_EQ(overview[0]["batches"], "1");
  EXPECT_EQ(overview[0]["records"], std::to_string(batch.size()));
  EXPECT_EQ(overview[0]["runs"], "2");
  EXPECT_NE(overview[0]["last_batch_at"], "<null>");
  EXPECT_EQ(overview[1]["station_id"], "st-b");
  EXPECT_EQ(overview[1]["last_batch_at"], "<null>") << "never relayed";
  EXPECT_EQ(overview[1]["last_seq"], "0");
  EXPECT_EQ(overview[1]["runs"], "0");

  // A DUT deleted on the station: its run_duts rows lose their serial, the
  // run stays.
  push(st, "st-a", {tombstone(++seq, "dut", kNil, "4")});
  EXPECT_EQ(scalar(reader, "SELECT dut_serial IS NULL FROM lab.run_duts WHERE position = 1"), "t");
}

// --- outages ---------------------------------------------------------------

TEST_F(CentralTest, ServerStoppedMidSessionIsTransientThenANewConnectionWorks) {
  auto admin = setup_stations();
  const std::string secret = "Pa55-w0rd-not-shown";
  const std::string info = conninfo(role_a_) + " password=" + secret;
  auto st = PgConnection::connect(info);
  ASSERT_TRUE(st.ok()) << st.error().message;
  expect_counts(push(*st, "st-a", {record(1, "run", kRun1, "7", run_payload(7, kRun1))}), 1, 0, 0);

  ASSERT_TRUE(cluster().stop());
  const std::vector<OutboxRecord> batch = {record(2, "run", kRun2, "8", run_payload(8, kRun2))};
  auto lost = push_batch(*st, "st-a", batch);
  ASSERT_FALSE(lost.ok());
  EXPECT_TRUE(lost.error().transient) << lost.error().message;
  EXPECT_EQ(lost.error().message.find(secret), std::string::npos) << lost.error().message;
  EXPECT_FALSE(st->ok());
  auto down = PgConnection::connect(info, 2);
  ASSERT_FALSE(down.ok());
  EXPECT_TRUE(down.error().transient);
  EXPECT_EQ(down.error().message.find(secret), std::string::npos) << down.error().message;

  ASSERT_TRUE(cluster().start()) << cluster().log();
  auto again = PgConnection::connect(info);
  ASSERT_TRUE(again.ok()) << again.error().message;
  expect_counts(push(*again, "st-a", batch), 1, 0, 0);
  auto admin2 = connect();
  EXPECT_EQ(scalar(admin2, "SELECT last_seq || '/' || batches FROM lab.relay_progress"), "2/2");
}

}  // namespace
}  // namespace gyrotherm::lab

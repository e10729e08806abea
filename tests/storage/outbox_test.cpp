// The lab outbox (schema v10): run uuids, the triggers that queue every
// change of a relayed table in the change's own transaction once the
// database is bound to a lab station, lab_bind with the station's history,
// what the relay reads (outbox_batch), acknowledges (outbox_ack) and
// reports (outbox_stats), several connections writing at once, and the v10
// migration of databases with data.
//
// The relayed tables, their kinds, keys and runs are written out here from
// the issue's contract (not taken from outbox.cpp), so the tests check the
// triggers against the specification rather than against themselves.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <regex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "migrations.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using nlohmann::json;
using testing::integrity_ok;
using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

const std::string kNil(kNilUuid);
const std::regex kUuidV4(R"([0-9a-f]{8}-[0-9a-f]{4}-4[0-9a-f]{3}-[89ab][0-9a-f]{3}-[0-9a-f]{12})");

enum class RunOf { kSelf, kRunId, kNone };
struct Relayed {
  std::string table;
  std::string kind;
  std::vector<std::string> key;
  RunOf run;
};
// The contract's table (issue 19 brief, "Local side").
const std::vector<Relayed> kRelayed = {
    {"runs", "run", {"id"}, RunOf::kSelf},
    {"segments", "segment", {"id"}, RunOf::kRunId},
    {"events", "event", {"id"}, RunOf::kRunId},
    {"segment_stats", "table1", {"segment_id", "dut_serial", "axis"}, RunOf::kRunId},
    {"allan", "allan", {"id"}, RunOf::kRunId},
    {"fits", "fit", {"id"}, RunOf::kNone},
    {"fit_runs", "fit_run", {"run_id", "fit_id"}, RunOf::kRunId},
    {"exports", "export", {"id"}, RunOf::kNone},
    {"export_runs", "export_run", {"export_id", "run_id"}, RunOf::kRunId},
    {"scale_factor_points", "sf_point", {"id"}, RunOf::kRunId},
    {"scale_factor_fits", "sf_fit", {"run_id", "sf_sequence", "dut_serial", "axis"}, RunOf::kRunId},
    {"scale_factor_temperature_fits",
     "sf_temperature_fit",
     {"run_id", "dut_serial", "axis"},
     RunOf::kRunId},
    {"duts", "dut", {"id"}, RunOf::kNone},
    {"run_duts", "run_dut", {"run_id", "dut_id"}, RunOf::kRunId},
    {"channels", "channel", {"id"}, RunOf::kRunId},
};
const std::set<std::string> kRunsNotRelayed = {"resume_json", "checkpoint_wall_unix_s",
                                               "config_toml"};

const Relayed& relayed_kind(const std::string& kind) {
  for (const Relayed& r : kRelayed) {
    if (r.kind == kind) return r;
  }
  ADD_FAILURE() << "unknown kind " << kind;
  std::abort();
}

struct OutboxRow {
  int64_t seq = 0;
  std::string kind, run_uuid, local_id;
  int64_t deleted = 0;
  std::string payload;
  double committed_unix_s = 0;
};

std::vector<OutboxRow> outbox_rows(sqlite3* db, int64_t after_seq = 0) {
  sqlite3_stmt* st = nullptr;
  EXPECT_EQ(sqlite3_prepare_v2(db,
                               "SELECT seq, kind, run_uuid, local_id, deleted, payload, "
                               "committed_unix_s FROM outbox WHERE seq > ? ORDER BY seq",
                               -1, &st, nullptr),
            SQLITE_OK)
      << sqlite3_errmsg(db);
  sqlite3_bind_int64(st, 1, after_seq);
  std::vector<OutboxRow> out;
  while (sqlite3_step(st) == SQLITE_ROW) {
    OutboxRow r;
    r.seq = sqlite3_column_int64(st, 0);
    r.kind = reinterpret_cast<const char*>(sqlite3_column_text(st, 1));
    r.run_uuid = reinterpret_cast<const char*>(sqlite3_column_text(st, 2));
    r.local_id = reinterpret_cast<const char*>(sqlite3_column_text(st, 3));
    r.deleted = sqlite3_column_int64(st, 4);
    r.payload = reinterpret_cast<const char*>(sqlite3_column_text(st, 5));
    r.committed_unix_s = sqlite3_column_double(st, 6);
    out.push_back(std::move(r));
  }
  sqlite3_finalize(st);
  return out;
}

// Reads the outbox rows written since the last call.
class OutboxCursor {
 public:
  explicit OutboxCursor(Database& db) : db_(db) {
    auto all = outbox_rows(db.handle());
    if (!all.empty()) mark_ = all.back().seq;
  }
  std::vector<OutboxRow> take() {
    auto rows = outbox_rows(db_.handle(), mark_);
    if (!rows.empty()) mark_ = rows.back().seq;
    return rows;
  }

 private:
  Database& db_;
  int64_t mark_ = 0;
};

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::string cur;
  for (char c : s) {
    if (c == sep) {
      out.push_back(cur);
      cur.clear();
    } else {
      cur += c;
    }
  }
  out.push_back(cur);
  return out;
}

std::string sql_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) {
    if (c == '\'') out += '\'';
    out += c;
  }
  return out + "'";
}

// The WHERE clause selecting the row an outbox row's local_id names.
std::string where_key(const Relayed& r, const std::string& local_id) {
  const auto parts = split(local_id, '/');
  EXPECT_EQ(parts.size(), r.key.size()) << r.kind << " local_id " << local_id;
  std::string out;
  for (std::size_t i = 0; i < r.key.size() && i < parts.size(); ++i) {
    if (i > 0) out += " AND ";
    out += fmt::format("CAST({} AS TEXT) = {}", r.key[i], sql_quote(parts[i]));
  }
  return out;
}

// local_id of the row `where` selects, from its key columns (the contract:
// their text joined by '/').
std::string expected_local_id(sqlite3* db, const Relayed& r, const std::string& where) {
  std::string expr;
  for (std::size_t i = 0; i < r.key.size(); ++i) {
    if (i > 0) expr += " || '/' || ";
    expr += fmt::format("CAST({} AS TEXT)", r.key[i]);
  }
  return query_text(db, fmt::format("SELECT {} FROM {} WHERE {}", expr, r.table, where));
}

std::string expected_run_uuid(sqlite3* db, const Relayed& r, const std::string& where) {
  switch (r.run) {
    case RunOf::kSelf:
      return query_text(db, fmt::format("SELECT uuid FROM runs WHERE {}", where));
    case RunOf::kRunId:
      return query_text(db, fmt::format("SELECT coalesce((SELECT uuid FROM runs WHERE id = "
                                        "t.run_id), '{}') FROM {} t WHERE {}",
                                        kNil, r.table, where));
    case RunOf::kNone:
      break;
  }
  return kNil;
}

// The payload is the row: one member per column (runs: but the three
// that stay at the station), integers and text as stored, REAL values
// exactly (they parse back to the same double), the infinities as
// "Infinity"/"-Infinity", NULL as null, *_json columns embedded as JSON
// when they hold JSON.
::testing::AssertionResult payload_is_row(sqlite3* db, const Relayed& r, const std::string& where,
                                          const std::string& payload) {
  const json j = json::parse(payload, nullptr, false);
  if (j.is_discarded() || !j.is_object()) {
    return ::testing::AssertionFailure() << r.kind << ": payload is not a JSON object: " << payload;
  }
  sqlite3_stmt* st = nullptr;
  const std::string sql = fmt::format("SELECT * FROM {} WHERE {}", r.table, where);
  if (sqlite3_prepare_v2(db, sql.c_str(), -1, &st, nullptr) != SQLITE_OK) {
    return ::testing::AssertionFailure() << sql << ": " << sqlite3_errmsg(db);
  }
  if (sqlite3_step(st) != SQLITE_ROW) {
    sqlite3_finalize(st);
    return ::testing::AssertionFailure() << sql << ": no row";
  }
  auto failure = ::testing::AssertionFailure() << r.kind << " " << where << ": ";
  bool ok = true;
  std::size_t expected_members = 0;
  for (int c = 0; c < sqlite3_column_count(st); ++c) {
    const std::string name = sqlite3_column_name(st, c);
    if (r.table == "runs" && kRunsNotRelayed.count(name) != 0) {
      if (j.contains(name)) {
        ok = false;
        failure << name << " must not be relayed; ";
      }
      continue;
    }
    ++expected_members;
    if (!j.contains(name)) {
      ok = false;
      failure << name << " missing; ";
      continue;
    }
    const json& v = j[name];
    switch (sqlite3_column_type(st, c)) {
      case SQLITE_NULL:
        if (!v.is_null()) {
          ok = false;
          failure << name << " should be null, is " << v.dump() << "; ";
        }
        break;
      case SQLITE_INTEGER:
        if (!v.is_number_integer() || v.get<int64_t>() != sqlite3_column_int64(st, c)) {
          ok = false;
          failure << name << " = " << v.dump() << ", row " << sqlite3_column_int64(st, c) << "; ";
        }
        break;
      case SQLITE_FLOAT: {
        const double d = sqlite3_column_double(st, c);
        if (std::isinf(d)) {
          if (v != json(d > 0 ? "Infinity" : "-Infinity")) {
            ok = false;
            failure << name << " = " << v.dump() << ", row " << d << "; ";
          }
        } else if (!v.is_number() || v.get<double>() != d) {
          ok = false;
          failure << name << " = " << v.dump() << ", row " << fmt::format("{:.17g}", d) << "; ";
        }
        break;
      }
      default: {
        const std::string text = reinterpret_cast<const char*>(sqlite3_column_text(st, c));
        const bool embedded =
            name.size() > 5 && name.substr(name.size() - 5) == "_json" && json::accept(text);
        const json want = embedded ? json::parse(text) : json(text);
        if (v != want) {
          ok = false;
          failure << name << " = " << v.dump() << ", row " << want.dump() << "; ";
        }
      }
    }
  }
  sqlite3_finalize(st);
  if (j.size() != expected_members) {
    ok = false;
    failure << j.size() << " members for " << expected_members << " columns: " << payload;
  }
  return ok ? ::testing::AssertionSuccess() : failure;
}

// An outbox row that is not a tombstone: kind, run_uuid, local_id, payload
// all as the contract says for the row it names.
::testing::AssertionResult row_is_right(sqlite3* db, const OutboxRow& o) {
  const Relayed& r = relayed_kind(o.kind);
  if (o.deleted != 0) return ::testing::AssertionFailure() << o.kind << " is a tombstone";
  const std::string where = where_key(r, o.local_id);
  if (expected_local_id(db, r, where) != o.local_id) {
    return ::testing::AssertionFailure() << o.kind << " " << o.local_id << ": no such row";
  }
  const std::string uuid = expected_run_uuid(db, r, where);
  if (o.run_uuid != uuid) {
    return ::testing::AssertionFailure()
           << o.kind << " " << o.local_id << ": run_uuid " << o.run_uuid << ", want " << uuid;
  }
  return payload_is_row(db, r, where, o.payload);
}

std::map<std::string, int> kinds(const std::vector<OutboxRow>& rows, bool deleted = false) {
  std::map<std::string, int> out;
  for (const auto& r : rows) {
    if ((r.deleted != 0) == deleted) ++out[r.kind];
  }
  return out;
}

// ------------------------------------------------------------ fixtures

RunRecord outbox_run(const std::string& name = "campaign") {
  RunRecord r;
  r.schedule_name = name;
  r.state = "ramping";
  r.started_utc = "2026-11-21T05:38:43.120Z";
  r.orientation = "up";
  r.latitude_deg = 48.1;
  r.time_scale = 1.0;
  r.config_json = R"({"station":{"name":"lab-3"},"analysis":{"ma_window":101}})";
  r.metadata.operator_name = "ana";
  r.metadata.tags = {"campaign", "imu-3x"};
  r.metadata.dut_serials = {"17-0042"};
  return r;
}

RunDutRecord outbox_kvh(const std::string& serial, int position) {
  RunDutRecord d;
  d.position = position;
  d.dut.serial = serial;
  d.dut.model = "KVH 1750";
  d.dut.first_seen_utc = "2026-11-21T05:38:44.000Z";
  d.config_json = R"({"serial":")" + serial + R"(","protocol":"kvh1750"})";
  d.primary_axis = "z";
  d.axes = {"x", "y", "z"};
  d.rate_hz = 1000;
  d.seq_modulo = 128;
  for (const char* axis : {"x", "y", "z"}) {
    ChannelRecord c;
    c.index = static_cast<int>(d.channels.size());
    c.spec = ChannelSpec{std::string("gyro_") + axis, "deg/h", ChannelKind::kRate, axis,
                         0.2062648062470964};
    d.channels.push_back(std::move(c));
  }
  ChannelRecord t;
  t.index = 3;
  t.spec = ChannelSpec{"temp_c", "degC", ChannelKind::kTemperature, "", 1};
  d.channels.push_back(std::move(t));
  return d;
}

SegmentRecord a_segment(int64_t run, int index) {
  SegmentRecord s;
  s.run_id = run;
  s.index = index;
  s.kind = "soak";
  s.label = fmt::format("step {}: soak 20 °C", index + 1);
  s.setpoint_c = 20.0 + index;
  s.t_start_s = 100.0 * index;
  s.state = "running";
  return s;
}

SegmentStatsRecord stats_of(int64_t run, int64_t segment, int index, const std::string& serial,
                            const std::string& axis) {
  SegmentStatsRecord s;
  s.segment_id = segment;
  s.run_id = run;
  s.dut_serial = serial;
  s.axis = axis;
  s.segment_index = index;
  s.setpoint_c = 20.0;
  s.n = 7200;
  s.duration_s = 7200.0;
  s.temp_mean_c = 20.013;
  s.bias_mean_dph = 0.1 + 0.2;  // 0.30000000000000004: needs 17 digits
  s.bias_std_dph = 1.0 / 3.0;
  s.bias_std_ma_dph = 0.0012345678901234567;
  s.bias_mean_earth_removed_dph = -11.2;
  s.earth_rate_dph = 11.5;
  s.t_from_s = 600.0;
  s.t_to_s = 7800.0;
  s.computed_utc = "2026-11-21T07:00:00.000Z";
  return s;
}

AllanRecord allan_of(int64_t run, int64_t segment, const std::string& serial) {
  AllanRecord a;
  a.run_id = run;
  a.dut_serial = serial;
  a.axis = "z";
  a.segment_id = segment;
  a.segment_index = 0;
  a.t_from_s = 600;
  a.t_to_s = 7800;
  a.taus = "octave";
  a.tau0_s = 0.001;
  a.n_samples = 7'200'000;
  a.tau_s = {0.001, 0.002, 1.0 / 3.0};
  a.adev_dph = {0.1, 0.07, 0.01};
  a.adev_lo_dph = {0.09, 0.06, 0.009};
  a.adev_hi_dph = {0.11, 0.08, 0.011};
  a.angle_random_walk_dprh = 0.0123456789012345;
  a.bias_instability_dph = 0.0047619047619047615;
  a.bias_instability_tau_s = 512.0;
  a.inputs_json = R"({"windows":[[600,7800]]})";
  a.computed_utc = "2026-11-21T07:00:00.000Z";
  return a;
}

FitRecord fit_of(std::vector<int64_t> runs) {
  FitRecord f;
  f.run_ids = std::move(runs);
  f.model = "T4+R1+G1";
  f.form = "centered";
  f.n = 1234;
  f.coefficients_json = R"({"T1":0.5,"R1":-0.25})";
  f.standard_errors_json = R"({"T1":0.01,"R1":0.02})";
  f.residual_std_dph = 0.0031;
  f.r_squared = 0.987;
  f.inputs_json = R"({"bin_s":1})";
  return f;
}

struct ScaleFactor {
  std::vector<ScaleFactorPointRecord> points;
  std::vector<ScaleFactorFitRecord> fits;
  ScaleFactorTemperatureFitRecord temperature;
};

ScaleFactor scale_factor_of(double k) {
  ScaleFactor sf;
  for (double rate : {-10.0, 10.0}) {
    ScaleFactorPointRecord p;
    p.sf_sequence = 1;
    p.repetition = 1;
    p.rate_dps = rate;
    p.measured_rate_dps = rate * 1.000001;
    p.output_dps = rate * k;
    p.n = 500;
    p.temperature_c = 20.1;
    p.duration_s = 36;
    p.turns = 1;
    sf.points.push_back(p);
  }
  ScaleFactorFitRecord f;
  f.sf_sequence = 1;
  f.temperature_c = 20.1;
  f.k = k;
  f.k_se = 1e-7;
  f.bias_dps = 1e-4;
  f.n_points = 2;
  sf.fits.push_back(f);
  sf.temperature.order = 1;
  sf.temperature.t_centre_c = 20;
  sf.temperature.k_coeffs_json = "[1.0000123, 2.1e-6]";
  sf.temperature.bias_coeffs_json = "[0.0001, 0.0]";
  sf.temperature.k_ppm_per_c = 2.1;
  sf.temperature.bias_dph_per_c = 0.01;
  return sf;
}

// A station's worth of history through the API: two runs with a DUT each
// (the same gyro in both), segments with windows, events in and outside
// runs, Table I rows, Allan, a fit over both runs, a scale factor, an
// export. Returns the run ids.
std::vector<int64_t> write_history(Database& db) {
  std::vector<int64_t> runs;
  for (int i = 0; i < 2; ++i) {
    auto run = db.create_run(outbox_run(fmt::format("campaign-{}", i)));
    EXPECT_TRUE(run.ok()) << run.error().message;
    runs.push_back(*run);
    EXPECT_TRUE(db.add_run_dut(*run, outbox_kvh("17-0042", 0)).ok());
    std::vector<int64_t> segments;
    for (int k = 0; k < 2; ++k) {
      SegmentRecord s = a_segment(*run, k);
      s.id = *db.create_segment(s);
      s.windows = {{100.0 * k + 10, 100.0 * k + 90}};
      s.state = "completed";
      s.t_end_s = 100.0 * k + 95;
      EXPECT_TRUE(db.update_segment(s).ok());
      segments.push_back(s.id);
      EXPECT_TRUE(db.put_segment_stats(stats_of(*run, s.id, k, "17-0042", "z")).ok());
      EXPECT_TRUE(db.put_segment_stats(stats_of(*run, s.id, k, "17-0042", "x")).ok());
    }
    EventRecord e;
    e.run_id = *run;
    e.t_s = 12.5;
    e.kind = "state";
    e.from_state = "ramping";
    e.to_state = "settling";
    e.message = "ramping -> settling";
    EXPECT_TRUE(db.add_event(e).ok());
    EXPECT_TRUE(db.put_allan(allan_of(*run, segments[0], "17-0042")).ok());
    const ScaleFactor sf = scale_factor_of(1.0000123);
    EXPECT_TRUE(db.store_scale_factor(*run, sf.points, sf.fits, sf.temperature).ok());
    EXPECT_TRUE(db.set_run_state(*run, "completed", true).ok());
  }
  EventRecord station;
  station.kind = "info";
  station.message = "daemon started";
  EXPECT_TRUE(db.add_event(station).ok());
  EXPECT_TRUE(db.add_fit(fit_of(runs)).ok());
  ExportRecord x;
  x.kind = "manual";
  x.directory = "/home/tech/report";
  x.run_ids = runs;
  auto exp = db.begin_export(x);
  EXPECT_TRUE(exp.ok()) << exp.error().message;
  EXPECT_TRUE(db.finish_export(*exp, "done", {"report.html", "table1.csv"}, "2 runs").ok());
  return runs;
}

// ------------------------------------------------------------ run uuids

TEST(RunUuid, CreateRunGivesEachRunARandomVersion4Uuid) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  std::set<std::string> seen;
  for (int i = 0; i < 50; ++i) {
    const int64_t id = *db.create_run(outbox_run());
    auto run = db.run(id);
    ASSERT_TRUE(run.ok()) << run.error().message;
    EXPECT_TRUE(std::regex_match(run->uuid, kUuidV4)) << run->uuid;
    seen.insert(run->uuid);
  }
  EXPECT_EQ(seen.size(), 50u);
  auto runs = db.runs();
  ASSERT_TRUE(runs.ok());
  EXPECT_EQ((*runs)[7].uuid, db.run((*runs)[7].id)->uuid);

  // A uuid given is kept (a run known elsewhere); another form is refused,
  // and so is a uuid already taken.
  RunRecord given = outbox_run();
  given.uuid = "0f1e2d3c-4b5a-4978-8695-a4b3c2d1e0f9";
  const int64_t id = *db.create_run(given);
  EXPECT_EQ(db.run(id)->uuid, given.uuid);
  auto taken = db.create_run(given);
  EXPECT_FALSE(taken.ok());
  given.uuid = "0F1E2D3C-4B5A-4978-8695-A4B3C2D1E0F9";
  auto upper = db.create_run(given);
  ASSERT_FALSE(upper.ok());
  EXPECT_NE(upper.error().message.find("0F1E2D3C"), std::string::npos) << upper.error().message;
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM runs WHERE uuid IS NULL"), 0);
}

// A run inserted by plain SQL (a tool, a test fixture) gets a uuid too.
TEST(RunUuid, RunsInsertedWithoutOneGetOne) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  ASSERT_TRUE(db.exec("INSERT INTO runs(schedule_name, state, started_utc) VALUES('a', 'x', 'y'), "
                      "('b', 'x', 'y')")
                  .ok());
  const std::string a = query_text(db.handle(), "SELECT uuid FROM runs WHERE id = 1");
  const std::string b = query_text(db.handle(), "SELECT uuid FROM runs WHERE id = 2");
  EXPECT_TRUE(std::regex_match(a, kUuidV4)) << a;
  EXPECT_TRUE(std::regex_match(b, kUuidV4)) << b;
  EXPECT_NE(a, b);
}

// ------------------------------------------------------------ not bound

// A lone station: nothing is queued, whatever it writes.
TEST(Outbox, NotBoundQueuesNothing) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  write_history(db);
  ASSERT_TRUE(db.exec("DELETE FROM export_runs").ok());
  EXPECT_EQ(*db.lab_station_id(), std::nullopt);
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM outbox"), 0);
  // (SQLite's AUTOINCREMENT bookkeeping writes the outbox's sqlite_sequence
  // row, at 0, at the first insert into a relayed table: the triggers'
  // programs are compiled into the statement, fired or not.)
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT coalesce(max(seq), 0) FROM sqlite_sequence WHERE name = 'outbox'"),
            0);
  auto stats = db.outbox_stats();
  ASSERT_TRUE(stats.ok()) << stats.error().message;
  EXPECT_EQ(stats->pending, 0);
  EXPECT_EQ(stats->pending_bytes, 0);
  EXPECT_FALSE(stats->oldest_unix_s.has_value());
  EXPECT_EQ(stats->last_acked_seq, 0);
  EXPECT_TRUE(db.outbox_batch(0, 100)->empty());
}

// ------------------------------------------------------------ bound: the API

TEST(Outbox, EveryResultWrittenThroughTheApiIsQueuedOnce) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  EXPECT_EQ(*db.lab_station_id(), std::optional<std::string>("lab-3"));
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM outbox"), 0);  // no history
  OutboxCursor cursor(db);
  sqlite3* h = db.handle();
  const auto check_all = [&](const std::vector<OutboxRow>& rows) {
    for (const OutboxRow& o : rows) {
      if (o.deleted == 0) {
        EXPECT_TRUE(row_is_right(h, o));
      }
    }
  };

  const int64_t run = *db.create_run(outbox_run());
  const std::string uuid = db.run(run)->uuid;
  auto rows = cursor.take();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].kind, "run");
  EXPECT_EQ(rows[0].local_id, std::to_string(run));
  EXPECT_EQ(rows[0].run_uuid, uuid);
  EXPECT_TRUE(row_is_right(h, rows[0]));
  const json payload = json::parse(rows[0].payload);
  EXPECT_EQ(payload["tags_json"], json::array({"campaign", "imu-3x"}));  // embedded, not a string
  EXPECT_EQ(payload["config_json"]["station"]["name"], "lab-3");
  EXPECT_EQ(payload["uuid"], uuid);

  // Checkpoints stay at the station; a state change is queued.
  for (int i = 0; i < 5; ++i) {
    ASSERT_TRUE(db.set_run_checkpoint(run, R"({"step":1})", 1.7e9 + i).ok());
  }
  EXPECT_TRUE(cursor.take().empty());
  ASSERT_TRUE(db.set_run_state(run, "acquiring", false).ok());
  rows = cursor.take();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(json::parse(rows[0].payload)["state"], "acquiring");
  check_all(rows);

  // A metadata edit: the run and its audit event.
  RunMetadata md = outbox_run().metadata;
  md.comment = "re-run after the door was left open";
  ASSERT_TRUE(db.set_run_metadata(run, md, "cli").ok());
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{{"run", 1}, {"event", 1}}));
  check_all(rows);

  // A DUT: its registry row, its place in the run, its channels.
  auto dut = db.add_run_dut(run, outbox_kvh("17-0042", 0));
  ASSERT_TRUE(dut.ok()) << dut.error().message;
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{{"dut", 1}, {"run_dut", 1}, {"channel", 4}}));
  check_all(rows);
  for (const OutboxRow& o : rows) {
    if (o.kind == "dut") {
      EXPECT_EQ(o.run_uuid, kNil);
    }
    if (o.kind == "run_dut") {
      EXPECT_EQ(o.local_id, fmt::format("{}/{}", run, dut->dut.id));
    }
    if (o.kind != "dut") {
      EXPECT_EQ(o.run_uuid, uuid);
    }
  }
  // The same DUT again (crash resume): the registry's upsert updates the
  // DUT's row (to the same values): that update is queued, nothing else.
  ASSERT_TRUE(db.add_run_dut(run, outbox_kvh("17-0042", 0)).ok());
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{{"dut", 1}}));
  check_all(rows);

  // A segment, and its update with acquisition windows (not relayed).
  SegmentRecord seg = a_segment(run, 0);
  seg.id = *db.create_segment(seg);
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{{"segment", 1}}));
  seg.windows = {{10, 50}, {60, 90}};
  seg.t_end_s = 95;
  seg.state = "completed";
  ASSERT_TRUE(db.update_segment(seg).ok());
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{{"segment", 1}}));
  check_all(rows);

  // Events, in a run and outside one (nil run).
  EventRecord e;
  e.run_id = run;
  e.kind = "interlock";
  e.message = "probe 'top' silent";
  const int64_t in_run = *db.add_event(e);
  e.run_id.reset();
  e.kind = "info";
  const int64_t outside = *db.add_event(e);
  rows = cursor.take();
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[0].local_id, std::to_string(in_run));
  EXPECT_EQ(rows[0].run_uuid, uuid);
  EXPECT_EQ(rows[1].local_id, std::to_string(outside));
  EXPECT_EQ(rows[1].run_uuid, kNil);
  check_all(rows);

  // Table I: keyed by segment, DUT and axis; NaN stored as NULL, an
  // infinity as "Infinity"; doubles exact.
  SegmentStatsRecord st = stats_of(run, seg.id, 0, "17-0042", "x");
  st.temp_mean_c = std::numeric_limits<double>::quiet_NaN();
  st.bias_std_ma_dph = std::numeric_limits<double>::infinity();
  st.bin_s = -std::numeric_limits<double>::infinity();
  ASSERT_TRUE(db.put_segment_stats(st).ok());
  rows = cursor.take();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].kind, "table1");
  EXPECT_EQ(rows[0].local_id, fmt::format("{}/17-0042/x", seg.id));
  EXPECT_TRUE(row_is_right(h, rows[0]));
  const json t1 = json::parse(rows[0].payload);
  EXPECT_TRUE(t1["temp_mean_c"].is_null());
  EXPECT_EQ(t1["bias_std_ma_dph"], "Infinity");
  EXPECT_EQ(t1["bin_s"], "-Infinity");
  EXPECT_EQ(t1["bias_mean_dph"].get<double>(), 0.1 + 0.2);
  // Stored again (re-analysis): one row, the same key.
  st.bias_mean_dph = 0.5;
  ASSERT_TRUE(db.put_segment_stats(st).ok());
  rows = cursor.take();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].local_id, fmt::format("{}/17-0042/x", seg.id));
  EXPECT_EQ(rows[0].deleted, 0);

  // Allan: inserted, then replaced in place (an update): one row each.
  const int64_t allan = *db.put_allan(allan_of(run, seg.id, "17-0042"));
  ASSERT_TRUE(db.put_allan(allan_of(run, seg.id, "17-0042")).ok());
  rows = cursor.take();
  ASSERT_EQ(rows.size(), 2u);
  for (const OutboxRow& o : rows) {
    EXPECT_EQ(o.kind, "allan");
    EXPECT_EQ(o.local_id, std::to_string(allan));
  }
  EXPECT_TRUE(json::parse(rows[1].payload)["curve_json"]["tau_s"].is_array());
  check_all(rows);

  // A fit: station-level (nil run), and its link to the run.
  const int64_t fit = *db.add_fit(fit_of({run}));
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{{"fit", 1}, {"fit_run", 1}}));
  for (const OutboxRow& o : rows) {
    if (o.kind == "fit") {
      EXPECT_EQ(o.run_uuid, kNil);
    }
    if (o.kind == "fit_run") {
      EXPECT_EQ(o.local_id, fmt::format("{}/{}", run, fit));
      EXPECT_EQ(o.run_uuid, uuid);
    }
  }
  check_all(rows);

  // Scale factor: stored, then replaced (the old rows' tombstones and the
  // new rows, in one transaction).
  ScaleFactor sf = scale_factor_of(1.0000123);
  ASSERT_TRUE(db.store_scale_factor(run, sf.points, sf.fits, sf.temperature).ok());
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{
                             {"sf_point", 2}, {"sf_fit", 1}, {"sf_temperature_fit", 1}}));
  check_all(rows);
  const auto first_points = rows;
  sf = scale_factor_of(1.0000456);
  ASSERT_TRUE(db.store_scale_factor(run, sf.points, sf.fits, sf.temperature).ok());
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{
                             {"sf_point", 2}, {"sf_fit", 1}, {"sf_temperature_fit", 1}}));
  EXPECT_EQ(
      kinds(rows, /*deleted=*/true),
      (std::map<std::string, int>{{"sf_point", 2}, {"sf_fit", 1}, {"sf_temperature_fit", 1}}));
  for (const OutboxRow& o : rows) {
    EXPECT_EQ(o.run_uuid, uuid);
    if (o.deleted != 0) {
      EXPECT_EQ(o.payload, "{}");
    }
  }
  EXPECT_EQ(rows[0].local_id, first_points[0].local_id);  // the old point, retracted
  check_all(rows);
  EXPECT_EQ(json::parse(rows.back().payload)["k_coeffs_json"], json::array({1.0000123, 2.1e-6}));

  // An export and its runs; finishing it updates it.
  ExportRecord x;
  x.kind = "manual";
  x.directory = "/home/tech/report";
  x.run_ids = {run};
  const int64_t exp = *db.begin_export(x);
  rows = cursor.take();
  EXPECT_EQ(kinds(rows), (std::map<std::string, int>{{"export", 1}, {"export_run", 1}}));
  for (const OutboxRow& o : rows) {
    if (o.kind == "export") {
      EXPECT_EQ(o.run_uuid, kNil);
    }
    if (o.kind == "export_run") {
      EXPECT_EQ(o.local_id, fmt::format("{}/{}", exp, run));
    }
  }
  ASSERT_TRUE(db.finish_export(exp, "done", {"a.html"}, "1 run").ok());
  rows = cursor.take();
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(json::parse(rows[0].payload)["files_json"], json::array({"a.html"}));
  check_all(rows);

  // Samples are not relayed.
  ASSERT_TRUE(db.exec(fmt::format("INSERT INTO temperature_samples VALUES({}, 1.0, 20, 20, 20, "
                                  "20)",
                                  run))
                  .ok());
  EXPECT_TRUE(cursor.take().empty());
  EXPECT_TRUE(integrity_ok(db));
}

// ------------------------------------------------------------ bound: any SQL

// Every relayed table, whatever writes it: an update adds one row, a delete
// one tombstone per row; an update that changes a row's key retracts the
// old key first; updates of runs that only checkpoint add none.
TEST(Outbox, EveryTableUpdateAndDeleteIsQueued) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  write_history(db);
  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  sqlite3* h = db.handle();
  OutboxCursor cursor(db);

  for (const Relayed& r : kRelayed) {
    SCOPED_TRACE(r.table);
    std::string order, where;
    for (const std::string& k : r.key) order += (order.empty() ? "" : ", ") + k;
    for (const std::string& k : r.key) {
      if (!where.empty()) where += " AND ";
      where += fmt::format("{0} = (SELECT {0} FROM {1} ORDER BY {2} LIMIT 1)", k, r.table, order);
    }
    // A column that is not part of the key (or the first key column when
    // every column is: fit_runs, export_runs), set to itself.
    std::string column = r.key.front();
    for (const std::string& c : split(
             query_text(
                 h, fmt::format("SELECT group_concat(name) FROM pragma_table_info('{}')", r.table)),
             ',')) {
      bool key = false;
      for (const std::string& k : r.key) key = key || k == c;
      if (!key && kRunsNotRelayed.count(c) == 0 && c != "uuid") {
        column = c;
        break;
      }
    }
    ASSERT_FALSE(column.empty());
    const std::string local_id = expected_local_id(h, r, where);
    ASSERT_FALSE(local_id.empty());
    ASSERT_TRUE(
        db.exec(fmt::format("UPDATE {0} SET {1} = {1} WHERE {2}", r.table, column, where)).ok());
    auto rows = cursor.take();
    ASSERT_EQ(rows.size(), 1u);
    EXPECT_EQ(rows[0].kind, r.kind);
    EXPECT_EQ(rows[0].local_id, local_id);
    EXPECT_TRUE(row_is_right(h, rows[0]));
  }

  // runs: only the relayed columns' updates.
  ASSERT_TRUE(db.exec("UPDATE runs SET resume_json = '{}', checkpoint_wall_unix_s = 1").ok());
  ASSERT_TRUE(db.exec("UPDATE runs SET config_toml = 'x = 1'").ok());
  EXPECT_TRUE(cursor.take().empty());
  ASSERT_TRUE(db.exec("UPDATE runs SET comment = 'c'").ok());
  EXPECT_EQ(kinds(cursor.take()), (std::map<std::string, int>{{"run", 2}}));

  // A key change: the old key's tombstone, then the row under its new key.
  const std::string seg = query_text(h, "SELECT min(segment_id) FROM segment_stats");
  ASSERT_TRUE(
      db.exec(fmt::format("UPDATE segment_stats SET axis = 'y' WHERE segment_id = {} AND axis = "
                          "'x'",
                          seg))
          .ok());
  auto rows = cursor.take();
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[0].deleted, 1);
  EXPECT_EQ(rows[0].local_id, seg + "/17-0042/x");
  EXPECT_EQ(rows[0].payload, "{}");
  EXPECT_EQ(rows[1].deleted, 0);
  EXPECT_EQ(rows[1].local_id, seg + "/17-0042/y");
  EXPECT_TRUE(row_is_right(h, rows[1]));

  // Deletes, children first: one tombstone per row, with the row's key and
  // run (taken before the rows go).
  ASSERT_TRUE(db.exec("DELETE FROM acquisition_windows").ok());
  EXPECT_TRUE(cursor.take().empty());
  for (const char* table :
       {"channels", "run_duts", "duts", "fit_runs", "fits", "export_runs", "exports",
        "segment_stats", "allan", "scale_factor_points", "scale_factor_fits",
        "scale_factor_temperature_fits", "events", "segments", "runs"}) {
    SCOPED_TRACE(table);
    const Relayed* r = nullptr;
    for (const Relayed& x : kRelayed) {
      if (x.table == table) r = &x;
    }
    ASSERT_NE(r, nullptr);
    std::multiset<std::pair<std::string, std::string>> want;  // (run_uuid, local_id)
    {
      std::string key;
      for (const std::string& k : r->key) key += (key.empty() ? "" : ", ") + k;
      sqlite3_stmt* st = nullptr;
      ASSERT_EQ(sqlite3_prepare_v2(h, fmt::format("SELECT {} FROM {}", key, table).c_str(), -1, &st,
                                   nullptr),
                SQLITE_OK);
      while (sqlite3_step(st) == SQLITE_ROW) {
        std::string where, local;
        for (std::size_t i = 0; i < r->key.size(); ++i) {
          const std::string v = reinterpret_cast<const char*>(sqlite3_column_text(st, i));
          where += (i > 0 ? " AND " : "") +
                   fmt::format("CAST({} AS TEXT) = {}", r->key[i], sql_quote(v));
          local += (i > 0 ? "/" : "") + v;
        }
        want.insert({expected_run_uuid(h, *r, where), local});
      }
      sqlite3_finalize(st);
    }
    ASSERT_FALSE(want.empty());
    ASSERT_TRUE(db.exec(fmt::format("DELETE FROM {}", table)).ok());
    std::multiset<std::pair<std::string, std::string>> got;
    for (const OutboxRow& o : cursor.take()) {
      EXPECT_EQ(o.kind, r->kind);
      EXPECT_EQ(o.deleted, 1);
      EXPECT_EQ(o.payload, "{}");
      got.insert({o.run_uuid, o.local_id});
    }
    EXPECT_EQ(got, want);
  }
  auto batch = db.outbox_batch(0, 100000);
  ASSERT_TRUE(batch.ok());
  EXPECT_TRUE(batch->back().deleted);
  EXPECT_EQ(batch->back().kind, "run");
  EXPECT_EQ(batch->back().payload_json, "{}");
}

// A run inserted by plain SQL on a bound database is queued once, with the
// uuid the trigger gave it.
TEST(Outbox, RunInsertedWithoutUuidIsQueuedOnceWithItsUuid) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  ASSERT_TRUE(
      db.exec("INSERT INTO runs(schedule_name, state, started_utc) VALUES('a', 'x', 'y')").ok());
  auto rows = outbox_rows(db.handle());
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].kind, "run");
  EXPECT_TRUE(std::regex_match(rows[0].run_uuid, kUuidV4)) << rows[0].run_uuid;
  EXPECT_EQ(rows[0].run_uuid, query_text(db.handle(), "SELECT uuid FROM runs"));
  EXPECT_TRUE(row_is_right(db.handle(), rows[0]));
}

// ------------------------------------------------------------ transactions

// The outbox row is written in the change's transaction: a change rolled
// back leaves none, and the seq it took is taken again.
TEST(Outbox, ARolledBackChangeLeavesNoRow) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  const int64_t run = *db.create_run(outbox_run());
  ScaleFactor sf = scale_factor_of(1.0000123);
  ASSERT_TRUE(db.store_scale_factor(run, sf.points, sf.fits, sf.temperature).ok());
  const auto before = outbox_rows(db.handle());

  // Fails after deleting the old rows and inserting the points: two fits of
  // the same sequence.
  ScaleFactor bad = scale_factor_of(2.0);
  bad.fits.push_back(bad.fits[0]);
  auto failed = db.store_scale_factor(run, bad.points, bad.fits, bad.temperature);
  ASSERT_FALSE(failed.ok());
  EXPECT_EQ(outbox_rows(db.handle()).size(), before.size());
  EXPECT_EQ((*db.scale_factor_fits(run))[0].k, 1.0000123);

  ASSERT_TRUE(db.exec("BEGIN IMMEDIATE").ok());
  EventRecord e;
  e.run_id = run;
  e.kind = "info";
  e.message = "never";
  ASSERT_TRUE(db.add_event(e).ok());
  ASSERT_TRUE(db.set_run_state(run, "failed", true).ok());
  EXPECT_EQ(outbox_rows(db.handle()).size(), before.size() + 2);  // inside: there
  ASSERT_TRUE(db.exec("ROLLBACK").ok());
  EXPECT_EQ(outbox_rows(db.handle()).size(), before.size());

  ASSERT_TRUE(db.add_event(e).ok());
  auto after = outbox_rows(db.handle());
  ASSERT_EQ(after.size(), before.size() + 1);
  EXPECT_EQ(after.back().seq, before.back().seq + 1);
}

// ------------------------------------------------------------ lab_bind

TEST(Outbox, BindQueuesTheHistoryOnceAndBelongsToOneStation) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  write_history(db);
  sqlite3* h = db.handle();
  ASSERT_EQ(query_int(h, "SELECT count(*) FROM outbox"), 0);

  auto invalid = db.lab_bind("lab 3");
  ASSERT_FALSE(invalid.ok());
  EXPECT_NE(invalid.error().message.find("'lab 3'"), std::string::npos);
  EXPECT_EQ(*db.lab_station_id(), std::nullopt);

  ASSERT_TRUE(db.lab_bind("lab-3.west_2").ok());
  EXPECT_EQ(*db.lab_station_id(), std::optional<std::string>("lab-3.west_2"));
  const auto rows = outbox_rows(h);
  const auto by_kind = kinds(rows);
  int64_t total = 0;
  for (const Relayed& r : kRelayed) {
    const int64_t n = query_int(h, fmt::format("SELECT count(*) FROM {}", r.table));
    EXPECT_GT(n, 0) << r.table << ": the history should have some";
    EXPECT_EQ(by_kind.count(r.kind) != 0 ? by_kind.at(r.kind) : 0, n) << r.table;
    total += n;
  }
  EXPECT_EQ(static_cast<int64_t>(rows.size()), total);
  std::set<std::pair<std::string, std::string>> keys;
  for (const OutboxRow& o : rows) {
    EXPECT_TRUE(row_is_right(h, o));
    keys.insert({o.kind, o.local_id});
  }
  EXPECT_EQ(keys.size(), rows.size());  // each row once
  EXPECT_EQ(rows.front().kind, "run");  // runs first

  // Bound again to the same id: nothing happens.
  ASSERT_TRUE(db.lab_bind("lab-3.west_2").ok());
  EXPECT_EQ(outbox_rows(h).size(), rows.size());
  // To another: refused for good, naming both.
  auto other = db.lab_bind("lab-4");
  ASSERT_FALSE(other.ok());
  EXPECT_FALSE(other.error().transient);
  EXPECT_NE(other.error().message.find("'lab-3.west_2'"), std::string::npos)
      << other.error().message;
  EXPECT_NE(other.error().message.find("'lab-4'"), std::string::npos) << other.error().message;
  EXPECT_EQ(outbox_rows(h).size(), rows.size());
  EXPECT_EQ(*db.lab_station_id(), std::optional<std::string>("lab-3.west_2"));

  // Another connection sees the binding; its writes are queued.
  Database other_connection = open_ok(dir.file("station.db"));
  EXPECT_EQ(*other_connection.lab_station_id(), std::optional<std::string>("lab-3.west_2"));
  EventRecord e;
  e.kind = "info";
  e.message = "from another connection";
  ASSERT_TRUE(other_connection.add_event(e).ok());
  EXPECT_EQ(outbox_rows(h).size(), rows.size() + 1);
}

// ------------------------------------------------------------ batch, ack, stats

TEST(Outbox, BatchAckAndStats) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  const double before_s =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  std::vector<int64_t> events;
  for (int i = 0; i < 10; ++i) {
    EventRecord e;
    e.kind = "info";
    e.message = std::string(static_cast<std::size_t>(100 * (i + 1)), 'x');
    events.push_back(*db.add_event(e));
  }
  ASSERT_TRUE(db.exec(fmt::format("DELETE FROM events WHERE id = {}", events[3])).ok());
  const double after_s =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();

  auto all = db.outbox_batch(0, 100);
  ASSERT_TRUE(all.ok()) << all.error().message;
  ASSERT_EQ(all->size(), 11u);
  int64_t bytes = 0;
  for (std::size_t i = 0; i < all->size(); ++i) {
    const OutboxRecord& r = (*all)[i];
    if (i > 0) {
      EXPECT_GT(r.seq, (*all)[i - 1].seq);
    }
    EXPECT_EQ(r.kind, "event");
    EXPECT_EQ(r.run_uuid, kNil);
    EXPECT_GE(r.committed_unix_s, before_s - 1);
    EXPECT_LE(r.committed_unix_s, after_s + 1);
    bytes += static_cast<int64_t>(r.payload_json.size());
  }
  for (std::size_t i = 0; i < 10; ++i) {
    EXPECT_FALSE((*all)[i].deleted);
    EXPECT_EQ((*all)[i].local_id, std::to_string(events[i]));
    EXPECT_EQ(json::parse((*all)[i].payload_json)["message"].get<std::string>().size(),
              100 * (i + 1));
  }
  EXPECT_TRUE(all->back().deleted);
  EXPECT_EQ(all->back().local_id, std::to_string(events[3]));
  EXPECT_EQ(all->back().payload_json, "{}");

  // after_seq and limit.
  auto page = db.outbox_batch((*all)[3].seq, 2);
  ASSERT_TRUE(page.ok());
  ASSERT_EQ(page->size(), 2u);
  EXPECT_EQ((*page)[0].seq, (*all)[4].seq);
  EXPECT_EQ((*page)[1].seq, (*all)[5].seq);
  EXPECT_TRUE(db.outbox_batch(all->back().seq, 100)->empty());
  EXPECT_FALSE(db.outbox_batch(0, 0).ok());
  // The byte cap: whole rows up to it, at least one.
  const int64_t two =
      static_cast<int64_t>((*all)[0].payload_json.size() + (*all)[1].payload_json.size());
  EXPECT_EQ(db.outbox_batch(0, 100, two)->size(), 2u);
  EXPECT_EQ(db.outbox_batch(0, 100, two + 1)->size(), 2u);
  EXPECT_EQ(db.outbox_batch(0, 100, two - 1)->size(), 1u);
  EXPECT_EQ(db.outbox_batch(0, 100, 1)->size(), 1u);

  auto stats = db.outbox_stats();
  ASSERT_TRUE(stats.ok()) << stats.error().message;
  EXPECT_EQ(stats->pending, 11);
  EXPECT_EQ(stats->pending_bytes, bytes);
  EXPECT_EQ(stats->oldest_unix_s, std::optional<double>((*all)[0].committed_unix_s));
  EXPECT_EQ(stats->last_acked_seq, 0);

  // Acknowledged up to the 5th row: those go, the mark stays in meta.
  ASSERT_TRUE(db.outbox_ack((*all)[4].seq).ok());
  stats = db.outbox_stats();
  EXPECT_EQ(stats->pending, 6);
  EXPECT_EQ(stats->oldest_unix_s, std::optional<double>((*all)[5].committed_unix_s));
  EXPECT_EQ(stats->last_acked_seq, (*all)[4].seq);
  EXPECT_EQ(query_text(db.handle(), "SELECT value FROM meta WHERE key = 'lab_last_acked_seq'"),
            std::to_string((*all)[4].seq));
  EXPECT_EQ(db.outbox_batch(0, 100)->front().seq, (*all)[5].seq);
  // A late, smaller acknowledgement does not move the mark back.
  ASSERT_TRUE(db.outbox_ack((*all)[2].seq).ok());
  EXPECT_EQ(db.outbox_stats()->last_acked_seq, (*all)[4].seq);
  // Beyond what the outbox wrote: refused, nothing changes.
  auto beyond = db.outbox_ack(all->back().seq + 1);
  ASSERT_FALSE(beyond.ok());
  EXPECT_EQ(db.outbox_stats()->pending, 6);

  // Everything: empty; the next row's seq is never one used before.
  ASSERT_TRUE(db.outbox_ack(all->back().seq).ok());
  stats = db.outbox_stats();
  EXPECT_EQ(stats->pending, 0);
  EXPECT_EQ(stats->pending_bytes, 0);
  EXPECT_FALSE(stats->oldest_unix_s.has_value());
  EXPECT_EQ(stats->last_acked_seq, all->back().seq);
  EventRecord e;
  e.kind = "info";
  e.message = "next";
  ASSERT_TRUE(db.add_event(e).ok());
  {
    // Across a reopen too (AUTOINCREMENT keeps the high mark in the file).
    Database again = open_ok(path);
    ASSERT_TRUE(again.add_event(e).ok());
    auto next = again.outbox_batch(all->back().seq, 10);
    ASSERT_EQ(next->size(), 2u);
    EXPECT_EQ((*next)[0].seq, all->back().seq + 1);
    EXPECT_EQ((*next)[1].seq, all->back().seq + 2);
    EXPECT_EQ(again.outbox_stats()->last_acked_seq, all->back().seq);
  }
}

// ------------------------------------------------------------ concurrency

// The control loop and the analysis write results on their own connections
// while the relay reads and acknowledges on a third: every result arrives
// once, in strictly increasing seq, none skipped (a row's seq is taken
// under the write lock, so seq order is commit order and reading after the
// last seq seen never misses a row committed later).
TEST(Outbox, SeveralConnectionsWriteWhileTheRelayReads) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  constexpr int kPerWriter = 400;
  int64_t run = 0;
  std::vector<int64_t> segments;
  {
    Database db = open_ok(path);
    run = *db.create_run(outbox_run());
    for (int i = 0; i < kPerWriter; ++i) segments.push_back(*db.create_segment(a_segment(run, i)));
    ASSERT_TRUE(db.lab_bind("lab-3").ok());  // queues the run and the segments
  }
  const int64_t history = kPerWriter + 1;

  std::atomic<int> writers_done{0};
  std::vector<std::string> errors_a, errors_b, errors_relay;
  std::vector<int64_t> event_ids;
  std::thread events([&] {
    Database db = open_ok(path);
    for (int i = 0; i < kPerWriter; ++i) {
      EventRecord e;
      e.run_id = run;
      e.kind = "info";
      e.message = fmt::format("event {}", i);
      auto id = db.add_event(e);
      if (!id) {
        errors_a.push_back(id.error().message);
      } else {
        event_ids.push_back(*id);
      }
    }
    writers_done.fetch_add(1);
  });
  std::thread stats([&] {
    Database db = open_ok(path);
    for (int i = 0; i < kPerWriter; ++i) {
      Status s = db.put_segment_stats(stats_of(run, segments[i], i, "", "z"));
      if (!s) errors_b.push_back(s.error().message);
    }
    writers_done.fetch_add(1);
  });
  std::vector<OutboxRecord> received;
  std::thread relay([&] {
    Database db = open_ok(path);
    int64_t last = 0;
    std::mt19937 rng(7);
    for (;;) {
      const bool finished = writers_done.load() == 2;  // before reading: nothing comes after
      auto batch = db.outbox_batch(last, 1 + static_cast<int>(rng() % 64));
      if (!batch) {
        errors_relay.push_back(batch.error().message);
        return;
      }
      if (batch->empty()) {
        if (finished) return;
        std::this_thread::yield();
        continue;
      }
      for (auto& r : *batch) {
        if (r.seq <= last) errors_relay.push_back(fmt::format("seq {} after {}", r.seq, last));
        last = r.seq;
        received.push_back(std::move(r));
      }
      if (Status s = db.outbox_ack(last); !s) {
        errors_relay.push_back(s.error().message);
        return;
      }
    }
  });
  events.join();
  stats.join();
  relay.join();
  EXPECT_TRUE(errors_a.empty()) << errors_a.front();
  EXPECT_TRUE(errors_b.empty()) << errors_b.front();
  EXPECT_TRUE(errors_relay.empty()) << errors_relay.front();

  ASSERT_EQ(static_cast<int64_t>(received.size()), history + 2 * kPerWriter);
  std::set<std::pair<std::string, std::string>> keys;
  for (std::size_t i = 0; i < received.size(); ++i) {
    if (i > 0) {
      EXPECT_GT(received[i].seq, received[i - 1].seq);
    }
    keys.insert({received[i].kind, received[i].local_id});
  }
  EXPECT_EQ(keys.size(), received.size());  // nothing twice
  for (int64_t id : event_ids) EXPECT_EQ(keys.count({"event", std::to_string(id)}), 1u) << id;
  for (int64_t seg : segments) {
    EXPECT_EQ(keys.count({"table1", fmt::format("{}//z", seg)}), 1u) << seg;
  }
  Database db = open_ok(path);
  auto stats_after = db.outbox_stats();
  EXPECT_EQ(stats_after->pending, 0);
  EXPECT_EQ(stats_after->last_acked_seq, received.back().seq);
  EXPECT_EQ(query_int(db.handle(), "SELECT seq FROM sqlite_sequence WHERE name = 'outbox'"),
            received.back().seq);
}

// ------------------------------------------------------------ documented queries

// The sqlite3 statements of docs/storage.md that read the outbox, run
// against a bound database with history: they parse, and answer what the
// API answers.
TEST(Outbox, DocumentedQueriesRun) {
  std::string doc;
  {
    std::FILE* f =
        std::fopen((std::string(GYROTHERM_SOURCE_DIR) + "/docs/storage.md").c_str(), "rb");
    ASSERT_NE(f, nullptr);
    char buf[4096];
    std::size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, f)) > 0) doc.append(buf, n);
    std::fclose(f);
  }
  std::vector<std::string> statements;
  for (std::size_t at = 0; (at = doc.find("```sql\n", at)) != std::string::npos;) {
    at += 7;
    const std::size_t end = doc.find("```", at);
    ASSERT_NE(end, std::string::npos);
    const std::string block = doc.substr(at, end - at);
    at = end + 3;
    if (block.find("FROM outbox") == std::string::npos) continue;
    for (std::size_t from = 0, semi; (semi = block.find(';', from)) != std::string::npos;
         from = semi + 1) {
      statements.push_back(block.substr(from, semi + 1 - from));
    }
  }
  ASSERT_EQ(statements.size(), 4u) << "the documented outbox queries changed: update this test";

  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  write_history(db);
  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  const auto first = db.outbox_batch(0, 5);
  ASSERT_TRUE(db.outbox_ack(first->back().seq).ok());
  const OutboxStats stats = *db.outbox_stats();
  std::vector<std::vector<std::vector<std::string>>> results;
  for (const std::string& sql : statements) {
    SCOPED_TRACE(sql);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(db.handle(), sql.c_str(), -1, &st, nullptr), SQLITE_OK)
        << sqlite3_errmsg(db.handle());
    std::vector<std::vector<std::string>> rows;
    int rc;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
      std::vector<std::string> row;
      for (int c = 0; c < sqlite3_column_count(st); ++c) {
        const auto* t = sqlite3_column_text(st, c);
        row.emplace_back(t != nullptr ? reinterpret_cast<const char*>(t) : "");
      }
      rows.push_back(std::move(row));
    }
    EXPECT_EQ(rc, SQLITE_DONE) << sqlite3_errmsg(db.handle());
    sqlite3_finalize(st);
    results.push_back(std::move(rows));
  }
  EXPECT_EQ(results[0], (std::vector<std::vector<std::string>>{
                            {"lab_last_acked_seq", std::to_string(first->back().seq)},
                            {"lab_station_id", "lab-3"}}));
  ASSERT_EQ(results[1].size(), 1u);
  EXPECT_EQ(results[1][0][0], std::to_string(stats.pending));
  EXPECT_EQ(results[1][0][1], std::to_string(stats.pending_bytes));
  const double age = std::stod(results[1][0][2]);
  EXPECT_GE(age, -1.0);
  EXPECT_LT(age, 600.0);
  int64_t by_kind = 0;
  for (const auto& row : results[2]) by_kind += std::stoll(row[1]);
  EXPECT_EQ(by_kind, stats.pending);
  ASSERT_EQ(results[3].size(), 10u);
  for (const auto& row : results[3]) {
    if (row[1] == "table1" || row[1] == "run" || row[1] == "segment") {
      EXPECT_FALSE(row[4].empty()) << row[1] << " " << row[2] << ": its run";
    }
  }
}

// ------------------------------------------------------------ migration

// A schema-9 database with runs: each gets its own valid uuid; the outbox
// and its triggers exist, empty and asleep until bound.
TEST(OutboxMigration, Schema9DatabaseGetsRunUuidsAndTheOutbox) {
  TempDir dir;
  const std::string path = dir.file("v9.db");
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    std::string sql = "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);";
    for (const auto& m : internal::migrations()) {
      if (m.version <= 9) sql += m.sql;
    }
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    ASSERT_TRUE(internal::migrations()[8].data_step(raw, path, "2026-01-01T00:00:00.000Z").ok());
    std::string runs = "BEGIN; INSERT INTO meta VALUES('schema_version', '9');";
    for (int i = 0; i < 200; ++i) {
      runs += fmt::format(
          "INSERT INTO runs(schedule_name, state, started_utc) VALUES('r{}', 'completed', 'x');",
          i);
    }
    runs += "COMMIT;";
    ASSERT_EQ(sqlite3_exec(raw, runs.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  EXPECT_TRUE(integrity_ok(db));
  auto runs = db.runs();
  ASSERT_TRUE(runs.ok());
  ASSERT_EQ(runs->size(), 200u);
  std::set<std::string> uuids;
  for (const RunRecord& r : *runs) {
    EXPECT_TRUE(std::regex_match(r.uuid, kUuidV4)) << r.uuid;
    uuids.insert(r.uuid);
  }
  EXPECT_EQ(uuids.size(), 200u);
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM sqlite_master WHERE type = 'index' AND name = "
                      "'runs_by_uuid' AND sql LIKE 'CREATE UNIQUE INDEX%'"),
            1);
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM sqlite_master WHERE type = 'trigger' AND name LIKE "
                      "'lab_outbox_%'"),
            3 * static_cast<int64_t>(kRelayed.size()));
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM outbox"), 0);
  EXPECT_FALSE(db.exec(fmt::format("UPDATE runs SET uuid = '{}' WHERE id = 2", (*runs)[0].uuid))
                   .ok());  // unique
  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  EXPECT_EQ(
      query_int(db.handle(), "SELECT count(DISTINCT run_uuid) FROM outbox WHERE kind = 'run'"),
      200);
}

// A schema-5 database with results migrates through v10 and binds: its
// history is queued with its runs' new uuids.
TEST(OutboxMigration, Schema5DatabaseWithResultsBindsWithItsHistory) {
  TempDir dir;
  const std::string path = dir.file("v5.db");
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    std::string sql = "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);";
    for (const auto& m : internal::migrations()) {
      if (m.version <= 5) sql += m.sql;
    }
    sql +=
        "INSERT INTO meta VALUES('schema_version', '5');"
        "INSERT INTO runs(id, schedule_name, state, started_utc, config_json) VALUES"
        "(1, 'a', 'completed', 'x', '[station]\nname = \"lab-1\"\n'), "
        "(2, 'b', 'completed', 'y', '{\"gyro\":{\"axis\":\"x\"}}');"
        "INSERT INTO segments(id, run_id, idx, kind, state) VALUES(7, 1, 0, 'soak', 'completed');"
        "INSERT INTO segment_stats(segment_id, run_id, segment_index, setpoint_c, n, "
        "bias_mean_dph, computed_utc) VALUES(7, 1, 0, 20.0, 2, 1.25, 'y');"
        "INSERT INTO events(run_id, t_s, wall_utc, kind, message) VALUES(1, 3.5, 'w', 'info', 'm'),"
        "(NULL, 0, 'w', 'info', 'station');"
        "INSERT INTO allan(run_id, segment_id, segment_index, taus, n_samples, curve_json, "
        "inputs_json, computed_utc) VALUES(1, 7, 0, 'octave', 10, '{\"tau_s\":[1],"
        "\"adev_dph\":[0.1],\"adev_lo_dph\":[0.09],\"adev_hi_dph\":[0.11]}', '{}', 'y');"
        "INSERT INTO fits(id, model, form, n, coefficients_json, standard_errors_json, "
        "inputs_json, computed_utc) VALUES(3, 'T1', 'paper', 8, '{\"T1\":0.5}', '{}', '{}', 'y');"
        "INSERT INTO fit_runs VALUES(1, 3), (2, 3);"
        "INSERT INTO exports(id, kind, state, directory, started_utc) VALUES(4, 'manual', 'done', "
        "'/tmp/r', 'z');"
        "INSERT INTO export_runs VALUES(4, 1);";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  EXPECT_TRUE(integrity_ok(db));
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM pragma_foreign_key_check"), 0);
  const std::string uuid1 = db.run(1)->uuid, uuid2 = db.run(2)->uuid;
  EXPECT_TRUE(std::regex_match(uuid1, kUuidV4)) << uuid1;
  EXPECT_TRUE(std::regex_match(uuid2, kUuidV4)) << uuid2;
  EXPECT_NE(uuid1, uuid2);
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM outbox"), 0);

  ASSERT_TRUE(db.lab_bind("lab-1").ok());
  const auto rows = outbox_rows(db.handle());
  for (const Relayed& r : kRelayed) {
    EXPECT_EQ(kinds(rows)[r.kind], query_int(db.handle(), "SELECT count(*) FROM " + r.table))
        << r.table;
  }
  for (const OutboxRow& o : rows) EXPECT_TRUE(row_is_right(db.handle(), o));
  for (const OutboxRow& o : rows) {
    if (o.kind == "table1") {
      EXPECT_EQ(o.local_id, "7//");  // before v8: the unnamed gyro, axis ''
      EXPECT_EQ(o.run_uuid, uuid1);
    }
    if (o.kind == "fit_run" && o.local_id == "2/3") {
      EXPECT_EQ(o.run_uuid, uuid2);
    }
    if (o.kind == "run" && o.local_id == "1") {
      const json p = json::parse(o.payload);
      EXPECT_FALSE(p.contains("config_toml"));  // the TOML text of old runs stays
      EXPECT_TRUE(p["config_json"].is_null());
    }
  }
}

}  // namespace
}  // namespace gyrotherm::storage

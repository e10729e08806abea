// Schema v8 records: run metadata (queue -> run, edits with an audit
// event), results per DUT and axis (keys, resolution of "", ordering,
// several DUTs' scale factors of one run), the migration of a schema-7
// database with its results, and dut_history.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "migrations.h"
#include "test_files.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using testing::integrity_ok;
using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

RunRecord a_run_record(const std::string& name = "campaign") {
  RunRecord r;
  r.schedule_name = name;
  r.state = "ramping";
  r.started_utc = "2026-11-21T05:38:43.120Z";
  r.orientation = "up";
  r.config_json = R"({"station":{"name":"lab-2"}})";
  return r;
}

RunDutRecord a_dut(const std::string& serial, int position, const std::string& primary = "z") {
  RunDutRecord d;
  d.position = position;
  d.dut.serial = serial;
  d.dut.model = "KVH 1750";
  d.primary_axis = primary;
  d.axes = {"x", "y", "z"};
  d.rate_hz = 1000;
  for (const char* axis : {"x", "y", "z"}) {
    ChannelRecord c;
    c.index = static_cast<int>(d.channels.size());
    c.spec = ChannelSpec{std::string("gyro_") + axis, "deg/h", ChannelKind::kRate, axis, 1.0};
    d.channels.push_back(c);
  }
  return d;
}

int64_t a_segment(Database& db, int64_t run_id, int index) {
  SegmentRecord s;
  s.run_id = run_id;
  s.index = index;
  s.kind = "soak";
  s.state = "completed";
  s.setpoint_c = 10.0 * index;
  return *db.create_segment(s);
}

SegmentStatsRecord stats(int64_t run_id, int64_t segment_id, int index, std::string serial,
                         std::string axis, double bias_dph) {
  SegmentStatsRecord r;
  r.run_id = run_id;
  r.segment_id = segment_id;
  r.segment_index = index;
  r.dut_serial = std::move(serial);
  r.axis = std::move(axis);
  r.n = 100;
  r.bias_mean_dph = bias_dph;
  r.computed_utc = "2026-11-21T09:00:00.000Z";
  return r;
}

AllanRecord allan_row(int64_t run_id, int index, std::string serial, std::string axis, double arw) {
  AllanRecord a;
  a.run_id = run_id;
  a.segment_index = index;
  a.dut_serial = std::move(serial);
  a.axis = std::move(axis);
  a.taus = "octave";
  a.tau0_s = 0.001;
  a.t_to_s = 100;
  a.n_samples = 1000;
  a.tau_s = {1, 2};
  a.adev_dph = {0.1, 0.07};
  a.adev_lo_dph = {0.09, 0.06};
  a.adev_hi_dph = {0.11, 0.08};
  a.angle_random_walk_dprh = arw;
  return a;
}

ScaleFactorFitRecord sf_fit(int sequence, double k, std::string serial = "",
                            std::string axis = "") {
  ScaleFactorFitRecord f;
  f.sf_sequence = sequence;
  f.dut_serial = std::move(serial);
  f.axis = std::move(axis);
  f.k = k;
  f.n_points = 4;
  f.created_utc = "2026-11-21T10:00:00.000Z";
  return f;
}

// --------------------------------------------------------------- metadata

TEST(RunMetadata, QueueEntryToRunAndBack) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  RunMetadata md;
  md.operator_name = "Ana Lima";
  md.comment = "week 12 campaign\n3 IMUs, \"lid closed\"";
  md.tags = {"campaign", "imu-3x"};
  md.dut_serials = {"17-0042", "17-0043"};
  auto entry = db.queue_add("campaign", "/s/c.toml", "[schedule]\n", false, md);
  ASSERT_TRUE(entry.ok()) << entry.error().message;
  EXPECT_EQ(entry->metadata.operator_name, md.operator_name);
  EXPECT_EQ(entry->metadata.comment, md.comment);
  EXPECT_EQ(entry->metadata.tags, md.tags);
  EXPECT_EQ(entry->metadata.dut_serials, md.dut_serials);
  EXPECT_EQ(db.queue_entries()->front().metadata.tags, md.tags);
  EXPECT_EQ(query_text(db.handle(), "SELECT tags_json FROM queue"), R"(["campaign","imu-3x"])");

  // The run gets the entry's metadata; a field the entry left empty takes
  // the caller's.
  RunRecord run = a_run_record();
  run.metadata.operator_name = "daemon default";
  auto run_id = db.queue_start_run(entry->id, run);
  ASSERT_TRUE(run_id.ok()) << run_id.error().message;
  ASSERT_TRUE(run_id->has_value());
  auto stored = db.run(**run_id);
  ASSERT_TRUE(stored.ok()) << stored.error().message;
  EXPECT_EQ(stored->metadata.operator_name, "Ana Lima");
  EXPECT_EQ(stored->metadata.comment, md.comment);
  EXPECT_EQ(stored->metadata.tags, md.tags);
  EXPECT_EQ(stored->metadata.dut_serials, md.dut_serials);
  EXPECT_EQ(db.runs()->front().metadata.dut_serials, md.dut_serials);

  auto plain = db.queue_add("plain", "", "", false);
  RunRecord caller = a_run_record();
  caller.metadata.operator_name = "from caller";
  caller.metadata.tags = {"t"};
  auto plain_run = db.queue_start_run(plain->id, caller);
  ASSERT_TRUE(plain_run.ok() && plain_run->has_value());
  EXPECT_EQ(db.run(**plain_run)->metadata.operator_name, "from caller");
  EXPECT_EQ(db.run(**plain_run)->metadata.tags, std::vector<std::string>{"t"});

  RunMetadata bad;
  bad.tags = {"ok", ""};
  auto refused = db.queue_add("x", "", "", false, bad);
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("metadata tags[1] is empty"), std::string::npos)
      << refused.error().message;
}

TEST(RunMetadata, EditsLeaveOneEventListingEachChange) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  RunRecord run = a_run_record();
  run.metadata.operator_name = "ana";
  run.metadata.tags = {"a"};
  const int64_t id = *db.create_run(run);
  EventRecord state;
  state.run_id = id;
  state.t_s = 42.5;
  state.kind = "state";
  ASSERT_TRUE(db.add_event(state).ok());

  RunMetadata md = db.run(id)->metadata;
  ASSERT_TRUE(db.set_run_metadata(id, md, "cli").ok());  // nothing changed
  EXPECT_EQ(db.events(id)->size(), 1u);

  md.operator_name = "bob";
  md.comment = "re-run after \"fix\"";
  md.tags = {"a", "b"};
  md.dut_serials = {"17-0042"};
  ASSERT_TRUE(db.set_run_metadata(id, md, "token lab-pc").ok());
  auto events = *db.events(id);
  ASSERT_EQ(events.size(), 2u);
  EXPECT_EQ(events[1].kind, "metadata");
  EXPECT_EQ(events[1].t_s, 42.5);  // after the run's latest event
  EXPECT_EQ(events[1].message,
            R"(metadata changed by token lab-pc: operator "ana" -> "bob"; comment "" -> )"
            R"("re-run after \"fix\""; tags ["a"] -> ["a", "b"]; duts [] -> ["17-0042"])");
  auto after = db.run(id)->metadata;
  EXPECT_EQ(after.operator_name, "bob");
  EXPECT_EQ(after.comment, md.comment);
  EXPECT_EQ(after.tags, md.tags);
  EXPECT_EQ(after.dut_serials, md.dut_serials);

  md.comment = "";
  ASSERT_TRUE(db.set_run_metadata(id, md, "cli").ok());
  events = *db.events(id);
  ASSERT_EQ(events.size(), 3u);
  EXPECT_EQ(events[2].message, R"(metadata changed by cli: comment "re-run after \"fix\"" -> "")");

  auto missing = db.set_run_metadata(id + 5, md, "cli");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find(fmt::format("no run with id {}", id + 5)),
            std::string::npos)
      << missing.error().message;
}

// ------------------------------------------------------- results per DUT

TEST(ResultsPerDut, SegmentStatsKeyedByDutAndAxis) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run_record());
  ASSERT_TRUE(db.add_run_dut(run, a_dut("B-2", 1, "x")).ok());
  ASSERT_TRUE(db.add_run_dut(run, a_dut("A-1", 0, "z")).ok());
  const int64_t seg0 = a_segment(db, run, 0);
  const int64_t seg1 = a_segment(db, run, 1);

  // "" = the first DUT (A-1, position 0), its primary axis z.
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg1, 1, "", "", 1.0)).ok());
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg1, 1, "B-2", "", 2.0)).ok());  // its x
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg1, 1, "B-2", "y", 3.0)).ok());
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg0, 0, "A-1", "x", 4.0)).ok());
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg1, 1, "A-1", "z", 1.5)).ok());  // replaces

  auto rows = db.segment_stats(run);
  ASSERT_TRUE(rows.ok()) << rows.error().message;
  ASSERT_EQ(rows->size(), 4u);
  const auto expect = [&](std::size_t i, int index, const char* serial, const char* axis,
                          double bias) {
    SCOPED_TRACE(i);
    EXPECT_EQ((*rows)[i].segment_index, index);
    EXPECT_EQ((*rows)[i].dut_serial, serial);
    EXPECT_EQ((*rows)[i].axis, axis);
    EXPECT_EQ((*rows)[i].bias_mean_dph, bias);
  };
  expect(0, 0, "A-1", "x", 4.0);
  expect(1, 1, "A-1", "z", 1.5);  // by segment, then DUT position (A-1 first), axis
  expect(2, 1, "B-2", "x", 2.0);
  expect(3, 1, "B-2", "y", 3.0);

  auto stranger = db.put_segment_stats(stats(run, seg0, 0, "C-3", "z", 0));
  ASSERT_FALSE(stranger.ok());
  EXPECT_NE(stranger.error().message.find(fmt::format("run {} has no DUT with serial 'C-3'", run)),
            std::string::npos)
      << stranger.error().message;
}

TEST(ResultsPerDut, AllanAndFitsKeyedByDutAndAxis) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run_record());
  ASSERT_TRUE(db.add_run_dut(run, a_dut("A-1", 0, "y")).ok());
  ASSERT_TRUE(db.add_run_dut(run, a_dut("B-2", 1)).ok());
  const auto first = db.put_allan(allan_row(run, 0, "", "", 0.01));
  ASSERT_TRUE(first.ok()) << first.error().message;
  ASSERT_TRUE(db.put_allan(allan_row(run, 0, "B-2", "z", 0.02)).ok());
  ASSERT_TRUE(db.put_allan(allan_row(run, 0, "B-2", "x", 0.03)).ok());
  const auto again = db.put_allan(allan_row(run, 0, "A-1", "y", 0.015));  // same key as first
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(*again, *first);  // replaced in place
  auto rows = *db.allan(run);
  ASSERT_EQ(rows.size(), 3u);
  EXPECT_EQ(rows[0].dut_serial, "A-1");
  EXPECT_EQ(rows[0].axis, "y");
  EXPECT_EQ(rows[0].angle_random_walk_dprh, 0.015);
  EXPECT_EQ(rows[1].axis, "x");
  EXPECT_EQ(rows[2].axis, "z");

  FitRecord fit;
  fit.run_ids = {run};
  fit.model = "T1";
  fit.form = "paper";
  fit.coefficients_json = "{}";
  fit.standard_errors_json = "{}";
  const int64_t f1 = *db.add_fit(fit);
  fit.dut_serial = "B-2";
  fit.axis = "x";
  const int64_t f2 = *db.add_fit(fit);
  auto fits = *db.fits(run);
  ASSERT_EQ(fits.size(), 2u);
  EXPECT_EQ(fits[0].id, f2);
  EXPECT_EQ(fits[0].dut_serial, "B-2");
  EXPECT_EQ(fits[0].axis, "x");
  EXPECT_EQ(fits[1].id, f1);
  EXPECT_EQ(fits[1].dut_serial, "A-1");
  EXPECT_EQ(fits[1].axis, "y");
  EXPECT_EQ((*db.fit(f2))->dut_serial, "B-2");
}

TEST(ResultsPerDut, ScaleFactorOfSeveralDutsInOneRun) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run_record());
  ASSERT_TRUE(db.add_run_dut(run, a_dut("A-1", 0)).ok());
  ASSERT_TRUE(db.add_run_dut(run, a_dut("B-2", 1)).ok());
  ScaleFactorPointRecord p;
  p.sf_sequence = 1;
  p.repetition = 1;
  p.rate_dps = 10;
  p.output_dps = 10.0001;
  p.n = 1000;
  ScaleFactorTemperatureFitRecord t;
  t.order = 1;
  t.k_coeffs_json = "[1.0, 2e-6]";

  // The first DUT through the old signature (records name no DUT).
  ASSERT_TRUE(db.store_scale_factor(run, {p}, {sf_fit(1, 1.00001)}, t).ok());
  // B-2 by the records it is given, then its y axis by a stream key.
  ScaleFactorPointRecord pb = p;
  pb.dut_serial = "B-2";
  ScaleFactorTemperatureFitRecord tb = t;
  tb.k_coeffs_json = "[1.1]";
  tb.dut_serial = "B-2";
  ASSERT_TRUE(db.store_scale_factor(run, {pb, pb}, {sf_fit(1, 1.00002, "B-2")}, tb).ok());
  ASSERT_TRUE(
      db.store_scale_factor(run, StreamKey{"B-2", "y"}, {p}, {sf_fit(1, 1.00003)}, std::nullopt)
          .ok());

  auto fits = *db.scale_factor_fits(run);
  ASSERT_EQ(fits.size(), 3u);
  EXPECT_EQ(fits[0].dut_serial, "A-1");
  EXPECT_EQ(fits[0].axis, "z");
  EXPECT_EQ(fits[0].k, 1.00001);
  EXPECT_EQ(fits[1].dut_serial, "B-2");
  EXPECT_EQ(fits[1].axis, "y");
  EXPECT_EQ(fits[2].axis, "z");
  EXPECT_EQ(fits[2].k, 1.00002);
  auto points = *db.scale_factor_points(run);
  ASSERT_EQ(points.size(), 4u);
  EXPECT_EQ(points[0].dut_serial, "A-1");
  EXPECT_EQ(points[3].dut_serial, "B-2");
  EXPECT_EQ(db.scale_factor_temperature_fits(run)->size(), 2u);
  EXPECT_EQ((*db.scale_factor_temperature_fit(run))->k_coeffs_json, "[1.0, 2e-6]");
  EXPECT_EQ((*db.scale_factor_temperature_fit(run, {"B-2", ""}))->k_coeffs_json, "[1.1]");
  EXPECT_FALSE(db.scale_factor_temperature_fit(run, {"B-2", "y"})->has_value());

  // Re-storing B-2 z replaces its rows only.
  ASSERT_TRUE(
      db.store_scale_factor(run, StreamKey{"B-2", ""}, {}, {sf_fit(1, 1.5)}, std::nullopt).ok());
  fits = *db.scale_factor_fits(run);
  ASSERT_EQ(fits.size(), 3u);
  EXPECT_EQ(fits[2].k, 1.5);
  EXPECT_EQ(db.scale_factor_points(run)->size(), 2u);  // A-1's and B-2 y's
  EXPECT_EQ(db.scale_factor_temperature_fits(run)->size(), 1u);

  // Records naming two series, or a series other than the key's: refused,
  // named, nothing changed.
  auto mixed = db.store_scale_factor(run, {pb}, {sf_fit(1, 2.0, "A-1")}, std::nullopt);
  ASSERT_FALSE(mixed.ok());
  EXPECT_NE(mixed.error().message.find("records name DUT 'B-2' axis '' and DUT 'A-1' axis ''"),
            std::string::npos)
      << mixed.error().message;
  auto other = db.store_scale_factor(run, StreamKey{"A-1", ""}, {pb}, {}, std::nullopt);
  ASSERT_FALSE(other.ok());
  EXPECT_NE(other.error().message.find("a point record is for DUT 'B-2' axis ''"),
            std::string::npos)
      << other.error().message;
  EXPECT_EQ(db.scale_factor_fits(run)->size(), 3u);
}

// A run recorded before DUTs had serials: results stored with '' stay ''
// (the unnamed gyro); once the run has its unnamed DUT (as the v9 migration
// registers it), storing its primary axis replaces the '' rows.
TEST(ResultsPerDut, UnnamedGyroRowsAreReplacedByItsPrimaryAxis) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const int64_t run = *db.create_run(a_run_record());
  const int64_t seg = a_segment(db, run, 0);
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg, 0, "", "", 1.0)).ok());
  ASSERT_TRUE(db.put_allan(allan_row(run, 0, "", "", 0.1)).ok());
  ASSERT_TRUE(db.store_scale_factor(run, {}, {sf_fit(1, 1.1)}, std::nullopt).ok());
  EXPECT_EQ(db.segment_stats(run)->front().axis, "");
  EXPECT_EQ(db.scale_factor_fits(run)->front().axis, "");

  RunDutRecord unnamed;
  unnamed.primary_axis = "z";
  ASSERT_TRUE(db.add_run_dut(run, unnamed).ok());
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg, 0, "", "", 2.0)).ok());
  ASSERT_TRUE(db.put_allan(allan_row(run, 0, "", "", 0.2)).ok());
  ASSERT_TRUE(db.store_scale_factor(run, {}, {sf_fit(1, 1.2)}, std::nullopt).ok());
  auto rows = *db.segment_stats(run);
  ASSERT_EQ(rows.size(), 1u);
  EXPECT_EQ(rows[0].axis, "z");
  EXPECT_EQ(rows[0].bias_mean_dph, 2.0);
  auto allan = *db.allan(run);
  ASSERT_EQ(allan.size(), 1u);
  EXPECT_EQ(allan[0].axis, "z");
  auto fits = *db.scale_factor_fits(run);
  ASSERT_EQ(fits.size(), 1u);
  EXPECT_EQ(fits[0].k, 1.2);
  // Another axis of the unnamed gyro is a series of its own.
  ASSERT_TRUE(db.put_segment_stats(stats(run, seg, 0, "", "x", 3.0)).ok());
  EXPECT_EQ(db.segment_stats(run)->size(), 2u);
}

// ------------------------------------------------------------ migration

TEST(ResultsPerDut, MigratesASchema7DatabaseKeepingItsResults) {
  TempDir dir;
  const std::string path = dir.file("v7.db");
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    std::string sql = "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);";
    for (const auto& m : internal::migrations()) {
      if (m.version <= 7) sql += m.sql;
    }
    sql +=
        "INSERT INTO meta VALUES('schema_version', '7');"
        "INSERT INTO runs(id, schedule_name, state, started_utc) VALUES(1, 'old', 'completed', "
        "'2026-01-02T03:04:05.000Z');"
        "INSERT INTO schedules(id, name, toml_text, created_utc) VALUES(1, 'old', '', 'x');"
        "INSERT INTO queue(schedule_id, position, state, added_utc) VALUES(1, 0, 'queued', 'x');"
        "INSERT INTO segments(id, run_id, idx, kind, state) VALUES(7, 1, 0, 'soak', 'completed');"
        "INSERT INTO segments(id, run_id, idx, kind, state) VALUES(8, 1, 1, 'rate', 'completed');"
        "INSERT INTO segment_stats(segment_id, run_id, segment_index, setpoint_c, n, "
        "bias_mean_dph, computed_utc) VALUES(7, 1, 0, 20.0, 2, 1.25, 'y');"
        "INSERT INTO allan(run_id, segment_id, segment_index, taus, n_samples, curve_json, "
        "inputs_json, computed_utc) VALUES(1, 7, 0, 'octave', 10, '{\"tau_s\":[1],"
        "\"adev_dph\":[0.1],\"adev_lo_dph\":[0.09],\"adev_hi_dph\":[0.11]}', '{}', 'y');"
        "INSERT INTO fits(id, model, form, n, coefficients_json, standard_errors_json, "
        "inputs_json, computed_utc) VALUES(3, 'T1', 'paper', 8, '{\"T1\":0.5}', '{}', '{}', 'y');"
        "INSERT INTO fit_runs VALUES(1, 3);"
        "INSERT INTO scale_factor_points(run_id, segment_id, sf_sequence, repetition, rate_dps, "
        "output_dps, n) VALUES(1, 8, 1, 1, 10.0, 10.0001, 500);"
        "INSERT INTO scale_factor_fits(run_id, sf_sequence, k, n_points, created_utc) "
        "VALUES(1, 1, 1.00001, 4, 'y');"
        "INSERT INTO scale_factor_temperature_fits(run_id, poly_order, t_centre_c, "
        "k_coeffs_json, bias_coeffs_json, created_utc) VALUES(1, 1, 20.0, '[1.0]', '[0.0]', 'y');";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  EXPECT_TRUE(integrity_ok(db));
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM pragma_foreign_key_check"), 0);

  auto run = db.run(1);
  ASSERT_TRUE(run.ok()) << run.error().message;
  EXPECT_EQ(run->metadata.operator_name, "");
  EXPECT_TRUE(run->metadata.tags.empty());
  EXPECT_TRUE(db.queue_entries()->front().metadata.dut_serials.empty());

  auto st = *db.segment_stats(1);
  ASSERT_EQ(st.size(), 1u);
  EXPECT_EQ(st[0].segment_id, 7);
  EXPECT_EQ(st[0].bias_mean_dph, 1.25);
  EXPECT_EQ(st[0].dut_serial, "");
  EXPECT_EQ(st[0].axis, "");
  auto allan = *db.allan(1);
  ASSERT_EQ(allan.size(), 1u);
  EXPECT_EQ(allan[0].dut_serial, "");
  EXPECT_EQ(allan[0].adev_dph, std::vector<double>{0.1});
  auto fit = *db.fit(3);
  ASSERT_TRUE(fit.has_value());
  EXPECT_EQ(fit->dut_serial, "");
  EXPECT_EQ(fit->run_ids, std::vector<int64_t>{1});
  EXPECT_EQ(db.scale_factor_points(1)->size(), 1u);
  auto sf = *db.scale_factor_fits(1);
  ASSERT_EQ(sf.size(), 1u);
  EXPECT_EQ(sf[0].k, 1.00001);
  EXPECT_EQ(sf[0].axis, "");
  auto t = *db.scale_factor_temperature_fit(1);
  ASSERT_TRUE(t.has_value());
  EXPECT_EQ(t->k_coeffs_json, "[1.0]");

  // The new keys hold: a second axis of the same segment is a row of its own.
  ASSERT_TRUE(db.put_segment_stats(stats(1, 7, 0, "", "x", 2.0)).ok());
  EXPECT_EQ(db.segment_stats(1)->size(), 2u);
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM sqlite_master WHERE type = 'index' AND "
                      "name IN ('segment_stats_by_run', 'segment_stats_by_dut', "
                      "'allan_by_run', 'allan_by_dut', 'fits_by_dut', "
                      "'scale_factor_points_by_run', 'scale_factor_fits_by_dut', "
                      "'run_duts_by_dut')"),
            8);
}

// ------------------------------------------------------------ DUT history

// Three runs: 17-0042 in runs 1 and 2 (position 0 with primary axis z,
// then position 1 with x), 17-0043 in all three; Table I rows for x and z,
// Allan and scale-factor fits for the primary axis, a drift fit per DUT.
struct HistoryFixture {
  int64_t run1 = 0, run2 = 0, run3 = 0, fit_0042 = 0;
};

HistoryFixture fill_history(Database& db) {
  HistoryFixture f;
  RunRecord r1 = a_run_record("week 1");
  r1.metadata.operator_name = "ana";
  r1.resume_json = R"({"step":3})";
  f.run1 = *db.create_run(r1);
  f.run2 = *db.create_run(a_run_record("week 2"));
  f.run3 = *db.create_run(a_run_record("other gyros only"));
  EXPECT_TRUE(db.add_run_dut(f.run1, a_dut("17-0042", 0)).ok());
  EXPECT_TRUE(db.add_run_dut(f.run1, a_dut("17-0043", 1)).ok());
  EXPECT_TRUE(db.add_run_dut(f.run2, a_dut("17-0043", 0)).ok());
  EXPECT_TRUE(db.add_run_dut(f.run2, a_dut("17-0042", 1, "x")).ok());
  EXPECT_TRUE(db.add_run_dut(f.run3, a_dut("17-0043", 0)).ok());
  for (int64_t run : {f.run1, f.run2, f.run3}) {
    for (int i = 0; i < 2; ++i) {
      const int64_t seg = a_segment(db, run, i);
      for (const char* serial : {"17-0042", "17-0043"}) {
        if (run == f.run3 && std::string(serial) == "17-0042") continue;
        for (const char* axis : {"x", "z"}) {
          EXPECT_TRUE(db.put_segment_stats(stats(run, seg, i, serial, axis, run * 10 + i)).ok());
        }
        EXPECT_TRUE(db.put_allan(allan_row(run, i, serial, "", 0.01)).ok());
      }
    }
    for (const char* serial : {"17-0042", "17-0043"}) {
      if (run == f.run3 && std::string(serial) == "17-0042") continue;
      EXPECT_TRUE(db.store_scale_factor(run, StreamKey{serial, ""}, {}, {sf_fit(1, 1.0 + run)},
                                        std::nullopt)
                      .ok());
    }
  }
  FitRecord fit;
  fit.run_ids = {f.run1, f.run2};
  fit.model = "T1";
  fit.form = "paper";
  fit.coefficients_json = "{}";
  fit.standard_errors_json = "{}";
  fit.dut_serial = "17-0042";
  f.fit_0042 = *db.add_fit(fit);
  fit.dut_serial = "17-0043";
  EXPECT_TRUE(db.add_fit(fit).ok());
  return f;
}

TEST(DutHistory, EverythingOneGyroWentThroughAcrossRuns) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const HistoryFixture fx = fill_history(db);
  ASSERT_FALSE(::testing::Test::HasFailure());
  const int64_t run1 = fx.run1, run2 = fx.run2, mine = fx.fit_0042;
  auto h = db.dut_history("17-0042");
  ASSERT_TRUE(h.ok()) << h.error().message;
  EXPECT_EQ(h->dut.serial, "17-0042");
  EXPECT_EQ(h->dut.model, "KVH 1750");
  ASSERT_EQ(h->runs.size(), 2u);  // not run 3
  const auto& a = h->runs[0];
  EXPECT_EQ(a.run.id, run1);
  EXPECT_EQ(a.run.metadata.operator_name, "ana");
  EXPECT_EQ(a.run.config_json, "");  // left out
  EXPECT_EQ(a.run.resume_json, "");
  EXPECT_EQ(a.in_run.position, 0);
  EXPECT_EQ(a.in_run.primary_axis, "z");
  EXPECT_EQ(a.in_run.channels.size(), 3u);
  EXPECT_EQ(a.segments.size(), 2u);
  ASSERT_EQ(a.stats.size(), 4u);  // 2 segments x 2 axes, this DUT only
  for (const auto& s : a.stats) EXPECT_EQ(s.dut_serial, "17-0042");
  EXPECT_EQ(a.stats[0].axis, "x");
  EXPECT_EQ(a.stats[1].axis, "z");
  EXPECT_EQ(a.stats[2].bias_mean_dph, run1 * 10 + 1);
  ASSERT_EQ(a.allan.size(), 2u);
  EXPECT_EQ(a.allan[0].axis, "z");  // "" = its primary axis in run 1
  ASSERT_EQ(a.scale_factor.size(), 1u);
  EXPECT_EQ(a.scale_factor[0].k, 1.0 + run1);
  const auto& b = h->runs[1];
  EXPECT_EQ(b.run.id, run2);
  EXPECT_EQ(b.in_run.position, 1);
  EXPECT_EQ(b.in_run.primary_axis, "x");
  ASSERT_EQ(b.allan.size(), 2u);
  EXPECT_EQ(b.allan[0].axis, "x");  // its primary axis in run 2
  ASSERT_EQ(b.scale_factor.size(), 1u);
  EXPECT_EQ(b.scale_factor[0].axis, "x");
  ASSERT_EQ(h->fits.size(), 1u);
  EXPECT_EQ(h->fits[0].id, mine);
  EXPECT_EQ(h->fits[0].run_ids, (std::vector<int64_t>{run1, run2}));

  auto other = db.dut_history("17-0043");
  ASSERT_TRUE(other.ok()) << other.error().message;
  EXPECT_EQ(other->runs.size(), 3u);

  auto unknown = db.dut_history("99-0001");
  ASSERT_FALSE(unknown.ok());
  EXPECT_NE(unknown.error().message.find("no DUT with serial '99-0001'"), std::string::npos)
      << unknown.error().message;
}

// The sqlite3 statements of docs/storage.md about DUTs, run against the
// history fixture: they parse, and answer what dut_history answers.
TEST(DutHistory, DocumentedQueriesRun) {
  const std::string doc =
      gyrotherm::testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/docs/storage.md");
  std::vector<std::string> statements;
  for (std::size_t at = 0; (at = doc.find("```sql\n", at)) != std::string::npos;) {
    at += 7;
    const std::size_t end = doc.find("```", at);
    ASSERT_NE(end, std::string::npos);
    const std::string block = doc.substr(at, end - at);
    at = end + 3;
    if (block.find("'17-0042'") == std::string::npos &&
        block.find("FROM run_duts rd JOIN duts d") == std::string::npos) {
      continue;
    }
    for (std::size_t from = 0, semi; (semi = block.find(';', from)) != std::string::npos;
         from = semi + 1) {
      statements.push_back(block.substr(from, semi + 1 - from));
    }
  }
  ASSERT_EQ(statements.size(), 6u) << "the documented DUT queries changed: update this test";

  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const HistoryFixture fx = fill_history(db);
  ASSERT_FALSE(::testing::Test::HasFailure());
  std::vector<std::size_t> rows;
  for (const std::string& sql : statements) {
    SCOPED_TRACE(sql);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(db.handle(), sql.c_str(), -1, &st, nullptr), SQLITE_OK)
        << sqlite3_errmsg(db.handle());
    std::size_t n = 0;
    int rc;
    while ((rc = sqlite3_step(st)) == SQLITE_ROW) {
      if (&sql == &statements[0]) {
        // run, ..., table1_rows (column 9), allan_rows, sf_fits
        EXPECT_EQ(sqlite3_column_int64(st, 0), n == 0 ? fx.run1 : fx.run2);
        EXPECT_EQ(sqlite3_column_int64(st, 9), 4);
        EXPECT_EQ(sqlite3_column_int64(st, 10), 2);
        EXPECT_EQ(sqlite3_column_int64(st, 11), 1);
      }
      ++n;
    }
    EXPECT_EQ(rc, SQLITE_DONE) << sqlite3_errmsg(db.handle());
    sqlite3_finalize(st);
    rows.push_back(n);
  }
  auto h = *db.dut_history("17-0042");
  std::size_t stats = 0, allan = 0, sf = 0;
  for (const auto& r : h.runs) {
    stats += r.stats.size();
    allan += r.allan.size();
    sf += r.scale_factor.size();
  }
  EXPECT_EQ(rows, (std::vector<std::size_t>{h.runs.size(), stats, allan, sf, h.fits.size(),
                                            3}));  // the last run: 17-0043, 3 channels
}

}  // namespace
}  // namespace gyrotherm::storage

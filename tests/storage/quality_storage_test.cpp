// The quality of stored results (schema v11; docs/storage.md "Result
// quality"): every result table keeps its coverage, longest gap, verdict
// and reasons, rows stored before v11 read "unassessed", and the lab
// outbox relays the new columns (the v11 migration regenerates the
// triggers from the tables' columns).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "migrations.h"
#include "test_files.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using nlohmann::json;
using testing::integrity_ok;
using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

ResultQuality flagged_quality() {
  ResultQuality q;
  q.samples = 600;
  q.expected = 10000;
  q.coverage = 0.06;
  q.longest_gap_s = 540.25;
  q.verdict = "flagged";
  q.reasons = {"coverage 6.0 % (600 of 10000 samples expected) is under 99 %",
               "K = -0.53 is not positive"};
  return q;
}

void expect_same(const ResultQuality& got, const ResultQuality& want) {
  EXPECT_EQ(got.samples, want.samples);
  EXPECT_EQ(got.expected, want.expected);
  EXPECT_EQ(got.coverage, want.coverage);
  EXPECT_EQ(got.longest_gap_s, want.longest_gap_s);
  EXPECT_EQ(got.verdict, want.verdict);
  EXPECT_EQ(got.reasons, want.reasons);
}

// A run with one soak segment; its id and the segment's.
std::pair<int64_t, int64_t> a_run(Database& db) {
  RunRecord run;
  run.schedule_name = "q";
  run.state = "completed";
  const int64_t id = *db.create_run(run);
  SegmentRecord seg;
  seg.run_id = id;
  seg.kind = "soak";
  seg.state = "completed";
  return {id, *db.create_segment(seg)};
}

TEST(ResultQualityStorage, EveryResultKeepsItsQuality) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const auto [run, segment] = a_run(db);
  const ResultQuality q = flagged_quality();

  SegmentStatsRecord st;
  st.run_id = run;
  st.segment_id = segment;
  st.quality = q;
  ASSERT_TRUE(db.put_segment_stats(st).ok());
  expect_same(db.segment_stats(run)->front().quality, q);

  AllanRecord a;
  a.run_id = run;
  a.segment_id = segment;
  a.taus = "octave";
  a.quality = q;
  a.quality.verdict = "ok";
  a.quality.reasons.clear();
  ASSERT_TRUE(db.put_allan(a).ok());
  expect_same(db.allan(run)->front().quality, a.quality);
  // Replaced in place (an upsert): the new quality.
  a.quality = q;
  ASSERT_TRUE(db.put_allan(a).ok());
  expect_same(db.allan(run)->front().quality, q);

  FitRecord f;
  f.run_ids = {run};
  f.model = "T1";
  f.form = "centered";
  f.coefficients_json = f.standard_errors_json = "{}";
  f.quality = q;
  const int64_t fit_id = *db.add_fit(f);
  expect_same((*db.fit(fit_id))->quality, q);

  ScaleFactorPointRecord p;
  p.segment_id = segment;
  p.rate_dps = 10;
  p.guard_s = 1.5;
  p.quality = q;
  p.quality.verdict = "excluded";
  ScaleFactorFitRecord sf;
  sf.sf_sequence = 1;
  sf.k = -0.53;
  sf.guard_s = 1.5;
  sf.quality = q;
  ASSERT_TRUE(db.store_scale_factor(run, {p}, {sf}, std::nullopt).ok());
  const auto points = *db.scale_factor_points(run);
  ASSERT_EQ(points.size(), 1u);
  EXPECT_EQ(points[0].guard_s, 1.5);
  expect_same(points[0].quality, p.quality);
  const auto fits = *db.scale_factor_fits(run);
  ASSERT_EQ(fits.size(), 1u);
  EXPECT_EQ(fits[0].guard_s, 1.5);
  expect_same(fits[0].quality, q);

  // As people query it.
  EXPECT_EQ(query_text(db.handle(), "SELECT quality FROM fits"), "flagged");
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT json_extract(quality_reasons_json, '$[1]') FROM "
                       "scale_factor_fits"),
            "K = -0.53 is not positive");
  EXPECT_EQ(query_text(db.handle(), "SELECT coverage FROM segment_stats"), "0.06");
  // A verdict that is none of the four is refused.
  EXPECT_FALSE(db.exec("UPDATE fits SET quality = 'fine'").ok());
  EXPECT_TRUE(integrity_ok(db));
}

TEST(ResultQualityStorage, ARecordNobodyAssessedIsStoredUnassessed) {
  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  const auto [run, segment] = a_run(db);
  SegmentStatsRecord st;
  st.run_id = run;
  st.segment_id = segment;
  ASSERT_TRUE(db.put_segment_stats(st).ok());
  const ResultQuality got = db.segment_stats(run)->front().quality;
  EXPECT_EQ(got.verdict, "unassessed");
  EXPECT_FALSE(got.coverage.has_value());
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM segment_stats WHERE coverage_samples "
                      "IS NULL AND coverage_expected IS NULL"),
            1);
}

// A schema-10 database bound to a lab, with a Table I row and a fit:
// after the v11 migration the old rows read "unassessed", and a result
// written afterwards reaches the outbox with every new column (the
// triggers were generated again from the tables' columns).
TEST(ResultQualityMigration, Schema10DatabaseRelaysTheNewColumns) {
  TempDir dir;
  const std::string path = dir.file("v10.db");
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    const std::string now = "2026-01-01T00:00:00.000Z";
    ASSERT_EQ(sqlite3_exec(raw, "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);",
                           nullptr, nullptr, nullptr),
              SQLITE_OK);
    for (const auto& m : internal::migrations()) {
      if (m.version > 10) break;
      ASSERT_EQ(sqlite3_exec(raw, m.sql, nullptr, nullptr, nullptr), SQLITE_OK)
          << m.version << ": " << sqlite3_errmsg(raw);
      if (m.data_step != nullptr) {
        ASSERT_TRUE(m.data_step(raw, path, now).ok()) << m.version;
      }
    }
    const std::string rows =
        "BEGIN; INSERT INTO meta VALUES('schema_version', '10');"
        "INSERT INTO runs(id, schedule_name, state, started_utc) VALUES(1, 'old', 'completed', "
        "'x');"
        "INSERT INTO segments(id, run_id, idx, kind, state) VALUES(1, 1, 0, 'soak', 'completed');"
        "INSERT INTO segment_stats(segment_id, run_id, segment_index, n, computed_utc) "
        "VALUES(1, 1, 0, 10, 'x');"
        "INSERT INTO fits(id, model, form, n, coefficients_json, standard_errors_json, "
        "inputs_json, computed_utc) VALUES(1, 'T1', 'centered', 5, '{}', '{}', '{}', 'x');"
        "INSERT INTO fit_runs VALUES(1, 1);"
        "COMMIT;";
    ASSERT_EQ(sqlite3_exec(raw, rows.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  EXPECT_TRUE(integrity_ok(db));
  EXPECT_EQ(db.segment_stats(1)->front().quality.verdict, "unassessed");
  EXPECT_EQ((*db.fit(1))->quality.verdict, "unassessed");
  EXPECT_EQ((*db.fit(1))->quality.reasons, std::vector<std::string>{});

  ASSERT_TRUE(db.lab_bind("lab-3").ok());
  SegmentStatsRecord st = db.segment_stats(1)->front();
  st.quality = flagged_quality();
  ASSERT_TRUE(db.put_segment_stats(st).ok());
  const json payload = json::parse(query_text(
      db.handle(), "SELECT payload FROM outbox WHERE kind = 'table1' ORDER BY seq DESC LIMIT 1"));
  EXPECT_EQ(payload.value("quality", ""), "flagged");
  EXPECT_EQ(payload["quality_reasons_json"], json(flagged_quality().reasons));  // embedded
  EXPECT_EQ(payload["coverage"], 0.06);
  EXPECT_EQ(payload["coverage_samples"], 600);
  EXPECT_EQ(payload["longest_gap_s"], 540.25);
  // The history queued at binding has them too, as the old rows hold them.
  const json history = json::parse(query_text(
      db.handle(), "SELECT payload FROM outbox WHERE kind = 'fit' ORDER BY seq LIMIT 1"));
  EXPECT_EQ(history.value("quality", ""), "unassessed");
  EXPECT_TRUE(history.contains("coverage"));
}

// The documented query (docs/storage.md "Result quality (v11)"): every
// flagged result of run 7, with why.
TEST(ResultQualityStorage, DocumentedQueryListsTheFlaggedResults) {
  const std::string doc =
      gyrotherm::testing::read_text(std::string(GYROTHERM_SOURCE_DIR) + "/docs/storage.md");
  std::string query;
  for (std::size_t at = 0; (at = doc.find("```sql\n", at)) != std::string::npos;) {
    at += 7;
    const std::size_t end = doc.find("```", at);
    ASSERT_NE(end, std::string::npos);
    const std::string block = doc.substr(at, end - at);
    at = end + 3;
    if (block.find("quality_reasons_json") != std::string::npos) query = block;
  }
  ASSERT_FALSE(query.empty()) << "the documented result-quality query is gone: update this test";

  TempDir dir;
  Database db = open_ok(dir.file("station.db"));
  for (int i = 0; i < 7; ++i) a_run(db);  // run 7 is the last, its segment 7
  const ResultQuality q = flagged_quality();
  SegmentStatsRecord st;
  st.run_id = 7;
  st.segment_id = 7;
  st.quality = q;
  ASSERT_TRUE(db.put_segment_stats(st).ok());
  FitRecord f;
  f.run_ids = {7};
  f.model = "T1";
  f.form = "centered";
  f.coefficients_json = f.standard_errors_json = "{}";
  f.quality = q;
  ASSERT_TRUE(db.add_fit(f).ok());
  f.quality.verdict = "ok";
  f.quality.reasons.clear();
  ASSERT_TRUE(db.add_fit(f).ok());  // not listed
  ScaleFactorFitRecord sf;
  sf.sf_sequence = 2;
  sf.quality = q;
  ASSERT_TRUE(db.store_scale_factor(7, {}, {sf}, std::nullopt).ok());

  sqlite3_stmt* st_query = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db.handle(), query.c_str(), -1, &st_query, nullptr), SQLITE_OK)
      << sqlite3_errmsg(db.handle()) << "\n"
      << query;
  std::vector<std::string> results;
  while (sqlite3_step(st_query) == SQLITE_ROW) {
    results.push_back(reinterpret_cast<const char*>(sqlite3_column_text(st_query, 0)));
    EXPECT_EQ(json::parse(reinterpret_cast<const char*>(sqlite3_column_text(st_query, 4))),
              json(q.reasons));
  }
  sqlite3_finalize(st_query);
  EXPECT_EQ(results, (std::vector<std::string>{"Table I", "fit centered", "scale factor 2"}));
}

}  // namespace
}  // namespace gyrotherm::storage

// The reads of `gyrotherm lab` (central.h): stations, runs, one run, one
// DUT's history, from the views of the lab schema (central_migrations.cpp).
// Every value a user gives travels as a statement parameter; the SQL text
// holds only the names of views and columns written here.
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <map>
#include <nlohmann/json.hpp>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/lab/central.h"
#include "read_util.h"

namespace gyrotherm::lab {

using nlohmann::json;

namespace internal {

std::string str(const nlohmann::json& row, const char* key) {
  if (!row.is_object()) return "";
  const auto it = row.find(key);
  return it != row.end() && it->is_string() ? it->get<std::string>() : std::string();
}

Error read_error(const PgConnection& pg, std::string_view what, const Error& error) {
  const std::string& state = pg.last_sqlstate();
  std::string hint;
  // 42P01 undefined table, 3F000 undefined schema: not migrated yet (or
  // another database). 42501: the role is neither a reader nor an
  // administrator.
  if (state == "42P01" || state == "3F000") {
    hint = " (is this the lab database, and migrated? gyrotherm lab migrate)";
  } else if (state == "42501") {
    hint = " (the role may not read the lab: gyrotherm lab add-reader ROLE makes a reader)";
  }
  return Error{fmt::format("reading {}: {}{}", what, error.message, hint), error.transient};
}

Result<ReadSnapshot> ReadSnapshot::begin(PgConnection& pg) {
  auto begun =
      pg.exec("BEGIN ISOLATION LEVEL REPEATABLE READ READ ONLY; SET LOCAL TIME ZONE 'UTC'");
  if (!begun) {
    (void)pg.exec("ROLLBACK");
    return read_error(pg, "the lab database", begun.error());
  }
  return ReadSnapshot(pg);
}

ReadSnapshot::~ReadSnapshot() {
  if (pg_ != nullptr) (void)pg_->exec("ROLLBACK");
}

Result<std::vector<json>> json_rows(PgConnection& pg, std::string_view what, std::string_view sql,
                                    const Params& params) {
  auto rows = pg.exec_params(sql, params);
  if (!rows) return read_error(pg, what, rows.error());
  std::vector<json> out;
  out.reserve(rows->rows.size());
  for (const auto& row : rows->rows) {
    if (row.empty() || !row[0]) continue;
    json j = json::parse(*row[0], nullptr, false);
    if (j.is_discarded()) {
      return Error::Permanent(
          fmt::format("reading {}: the server sent a row that is not JSON", what));
    }
    out.push_back(std::move(j));
  }
  return out;
}

std::string utc_text(std::string_view column) {
  return fmt::format(R"(to_char({} AT TIME ZONE 'UTC', 'YYYY-MM-DD"T"HH24:MI:SS.MS"Z"'))", column);
}

Result<std::string> normalize_since(const std::string& since) {
  if (since.empty()) return std::string();
  auto unix_s = parse_utc_iso(since);
  if (!unix_s) return Error::Permanent(fmt::format("since: {}", unix_s.error().message));
  return utc_iso(*unix_s);
}

}  // namespace internal

namespace {

using internal::json_rows;
using internal::Params;
using internal::read_error;
using internal::ReadSnapshot;
using internal::str;
using internal::utc_text;

// Orders text ids ("12", "3/17-0042/x") by their first number, then as
// text: local ids are the stations' integer keys as text.
std::string numeric_order(std::string_view column) {
  return fmt::format(
      "(CASE WHEN ({0})::text ~ '^[0-9]{{1,18}}$' THEN ({0})::text::bigint END), ({0})::text",
      column);
}

std::optional<std::string> opt(const std::string& s) {
  return s.empty() ? std::nullopt : std::optional<std::string>(s);
}

std::string text_or(const std::optional<std::string>& v, std::string fallback = "") {
  return v ? *v : fallback;
}

int64_t int_or(const std::optional<std::string>& v, int64_t fallback = 0) {
  if (!v) return fallback;
  try {
    return std::stoll(*v);
  } catch (const std::exception&) {
    return fallback;
  }
}

// A JSON array's items as text (strings as they are, other values dumped).
std::vector<std::string> string_list(const std::optional<std::string>& text) {
  std::vector<std::string> out;
  if (!text) return out;
  const json j = json::parse(*text, nullptr, false);
  if (!j.is_array()) return out;
  for (const auto& item : j)
    out.push_back(item.is_string() ? item.get<std::string>() : item.dump());
  return out;
}

bool is_uuid(std::string_view s) {
  if (s.size() != 36) return false;
  for (std::size_t i = 0; i < s.size(); ++i) {
    const bool dash = i == 8 || i == 13 || i == 18 || i == 23;
    if (dash ? s[i] != '-' : !std::isxdigit(static_cast<unsigned char>(s[i]))) return false;
  }
  return true;
}

bool is_whole_number(std::string_view s) {
  return !s.empty() && s.size() <= 18 &&
         std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

struct RunKey {
  std::string station_id;
  std::string run_uuid;
};

// `run` (a run UUID, or "STATION/LOCAL_ID") as the run's key in the lab.
Result<RunKey> resolve_run(PgConnection& pg, const std::string& run) {
  if (is_uuid(run)) {
    std::string uuid = run;
    std::transform(uuid.begin(), uuid.end(), uuid.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    auto rows = pg.exec_params(
        "SELECT station_id, local_run_id FROM lab.runs WHERE run_uuid = $1::uuid "
        "ORDER BY station_id",
        {uuid});
    if (!rows) return read_error(pg, "lab.runs", rows.error());
    if (rows->rows.empty()) return Error::Permanent(fmt::format("no run {} in the lab", run));
    if (rows->rows.size() > 1) {
      // One UUID at two stations: a database copied from one station to
      // another. Only STATION/LOCAL_ID tells them apart.
      std::vector<std::string> where;
      for (const auto& r : rows->rows) {
        where.push_back(fmt::format("{}/{}", text_or(r[0]), text_or(r[1])));
      }
      return Error::Permanent(
          fmt::format("run {} is at more than one station ({}): name it as "
                      "STATION/LOCAL_ID",
                      run, fmt::join(where, ", ")));
    }
    return RunKey{text_or(rows->rows[0][0]), uuid};
  }
  const auto slash = run.rfind('/');
  const std::string station = slash == std::string::npos ? "" : run.substr(0, slash);
  const std::string local = slash == std::string::npos ? "" : run.substr(slash + 1);
  if (station.empty() || !is_whole_number(local)) {
    return Error::Permanent(
        fmt::format("run \"{}\": give a run UUID or STATION/LOCAL_ID (e.g. station-3/12)", run));
  }
  auto rows = pg.exec_params(
      "SELECT run_uuid::text FROM lab.runs WHERE station_id = $1 AND local_run_id = $2::bigint",
      {station, local});
  if (!rows) return read_error(pg, "lab.runs", rows.error());
  if (rows->rows.empty()) {
    auto known = pg.exec_params("SELECT 1 FROM lab.stations WHERE station_id = $1", {station});
    if (!known) return read_error(pg, "lab.stations", known.error());
    if (known->rows.empty()) {
      return Error::Permanent(
          fmt::format("no run {} in the lab: no station \"{}\" is registered", run, station));
    }
    return Error::Permanent(
        fmt::format("no run {} in the lab (station {} has not relayed it)", run, station));
  }
  return RunKey{station, text_or(rows->rows[0][0])};
}

// What `run` and `dut` read of a run besides the run itself: (name in the
// JSON, view, order).
struct Section {
  const char* name;
  const char* view;
  std::string order;
};

std::vector<Section> run_sections() {
  return {
      {"duts", "lab.run_duts", "t.position, t.dut_serial"},
      {"segments", "lab.segments", "t.idx, " + numeric_order("t.local_segment_id")},
      {"table1", "lab.table1", "t.dut_serial, t.axis, t.segment_index"},
      {"allan", "lab.allan", "t.dut_serial, t.axis, t.segment_index, t.taus"},
      {"fits", "lab.fits", numeric_order("t.fit_local_id")},
      {"scale_factor_fits", "lab.scale_factor_fits", "t.dut_serial, t.axis, t.sf_sequence"},
      {"scale_factor_temperature_fits", "lab.scale_factor_temperature_fits",
       "t.dut_serial, t.axis"},
      // In the order the station recorded them (its event ids), as
      // `gyrotherm run` lists them.
      {"events", "lab.events", numeric_order("t.local_id")},
  };
}

// The fits of lab.fits come one row per fit and run; each row also carries
// the local ids of every run of its fit (its station's), as `run_ids`.
constexpr const char* kFitRunIds =
    "(SELECT coalesce(jsonb_agg(r2.local_run_id ORDER BY r2.local_run_id), '[]'::jsonb) "
    "FROM lab.fits f2 JOIN lab.runs r2 ON r2.station_id = f2.station_id AND "
    "r2.run_uuid = f2.run_uuid "
    "WHERE f2.station_id = t.station_id AND f2.fit_local_id = t.fit_local_id)";

std::string row_json(const Section& s) {
  if (std::string_view(s.view) == "lab.fits") {
    return fmt::format("to_jsonb(t) || jsonb_build_object('run_ids', {})", kFitRunIds);
  }
  return "to_jsonb(t)";
}

// Drops the key columns every row of a run repeats.
json without_run_key(json row) {
  if (row.is_object()) {
    row.erase("station_id");
    row.erase("run_uuid");
  }
  return row;
}

// The runs a DUT was in, by (station_id, run_uuid): recorded in it
// (run_duts), declared for it when queued, or with results of its serial
// (runs recorded before DUTs had records).
constexpr const char* kDutRunKeys = R"sql(
WITH keys AS (
  SELECT station_id, run_uuid FROM lab.run_duts WHERE dut_serial = $1
  UNION SELECT station_id, run_uuid FROM lab.runs WHERE coalesce(dut_serials, '[]'::jsonb) ? $1
  UNION SELECT station_id, run_uuid FROM lab.table1 WHERE dut_serial = $1
  UNION SELECT station_id, run_uuid FROM lab.allan WHERE dut_serial = $1
  UNION SELECT station_id, run_uuid FROM lab.scale_factor_fits WHERE dut_serial = $1
  UNION SELECT station_id, run_uuid FROM lab.scale_factor_temperature_fits WHERE dut_serial = $1
  UNION SELECT station_id, run_uuid FROM lab.fits WHERE dut_serial = $1
)
)sql";

std::string run_key(const json& row) {
  return str(row, "station_id") + "\n" + str(row, "run_uuid");
}

}  // namespace

namespace internal {

Result<std::vector<LabStation>> read_stations(PgConnection& pg) {
  auto rows =
      pg.exec(fmt::format("SELECT station_id, db_role::text, coalesce(description, ''), {}, {}, "
                          "coalesce(last_seq, 0), coalesce(runs, 0), coalesce(records, 0) "
                          "FROM lab.station_overview ORDER BY station_id",
                          utc_text("registered_at"), utc_text("last_batch_at")));
  if (!rows) return read_error(pg, "lab.station_overview", rows.error());
  std::vector<LabStation> out;
  for (const auto& r : rows->rows) {
    LabStation s;
    s.station_id = text_or(r[0]);
    s.db_role = text_or(r[1]);
    s.description = text_or(r[2]);
    s.registered_utc = text_or(r[3]);
    s.last_batch_utc = r[4];
    s.last_seq = int_or(r[5]);
    s.runs = int_or(r[6]);
    s.records = int_or(r[7]);
    out.push_back(std::move(s));
  }
  return out;
}

Result<std::vector<LabRun>> read_runs(PgConnection& pg, const LabRunFilter& filter) {
  auto since = normalize_since(filter.since_utc);
  if (!since) return since.error();
  // The DUTs of a run are those it recorded, by position; a run that
  // recorded none (not started, or from before DUTs) shows the serials
  // declared when it was queued.
  constexpr const char* kSql = R"sql(
SELECT r.station_id, r.run_uuid::text, r.local_run_id, r.schedule_name, r.state,
       coalesce(r.started_utc, ''), coalesce(r.ended_utc, ''), coalesce(r.operator, ''),
       coalesce(r.comment, ''), coalesce(r.tags, '[]'::jsonb)::text,
       coalesce((SELECT jsonb_agg(d.dut_serial ORDER BY d.position, d.dut_serial)
                 FROM lab.run_duts d
                 WHERE d.station_id = r.station_id AND d.run_uuid = r.run_uuid),
                r.dut_serials, '[]'::jsonb)::text
FROM lab.runs r
WHERE ($1::text IS NULL OR r.station_id = $1)
  AND ($2::text IS NULL
       OR EXISTS (SELECT 1 FROM lab.run_duts d
                  WHERE d.station_id = r.station_id AND d.run_uuid = r.run_uuid
                    AND d.dut_serial = $2)
       OR coalesce(r.dut_serials, '[]'::jsonb) ? $2)
  AND ($3::text IS NULL OR r.started_utc >= $3)
ORDER BY r.started_utc DESC, r.station_id, r.local_run_id DESC
LIMIT $4::bigint
)sql";
  const Params params = {
      opt(filter.station_id), opt(filter.dut_serial), opt(*since),
      filter.limit > 0 ? std::optional<std::string>(std::to_string(filter.limit)) : std::nullopt};
  auto rows = pg.exec_params(kSql, params);
  if (!rows) return read_error(pg, "lab.runs", rows.error());
  std::vector<LabRun> out;
  for (const auto& r : rows->rows) {
    LabRun run;
    run.station_id = text_or(r[0]);
    run.run_uuid = text_or(r[1]);
    run.local_run_id = int_or(r[2]);
    run.schedule_name = text_or(r[3]);
    run.state = text_or(r[4]);
    run.started_utc = text_or(r[5]);
    run.ended_utc = text_or(r[6]);
    run.operator_name = text_or(r[7]);
    run.comment = text_or(r[8]);
    run.tags = string_list(r[9]);
    run.dut_serials = string_list(r[10]);
    out.push_back(std::move(run));
  }
  return out;
}

}  // namespace internal

Result<std::vector<LabStation>> lab_stations(PgConnection& pg) {
  auto snapshot = ReadSnapshot::begin(pg);
  if (!snapshot) return snapshot.error();
  return internal::read_stations(pg);
}

Result<std::vector<LabRun>> lab_runs(PgConnection& pg, const LabRunFilter& filter) {
  if (auto since = internal::normalize_since(filter.since_utc); !since) return since.error();
  auto snapshot = ReadSnapshot::begin(pg);
  if (!snapshot) return snapshot.error();
  return internal::read_runs(pg, filter);
}

Result<std::string> lab_run_json(PgConnection& pg, const std::string& run) {
  auto snapshot = ReadSnapshot::begin(pg);
  if (!snapshot) return snapshot.error();
  auto key = resolve_run(pg, run);
  if (!key) return key.error();
  const Params params = {key->station_id, key->run_uuid};
  auto run_row = json_rows(pg, "lab.runs",
                           "SELECT to_jsonb(t) FROM lab.runs t "
                           "WHERE t.station_id = $1 AND t.run_uuid = $2::uuid",
                           params);
  if (!run_row) return run_row.error();
  if (run_row->empty()) return Error::Permanent(fmt::format("no run {} in the lab", run));
  json out = json::object({{"run", run_row->front()}});
  for (const Section& s : run_sections()) {
    auto rows = json_rows(pg, s.view,
                          fmt::format("SELECT {} FROM {} t WHERE t.station_id = $1 AND "
                                      "t.run_uuid = $2::uuid ORDER BY {}",
                                      row_json(s), s.view, s.order),
                          params);
    if (!rows) return rows.error();
    json list = json::array();
    for (auto& r : *rows) list.push_back(without_run_key(std::move(r)));
    out[s.name] = std::move(list);
  }
  return out.dump();
}

Result<std::string> lab_dut_json(PgConnection& pg, const std::string& serial) {
  auto snapshot = ReadSnapshot::begin(pg);
  if (!snapshot) return snapshot.error();
  const Params params = {serial};
  // Each run with the DUT's place in it (null when it recorded no DUTs).
  auto runs = json_rows(pg, "lab.runs", std::string(kDutRunKeys) + R"sql(
SELECT to_jsonb(r) || jsonb_build_object('dut',
         (SELECT to_jsonb(d) - 'station_id' - 'run_uuid' - 'local_run_id' FROM lab.run_duts d
          WHERE d.station_id = r.station_id AND d.run_uuid = r.run_uuid AND d.dut_serial = $1
          LIMIT 1))
FROM lab.runs r JOIN keys k ON k.station_id = r.station_id AND k.run_uuid = r.run_uuid
ORDER BY r.started_utc, r.station_id, r.local_run_id
)sql",
                        params);
  if (!runs) return runs.error();
  if (runs->empty()) {
    return Error::Permanent(
        fmt::format("no DUT \"{}\" in the lab (no station relayed a run of it)", serial));
  }

  json out = {{"serial", serial}, {"model", ""}, {"first_seen_utc", nullptr}};
  json stations = json::array();
  json run_list = json::array();
  std::map<std::string, std::size_t> index;  // run_key -> position in run_list
  for (auto& r : *runs) {
    json dut = r.contains("dut") ? r["dut"] : json(nullptr);
    r.erase("dut");
    const std::string station = str(r, "station_id");
    if (std::find(stations.begin(), stations.end(), json(station)) == stations.end()) {
      stations.push_back(station);
    }
    if (!str(dut, "model").empty()) out["model"] = str(dut, "model");
    if (out["first_seen_utc"].is_null() && r.contains("started_utc")) {
      out["first_seen_utc"] = r["started_utc"];
    }
    index[run_key(r)] = run_list.size();
    run_list.push_back({{"station_id", station},
                        {"run", std::move(r)},
                        {"dut", std::move(dut)},
                        {"segments", json::array()},
                        {"table1", json::array()},
                        {"allan", json::array()},
                        {"fits", json::array()},
                        {"scale_factor_fits", json::array()},
                        {"scale_factor_temperature_fits", json::array()}});
  }

  // The results of this serial, each put under its run.
  for (const Section& s : run_sections()) {
    const std::string name = s.name;
    if (name == "duts" || name == "events") continue;
    const std::string sql = name == "segments"
                                ? fmt::format(
                                      "{}SELECT to_jsonb(t) FROM lab.segments t JOIN keys k ON "
                                      "k.station_id = t.station_id AND k.run_uuid = t.run_uuid "
                                      "ORDER BY t.station_id, t.run_uuid, {}",
                                      kDutRunKeys, s.order)
                                : fmt::format(
                                      "SELECT {} FROM {} t WHERE t.dut_serial = $1 "
                                      "ORDER BY t.station_id, t.run_uuid, {}",
                                      row_json(s), s.view, s.order);
    auto rows = json_rows(pg, s.view, sql, params);
    if (!rows) return rows.error();
    for (auto& row : *rows) {
      const auto it = index.find(run_key(row));
      if (it == index.end()) continue;  // a result whose run record is not (yet) relayed
      run_list[it->second][name].push_back(without_run_key(std::move(row)));
    }
  }

  // The DUT's drift fits, one per fit (a fit may span runs of its station).
  auto fits = json_rows(pg, "lab.fits",
                        fmt::format("SELECT DISTINCT ON (t.station_id, t.fit_local_id) "
                                    "to_jsonb(t) - 'run_uuid' - 'local_run_id' || "
                                    "jsonb_build_object('run_ids', {}) "
                                    "FROM lab.fits t WHERE t.dut_serial = $1 "
                                    "ORDER BY t.station_id, t.fit_local_id",
                                    kFitRunIds),
                        params);
  if (!fits) return fits.error();
  json fit_list = json::array();
  for (auto& f : *fits) fit_list.push_back(std::move(f));
  std::stable_sort(fit_list.begin(), fit_list.end(), [](const json& a, const json& b) {
    return str(a, "computed_utc") < str(b, "computed_utc");
  });

  out["stations"] = std::move(stations);
  out["runs"] = std::move(run_list);
  out["fits"] = std::move(fit_list);
  return out.dump();
}

}  // namespace gyrotherm::lab

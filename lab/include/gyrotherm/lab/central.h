// The lab database: one PostgreSQL for every station (docs/lab.md).
//
// Schema `lab`, created and migrated by versioned migrations
// (lab.schema_migrations), applied by an administrator with
// `gyrotherm lab migrate` (never by a station). Every relayed record is one
// row of lab.records keyed (station_id, run_uuid, kind, local_id), its
// payload the station's row as JSON; typed views (lab.runs, lab.table1,
// ...) read them. Row-level security lets a station's role insert and
// update only rows of the station id registered to it (lab.stations), and
// readers (role gyrotherm_reader) only read.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/lab/pg.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::lab {

inline constexpr int kCentralSchemaVersion = 4;

// A station id lab.stations accepts (its CHECK): a letter or digit, then up
// to 63 letters, digits, '.', '_' or '-'.
bool valid_station_id(const std::string& id);

// The version of the lab schema in the database (0: none yet).
Result<int> central_schema_version(PgConnection& pg);
// Applies every migration the database lacks, one transaction each, under
// an advisory lock (two administrators at once: one waits). Needs a role
// that may create schemas and roles. A database with a newer schema than
// this build knows is a permanent error. Returns the version reached.
Result<int> migrate_central(PgConnection& pg);

// Registers a station: rows of `station_id` may be written by login role
// `db_role` only (created LOGIN without a password when missing: the
// administrator sets its password or certificate), made a member of
// gyrotherm_station. Re-registering the same pair is a
// no-op; the id taken by another role, or the role by another id, is an
// error naming both.
Status add_station(PgConnection& pg, const std::string& station_id, const std::string& db_role,
                   const std::string& description = "");
// Creates (if missing) login role `db_role` as a member of gyrotherm_reader.
Status add_reader(PgConnection& pg, const std::string& db_role);

// The relay's check at connect, before it sends anything: `station_id` is
// registered in lab.stations to the role this connection logged in as. A
// permanent error says what is wrong (not registered, registered to
// another role, the role may not read lab.stations, no lab schema); a lost
// connection is transient.
Status check_station(PgConnection& pg, const std::string& station_id);

// What a relay batch did centrally.
struct PushResult {
  int64_t upserted = 0;  // rows inserted or updated
  int64_t redelivered =
      0;              // rows whose (key, outbox_seq) was already there (at-least-once replays)
  int64_t stale = 0;  // rows older (outbox_seq) than the one already there: ignored
};

// Why the lab refused a batch for good (the relay stops retrying it).
inline constexpr std::string_view kRefusedSqlstates[] = {"42501", "23503"};

// Writes one batch in one transaction: every record upserted on
// (station_id, run_uuid, kind, local_id), newer outbox_seq wins (a replay
// or an older version never overwrites a newer one), tombstones mark the
// row deleted; lab.relay_progress of the station advanced to the batch's
// last seq. Records of the same key within the batch are reduced to the
// last. Nothing is written when any row is refused. A refusal (row-level
// security: the station id is not the connecting role's; an unregistered
// id) is a permanent error whose message says so; a lost connection is
// transient.
Result<PushResult> push_batch(PgConnection& pg, const std::string& station_id,
                              std::span<const storage::OutboxRecord> batch);

// Reads for `gyrotherm lab` (from the views; any role that may read).
struct LabStation {
  std::string station_id;
  std::string db_role;
  std::string description;
  std::string registered_utc;
  std::optional<std::string> last_batch_utc;  // nullopt: never relayed
  int64_t last_seq = 0;
  int64_t runs = 0;
  int64_t records = 0;
};
struct LabRun {
  std::string station_id;
  std::string run_uuid;
  int64_t local_run_id = 0;
  std::string schedule_name;
  std::string state;
  std::string started_utc;
  std::string ended_utc;  // "" while running
  std::string operator_name;
  std::string comment;
  std::vector<std::string> tags;
  std::vector<std::string> dut_serials;  // DUTs of the run (run_duts), by position
};
struct LabRunFilter {
  std::string station_id;  // "" = every station
  std::string dut_serial;  // "" = every DUT
  std::string since_utc;   // "" = no bound (started_utc >= since)
  int limit = 200;
};
Result<std::vector<LabStation>> lab_stations(PgConnection& pg);
Result<std::vector<LabRun>> lab_runs(PgConnection& pg, const LabRunFilter& filter);
// One run with everything relayed for it, as the JSON the CLI prints:
// {"run":{...}, "duts":[...], "segments":[...], "table1":[...], "allan":[...],
//  "fits":[...], "scale_factor_fits":[...], "scale_factor_temperature_fits":[...],
//  "events":[...]}. `run` is a run_uuid, or "STATION/LOCAL_ID". Error naming
// it when unknown.
Result<std::string> lab_run_json(PgConnection& pg, const std::string& run);
// A DUT's history across stations: every run it was in (station, run,
// segments' Table I per axis, Allan, scale factor, fits), as JSON
// {"serial":..., "runs":[{"station_id":..., "run":{...}, "table1":[...], ...}]}.
Result<std::string> lab_dut_json(PgConnection& pg, const std::string& serial);

// The lab summary page: the nightly report's campaign summary across
// stations and DUTs, from the lab database. One self-contained HTML page
// (no external request): the stations and their relay progress, the runs
// (station, schedule, state, operator, DUTs, tags), and per DUT serial and
// axis, Table I across runs and stations (bias, std, std after the moving
// average per set point), the drift fits' coefficients, Allan noise terms
// and scale factor.
struct LabSummaryOptions {
  std::string since_utc;      // "" = every run
  std::string generated_utc;  // "" = now
  std::string server;         // shown in the provenance (no password)
};
Result<std::string> lab_summary_html(PgConnection& pg, const LabSummaryOptions& options);

}  // namespace gyrotherm::lab

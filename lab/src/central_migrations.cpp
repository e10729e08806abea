// The lab database's schema (`lab`) and its versioned migrations
// (docs/lab.md "Central schema"). Each migration runs in its own
// transaction under a transaction-scoped advisory lock, so two
// administrators migrating at once serialise: the second sees the first's
// version and applies nothing.
#include <fmt/format.h>

#include <string>

#include "gyrotherm/lab/central.h"
#include "pg_transaction.h"

namespace gyrotherm::lab {
namespace {

// pg_advisory_xact_lock key of lab migrations: "gyrolab" in ASCII.
constexpr const char* kMigrationLockSql = "SELECT pg_advisory_xact_lock(29104238963630434)";

// v1: stations, their records and relay progress; the two group roles,
// their grants and the row-level security that keeps each station to its
// own rows; the typed views readers use.
//
// Every relayed row is one lab.records row whose payload is the station's
// SQLite row as JSON (the outbox triggers' json_object of its columns,
// *_json columns embedded as JSON). The views read the payload: text as
// text, numbers through lab.jsonb_float8/lab.jsonb_int8 (NULL for a JSON
// null or a non-number, so one odd row never breaks a view), *_json
// columns as jsonb; tombstones (deleted) are left out; the nil run UUID
// (rows outside any run) reads as NULL. The views are security_invoker:
// what a role sees through them is what row-level security lets it see in
// lab.records (every row for gyrotherm_reader).
constexpr const char* kCentralV1 = R"sql(
CREATE SCHEMA IF NOT EXISTS lab;
COMMENT ON SCHEMA lab IS 'gyrotherm lab database: results relayed by every station (docs/lab.md)';

-- Roles are cluster-wide: another database of the cluster (or another
-- administrator, concurrently) may have created them already.
DO $$
BEGIN
  CREATE ROLE gyrotherm_station NOLOGIN;
EXCEPTION WHEN duplicate_object OR unique_violation THEN NULL;
END
$$;
DO $$
BEGIN
  CREATE ROLE gyrotherm_reader NOLOGIN;
EXCEPTION WHEN duplicate_object OR unique_violation THEN NULL;
END
$$;

CREATE TABLE lab.schema_migrations(
  version int PRIMARY KEY,
  description text,
  applied_at timestamptz DEFAULT now()
);

CREATE TABLE lab.stations(
  station_id text PRIMARY KEY CHECK (station_id ~ '^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$'),
  db_role name NOT NULL UNIQUE,
  description text NOT NULL DEFAULT '',
  registered_at timestamptz NOT NULL DEFAULT now()
);
COMMENT ON TABLE lab.stations IS
  'registered stations: rows of station_id may be written by login role db_role only';

CREATE TABLE lab.records(
  station_id text NOT NULL REFERENCES lab.stations,
  run_uuid uuid NOT NULL,
  kind text NOT NULL,
  local_id text NOT NULL,
  outbox_seq bigint NOT NULL,
  deleted boolean NOT NULL DEFAULT false,
  payload jsonb NOT NULL,
  station_committed_at timestamptz NOT NULL,
  central_committed_at timestamptz NOT NULL DEFAULT now(),
  redeliveries integer NOT NULL DEFAULT 0,
  PRIMARY KEY (station_id, run_uuid, kind, local_id)
);
COMMENT ON TABLE lab.records IS
  'every relayed row of every station, keyed (station_id, run_uuid, kind, local_id); payload: the station''s row as JSON; the highest outbox_seq wins';
COMMENT ON COLUMN lab.records.run_uuid IS
  'the run''s uuid; 00000000-0000-0000-0000-000000000000 for rows outside a run (duts, fits, exports, station events)';
COMMENT ON COLUMN lab.records.kind IS
  'run, segment, event, table1, allan, fit, fit_run, export, export_run, sf_point, sf_fit, sf_temperature_fit, dut, run_dut, channel';
COMMENT ON COLUMN lab.records.outbox_seq IS 'the station''s outbox seq of the version held';
COMMENT ON COLUMN lab.records.deleted IS 'a tombstone: the row was deleted on the station';
COMMENT ON COLUMN lab.records.station_committed_at IS 'when the station committed this version (its wall clock)';
COMMENT ON COLUMN lab.records.central_committed_at IS 'when the lab committed this version (transaction time; kept on redelivery)';
COMMENT ON COLUMN lab.records.redeliveries IS
  'times a version already held arrived again (at-least-once replays), over every version of the key';
-- Reads by run (lab run), by kind across stations (joins of the views), by DUT.
CREATE INDEX records_by_run ON lab.records(run_uuid, kind);
CREATE INDEX records_by_kind ON lab.records(kind, station_id, local_id);
CREATE INDEX records_by_dut_serial ON lab.records(kind, (payload->>'dut_serial'));

CREATE TABLE lab.relay_progress(
  station_id text PRIMARY KEY REFERENCES lab.stations,
  last_seq bigint NOT NULL,
  last_batch_at timestamptz NOT NULL,
  batches bigint NOT NULL,
  records bigint NOT NULL
);
COMMENT ON TABLE lab.relay_progress IS
  'per station: highest outbox seq received, last batch (lab time), batches and records received (replays included)';

ALTER TABLE lab.records ENABLE ROW LEVEL SECURITY;
ALTER TABLE lab.relay_progress ENABLE ROW LEVEL SECURITY;
CREATE POLICY station_own_rows ON lab.records FOR ALL TO gyrotherm_station
  USING (station_id IN (SELECT station_id FROM lab.stations WHERE db_role = current_user))
  WITH CHECK (station_id IN (SELECT station_id FROM lab.stations WHERE db_role = current_user));
CREATE POLICY reader_all_rows ON lab.records FOR SELECT TO gyrotherm_reader USING (true);
CREATE POLICY station_own_rows ON lab.relay_progress FOR ALL TO gyrotherm_station
  USING (station_id IN (SELECT station_id FROM lab.stations WHERE db_role = current_user))
  WITH CHECK (station_id IN (SELECT station_id FROM lab.stations WHERE db_role = current_user));
CREATE POLICY reader_all_rows ON lab.relay_progress FOR SELECT TO gyrotherm_reader USING (true);

-- A JSON number as float8 (beyond float8's range: +-Infinity; SQLite
-- writes an infinite REAL as 9.0e+999), else NULL.
CREATE FUNCTION lab.jsonb_float8(j jsonb) RETURNS float8
LANGUAGE sql IMMUTABLE PARALLEL SAFE AS $$
  SELECT CASE WHEN jsonb_typeof(j) = 'number' THEN
    CASE WHEN abs(j::numeric) > 1.7976931348623157e308
         THEN sign(j::numeric)::float8 * 'Infinity'::float8
         ELSE j::numeric::float8 END
  END
$$;
-- A JSON number as bigint (rounded), else NULL.
CREATE FUNCTION lab.jsonb_int8(j jsonb) RETURNS bigint
LANGUAGE sql IMMUTABLE PARALLEL SAFE AS $$
  SELECT CASE WHEN jsonb_typeof(j) = 'number' AND abs(j::numeric) < 9223372036854775807
    THEN round(j::numeric)::bigint END
$$;

CREATE VIEW lab.runs WITH (security_invoker = true) AS
SELECT r.station_id,
       NULLIF(r.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(r.payload->'id') AS local_run_id,
       r.payload->>'schedule_name' AS schedule_name,
       r.payload->>'state' AS state,
       r.payload->>'started_utc' AS started_utc,
       r.payload->>'ended_utc' AS ended_utc,
       r.payload->>'operator' AS operator,
       r.payload->>'comment' AS comment,
       r.payload->'tags_json' AS tags,
       r.payload->'dut_serials_json' AS dut_serials,
       lab.jsonb_float8(r.payload->'time_scale') AS time_scale,
       r.central_committed_at
FROM lab.records r
WHERE r.kind = 'run' AND NOT r.deleted;

CREATE VIEW lab.run_duts WITH (security_invoker = true) AS
SELECT rd.station_id,
       NULLIF(rd.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(rd.payload->'run_id') AS local_run_id,
       d.payload->>'serial' AS dut_serial,
       d.payload->>'model' AS model,
       lab.jsonb_int8(rd.payload->'position') AS position,
       rd.payload->>'primary_axis' AS primary_axis,
       rd.payload->'axes_json' AS axes,
       lab.jsonb_float8(rd.payload->'rate_hz') AS rate_hz
FROM lab.records rd
LEFT JOIN lab.records d
  ON d.station_id = rd.station_id AND d.kind = 'dut' AND NOT d.deleted
     AND d.local_id = rd.payload->>'dut_id'
WHERE rd.kind = 'run_dut' AND NOT rd.deleted;

CREATE VIEW lab.segments WITH (security_invoker = true) AS
SELECT s.station_id,
       NULLIF(s.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(s.payload->'id') AS local_segment_id,
       lab.jsonb_int8(s.payload->'idx') AS idx,
       s.payload->>'kind' AS kind,
       s.payload->>'label' AS label,
       lab.jsonb_float8(s.payload->'setpoint_c') AS setpoint_c,
       s.payload->>'state' AS state,
       lab.jsonb_float8(s.payload->'t_start_s') AS t_start_s,
       lab.jsonb_float8(s.payload->'t_end_s') AS t_end_s,
       s.payload->>'table_mode' AS table_mode,
       lab.jsonb_float8(s.payload->'table_rate_dps') AS table_rate_dps
FROM lab.records s
WHERE s.kind = 'segment' AND NOT s.deleted;

CREATE VIEW lab.table1 WITH (security_invoker = true) AS
SELECT t.station_id,
       NULLIF(t.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       t.payload->>'dut_serial' AS dut_serial,
       t.payload->>'axis' AS axis,
       lab.jsonb_int8(t.payload->'segment_id') AS segment_id,
       lab.jsonb_int8(t.payload->'segment_index') AS segment_index,
       lab.jsonb_float8(t.payload->'setpoint_c') AS setpoint_c,
       lab.jsonb_int8(t.payload->'n') AS n,
       lab.jsonb_float8(t.payload->'duration_s') AS duration_s,
       lab.jsonb_float8(t.payload->'temp_mean_c') AS temp_mean_c,
       lab.jsonb_float8(t.payload->'bias_mean_dph') AS bias_mean_dph,
       lab.jsonb_float8(t.payload->'bias_std_dph') AS bias_std_dph,
       lab.jsonb_float8(t.payload->'bias_std_ma_dph') AS bias_std_ma_dph,
       lab.jsonb_float8(t.payload->'bias_mean_earth_removed_dph') AS bias_mean_earth_removed_dph,
       lab.jsonb_float8(t.payload->'earth_rate_dph') AS earth_rate_dph,
       lab.jsonb_int8(t.payload->'ma_window') AS ma_window,
       t.payload->>'computed_utc' AS computed_utc
FROM lab.records t
WHERE t.kind = 'table1' AND NOT t.deleted;

CREATE VIEW lab.allan WITH (security_invoker = true) AS
SELECT a.station_id,
       NULLIF(a.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(a.payload->'id') AS local_id,
       a.payload->>'dut_serial' AS dut_serial,
       a.payload->>'axis' AS axis,
       lab.jsonb_int8(a.payload->'segment_index') AS segment_index,
       a.payload->>'taus' AS taus,
       lab.jsonb_int8(a.payload->'n_samples') AS n_samples,
       lab.jsonb_float8(a.payload->'angle_random_walk_dprh') AS angle_random_walk_dprh,
       lab.jsonb_float8(a.payload->'bias_instability_dph') AS bias_instability_dph,
       lab.jsonb_float8(a.payload->'bias_instability_tau_s') AS bias_instability_tau_s,
       lab.jsonb_float8(a.payload->'rate_random_walk_dphprh') AS rate_random_walk_dphprh,
       a.payload->'curve_json' AS curve,
       a.payload->>'computed_utc' AS computed_utc
FROM lab.records a
WHERE a.kind = 'allan' AND NOT a.deleted;

-- One row per fit and run it covers (a fit may span runs: fit_runs).
CREATE VIEW lab.fits WITH (security_invoker = true) AS
SELECT f.station_id,
       NULLIF(fr.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(f.payload->'id') AS fit_local_id,
       f.payload->>'model' AS model,
       f.payload->>'form' AS form,
       f.payload->>'dut_serial' AS dut_serial,
       f.payload->>'axis' AS axis,
       lab.jsonb_int8(f.payload->'n') AS n,
       f.payload->'coefficients_json' AS coefficients,
       f.payload->'standard_errors_json' AS standard_errors,
       lab.jsonb_float8(f.payload->'residual_std_dph') AS residual_std_dph,
       lab.jsonb_float8(f.payload->'r_squared') AS r_squared,
       f.payload->>'computed_utc' AS computed_utc
FROM lab.records f
JOIN lab.records fr
  ON fr.station_id = f.station_id AND fr.kind = 'fit_run' AND NOT fr.deleted
     AND fr.payload->>'fit_id' = f.local_id
WHERE f.kind = 'fit' AND NOT f.deleted;

CREATE VIEW lab.scale_factor_fits WITH (security_invoker = true) AS
SELECT k.station_id,
       NULLIF(k.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       k.payload->>'dut_serial' AS dut_serial,
       k.payload->>'axis' AS axis,
       lab.jsonb_int8(k.payload->'sf_sequence') AS sf_sequence,
       lab.jsonb_float8(k.payload->'temperature_c') AS temperature_c,
       lab.jsonb_float8(k.payload->'k') AS k,
       lab.jsonb_float8(k.payload->'k_se') AS k_se,
       lab.jsonb_float8(k.payload->'bias_dps') AS bias_dps,
       lab.jsonb_float8(k.payload->'nonlinearity_ppm') AS nonlinearity_ppm,
       lab.jsonb_float8(k.payload->'asymmetry_ppm') AS asymmetry_ppm,
       lab.jsonb_float8(k.payload->'repeatability_ppm') AS repeatability_ppm,
       lab.jsonb_int8(k.payload->'n_points') AS n_points
FROM lab.records k
WHERE k.kind = 'sf_fit' AND NOT k.deleted;

CREATE VIEW lab.scale_factor_temperature_fits WITH (security_invoker = true) AS
SELECT k.station_id,
       NULLIF(k.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       k.payload->>'dut_serial' AS dut_serial,
       k.payload->>'axis' AS axis,
       lab.jsonb_int8(k.payload->'poly_order') AS poly_order,
       lab.jsonb_float8(k.payload->'t_centre_c') AS t_centre_c,
       lab.jsonb_float8(k.payload->'k_ppm_per_c') AS k_ppm_per_c,
       lab.jsonb_float8(k.payload->'bias_dph_per_c') AS bias_dph_per_c,
       k.payload->'k_coeffs_json' AS k_coeffs,
       k.payload->'bias_coeffs_json' AS bias_coeffs
FROM lab.records k
WHERE k.kind = 'sf_temperature_fit' AND NOT k.deleted;

CREATE VIEW lab.events WITH (security_invoker = true) AS
SELECT e.station_id,
       NULLIF(e.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(e.payload->'id') AS local_id,
       lab.jsonb_float8(e.payload->'t_s') AS t_s,
       e.payload->>'wall_utc' AS wall_utc,
       e.payload->>'kind' AS kind,
       e.payload->>'from_state' AS from_state,
       e.payload->>'to_state' AS to_state,
       e.payload->>'message' AS message
FROM lab.records e
WHERE e.kind = 'event' AND NOT e.deleted;

CREATE VIEW lab.exports WITH (security_invoker = true) AS
SELECT x.station_id,
       lab.jsonb_int8(x.payload->'id') AS local_id,
       x.payload->>'kind' AS kind,
       x.payload->>'state' AS state,
       x.payload->>'directory' AS directory,
       x.payload->'files_json' AS files,
       x.payload->>'started_utc' AS started_utc,
       x.payload->>'finished_utc' AS finished_utc,
       x.payload->>'message' AS message
FROM lab.records x
WHERE x.kind = 'export' AND NOT x.deleted;

-- Every registered station, relayed or not (never relayed: last_batch_at
-- NULL, the counts 0).
CREATE VIEW lab.station_overview WITH (security_invoker = true) AS
SELECT s.station_id,
       s.db_role::text AS db_role,
       s.description,
       s.registered_at,
       coalesce(p.last_seq, 0) AS last_seq,
       p.last_batch_at,
       coalesce(p.batches, 0) AS batches,
       coalesce(p.records, 0) AS records,
       (SELECT count(*) FROM lab.runs r WHERE r.station_id = s.station_id) AS runs
FROM lab.stations s
LEFT JOIN lab.relay_progress p ON p.station_id = s.station_id;

GRANT USAGE ON SCHEMA lab TO gyrotherm_station, gyrotherm_reader;
GRANT SELECT ON lab.stations TO gyrotherm_station;
GRANT SELECT, INSERT, UPDATE ON lab.records, lab.relay_progress TO gyrotherm_station;
GRANT SELECT ON ALL TABLES IN SCHEMA lab TO gyrotherm_reader;
)sql";

// v2: the quality of every result (the station's schema v11,
// docs/analysis.md "Result quality"): lab.table1, lab.allan, lab.fits and
// lab.scale_factor_fits gain coverage, longest_gap_s, quality ('ok',
// 'flagged', 'excluded'; 'unassessed' for rows relayed before the
// station's v11) and quality_reasons (a JSON array), appended to their
// columns.
constexpr const char* kCentralV2 = R"sql(
CREATE OR REPLACE VIEW lab.table1 WITH (security_invoker = true) AS
SELECT t.station_id,
       NULLIF(t.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       t.payload->>'dut_serial' AS dut_serial,
       t.payload->>'axis' AS axis,
       lab.jsonb_int8(t.payload->'segment_id') AS segment_id,
       lab.jsonb_int8(t.payload->'segment_index') AS segment_index,
       lab.jsonb_float8(t.payload->'setpoint_c') AS setpoint_c,
       lab.jsonb_int8(t.payload->'n') AS n,
       lab.jsonb_float8(t.payload->'duration_s') AS duration_s,
       lab.jsonb_float8(t.payload->'temp_mean_c') AS temp_mean_c,
       lab.jsonb_float8(t.payload->'bias_mean_dph') AS bias_mean_dph,
       lab.jsonb_float8(t.payload->'bias_std_dph') AS bias_std_dph,
       lab.jsonb_float8(t.payload->'bias_std_ma_dph') AS bias_std_ma_dph,
       lab.jsonb_float8(t.payload->'bias_mean_earth_removed_dph') AS bias_mean_earth_removed_dph,
       lab.jsonb_float8(t.payload->'earth_rate_dph') AS earth_rate_dph,
       lab.jsonb_int8(t.payload->'ma_window') AS ma_window,
       t.payload->>'computed_utc' AS computed_utc,
       lab.jsonb_float8(t.payload->'coverage') AS coverage,
       lab.jsonb_float8(t.payload->'longest_gap_s') AS longest_gap_s,
       coalesce(t.payload->>'quality', 'unassessed') AS quality,
       coalesce(t.payload->'quality_reasons_json', '[]'::jsonb) AS quality_reasons
FROM lab.records t
WHERE t.kind = 'table1' AND NOT t.deleted;

CREATE OR REPLACE VIEW lab.allan WITH (security_invoker = true) AS
SELECT a.station_id,
       NULLIF(a.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(a.payload->'id') AS local_id,
       a.payload->>'dut_serial' AS dut_serial,
       a.payload->>'axis' AS axis,
       lab.jsonb_int8(a.payload->'segment_index') AS segment_index,
       a.payload->>'taus' AS taus,
       lab.jsonb_int8(a.payload->'n_samples') AS n_samples,
       lab.jsonb_float8(a.payload->'angle_random_walk_dprh') AS angle_random_walk_dprh,
       lab.jsonb_float8(a.payload->'bias_instability_dph') AS bias_instability_dph,
       lab.jsonb_float8(a.payload->'bias_instability_tau_s') AS bias_instability_tau_s,
       lab.jsonb_float8(a.payload->'rate_random_walk_dphprh') AS rate_random_walk_dphprh,
       a.payload->'curve_json' AS curve,
       a.payload->>'computed_utc' AS computed_utc,
       lab.jsonb_float8(a.payload->'coverage') AS coverage,
       lab.jsonb_float8(a.payload->'longest_gap_s') AS longest_gap_s,
       coalesce(a.payload->>'quality', 'unassessed') AS quality,
       coalesce(a.payload->'quality_reasons_json', '[]'::jsonb) AS quality_reasons
FROM lab.records a
WHERE a.kind = 'allan' AND NOT a.deleted;

CREATE OR REPLACE VIEW lab.fits WITH (security_invoker = true) AS
SELECT f.station_id,
       NULLIF(fr.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(f.payload->'id') AS fit_local_id,
       f.payload->>'model' AS model,
       f.payload->>'form' AS form,
       f.payload->>'dut_serial' AS dut_serial,
       f.payload->>'axis' AS axis,
       lab.jsonb_int8(f.payload->'n') AS n,
       f.payload->'coefficients_json' AS coefficients,
       f.payload->'standard_errors_json' AS standard_errors,
       lab.jsonb_float8(f.payload->'residual_std_dph') AS residual_std_dph,
       lab.jsonb_float8(f.payload->'r_squared') AS r_squared,
       f.payload->>'computed_utc' AS computed_utc,
       lab.jsonb_float8(f.payload->'coverage') AS coverage,
       lab.jsonb_float8(f.payload->'longest_gap_s') AS longest_gap_s,
       coalesce(f.payload->>'quality', 'unassessed') AS quality,
       coalesce(f.payload->'quality_reasons_json', '[]'::jsonb) AS quality_reasons
FROM lab.records f
JOIN lab.records fr
  ON fr.station_id = f.station_id AND fr.kind = 'fit_run' AND NOT fr.deleted
     AND fr.payload->>'fit_id' = f.local_id
WHERE f.kind = 'fit' AND NOT f.deleted;

CREATE OR REPLACE VIEW lab.scale_factor_fits WITH (security_invoker = true) AS
SELECT k.station_id,
       NULLIF(k.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       k.payload->>'dut_serial' AS dut_serial,
       k.payload->>'axis' AS axis,
       lab.jsonb_int8(k.payload->'sf_sequence') AS sf_sequence,
       lab.jsonb_float8(k.payload->'temperature_c') AS temperature_c,
       lab.jsonb_float8(k.payload->'k') AS k,
       lab.jsonb_float8(k.payload->'k_se') AS k_se,
       lab.jsonb_float8(k.payload->'bias_dps') AS bias_dps,
       lab.jsonb_float8(k.payload->'nonlinearity_ppm') AS nonlinearity_ppm,
       lab.jsonb_float8(k.payload->'asymmetry_ppm') AS asymmetry_ppm,
       lab.jsonb_float8(k.payload->'repeatability_ppm') AS repeatability_ppm,
       lab.jsonb_int8(k.payload->'n_points') AS n_points,
       lab.jsonb_float8(k.payload->'coverage') AS coverage,
       lab.jsonb_float8(k.payload->'longest_gap_s') AS longest_gap_s,
       coalesce(k.payload->>'quality', 'unassessed') AS quality,
       coalesce(k.payload->'quality_reasons_json', '[]'::jsonb) AS quality_reasons
FROM lab.records k
WHERE k.kind = 'sf_fit' AND NOT k.deleted;
)sql";

// v3: Table I's mean with its uncertainty (the station's schema v13,
// docs/analysis.md "Uncertainty of a mean"): lab.table1 gains bias_u_dph,
// bias_u_expanded_dph (95 %), bias_u_k, bias_u_dof, bias_u_floor_dph,
// bias_u_random_walk and bias_u_note, appended to its columns; NULL (and
// '') for rows relayed before the station's v13.
constexpr const char* kCentralV3 = R"sql(
CREATE OR REPLACE VIEW lab.table1 WITH (security_invoker = true) AS
SELECT t.station_id,
       NULLIF(t.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       t.payload->>'dut_serial' AS dut_serial,
       t.payload->>'axis' AS axis,
       lab.jsonb_int8(t.payload->'segment_id') AS segment_id,
       lab.jsonb_int8(t.payload->'segment_index') AS segment_index,
       lab.jsonb_float8(t.payload->'setpoint_c') AS setpoint_c,
       lab.jsonb_int8(t.payload->'n') AS n,
       lab.jsonb_float8(t.payload->'duration_s') AS duration_s,
       lab.jsonb_float8(t.payload->'temp_mean_c') AS temp_mean_c,
       lab.jsonb_float8(t.payload->'bias_mean_dph') AS bias_mean_dph,
       lab.jsonb_float8(t.payload->'bias_std_dph') AS bias_std_dph,
       lab.jsonb_float8(t.payload->'bias_std_ma_dph') AS bias_std_ma_dph,
       lab.jsonb_float8(t.payload->'bias_mean_earth_removed_dph') AS bias_mean_earth_removed_dph,
       lab.jsonb_float8(t.payload->'earth_rate_dph') AS earth_rate_dph,
       lab.jsonb_int8(t.payload->'ma_window') AS ma_window,
       t.payload->>'computed_utc' AS computed_utc,
       lab.jsonb_float8(t.payload->'coverage') AS coverage,
       lab.jsonb_float8(t.payload->'longest_gap_s') AS longest_gap_s,
       coalesce(t.payload->>'quality', 'unassessed') AS quality,
       coalesce(t.payload->'quality_reasons_json', '[]'::jsonb) AS quality_reasons,
       lab.jsonb_float8(t.payload->'bias_u_dph') AS bias_u_dph,
       lab.jsonb_float8(t.payload->'bias_u_expanded_dph') AS bias_u_expanded_dph,
       lab.jsonb_float8(t.payload->'bias_u_k') AS bias_u_k,
       lab.jsonb_float8(t.payload->'bias_u_dof') AS bias_u_dof,
       lab.jsonb_float8(t.payload->'bias_u_floor_dph') AS bias_u_floor_dph,
       (lab.jsonb_int8(t.payload->'bias_u_random_walk') = 1) AS bias_u_random_walk,
       coalesce(t.payload->>'bias_u_note', '') AS bias_u_note
FROM lab.records t
WHERE t.kind = 'table1' AND NOT t.deleted;
)sql";

// v4: adaptive soaks (the station's schema v14, docs/schedules.md
// "Adaptive soaks"): lab.segments gains acquire_stop, why a soak's
// acquisition ended, appended to its columns; '' for fixed soaks and rows
// relayed before the station's v14.
constexpr const char* kCentralV4 = R"sql(
CREATE OR REPLACE VIEW lab.segments WITH (security_invoker = true) AS
SELECT s.station_id,
       NULLIF(s.run_uuid, '00000000-0000-0000-0000-000000000000') AS run_uuid,
       lab.jsonb_int8(s.payload->'id') AS local_segment_id,
       lab.jsonb_int8(s.payload->'idx') AS idx,
       s.payload->>'kind' AS kind,
       s.payload->>'label' AS label,
       lab.jsonb_float8(s.payload->'setpoint_c') AS setpoint_c,
       s.payload->>'state' AS state,
       lab.jsonb_float8(s.payload->'t_start_s') AS t_start_s,
       lab.jsonb_float8(s.payload->'t_end_s') AS t_end_s,
       s.payload->>'table_mode' AS table_mode,
       lab.jsonb_float8(s.payload->'table_rate_dps') AS table_rate_dps,
       coalesce(s.payload->>'acquire_stop', '') AS acquire_stop
FROM lab.records s
WHERE s.kind = 'segment' AND NOT s.deleted;
)sql";

struct CentralMigration {
  int version;
  const char* description;
  const char* sql;
};

constexpr CentralMigration kCentralMigrations[] = {
    {1, "stations, records, relay progress, roles, row-level security, views", kCentralV1},
    {2, "result quality in the views of results", kCentralV2},
    {3, "Table I mean uncertainty in lab.table1", kCentralV3},
    {4, "adaptive soaks' stop reasons in lab.segments", kCentralV4},
};

static_assert(sizeof(kCentralMigrations) / sizeof(kCentralMigrations[0]) == kCentralSchemaVersion,
              "one migration per central schema version");

Error newer_schema(const PgConnection& pg, int found) {
  return Error::Permanent(fmt::format(
      "lab database {} has lab schema version {}, newer than version {} this build knows: "
      "upgrade gyrotherm (a schema is never downgraded)",
      pg.server(), found, kCentralSchemaVersion));
}

}  // namespace

Result<int> central_schema_version(PgConnection& pg) {
  auto exists = pg.exec("SELECT to_regclass('lab.schema_migrations') IS NOT NULL");
  if (!exists.ok()) return exists.error();
  if (exists->rows.empty() || exists->rows[0][0] != "t") return 0;
  auto version = pg.exec("SELECT coalesce(max(version), 0) FROM lab.schema_migrations");
  if (!version.ok()) return version.error();
  return std::stoi(version->rows.at(0).at(0).value_or("0"));
}

Result<int> migrate_central(PgConnection& pg) {
  int reached = 0;
  for (const auto& m : kCentralMigrations) {
    internal::PgTransaction tx(pg);
    if (auto s = tx.begin(); !s.ok()) return s.error();
    // Held until this transaction ends: a concurrent migrate waits here,
    // then reads the version this one committed.
    if (auto r = pg.exec(kMigrationLockSql); !r.ok()) return r.error();
    auto version = central_schema_version(pg);
    if (!version.ok()) return version.error();
    if (*version > kCentralSchemaVersion) return newer_schema(pg, *version);
    if (*version >= m.version) {
      reached = *version;
      if (auto s = tx.commit(); !s.ok()) return s.error();
      continue;
    }
    if (auto r = pg.exec(m.sql); !r.ok()) {
      return Error{fmt::format("lab schema migration to version {} ({}): {}", m.version,
                               m.description, r.error().message),
                   r.error().transient};
    }
    auto recorded =
        pg.exec_params("INSERT INTO lab.schema_migrations(version, description) VALUES ($1, $2)",
                       {std::to_string(m.version), std::string(m.description)});
    if (!recorded.ok()) return recorded.error();
    if (auto s = tx.commit(); !s.ok()) return s.error();
    reached = m.version;
  }
  return reached;
}

}  // namespace gyrotherm::lab

#include "migrations.h"

#include "chunks.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::storage::internal {
namespace {

// The comments inside CREATE TABLE are kept by SQLite and shown by the
// sqlite3 shell's `.schema`, so units are visible where people query.
// docs/storage.md documents every column.
constexpr const char* kSchemaV1 = R"sql(
CREATE TABLE runs(
  id INTEGER PRIMARY KEY,
  schedule_name TEXT NOT NULL,
  state TEXT NOT NULL,          -- run state machine: queued, ramping, settling, acquiring, paused, suspended, aborting, completed, failed, interrupted
  started_utc TEXT NOT NULL,    -- ISO-8601 UTC wall time
  ended_utc TEXT,               -- ISO-8601 UTC wall time; NULL while running
  time_scale REAL,              -- station seconds per wall second (1 on a real station)
  latitude_deg REAL,            -- station latitude, degrees north
  orientation TEXT,             -- sensitive axis: up, down, horizontal
  config_json TEXT              -- the station configuration the run used, JSON
);

CREATE TABLE schedules(
  id INTEGER PRIMARY KEY,
  name TEXT NOT NULL,
  source_path TEXT,             -- file the schedule was read from
  toml_text TEXT NOT NULL,      -- the schedule file's full text as queued
  created_utc TEXT NOT NULL     -- ISO-8601 UTC wall time
);

CREATE TABLE queue(
  id INTEGER PRIMARY KEY,
  schedule_id INTEGER NOT NULL REFERENCES schedules(id),
  position INTEGER NOT NULL,    -- 0 = next to run
  state TEXT NOT NULL,
  added_utc TEXT NOT NULL,      -- ISO-8601 UTC wall time
  ignore_failures INTEGER NOT NULL DEFAULT 0  -- 1: a failed run does not stop the queue
);
CREATE INDEX queue_by_position ON queue(position);

CREATE TABLE segments(
  id INTEGER PRIMARY KEY,
  run_id INTEGER NOT NULL REFERENCES runs(id),
  idx INTEGER NOT NULL,         -- step position in the expanded schedule, from 0
  kind TEXT NOT NULL,           -- soak, ramp, hold
  label TEXT,
  setpoint_c REAL,              -- soak/hold set point or ramp target, degC
  ramp_rate_c_per_min REAL,     -- ramps only, degC/min
  t_start_s REAL,               -- station s since run start
  t_settled_s REAL,             -- station s; NULL until the stability gate held
  t_acquire_start_s REAL,       -- station s; NULL until acquisition started
  t_acquire_end_s REAL,         -- station s; NULL until acquisition ended
  t_end_s REAL,                 -- station s; NULL while the step runs
  paused_s REAL,                -- station s excluded from acquisition (pauses, suspensions)
  state TEXT NOT NULL           -- running, completed, failed, aborted
);
CREATE INDEX segments_by_run ON segments(run_id, idx);

-- (run_id, t_s) is unique and is the table's key: WITHOUT ROWID stores rows
-- in key order, which inserts faster and reads time windows faster than a
-- rowid table plus an index, in a smaller file.
CREATE TABLE gyro_samples(
  run_id INTEGER NOT NULL,      -- runs.id (not enforced, for insert speed)
  t_s REAL NOT NULL,            -- station s since run start
  seq INTEGER NOT NULL,         -- frame sequence counter (0..127 for KVH 1750)
  rate_dph REAL,                -- rate about the configured axis, deg/h
  status INTEGER NOT NULL,      -- frame status byte as sent
  temp_c INTEGER,               -- gyro internal temperature as sent, degC
  PRIMARY KEY(run_id, t_s)
) WITHOUT ROWID;

CREATE TABLE temperature_samples(
  run_id INTEGER NOT NULL,      -- runs.id (not enforced, for insert speed)
  t_s REAL NOT NULL,            -- station s since run start
  setpoint_c REAL,              -- chamber set point in force, degC
  chamber_c REAL,               -- chamber air (controller process value), degC
  top_c REAL,                   -- gyro shell probe "top", degC
  side_c REAL,                  -- gyro shell probe "side", degC
  PRIMARY KEY(run_id, t_s)
) WITHOUT ROWID;

CREATE TABLE events(
  id INTEGER PRIMARY KEY,
  run_id INTEGER REFERENCES runs(id),  -- NULL for station events outside a run
  t_s REAL,                     -- station s since run start (0 without a run)
  wall_utc TEXT NOT NULL,       -- ISO-8601 UTC wall time
  kind TEXT NOT NULL,           -- state, interlock, device, info, error
  from_state TEXT,              -- state transitions only
  to_state TEXT,                -- state transitions only
  message TEXT                  -- what a technician reads
);
CREATE INDEX events_by_run ON events(run_id, id);

CREATE TABLE segment_stats(
  segment_id INTEGER PRIMARY KEY REFERENCES segments(id),
  run_id INTEGER NOT NULL REFERENCES runs(id),
  segment_index INTEGER NOT NULL,   -- segments.idx
  setpoint_c REAL,                  -- degC
  n INTEGER NOT NULL,               -- points of the analysis series
  duration_s REAL,                  -- station s
  temp_mean_c REAL,                 -- mean of (top + side)/2, degC
  bias_mean_dph REAL,               -- zero-bias mean, deg/h
  bias_std_dph REAL,                -- zero-bias sample std (ddof 1), deg/h
  bias_std_ma_dph REAL,             -- std after the ma_window-point moving average, deg/h
  bias_mean_earth_removed_dph REAL, -- bias_mean_dph - earth_rate_dph, deg/h
  bin_s REAL,                       -- analysis bin, s
  ma_window INTEGER,                -- moving-average window, points
  earth_rate_dph REAL,              -- Earth-rate component removed, deg/h
  t_from_s REAL,                    -- window start, station s since run start
  t_to_s REAL,                      -- window end, station s since run start
  computed_utc TEXT NOT NULL        -- ISO-8601 UTC wall time
);
CREATE INDEX segment_stats_by_run ON segment_stats(run_id, segment_index);
)sql";

// v2: the persistent queue, crash resume and acquisition windows.
constexpr const char* kSchemaV2 = R"sql(
ALTER TABLE runs ADD COLUMN queue_id INTEGER;
ALTER TABLE runs ADD COLUMN schedule_id INTEGER;
ALTER TABLE runs ADD COLUMN resume_json TEXT;
ALTER TABLE runs ADD COLUMN checkpoint_wall_unix_s REAL;
ALTER TABLE queue ADD COLUMN run_id INTEGER;

-- The stretches of a step that count as acquisition: pauses and
-- suspensions are cut out, so a soak's statistics use these windows only.
CREATE TABLE acquisition_windows(
  segment_id INTEGER NOT NULL REFERENCES segments(id),
  run_id INTEGER NOT NULL,      -- runs.id
  t_from_s REAL NOT NULL,       -- station s since run start
  t_to_s REAL NOT NULL,         -- station s since run start
  PRIMARY KEY(segment_id, t_from_s)
) WITHOUT ROWID;
)sql";

// v3: rollups of the gyro rate for decimated reads (the REST samples route
// reads these instead of millions of rows), and stored drift-model fits.
// The rollup is filled from the samples already stored; from then on the
// sample writer keeps it in the same transaction as the samples.
constexpr const char* kSchemaV3 = R"sql(
CREATE TABLE gyro_rollup(
  run_id INTEGER NOT NULL,      -- runs.id
  level INTEGER NOT NULL,       -- block length 0.1 * 10^level s (0.1, 1, 10, 100, 1000)
  block INTEGER NOT NULL,       -- floor(t_s / block length)
  n INTEGER NOT NULL,           -- samples in the block
  t_sum_s REAL NOT NULL,        -- sum of their t_s (mean time = t_sum_s / n)
  rate_n INTEGER NOT NULL,      -- samples with a rate (rate_dph not NULL)
  rate_sum_dph REAL,            -- sum of rate_dph
  rate_min_dph REAL,
  rate_max_dph REAL,
  PRIMARY KEY(run_id, level, block)
) WITHOUT ROWID;

WITH levels(level, block_s) AS (VALUES (0, 0.1), (1, 1.0), (2, 10.0), (3, 100.0), (4, 1000.0)),
     blocks AS (
       SELECT g.run_id, l.level, g.t_s, g.rate_dph,
              CAST(g.t_s / l.block_s AS INTEGER)
                - (g.t_s < 0 AND CAST(g.t_s / l.block_s AS INTEGER) != g.t_s / l.block_s) AS block
       FROM gyro_samples g, levels l)
INSERT INTO gyro_rollup(run_id, level, block, n, t_sum_s, rate_n, rate_sum_dph, rate_min_dph,
                        rate_max_dph)
SELECT run_id, level, block, count(*), sum(t_s), count(rate_dph), sum(rate_dph), min(rate_dph),
       max(rate_dph)
FROM blocks GROUP BY run_id, level, block;

CREATE TABLE fits(
  id INTEGER PRIMARY KEY,
  model TEXT NOT NULL,              -- model spec, e.g. 'T4+R1+G1'
  form TEXT NOT NULL,               -- 'paper' (L - L0, no intercept) or 'centered'
  n INTEGER NOT NULL,               -- points fitted (analysis series)
  coefficients_json TEXT NOT NULL,  -- {"T1": ..., "G1": ...} in physical units
  standard_errors_json TEXT NOT NULL,
  residual_std_dph REAL,
  r_squared REAL,
  inputs_json TEXT NOT NULL,        -- what reproduces it: windows, bin_s, derivative window...
  computed_utc TEXT NOT NULL        -- ISO-8601 UTC wall time
);
CREATE TABLE fit_runs(
  run_id INTEGER NOT NULL,          -- runs.id
  fit_id INTEGER NOT NULL REFERENCES fits(id),
  PRIMARY KEY(run_id, fit_id)
) WITHOUT ROWID;
)sql";

// v4: the Allan deviation of each soak, one row per (run, step, tau set).
// The curve is one JSON object of equal-length arrays, readable with
// sqlite3's json_each; the noise terms are NULL when they could not be read
// off the curve.
constexpr const char* kSchemaV4 = R"sql(
CREATE TABLE allan(
  id INTEGER PRIMARY KEY,
  run_id INTEGER NOT NULL REFERENCES runs(id),
  segment_id INTEGER REFERENCES segments(id),  -- the soak's segment; NULL: not tied to one
  segment_index INTEGER NOT NULL,   -- segments.idx
  t_from_s REAL,                    -- first sample used, station s since run start
  t_to_s REAL,                      -- last sample used, station s since run start
  taus TEXT NOT NULL,               -- tau set: octave, decade, all
  tau0_s REAL,                      -- sample spacing (median of the t_s steps), s
  n_samples INTEGER NOT NULL,       -- samples the deviation was computed from
  curve_json TEXT NOT NULL,         -- {"tau_s":[...],"adev_dph":[...],"adev_lo_dph":[...],"adev_hi_dph":[...]}, equal lengths; s and deg/h
  angle_random_walk_dprh REAL,      -- angle random walk, deg/sqrt(h); NULL: not determined
  bias_instability_dph REAL,        -- bias instability, deg/h; NULL: not determined
  bias_instability_tau_s REAL,      -- tau of the curve's minimum it was read at, s
  rate_random_walk_dphprh REAL,     -- rate random walk, deg/h/sqrt(h); NULL: not determined
  bias_instability_method TEXT,     -- e.g. 'minimum / 0.664'
  inputs_json TEXT NOT NULL,        -- what reproduces it: windows, taus, bin...
  computed_utc TEXT NOT NULL        -- ISO-8601 UTC wall time
);
CREATE UNIQUE INDEX allan_by_run ON allan(run_id, segment_index, taus);
)sql";

// v5: the record of calibration exports (docs/reports.md). A nightly export
// is tied to its scheduled slot (one export per slot: a daemon that was down
// catches up on the slots it missed, and never writes a slot twice);
// export_runs lists the runs each export covered.
constexpr const char* kSchemaV5 = R"sql(
CREATE TABLE exports(
  id INTEGER PRIMARY KEY,
  kind TEXT NOT NULL CHECK(kind IN ('nightly', 'manual')),
  slot_unix_s REAL,             -- nightly: the scheduled slot, Unix s (UTC); NULL for manual
  slot_local TEXT NOT NULL DEFAULT '',  -- nightly: the slot as local time, e.g. '2026-03-29 02:00 CET'
  state TEXT NOT NULL CHECK(state IN ('writing', 'done', 'failed')),
  directory TEXT NOT NULL,      -- where the files were written
  files_json TEXT NOT NULL DEFAULT '[]',  -- JSON array of file paths relative to directory
  started_utc TEXT NOT NULL,    -- ISO-8601 UTC wall time
  finished_utc TEXT,            -- ISO-8601 UTC wall time; NULL until finished
  message TEXT NOT NULL DEFAULT '',  -- failed: why; done: a summary
  CHECK(kind != 'nightly' OR slot_unix_s IS NOT NULL)
);
CREATE UNIQUE INDEX exports_nightly_slot ON exports(slot_unix_s) WHERE kind = 'nightly';

CREATE TABLE export_runs(
  export_id INTEGER NOT NULL REFERENCES exports(id),
  run_id INTEGER NOT NULL REFERENCES runs(id),
  PRIMARY KEY(export_id, run_id)
) WITHOUT ROWID;
CREATE INDEX export_runs_by_run ON export_runs(run_id);
)sql";

// v6: runs.config_json holds what its name says: the configuration in force
// when the run started, as JSON. Versions 1-5 stored the config file's TOML
// text there, re-read from disk at run start; that text moves to its own
// column, config_toml, and stays readable. The triggers refuse text that is
// not JSON in config_json from now on.
constexpr const char* kSchemaV6 = R"sql(
ALTER TABLE runs ADD COLUMN config_toml TEXT;  -- before v6: the config file's TOML text read at run start (tokens redacted); NULL from v6 on
UPDATE runs SET config_toml = config_json, config_json = NULL
  WHERE config_json IS NOT NULL AND NOT json_valid(config_json);
CREATE TRIGGER runs_config_json_is_json_on_insert BEFORE INSERT ON runs
  WHEN NEW.config_json IS NOT NULL AND NOT json_valid(NEW.config_json)
  BEGIN SELECT RAISE(ABORT, 'runs.config_json must be JSON'); END;
CREATE TRIGGER runs_config_json_is_json_on_update BEFORE UPDATE OF config_json ON runs
  WHEN NEW.config_json IS NOT NULL AND NOT json_valid(NEW.config_json)
  BEGIN SELECT RAISE(ABORT, 'runs.config_json must be JSON'); END;
)sql";

// v7: the rate table (turntable) and scale-factor calibration. The table's
// readings go to table_samples (written by the sample writer like the other
// samples); each segment records the table demand of its step, the table's
// measured means over the acquisition windows and, for rate points, the
// scale-factor sequence it belongs to. The scale-factor analysis of a run is
// stored in three tables, replaced as a whole when the run is re-analysed.
// Segments stored before v7 read table_mode 'none' and zeros.
constexpr const char* kSchemaV7 = R"sql(
CREATE TABLE table_samples(
  run_id INTEGER NOT NULL,      -- runs.id (not enforced, for insert speed)
  t_s REAL NOT NULL,            -- station s since run start
  demand_mode TEXT NOT NULL,    -- the step's demand: none, static, rate
  demand_rate_dps REAL,         -- demanded rate, deg/s (0 unless demand_mode is rate)
  demand_position_deg REAL,     -- demanded position, deg; NULL when none
  rate_dps REAL,                -- measured rate, deg/s (positive counter-clockwise from above)
  position_deg REAL,            -- measured position, deg, [0, 360) on a continuous axis
  mode TEXT,                    -- servo mode reported: off, rate, position, unknown
  interlock TEXT,               -- open, closed, fault
  PRIMARY KEY(run_id, t_s)
) WITHOUT ROWID;

ALTER TABLE segments ADD COLUMN table_mode TEXT NOT NULL DEFAULT 'none'
  CHECK(table_mode IN ('none', 'static', 'rate'));  -- the step's table demand
ALTER TABLE segments ADD COLUMN table_rate_dps REAL;       -- demanded rate, deg/s; NULL when table_mode is none
ALTER TABLE segments ADD COLUMN table_position_deg REAL;   -- demanded position, deg; NULL when none
ALTER TABLE segments ADD COLUMN table_mean_rate_dps REAL;  -- measured rate over the acquisition windows, deg/s; NULL until known
ALTER TABLE segments ADD COLUMN table_mean_position_deg REAL;  -- circular mean of the measured position over the windows, deg; NULL until known (or spread round the circle)
ALTER TABLE segments ADD COLUMN turns INTEGER NOT NULL DEFAULT 0;     -- rate points: whole turns acquired; 0 otherwise
ALTER TABLE segments ADD COLUMN dwell_s REAL NOT NULL DEFAULT 0;      -- rate points: acquisition time over those turns, station s; 0 otherwise
ALTER TABLE segments ADD COLUMN sf_sequence INTEGER NOT NULL DEFAULT 0;    -- rate points: scale-factor sequence of the plan, from 1; 0 otherwise
ALTER TABLE segments ADD COLUMN sf_repetition INTEGER NOT NULL DEFAULT 0;  -- rate points: repetition of that sequence, from 1; 0 otherwise

CREATE TABLE scale_factor_points(
  id INTEGER PRIMARY KEY,
  run_id INTEGER NOT NULL REFERENCES runs(id),
  segment_id INTEGER REFERENCES segments(id),  -- the rate point's segment; NULL: not tied to one
  sf_sequence INTEGER NOT NULL,     -- segments.sf_sequence
  repetition INTEGER NOT NULL,      -- segments.sf_repetition
  rate_dps REAL,                    -- demanded table rate, deg/s
  measured_rate_dps REAL,           -- table rate measured over the windows, deg/s
  output_dps REAL,                  -- mean gyro output over the windows, deg/s
  n INTEGER NOT NULL,               -- gyro samples averaged
  temperature_c REAL,               -- mean shell temperature (top + side)/2, degC
  duration_s REAL,                  -- acquisition time, station s
  turns REAL                        -- turns of the table over the acquisition
);
CREATE INDEX scale_factor_points_by_run ON scale_factor_points(run_id, sf_sequence, repetition);

CREATE TABLE scale_factor_fits(
  run_id INTEGER NOT NULL REFERENCES runs(id),
  sf_sequence INTEGER NOT NULL,     -- the sequence fitted (its points in scale_factor_points)
  temperature_c REAL,               -- mean temperature of its points, degC
  k REAL,                           -- scale factor K of output = K * rate + bias, (deg/s)/(deg/s)
  k_se REAL,                        -- standard error of K
  bias_dps REAL,                    -- bias B0 of the fit, deg/s
  nonlinearity_ppm REAL,            -- largest deviation of a point from the line relative to K, ppm
  nonlinearity_fs_ppm REAL,         -- the same relative to the full-scale output, ppm
  asymmetry_ppm REAL,               -- (K+ - K-) / mean K, ppm; NULL with one direction only
  repeatability_ppm REAL,           -- spread of K over the repetitions, ppm; NULL with fewer than 2
  n_points INTEGER NOT NULL,        -- points fitted
  created_utc TEXT NOT NULL,        -- ISO-8601 UTC wall time
  PRIMARY KEY(run_id, sf_sequence)
) WITHOUT ROWID;

CREATE TABLE scale_factor_temperature_fits(
  run_id INTEGER PRIMARY KEY REFERENCES runs(id),
  poly_order INTEGER NOT NULL,      -- degree of the polynomials in (T - t_centre_c)
  t_centre_c REAL,                  -- temperature the polynomials are centred on, degC
  k_coeffs_json TEXT NOT NULL,      -- [k0, k1, ...]: K(T) = sum k_i (T - t_centre_c)^i
  bias_coeffs_json TEXT NOT NULL,   -- [b0, b1, ...]: bias(T) = sum b_i (T - t_centre_c)^i, deg/s
  k_ppm_per_c REAL,                 -- dK/dT at t_centre_c relative to K, ppm/degC
  bias_dph_per_c REAL,              -- dbias/dT at t_centre_c, (deg/h)/degC
  created_utc TEXT NOT NULL         -- ISO-8601 UTC wall time
);
)sql";

// v8: devices under test, run metadata, results per DUT and axis.
// duts is the station's registry of gyros by serial number; run_duts says
// which DUTs a run had (and how each was configured), channels what each of
// their frames carried. Every result table gains the DUT's serial and the
// axis; rows stored before v8 keep '' in both (the unnamed gyro of the run,
// its primary axis). Tables whose key must now include the DUT and axis
// (segment_stats, scale_factor_fits, scale_factor_temperature_fits) are
// rebuilt with their rows; the others gain columns and a wider unique index.
constexpr const char* kSchemaV8 = R"sql(
CREATE TABLE duts(
  id INTEGER PRIMARY KEY,
  serial TEXT NOT NULL UNIQUE,      -- serial number as configured; '' = the unnamed gyro of older runs
  model TEXT NOT NULL DEFAULT '',   -- e.g. 'KVH 1750'
  first_seen_utc TEXT NOT NULL      -- ISO-8601 UTC wall time of the first run it was in
);

CREATE TABLE run_duts(
  run_id INTEGER NOT NULL REFERENCES runs(id),
  dut_id INTEGER NOT NULL REFERENCES duts(id),
  position INTEGER NOT NULL,        -- order in the run's [[dut]] list, from 0 (0 = the run's first DUT)
  primary_axis TEXT NOT NULL,       -- the sensitive axis (Earth-rate removal, old single-axis paths)
  axes_json TEXT NOT NULL DEFAULT '[]',  -- JSON array of the analysed rate axes, e.g. ["x","y","z"]
  rate_hz REAL,                     -- nominal output rate, Hz; NULL: unknown
  seq_modulo INTEGER NOT NULL DEFAULT 0,  -- the frames' sequence counter wraps at this; 0: no counter
  config_json TEXT NOT NULL DEFAULT '{}', -- the [[dut]] entry the run used, JSON
  PRIMARY KEY(run_id, dut_id)
);
CREATE INDEX run_duts_by_dut ON run_duts(dut_id, run_id);

CREATE TABLE channels(
  id INTEGER PRIMARY KEY,
  run_id INTEGER NOT NULL,          -- runs.id
  dut_id INTEGER NOT NULL,          -- duts.id
  idx INTEGER NOT NULL,             -- position in the DUT's frames, from 0
  name TEXT NOT NULL,               -- gyro_x, accel_z, status, temp_c, rate, ...
  unit TEXT NOT NULL,               -- physical unit: deg/h, g, degC, '' for status
  kind TEXT NOT NULL,               -- rate, accel, temperature, status, other
  axis TEXT NOT NULL DEFAULT '',    -- x, y, z for rate and accel channels; '' otherwise
  scale REAL NOT NULL,              -- physical = raw * scale
  UNIQUE(run_id, dut_id, name)
);

ALTER TABLE runs ADD COLUMN operator TEXT NOT NULL DEFAULT '';   -- who ran it
ALTER TABLE runs ADD COLUMN comment TEXT NOT NULL DEFAULT '';
ALTER TABLE runs ADD COLUMN tags_json TEXT NOT NULL DEFAULT '[]';         -- JSON array of free tags
ALTER TABLE runs ADD COLUMN dut_serials_json TEXT NOT NULL DEFAULT '[]';  -- JSON array of the DUT serials declared when queued
ALTER TABLE queue ADD COLUMN operator TEXT NOT NULL DEFAULT '';  -- given to the run the entry starts
ALTER TABLE queue ADD COLUMN comment TEXT NOT NULL DEFAULT '';
ALTER TABLE queue ADD COLUMN tags_json TEXT NOT NULL DEFAULT '[]';
ALTER TABLE queue ADD COLUMN dut_serials_json TEXT NOT NULL DEFAULT '[]';

CREATE TABLE segment_stats_v8(
  segment_id INTEGER NOT NULL REFERENCES segments(id),
  run_id INTEGER NOT NULL REFERENCES runs(id),
  dut_serial TEXT NOT NULL DEFAULT '',  -- duts.serial; '' = the unnamed gyro
  axis TEXT NOT NULL DEFAULT '',        -- x, y, z; '' = the DUT's primary axis (rows before v8)
  segment_index INTEGER NOT NULL,   -- segments.idx
  setpoint_c REAL,                  -- degC
  n INTEGER NOT NULL,               -- points of the analysis series
  duration_s REAL,                  -- station s
  temp_mean_c REAL,                 -- mean of (top + side)/2, degC
  bias_mean_dph REAL,               -- zero-bias mean, deg/h
  bias_std_dph REAL,                -- zero-bias sample std (ddof 1), deg/h
  bias_std_ma_dph REAL,             -- std after the ma_window-point moving average, deg/h
  bias_mean_earth_removed_dph REAL, -- bias_mean_dph - earth_rate_dph, deg/h
  bin_s REAL,                       -- analysis bin, s
  ma_window INTEGER,                -- moving-average window, points
  earth_rate_dph REAL,              -- Earth-rate component removed, deg/h
  t_from_s REAL,                    -- window start, station s since run start
  t_to_s REAL,                      -- window end, station s since run start
  computed_utc TEXT NOT NULL,       -- ISO-8601 UTC wall time
  PRIMARY KEY(segment_id, dut_serial, axis)
);
INSERT INTO segment_stats_v8(segment_id, run_id, segment_index, setpoint_c, n, duration_s,
  temp_mean_c, bias_mean_dph, bias_std_dph, bias_std_ma_dph, bias_mean_earth_removed_dph, bin_s,
  ma_window, earth_rate_dph, t_from_s, t_to_s, computed_utc)
SELECT segment_id, run_id, segment_index, setpoint_c, n, duration_s, temp_mean_c, bias_mean_dph,
  bias_std_dph, bias_std_ma_dph, bias_mean_earth_removed_dph, bin_s, ma_window, earth_rate_dph,
  t_from_s, t_to_s, computed_utc FROM segment_stats;
DROP TABLE segment_stats;
ALTER TABLE segment_stats_v8 RENAME TO segment_stats;
CREATE INDEX segment_stats_by_run ON segment_stats(run_id, segment_index);
CREATE INDEX segment_stats_by_dut ON segment_stats(dut_serial, run_id);

ALTER TABLE allan ADD COLUMN dut_serial TEXT NOT NULL DEFAULT '';  -- duts.serial; '' = the unnamed gyro
ALTER TABLE allan ADD COLUMN axis TEXT NOT NULL DEFAULT '';        -- '' = the DUT's primary axis
DROP INDEX allan_by_run;
CREATE UNIQUE INDEX allan_by_run ON allan(run_id, segment_index, taus, dut_serial, axis);
CREATE INDEX allan_by_dut ON allan(dut_serial, run_id);

ALTER TABLE fits ADD COLUMN dut_serial TEXT NOT NULL DEFAULT '';  -- duts.serial; '' = the unnamed gyro
ALTER TABLE fits ADD COLUMN axis TEXT NOT NULL DEFAULT '';        -- '' = the DUT's primary axis
CREATE INDEX fits_by_dut ON fits(dut_serial, id);

ALTER TABLE scale_factor_points ADD COLUMN dut_serial TEXT NOT NULL DEFAULT '';  -- duts.serial
ALTER TABLE scale_factor_points ADD COLUMN axis TEXT NOT NULL DEFAULT '';        -- '' = primary axis
DROP INDEX scale_factor_points_by_run;
CREATE INDEX scale_factor_points_by_run
  ON scale_factor_points(run_id, dut_serial, axis, sf_sequence, repetition);
CREATE INDEX scale_factor_points_by_dut ON scale_factor_points(dut_serial, run_id);

CREATE TABLE scale_factor_fits_v8(
  run_id INTEGER NOT NULL REFERENCES runs(id),
  sf_sequence INTEGER NOT NULL,     -- the sequence fitted (its points in scale_factor_points)
  dut_serial TEXT NOT NULL DEFAULT '',  -- duts.serial; '' = the unnamed gyro
  axis TEXT NOT NULL DEFAULT '',        -- x, y, z; '' = the DUT's primary axis (rows before v8)
  temperature_c REAL,               -- mean temperature of its points, degC
  k REAL,                           -- scale factor K of output = K * rate + bias, (deg/s)/(deg/s)
  k_se REAL,                        -- standard error of K
  bias_dps REAL,                    -- bias B0 of the fit, deg/s
  nonlinearity_ppm REAL,            -- largest deviation of a point from the line relative to K, ppm
  nonlinearity_fs_ppm REAL,         -- the same relative to the full-scale output, ppm
  asymmetry_ppm REAL,               -- (K+ - K-) / mean K, ppm; NULL with one direction only
  repeatability_ppm REAL,           -- spread of K over the repetitions, ppm; NULL with fewer than 2
  n_points INTEGER NOT NULL,        -- points fitted
  created_utc TEXT NOT NULL,        -- ISO-8601 UTC wall time
  PRIMARY KEY(run_id, sf_sequence, dut_serial, axis)
) WITHOUT ROWID;
INSERT INTO scale_factor_fits_v8(run_id, sf_sequence, temperature_c, k, k_se, bias_dps,
  nonlinearity_ppm, nonlinearity_fs_ppm, asymmetry_ppm, repeatability_ppm, n_points, created_utc)
SELECT run_id, sf_sequence, temperature_c, k, k_se, bias_dps, nonlinearity_ppm,
  nonlinearity_fs_ppm, asymmetry_ppm, repeatability_ppm, n_points, created_utc
FROM scale_factor_fits;
DROP TABLE scale_factor_fits;
ALTER TABLE scale_factor_fits_v8 RENAME TO scale_factor_fits;
CREATE INDEX scale_factor_fits_by_dut ON scale_factor_fits(dut_serial, run_id);

CREATE TABLE scale_factor_temperature_fits_v8(
  run_id INTEGER NOT NULL REFERENCES runs(id),
  dut_serial TEXT NOT NULL DEFAULT '',  -- duts.serial; '' = the unnamed gyro
  axis TEXT NOT NULL DEFAULT '',        -- x, y, z; '' = the DUT's primary axis (rows before v8)
  poly_order INTEGER NOT NULL,      -- degree of the polynomials in (T - t_centre_c)
  t_centre_c REAL,                  -- temperature the polynomials are centred on, degC
  k_coeffs_json TEXT NOT NULL,      -- [k0, k1, ...]: K(T) = sum k_i (T - t_centre_c)^i
  bias_coeffs_json TEXT NOT NULL,   -- [b0, b1, ...]: bias(T) = sum b_i (T - t_centre_c)^i, deg/s
  k_ppm_per_c REAL,                 -- dK/dT at t_centre_c relative to K, ppm/degC
  bias_dph_per_c REAL,              -- dbias/dT at t_centre_c, (deg/h)/degC
  created_utc TEXT NOT NULL,        -- ISO-8601 UTC wall time
  PRIMARY KEY(run_id, dut_serial, axis)
) WITHOUT ROWID;
INSERT INTO scale_factor_temperature_fits_v8(run_id, poly_order, t_centre_c, k_coeffs_json,
  bias_coeffs_json, k_ppm_per_c, bias_dph_per_c, created_utc)
SELECT run_id, poly_order, t_centre_c, k_coeffs_json, bias_coeffs_json, k_ppm_per_c,
  bias_dph_per_c, created_utc FROM scale_factor_temperature_fits;
DROP TABLE scale_factor_temperature_fits;
ALTER TABLE scale_factor_temperature_fits_v8 RENAME TO scale_factor_temperature_fits;
CREATE INDEX scale_factor_temperature_fits_by_dut
  ON scale_factor_temperature_fits(dut_serial, run_id);
)sql";

// v9: chunked sample storage (docs/storage.md "sample_chunks"). Samples of
// every DUT channel are stored per channel in chunks of up to 4096 samples
// on a regular clock (implicit time stamps), values as sent in the
// narrowest exact encoding. The data step (chunks.cpp) moves each run's
// gyro_samples into chunks of the unnamed gyro (serial '') and drops
// gyro_samples and gyro_rollup.
constexpr const char* kSchemaV9 = R"sql(
CREATE TABLE sample_chunks(
  id INTEGER PRIMARY KEY,
  channel_id INTEGER NOT NULL,  -- channels.id (not enforced, for insert speed)
  t0_s REAL NOT NULL,           -- first sample, station s since run start
  period_s REAL NOT NULL,       -- sample i is at t0_s + i * period_s, station s (0 when n = 1)
  n INTEGER NOT NULL,           -- samples in the chunk
  seq0 INTEGER NOT NULL,        -- frame counter of the first sample; sample i: (seq0 + i) mod run_duts.seq_modulo (0 when the frames carry none)
  encoding TEXT NOT NULL,       -- how data holds the raw values as sent: u8, i8, u16, i16, u32, i32, f32, f64 (little-endian)
  vn INTEGER NOT NULL,          -- samples with a finite value
  vmin REAL,                    -- smallest physical value (raw * channels.scale) of those; NULL when vn = 0
  vmax REAL,                    -- largest
  vsum REAL,                    -- sum (mean = vsum / vn)
  data BLOB NOT NULL            -- n values of the encoding; NaN = flagged invalid
);
CREATE INDEX sample_chunks_by_channel ON sample_chunks(channel_id, t0_s);

CREATE TABLE channel_rollup(
  channel_id INTEGER NOT NULL,  -- channels.id
  level INTEGER NOT NULL,       -- block length 0.1 * 10^level s: 1, 10, 100, 1000 s (levels 1..4)
  block INTEGER NOT NULL,       -- floor(t_s / block length)
  n INTEGER NOT NULL,           -- samples in the block
  t_sum_s REAL NOT NULL,        -- sum of their t_s (mean time = t_sum_s / n)
  v_n INTEGER NOT NULL,         -- samples with a finite value
  v_sum REAL,                   -- sum of the physical values (mean = v_sum / v_n)
  v_min REAL,
  v_max REAL,
  PRIMARY KEY(channel_id, level, block)
) WITHOUT ROWID;
)sql";

// v10: the lab (docs/storage.md "Lab outbox"). Each run gets an identity
// that holds across the lab's stations: a random (version 4) UUID in lower
// case, set by create_run; runs stored before v10 get one here, made of
// randomblob() in the RFC 4122 text form. A run inserted without one
// (plain SQL, an older tool) gets one from the trigger, so every run has
// one. The outbox holds the changes of the relayed tables once the
// database is bound to a lab station (lab_bind); its triggers are
// generated from the tables' columns by the data step
// (install_lab_triggers, outbox.cpp), which every later migration that
// changes a relayed table runs again.
constexpr const char* kSchemaV10 = R"sql(
ALTER TABLE runs ADD COLUMN uuid TEXT;  -- the run's identity across the lab: RFC 4122 UUID, lower case (version 4, random)
UPDATE runs SET uuid = lower(hex(randomblob(4))) || '-' || lower(hex(randomblob(2))) || '-4' ||
  substr(lower(hex(randomblob(2))), 2) || '-' || substr('89ab', 1 + (random() & 3), 1) ||
  substr(lower(hex(randomblob(2))), 2) || '-' || lower(hex(randomblob(6)));
CREATE UNIQUE INDEX runs_by_uuid ON runs(uuid);
CREATE TRIGGER runs_uuid_on_insert AFTER INSERT ON runs WHEN NEW.uuid IS NULL
BEGIN
  UPDATE runs SET uuid = lower(hex(randomblob(4))) || '-' || lower(hex(randomblob(2))) || '-4' ||
    substr(lower(hex(randomblob(2))), 2) || '-' || substr('89ab', 1 + (random() & 3), 1) ||
    substr(lower(hex(randomblob(2))), 2) || '-' || lower(hex(randomblob(6)))
  WHERE id = NEW.id;
END;

-- Changes of the relayed tables waiting for the lab, in commit order: the
-- relay sends them and deletes them once the lab committed them.
CREATE TABLE outbox(
  seq INTEGER PRIMARY KEY AUTOINCREMENT,  -- order of the changes; never reused (also after acknowledgement)
  kind TEXT NOT NULL,               -- record kind: run, segment, event, table1, allan, fit, fit_run, export, export_run, sf_point, sf_fit, sf_temperature_fit, dut, run_dut, channel
  run_uuid TEXT NOT NULL,           -- runs.uuid of the row's run; 00000000-0000-0000-0000-000000000000 when none
  local_id TEXT NOT NULL,           -- the row's key in its table, key columns joined by '/', e.g. '12/SN-0042/x'
  deleted INTEGER NOT NULL DEFAULT 0,  -- 1: the row was deleted (a tombstone; payload '{}')
  payload TEXT NOT NULL,            -- the row as a JSON object of its columns
  committed_unix_s REAL NOT NULL    -- wall time of the change (system clock), Unix s
);
)sql";

// v11: how complete each result's input was and whether it is plausible
// (docs/analysis.md "Result quality"): coverage (samples stored against
// those expected over the result's windows), the longest gap and a verdict
// with its reasons, on every result table; the guard bands cut from the
// ends of the rate points' windows. Rows stored before v11 read quality
// 'unassessed'. The tables are relayed: the data step regenerates the
// lab outbox triggers from their new columns.
constexpr const char* kSchemaV11 = R"sql(
ALTER TABLE segment_stats ADD COLUMN coverage_samples INTEGER;  -- samples stored over the result's windows; NULL: not assessed
ALTER TABLE segment_stats ADD COLUMN coverage_expected REAL;    -- samples expected: window length x the DUT's output rate; NULL: not known
ALTER TABLE segment_stats ADD COLUMN coverage REAL;             -- coverage_samples / coverage_expected; NULL: not known
ALTER TABLE segment_stats ADD COLUMN longest_gap_s REAL;        -- longest stretch of a window without a sample, station s; NULL: not known
ALTER TABLE segment_stats ADD COLUMN quality TEXT NOT NULL DEFAULT 'unassessed'
  CHECK(quality IN ('ok', 'flagged', 'excluded', 'unassessed'));  -- the verdict ('excluded': a rate point left out of its fit)
ALTER TABLE segment_stats ADD COLUMN quality_reasons_json TEXT NOT NULL DEFAULT '[]';  -- JSON array of the verdict's reasons

ALTER TABLE allan ADD COLUMN coverage_samples INTEGER;  -- samples stored over the result's windows; NULL: not assessed
ALTER TABLE allan ADD COLUMN coverage_expected REAL;    -- samples expected: window length x the DUT's output rate; NULL: not known
ALTER TABLE allan ADD COLUMN coverage REAL;             -- coverage_samples / coverage_expected; NULL: not known
ALTER TABLE allan ADD COLUMN longest_gap_s REAL;        -- longest stretch of a window without a sample, station s; NULL: not known
ALTER TABLE allan ADD COLUMN quality TEXT NOT NULL DEFAULT 'unassessed'
  CHECK(quality IN ('ok', 'flagged', 'excluded', 'unassessed'));  -- the verdict ('excluded': a rate point left out of its fit)
ALTER TABLE allan ADD COLUMN quality_reasons_json TEXT NOT NULL DEFAULT '[]';  -- JSON array of the verdict's reasons

ALTER TABLE fits ADD COLUMN coverage_samples INTEGER;  -- samples stored over the result's windows; NULL: not assessed
ALTER TABLE fits ADD COLUMN coverage_expected REAL;    -- samples expected: window length x the DUT's output rate; NULL: not known
ALTER TABLE fits ADD COLUMN coverage REAL;             -- coverage_samples / coverage_expected; NULL: not known
ALTER TABLE fits ADD COLUMN longest_gap_s REAL;        -- longest stretch of a window without a sample, station s; NULL: not known
ALTER TABLE fits ADD COLUMN quality TEXT NOT NULL DEFAULT 'unassessed'
  CHECK(quality IN ('ok', 'flagged', 'excluded', 'unassessed'));  -- the verdict ('excluded': a rate point left out of its fit)
ALTER TABLE fits ADD COLUMN quality_reasons_json TEXT NOT NULL DEFAULT '[]';  -- JSON array of the verdict's reasons

ALTER TABLE scale_factor_points ADD COLUMN coverage_samples INTEGER;  -- samples stored over the result's windows; NULL: not assessed
ALTER TABLE scale_factor_points ADD COLUMN coverage_expected REAL;    -- samples expected: window length x the DUT's output rate; NULL: not known
ALTER TABLE scale_factor_points ADD COLUMN coverage REAL;             -- coverage_samples / coverage_expected; NULL: not known
ALTER TABLE scale_factor_points ADD COLUMN longest_gap_s REAL;        -- longest stretch of a window without a sample, station s; NULL: not known
ALTER TABLE scale_factor_points ADD COLUMN quality TEXT NOT NULL DEFAULT 'unassessed'
  CHECK(quality IN ('ok', 'flagged', 'excluded', 'unassessed'));  -- the verdict ('excluded': a rate point left out of its fit)
ALTER TABLE scale_factor_points ADD COLUMN quality_reasons_json TEXT NOT NULL DEFAULT '[]';  -- JSON array of the verdict's reasons

ALTER TABLE scale_factor_fits ADD COLUMN coverage_samples INTEGER;  -- samples stored over the result's windows; NULL: not assessed
ALTER TABLE scale_factor_fits ADD COLUMN coverage_expected REAL;    -- samples expected: window length x the DUT's output rate; NULL: not known
ALTER TABLE scale_factor_fits ADD COLUMN coverage REAL;             -- coverage_samples / coverage_expected; NULL: not known
ALTER TABLE scale_factor_fits ADD COLUMN longest_gap_s REAL;        -- longest stretch of a window without a sample, station s; NULL: not known
ALTER TABLE scale_factor_fits ADD COLUMN quality TEXT NOT NULL DEFAULT 'unassessed'
  CHECK(quality IN ('ok', 'flagged', 'excluded', 'unassessed'));  -- the verdict ('excluded': a rate point left out of its fit)
ALTER TABLE scale_factor_fits ADD COLUMN quality_reasons_json TEXT NOT NULL DEFAULT '[]';  -- JSON array of the verdict's reasons

ALTER TABLE scale_factor_points ADD COLUMN guard_s REAL NOT NULL DEFAULT 0;  -- cut from each end of each window before the mean, station s
ALTER TABLE scale_factor_fits ADD COLUMN guard_s REAL NOT NULL DEFAULT 0;    -- its points' guard bands, station s
)sql";

// v12: packed sample chunks (docs/storage.md "Encodings"). Closed chunks
// are now written in the encodings i32/1e<k>, i64/1e<k> and
// <base>+shuffle+zstd beside the plain ones, which an older build cannot
// read; the version keeps it from opening such a file (it refuses a newer
// schema). Chunks already stored stay as they are. An open chunk is
// written in pieces, numbered within their chunk (`piece`; 0: a whole
// chunk), so that pieces a killed writer left are found (the partial index)
// and merged by the next writer.
constexpr const char* kSchemaV12 = R"sql(
ALTER TABLE sample_chunks ADD COLUMN piece INTEGER NOT NULL DEFAULT 0;
CREATE INDEX sample_chunks_pieces ON sample_chunks(channel_id, t0_s) WHERE piece > 0;
)sql";

// v13: Table I's mean with its uncertainty (docs/analysis.md "Uncertainty
// of a mean"): the noise model's u(T) at the soak's duration, its expanded
// form at 95 %, the coverage factor and degrees of freedom, the flicker
// floor and the random-walk flag; NULL for rows stored before v13 or a soak
// that gave no model (bias_u_note says why). The table is relayed: the data
// step regenerates the lab outbox triggers from its new columns.
constexpr const char* kSchemaV13 = R"sql(
ALTER TABLE segment_stats ADD COLUMN bias_u_dph REAL;           -- standard uncertainty of bias_mean_dph, °/h; NULL: none
ALTER TABLE segment_stats ADD COLUMN bias_u_expanded_dph REAL;  -- bias_u_k x bias_u_dph, 95 %
ALTER TABLE segment_stats ADD COLUMN bias_u_k REAL;             -- coverage factor (Student t at bias_u_dof)
ALTER TABLE segment_stats ADD COLUMN bias_u_dof REAL;           -- effective degrees of freedom (at most 1e6)
ALTER TABLE segment_stats ADD COLUMN bias_u_floor_dph REAL;     -- the flicker floor no soak length gets below, °/h
ALTER TABLE segment_stats ADD COLUMN bias_u_random_walk INTEGER;  -- 1: u is mostly rate random walk (covers less than it says)
ALTER TABLE segment_stats ADD COLUMN bias_u_note TEXT NOT NULL DEFAULT '';  -- why there is no uncertainty
)sql";

// v14: adaptive soaks (docs/schedules.md "Adaptive soaks"): why a soak's
// acquisition ended, the target reached, out of reach (with the floor) or
// the cap; empty for fixed soaks and older rows. Segments are relayed: the
// data step regenerates the lab outbox triggers from the new column.
constexpr const char* kSchemaV14 = R"sql(
ALTER TABLE segments ADD COLUMN acquire_stop TEXT NOT NULL DEFAULT '';  -- adaptive soak: why its acquisition ended
)sql";

constexpr Migration kMigrations[] = {
    {1, "initial schema", kSchemaV1},
    {2, "queue, crash resume, acquisition windows", kSchemaV2},
    {3, "gyro rate rollups, drift-model fits", kSchemaV3},
    {4, "Allan deviation per soak", kSchemaV4},
    {5, "calibration exports", kSchemaV5},
    {6, "runs.config_json is JSON, old TOML in runs.config_toml", kSchemaV6},
    {7, "rate table samples and segments, scale-factor points and fits", kSchemaV7},
    {8, "devices under test, run metadata, results per DUT and axis", kSchemaV8},
    {9, "chunked sample storage", kSchemaV9, migrate_gyro_samples_to_chunks},
    {10, "run UUIDs, lab outbox", kSchemaV10, install_lab_triggers_step},
    {11, "result coverage and quality, rate-point guard bands", kSchemaV11,
     install_lab_triggers_step},
    {12, "packed sample chunks", kSchemaV12},
    {13, "Table I mean uncertainty", kSchemaV13, install_lab_triggers_step},
    {14, "adaptive soaks' stop reasons", kSchemaV14, install_lab_triggers_step},
};

static_assert(sizeof(kMigrations) / sizeof(kMigrations[0]) == kSchemaVersion,
              "one migration per schema version");

}  // namespace

std::span<const Migration> migrations() { return kMigrations; }

}  // namespace gyrotherm::storage::internal

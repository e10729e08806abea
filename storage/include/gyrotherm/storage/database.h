// The station database (SQLite, WAL mode): schema, migrations, records.
//
// One database per station. The schema is a user interface (people query it
// with sqlite3); it is documented in docs/storage.md and versioned in the
// `meta` table (key 'schema_version'); open() applies every migration the
// file lacks, in one transaction each.
//
// A Database object owns one connection and is not thread-safe: each thread
// (control loop, sample writer, HTTP readers, CLI) opens its own. WAL lets
// readers work while a run is being written; busy_timeout is 5 s.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"

struct sqlite3;

namespace gyrotherm::storage {

namespace internal {
struct FileGuard;
}

// v8: DUTs, run metadata, results per DUT and axis (records).
// v9: chunked sample storage (sample_chunks, channel_rollup).
// v10: run UUIDs and the lab outbox (runs.uuid, outbox; docs/lab.md).
// v11: coverage and a quality verdict on every result; rate points' guard
// bands.
inline constexpr int kSchemaVersion = 12;

// Rollup blocks of the gyro rate (table gyro_rollup): block length of each
// level, station seconds. A sample at t_s is in block floor(t_s / length).
inline constexpr double kRollupBlockS[] = {0.1, 1.0, 10.0, 100.0, 1000.0};
inline constexpr int kRollupLevels = 5;

// Who ran a run and why, and which gyros were in it (schema v8). Set when
// queued, kept on the run, editable afterwards (each edit is an event).
struct RunMetadata {
  std::string operator_name;  // column runs.operator
  std::string comment;
  std::vector<std::string> tags;         // free tags, stored as a JSON array
  std::vector<std::string> dut_serials;  // as declared when queued; the run's DUTs are run_duts
};

struct RunRecord {
  int64_t id = 0;
  std::string schedule_name;
  std::string state;        // queued, ramping, settling, acquiring, ..., completed, failed
  std::string started_utc;  // ISO-8601 UTC wall time; "" = now (create_run)
  std::string ended_utc;    // "" while running
  double time_scale = 1.0;
  double latitude_deg = 0;
  std::string orientation;  // up, down, horizontal
  // The station configuration in force when the run started, as a JSON
  // object (API tokens redacted); "" when unknown. Schema v6 refuses text
  // that is not JSON.
  std::string config_json;
  // Runs stored before schema v6: the config file's TOML text as re-read
  // from disk at run start (not necessarily the config in force); "" for
  // later runs. Read-only history: new runs store config_json.
  std::string config_toml;
  std::optional<int64_t> queue_id;
  std::optional<int64_t> schedule_id;
  // Crash resume: the sequencer's last snapshot (JSON) and the wall time it
  // was taken (Unix seconds); empty / nullopt until the first checkpoint.
  std::string resume_json;
  std::optional<double> checkpoint_wall_unix_s;
  RunMetadata metadata;  // schema v8
  // Schema v10: the run's identity across the lab (RFC 4122 text form,
  // lower case), set by create_run when "" (random, version 4); runs
  // stored before v10 got one in the migration.
  std::string uuid;
};

// A device under test, as the station has known it (table duts): one row
// per serial number, whatever runs it was in. serial "" is the unnamed gyro
// of runs recorded before DUTs had serials.
struct DutRecord {
  int64_t id = 0;
  std::string serial;
  std::string model;
  std::string first_seen_utc;  // "" = now
};

// One channel of one DUT in one run (table channels). Samples are stored
// per channel; see sample_chunks (docs/storage.md).
struct ChannelRecord {
  int64_t id = 0;
  int64_t run_id = 0;
  int64_t dut_id = 0;
  int index = 0;  // position in the DUT's frames (DutFrame::raw)
  ChannelSpec spec;
};

// A DUT in a run (table run_duts) with its channels.
struct RunDutRecord {
  int64_t run_id = 0;
  int position = 0;  // order in the run's [[dut]] list, from 0
  DutRecord dut;
  std::string config_json;              // the [[dut]] entry the run used (JSON object)
  std::string primary_axis;             // e.g. "z"
  std::vector<std::string> axes;        // analysed rate axes
  double rate_hz = 0;                   // nominal output rate
  uint32_t seq_modulo = 0;              // 0: the frames carry no counter
  std::vector<ChannelRecord> channels;  // by index
};

// Which rate series of a run: a DUT (by serial; "" with dut_id 0 = the run's
// first DUT) and its axis ("" = that DUT's primary axis).
struct StreamKey {
  std::string dut_serial;
  std::string axis;
};

struct SegmentRecord {
  int64_t id = 0;
  int64_t run_id = 0;
  int index = 0;                   // position in the expanded schedule, from 0
  std::string kind;                // soak, ramp, hold
  std::string label;               // e.g. "soak 20 °C (step 1)"
  double setpoint_c = 0;           // soak/hold set point, ramp target
  double ramp_rate_c_per_min = 0;  // ramps only
  // Station seconds since run start; nullopt until reached.
  double t_start_s = 0;
  std::optional<double> t_settled_s;
  std::optional<double> t_acquire_start_s;
  std::optional<double> t_acquire_end_s;
  std::optional<double> t_end_s;
  double paused_s = 0;  // station seconds excluded from acquisition
  std::string state;    // running, completed, failed, aborted
  // Acquisition windows (from_s, to_s), station s; pauses and suspensions
  // cut out. update_segment() replaces the stored list.
  std::vector<std::pair<double, double>> windows;
  // The rate table during the step (schema v7). The demand, from the plan
  // step: table_mode none, static or rate; table_rate_dps the demanded rate
  // (0 for static), nullopt when the mode is none; table_position_deg the
  // demanded position, nullopt when none was given.
  std::string table_mode = "none";
  std::optional<double> table_rate_dps{};
  std::optional<double> table_position_deg{};
  // Measured over the acquisition windows (mean_table_over_windows): the
  // mean rate, °/s, and the circular mean position, degrees in [0, 360);
  // nullopt until known.
  std::optional<double> table_mean_rate_dps{};
  std::optional<double> table_mean_position_deg{};
  // Rate points (kind "rate"): the whole turns acquired and the dwell over
  // them (station s), the scale-factor sequence of the plan and the
  // repetition (both from 1); 0 for other steps.
  int turns = 0;
  double dwell_s = 0;
  int sf_sequence = 0;
  int sf_repetition = 0;
};

// One entry of the persistent run queue, with its schedule.
struct QueueEntry {
  int64_t id = 0;
  RunMetadata metadata;  // schema v8: given to the run it starts
  int64_t schedule_id = 0;
  int position = 0;   // among queued entries, 0 = next; -1 once taken
  std::string state;  // queued, running, completed, failed, interrupted, removed
  std::string added_utc;
  bool ignore_failures = false;
  std::optional<int64_t> run_id;
  std::string schedule_name;
  std::string source_path;
  std::string toml_text;
};

struct EventRecord {
  int64_t id = 0;
  std::optional<int64_t> run_id;
  double t_s = 0;        // station seconds since run start (0 without run)
  std::string wall_utc;  // ISO-8601 UTC; "" = now (add_event)
  std::string kind;      // state, interlock, device, info, error
  std::string from_state;
  std::string to_state;
  std::string message;  // what a technician reads
};

// How complete a result's input was and whether the result is plausible
// (schema v11; docs/analysis.md "Result quality"). Coverage: the samples
// stored over the result's windows against those expected (window length ×
// the DUT's output rate); the longest gap: the longest stretch of a window
// without a sample. verdict "ok" or "flagged", with the reasons; a rate
// point left out of its sequence's fit is "excluded" (the reasons say
// why); a result nobody assessed (rows stored before v11, a record left
// as constructed) is "unassessed". Columns coverage_samples,
// coverage_expected, coverage, longest_gap_s, quality, quality_reasons_json.
struct ResultQuality {
  int64_t samples = 0;
  double expected = 0;                  // 0: not known (no output rate)
  std::optional<double> coverage{};     // samples / expected; nullopt: not known
  std::optional<double> longest_gap_s;  // nullopt: not known
  std::string verdict = "unassessed";   // ok, flagged, excluded, unassessed
  std::vector<std::string> reasons{};   // what a technician reads, one each
  bool flagged() const { return verdict == "flagged"; }
  bool excluded() const { return verdict == "excluded"; }
};

// One Table I row (docs/analysis.md) with the inputs it was computed with.
struct SegmentStatsRecord {
  int64_t segment_id = 0;
  int64_t run_id = 0;
  // Schema v8: the DUT and axis (one row per segment, DUT and axis). ""
  // when written means the run's first DUT and its primary axis.
  std::string dut_serial;
  std::string axis;
  int segment_index = 0;
  double setpoint_c = 0;
  int64_t n = 0;
  double duration_s = 0;
  double temp_mean_c = 0;
  double bias_mean_dph = 0;
  double bias_std_dph = 0;
  double bias_std_ma_dph = 0;  // after the ma_window-point moving average
  double bias_mean_earth_removed_dph = 0;
  double bin_s = 1.0;
  int ma_window = 101;
  double earth_rate_dph = 0;        // the component that was removed
  double t_from_s = 0, t_to_s = 0;  // window, station s since run start
  std::string computed_utc;         // ISO-8601 UTC; "" = now
  ResultQuality quality;            // schema v11: over the soak's windows
};

// A stored drift-model fit (paper eq. 1) with what it was computed from.
struct FitRecord {
  int64_t id = 0;
  std::string dut_serial;        // schema v8; "" = the runs' first DUT
  std::string axis;              // schema v8; "" = its primary axis
  std::vector<int64_t> run_ids;  // the runs whose data were fitted
  std::string model;             // e.g. "T4+R1+G1"
  std::string form;              // paper, centered
  int64_t n = 0;
  std::string coefficients_json;     // JSON object, physical units
  std::string standard_errors_json;  // JSON object, same keys
  double residual_std_dph = 0;
  double r_squared = 0;
  std::string inputs_json;   // JSON object
  std::string computed_utc;  // "" = now (add_fit)
  ResultQuality quality;     // schema v11: over the stretches fitted
};

// The Allan deviation of one soak's acquisition (docs/analysis.md) with what it
// was computed from (schema v4, table `allan`). The curve is stored as JSON
// arrays of the same length so sqlite3's json functions can read it.
struct AllanRecord {
  int64_t id = 0;
  int64_t run_id = 0;
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int64_t segment_id = 0;           // the soak's segment (0: not tied to a segment)
  int segment_index = 0;            // 0-based step index
  double t_from_s = 0, t_to_s = 0;  // samples used, station s since run start
  std::string taus;                 // octave, decade, all
  double tau0_s = 0;
  int64_t n_samples = 0;
  std::vector<double> tau_s, adev_dph, adev_lo_dph, adev_hi_dph;  // same length
  std::optional<double> angle_random_walk_dprh;                   // °/√h
  std::optional<double> bias_instability_dph;                     // minimum / 0.664
  std::optional<double> bias_instability_tau_s;
  std::optional<double> rate_random_walk_dphprh;  // °/h/√h
  std::string bias_instability_method = "minimum / 0.664";
  std::string inputs_json;   // JSON object: windows, taus, ...
  std::string computed_utc;  // "" = now (put_allan)
  ResultQuality quality;     // schema v11: over [t_from_s, t_to_s)
};

// One calibration export (docs/reports.md; schema v5, tables `exports` and
// `export_runs`): the reports of some runs written into one directory.
// Nightly exports carry the slot they ran for; at most one export per slot
// (a unique index), and a completed run is in at most one nightly export
// that is writing or done, so nothing is exported twice. Manual exports
// (`gyrotherm export`) are recorded too but never take runs from the nightly
// selection.
struct ExportRecord {
  int64_t id = 0;
  std::string kind;                   // nightly, manual
  std::optional<double> slot_unix_s;  // nightly: the scheduled slot (Unix seconds)
  std::string slot_local;          // nightly: the slot as local time, e.g. "2026-03-29 02:00 CET"
  std::string state;               // writing, done, failed
  std::string directory;           // where the files are
  std::vector<int64_t> run_ids;    // ascending
  std::vector<std::string> files;  // relative to directory (set by finish_export)
  std::string started_utc;         // ISO-8601 UTC; "" = now (begin_export)
  std::string finished_utc;        // "" until finished
  std::string message;             // failed: why; done: a summary (may be "")
};

// One rate point of a scale-factor sequence (schema v7, table
// scale_factor_points): the gyro's mean output against the table's rate over
// the point's acquisition windows. Rates in °/s (the gyro output converted
// from °/h). NaN is stored as NULL and read back as NaN.
struct ScaleFactorPointRecord {
  int64_t id = 0;          // set when read
  int64_t run_id = 0;      // 0: the run store_scale_factor() is given
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int64_t segment_id = 0;        // the rate point's segment (0: not tied to one)
  int sf_sequence = 0;           // segments.sf_sequence
  int repetition = 0;            // segments.sf_repetition
  double rate_dps = 0;           // demanded table rate
  double measured_rate_dps = 0;  // table rate measured over the windows
  double output_dps = 0;         // mean gyro output over the windows
  int64_t n = 0;                 // gyro samples averaged
  double temperature_c = 0;      // mean shell temperature (top + side) / 2
  double duration_s = 0;         // acquisition time, station s
  double turns = 0;              // table turns over the acquisition
  // Schema v11: cut from each end of each acquisition window before the
  // mean (docs/analysis.md "Rate points"), station s; the quality is over
  // what is left. verdict "excluded": left out of the sequence's fit.
  double guard_s = 0;
  ResultQuality quality;
};

// The fit output = K * rate + bias of one scale-factor sequence (table
// scale_factor_fits; docs/analysis.md defines the figures).
struct ScaleFactorFitRecord {
  int64_t run_id = 0;      // 0: the run store_scale_factor() is given
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int sf_sequence = 0;
  double temperature_c = 0;  // mean temperature of the sequence's points
  double k = 0;              // scale factor, (°/s) / (°/s)
  double k_se = 0;           // its standard error
  double bias_dps = 0;
  double nonlinearity_ppm = 0;                // relative to K
  double nonlinearity_fs_ppm = 0;             // relative to the full-scale output
  std::optional<double> asymmetry_ppm{};      // nullopt: one direction only
  std::optional<double> repeatability_ppm{};  // nullopt: fewer than 2 repetitions
  int64_t n_points = 0;
  std::string created_utc{};  // ISO-8601 UTC; "" = now (store_scale_factor)
  double guard_s = 0;         // schema v11: the points' guard bands, station s
  ResultQuality quality{};    // schema v11: over the points fitted
};

// K(T) and bias(T) of a run as polynomials in (T - t_centre_c) (table
// scale_factor_temperature_fits, column poly_order for `order`). The
// coefficients are JSON arrays of numbers, lowest power first; bias in °/s.
struct ScaleFactorTemperatureFitRecord {
  int64_t run_id = 0;      // 0: the run store_scale_factor() is given
  std::string dut_serial;  // schema v8, as SegmentStatsRecord
  std::string axis;
  int order = 0;  // polynomial degree
  double t_centre_c = 0;
  std::string k_coeffs_json{};     // e.g. "[1.0000123, 2.1e-6]"; "" stores "[]"
  std::string bias_coeffs_json{};  // °/s; "" stores "[]"
  double k_ppm_per_c = 0;          // dK/dT / K at t_centre_c, ppm/°C
  double bias_dph_per_c = 0;       // dbias/dT at t_centre_c, (°/h)/°C
  std::string created_utc{};       // "" = now (store_scale_factor)
};

// The table over a segment's acquisition windows (mean_table_over_windows).
struct TableWindowMeans {
  int64_t n = 0;                     // table samples in the windows
  std::optional<double> rate_dps{};  // mean measured rate; nullopt: no rate
  // Circular mean of the measured position, [0, 360); nullopt when there is
  // none or the positions are spread evenly round the circle (resultant
  // below kMinResultant, e.g. whole turns at rate).
  std::optional<double> position_deg{};
  double position_resultant = 0;  // mean resultant length of the positions, 0..1
  static constexpr double kMinResultant = 1e-6;
};

// A run's samples in [from_s, to_s] reduced to at most max_points points
// each: the gyro rate as mean with a min/max envelope, the temperatures as
// means, the table's rate as mean with an envelope and its state as last seen. Points are buckets
// of bucket_s station seconds; bucket_s == 0 when the samples are returned as recorded (no more
// than max_points of them).
struct DecimatedSamples {
  std::string dut_serial;  // the series the gyro points are of
  std::string channel;     // e.g. gyro_z
  std::string unit;        // of the gyro points (deg/h for rate channels)
  double from_s = 0, to_s = 0;
  double bucket_s = 0;
  bool from_rollup = false;  // gyro points come from gyro_rollup blocks
  struct Gyro {
    std::vector<double> t_s;  // mean time of the bucket's samples
    std::vector<int64_t> n;
    std::vector<double> mean_dph, min_dph, max_dph;  // NaN: no rate in the bucket
  } gyro;
  struct Temperatures {
    std::vector<double> t_s;
    std::vector<double> setpoint_c, chamber_c, top_c, side_c;  // NaN: none
  } temperature;
  // The rate table (schema v7), bucketed like the temperatures: the
  // measured rate as mean with a min/max envelope (°/s), the rest as the
  // bucket's last reading. Empty for a run without a table.
  struct Table {
    std::vector<double> t_s;  // mean time of the bucket's samples
    std::vector<int64_t> n;
    std::vector<double> mean_rate_dps, min_rate_dps, max_rate_dps;  // NaN: no rate
    std::vector<double> position_deg;                       // last measured position; NaN: none
    std::vector<double> demand_rate_dps;                    // last demanded rate
    std::vector<std::string> demand_mode, mode, interlock;  // last
  } table;
};

// Everything one gyro has been through (dut_history): its runs, their
// segments, and its results per axis.
struct DutHistory {
  DutRecord dut;
  struct Run {
    RunRecord run;  // config_json and resume_json left empty
    RunDutRecord in_run;
    std::vector<SegmentRecord> segments;
    std::vector<SegmentStatsRecord> stats;           // this DUT's rows, every axis
    std::vector<AllanRecord> allan;                  // this DUT's
    std::vector<ScaleFactorFitRecord> scale_factor;  // this DUT's
  };
  std::vector<Run> runs;        // by run id
  std::vector<FitRecord> fits;  // this DUT's drift fits, newest first
};

// The lab outbox (schema v10, docs/lab.md "Outbox"). Once a station is
// bound to a lab (lab_bind), every insert, update and delete of a relayed
// table (runs, segments, events, segment_stats, allan, fits, fit_runs,
// exports, export_runs, scale_factor_points, scale_factor_fits,
// scale_factor_temperature_fits, duts, run_duts, channels) adds one outbox
// row, written by triggers in the same
// transaction as the change itself: a result committed is a result queued
// for the lab. Raw samples are not relayed.
struct OutboxRecord {
  int64_t seq = 0;   // outbox order (AUTOINCREMENT: never reused)
  std::string kind;  // the relayed table's record kind: run, segment, table1, allan, ...
  std::string
      run_uuid;  // the run's uuid; kNilUuid for station-level rows (duts, events outside runs)
  std::string local_id;         // the row's key in its table as text, e.g. "12" or "12/17-0042/x"
  bool deleted = false;         // a tombstone: the row was deleted (payload {})
  std::string payload_json;     // the row as a JSON object of its columns ({} for tombstones)
  double committed_unix_s = 0;  // wall time (system clock) the change was written, Unix s
};

inline constexpr std::string_view kNilUuid = "00000000-0000-0000-0000-000000000000";

struct OutboxStats {
  int64_t pending = 0;                  // rows not yet acknowledged
  int64_t pending_bytes = 0;            // sum of their payload sizes
  std::optional<double> oldest_unix_s;  // committed_unix_s of the oldest pending row
  int64_t last_acked_seq = 0;           // highest seq acknowledged so far (0: none)
};

// The file a connection opened: its device and inode when it was opened.
struct FileIdentity {
  uint64_t dev = 0;
  uint64_t ino = 0;
  bool operator==(const FileIdentity&) const = default;
};

// What open() checks before it migrates or writes anything.
enum class OpenCheck {
  kNone,
  // PRAGMA quick_check over the whole file: it reads every page, about 1 s
  // per GB from the page cache, the disk's read time otherwise
  // (docs/storage.md). The daemon's start.
  kQuick,
};

class Database {
 public:
  // Opens or creates `path`, sets WAL and busy_timeout, migrates to
  // kSchemaVersion. Errors name the file. A file with a newer schema than this
  // build knows is a permanent error (never downgraded). The UTC times it
  // stamps (a run's start and end, events, statistics, fits, exports, queue
  // entries) come from `wall` (not owned; outlives the connection).
  // With OpenCheck::kQuick a file quick_check finds damaged is refused (a
  // permanent error naming the file and the first problems) before anything
  // is written to it.
  //
  // The connection records the file's identity (device, inode) and commits
  // nothing once its path names another file or none (check_file()): every
  // write transaction is then rolled back with an error saying so.
  static Result<Database> open(const std::string& path, const WallClock& wall = system_wall_clock(),
                               OpenCheck check = OpenCheck::kNone);
  // Opens an existing database read-only (for the CLI and HTTP readers); no
  // migration. Error if it does not exist or its schema is unknown.
  static Result<Database> open_read_only(const std::string& path);

  Database(Database&& other) noexcept;
  Database& operator=(Database&& other) noexcept;
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;
  ~Database();

  Result<int> schema_version();

  // Runs.
  Result<int64_t> create_run(const RunRecord& run);  // id and ended_utc ignored
  // ended: stamps ended_utc with the current wall time; otherwise clears it
  // (a resumed interrupted run is running again).
  Status set_run_state(int64_t run_id, std::string_view state, bool ended);
  Result<std::vector<RunRecord>> runs();
  Result<RunRecord> run(int64_t run_id);

  // Run metadata (schema v8). set_run_metadata replaces it and adds an
  // event (kind "metadata") naming who changed what (`changed_by`: a token
  // label or "cli"); the event's message lists old -> new per field.
  Status set_run_metadata(int64_t run_id, const RunMetadata& metadata, std::string_view changed_by);

  // DUTs (schema v8). add_run_dut registers the DUT (by serial: created on
  // first sight, model updated when given) in the run with its channels, in
  // one transaction; returns the record with every id set. Twice for the
  // same (run, serial): returns the existing record (crash resume).
  Result<RunDutRecord> add_run_dut(int64_t run_id, const RunDutRecord& dut);
  Result<std::vector<RunDutRecord>> run_duts(int64_t run_id);  // by position
  Result<std::vector<DutRecord>> duts();                       // by serial
  Result<std::optional<DutRecord>> dut(std::string_view serial);
  Result<DutHistory> dut_history(std::string_view serial);  // error when unknown (named)
  // The run's DUT and axis `key` names, resolved ("" -> first DUT, primary
  // axis); error naming the serial or axis when the run has no such.
  Result<std::pair<RunDutRecord, std::string>> resolve_stream(int64_t run_id, const StreamKey& key);

  // Stores the sequencer snapshot for crash resume.
  Status set_run_checkpoint(int64_t run_id, std::string_view resume_json, double wall_unix_s);
  // Runs `body` (calls of this Database) in one transaction: all of its
  // writes commit together, or none when it returns an error (that error is
  // returned). For what must not be seen half done after a crash: a step's
  // end, the next step's start and the checkpoint that says so.
  Status atomically(const std::function<Status()>& body);
  // Latest station time with a committed sample of the run (gyro,
  // temperature or table); nullopt when it has none.
  Result<std::optional<double>> last_sample_t_s(int64_t run_id);
  // Latest station time with a committed gyro sample of the run; nullopt
  // when it has none. What a crash resume credits acquisition up to: Table I
  // is made of gyro samples, and temperatures (one per control tick) can be
  // committed well past them when the gyro stream lags.
  Result<std::optional<double>> last_gyro_sample_t_s(int64_t run_id);

  // The queue. Positions of queued entries are kept 0..n-1 in run order.
  // add: stores the schedule text and appends the entry.
  Result<QueueEntry> queue_add(const std::string& schedule_name, const std::string& source_path,
                               const std::string& toml_text, bool ignore_failures,
                               const RunMetadata& metadata = {});
  // The running entry (if any) first, then queued entries by position.
  Result<std::vector<QueueEntry>> queue_entries();
  Result<std::optional<QueueEntry>> queue_entry(int64_t id);
  // Queued -> removed. False (nothing changed) when the entry is not queued.
  Result<bool> queue_remove(int64_t id);
  // Moves a queued entry to `position` (clamped). False when not queued.
  Result<bool> queue_move(int64_t id, int position);
  // Queued -> running with its run. False when the entry is no longer queued.
  Result<bool> queue_claim(int64_t id, int64_t run_id);
  // Starts the run of a queued entry in one transaction: the entry goes
  // queued -> running and a run row is created from `run` (its queue_id and
  // schedule_id are the entry's). nullopt, and no run row, when the entry is
  // no longer queued (removed or moved on by another connection meanwhile).
  Result<std::optional<int64_t>> queue_start_run(int64_t id, const RunRecord& run);
  // running -> a final state (completed, failed, interrupted).
  Status queue_finish(int64_t id, std::string_view state);
  // Running -> queued again at the head (a run that could not start).
  Status queue_requeue(int64_t id);

  // Station-wide settings (the meta table): queue hold, etc.
  Result<std::optional<std::string>> meta(std::string_view key);
  Status set_meta(std::string_view key, std::string_view value);
  Status delete_meta(std::string_view key);

  // Segments: one per step execution.
  Result<int64_t> create_segment(const SegmentRecord& segment);  // id ignored
  Status update_segment(const SegmentRecord& segment);           // by id
  Result<std::vector<SegmentRecord>> segments(int64_t run_id);

  // Events.
  Result<int64_t> add_event(const EventRecord& event);
  Result<std::vector<EventRecord>> events(int64_t run_id);

  // Table I rows. put_segment_stats inserts or replaces by (segment, DUT,
  // axis); dut_serial/axis "" are resolved when the run has DUTs (the first
  // DUT, its primary axis; docs/storage.md "Results per DUT and axis"); a
  // serial not in the run is refused. Storing a DUT's primary axis replaces
  // that DUT's row of the segment stored before v8 (axis '').
  Status put_segment_stats(const SegmentStatsRecord& stats);
  // All rows (run_id nullopt) or one run's, ordered by run, segment index,
  // DUT position in the run, serial, axis.
  Result<std::vector<SegmentStatsRecord>> segment_stats(std::optional<int64_t> run_id);

  // Samples in [t_from_s, t_to_s) of a run, ordered by time (t_s relative to
  // run start). For analysis windows; not for whole 10-M-sample runs.
  // The first form: the run's first DUT, its primary axis.
  Result<std::vector<GyroSample>> gyro_samples(int64_t run_id, double t_from_s, double t_to_s);
  // One DUT's rate axis: rate_dph from the axis's channel; status, temp_c
  // from the DUT's status and temperature channels when it has them; seq
  // from the chunk's counter.
  Result<std::vector<GyroSample>> gyro_samples(int64_t run_id, const StreamKey& key,
                                               double t_from_s, double t_to_s);
  // Streams one channel's samples in [t_from_s, t_to_s) in time order, in
  // blocks (one chunk at a time: memory independent of the span): `block`
  // gets times (run s) and physical values (raw * scale; NaN where
  // invalid) of equal length. Returning false stops the scan.
  Status for_each_channel_block(
      int64_t channel_id, double t_from_s, double t_to_s,
      const std::function<bool(std::span<const double> t_s, std::span<const double> value,
                               std::span<const uint32_t> seq)>& block);
  // Samples of a channel (every DUT channel; committed).
  Result<int64_t> count_channel_samples(int64_t channel_id);
  Result<std::vector<TemperatureSample>> temperature_samples(int64_t run_id, double t_from_s,
                                                             double t_to_s);
  Result<std::vector<TableSample>> table_samples(int64_t run_id, double t_from_s, double t_to_s);
  Result<int64_t> count_gyro_samples(int64_t run_id);  // frames of the run's first DUT
  // The table's mean rate and circular mean position over `windows`
  // ((from_s, to_s) station s, each half-open like table_samples): what a
  // segment's table_mean_* columns hold. Overlapping windows count a sample
  // once per window.
  Result<TableWindowMeans> mean_table_over_windows(
      int64_t run_id, const std::vector<std::pair<double, double>>& windows);
  // Decimated samples for plots (docs/storage.md "Rollups"). Reads at most
  // about 10 * max_points rows whatever the run's length: gyro buckets are
  // made of whole rollup blocks (so [from_s, to_s] widens to block edges)
  // unless the raw rows in range are few. to_s nullopt: the last sample.
  Result<DecimatedSamples> decimated_samples(int64_t run_id, double from_s,
                                             std::optional<double> to_s, int max_points);
  // The same for one DUT's channel (`channel` "" = the DUT's primary rate
  // axis channel; any numeric channel may be asked for): the gyro points
  // are that channel's, in its unit.
  Result<DecimatedSamples> decimated_samples(int64_t run_id, const StreamKey& dut,
                                             const std::string& channel, double from_s,
                                             std::optional<double> to_s, int max_points);

  // Fits.
  // The DUT and axis are resolved against the first of run_ids, as
  // put_segment_stats does.
  Result<int64_t> add_fit(const FitRecord& fit);
  // A run's fits (every fit that used it), newest first.
  Result<std::vector<FitRecord>> fits(int64_t run_id);
  Result<std::optional<FitRecord>> fit(int64_t fit_id);

  // Allan deviation. put_allan inserts, or replaces the row of the same
  // (run_id, segment_index, taus, dut_serial, axis), DUT and axis resolved
  // as put_segment_stats does; returns the row id.
  Result<int64_t> put_allan(const AllanRecord& allan);
  // A run's Allan records, by segment_index, DUT position, serial, axis,
  // taus.
  Result<std::vector<AllanRecord>> allan(int64_t run_id);

  // Scale factor (schema v7). store_scale_factor replaces the points,
  // fits and temperature fit (none stored when `temperature_fit` is nullopt)
  // of one DUT and axis of the run (schema v8) in one transaction: after a
  // failure the previous rows are intact; other DUTs' and axes' rows stay.
  // The DUT and axis are the ones the records name (dut_serial/axis; every
  // record naming one must name the same, else refused naming both); when
  // none names one, the run's first DUT and its primary axis.
  // Records with run_id 0 take `run_id`; another run_id is refused (named).
  // Rows are stamped created_utc from the wall clock when theirs is "".
  Status store_scale_factor(int64_t run_id, const std::vector<ScaleFactorPointRecord>& points,
                            const std::vector<ScaleFactorFitRecord>& fits,
                            const std::optional<ScaleFactorTemperatureFitRecord>& temperature_fit);
  // The same for the DUT and axis `stream` names (resolved like results:
  // "" = the run's first DUT, its primary axis). Records with dut_serial
  // or axis "" take the stream's; a record naming another is refused.
  Status store_scale_factor(int64_t run_id, const StreamKey& stream,
                            const std::vector<ScaleFactorPointRecord>& points,
                            const std::vector<ScaleFactorFitRecord>& fits,
                            const std::optional<ScaleFactorTemperatureFitRecord>& temperature_fit);
  // Every DUT and axis of the run: by DUT position, serial, axis, then
  // sf_sequence, repetition, demanded rate.
  Result<std::vector<ScaleFactorPointRecord>> scale_factor_points(int64_t run_id);
  // Every DUT and axis: by DUT position, serial, axis, then sf_sequence.
  Result<std::vector<ScaleFactorFitRecord>> scale_factor_fits(int64_t run_id);
  // The run's first DUT, primary axis (as before v8: the run's one fit).
  Result<std::optional<ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fit(
      int64_t run_id);
  // One DUT and axis ("" as in store_scale_factor).
  Result<std::optional<ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fit(
      int64_t run_id, const StreamKey& stream);
  // Every DUT and axis of the run, by DUT position, serial, axis.
  Result<std::vector<ScaleFactorTemperatureFitRecord>> scale_factor_temperature_fits(
      int64_t run_id);

  // Exports. begin_export inserts the record in state "writing" with its
  // runs (one transaction) and returns its id; errors: a nightly export
  // without slot, a second export of the same nightly slot (names the slot),
  // a run in another nightly export that is writing or done (names it), an
  // unknown run. finish_export sets state "done" or "failed", the files and
  // the message, and stamps finished_utc.
  Result<int64_t> begin_export(const ExportRecord& record);
  Status finish_export(int64_t export_id, std::string_view state,
                       const std::vector<std::string>& files, std::string_view message);
  // Every export, newest (highest id) first, with runs and files.
  Result<std::vector<ExportRecord>> exports();
  Result<std::optional<ExportRecord>> export_record(int64_t export_id);
  // The latest slot of any nightly export (whatever its state); nullopt when
  // there is none.
  Result<std::optional<double>> last_nightly_slot_unix_s();
  // Completed runs (state 'completed') in no nightly export that is writing
  // or done, ascending.
  Result<std::vector<int64_t>> runs_not_exported();

  // The lab (schema v10). lab_station_id: the station id the database is
  // bound to (meta 'lab_station_id'), nullopt when never bound. lab_bind
  // binds it (first time: in one transaction, sets the id and queues every
  // existing row of the relayed tables in the outbox, so the lab gets the
  // station's history) or checks it (same id: nothing changes; another id:
  // permanent error naming both: a database belongs to one station).
  Result<std::optional<std::string>> lab_station_id();
  Status lab_bind(std::string_view station_id);
  // Up to `limit` pending outbox rows with seq > after_seq, in seq order,
  // their payloads totalling at most about max_bytes (at least one row).
  Result<std::vector<OutboxRecord>> outbox_batch(int64_t after_seq, int limit,
                                                 int64_t max_bytes = 4 << 20);
  // Acknowledges (deletes) every pending row with seq <= up_to_seq; called
  // only after the lab database committed them.
  Status outbox_ack(int64_t up_to_seq);
  Result<OutboxStats> outbox_stats();

  // PRAGMA integrity_check (quick: PRAGMA quick_check, which skips the
  // index contents): its rows, exactly {"ok"} when the file is sound, one
  // problem per row otherwise. An error when the check could not run (the
  // file is too damaged to read, I/O error).
  Result<std::vector<std::string>> integrity_check(bool quick = false);
  // Ok when quick_check answers "ok"; else a permanent error naming the file
  // and its first problems (what OpenCheck::kQuick refuses).
  Status verify_quick();

  // Whether the path still names the file this connection opened (one
  // stat(), microseconds). A permanent error naming the path when the file
  // was deleted, or another was put in its place (renamed over it); such a
  // connection commits nothing any more. Ok for an in-memory or temporary
  // database.
  Status check_file() const;
  // The file's identity when the connection opened it; nullopt without a
  // file (":memory:", "").
  std::optional<FileIdentity> file_identity() const;
  // Once check_file() failed: moves what the write-ahead log holds into the
  // file this connection has open (which nobody reads any more) and empties
  // the log, so the `-wal` beside the path is not replayed into the file
  // now there (or a new one) when it is next opened. Does not wait for other
  // connections: busy, it can be tried again later.
  Status release_wal();

  // Direct SQL for statements the API above does not cover (tests, tools).
  // Result rows are discarded: a check that answers in rows (integrity_check,
  // foreign_key_check, wal_checkpoint) needs its own reader.
  Status exec(std::string_view sql);
  sqlite3* handle() { return db_; }
  const std::string& path() const { return path_; }
  // Now, from the wall clock the connection was opened with, as ISO-8601
  // UTC: what it stamps rows with (and what callers stamp records with).
  std::string utc_now() const;

 private:
  Database(sqlite3* db, std::string path, const WallClock& wall);
  // `utc` itself when it is set, else utc_now().
  std::string utc_or_now(const std::string& utc) const { return utc.empty() ? utc_now() : utc; }

  sqlite3* db_ = nullptr;  // owned
  std::string path_;
  const WallClock* wall_;
  // The file's identity, for the commit hook (heap: stays put when moved);
  // nullptr without a file.
  std::unique_ptr<internal::FileGuard> guard_;
};

}  // namespace gyrotherm::storage

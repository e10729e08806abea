// Runs in the station database (database.h): a run's row with its
// metadata and crash-resume checkpoint, and its segments (one per step
// execution). Which rate series of a run a read or a result is about
// (StreamKey) is here too: the other stores name it.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gyrotherm/core/result.h"

struct sqlite3;

namespace gyrotherm::storage {

class Database;

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
  // An adaptive soak (schema v14): why its acquisition ended (the target
  // reached, out of reach with its floor, or the cap); empty otherwise.
  std::string acquire_stop;
};

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/runs.cpp.
class RunStore {
 public:
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

  // Stores the sequencer snapshot for crash resume.
  Status set_run_checkpoint(int64_t run_id, std::string_view resume_json, double wall_unix_s);

  // Segments: one per step execution.
  Result<int64_t> create_segment(const SegmentRecord& segment);  // id ignored
  Status update_segment(const SegmentRecord& segment);           // by id
  Result<std::vector<SegmentRecord>> segments(int64_t run_id);
  // How long the station's last soaks took to settle (t_settled_s −
  // t_start_s, station s), newest first, at most `limit`: every run's soaks
  // that settled without a pause or a suspension (held time cannot be told
  // apart from settling in the record).
  Result<std::vector<double>> recent_settles_s(int limit);

 private:
  friend class Database;
  RunStore() = default;
  ~RunStore() = default;
  RunStore(const RunStore&) = delete;
  RunStore& operator=(const RunStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (runs.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage

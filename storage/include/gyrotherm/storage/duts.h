// Devices under test in the station database (database.h; schema v8,
// docs/storage.md "Devices under test"): the station's registry of gyros
// by serial number, the DUTs of each run with their channels, a gyro's
// history, and the resolution of a StreamKey to one DUT and axis of a run.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/storage/results.h"
#include "gyrotherm/storage/runs.h"

struct sqlite3;

namespace gyrotherm::storage {

class Database;

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

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/duts.cpp.
class DutStore {
 public:
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

 private:
  friend class Database;
  DutStore() = default;
  ~DutStore() = default;
  DutStore(const DutStore&) = delete;
  DutStore& operator=(const DutStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (duts.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage

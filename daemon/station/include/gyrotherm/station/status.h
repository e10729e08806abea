// A snapshot of the station for the REST API and the CLI.
#pragma once

#include <cstdint>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/drivers/gyro_reader.h"
#include "gyrotherm/drivers/modbus_device.h"
#include "gyrotherm/drivers/rate_table.h"
#include "gyrotherm/lab/relay_status.h"
#include "gyrotherm/schedules/progress.h"
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm::station {

// What status() shows of the rate table.
struct TableStatus {
  bool connected = false;
  std::optional<drivers::TableState> state;  // the last good reading
  schedules::TableDemand demand;             // what the station wants now
  bool safing = false;                       // stopping; servo off once at rest
  drivers::DeviceHealth health;
};

// One device under test, live.
struct DutStatus {
  std::string serial;
  std::string model;
  std::string primary_axis;
  // Mean of the last full station second per rate axis, deg/h ("x", "y",
  // "z" as the DUT carries them); nullopt before the first full second.
  std::vector<std::pair<std::string, std::optional<double>>> rates_dph;
  std::optional<double> temp_c;  // the DUT's internal temperature, last frame
  double samples_per_s = 0;      // frames per station second
  bool required = true;          // [[dut]] required
  bool lost = false;             // not required, silent past its timeout: left out
  drivers::GyroReaderHealth health;
};

// Where the run and the queue are (docs/api.md "Progress"). A settling step
// has no fixed length: its fraction and the ETAs are then nullopt and the
// gate's progress is given instead.
struct Progress {
  std::optional<double> step_elapsed_s;  // station s in the current step
  std::optional<double> step_planned_s;  // its fixed length (ramps, acquisition, dwell)
  std::optional<double> step_fraction;   // 0..1; nullopt while settling
  std::string phase;                     // ramping, settling, acquiring, spinning_up, ...
  // Settling: how long the stability gate has held and how long it must.
  std::optional<double> gate_held_s;
  std::optional<double> gate_needed_s;
  double run_remaining_fixed_s = 0;  // the run's remaining fixed-length time, station s
  int run_settles_remaining = 0;     // settles ahead whose length is unknown
  // Station s to the run's end, with its band (schedules::RunProgress):
  // nullopt while a settle remains that neither the current soak's forecast
  // nor the chamber's past settles (the prior) can say.
  std::optional<double> run_eta_s;
  std::optional<double> run_eta_p10_s;
  std::optional<double> run_eta_p90_s;
  std::string run_eta_basis;  // fixed, forecast, prior, forecast+prior; "" without an ETA
  int prior_settles = 0;      // past settles behind the prior
  // While a soak settles: the forecast of its gate (schedules::SettleForecast).
  std::optional<schedules::SettleForecast> settle;
  // While an adaptive soak acquires: its gated axes' last judgement
  // (schedules::AcquireForecast).
  std::optional<schedules::AcquireForecast> acquire;
  double queue_fixed_s = 0;  // fixed-length time of the queued entries, station s
  int queue_settles = 0;
  // Their time with the settles from the prior; nullopt without one.
  std::optional<double> queue_eta_s, queue_eta_p10_s, queue_eta_p90_s;
};

struct StatusSnapshot {
  std::string station_name;
  std::string state = "idle";  // idle, or the current run's state
  std::optional<int64_t> run_id;
  std::string schedule_name;
  std::optional<int> step_index;  // 0-based
  int step_count = 0;
  std::string step_label;
  std::optional<double> setpoint_c;  // commanded
  std::optional<double> chamber_c;
  std::optional<double> top_c;
  std::optional<double> side_c;
  std::optional<double> gradient_c;           // top − side
  std::optional<double> temp_rate_c_per_min;  // shell, over the last minute
  std::optional<double> gyro_rate_dph;        // mean of the last full second (station)
  double gyro_samples_per_s = 0;              // station time
  double t_station_s = 0;
  double t_run_s = 0;
  double uptime_s = 0;  // wall
  double time_scale = 1;
  // Where station time comes from: "sim" (the simulator's shared clock,
  // time_scale its ceiling) or "scaled" (wall time x time_scale).
  std::string clock = "scaled";
  drivers::DeviceHealth chamber;
  drivers::DeviceHealth probes;
  drivers::GyroReaderHealth gyro;
  std::optional<TableStatus> table;  // nullopt: the station has no table
  std::vector<DutStatus> duts;       // every [[dut]], in config order
  Progress progress;
  // The current run's metadata (operator, comment, tags, DUT serials).
  std::string run_operator;
  std::string run_comment;
  std::vector<std::string> run_tags;
  storage::SampleWriterStats storage;
  std::string last_event;
  bool paused = false;
  struct Interlock {
    std::string kind;
    std::string message;
  };
  std::vector<Interlock> interlocks;  // tripped now
  int queue_length = 0;               // entries waiting
  bool queue_held = false;
  std::string queue_hold_reason;
  // [lab] (docs/lab.md): the relay's state; nullopt when the station has
  // no [lab]. Filled in by StationHooks::lab_status at each snapshot.
  std::optional<lab::RelayStatus> lab;
  // Free bytes on the file system of the station database (statvfs, for
  // the "disk filling" alert); nullopt when it cannot be read.
  std::optional<int64_t> storage_free_bytes;
  // The size of that file system (statvfs: total bytes); nullopt likewise.
  std::optional<int64_t> storage_size_bytes;
};

nlohmann::json to_json(const StatusSnapshot& s);
// The status's progress from the schedules' pure computation (progress.h).
Progress to_progress(const schedules::RunProgress& p);

}  // namespace gyrotherm::station

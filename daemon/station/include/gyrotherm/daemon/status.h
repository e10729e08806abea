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
#include "gyrotherm/schedules/schedule.h"
#include "gyrotherm/storage/sample_writer.h"

namespace gyrotherm::daemon {

// What status() shows of the rate table.
struct TableStatus {
  bool connected = false;
  std::optional<drivers::TableState> state;  // the last good reading
  schedules::TableDemand demand;             // what the station wants now
  bool safing = false;                       // stopping; servo off once at rest
  drivers::DeviceHealth health;
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
  drivers::DeviceHealth chamber;
  drivers::DeviceHealth probes;
  drivers::GyroReaderHealth gyro;
  std::optional<TableStatus> table;  // nullopt: the station has no table
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
};

nlohmann::json to_json(const StatusSnapshot& s);

}  // namespace gyrotherm::daemon

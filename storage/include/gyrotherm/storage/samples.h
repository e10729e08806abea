// A run's samples in the station database (database.h): the gyro's
// (chunked per channel, schema v9), the temperatures and the rate table's;
// reads over a time window, counts, and decimated reads for plots. The
// sample writer (sample_writer.h) writes them.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/core/samples.h"
#include "gyrotherm/storage/runs.h"

struct sqlite3;

namespace gyrotherm::storage {

class Database;

// Rollup blocks of the gyro rate (table gyro_rollup): block length of each
// level, station seconds. A sample at t_s is in block floor(t_s / length).
inline constexpr double kRollupBlockS[] = {0.1, 1.0, 10.0, 100.0, 1000.0};
inline constexpr int kRollupLevels = 5;

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

// Part of Database (database.h): call these on a Database. Defined in
// storage/src/samples.cpp.
class SampleStore {
 public:
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

  // Latest station time with a committed sample of the run (gyro,
  // temperature or table); nullopt when it has none.
  Result<std::optional<double>> last_sample_t_s(int64_t run_id);
  // Latest station time with a committed gyro sample of the run; nullopt
  // when it has none. What a crash resume credits acquisition up to: Table I
  // is made of gyro samples, and temperatures (one per control tick) can be
  // committed well past them when the gyro stream lags.
  Result<std::optional<double>> last_gyro_sample_t_s(int64_t run_id);

 private:
  friend class Database;
  SampleStore() = default;
  ~SampleStore() = default;
  SampleStore(const SampleStore&) = delete;
  SampleStore& operator=(const SampleStore&) = delete;
  // The Database this store is part of, its connection and its path
  // (samples.cpp).
  Database& self();
  sqlite3* db();
  const std::string& path();
};

}  // namespace gyrotherm::storage

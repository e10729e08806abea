// What the REST API asks of the station: queue, operator commands and run
// records (docs/api.md). The Station implements it; API tests use a fake.
//
// Replies carry JSON bodies ready to send, or a Refusal saying why nothing
// was done; the API maps refusals to HTTP statuses (400, 404, 409, 422, 503).
#pragma once

#include <cstddef>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::station {

struct Refusal {
  enum class Kind {
    kNotFound,     // no such queue entry or run
    kConflict,     // does not apply now (pause with no run, remove the running entry)
    kInvalid,      // bad input: a refused schedule, a bad position
    kUnavailable,  // the database failed
    kBadRequest,   // names something this station does not have (an unknown DUT serial)
  };
  Kind kind = Kind::kInvalid;
  std::string message;
  std::vector<std::string> details;  // e.g. every error of a refused schedule
};

struct Reply {
  std::optional<Refusal> refusal;
  nlohmann::json body;

  static Reply ok(nlohmann::json body) { return Reply{std::nullopt, std::move(body)}; }
  static Reply refused(Refusal::Kind kind, std::string message,
                       std::vector<std::string> details = {}) {
    return Reply{Refusal{kind, std::move(message), std::move(details)}, nullptr};
  }
};

// GET /runs/{id}/samples parameters (station seconds since run start).
struct SamplesQuery {
  double from_s = 0;
  std::optional<double> to_s;  // nullopt: the last sample
  int max_points = 2000;
  std::string dut;      // serial; "" = the run's first DUT
  std::string channel;  // e.g. gyro_x, temp_c; "" = the DUT's primary rate axis
};

// Run metadata limits (POST /queue, PATCH /runs/{id}); the API refuses
// longer values with 400 naming the field. Lengths in characters (UTF-8
// code points).
inline constexpr std::size_t kMaxOperatorChars = 128;
inline constexpr std::size_t kMaxCommentChars = 4096;
inline constexpr std::size_t kMaxTags = 32;
inline constexpr std::size_t kMaxTagChars = 64;
inline constexpr std::size_t kMaxDutSerials =
    16;  // in a request ([[dut]] allows 8; recorded ones may be more)
inline constexpr std::size_t kMaxSerialChars = 64;

// POST /queue: a schedule and the metadata its run will carry. The API has
// checked types and lengths; the station checks the DUT serials against its
// [[dut]] entries (kBadRequest naming an unknown one).
struct QueueRequest {
  std::string toml_text;
  std::string source;
  bool ignore_failures = false;
  storage::RunMetadata metadata;  // dut_serials empty: every configured DUT
};

// PATCH /runs/{id}: the fields given replace the run's; the others stay.
struct MetadataEdit {
  std::optional<std::string> operator_name;
  std::optional<std::string> comment;
  std::optional<std::vector<std::string>> tags;
  std::optional<std::vector<std::string>> dut_serials;
};

// GET /runs/{id}/stats filters; "" = every DUT / every axis.
struct StatsQuery {
  std::string dut;
  std::string axis;
};

class StationControl {
 public:
  virtual ~StationControl() = default;
  virtual Reply queue_list() = 0;
  virtual Reply queue_add(const std::string& toml_text, const std::string& source,
                          bool ignore_failures) = 0;
  virtual Reply queue_remove(int64_t id) = 0;
  virtual Reply queue_move(int64_t id, int position) = 0;
  // action: pause, resume, abort, stop, table-reset (the rate table's
  // latched fault).
  virtual Reply control(std::string_view action, const std::string& reason) = 0;
  virtual Reply runs() = 0;
  virtual Reply run(int64_t id) = 0;
  virtual Reply run_events(int64_t id) = 0;
  virtual Reply run_stats(int64_t id) = 0;
  // Decimated samples (storage::Database::decimated_samples).
  virtual Reply run_samples(int64_t id, const SamplesQuery& query) = 0;
  virtual Reply run_fits(int64_t id) = 0;
  virtual Reply run_allan(int64_t id) = 0;  // Allan deviation per soak
  // Scale factor: {"points", "fits", "temperature_fit"} (empty / null when
  // the run has no rate points or was not analysed yet).
  virtual Reply run_scale_factor(int64_t id) = 0;
  virtual Reply fit(int64_t id) = 0;
  // Calibration exports (nightly and manual), newest first.
  virtual Reply exports() = 0;

  // Run metadata and DUTs (schema v8).
  // POST /queue with the run's metadata (queue_add is the same without).
  virtual Reply enqueue(const QueueRequest& request) = 0;
  // GET /runs/{id}: the run with its metadata, segments and DUTs
  // (run_detail_json).
  virtual Reply run_with_duts(int64_t id) = 0;
  // PATCH /runs/{id}: replaces the given fields and records an event of
  // kind "metadata" naming `changed_by`; answers as run_with_duts.
  virtual Reply edit_run(int64_t id, const MetadataEdit& edit, const std::string& changed_by) = 0;
  // GET /runs/{id}/stats with filters; rows name their DUT and axis (""
  // stored = the run's first DUT, its primary axis, answered resolved).
  virtual Reply run_stats_filtered(int64_t id, const StatsQuery& query) = 0;
  // GET /runs/{id}/samples of a DUT's channel (kNotFound naming an unknown
  // serial or channel).
  virtual Reply run_channel_samples(int64_t id, const SamplesQuery& query) = 0;
  // GET /duts, GET /duts/{serial} (duts_json, dut_history_json).
  virtual Reply duts() = 0;
  virtual Reply dut_history(const std::string& serial) = 0;
};

// JSON forms of the stored records (docs/api.md).
nlohmann::json to_json(const storage::QueueEntry& e, int step_count);
nlohmann::json to_json(const storage::RunRecord& r);
nlohmann::json to_json(const storage::SegmentRecord& s);
nlohmann::json to_json(const storage::EventRecord& e);
nlohmann::json to_json(const storage::SegmentStatsRecord& s);
nlohmann::json to_json(const storage::FitRecord& f);
nlohmann::json to_json(const storage::AllanRecord& a);
nlohmann::json to_json(const storage::ScaleFactorPointRecord& p);
nlohmann::json to_json(const storage::ScaleFactorFitRecord& f);
nlohmann::json to_json(const storage::ScaleFactorTemperatureFitRecord& t);
nlohmann::json to_json(const storage::DecimatedSamples& d);
nlohmann::json to_json(const storage::ExportRecord& e);
// Schema v8: {"operator", "comment", "tags", "duts"}.
nlohmann::json to_json(const storage::RunMetadata& m);
// A DUT in a run: {"serial", "model", "position", "primary_axis", "axes",
// "rate_hz", "channels": [{"name", "unit", "kind", "axis"}]}.
nlohmann::json to_json(const storage::RunDutRecord& d);
// GET /duts item: {"serial", "model", "first_seen_utc", "runs": n}.
nlohmann::json to_json(const storage::DutRecord& d, int64_t run_count);
// GET /duts/{serial}: the DUT, its runs (each with metadata, the DUT's
// place in it, segments, Table I, Allan and scale-factor rows of every
// axis) and its drift fits.
nlohmann::json to_json(const storage::DutHistory& h);

// The answers built from a database, shared by the station's routes and the
// CLI's --db (so offline output equals the daemon's). Errors: the
// database's (a permanent one for an unknown run or DUT, named).
Result<nlohmann::json> run_detail_json(storage::Database& db, int64_t run_id);
Result<nlohmann::json> duts_json(storage::Database& db);
Result<nlohmann::json> dut_history_json(storage::Database& db, const std::string& serial);

}  // namespace gyrotherm::station

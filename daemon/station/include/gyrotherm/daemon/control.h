// What the REST API asks of the station: queue, operator commands and run
// records (docs/api.md). The Station implements it; API tests use a fake.
//
// Replies carry JSON bodies ready to send, or a Refusal saying why nothing
// was done; the API maps refusals to HTTP statuses (404, 409, 422, 503).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/storage/database.h"

namespace gyrotherm::daemon {

struct Refusal {
  enum class Kind {
    kNotFound,     // no such queue entry or run
    kConflict,     // does not apply now (pause with no run, remove the running entry)
    kInvalid,      // bad input: a refused schedule, a bad position
    kUnavailable,  // the database failed
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
};

class StationControl {
 public:
  virtual ~StationControl() = default;
  virtual Reply queue_list() = 0;
  virtual Reply queue_add(const std::string& toml_text, const std::string& source,
                          bool ignore_failures) = 0;
  virtual Reply queue_remove(int64_t id) = 0;
  virtual Reply queue_move(int64_t id, int position) = 0;
  // action: pause, resume, abort, stop.
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

}  // namespace gyrotherm::daemon

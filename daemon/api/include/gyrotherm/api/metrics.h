// The daemon's Prometheus metrics (GET /metrics, text format 0.0.4), kept
// with prometheus-cpp's registry and serializer.
//
// Latencies are histograms observed as they happen (each Modbus request,
// each database commit; thread-safe, no allocation). Counters and gauges are
// read from the station's status at scrape time, so there is one source of
// truth for them: the figures /api/v1/status shows. docs/api.md lists them.
#pragma once

#include <memory>
#include <string>
#include <string_view>

#include "gyrotherm/station/status.h"

namespace prometheus {
class Histogram;
class Registry;
}  // namespace prometheus

namespace gyrotherm::api {

// Figures of the HTTP side, read at scrape time.
struct ServerFigures {
  uint64_t http_requests = 0;
  uint64_t http_refused_connections = 0;
  uint64_t http_bad_requests = 0;
  int http_connections = 0;
  int stream_clients = 0;
  uint64_t stream_clients_dropped = 0;
};

class Metrics {
 public:
  Metrics();
  ~Metrics();

  // device: "chamber" or "probes". Thread-safe.
  void observe_modbus(std::string_view device, double seconds);
  void observe_commit(double seconds);

  std::string scrape(const station::StatusSnapshot& status, const ServerFigures& server) const;

 private:
  std::shared_ptr<prometheus::Registry> registry_;
  prometheus::Histogram* modbus_chamber_s_;
  prometheus::Histogram* modbus_probes_s_;
  prometheus::Histogram* commit_s_;
};

// Every state a gyrotherm_state gauge is reported for.
inline constexpr std::string_view kStatesForMetrics[] = {
    "idle",      "queued",   "ramping",   "settling", "acquiring",  "paused",
    "suspended", "aborting", "completed", "failed",   "interrupted"};

// Every state a gyrotherm_lab_relay_state gauge is reported for (lab::RelayStatus::state).
inline constexpr std::string_view kLabRelayStates[] = {"disabled", "connecting", "connected",
                                                       "backoff",  "refused",    "stopped"};

}  // namespace gyrotherm::api

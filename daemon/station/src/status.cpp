#include "gyrotherm/daemon/status.h"

#include <nlohmann/json.hpp>

namespace gyrotherm::daemon {
namespace {

template <class T>
nlohmann::json opt(const std::optional<T>& v) {
  return v ? nlohmann::json(*v) : nlohmann::json(nullptr);
}

nlohmann::json to_json(const drivers::DeviceHealth& h) {
  return {{"connected", h.connected},
          {"last_success_utc", h.last_success_utc},
          {"requests", h.requests},
          {"errors", h.errors},
          {"reconnects", h.reconnects},
          {"last_error", h.last_error},
          {"last_latency_ms", h.last_latency_ms}};
}

// null when the station has no table.
nlohmann::json table_json(const std::optional<TableStatus>& t) {
  if (!t) return nullptr;
  nlohmann::json j = {
      {"connected", t->connected},
      {"demand",
       {{"mode", schedules::to_string(t->demand.mode)},
        {"rate_dps", t->demand.rate_dps},
        {"position_deg", opt(t->demand.position_deg)}}},
      {"safing", t->safing},
      {"mode", nullptr},
      {"interlock", nullptr},
      {"rate_dps", nullptr},
      {"position_deg", nullptr},
      {"fault", ""},
  };
  if (t->state) {
    j["mode"] = drivers::to_string(t->state->mode);
    j["interlock"] = drivers::to_string(t->state->interlock);
    j["rate_dps"] = t->state->rate_dps;
    j["position_deg"] = t->state->position_deg;
    j["fault"] = t->state->fault;
  }
  return j;
}

}  // namespace

nlohmann::json to_json(const StatusSnapshot& s) {
  const auto& g = s.gyro;
  nlohmann::json interlocks = nlohmann::json::array();
  for (const auto& i : s.interlocks)
    interlocks.push_back({{"kind", i.kind}, {"message", i.message}});
  return {
      {"station", s.station_name},
      {"state", s.state},
      {"run_id", opt(s.run_id)},
      {"schedule", s.schedule_name},
      {"step", {{"index", opt(s.step_index)}, {"count", s.step_count}, {"label", s.step_label}}},
      {"setpoint_c", opt(s.setpoint_c)},
      {"chamber_c", opt(s.chamber_c)},
      {"top_c", opt(s.top_c)},
      {"side_c", opt(s.side_c)},
      {"gradient_c", opt(s.gradient_c)},
      {"temp_rate_c_per_min", opt(s.temp_rate_c_per_min)},
      {"gyro_rate_dph", opt(s.gyro_rate_dph)},
      {"gyro_samples_per_s", s.gyro_samples_per_s},
      {"t_station_s", s.t_station_s},
      {"t_run_s", s.t_run_s},
      {"uptime_s", s.uptime_s},
      {"time_scale", s.time_scale},
      {"last_event", s.last_event},
      {"paused", s.paused},
      {"interlocks", interlocks},
      {"queue_length", s.queue_length},
      {"queue_held", s.queue_held},
      {"queue_hold_reason", s.queue_hold_reason},
      {"table", table_json(s.table)},
      {"devices",
       {{"chamber", to_json(s.chamber)},
        {"probes", to_json(s.probes)},
        {"gyro",
         {{"connected", g.connected},
          {"samples", g.samples},
          {"frames_ok", g.parser.frames_ok},
          {"crc_failures", g.parser.crc_failures},
          {"bytes_skipped", g.parser.bytes_skipped},
          {"sequence_gaps", g.parser.sequence_gaps},
          {"frames_missed", g.parser.frames_missed},
          {"invalid_samples", g.invalid_samples},
          {"reopens", g.reopens},
          {"read_errors", g.read_errors},
          {"last_error", g.last_error}}},
        {"table", s.table ? to_json(s.table->health) : nlohmann::json(nullptr)}}},
      {"storage",
       {{"gyro_rows", s.storage.gyro_rows},
        {"temperature_rows", s.storage.temperature_rows},
        {"table_rows", s.storage.table_rows},
        {"commits", s.storage.commits},
        {"commit_failures", s.storage.commit_failures},
        {"consecutive_failures", s.storage.consecutive_failures},
        {"dropped", s.storage.dropped},
        {"pending", s.storage.pending},
        {"last_commit_ms", s.storage.last_commit_ms},
        {"max_commit_ms", s.storage.max_commit_ms},
        {"last_error", s.storage.last_error}}},
  };
}

}  // namespace gyrotherm::daemon

#include "gyrotherm/station/status.h"

#include <nlohmann/json.hpp>

namespace gyrotherm::station {
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

// A gyro reader's health: today's "gyro" device object, and each DUT's "health".
nlohmann::json to_json(const drivers::GyroReaderHealth& g) {
  return {{"connected", g.connected},
          {"samples", g.samples},
          {"frames_ok", g.parser.frames_ok},
          {"crc_failures", g.parser.crc_failures},
          {"bytes_skipped", g.parser.bytes_skipped},
          {"sequence_gaps", g.parser.sequence_gaps},
          {"frames_missed", g.parser.frames_missed},
          {"invalid_samples", g.invalid_samples},
          {"reopens", g.reopens},
          {"read_errors", g.read_errors},
          {"last_error", g.last_error}};
}

nlohmann::json to_json(const DutStatus& d) {
  nlohmann::json rates = nlohmann::json::object();
  for (const auto& [axis, rate] : d.rates_dph) rates[axis] = opt(rate);
  return {{"serial", d.serial},     {"model", d.model},        {"primary_axis", d.primary_axis},
          {"rates_dph", rates},     {"temp_c", opt(d.temp_c)}, {"samples_per_s", d.samples_per_s},
          {"required", d.required}, {"lost", d.lost},          {"health", to_json(d.health)}};
}

// null unless a soak settles and has been forecast.
nlohmann::json settle_json(const std::optional<schedules::SettleForecast>& f) {
  if (!f) return nullptr;
  return {{"verdict", f->verdict},  {"note", f->note},        {"p10_s", opt(f->p10_s)},
          {"p50_s", opt(f->p50_s)}, {"p90_s", opt(f->p90_s)}, {"age_s", f->age_s}};
}

// [[t_s, u95_dph], ...]
nlohmann::json projection_json(const std::vector<schedules::AcquireAxis::Point>& points) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& p : points) out.push_back({p.t_s, p.u95_dph});
  return out;
}

// null unless an adaptive soak acquires and its axes have been judged.
nlohmann::json acquire_json(const std::optional<schedules::AcquireForecast>& f) {
  if (!f) return nullptr;
  nlohmann::json axes = nlohmann::json::array();
  for (const auto& a : f->axes) {
    axes.push_back({{"name", a.name},
                    {"verdict", a.verdict},
                    {"u95_dph", opt(a.u95_dph)},
                    {"reach_s", opt(a.reach_s)},
                    {"floor_dph", opt(a.floor_dph)},
                    {"model", a.model ? nlohmann::json{{"q_n", a.model->q_n},
                                                       {"q_b", a.model->q_b},
                                                       {"q_k", a.model->q_k},
                                                       {"q_g", a.model->q_g},
                                                       {"gm_tc_s", a.model->gm_tc_s},
                                                       {"k", a.model->k}}
                                      : nlohmann::json(nullptr)},
                    {"projection", projection_json(a.projection)},
                    {"note", a.note}});
  }
  return {{"target_u95_dph", f->target_u95_dph},
          {"min_s", f->min_s},
          {"max_s", f->max_s},
          {"acquired_s", f->acquired_s},
          {"planned_s", opt(f->planned_s)},
          {"axes", axes},
          {"age_s", f->age_s}};
}

nlohmann::json to_json(const Progress& p) {
  return {{"phase", p.phase},
          {"step_elapsed_s", opt(p.step_elapsed_s)},
          {"step_planned_s", opt(p.step_planned_s)},
          {"step_fraction", opt(p.step_fraction)},
          {"gate_held_s", opt(p.gate_held_s)},
          {"gate_needed_s", opt(p.gate_needed_s)},
          {"run_remaining_fixed_s", p.run_remaining_fixed_s},
          {"run_settles_remaining", p.run_settles_remaining},
          {"run_eta_s", opt(p.run_eta_s)},
          {"run_eta_p10_s", opt(p.run_eta_p10_s)},
          {"run_eta_p90_s", opt(p.run_eta_p90_s)},
          {"run_eta_basis",
           p.run_eta_basis.empty() ? nlohmann::json(nullptr) : nlohmann::json(p.run_eta_basis)},
          {"prior_settles", p.prior_settles},
          {"settle", settle_json(p.settle)},
          {"acquire", acquire_json(p.acquire)},
          {"queue_fixed_s", p.queue_fixed_s},
          {"queue_settles", p.queue_settles},
          {"queue_eta_s", opt(p.queue_eta_s)},
          {"queue_eta_p10_s", opt(p.queue_eta_p10_s)},
          {"queue_eta_p90_s", opt(p.queue_eta_p90_s)}};
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

// null when the station has no [lab]; the relay's state otherwise.
nlohmann::json lab_json(const std::optional<lab::RelayStatus>& l) {
  if (!l) return nullptr;
  return {{"station_id", l->station_id},
          {"server", l->server},
          {"state", l->state},
          {"pending", l->pending},
          {"pending_bytes", l->pending_bytes},
          {"oldest_pending_age_s", opt(l->oldest_pending_age_s)},
          {"sent_total", l->sent_total},
          {"batches_total", l->batches_total},
          {"redelivered_total", l->redelivered_total},
          {"errors_total", l->errors_total},
          {"last_lag_s", opt(l->last_lag_s)},
          {"max_lag_s", opt(l->max_lag_s)},
          {"last_error", l->last_error},
          {"retry_in_s", opt(l->retry_in_s)},
          {"last_sent_utc", l->last_sent_utc}};
}

}  // namespace

nlohmann::json to_json(const StatusSnapshot& s) {
  nlohmann::json interlocks = nlohmann::json::array();
  for (const auto& i : s.interlocks)
    interlocks.push_back({{"kind", i.kind}, {"message", i.message}});
  nlohmann::json duts = nlohmann::json::array();
  for (const auto& d : s.duts) duts.push_back(to_json(d));
  nlohmann::json j = {
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
      {"clock", s.clock},
      {"last_event", s.last_event},
      {"paused", s.paused},
      {"interlocks", interlocks},
      {"queue_length", s.queue_length},
      {"queue_held", s.queue_held},
      {"queue_hold_reason", s.queue_hold_reason},
      {"table", table_json(s.table)},
      {"duts", duts},
      {"progress", to_json(s.progress)},
      {"devices",
       {{"chamber", to_json(s.chamber)},
        {"probes", to_json(s.probes)},
        {"gyro", to_json(s.gyro)},
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
        {"last_error", s.storage.last_error},
        {"free_bytes", opt(s.storage_free_bytes)},
        {"size_bytes", opt(s.storage_size_bytes)}}},
      {"lab", lab_json(s.lab)},
  };
  // While a run runs: who runs it and why (set with `queue add`).
  if (s.run_id) {
    j["run_metadata"] = {
        {"operator", s.run_operator}, {"comment", s.run_comment}, {"tags", s.run_tags}};
  }
  return j;
}

Progress to_progress(const schedules::RunProgress& p) {
  Progress out;
  out.phase = p.phase;
  out.step_elapsed_s = p.step_elapsed_s;
  out.step_planned_s = p.step_planned_s;
  out.step_fraction = p.step_fraction;
  out.gate_held_s = p.gate_held_s;
  out.gate_needed_s = p.gate_needed_s;
  out.run_remaining_fixed_s = p.run_remaining_fixed_s;
  out.run_settles_remaining = p.run_settles_remaining;
  out.run_eta_s = p.run_eta_s;
  out.run_eta_p10_s = p.run_eta_p10_s;
  out.run_eta_p90_s = p.run_eta_p90_s;
  out.settle = p.settle;
  out.acquire = p.acquire;
  out.run_eta_basis = p.run_eta_basis;
  out.prior_settles = p.prior_settles;
  out.queue_eta_s = p.queue_eta_s;
  out.queue_eta_p10_s = p.queue_eta_p10_s;
  out.queue_eta_p90_s = p.queue_eta_p90_s;
  out.queue_fixed_s = p.queue_fixed_s;
  out.queue_settles = p.queue_settles;
  return out;
}

}  // namespace gyrotherm::station

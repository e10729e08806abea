// A small lab of two stations for the read tests (lab_read_test.cpp) and
// the CLI's (tests/integration/lab_cli_test.cpp): outbox records built as
// the stations' SQLite triggers write them (docs/lab.md "Outbox": a JSON
// object of every column of the row, `*_json` columns embedded as JSON;
// keys and kinds of docs/lab.md), pushed with push_batch as each
// station's own role.
//
// Station "lab-a" (role lab_a_relay):
//   run 1 (kUuidA1) paper-table1, completed 2026-11-20, DUTs 17-0042 and TS-7,
//     a comment with "<script>"; Table I of 17-0042 z at 20 °C (1.2031 °/h)
//     and 40 °C (1.4562 °/h), an Allan row, a drift fit, a scale factor fit
//     and its temperature fit, two run events; a station event outside runs.
//   run 2 (kUuidA2) rate-sweep, running since 2026-11-22, DUT TS-7.
// Station "lab-b" (role lab_b_relay): the gyro 17-0042 moved there;
//   run 1 (kUuidB1, the same local id as lab-a's first) paper-table1,
//   completed 2026-11-25, Table I at -10 °C (0.9876 °/h) and 20 °C (1.2105).
#pragma once

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"
#include "gyrotherm/storage/database.h"

namespace gyrotherm::testing {

inline constexpr const char* kUuidA1 = "6f1c2a4e-8b7d-4c1e-9a3f-0d2b5e7c9a11";
inline constexpr const char* kUuidA2 = "0a9b8c7d-6e5f-4a3b-8c1d-2e3f4a5b6c22";
inline constexpr const char* kUuidB1 = "c3d4e5f6-a7b8-4c9d-8e0f-1a2b3c4d5e33";
// Lab-b's second soak was adaptive (docs/schedules.md, "Adaptive soaks").
inline constexpr const char* kAdaptiveStopB =
    "target reached: U95 <= 0.05 °/h on every gated axis (1 of them) after 31 min (widest: "
    "17-0042 z, U95 0.0481 °/h)";
inline constexpr const char* kComment = "<script>alert('x')</script> & after the re-splice";

// The outbox of one station, in seq order.
class StationOutbox {
 public:
  // Records numbered after `after_seq` (a later batch of the same station).
  explicit StationOutbox(int64_t after_seq = 0) : seq_(after_seq) {}

  std::vector<storage::OutboxRecord> records;

  void add(const std::string& kind, const std::string& run_uuid, const std::string& local_id,
           const nlohmann::json& payload) {
    storage::OutboxRecord r;
    r.seq = ++seq_;
    r.kind = kind;
    r.run_uuid = run_uuid;
    r.local_id = local_id;
    r.payload_json = payload.dump();
    r.committed_unix_s = 1795000000.0 + static_cast<double>(seq_);
    records.push_back(std::move(r));
  }

  // A deletion: the row's key, payload {}.
  void tombstone(const std::string& kind, const std::string& run_uuid,
                 const std::string& local_id) {
    add(kind, run_uuid, local_id, nlohmann::json::object());
    records.back().deleted = true;
  }

  // A runs row (every column but resume_json, checkpoint_wall_unix_s,
  // config_toml).
  void run(int64_t id, const std::string& uuid, const std::string& schedule,
           const std::string& state, const std::string& started, const nlohmann::json& ended,
           const std::string& operator_name, const std::string& comment, const nlohmann::json& tags,
           const nlohmann::json& serials) {
    add("run", uuid, std::to_string(id),
        {{"id", id},
         {"schedule_name", schedule},
         {"state", state},
         {"started_utc", started},
         {"ended_utc", ended},
         {"time_scale", 1.0},
         {"latitude_deg", 48.1},
         {"orientation", "up"},
         {"config_json",
          nlohmann::json::object({{"station", nlohmann::json::object({{"name", "bench"}})}})},
         {"queue_id", id},
         {"schedule_id", id},
         {"operator", operator_name},
         {"comment", comment},
         {"tags_json", tags},
         {"dut_serials_json", serials},
         {"uuid", uuid}});
  }
  void dut(int64_t id, const std::string& serial, const std::string& model) {
    add("dut", std::string(storage::kNilUuid), std::to_string(id),
        {{"id", id},
         {"serial", serial},
         {"model", model},
         {"first_seen_utc", "2026-11-01T08:00:00.000Z"}});
  }
  void run_dut(int64_t run_id, const std::string& uuid, int64_t dut_id, int64_t position,
               const std::string& primary_axis) {
    add("run_dut", uuid, std::to_string(run_id) + "/" + std::to_string(dut_id),
        {{"run_id", run_id},
         {"dut_id", dut_id},
         {"position", position},
         {"primary_axis", primary_axis},
         {"axes_json", nlohmann::json::array({"x", "y", "z"})},
         {"rate_hz", 1000.0},
         {"seq_modulo", 128},
         {"config_json", nlohmann::json::object({{"serial", "configured"}})}});
  }
  void segment(int64_t id, int64_t run_id, const std::string& uuid, int64_t idx,
               const std::string& kind, double setpoint_c, const std::string& acquire_stop = "") {
    add("segment", uuid, std::to_string(id),
        {{"id", id},
         {"run_id", run_id},
         {"idx", idx},
         {"kind", kind},
         {"label", kind + " " + std::to_string(static_cast<int>(setpoint_c)) + " °C"},
         {"setpoint_c", setpoint_c},
         {"ramp_rate_c_per_min", kind == "ramp" ? nlohmann::json(1.0) : nlohmann::json()},
         {"t_start_s", 3600.0 * static_cast<double>(idx)},
         {"t_settled_s", nullptr},
         {"t_acquire_start_s", nullptr},
         {"t_acquire_end_s", nullptr},
         {"t_end_s", 3600.0 * static_cast<double>(idx + 1)},
         {"paused_s", 0.0},
         {"state", "completed"},
         {"table_mode", "none"},
         {"table_rate_dps", nullptr},
         {"table_position_deg", nullptr},
         {"table_mean_rate_dps", nullptr},
         {"table_mean_position_deg", nullptr},
         {"turns", 0},
         {"dwell_s", 0.0},
         {"sf_sequence", 0},
         {"sf_repetition", 0},
         {"acquire_stop", acquire_stop}});
  }
  void table1(int64_t segment_id, int64_t run_id, const std::string& uuid,
              const std::string& serial, const std::string& axis, int64_t segment_index,
              double setpoint_c, double bias_dph, double std_dph) {
    add("table1", uuid, std::to_string(segment_id) + "/" + serial + "/" + axis,
        {{"segment_id", segment_id},
         {"run_id", run_id},
         {"dut_serial", serial},
         {"axis", axis},
         {"segment_index", segment_index},
         {"setpoint_c", setpoint_c},
         {"n", 3600},
         {"duration_s", 3600.0},
         {"temp_mean_c", setpoint_c + 0.02},
         {"bias_mean_dph", bias_dph},
         {"bias_std_dph", std_dph},
         {"bias_std_ma_dph", std_dph / 3},
         {"bias_mean_earth_removed_dph", bias_dph - 9.7031},
         {"bin_s", 1.0},
         {"ma_window", 101},
         {"earth_rate_dph", 9.7031},
         {"t_from_s", 600.0},
         {"t_to_s", 4200.0},
         {"computed_utc", "2026-11-20T12:00:00.000Z"}});
  }
  void event(int64_t id, const nlohmann::json& run_id, const std::string& uuid, double t_s,
             const std::string& kind, const std::string& from, const std::string& to,
             const std::string& message) {
    add("event", uuid, std::to_string(id),
        {{"id", id},
         {"run_id", run_id},
         {"t_s", t_s},
         {"wall_utc", "2026-11-20T05:00:00.000Z"},
         {"kind", kind},
         {"from_state", from.empty() ? nlohmann::json() : nlohmann::json(from)},
         {"to_state", to.empty() ? nlohmann::json() : nlohmann::json(to)},
         {"message", message}});
  }

 private:
  int64_t seq_ = 0;
};

inline StationOutbox station_a_outbox() {
  using nlohmann::json;
  const std::string nil(storage::kNilUuid);
  StationOutbox o;
  o.dut(1, "17-0042", "KVH 1750");
  o.dut(2, "TS-7", "rate test set");
  o.event(1, nullptr, nil, 0, "info", "", "", "station started");
  o.run(1, kUuidA1, "paper-table1", "completed", "2026-11-20T05:00:00.000Z",
        "2026-11-20T11:00:00.000Z", "Ana Müller", kComment, json::array({"campaign-7", "week-1"}),
        json::array({"17-0042", "TS-7"}));
  o.run_dut(1, kUuidA1, 1, 0, "z");
  o.run_dut(1, kUuidA1, 2, 1, "x");
  o.segment(1, 1, kUuidA1, 0, "soak", 20);
  o.segment(2, 1, kUuidA1, 1, "ramp", 40);
  o.segment(3, 1, kUuidA1, 2, "soak", 40);
  o.table1(1, 1, kUuidA1, "17-0042", "z", 0, 20, 1.2031, 0.0117);
  o.table1(3, 1, kUuidA1, "17-0042", "z", 2, 40, 1.4562, 0.0131);
  o.table1(1, 1, kUuidA1, "TS-7", "x", 0, 20, -3.25, 0.5);
  o.add(
      "allan", kUuidA1, "1",
      {{"id", 1},
       {"run_id", 1},
       {"segment_id", 1},
       {"segment_index", 0},
       {"t_from_s", 600.0},
       {"t_to_s", 4200.0},
       {"taus", "octave"},
       {"tau0_s", 0.001},
       {"n_samples", 3600000},
       {"curve_json", {{"tau_s", json::array({1.0, 2.0})}, {"adev_dph", json::array({0.1, 0.07})}}},
       {"angle_random_walk_dprh", 0.00123},
       {"bias_instability_dph", 0.0456},
       {"bias_instability_tau_s", 120.0},
       {"rate_random_walk_dphprh", nullptr},
       {"bias_instability_method", "minimum / 0.664"},
       {"inputs_json", json::object({{"bin_s", 0.001}})},
       {"computed_utc", "2026-11-20T12:00:00.000Z"},
       {"dut_serial", "17-0042"},
       {"axis", "z"}});
  o.add("fit", nil, "1",
        {{"id", 1},
         {"model", "T1+R1"},
         {"form", "centered"},
         {"n", 7200},
         {"coefficients_json", {{"T1", 0.0123}, {"R1", -0.5}}},
         {"standard_errors_json", {{"T1", 0.0004}, {"R1", 0.02}}},
         {"residual_std_dph", 0.0089},
         {"r_squared", 0.987},
         {"inputs_json", json::object({{"bin_s", 1.0}})},
         {"computed_utc", "2026-11-20T12:30:00.000Z"},
         {"dut_serial", "17-0042"},
         {"axis", "z"}});
  o.add("fit_run", kUuidA1, "1/1", {{"run_id", 1}, {"fit_id", 1}});
  o.add("sf_fit", kUuidA1, "1/1/17-0042/z",
        {{"run_id", 1},
         {"sf_sequence", 1},
         {"dut_serial", "17-0042"},
         {"axis", "z"},
         {"temperature_c", 20.1},
         {"k", 1.00015},
         {"k_se", 2e-6},
         {"bias_dps", 0.0021},
         {"nonlinearity_ppm", 41.0},
         {"nonlinearity_fs_ppm", 12.0},
         {"asymmetry_ppm", 30.2},
         {"repeatability_ppm", nullptr},
         {"n_points", 12},
         {"created_utc", "2026-11-20T12:00:00.000Z"}});
  o.add("sf_temperature_fit", kUuidA1, "1/17-0042/z",
        {{"run_id", 1},
         {"dut_serial", "17-0042"},
         {"axis", "z"},
         {"poly_order", 1},
         {"t_centre_c", 30.0},
         {"k_coeffs_json", json::array({1.00015, 1.5e-6})},
         {"bias_coeffs_json", json::array({0.0021, 1e-5})},
         {"k_ppm_per_c", 1.4998},
         {"bias_dph_per_c", 0.036},
         {"created_utc", "2026-11-20T12:00:00.000Z"}});
  o.event(2, 1, kUuidA1, 0, "state", "queued", "ramping", "run started");
  o.event(3, 1, kUuidA1, 21600, "state", "acquiring", "completed", "run completed");

  o.run(2, kUuidA2, "rate-sweep", "acquiring", "2026-11-22T09:30:00.000Z", nullptr, "Bo Lind", "",
        json::array(), json::array({"TS-7"}));
  o.run_dut(2, kUuidA2, 2, 0, "x");
  o.segment(4, 2, kUuidA2, 0, "soak", 25);
  return o;
}

inline StationOutbox station_b_outbox() {
  using nlohmann::json;
  StationOutbox o;
  o.dut(1, "17-0042", "KVH 1750");
  o.run(1, kUuidB1, "paper-table1", "completed", "2026-11-25T06:00:00.000Z",
        "2026-11-25T12:00:00.000Z", "Cy Ode", "moved from lab-a", json::array({"campaign-7"}),
        json::array({"17-0042"}));
  o.run_dut(1, kUuidB1, 1, 0, "z");
  o.segment(1, 1, kUuidB1, 0, "soak", -10);
  o.segment(2, 1, kUuidB1, 1, "soak", 20, kAdaptiveStopB);
  o.table1(1, 1, kUuidB1, "17-0042", "z", 0, -10, 0.9876, 0.0144);
  o.table1(2, 1, kUuidB1, "17-0042", "z", 1, 20, 1.2105, 0.0119);
  o.event(1, 1, kUuidB1, 0, "state", "queued", "ramping", "run started");
  return o;
}

// Migrates the lab at `admin_conninfo`, registers both stations and
// pushes their outboxes as their own roles (`conninfo_of(role)`).
template <class ConninfoOf>
void fill_two_station_lab(const std::string& admin_conninfo, ConninfoOf conninfo_of) {
  auto admin = lab::PgConnection::connect(admin_conninfo);
  ASSERT_TRUE(admin.ok()) << admin.error().message;
  auto version = lab::migrate_central(*admin);
  ASSERT_TRUE(version.ok()) << version.error().message;
  const std::pair<const char*, const char*> stations[] = {{"lab-a", "lab_a_relay"},
                                                          {"lab-b", "lab_b_relay"}};
  for (const auto& [id, role] : stations) {
    auto added = lab::add_station(*admin, id, role, std::string("bench ") + id);
    ASSERT_TRUE(added.ok()) << added.error().message;
  }
  const StationOutbox outboxes[] = {station_a_outbox(), station_b_outbox()};
  for (std::size_t i = 0; i < 2; ++i) {
    auto station = lab::PgConnection::connect(conninfo_of(stations[i].second));
    ASSERT_TRUE(station.ok()) << station.error().message;
    auto pushed = lab::push_batch(*station, stations[i].first, outboxes[i].records);
    ASSERT_TRUE(pushed.ok()) << pushed.error().message;
    ASSERT_EQ(pushed->upserted, static_cast<int64_t>(outboxes[i].records.size()));
  }
}

}  // namespace gyrotherm::testing

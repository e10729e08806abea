// The OpenAPI document (daemon/api/openapi.json) against the daemon: the same
// routes, every documented operation answered with a documented status, and
// the bodies of those answers shaped as the document's schemas say.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>

#include "gyrotherm/api/api.h"
#include "gyrotherm/api/auth_limiter.h"
#include "gyrotherm/api/http_message.h"
#include "gyrotherm/api/metrics.h"
#include "gyrotherm/api/web_assets.h"
#include "gyrotherm/core/clock.h"

#ifndef GYROTHERM_OPENAPI_PATH
#define GYROTHERM_OPENAPI_PATH GYROTHERM_SOURCE_DIR "/daemon/api/openapi.json"
#endif

namespace gyrotherm::api {
namespace {

namespace http = boost::beast::http;
using nlohmann::json;

constexpr const char* kContractToken = "contract-token-0123456789abcdef";
constexpr const char* kMethods[] = {"get", "put", "post", "delete", "patch", "head", "options"};

const json& document() {
  static const json doc = [] {
    std::ifstream in(GYROTHERM_OPENAPI_PATH);
    if (!in) throw std::runtime_error("cannot open " GYROTHERM_OPENAPI_PATH);
    return json::parse(in);
  }();
  return doc;
}

std::string upper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

// "METHOD path" of every documented operation.
std::set<std::string> documented_operations() {
  std::set<std::string> out;
  for (const auto& [path, item] : document().at("paths").items()) {
    for (const char* m : kMethods) {
      if (item.contains(m)) out.insert(upper(m) + " " + path);
    }
  }
  return out;
}

// Resolves a local "$ref" ("#/components/schemas/X").
const json& resolve(const json& node) {
  const json* n = &node;
  for (int depth = 0; n->is_object() && n->contains("$ref"); ++depth) {
    if (depth > 16) throw std::runtime_error("$ref loop");
    const std::string ref = n->at("$ref").get<std::string>();
    if (ref.rfind("#/", 0) != 0) throw std::runtime_error("non-local $ref " + ref);
    n = &document().at(json::json_pointer(ref.substr(1)));
  }
  return *n;
}

// Checks `value` against the subset of OpenAPI 3.0 schema keywords the
// document uses; appends "where: what" for each mismatch.
// `strict`: fields the schema does not declare are errors (off for the parts
// of an allOf, whose fields together are checked by check_all_of_fields).
void check_schema(const json& value, const json& schema_in, const std::string& where,
                  std::vector<std::string>& errors, bool strict = true) {
  const json& schema = resolve(schema_in);
  if (value.is_null()) {
    if (!schema.value("nullable", false) && !schema.empty()) {
      errors.push_back(where + ": null but not nullable");
    }
    return;
  }
  if (schema.contains("allOf")) {
    for (const auto& part : schema.at("allOf")) check_schema(value, part, where, errors, false);
  }
  if (schema.contains("enum")) {
    bool found = false;
    for (const auto& e : schema.at("enum")) found |= e == value;
    if (!found)
      errors.push_back(
          fmt::format("{}: {} is not in {}", where, value.dump(), schema.at("enum").dump()));
  }
  if (!schema.contains("type")) return;
  const std::string type = schema.at("type");
  const bool type_ok =
      (type == "object" && value.is_object()) || (type == "array" && value.is_array()) ||
      (type == "string" && value.is_string()) || (type == "boolean" && value.is_boolean()) ||
      (type == "integer" && value.is_number_integer()) || (type == "number" && value.is_number());
  if (!type_ok) {
    errors.push_back(fmt::format("{}: {} is not of type {}", where, value.dump(), type));
    return;
  }
  if (type == "object") {
    const json props = schema.value("properties", json::object());
    for (const auto& r : schema.value("required", json::array())) {
      if (!value.contains(r.get<std::string>())) {
        errors.push_back(
            fmt::format("{}: required field '{}' missing", where, r.get<std::string>()));
      }
    }
    for (const auto& [key, v] : value.items()) {
      if (props.contains(key)) {
        check_schema(v, props.at(key), where + "." + key, errors);
      } else if (schema.contains("additionalProperties")) {
        const json& extra = schema.at("additionalProperties");
        if (extra.is_boolean()) {
          if (!extra.get<bool>()) errors.push_back(where + ": undocumented field '" + key + "'");
        } else {
          check_schema(v, extra, where + "." + key, errors);
        }
      } else if (strict && !schema.contains("allOf") && !props.empty()) {
        // Undocumented fields in a response: the document is incomplete.
        errors.push_back(where + ": undocumented field '" + key + "'");
      }
    }
  }
  if (type == "array" && schema.contains("items")) {
    for (std::size_t i = 0; i < value.size(); ++i) {
      check_schema(value[i], schema.at("items"), fmt::format("{}[{}]", where, i), errors);
    }
  }
}

// Field names an object schema declares, through allOf parts.
void declared_fields(const json& schema_in, std::set<std::string>& out) {
  const json& schema = resolve(schema_in);
  const json props = schema.value("properties", json::object());
  for (const auto& [key, v] : props.items()) out.insert(key);
  for (const auto& part : schema.value("allOf", json::array())) declared_fields(part, out);
}

// Undocumented fields of objects described with allOf (which check_schema
// cannot see part by part).
void check_all_of_fields(const json& value, const json& schema_in, const std::string& where,
                         std::vector<std::string>& errors) {
  const json& schema = resolve(schema_in);
  if (schema.contains("allOf") && value.is_object()) {
    std::set<std::string> fields;
    declared_fields(schema, fields);
    for (const auto& [key, v] : value.items()) {
      if (!fields.count(key)) errors.push_back(where + ": undocumented field '" + key + "'");
    }
  }
  if (value.is_object()) {
    std::set<std::string> fields;
    declared_fields(schema, fields);
    json props = json::object();
    for (const auto& part : schema.value("allOf", json::array())) {
      props.update(resolve(part).value("properties", json::object()));
    }
    props.update(schema.value("properties", json::object()));
    for (const auto& [key, v] : value.items()) {
      if (props.contains(key)) check_all_of_fields(v, props.at(key), where + "." + key, errors);
    }
  } else if (value.is_array() && schema.contains("items")) {
    for (std::size_t i = 0; i < value.size(); ++i) {
      check_all_of_fields(value[i], schema.at("items"), fmt::format("{}[{}]", where, i), errors);
    }
  }
}

// ------------------------------------------------------------ the daemon side

station::StatusSnapshot busy_station() {
  station::StatusSnapshot s;
  s.station_name = "contract";
  s.state = "acquiring";
  s.run_id = 1;
  s.schedule_name = "paper-table1";
  s.step_index = 3;
  s.step_count = 32;
  s.step_label = "step 4: soak 20 °C";
  s.setpoint_c = 20;
  s.chamber_c = 20.1;
  s.top_c = 20.02;
  s.side_c = 19.98;
  s.gradient_c = 0.04;
  s.temp_rate_c_per_min = 0.01;
  s.gyro_rate_dph = 7.95;
  s.gyro_samples_per_s = 1000;
  s.interlocks.push_back({"probe_disagreement", "top and side differ by 2.1 °C"});
  s.queue_length = 2;
  s.queue_held = true;
  s.queue_hold_reason = "stopped by the operator";
  station::TableStatus table;
  table.connected = true;
  table.state = drivers::TableState{
      drivers::TableMode::kRate, "Rate", drivers::TableInterlock::kClosed, 100.0004, 123.4, ""};
  table.demand = {schedules::TableDemandMode::kRate, std::nullopt, 100.0};
  s.table = table;
  // Three DUTs: one with all axes and its temperature, one before its first
  // full second (nulls), the unnamed gyro with one axis.
  station::DutStatus imu;
  imu.serial = "17-0042";
  imu.model = "KVH 1750";
  imu.primary_axis = "z";
  imu.rates_dph = {{"x", 1.5}, {"y", -2.25}, {"z", 7.95}};
  imu.temp_c = 41.2;
  imu.samples_per_s = 1000;
  imu.health.connected = true;
  station::DutStatus starting = imu;
  starting.serial = "17-0043";
  starting.rates_dph = {{"x", std::nullopt}, {"y", std::nullopt}, {"z", std::nullopt}};
  starting.temp_c = std::nullopt;
  starting.samples_per_s = 0;
  station::DutStatus unnamed;
  unnamed.primary_axis = "z";
  unnamed.rates_dph = {{"z", 8.0}};
  s.duts = {imu, starting, unnamed};
  // Settling: the gate's progress, no fraction, no ETA.
  s.progress.phase = "settling";
  s.progress.step_elapsed_s = 420;
  s.progress.step_planned_s = 6000;
  s.progress.gate_held_s = 240;
  s.progress.gate_needed_s = 600;
  s.progress.run_remaining_fixed_s = 90000;
  s.progress.run_settles_remaining = 29;
  s.progress.queue_fixed_s = 43200;
  s.progress.queue_settles = 8;
  s.run_operator = "ana";
  s.run_comment = "lot 7, cold start";
  s.run_tags = {"cold", "lot-7"};
  s.storage_free_bytes = int64_t{12} << 30;
  s.storage_size_bytes = int64_t{200} << 30;
  // A lab relay that lost the lab a while ago: every field, some null.
  lab::RelayStatus relay;
  relay.station_id = "st-07";
  relay.server = "lab-db:5432/lab as st07";
  relay.state = "backoff";
  relay.pending = 120;
  relay.pending_bytes = 48000;
  relay.oldest_pending_age_s = 95.5;
  relay.sent_total = 10500;
  relay.batches_total = 30;
  relay.redelivered_total = 12;
  relay.errors_total = 4;
  relay.max_lag_s = 1.25;
  relay.last_error = "could not connect to server: Connection refused";
  relay.retry_in_s = 16;
  relay.last_sent_utc = "2026-11-21T09:10:00.000Z";
  s.lab = relay;
  return s;
}

storage::QueueEntry queue_entry(int64_t id, std::string state) {
  storage::QueueEntry e;
  e.id = id;
  e.position = state == "queued" ? 0 : -1;
  e.state = std::move(state);
  e.added_utc = "2026-11-21T05:38:43.120Z";
  e.schedule_name = "paper-table1";
  e.source_path = "paper-table1.toml";
  if (e.state == "running") e.run_id = 1;
  return e;
}

// Answers every call with a body built by the daemon's own record
// serializers, so the schemas are checked against what the daemon sends.
class ContractControl : public station::StationControl {
 public:
  json queue_json() {
    return {{"held", false},
            {"hold_reason", ""},
            {"current", station::to_json(queue_entry(1, "running"), 32)},
            {"entries", json::array({station::to_json(queue_entry(2, "queued"), 4)})}};
  }
  station::Reply queue_list() override { return station::Reply::ok(queue_json()); }
  station::Reply queue_add(const std::string&, const std::string&, bool) override {
    return station::Reply::ok(station::to_json(queue_entry(3, "queued"), 4));
  }
  station::Reply queue_remove(int64_t id) override { return station::Reply::ok({{"removed", id}}); }
  station::Reply queue_move(int64_t, int) override { return station::Reply::ok(queue_json()); }
  station::Reply control(std::string_view action, const std::string&) override {
    return station::Reply::ok({{"ok", true}, {"message", fmt::format("{} done", action)}});
  }
  static storage::RunRecord run_record(int64_t id) {
    storage::RunRecord r;
    r.id = id;
    r.schedule_name = "paper-table1";
    r.state = "acquiring";
    r.started_utc = "2026-11-21T05:38:43.120Z";
    r.queue_id = 1;
    return r;
  }
  station::Reply runs() override {
    auto done = run_record(2);
    done.state = "completed";
    done.ended_utc = "2026-11-21T07:38:43.120Z";
    done.queue_id.reset();
    return station::Reply::ok(
        json::array({station::to_json(done), station::to_json(run_record(1))}));
  }
  station::Reply run(int64_t id) override {
    storage::SegmentRecord s;
    s.index = 0;
    s.kind = "soak";
    s.label = "step 1: soak 20 °C";
    s.setpoint_c = 20;
    s.t_settled_s = 600;
    s.t_acquire_start_s = 600;
    s.state = "running";
    s.windows = {{600, 900}, {960, 1200}};
    json j = station::to_json(run_record(id));
    j["segments"] = json::array({station::to_json(s)});
    return station::Reply::ok(j);
  }
  station::Reply run_events(int64_t) override {
    storage::EventRecord state;
    state.id = 1;
    state.t_s = 600;
    state.wall_utc = "2026-11-21T05:48:43.120Z";
    state.kind = "state";
    state.from_state = "settling";
    state.to_state = "acquiring";
    state.message = "stable";
    storage::EventRecord info = state;
    info.id = 2;
    info.kind = "operator";
    info.from_state.clear();
    info.to_state.clear();
    return station::Reply::ok(json::array({station::to_json(state), station::to_json(info)}));
  }
  station::Reply run_stats(int64_t id) override {
    storage::SegmentStatsRecord s;
    s.segment_id = 1;
    s.run_id = id;
    s.n = 7200;
    s.bias_std_ma_dph = std::numeric_limits<double>::quiet_NaN();
    s.computed_utc = "2026-11-21T07:38:43.120Z";
    return station::Reply::ok(json::array({station::to_json(s)}));
  }
  station::Reply run_samples(int64_t id, const station::SamplesQuery& query) override {
    storage::DecimatedSamples d;
    d.from_s = query.from_s;
    d.to_s = query.to_s.value_or(7200);
    d.bucket_s = 3.6;
    d.from_rollup = true;
    d.gyro.t_s = {1.8, 5.4};
    d.gyro.n = {3600, 3600};
    d.gyro.mean_dph = {7.9, std::numeric_limits<double>::quiet_NaN()};
    d.gyro.min_dph = {7.1, 7.2};
    d.gyro.max_dph = {8.7, 8.8};
    d.temperature.t_s = {1.8};
    d.temperature.setpoint_c = {20};
    d.temperature.chamber_c = {20.1};
    d.temperature.top_c = {20.02};
    d.temperature.side_c = {std::numeric_limits<double>::quiet_NaN()};
    json j = station::to_json(d);  // what Station::run_samples adds:
    j["run_id"] = id;
    j["max_points"] = query.max_points;
    return station::Reply::ok(j);
  }
  static storage::FitRecord fit_record(int64_t id) {
    storage::FitRecord f;
    f.id = id;
    f.run_ids = {1, 2};
    f.model = "T4+R1+G1";
    f.form = "paper";
    f.n = 14400;
    f.coefficients_json = R"({"T0": 7.9, "T1": 0.012, "R1": -0.4, "G1": 0.8})";
    f.standard_errors_json = R"({"T0": 0.01, "T1": 0.001, "R1": 0.02, "G1": 0.05})";
    f.residual_std_dph = 0.03;
    f.r_squared = 0.98;
    f.inputs_json = R"({"bin_s": 1, "windows": [[600, 7800]]})";
    f.computed_utc = "2026-11-21T07:38:43.120Z";
    return f;
  }
  station::Reply run_fits(int64_t) override {
    return station::Reply::ok(json::array({station::to_json(fit_record(1))}));
  }
  station::Reply fit(int64_t id) override {
    return station::Reply::ok(station::to_json(fit_record(id)));
  }
  station::Reply run_allan(int64_t) override {
    storage::AllanRecord a;
    a.id = 4;
    a.run_id = 1;
    a.segment_id = 2;
    a.segment_index = 0;
    a.t_from_s = 600;
    a.t_to_s = 7800;
    a.taus = "octave";
    a.tau0_s = 0.01;
    a.n_samples = 720000;
    a.tau_s = {0.01, 0.02, 0.04};
    a.adev_dph = {10.0, 7.07, 5.0};
    a.adev_lo_dph = {9.99, 7.06, 4.99};
    a.adev_hi_dph = {10.01, 7.08, 5.01};
    a.angle_random_walk_dprh = 0.0167;
    a.rate_random_walk_dphprh = std::nullopt;  // a null noise term must match the schema too
    a.inputs_json = R"({"run_id": 1, "segment": 1, "taus": "octave", "window": [600, 7800]})";
    a.computed_utc = "2026-11-21T07:38:43.120Z";
    return station::Reply::ok(json::array({station::to_json(a)}));
  }
  station::Reply run_scale_factor(int64_t) override {
    storage::ScaleFactorPointRecord p;
    p.segment_id = 7;
    p.sf_sequence = 1;
    p.repetition = 1;
    p.rate_dps = -10.0;
    p.measured_rate_dps = -10.0004;
    p.output_dps = -10.0015;
    p.n = 36000;
    p.temperature_c = 20.1;
    p.duration_s = 36.0;
    p.turns = 1.0;
    storage::ScaleFactorFitRecord f;
    f.sf_sequence = 1;
    f.temperature_c = 20.1;
    f.k = 1.00015;
    f.k_se = 2e-7;
    f.bias_dps = 0.0021;
    f.nonlinearity_ppm = 41.0;
    f.nonlinearity_fs_ppm = 12.5;
    f.asymmetry_ppm = 30.2;
    f.repeatability_ppm = std::nullopt;  // a null figure must match the schema too
    f.n_points = 14;
    f.created_utc = "2026-11-21T07:38:43.120Z";
    storage::ScaleFactorTemperatureFitRecord t;
    t.order = 1;
    t.t_centre_c = 25.0;
    t.k_coeffs_json = "[1.00015, 2.0e-5]";
    t.bias_coeffs_json = "[0.0021, 1.0e-6]";
    t.k_ppm_per_c = 20.0;
    t.bias_dph_per_c = 0.0036;
    t.created_utc = "2026-11-21T07:38:43.120Z";
    return station::Reply::ok({{"points", json::array({station::to_json(p)})},
                               {"fits", json::array({station::to_json(f)})},
                               {"temperature_fit", station::to_json(t)},
                               {"temperature_fits", json::array({station::to_json(t)})}});
  }
  static storage::RunDutRecord run_dut() {
    storage::RunDutRecord d;
    d.run_id = 1;
    d.position = 0;
    d.dut.id = 1;
    d.dut.serial = "17-0042";
    d.dut.model = "KVH 1750";
    d.dut.first_seen_utc = "2026-11-20T05:38:43.120Z";
    d.primary_axis = "z";
    d.axes = {"x", "y", "z"};
    d.rate_hz = 1000;
    const std::pair<const char*, ChannelKind> channels[] = {{"gyro_z", ChannelKind::kRate},
                                                            {"accel_z", ChannelKind::kAccel},
                                                            {"status", ChannelKind::kStatus},
                                                            {"temp_c", ChannelKind::kTemperature}};
    for (const auto& [name, kind] : channels) {
      storage::ChannelRecord c;
      c.index = static_cast<int>(d.channels.size());
      c.spec.name = name;
      c.spec.kind = kind;
      c.spec.unit = kind == ChannelKind::kRate          ? "deg/h"
                    : kind == ChannelKind::kAccel       ? "g"
                    : kind == ChannelKind::kTemperature ? "degC"
                                                        : "";
      c.spec.axis = kind == ChannelKind::kRate || kind == ChannelKind::kAccel ? "z" : "";
      d.channels.push_back(c);
    }
    d.rate_hz = 0;  // unknown: null must match the schema too
    return d;
  }
  station::Reply enqueue(const station::QueueRequest&) override {
    auto e = queue_entry(3, "queued");
    e.metadata.operator_name = "ana";
    e.metadata.tags = {"campaign-7"};
    e.metadata.dut_serials = {"17-0042"};
    return station::Reply::ok(station::to_json(e, 4));
  }
  station::Reply run_with_duts(int64_t id) override {
    station::Reply r = run(id);
    r.body["metadata"] = station::to_json(storage::RunMetadata{"ana", "line 1\nline 2", {"a"}, {}});
    r.body["duts"] = json::array({station::to_json(run_dut())});
    return r;
  }
  station::Reply edit_run(int64_t id, const station::MetadataEdit&, const std::string&) override {
    return run_with_duts(id);
  }
  station::Reply run_stats_filtered(int64_t id, const station::StatsQuery&) override {
    station::Reply r = run_stats(id);
    r.body[0]["dut_serial"] = "17-0042";
    r.body[0]["axis"] = "z";
    return r;
  }
  station::Reply run_channel_samples(int64_t id, const station::SamplesQuery& query) override {
    station::Reply r = run_samples(id, query);
    r.body["dut"] = "17-0042";
    r.body["channel"] = "gyro_z";
    r.body["unit"] = "deg/h";
    return r;
  }
  station::Reply duts() override {
    storage::DutRecord d = run_dut().dut;
    storage::DutRecord unnamed;
    unnamed.id = 2;
    unnamed.first_seen_utc = "2026-01-02T03:04:05.000Z";
    return station::Reply::ok(json::array({station::to_json(unnamed, 3), station::to_json(d, 1)}));
  }
  station::Reply dut_history(const std::string&) override {
    storage::DutHistory h;
    h.dut = run_dut().dut;
    storage::DutHistory::Run r;
    r.run = run_record(1);
    r.run.metadata.operator_name = "ana";
    r.in_run = run_dut();
    storage::SegmentRecord s;
    s.kind = "soak";
    s.label = "step 1: soak 20 °C";
    s.setpoint_c = 20;
    s.state = "completed";
    r.segments = {s};
    storage::SegmentStatsRecord row;
    row.segment_id = 1;
    row.run_id = 1;
    row.dut_serial = "17-0042";
    row.axis = "x";
    row.n = 7200;
    r.stats = {row};
    storage::AllanRecord a;
    a.run_id = 1;
    a.dut_serial = "17-0042";
    a.axis = "x";
    a.taus = "octave";
    r.allan = {a};
    storage::ScaleFactorFitRecord f;
    f.dut_serial = "17-0042";
    f.axis = "z";
    f.sf_sequence = 1;
    f.k = 1.00015;
    r.scale_factor = {f};
    h.runs = {r};
    auto fit = fit_record(5);
    fit.dut_serial = "17-0042";
    fit.axis = "z";
    h.fits = {fit};
    return station::Reply::ok(station::to_json(h));
  }
  station::Reply exports() override {
    storage::ExportRecord done;
    done.id = 2;
    done.kind = "nightly";
    done.slot_unix_s = 1795316400;
    done.slot_local = "2026-11-21 02:00 UTC+01:00";
    done.state = "done";
    done.directory = "/var/lib/gyrotherm/reports/2026-11-21";
    done.run_ids = {3, 4};
    done.files = {"index.html", "run-0003/report.html", "table1.csv"};
    done.started_utc = "2026-11-21T01:00:00.020Z";
    done.finished_utc = "2026-11-21T01:00:02.410Z";
    done.message = "2 runs, 3 files";
    storage::ExportRecord writing;  // a manual export still being written
    writing.id = 3;
    writing.kind = "manual";
    writing.state = "writing";
    writing.directory = "/tmp/reports";
    writing.run_ids = {4};
    writing.started_utc = "2026-11-21T09:12:00.000Z";
    return station::Reply::ok(json::array({station::to_json(writing), station::to_json(done)}));
  }
};

// A web root with the files the document's examples name.
class WebRoot {
 public:
  WebRoot() {
    dir_ = std::filesystem::temp_directory_path() / fmt::format("gyrotherm-openapi-{}", ::getpid());
    std::filesystem::create_directories(dir_);
    std::ofstream(dir_ / "index.html") << "<!doctype html><title>gyrotherm</title>";
    std::ofstream(dir_ / "app.js") << "console.log('gyrotherm');";
    auto loaded = WebAssets::load(dir_.string());
    if (!loaded) throw std::runtime_error(loaded.error().message);
    assets_ = std::move(*loaded);
  }
  ~WebRoot() { std::filesystem::remove_all(dir_); }
  const WebAssets* assets() const { return &*assets_; }

 private:
  std::filesystem::path dir_;
  std::optional<WebAssets> assets_;
};

ApiContext contract_context(station::StationControl* control, const WebAssets* web = nullptr,
                            const Metrics* metrics = nullptr) {
  ApiContext ctx;
  ctx.status = busy_station;
  ctx.control = control;
  ctx.tokens = {kContractToken};
  ctx.web = web;
  if (metrics) ctx.metrics = [metrics] { return metrics->scrape(busy_station(), {}); };
  return ctx;
}

// Path template with its parameters filled: {id} -> 1, an enum parameter
// -> each of its values.
std::vector<std::string> fill_path(const std::string& path, const json& params) {
  std::vector<std::string> targets = {path};
  for (const auto& p_in : params) {
    const json& p = resolve(p_in);
    if (p.at("in") != "path") continue;
    const std::string placeholder = "{" + p.at("name").get<std::string>() + "}";
    const json& schema = resolve(p.at("schema"));
    std::vector<std::string> values;
    if (schema.contains("enum")) {
      for (const auto& v : schema.at("enum")) values.push_back(v.get<std::string>());
    } else if (schema.contains("example")) {
      values.push_back(schema.at("example").is_string() ? schema.at("example").get<std::string>()
                                                        : schema.at("example").dump());
    } else {
      values.push_back("1");
    }
    std::vector<std::string> next;
    for (const auto& t : targets) {
      for (const auto& v : values) {
        std::string filled = t;
        filled.replace(filled.find(placeholder), placeholder.size(), v);
        next.push_back(filled);
      }
    }
    targets = std::move(next);
  }
  return targets;
}

json operation_parameters(const json& item, const json& operation) {
  json params = item.value("parameters", json::array());
  for (const auto& p : operation.value("parameters", json::array())) params.push_back(p);
  return params;
}

// ------------------------------------------------------------------- tests

TEST(OpenApi, DocumentsExactlyTheServedRoutes) {
  std::set<std::string> served;
  for (const RouteInfo& r : api_routes()) served.insert(r.method + " " + r.path);
  const std::set<std::string> documented = documented_operations();
  std::vector<std::string> undocumented, not_served;
  std::set_difference(served.begin(), served.end(), documented.begin(), documented.end(),
                      std::back_inserter(undocumented));
  std::set_difference(documented.begin(), documented.end(), served.begin(), served.end(),
                      std::back_inserter(not_served));
  EXPECT_TRUE(undocumented.empty()) << "served but not in daemon/api/openapi.json:\n  "
                                    << fmt::format("{}", fmt::join(undocumented, "\n  "));
  EXPECT_TRUE(not_served.empty()) << "in daemon/api/openapi.json but not served (api_routes()):\n  "
                                  << fmt::format("{}", fmt::join(not_served, "\n  "));
}

TEST(OpenApi, EveryRefResolves) {
  std::vector<std::string> broken;
  std::function<void(const json&, const std::string&)> walk = [&](const json& node,
                                                                  const std::string& where) {
    if (node.is_object()) {
      if (node.contains("$ref")) {
        const std::string ref = node.at("$ref").get<std::string>();
        if (ref.rfind("#/", 0) != 0 || !document().contains(json::json_pointer(ref.substr(1)))) {
          broken.push_back(where + ": " + ref);
        }
      }
      for (const auto& [k, v] : node.items()) walk(v, where + "/" + k);
    } else if (node.is_array()) {
      for (std::size_t i = 0; i < node.size(); ++i) walk(node[i], where + "/" + std::to_string(i));
    }
  };
  walk(document(), "");
  EXPECT_TRUE(broken.empty()) << fmt::format("{}", fmt::join(broken, "\n"));
}

TEST(OpenApi, OperationsAreCompleteAndMutationsNeedTheToken) {
  const json& doc = document();
  EXPECT_EQ(doc.at("openapi"), "3.0.3");
  EXPECT_EQ(doc.at("info").at("version"), "0.1.0");
  ASSERT_TRUE(doc.at("components").at("securitySchemes").contains("bearerAuth"));
  for (const auto& [path, item] : doc.at("paths").items()) {
    for (const char* m : kMethods) {
      if (!item.contains(m)) continue;
      const json& op = item.at(m);
      const std::string name = upper(m) + " " + path;
      EXPECT_TRUE(op.contains("summary") && op.contains("description")) << name;
      EXPECT_TRUE(op.contains("operationId")) << name;

      bool has_2xx = false;
      for (const auto& [code, res] : op.at("responses").items()) {
        has_2xx |= code.size() == 3 && code[0] == '2';
        EXPECT_TRUE(resolve(res).contains("description")) << name << " " << code;
      }
      EXPECT_TRUE(has_2xx) << name << " documents no 2xx answer";

      // Every {param} of the template is a required path parameter, and no
      // path parameter is missing from the template.
      std::set<std::string> in_template;
      for (std::size_t open = path.find('{'); open != std::string::npos;
           open = path.find('{', open + 1)) {
        in_template.insert(path.substr(open + 1, path.find('}', open) - open - 1));
      }
      std::set<std::string> declared;
      for (const auto& p_in : operation_parameters(item, op)) {
        const json& p = resolve(p_in);
        EXPECT_TRUE(p.contains("schema")) << name << " parameter " << p.value("name", "?");
        if (p.at("in") != "path") continue;
        declared.insert(p.at("name").get<std::string>());
        EXPECT_TRUE(p.value("required", false)) << name << ": path parameter must be required";
      }
      EXPECT_EQ(in_template, declared) << name << ": template parameters vs declared ones";

      // Mutations require the bearer token; reads of station data (all of
      // /api/v1 and /metrics) take one optionally ({}: none, in open mode);
      // liveness and the dashboard's files none.
      const bool mutation =
          std::string(m) == "post" || std::string(m) == "patch" || std::string(m) == "delete";
      const bool data_read = !mutation && (path.rfind("/api/v1/", 0) == 0 || path == "/metrics");
      const json security = op.value("security", doc.value("security", json::array()));
      if (mutation) {
        EXPECT_EQ(security, json::parse(R"([{"bearerAuth": []}])")) << name;
        for (const char* code : {"401", "403", "429"}) {
          EXPECT_TRUE(op.at("responses").contains(code)) << name << " " << code;
        }
      } else if (data_read) {
        EXPECT_EQ(security, json::parse(R"([{}, {"bearerAuth": []}])")) << name;
        for (const char* code : {"401", "429"}) {
          EXPECT_TRUE(op.at("responses").contains(code)) << name << " " << code;
        }
      } else {
        EXPECT_TRUE(security.empty()) << name << ": open to all";
      }
      if (op.contains("requestBody")) {
        const json& schema =
            resolve(op.at("requestBody").at("content").at("application/json").at("schema"));
        EXPECT_EQ(schema.value("additionalProperties", true), false)
            << name << ": request bodies refuse unknown fields";
      }
    }
  }
}

// Every documented operation, sent with its path parameters filled, a valid
// token and the documented example body (itself valid for the documented
// schema) to a station that agrees to everything: a documented 2xx status,
// a documented content type, and a body shaped as the documented schema.
TEST(OpenApi, EveryOperationAnswersAsDocumented) {
  ContractControl control;
  const WebRoot web;
  const Metrics metrics;
  ApiContext ctx = contract_context(&control, web.assets(), &metrics);
  int checked = 0;
  // Reads open, then reads that need a token: the control token serves both.
  for (const bool token_mode : {false, true}) {
    ctx.reads_need_token = token_mode;
    for (const auto& [path, item] : document().at("paths").items()) {
      for (const char* m : kMethods) {
        if (!item.contains(m)) continue;
        const json& op = item.at(m);
        std::string body;
        if (op.contains("requestBody")) {
          const json& media = op.at("requestBody").at("content").at("application/json");
          ASSERT_TRUE(media.contains("example"))
              << upper(m) << " " << path << ": document an example body (the test sends it)";
          body = media.at("example").dump();
          std::vector<std::string> errors;
          check_schema(media.at("example"), media.at("schema"), "example", errors);
          EXPECT_TRUE(errors.empty())
              << upper(m) << " " << path << ": " << fmt::format("{}", fmt::join(errors, "\n"));
        }
        for (const std::string& target : fill_path(path, operation_parameters(item, op))) {
          const std::string name = upper(m) + " " + target;
          SCOPED_TRACE(name);
          HttpRequest req{http::string_to_verb(upper(m)), target, 11};
          req.set(http::field::authorization, std::string("Bearer ") + kContractToken);
          if (!body.empty()) req.set(http::field::content_type, "application/json");
          req.body() = body;
          req.prepare_payload();
          const HttpResponse res = handle_api_request(req, ctx);
          const int status = static_cast<int>(res.result());
          EXPECT_NE(status, 404) << res.body();
          EXPECT_NE(status, 405) << res.body();
          // The station agrees to everything here, so only success is right;
          // the stream is served by the HTTP server, not by this function.
          if (target != "/api/v1/stream") {
            EXPECT_EQ(status / 100, 2) << res.body();
          }
          const json& responses = op.at("responses");
          const std::string code = std::to_string(status);
          if (!responses.contains(code)) {
            ADD_FAILURE() << name << " answered " << status << ", not documented: " << res.body();
            continue;
          }
          ++checked;
          const json& documented = resolve(responses.at(code));
          if (!documented.contains("content")) continue;
          std::string type(res[http::field::content_type]);
          type = type.substr(0, type.find(';'));
          if (!documented.at("content").contains(type)) {
            ADD_FAILURE() << name << ": content type '" << type << "' is not documented for "
                          << code;
            continue;
          }
          if (type != "application/json") continue;
          const json& schema = documented.at("content").at(type).value("schema", json::object());
          json value;
          try {
            value = json::parse(res.body());
          } catch (const json::parse_error& e) {
            ADD_FAILURE() << name << ": body is not JSON: " << e.what();
            continue;
          }
          std::vector<std::string> errors;
          check_schema(value, schema, "body", errors);
          check_all_of_fields(value, schema, "body", errors);
          EXPECT_TRUE(errors.empty()) << fmt::format("{}", fmt::join(errors, "\n"));
        }
      }
    }
  }
  EXPECT_GE(checked, 2 * static_cast<int>(documented_operations().size()));
}

// The mutations without a token, and with no token configured, answer the
// documented 401 and 403 with an Error body.
TEST(OpenApi, RefusedMutationsAnswerTheDocumentedErrors) {
  ContractControl control;
  ApiContext ctx = contract_context(&control);
  ApiContext no_tokens = ctx;
  no_tokens.tokens.clear();
  for (const auto& [path, item] : document().at("paths").items()) {
    for (const char* m : {"post", "patch", "delete"}) {
      if (!item.contains(m)) continue;
      const json& op = item.at(m);
      for (const std::string& target : fill_path(path, operation_parameters(item, op))) {
        HttpRequest req{http::string_to_verb(upper(m)), target, 11};
        for (const auto& [context, expected] :
             {std::pair<const ApiContext*, int>{&ctx, 401}, {&no_tokens, 403}}) {
          const HttpResponse res = handle_api_request(req, *context);
          EXPECT_EQ(static_cast<int>(res.result()), expected) << upper(m) << " " << target;
          std::vector<std::string> errors;
          check_schema(json::parse(res.body()),
                       resolve(op.at("responses").at(std::to_string(expected)))
                           .at("content")
                           .at("application/json")
                           .at("schema"),
                       "body", errors);
          EXPECT_TRUE(errors.empty()) << fmt::format("{}", fmt::join(errors, "\n"));
        }
      }
    }
  }
}

// A read token on every mutation: the documented 403. A peer locked out by
// the failed-authentication throttle: the documented 429 with Retry-After,
// on mutations and, in token mode, on reads of station data. Reads without
// a token in token mode: the documented 401.
TEST(OpenApi, ReadTokensTokenModeAndThrottlingAnswerTheDocumentedErrors) {
  constexpr const char* kReadToken = "contract-read-token-0123456789";
  ContractControl control;
  const Metrics metrics;
  ManualClock wall;
  auto made = AuthLimiter::create({.max_failures = 1, .window_s = 60.0}, &wall);
  ASSERT_TRUE(made.ok()) << made.error().message;
  AuthLimiter& limiter = **made;
  ApiContext ctx = contract_context(&control, nullptr, &metrics);
  ctx.read_tokens = {kReadToken};
  ctx.reads_need_token = true;
  ctx.auth_limiter = &limiter;
  HttpRequest wrong{http::verb::post, "/api/v1/control/stop", 11};
  wrong.set(http::field::authorization, "Bearer not-a-token-of-this-station");
  ASSERT_EQ(handle_api_request(wrong, ctx, "192.0.2.9").result(), http::status::unauthorized);

  const auto check = [&](const json& op, const std::string& name, const HttpResponse& res,
                         int expected) {
    ASSERT_EQ(static_cast<int>(res.result()), expected) << name << ": " << res.body();
    const std::string code = std::to_string(expected);
    ASSERT_TRUE(op.at("responses").contains(code)) << name << " " << code;
    const json& documented = resolve(op.at("responses").at(code));
    const json headers = documented.value("headers", json::object());
    for (const auto& [header, spec] : headers.items()) {
      EXPECT_FALSE(res[header].empty()) << name << ": documented header " << header;
    }
    std::vector<std::string> errors;
    check_schema(json::parse(res.body()),
                 documented.at("content").at("application/json").at("schema"), "body", errors);
    EXPECT_TRUE(errors.empty()) << name << fmt::format("{}", fmt::join(errors, "\n"));
  };
  int checked = 0;
  for (const auto& [path, item] : document().at("paths").items()) {
    for (const char* m : {"get", "post", "patch", "delete"}) {
      if (!item.contains(m)) continue;
      const json& op = item.at(m);
      if (!op.contains("security")) continue;  // open to all
      const bool mutation = std::string(m) != "get";
      for (const std::string& target : fill_path(path, operation_parameters(item, op))) {
        const std::string name = upper(m) + " " + target;
        HttpRequest req{http::string_to_verb(upper(m)), target, 11};
        req.set(http::field::authorization, std::string("Bearer ") + kReadToken);
        if (mutation) check(op, name, handle_api_request(req, ctx, "192.0.2.1"), 403);
        check(op, name, handle_api_request(req, ctx, "192.0.2.9"), 429);
        if (!mutation) {
          HttpRequest anonymous{http::verb::get, target, 11};
          check(op, name, handle_api_request(anonymous, ctx, "192.0.2.1"), 401);
        }
        ++checked;
      }
    }
  }
  EXPECT_GE(checked, 15);
}

// GET /api/v1/openapi.json serves this very document (embedded at build
// time: a stale build fails here).
TEST(OpenApi, ServedDocumentIsTheSourceFile) {
  ContractControl control;
  const HttpRequest req{http::verb::get, "/api/v1/openapi.json", 11};
  const HttpResponse res = handle_api_request(req, contract_context(&control));
  ASSERT_EQ(res.result(), http::status::ok);
  EXPECT_EQ(json::parse(res.body()), document());
}

// The checker itself finds what it is meant to find.
TEST(OpenApi, SchemaCheckerCatchesMismatches) {
  const json& run = document().at("components").at("schemas").at("Run");
  json good = station::to_json(ContractControl::run_record(4));
  std::vector<std::string> errors;
  check_schema(good, run, "run", errors);
  EXPECT_TRUE(errors.empty()) << fmt::format("{}", fmt::join(errors, "\n"));
  json bad = good;
  bad["state"] = "melting";
  bad.erase("started_utc");
  bad["id"] = "four";
  bad["colour"] = "red";
  check_schema(bad, run, "run", errors);
  EXPECT_EQ(errors.size(), 4u) << fmt::format("{}", fmt::join(errors, "\n"));
}

}  // namespace
}  // namespace gyrotherm::api

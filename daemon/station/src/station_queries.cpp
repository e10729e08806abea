#include "gyrotherm/station/station_queries.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <nlohmann/json.hpp>
#include <sstream>
#include <utility>
#include <vector>

#include "gyrotherm/schedules/schedule.h"

namespace gyrotherm::station {
namespace {

std::vector<std::string> split_lines(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    if (!line.empty()) out.push_back(line);
  }
  return out;
}

Reply db_failure(const Error& e) {
  spdlog::error("{}", e.message);
  return Reply::refused(Refusal::Kind::kUnavailable, e.message);
}

// A failed run lookup: "no such run" (permanent) or the database failing.
Reply run_lookup_failure(const Error& e, int64_t id) {
  if (e.transient) return db_failure(e);
  return Reply::refused(Refusal::Kind::kNotFound, fmt::format("no run {}", id));
}

std::string joined(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& i : items) out += fmt::format("{}'{}'", out.empty() ? "" : ", ", i);
  return out.empty() ? std::string("none") : out;
}

// The first of `given` that is not in `known`, refused naming `field`.
std::optional<Reply> unknown_serial(const std::vector<std::string>& given,
                                    const std::vector<std::string>& known, std::string_view field,
                                    std::string_view known_what) {
  for (const auto& serial : given) {
    if (std::find(known.begin(), known.end(), serial) == known.end()) {
      return Reply::refused(Refusal::Kind::kBadRequest,
                            fmt::format("field '{}': no DUT with serial '{}' ({}: {})", field,
                                        serial, known_what, joined(known)));
    }
  }
  return std::nullopt;
}

std::vector<std::string> configured_serials(const config::StationConfig& config) {
  std::vector<std::string> out;
  for (const auto& d : config.duts) out.push_back(d.serial);
  return out;
}

// The run's DUT named `serial` ("" = its first), or a 404 naming it.
Result<const storage::RunDutRecord*> find_run_dut(const std::vector<storage::RunDutRecord>& duts,
                                                  int64_t run_id, const std::string& serial) {
  std::vector<std::string> serials;
  for (const auto& d : duts) {
    if (serial.empty() || d.dut.serial == serial) return &d;
    serials.push_back(d.dut.serial);
  }
  return Error::Permanent(serial.empty() ? fmt::format("run {} recorded no DUT", run_id)
                                         : fmt::format("run {} has no DUT '{}' (its DUTs: {})",
                                                       run_id, serial, joined(serials)));
}

}  // namespace

StationQueries::StationQueries(const config::StationConfig& config, storage::Database db,
                               Links links)
    : config_(config), links_(std::move(links)), db_(std::move(db)) {}

Reply StationQueries::queue_list() {
  std::lock_guard lock(mu_);
  auto entries = db_.queue_entries();
  if (!entries) return db_failure(entries.error());
  nlohmann::json current = nullptr;
  nlohmann::json list = nlohmann::json::array();
  for (const auto& e : *entries) {
    auto plan =
        schedules::parse_schedule(e.toml_text, e.source_path, config::station_limits(config_));
    const int steps = plan ? static_cast<int>(plan->steps.size()) : 0;
    if (e.state == "running") {
      current = to_json(e, steps);
    } else {
      list.push_back(to_json(e, steps));
    }
  }
  // The stored hold is what the answer reads, held and reason from one read:
  // the control thread writes it before it raises queue_held, so a reader
  // never sees "held" without its reason (it once did, between the two).
  // queue_held alone still counts if the store failed.
  std::string reason;
  bool held = false;
  if (auto m = db_.meta(kQueueHoldKey); m && *m) {
    held = true;
    reason = **m;
  }
  held = held || links_.queue_held.load();
  return Reply::ok(
      {{"held", held}, {"hold_reason", reason}, {"current", current}, {"entries", list}});
}

std::optional<Reply> StationQueries::unless_queued(int64_t id, std::string_view when_running) {
  auto entry = db_.queue_entry(id);
  if (!entry) return db_failure(entry.error());
  if (*entry && (*entry)->state == "queued") return std::nullopt;
  if (*entry && (*entry)->state == "running") {
    return Reply::refused(Refusal::Kind::kConflict,
                          fmt::format("queue entry {} is running; {}", id, when_running));
  }
  return Reply::refused(Refusal::Kind::kNotFound, fmt::format("no queued entry {}", id));
}

Reply StationQueries::queue_remove(int64_t id) {
  std::lock_guard lock(mu_);
  if (auto refused = unless_queued(id, "abort the run instead")) return *refused;
  auto removed = db_.queue_remove(id);
  if (!removed) return db_failure(removed.error());
  if (!*removed) {
    return Reply::refused(
        Refusal::Kind::kConflict,
        fmt::format("queue entry {} has just started; abort the run instead", id));
  }
  links_.queue_length.fetch_sub(1);
  spdlog::info("queue entry {} removed", id);
  return Reply::ok({{"removed", id}});
}

Reply StationQueries::queue_move(int64_t id, int position) {
  {
    std::lock_guard lock(mu_);
    if (auto refused = unless_queued(id, "it cannot move")) return *refused;
    auto moved = db_.queue_move(id, position);
    if (!moved) return db_failure(moved.error());
    if (!*moved) {
      return Reply::refused(Refusal::Kind::kConflict,
                            fmt::format("queue entry {} has just started", id));
    }
  }
  return queue_list();
}

Reply StationQueries::runs() {
  std::lock_guard lock(mu_);
  auto runs = db_.runs();
  if (!runs) return db_failure(runs.error());
  nlohmann::json out = nlohmann::json::array();
  for (auto it = runs->rbegin(); it != runs->rend(); ++it) out.push_back(to_json(*it));
  return Reply::ok(std::move(out));
}

template <class Answer>
Reply StationQueries::consistently(Answer answer) {
  std::optional<Reply> reply;
  const Status read = db_.read_consistently([&]() -> Status {
    reply.emplace(answer());
    return Status::Ok();
  });
  if (!read) return db_failure(read.error());
  return std::move(*reply);
}

Reply StationQueries::run(int64_t id) {
  std::lock_guard lock(mu_);
  return consistently([&] {
    auto run = db_.run(id);
    if (!run) return run_lookup_failure(run.error(), id);
    auto segs = db_.segments(id);
    if (!segs) return db_failure(segs.error());
    nlohmann::json j = to_json(*run);
    nlohmann::json list = nlohmann::json::array();
    for (const auto& s : *segs) list.push_back(to_json(s));
    j["segments"] = std::move(list);
    return Reply::ok(std::move(j));
  });
}

// A run's records as a JSON array; 404 for an unknown run.
template <class Fetch>
Reply StationQueries::run_records(int64_t id, Fetch fetch) {
  std::lock_guard lock(mu_);
  return consistently([&] {
    if (auto run = db_.run(id); !run) return run_lookup_failure(run.error(), id);
    auto records = fetch(db_);
    if (!records) return db_failure(records.error());
    nlohmann::json out = nlohmann::json::array();
    for (const auto& r : *records) out.push_back(to_json(r));
    return Reply::ok(std::move(out));
  });
}

Reply StationQueries::run_events(int64_t id) {
  return run_records(id, [id](storage::Database& db) { return db.events(id); });
}

Reply StationQueries::run_stats(int64_t id) {
  return run_records(id, [id](storage::Database& db) { return db.segment_stats(id); });
}

Reply StationQueries::run_fits(int64_t id) {
  return run_records(id, [id](storage::Database& db) { return db.fits(id); });
}

Reply StationQueries::run_allan(int64_t id) {
  return run_records(id, [id](storage::Database& db) { return db.allan(id); });
}

Reply StationQueries::run_scale_factor(int64_t id) {
  std::lock_guard lock(mu_);
  // One read: the analysis stores a series' points and fits together.
  return consistently([&] {
    if (auto run = db_.run(id); !run) return run_lookup_failure(run.error(), id);
    auto points = db_.scale_factor_points(id);
    if (!points) return db_failure(points.error());
    auto fits = db_.scale_factor_fits(id);
    if (!fits) return db_failure(fits.error());
    auto over_t = db_.scale_factor_temperature_fit(id);
    if (!over_t) return db_failure(over_t.error());
    auto every_over_t = db_.scale_factor_temperature_fits(id);
    if (!every_over_t) return db_failure(every_over_t.error());
    nlohmann::json out = {{"points", nlohmann::json::array()},
                          {"fits", nlohmann::json::array()},
                          {"temperature_fit", nullptr},
                          {"temperature_fits", nlohmann::json::array()}};
    for (const auto& p : *points) out["points"].push_back(to_json(p));
    for (const auto& f : *fits) out["fits"].push_back(to_json(f));
    // temperature_fit: the first DUT's primary axis, as before several DUTs;
    // temperature_fits: every DUT and axis.
    if (*over_t) out["temperature_fit"] = to_json(**over_t);
    for (const auto& t : *every_over_t) out["temperature_fits"].push_back(to_json(t));
    return Reply::ok(std::move(out));
  });
}

Reply StationQueries::fit(int64_t id) {
  std::lock_guard lock(mu_);
  auto fit = db_.fit(id);
  if (!fit) return db_failure(fit.error());
  if (!*fit) return Reply::refused(Refusal::Kind::kNotFound, fmt::format("no fit {}", id));
  return Reply::ok(to_json(**fit));
}

Reply StationQueries::exports() {
  std::lock_guard lock(mu_);
  auto exports = db_.exports();
  if (!exports) return db_failure(exports.error());
  nlohmann::json out = nlohmann::json::array();
  for (const auto& e : *exports) out.push_back(to_json(e));
  return Reply::ok(std::move(out));
}

// ---------------------------------------------------------------- run metadata and DUT history
//
// The StationControl routes of schema v8 (docs/api.md "Run metadata", "DUT
// history").

Reply StationQueries::enqueue(const QueueRequest& request) {
  if (auto bad = unknown_serial(request.metadata.dut_serials, configured_serials(config_), "duts",
                                "configured [[dut]] serials")) {
    return *bad;
  }
  const std::string name = request.source.empty() ? std::string("schedule") : request.source;
  auto plan = schedules::parse_schedule(request.toml_text, name, config::station_limits(config_));
  if (!plan) {
    return Reply::refused(Refusal::Kind::kInvalid, "schedule refused, nothing queued",
                          split_lines(plan.error().message));
  }
  Result<storage::QueueEntry> entry = Error::Permanent("not added");
  {
    std::lock_guard lock(mu_);
    entry = db_.queue_add(plan->name, request.source, request.toml_text, request.ignore_failures,
                          request.metadata);
    if (!entry) return db_failure(entry.error());
    links_.queue_length.fetch_add(1);
  }
  spdlog::info("queued {} ({} steps) as entry {}{}", plan->name, plan->steps.size(), entry->id,
               request.metadata.operator_name.empty()
                   ? std::string()
                   : fmt::format(" by {}", request.metadata.operator_name));
  if (links_.wake) links_.wake();
  return Reply::ok(to_json(*entry, static_cast<int>(plan->steps.size())));
}

Reply StationQueries::run_with_duts(int64_t id) {
  std::lock_guard lock(mu_);
  auto run = run_detail_json(db_, id);
  if (!run) return run_lookup_failure(run.error(), id);
  return Reply::ok(std::move(*run));
}

Reply StationQueries::edit_run(int64_t id, const MetadataEdit& edit,
                               const std::string& changed_by) {
  std::lock_guard lock(mu_);
  auto run = db_.run(id);
  if (!run) return run_lookup_failure(run.error(), id);
  storage::RunMetadata metadata = run->metadata;
  if (edit.dut_serials) {
    // Serials configured now or recorded in any run: a run's gyros may have
    // left the station's config since.
    std::vector<std::string> known = configured_serials(config_);
    auto registered = db_.duts();
    if (!registered) return db_failure(registered.error());
    for (const auto& d : *registered) {
      if (std::find(known.begin(), known.end(), d.serial) == known.end()) known.push_back(d.serial);
    }
    if (auto bad =
            unknown_serial(*edit.dut_serials, known, "duts", "configured or recorded serials")) {
      return *bad;
    }
    metadata.dut_serials = *edit.dut_serials;
  }
  if (edit.operator_name) metadata.operator_name = *edit.operator_name;
  if (edit.comment) metadata.comment = *edit.comment;
  if (edit.tags) metadata.tags = *edit.tags;
  if (auto st = db_.set_run_metadata(id, metadata, changed_by); !st) {
    return run_lookup_failure(st.error(), id);
  }
  if (links_.metadata_changed) links_.metadata_changed(id, metadata);
  spdlog::info("run {}: metadata changed by {}", id, changed_by);
  auto detail = run_detail_json(db_, id);
  if (!detail) return db_failure(detail.error());
  return Reply::ok(std::move(*detail));
}

Reply StationQueries::run_stats_filtered(int64_t id, const StatsQuery& query) {
  std::lock_guard lock(mu_);
  return consistently([&] {
    if (auto run = db_.run(id); !run) return run_lookup_failure(run.error(), id);
    auto duts = db_.run_duts(id);
    if (!duts) return db_failure(duts.error());
    if (!query.dut.empty()) {
      if (auto d = find_run_dut(*duts, id, query.dut); !d) {
        return Reply::refused(Refusal::Kind::kNotFound, d.error().message);
      }
    }
    auto rows = db_.segment_stats(id);
    if (!rows) return db_failure(rows.error());
    nlohmann::json out = nlohmann::json::array();
    for (auto row : *rows) {
      // Rows stored with "" are the run's first DUT and its primary axis.
      if (!duts->empty()) {
        if (row.dut_serial.empty()) row.dut_serial = duts->front().dut.serial;
        if (row.axis.empty()) {
          if (auto d = find_run_dut(*duts, id, row.dut_serial); d) row.axis = (*d)->primary_axis;
        }
      }
      if (!query.dut.empty() && row.dut_serial != query.dut) continue;
      if (!query.axis.empty() && row.axis != query.axis) continue;
      out.push_back(to_json(row));
    }
    return Reply::ok(std::move(out));
  });
}

Reply StationQueries::run_channel_samples(int64_t id, const SamplesQuery& query) {
  std::lock_guard lock(mu_);
  if (auto run = db_.run(id); !run) return run_lookup_failure(run.error(), id);
  Result<storage::DecimatedSamples> samples = Error::Permanent("not read");
  if (query.dut.empty() && query.channel.empty()) {
    // The run's first DUT, its primary axis (also a run with no DUT yet).
    samples = db_.decimated_samples(id, query.from_s, query.to_s, query.max_points);
  } else {
    auto duts = db_.run_duts(id);
    if (!duts) return db_failure(duts.error());
    auto dut = find_run_dut(*duts, id, query.dut);
    if (!dut) return Reply::refused(Refusal::Kind::kNotFound, dut.error().message);
    if (!query.channel.empty()) {
      std::vector<std::string> names;
      for (const auto& c : (*dut)->channels) names.push_back(c.spec.name);
      if (std::find(names.begin(), names.end(), query.channel) == names.end()) {
        return Reply::refused(
            Refusal::Kind::kNotFound,
            fmt::format("DUT '{}' of run {} has no channel '{}' (its channels: {})",
                        (*dut)->dut.serial, id, query.channel, joined(names)));
      }
    }
    samples = db_.decimated_samples(id, storage::StreamKey{(*dut)->dut.serial, ""}, query.channel,
                                    query.from_s, query.to_s, query.max_points);
  }
  if (!samples) {
    if (samples.error().transient) return db_failure(samples.error());
    return Reply::refused(Refusal::Kind::kInvalid, samples.error().message);
  }
  nlohmann::json j = to_json(*samples);
  j["run_id"] = id;
  j["max_points"] = query.max_points;
  return Reply::ok(std::move(j));
}

Reply StationQueries::duts() {
  std::lock_guard lock(mu_);
  auto out = duts_json(db_);
  if (!out) return db_failure(out.error());
  return Reply::ok(std::move(*out));
}

Reply StationQueries::dut_history(const std::string& serial) {
  std::lock_guard lock(mu_);
  auto dut = db_.dut(serial);
  if (!dut) return db_failure(dut.error());
  if (!*dut) {
    return Reply::refused(
        Refusal::Kind::kNotFound,
        fmt::format("no DUT with serial '{}' (GET /api/v1/duts lists them)", serial));
  }
  auto history = dut_history_json(db_, serial);
  if (!history) return db_failure(history.error());
  return Reply::ok(std::move(*history));
}

}  // namespace gyrotherm::station

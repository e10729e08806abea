#include "export.h"

#include <fmt/format.h>

#include <CLI/CLI.hpp>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>

#include "analysis.h"
#include "control.h"
#include "gyrotherm/calibration/exporter.h"
#include "gyrotherm/core/clock.h"
#include "gyrotherm/schedules/sequencer.h"
#include "gyrotherm/storage/database.h"
#include "output.h"

namespace gyrotherm::cli {

namespace {

constexpr std::string_view kWho = "gyrotherm export";

}  // namespace

struct ExportCommand::Parsed {
  CLI::App* command = nullptr;
  std::string db_path, config_path, out_dir;
  std::optional<std::string> since, runs;
  bool json = false;
  bool force = false;
};

ExportCommand::ExportCommand(CLI::App& app) : parsed_(std::make_unique<Parsed>()) {
  Parsed& p = *parsed_;
  p.command = app.add_subcommand(
      "export",
      "write the calibration reports of stored runs (HTML, CSV, coefficients as JSON and C "
      "header) into a new directory, and record the export in the database");
  auto* db = p.command->add_option("--db", p.db_path, "station database");
  auto* config = p.command->add_option(
      "--config", p.config_path, "station config: its [storage] db is the database (or --db)");
  db->excludes(config);
  p.command->add_option("--out", p.out_dir, "output directory (must not exist, or be empty)")
      ->required();
  auto* since =
      p.command->add_option("--since", p.since,
                            "completed runs that ended at or after DATE (ISO-8601; UTC unless an "
                            "offset is given), e.g. 2026-11-20 or 2026-11-20T18:00+01:00");
  auto* runs = p.command->add_option("--runs", p.runs, "these runs, e.g. 3,5-7");
  since->excludes(runs);
  p.command->add_flag("--json", p.json, "machine-readable output");
  p.command->add_flag(
      "--force", p.force,
      "write the C headers of flagged results too (docs/analysis.md \"Result quality\"), each "
      "marked as forced with the reasons; without it they are left out and listed as problems");
}

ExportCommand::~ExportCommand() = default;

std::optional<int> ExportCommand::run(bool json) {
  Parsed& p = *parsed_;
  if (!*p.command) return std::nullopt;
  json = json || p.json;
  {
    auto db = choose_database(p.db_path, p.config_path);
    if (!db) return fail(db.error().message, kExitInput, kWho);
    if (!db->given) return fail("give --db FILE or --config FILE (the station database)", 2, kWho);
    p.db_path = db->path;
  }
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::exists(p.db_path, ec))
    return fail(fmt::format("{}: no such database", p.db_path), 2, kWho);
  auto db = storage::Database::open(p.db_path);
  if (!db) return fail(db.error().message, kExitInput, kWho);

  auto all = db->runs();
  if (!all) return fail(all.error().message, kExitFailed, kWho);
  std::vector<int64_t> ids;
  std::string what;
  if (p.runs) {
    auto list = parse_run_list(*p.runs);
    if (!list) return fail(fmt::format("--runs: {}", list.error().message), kExitInput, kWho);
    for (int64_t id : *list) {
      const auto it = std::find_if(all->begin(), all->end(),
                                   [id](const storage::RunRecord& r) { return r.id == id; });
      if (it == all->end()) {
        return fail(fmt::format("--runs: run {} is not in {}", id, p.db_path), kExitInput, kWho);
      }
      const auto state = schedules::parse_run_state(it->state);
      if (!state || !schedules::is_terminal(*state)) {
        return fail(fmt::format("--runs: run {} has not ended (state {}); export it once it has",
                                id, it->state),
                    kExitInput, kWho);
      }
    }
    ids = *list;
    std::sort(ids.begin(), ids.end());
    what = fmt::format("runs {}", *p.runs);
  } else if (p.since) {
    auto since = parse_utc_iso(*p.since);
    if (!since) return fail(fmt::format("--since: {}", since.error().message), kExitInput, kWho);
    for (const auto& r : *all) {
      if (r.state != "completed" || r.ended_utc.empty()) continue;
      auto ended = parse_utc_iso(r.ended_utc);
      if (ended && *ended >= *since) ids.push_back(r.id);
    }
    what = fmt::format("completed runs that ended since {}", utc_iso(*since));
  } else {
    auto pending = db->runs_not_exported();
    if (!pending) return fail(pending.error().message, kExitFailed, kWho);
    ids = *pending;
    what = "completed runs not yet in a nightly export";
  }
  if (ids.empty()) {
    if (json) {
      std::cout << nlohmann::json({{"export_id", nullptr}, {"runs", ids}, {"files", {}}}).dump(2)
                << "\n";
    } else {
      std::cout << fmt::format("nothing to export: no {}\n", what);
    }
    return 0;
  }
  if (fs::exists(p.out_dir, ec) &&
      (!fs::is_directory(p.out_dir, ec) || !fs::is_empty(p.out_dir, ec))) {
    return fail(
        fmt::format("--out {}: exists and is not an empty directory; give a new one", p.out_dir),
        kExitInput, kWho);
  }

  calibration::ExportRequest request;
  request.kind = "manual";
  request.run_ids = ids;
  request.directory = fs::absolute(p.out_dir, ec).lexically_normal().string();
  request.report.export_label = fmt::format("on demand (gyrotherm export), {}", what);
  request.report.force_flagged = p.force;
  auto out = calibration::write_export(*db, request);
  if (!out) return fail(out.error().message, kExitFailed, kWho);
  if (json) {
    std::cout << nlohmann::json({{"export_id", out->export_id},
                                 {"directory", out->directory},
                                 {"index", (fs::path(out->directory) / "index.html").string()},
                                 {"runs", ids},
                                 {"files", out->files},
                                 {"problems", out->problems}})
                     .dump(2)
              << "\n";
    return 0;
  }
  std::cout << fmt::format("export {}: {} run{} ({}), {} files in {}\n", out->export_id, ids.size(),
                           ids.size() == 1 ? "" : "s", fmt::join(ids, ", "), out->files.size(),
                           out->directory);
  std::cout << fmt::format("summary: {}\n", (fs::path(out->directory) / "index.html").string());
  for (int64_t id : ids) {
    std::cout << fmt::format(
        "run {}:  {}\n", id,
        (fs::path(out->directory) / fmt::format("run-{:04}", id) / "report.html").string());
  }
  for (const auto& problem : out->problems) std::cout << "problem: " << problem << "\n";
  return 0;
}

}  // namespace gyrotherm::cli

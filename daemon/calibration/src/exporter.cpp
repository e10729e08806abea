#include "gyrotherm/calibration/exporter.h"

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <stdlib.h>
#include <sys/stat.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <set>

#include "gyrotherm/core/files.h"

namespace gyrotherm::calibration {

namespace fs = std::filesystem;

namespace {

constexpr const char* kSinceKey = "nightly_export_since_unix_s";

std::tm local_tm(double unix_s, const config::TimeZone& zone) {
  const auto local_s = static_cast<std::time_t>(std::floor(unix_s) + zone.offset_s(unix_s));
  std::tm tm{};
  gmtime_r(&local_s, &tm);
  return tm;
}

// Every regular file under `dir`, relative to it, sorted.
std::vector<std::string> list_files(const fs::path& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(dir, ec);
       !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    if (it->is_regular_file(ec)) out.push_back(fs::relative(it->path(), dir, ec).string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Renders every file of the export into a fresh hidden directory beside
// `target`, then renames it to `target`.
Status write_files(const fs::path& target, const std::vector<ReportFile>& files) {
  std::error_code ec;
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  fs::create_directories(parent, ec);
  if (ec) {
    return Error::Permanent(
        fmt::format("cannot create the directory {}: {}", parent.string(), ec.message()));
  }
  if (fs::exists(target, ec)) {
    if (!fs::is_directory(target, ec) || !fs::is_empty(target, ec)) {
      return Error::Permanent(
          fmt::format("{} exists and is not an empty directory; choose another output directory",
                      target.string()));
    }
  }
  std::string tmpl =
      (parent / fmt::format(".{}.partial-XXXXXX", target.filename().string())).string();
  if (::mkdtemp(tmpl.data()) == nullptr) {
    return Error::Permanent(fmt::format("cannot create a temporary directory in {}: {}",
                                        parent.string(), std::strerror(errno)));
  }
  const fs::path partial(tmpl);
  // The temporary directory is gone once this returns: errors name the
  // export's directory, and its files by their place in it.
  const auto give_up = [&partial, &target](Error e) {
    std::error_code ignored;
    fs::remove_all(partial, ignored);
    e.message = fmt::format("cannot write the export {}: {}", target.string(), e.message);
    return e;
  };
  const auto in_target = [&partial, &target](Error e) {
    const std::string from = partial.string(), to = target.string();
    for (auto at = e.message.find(from); at != std::string::npos;
         at = e.message.find(from, at + to.size())) {
      e.message.replace(at, from.size(), to);
    }
    return e;
  };
  for (const auto& f : files) {
    const fs::path path = partial / f.path;
    fs::create_directories(path.parent_path(), ec);
    if (ec) {
      return give_up(in_target(Error::Permanent(fmt::format(
          "cannot create the directory {}: {}", path.parent_path().string(), ec.message()))));
    }
    if (Status st = write_file_atomically(path.string(), f.content); !st) {
      return give_up(in_target(st.error()));
    }
  }
  ::chmod(partial.c_str(), 0755);
  if (fs::exists(target, ec)) fs::remove(target, ec);  // checked empty above
  if (Status st = rename_directory_durably(partial.string(), target.string()); !st) {
    return give_up(st.error());
  }
  return Status::Ok();
}

}  // namespace

std::string local_time_label(double unix_s, const config::TimeZone& zone) {
  const std::tm tm = local_tm(unix_s, zone);
  const int offset_s = zone.offset_s(unix_s);
  const int a = std::abs(offset_s);
  return fmt::format("{:04}-{:02}-{:02} {:02}:{:02} UTC{}{:02}:{:02}", tm.tm_year + 1900,
                     tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, offset_s < 0 ? '-' : '+',
                     a / 3600, a % 3600 / 60);
}

std::string nightly_directory(const std::string& root, double slot_unix_s,
                              const config::TimeZone& zone) {
  const std::tm tm = local_tm(slot_unix_s, zone);
  const std::string date =
      fmt::format("{:04}-{:02}-{:02}", tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday);
  fs::path dir = fs::path(root) / date;
  std::error_code ec;
  for (int k = 2; fs::exists(dir, ec); ++k) dir = fs::path(root) / fmt::format("{}-{}", date, k);
  return dir.string();
}

namespace {

// The files of export `id` (recorded, state "writing"), then its record done
// or failed.
Result<ExportOutcome> complete_export(storage::Database& db, int64_t id,
                                      const ExportRequest& request) {
  ExportOutcome out;
  out.export_id = id;
  out.directory = request.directory;
  const auto fail = [&](const Error& e) -> Error {
    if (Status st = db.finish_export(id, "failed", {}, e.message); !st) {
      spdlog::error("export {}: cannot record the failure: {}", id, st.error().message);
    }
    return e;
  };
  if (request.run_ids.empty()) {
    if (Status st = db.finish_export(id, "done", {}, "no run completed since the last export");
        !st) {
      return st.error();
    }
    return out;
  }

  ReportOptions options = request.report;
  if (options.generated_utc.empty()) options.generated_utc = wall_time_utc_iso();
  if (options.database_path.empty()) options.database_path = db.path();
  // Every DUT axis of every run: a report each, a summary per DUT axis.
  std::vector<std::vector<RunReport>> runs;
  for (int64_t run_id : request.run_ids) {
    auto r = collect_run_reports(db, run_id, options);
    if (!r) return fail(Error::Permanent(fmt::format("run {}: {}", run_id, r.error().message)));
    runs.push_back(std::move(*r));
  }
  const std::vector<ReportFile> files = render_export_files(runs, options, out.problems);

  if (Status st = write_files(request.directory, files); !st) return fail(st.error());
  for (const auto& f : files) out.files.push_back(f.path);
  std::sort(out.files.begin(), out.files.end());
  const std::string message =
      out.problems.empty()
          ? fmt::format("{} run{}, {} files", request.run_ids.size(),
                        request.run_ids.size() == 1 ? "" : "s", out.files.size())
          : fmt::format("{} run{}, {} files; {} problem{} (see the report)", request.run_ids.size(),
                        request.run_ids.size() == 1 ? "" : "s", out.files.size(),
                        out.problems.size(), out.problems.size() == 1 ? "" : "s");
  if (Status st = db.finish_export(id, "done", out.files, message); !st) return st.error();
  return out;
}

}  // namespace

Result<ExportOutcome> write_export(storage::Database& db, const ExportRequest& given) {
  // "DIR/" and "DIR/." name DIR: the temporary directory goes beside it.
  ExportRequest request = given;
  fs::path target = fs::path(request.directory).lexically_normal();
  while (!target.empty() && !target.has_filename() && target != target.root_path()) {
    target = target.parent_path();
  }
  if (target.empty() || target == target.root_path()) {
    return Error::Permanent(fmt::format("\"{}\" cannot be an export directory", given.directory));
  }
  request.directory = target.string();
  // A directory in the way is refused before anything is recorded.
  std::error_code ec;
  if (!request.run_ids.empty() && fs::exists(request.directory, ec) &&
      (!fs::is_directory(request.directory, ec) || !fs::is_empty(request.directory, ec))) {
    return Error::Permanent(
        fmt::format("{} exists and is not an empty directory; choose another output directory",
                    request.directory));
  }
  storage::ExportRecord rec;
  rec.kind = request.kind;
  rec.slot_unix_s = request.slot_unix_s;
  rec.slot_local = request.slot_local;
  rec.directory = request.directory;
  rec.run_ids = request.run_ids;
  auto id = db.begin_export(rec);
  if (!id) return id.error();
  return complete_export(db, *id, request);
}

// ------------------------------------------------------------ NightlyExporter

bool NightlyOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (at.hour < 0 || at.hour > 23 || at.minute < 0 || at.minute > 59) {
    return fail(
        fmt::format("at = {:02}:{:02} is not a time of day (00:00 … 23:59)", at.hour, at.minute));
  }
  if (directory.empty()) return fail("directory is empty (the root the exports go into)");
  // The thread sleeps poll_wall_s between looks: 0 would spin.
  if (!(poll_wall_s > 0) || !std::isfinite(poll_wall_s)) {
    return fail(fmt::format("poll_wall_s = {} must be finite and > 0", poll_wall_s));
  }
  return true;
}

Result<std::unique_ptr<NightlyExporter>> NightlyExporter::create(
    std::string db_path, const WallClock& clock, NightlyOptions options,
    std::function<void()> before_export, Done done) {
  if (std::string why; !options.is_valid(&why)) {
    return Error::Permanent("invalid nightly export options: " + why);
  }
  return std::unique_ptr<NightlyExporter>(new NightlyExporter(
      std::move(db_path), clock, std::move(options), std::move(before_export), std::move(done)));
}

NightlyExporter::NightlyExporter(std::string db_path, const WallClock& clock,
                                 NightlyOptions options, std::function<void()> before_export,
                                 Done done)
    : db_path_(std::move(db_path)),
      clock_(clock),
      options_(std::move(options)),
      before_export_(std::move(before_export)),
      done_(std::move(done)) {}

NightlyExporter::~NightlyExporter() { stop(); }

Result<storage::Database*> NightlyExporter::database() {
  if (!db_) {
    auto db = storage::Database::open(db_path_);
    if (!db) return db.error();
    db_.emplace(std::move(*db));
  }
  return &*db_;
}

double NightlyExporter::next_slot_unix_s() const {
  return config::next_slot_unix_s(clock_.unix_now_s(), options_.at, options_.zone);
}

Status NightlyExporter::finish_interrupted(storage::Database& db) {
  auto exports = db.exports();
  if (!exports) return exports.error();
  for (const auto& e : *exports) {
    if (e.state != "writing" || e.kind != "nightly") continue;
    std::error_code ec;
    if (fs::is_directory(e.directory, ec)) {
      // Renamed into place before the crash: only the record was missing.
      ExportOutcome outcome;
      outcome.export_id = e.id;
      outcome.directory = e.directory;
      outcome.files = list_files(e.directory);
      if (Status st = db.finish_export(e.id, "done", outcome.files, "finished after a restart");
          !st) {
        return st;
      }
      if (done_) done_(db, Result<ExportOutcome>(std::move(outcome)));
      continue;
    }
    // Not written: write it now, same record, same runs, same directory
    // (a temporary directory the crash left is hidden and ignored).
    spdlog::warn("nightly export {} ({}) was interrupted; writing it again", e.id, e.slot_local);
    if (before_export_) before_export_();
    ExportRequest request;
    request.kind = e.kind;
    request.slot_unix_s = e.slot_unix_s;
    request.slot_local = e.slot_local;
    request.run_ids = e.run_ids;
    request.directory = e.directory;
    request.report = options_.report;
    request.report.export_label = "nightly export of " + e.slot_local;
    auto outcome = complete_export(db, e.id, request);
    if (done_) done_(db, outcome);
    if (!outcome && outcome.error().transient) return outcome.error();
  }
  return Status::Ok();
}

Result<std::optional<ExportOutcome>> NightlyExporter::poll() {
  auto db = database();
  if (!db) return db.error();
  storage::Database& d = **db;
  if (!recovered_) {  // a "writing" record is a crash of an earlier process: once per start
    if (Status st = finish_interrupted(d); !st) return st.error();
    recovered_ = true;
  }

  const double now = clock_.unix_now_s();
  auto last = d.last_nightly_slot_unix_s();
  if (!last) return last.error();
  double since = now;
  if (!*last) {
    // Never exported: slots count from the first start with this feature.
    auto stored = d.meta(kSinceKey);
    if (!stored) return stored.error();
    if (*stored) {
      since = std::strtod((*stored)->c_str(), nullptr);
    } else if (Status st = d.set_meta(kSinceKey, fmt::format("{:.3f}", now)); !st) {
      return st.error();
    }
  }
  const auto slot = config::due_slot_unix_s(*last, since, now, options_.at, options_.zone);
  if (!slot) return std::optional<ExportOutcome>();

  if (before_export_) before_export_();
  auto runs = d.runs_not_exported();
  if (!runs) return runs.error();
  ExportRequest request;
  request.kind = "nightly";
  request.slot_unix_s = *slot;
  request.slot_local = local_time_label(*slot, options_.zone);
  request.run_ids = *runs;
  request.directory = nightly_directory(options_.directory, *slot, options_.zone);
  request.report = options_.report;
  request.report.export_label = "nightly export of " + request.slot_local;
  auto outcome = write_export(d, request);
  if (done_) done_(d, outcome);
  if (!outcome) return outcome.error();
  return std::optional<ExportOutcome>(std::move(*outcome));
}

void NightlyExporter::start() {
  std::lock_guard lock(mu_);
  if (thread_.joinable()) return;
  stop_ = false;
  thread_ = std::thread([this] {
    std::unique_lock lock(mu_);
    while (!stop_) {
      lock.unlock();
      // After a failure (say the database is locked), look again in a
      // minute rather than logging the same error every poll.
      double wait_s = options_.poll_wall_s;
      if (auto r = poll(); !r) {
        spdlog::error("nightly export: {} (next attempt in a minute)", r.error().message);
        wait_s = std::max(wait_s, 60.0);
      } else if (*r) {
        spdlog::info("nightly export {}: {} ({} files)", (*r)->export_id, (*r)->directory,
                     (*r)->files.size());
      }
      lock.lock();
      cv_.wait_for(lock, std::chrono::duration<double>(wait_s), [this] { return stop_; });
    }
  });
}

void NightlyExporter::stop() {
  {
    std::lock_guard lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

}  // namespace gyrotherm::calibration

// RunStore (runs.h): runs, crash-resume checkpoints and segments, and run
// metadata (schema v8; docs/storage.md "Run metadata"): who ran a run, why, its
// tags and declared DUT serials, stored on the queue entry and copied into the
// run it starts; edits afterwards leave an event.
#include "gyrotherm/storage/runs.h"

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <sqlite3.h>

#include <boost/uuid/uuid.hpp>
#include <boost/uuid/uuid_generators.hpp>
#include <boost/uuid/uuid_io.hpp>
#include <nlohmann/json.hpp>
#include <utility>

#include "duts_internal.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage {

using internal::expect_done;
using internal::sqlite_error;
using internal::Stmt;
using internal::Transaction;

namespace internal {

Status check_metadata(const RunMetadata& md, const std::string& path, std::string_view what) {
  const auto empty_in = [&](const char* field, const std::vector<std::string>& values) {
    for (std::size_t i = 0; i < values.size(); ++i) {
      if (values[i].empty()) {
        return Status(Error::Permanent(
            fmt::format("storage: {}: {}: metadata {}[{}] is empty", path, what, field, i)));
      }
    }
    return Status::Ok();
  };
  if (Status s = empty_in("tags", md.tags); !s) return s;
  return empty_in("dut_serials", md.dut_serials);
}

void bind_metadata(Stmt& st, int first, const RunMetadata& md) {
  st.bind(first, std::string_view(md.operator_name));
  st.bind(first + 1, std::string_view(md.comment));
  st.bind(first + 2, std::string_view(strings_json(md.tags)));
  st.bind(first + 3, std::string_view(strings_json(md.dut_serials)));
}

Result<RunMetadata> read_metadata(const Stmt& st, int first, const std::string& where) {
  RunMetadata md;
  md.operator_name = st.column_text(first);
  md.comment = st.column_text(first + 1);
  auto tags = strings_from_json(st.column_text(first + 2), where + ": tags_json");
  if (!tags) return tags.error();
  md.tags = std::move(*tags);
  auto serials = strings_from_json(st.column_text(first + 3), where + ": dut_serials_json");
  if (!serials) return serials.error();
  md.dut_serials = std::move(*serials);
  return md;
}

}  // namespace internal

namespace {

constexpr const char* kRunColumns =
    "id, schedule_name, state, started_utc, ended_utc, time_scale, latitude_deg, orientation, "
    "config_json, queue_id, schedule_id, resume_json, checkpoint_wall_unix_s, config_toml, "
    "operator, comment, tags_json, dut_serials_json, uuid";

Result<RunRecord> read_run(const Stmt& st, const std::string& path) {
  RunRecord r;
  r.id = st.column_int64(0);
  r.schedule_name = st.column_text(1);
  r.state = st.column_text(2);
  r.started_utc = st.column_text(3);
  r.ended_utc = st.column_text(4);
  r.time_scale = st.column_double(5);
  r.latitude_deg = st.column_double(6);
  r.orientation = st.column_text(7);
  r.config_json = st.column_text(8);
  r.queue_id = st.column_optional_int64(9);
  r.schedule_id = st.column_optional_int64(10);
  r.resume_json = st.column_text(11);
  r.checkpoint_wall_unix_s = st.column_optional_double(12);
  r.config_toml = st.column_text(13);
  auto metadata = internal::read_metadata(st, 14, fmt::format("storage: {}: run {}", path, r.id));
  if (!metadata) return metadata.error();
  r.metadata = std::move(*metadata);
  r.uuid = st.column_text(18);
  return r;
}

// A random (version 4) UUID in the RFC 4122 text form, lower case.
Result<std::string> random_uuid(const std::string& path) {
  try {
    boost::uuids::random_generator generate;  // the kernel's entropy (getrandom)
    return boost::uuids::to_string(generate());
  } catch (const std::exception& e) {
    return Error::Transient(fmt::format("storage: {}: making a run uuid: {}", path, e.what()));
  }
}

// xxxxxxxx-xxxx-xxxx-xxxx-xxxxxxxxxxxx, lower-case hex digits.
bool is_uuid_text(std::string_view s) {
  if (s.size() != 36) return false;
  for (std::size_t i = 0; i < s.size(); ++i) {
    const char c = s[i];
    if (i == 8 || i == 13 || i == 18 || i == 23) {
      if (c != '-') return false;
    } else if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) {
      return false;
    }
  }
  return true;
}

constexpr const char* kSegmentColumns =
    "id, run_id, idx, kind, label, setpoint_c, ramp_rate_c_per_min, t_start_s, t_settled_s, "
    "t_acquire_start_s, t_acquire_end_s, t_end_s, paused_s, state, table_mode, table_rate_dps, "
    "table_position_deg, table_mean_rate_dps, table_mean_position_deg, turns, dwell_s, "
    "sf_sequence, sf_repetition, acquire_stop";

SegmentRecord read_segment(const Stmt& st) {
  SegmentRecord s;
  s.id = st.column_int64(0);
  s.run_id = st.column_int64(1);
  s.index = static_cast<int>(st.column_int64(2));
  s.kind = st.column_text(3);
  s.label = st.column_text(4);
  s.setpoint_c = st.column_double(5);
  s.ramp_rate_c_per_min = st.column_double(6);
  s.t_start_s = st.column_double(7);
  s.t_settled_s = st.column_optional_double(8);
  s.t_acquire_start_s = st.column_optional_double(9);
  s.t_acquire_end_s = st.column_optional_double(10);
  s.t_end_s = st.column_optional_double(11);
  s.paused_s = st.column_double(12);
  s.state = st.column_text(13);
  s.table_mode = st.column_text(14);
  s.table_rate_dps = st.column_optional_double(15);
  s.table_position_deg = st.column_optional_double(16);
  s.table_mean_rate_dps = st.column_optional_double(17);
  s.table_mean_position_deg = st.column_optional_double(18);
  s.turns = static_cast<int>(st.column_int64(19));
  s.dwell_s = st.column_double(20);
  s.sf_sequence = static_cast<int>(st.column_int64(21));
  s.sf_repetition = static_cast<int>(st.column_int64(22));
  s.acquire_stop = st.column_text(23);
  return s;
}

// Binds the segment's fields from parameter `first` on, in kSegmentColumns
// order without id.
void bind_segment(Stmt& st, const SegmentRecord& s, int first) {
  int i = first;
  st.bind(i++, s.run_id);
  st.bind(i++, s.index);
  st.bind(i++, std::string_view(s.kind));
  st.bind(i++, std::string_view(s.label));
  st.bind(i++, s.setpoint_c);
  st.bind(i++, s.ramp_rate_c_per_min);
  st.bind(i++, s.t_start_s);
  st.bind(i++, s.t_settled_s);
  st.bind(i++, s.t_acquire_start_s);
  st.bind(i++, s.t_acquire_end_s);
  st.bind(i++, s.t_end_s);
  st.bind(i++, s.paused_s);
  st.bind(i++, std::string_view(s.state));
  st.bind(i++, std::string_view(s.table_mode));
  st.bind(i++, s.table_rate_dps);
  st.bind(i++, s.table_position_deg);
  st.bind(i++, s.table_mean_rate_dps);
  st.bind(i++, s.table_mean_position_deg);
  st.bind(i++, s.turns);
  st.bind(i++, s.dwell_s);
  st.bind(i++, s.sf_sequence);
  st.bind(i++, s.sf_repetition);
  st.bind(i++, std::string_view(s.acquire_stop));
}
constexpr int kSegmentBoundColumns = 23;  // bind_segment's parameters

// '...' with the text as JSON would quote it (newlines and quotes escaped),
// so a message stays one line whatever a comment holds.
std::string quoted(const std::string& text) { return nlohmann::json(text).dump(); }

std::string listed(const std::vector<std::string>& values) {
  std::vector<std::string> q;
  for (const auto& v : values) q.push_back(quoted(v));
  return fmt::format("[{}]", fmt::join(q, ", "));
}

}  // namespace

Database& RunStore::self() { return static_cast<Database&>(*this); }
sqlite3* RunStore::db() { return self().db_; }
const std::string& RunStore::path() { return self().path_; }

Result<int64_t> RunStore::create_run(const RunRecord& run) {
  if (Status s = internal::check_metadata(run.metadata, path(), "creating a run"); !s) {
    return s.error();
  }
  std::string uuid = run.uuid;
  if (uuid.empty()) {
    auto made = random_uuid(path());
    if (!made) return made.error();
    uuid = std::move(*made);
  } else if (!is_uuid_text(uuid)) {
    return Error::Permanent(
        fmt::format("storage: {}: creating a run: uuid '{}' is not a UUID in lower-case text "
                    "form (xxxxxxxx-xxxx-xxxx-xxxx-xxxxxxxxxxxx)",
                    path(), uuid));
  }
  auto st = Stmt::prepare(db(), path(),
                          "INSERT INTO runs(schedule_name, state, started_utc, ended_utc, "
                          "time_scale, latitude_deg, orientation, config_json, queue_id, "
                          "schedule_id, config_toml, operator, comment, tags_json, "
                          "dut_serials_json, uuid) VALUES(?, ?, ?, NULL, ?, ?, ?, ?, ?, ?, ?, ?, "
                          "?, ?, ?, ?)");
  if (!st) return st.error();
  st->bind(1, std::string_view(run.schedule_name));
  st->bind(2, std::string_view(run.state));
  st->bind(3, std::string_view(self().utc_or_now(run.started_utc)));
  st->bind(4, run.time_scale);
  st->bind(5, run.latitude_deg);
  st->bind(6, std::string_view(run.orientation));
  st->bind_text_or_null(7, run.config_json);
  st->bind(8, run.queue_id);
  st->bind(9, run.schedule_id);
  st->bind_text_or_null(10, run.config_toml);
  internal::bind_metadata(*st, 11, run.metadata);
  st->bind(15, std::string_view(uuid));
  if (Status s = expect_done(*st, db(), path(), "creating a run"); !s) return s.error();
  return static_cast<int64_t>(sqlite3_last_insert_rowid(db()));
}

Status RunStore::set_run_state(int64_t run_id, std::string_view state, bool ended) {
  auto st = Stmt::prepare(db(), path(), "UPDATE runs SET state = ?, ended_utc = ? WHERE id = ?");
  if (!st) return st.error();
  st->bind(1, state);
  if (ended) {
    st->bind(2, std::string_view(self().utc_now()));
  } else {
    st->bind_null(2);
  }
  st->bind(3, run_id);
  const std::string what = fmt::format("setting run {} state to '{}'", run_id, state);
  if (Status s = expect_done(*st, db(), path(), what); !s) return s;
  if (sqlite3_changes(db()) == 0) {
    return Error::Permanent(fmt::format("storage: {}: {}: no such run", path(), what));
  }
  return Status::Ok();
}

Result<std::vector<RunRecord>> RunStore::runs() {
  auto st =
      Stmt::prepare(db(), path(), fmt::format("SELECT {} FROM runs ORDER BY id", kRunColumns));
  if (!st) return st.error();
  std::vector<RunRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) {
    auto run = read_run(*st, path());
    if (!run) return run.error();
    out.push_back(std::move(*run));
  }
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), "reading runs");
  return out;
}

Result<RunRecord> RunStore::run(int64_t run_id) {
  auto st =
      Stmt::prepare(db(), path(), fmt::format("SELECT {} FROM runs WHERE id = ?", kRunColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  const int rc = st->step();
  if (rc == SQLITE_ROW) return read_run(*st, path());
  if (rc == SQLITE_DONE) {
    return Error::Permanent(fmt::format("storage: {}: no run with id {}", path(), run_id));
  }
  return sqlite_error(db(), path(), fmt::format("reading run {}", run_id));
}

Status RunStore::set_run_metadata(int64_t run_id, const RunMetadata& md,
                                  std::string_view changed_by) {
  const std::string what = fmt::format("editing the metadata of run {}", run_id);
  if (Status s = internal::check_metadata(md, path(), what); !s) return s;
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s;
  auto old = run(run_id);  // under the write lock: no edit in between
  if (!old) return old.error();
  const RunMetadata& was = old->metadata;

  std::vector<std::string> changes;
  if (was.operator_name != md.operator_name) {
    changes.push_back(
        fmt::format("operator {} -> {}", quoted(was.operator_name), quoted(md.operator_name)));
  }
  if (was.comment != md.comment) {
    changes.push_back(fmt::format("comment {} -> {}", quoted(was.comment), quoted(md.comment)));
  }
  if (was.tags != md.tags) {
    changes.push_back(fmt::format("tags {} -> {}", listed(was.tags), listed(md.tags)));
  }
  if (was.dut_serials != md.dut_serials) {
    changes.push_back(
        fmt::format("duts {} -> {}", listed(was.dut_serials), listed(md.dut_serials)));
  }
  if (changes.empty()) return Status::Ok();  // nothing to record

  auto st = Stmt::prepare(db(), path(),
                          "UPDATE runs SET operator = ?, comment = ?, tags_json = ?, "
                          "dut_serials_json = ? WHERE id = ?");
  if (!st) return st.error();
  internal::bind_metadata(*st, 1, md);
  st->bind(5, run_id);
  if (Status s = expect_done(*st, db(), path(), what); !s) return s;

  // The edit is filed after the run's latest event (t_s), so a time-ordered
  // event list shows it last; its wall_utc says when it happened.
  auto last =
      Stmt::prepare(db(), path(), "SELECT coalesce(max(t_s), 0) FROM events WHERE run_id = ?");
  if (!last) return last.error();
  last->bind(1, run_id);
  if (last->step() != SQLITE_ROW) return sqlite_error(db(), path(), what);
  EventRecord e;
  e.run_id = run_id;
  e.t_s = last->column_double(0);
  last->reset();
  e.kind = "metadata";
  e.message = fmt::format("metadata changed by {}: {}", changed_by.empty() ? "?" : changed_by,
                          fmt::join(changes, "; "));
  if (auto id = self().add_event(e); !id) return id.error();
  return tx.commit();
}

Status RunStore::set_run_checkpoint(int64_t run_id, std::string_view resume_json,
                                    double wall_unix_s) {
  auto st = Stmt::prepare(
      db(), path(), "UPDATE runs SET resume_json = ?, checkpoint_wall_unix_s = ? WHERE id = ?");
  if (!st) return st.error();
  st->bind(1, resume_json);
  st->bind(2, wall_unix_s);
  st->bind(3, run_id);
  return expect_done(*st, db(), path(), fmt::format("checkpointing run {}", run_id));
}

Result<int64_t> RunStore::create_segment(const SegmentRecord& segment) {
  auto st = Stmt::prepare(db(), path(),
                          "INSERT INTO segments(run_id, idx, kind, label, setpoint_c, "
                          "ramp_rate_c_per_min, t_start_s, t_settled_s, t_acquire_start_s, "
                          "t_acquire_end_s, t_end_s, paused_s, state, table_mode, "
                          "table_rate_dps, table_position_deg, table_mean_rate_dps, "
                          "table_mean_position_deg, turns, dwell_s, sf_sequence, sf_repetition, "
                          "acquire_stop) "
                          "VALUES(?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, "
                          "?, ?)");
  if (!st) return st.error();
  bind_segment(*st, segment, 1);
  if (Status s =
          expect_done(*st, db(), path(),
                      fmt::format("creating segment {} of run {}", segment.index, segment.run_id));
      !s) {
    return s.error();
  }
  return static_cast<int64_t>(sqlite3_last_insert_rowid(db()));
}

Status RunStore::update_segment(const SegmentRecord& segment) {
  Transaction tx(db(), path());
  if (Status s = tx.begin_immediate(); !s) return s;
  auto st = Stmt::prepare(db(), path(),
                          "UPDATE segments SET run_id = ?, idx = ?, kind = ?, label = ?, "
                          "setpoint_c = ?, ramp_rate_c_per_min = ?, t_start_s = ?, "
                          "t_settled_s = ?, t_acquire_start_s = ?, t_acquire_end_s = ?, "
                          "t_end_s = ?, paused_s = ?, state = ?, table_mode = ?, "
                          "table_rate_dps = ?, table_position_deg = ?, table_mean_rate_dps = ?, "
                          "table_mean_position_deg = ?, turns = ?, dwell_s = ?, sf_sequence = ?, "
                          "sf_repetition = ?, acquire_stop = ? WHERE id = ?");
  if (!st) return st.error();
  bind_segment(*st, segment, 1);
  st->bind(kSegmentBoundColumns + 1, segment.id);
  const std::string what = fmt::format("updating segment {}", segment.id);
  if (Status s = expect_done(*st, db(), path(), what); !s) return s;
  if (sqlite3_changes(db()) == 0) {
    return Error::Permanent(fmt::format("storage: {}: {}: no such segment", path(), what));
  }
  auto del = Stmt::prepare(db(), path(), "DELETE FROM acquisition_windows WHERE segment_id = ?");
  if (!del) return del.error();
  del->bind(1, segment.id);
  if (Status s = expect_done(*del, db(), path(), what); !s) return s;
  auto ins = Stmt::prepare(db(), path(),
                           "INSERT OR REPLACE INTO acquisition_windows(segment_id, run_id, "
                           "t_from_s, t_to_s) VALUES(?, ?, ?, ?)");
  if (!ins) return ins.error();
  for (const auto& [from_s, to_s] : segment.windows) {
    ins->reset();
    ins->bind(1, segment.id);
    ins->bind(2, segment.run_id);
    ins->bind(3, from_s);
    ins->bind(4, to_s);
    if (Status s = expect_done(*ins, db(), path(), what); !s) return s;
  }
  return tx.commit();
}

Result<std::vector<SegmentRecord>> RunStore::segments(int64_t run_id) {
  auto st = Stmt::prepare(
      db(), path(),
      fmt::format("SELECT {} FROM segments WHERE run_id = ? ORDER BY idx, id", kSegmentColumns));
  if (!st) return st.error();
  st->bind(1, run_id);
  std::vector<SegmentRecord> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) out.push_back(read_segment(*st));
  if (rc != SQLITE_DONE) {
    return sqlite_error(db(), path(), fmt::format("reading segments of run {}", run_id));
  }
  auto win = Stmt::prepare(db(), path(),
                           "SELECT t_from_s, t_to_s FROM acquisition_windows WHERE segment_id = ? "
                           "ORDER BY t_from_s");
  if (!win) return win.error();
  for (auto& seg : out) {
    win->reset();
    win->bind(1, seg.id);
    while ((rc = win->step()) == SQLITE_ROW) {
      seg.windows.emplace_back(win->column_double(0), win->column_double(1));
    }
    if (rc != SQLITE_DONE) {
      return sqlite_error(db(), path(), fmt::format("reading windows of segment {}", seg.id));
    }
  }
  return out;
}

Result<std::vector<double>> RunStore::recent_settles_s(int limit) {
  auto st = Stmt::prepare(db(), path(),
                          "SELECT t_settled_s - t_start_s FROM segments WHERE kind = 'soak' AND "
                          "t_settled_s IS NOT NULL AND paused_s = 0 ORDER BY id DESC LIMIT ?");
  if (!st) return st.error();
  st->bind(1, static_cast<int64_t>(limit));
  std::vector<double> out;
  int rc;
  while ((rc = st->step()) == SQLITE_ROW) out.push_back(st->column_double(0));
  if (rc != SQLITE_DONE) return sqlite_error(db(), path(), "reading the soaks' settle times");
  return out;
}

}  // namespace gyrotherm::storage

// Database: run metadata (schema v8; docs/storage.md "Run metadata"): who
// ran a run, why, its tags and declared DUT serials, stored on the queue
// entry and copied into the run it starts; edits afterwards leave an event.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <sqlite3.h>

#include <nlohmann/json.hpp>

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

// '...' with the text as JSON would quote it (newlines and quotes escaped),
// so a message stays one line whatever a comment holds.
std::string quoted(const std::string& text) { return nlohmann::json(text).dump(); }

std::string listed(const std::vector<std::string>& values) {
  std::vector<std::string> q;
  for (const auto& v : values) q.push_back(quoted(v));
  return fmt::format("[{}]", fmt::join(q, ", "));
}

}  // namespace

Status Database::set_run_metadata(int64_t run_id, const RunMetadata& md,
                                  std::string_view changed_by) {
  const std::string what = fmt::format("editing the metadata of run {}", run_id);
  if (Status s = internal::check_metadata(md, path_, what); !s) return s;
  Transaction tx(db_, path_);
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

  auto st = Stmt::prepare(db_, path_,
                          "UPDATE runs SET operator = ?, comment = ?, tags_json = ?, "
                          "dut_serials_json = ? WHERE id = ?");
  if (!st) return st.error();
  internal::bind_metadata(*st, 1, md);
  st->bind(5, run_id);
  if (Status s = expect_done(*st, db_, path_, what); !s) return s;

  // The edit is filed after the run's latest event (t_s), so a time-ordered
  // event list shows it last; its wall_utc says when it happened.
  auto last =
      Stmt::prepare(db_, path_, "SELECT coalesce(max(t_s), 0) FROM events WHERE run_id = ?");
  if (!last) return last.error();
  last->bind(1, run_id);
  if (last->step() != SQLITE_ROW) return sqlite_error(db_, path_, what);
  EventRecord e;
  e.run_id = run_id;
  e.t_s = last->column_double(0);
  last->reset();
  e.kind = "metadata";
  e.message = fmt::format("metadata changed by {}: {}", changed_by.empty() ? "?" : changed_by,
                          fmt::join(changes, "; "));
  if (auto id = add_event(e); !id) return id.error();
  return tx.commit();
}

}  // namespace gyrotherm::storage

// What the lab's reads share (central_read.cpp, summary.cpp): one read-only
// snapshot per answer, rows of the views as JSON objects, and errors that
// say what to do about a missing schema or a role that may not read.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/lab/central.h"
#include "gyrotherm/lab/pg.h"

namespace gyrotherm::lab::internal {

using Params = std::vector<std::optional<std::string>>;

// A string member of a row; "" when the row is no object, or the member is
// missing or no string.
std::string str(const nlohmann::json& row, const char* key);

// The error of a failed read of `what` (a view), with a hint when the
// server's SQLSTATE says the schema is missing or the role may not read.
Error read_error(const PgConnection& pg, std::string_view what, const Error& error);

// Opens a read-only, repeatable-read transaction in UTC: every query of one
// answer sees the same committed state (a relay batch landing meanwhile is
// either wholly in it or not at all), and timestamps come out in UTC. The
// transaction is rolled back (nothing was written) when this goes.
class ReadSnapshot {
 public:
  static Result<ReadSnapshot> begin(PgConnection& pg);
  ReadSnapshot(ReadSnapshot&& other) noexcept : pg_(other.pg_) { other.pg_ = nullptr; }
  ReadSnapshot& operator=(ReadSnapshot&&) = delete;
  ReadSnapshot(const ReadSnapshot&) = delete;
  ReadSnapshot& operator=(const ReadSnapshot&) = delete;
  ~ReadSnapshot();

 private:
  explicit ReadSnapshot(PgConnection& pg) : pg_(&pg) {}
  PgConnection* pg_;
};

// Runs `sql`, whose single column is a JSON object per row (to_jsonb(...)),
// and parses them. `what` names the view in errors.
Result<std::vector<nlohmann::json>> json_rows(PgConnection& pg, std::string_view what,
                                              std::string_view sql, const Params& params);

// `since` (ISO-8601, any offset; "" = none) as the stations write
// started_utc ("2026-11-21T05:38:43.120Z"), so that it compares as text.
// Error naming it when it is not a date.
Result<std::string> normalize_since(const std::string& since);

// lab_stations and lab_runs within a snapshot the caller holds.
Result<std::vector<LabStation>> read_stations(PgConnection& pg);
Result<std::vector<LabRun>> read_runs(PgConnection& pg, const LabRunFilter& filter);

// timestamptz `column` as SQL text in the stations' format
// ("2026-11-21T05:38:43.120Z").
std::string utc_text(std::string_view column);

}  // namespace gyrotherm::lab::internal

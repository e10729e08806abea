// Internal helpers shared by the record code (duts.cpp, runs.cpp, queue.cpp,
// results.cpp, scale_factor.cpp): nesting write transactions, JSON
// string arrays, and the DUT/axis a result row is filed under.
#pragma once

#include <sqlite3.h>

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/database.h"
#include "sqlite_util.h"

namespace gyrotherm::storage::internal {

// A write transaction that nests: BEGIN IMMEDIATE outside a transaction, a
// savepoint inside one (the sample writer may register a DUT inside its own
// transaction). Rolls back unless commit() succeeded.
class WriteScope {
 public:
  WriteScope(sqlite3* db, const std::string& path, const char* name)
      : db_(db), path_(path), name_(name) {}
  WriteScope(const WriteScope&) = delete;
  WriteScope& operator=(const WriteScope&) = delete;
  ~WriteScope();
  Status begin();
  Status commit();

 private:
  sqlite3* db_;
  const std::string& path_;
  const char* name_;
  bool nested_ = false;
  bool open_ = false;
};

// A JSON array of strings, and back ("" reads as []); `where` names the
// column in errors.
std::string strings_json(const std::vector<std::string>& values);
Result<std::vector<std::string>> strings_from_json(const std::string& text,
                                                   const std::string& where);

// Run metadata in the columns operator, comment, tags_json,
// dut_serials_json (runs and queue), from parameter / column `first` on.
// check_metadata refuses what cannot be stored (an empty tag or serial),
// naming the field; read_metadata names `where` (e.g. "storage: F: run 3")
// when a JSON column is not an array of strings.
Status check_metadata(const RunMetadata& md, const std::string& path, std::string_view what);
void bind_metadata(Stmt& st, int first, const RunMetadata& md);
Result<RunMetadata> read_metadata(const Stmt& st, int first, const std::string& where);

// The serial and primary axis of the run's first DUT (position order);
// nullopt when the run has none.
Result<std::optional<std::pair<std::string, std::string>>> first_dut_of_run(sqlite3* db,
                                                                            const std::string& path,
                                                                            int64_t run_id);

// The (dut_serial, axis) a result of `run_id` is stored under: serial ""
// is the run's first DUT (its serial) and axis "" that DUT's primary axis,
// when the run has DUTs; a run without DUTs stores what it is given (""
// = the unnamed gyro). A serial the run's DUTs do not include is refused
// (naming it) when the run has DUTs. `what` prefixes errors. `primary`:
// the axis is the DUT's primary axis (for a run without DUTs: the axis is
// ""), so rows stored before v8 (axis '') of that DUT are the same series.
struct ResultKey {
  std::string serial;
  std::string axis;
  bool primary = true;
};
Result<ResultKey> result_key(sqlite3* db, const std::string& path, int64_t run_id,
                             const std::string& serial, const std::string& axis,
                             std::string_view what);

// The order of result rows of a run: by the DUT's position in the run
// (rows of a serial the run did not register, such as the unnamed gyro of
// rows stored before v8, count as position 0), then serial, then axis.
// dut_position_join(alias) joins the result table (aliased `alias`, with
// run_id and dut_serial columns) to its DUT's run_duts row (alias rd_rd);
// kDutPositionOrder is the ORDER BY term.
std::string dut_position_join(std::string_view alias);
inline constexpr const char* kDutPositionOrder = "coalesce(rd_rd.position, 0)";

// The drift fits filed under a DUT (fits.dut_serial), newest first.
Result<std::vector<FitRecord>> fits_of_dut(sqlite3* db, const std::string& path,
                                           const std::string& serial);

// "a, b" -> "x.a, x.b".
std::string qualified(std::string_view columns, std::string_view alias);

// A result's quality (schema v11) in the columns kQualityColumns, from
// parameter / column `first` on (quality.cpp). Unknown numbers are NULL;
// reasons that are not a JSON array of strings read as one reason quoting
// the text.
inline constexpr const char* kQualityColumns =
    "coverage_samples, coverage_expected, coverage, longest_gap_s, quality, quality_reasons_json";
inline constexpr int kQualityColumnCount = 6;
void bind_quality(Stmt& st, int first, const ResultQuality& q);
ResultQuality read_quality(const Stmt& st, int first);

}  // namespace gyrotherm::storage::internal

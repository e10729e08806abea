// Internal helpers shared by the record code (duts.cpp, database.cpp,
// queue.cpp, scale_factor.cpp, plots.cpp): nesting write transactions, JSON
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

// The serial and primary axis of the run's first DUT (position order);
// nullopt when the run has none.
Result<std::optional<std::pair<std::string, std::string>>> first_dut_of_run(sqlite3* db,
                                                                            const std::string& path,
                                                                            int64_t run_id);

// The (dut_serial, axis) a result of `run_id` is stored under: serial ""
// is the run's first DUT (its serial) and axis "" that DUT's primary axis,
// when the run has DUTs; a run without DUTs stores what it is given (""
// = the unnamed gyro). A serial the run's DUTs do not include is refused
// (naming it) when the run has DUTs. `what` prefixes errors.
Result<std::pair<std::string, std::string>> result_key(sqlite3* db, const std::string& path,
                                                       int64_t run_id, const std::string& serial,
                                                       const std::string& axis,
                                                       std::string_view what);

}  // namespace gyrotherm::storage::internal

// The ordered list of schema migrations. Migration k takes a database from
// schema version k-1 to k; version 0 is an empty file. Never edit a released
// migration: append a new one and bump kSchemaVersion (database.h).
#pragma once

#include <sqlite3.h>

#include <span>
#include <string>

#include "gyrotherm/core/result.h"

namespace gyrotherm::storage::internal {

struct Migration {
  int version;       // the schema version after this script
  const char* name;  // short description, for error messages
  const char* sql;
  // A step in C++ after the script, in the same transaction (moving data
  // SQL alone cannot, e.g. samples into chunks); nullptr: none. now_utc:
  // the wall time rows are stamped with.
  Status (*data_step)(sqlite3* db, const std::string& path, const std::string& now_utc) = nullptr;
};

std::span<const Migration> migrations();

}  // namespace gyrotherm::storage::internal

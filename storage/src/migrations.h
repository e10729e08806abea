// The ordered list of schema migrations. Migration k takes a database from
// schema version k-1 to k; version 0 is an empty file. Never edit a released
// migration: append a new one and bump kSchemaVersion (database.h).
#pragma once

#include <span>

namespace gyrotherm::storage::internal {

struct Migration {
  int version;       // the schema version after this script
  const char* name;  // short description, for error messages
  const char* sql;
};

std::span<const Migration> migrations();

}  // namespace gyrotherm::storage::internal

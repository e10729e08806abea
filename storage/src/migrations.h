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

// The lab outbox's triggers (outbox.cpp, docs/storage.md "Lab outbox"):
// drops every trigger named lab_outbox_* and creates, for each relayed
// table, AFTER INSERT / UPDATE / DELETE triggers generated from its
// current columns (PRAGMA table_info). Run by the v10 migration and again
// by any later migration that changes a relayed table's columns, in the
// migration's transaction. The second form is the migration data step.
Status install_lab_triggers(sqlite3* db, const std::string& path);
Status install_lab_triggers_step(sqlite3* db, const std::string& path, const std::string& now_utc);

}  // namespace gyrotherm::storage::internal

// The station database (SQLite, WAL mode): schema, migrations, records.
//
// One database per station. The schema is a user interface (people query it
// with sqlite3); it is documented in docs/storage.md and versioned in the
// `meta` table (key 'schema_version'); open() applies every migration the
// file lacks, in one transaction each.
//
// A Database object owns one connection and is not thread-safe: each thread
// (control loop, sample writer, HTTP readers, CLI) opens its own. WAL lets
// readers work while a run is being written; busy_timeout is 5 s.
//
// The records are kept by the stores a Database is made of: base classes
// whose methods are called on the Database, each declared in its own header
// with its records (this header includes them all):
//   runs.h     RunStore: runs, their metadata and checkpoints, segments
//   duts.h     DutStore: devices under test, their channels and history
//   queue.h    QueueStore: the run queue and station settings (meta)
//   events.h   EventStore: events
//   results.h  ResultStore: Table I rows, fits, Allan deviations, scale factor
//   samples.h  SampleStore: gyro, temperature and table samples; plot reads
//   exports.h  ExportStore: calibration exports
//   outbox.h   OutboxStore: the lab outbox and the lab binding
// A store's methods are defined in storage/src/<header name>.cpp (the scale
// factor in scale_factor.cpp); the connection itself in database.cpp.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"
#include "gyrotherm/storage/duts.h"
#include "gyrotherm/storage/events.h"
#include "gyrotherm/storage/exports.h"
#include "gyrotherm/storage/outbox.h"
#include "gyrotherm/storage/queue.h"
#include "gyrotherm/storage/results.h"
#include "gyrotherm/storage/runs.h"
#include "gyrotherm/storage/samples.h"

struct sqlite3;

namespace gyrotherm::storage {

namespace internal {
struct FileGuard;
}

// v8: DUTs, run metadata, results per DUT and axis (records).
// v9: chunked sample storage (sample_chunks, channel_rollup).
// v10: run UUIDs and the lab outbox (runs.uuid, outbox; docs/lab.md).
// v11: coverage and a quality verdict on every result; rate points' guard
// bands.
inline constexpr int kSchemaVersion = 14;

// The file a connection opened: its device and inode when it was opened.
struct FileIdentity {
  uint64_t dev = 0;
  uint64_t ino = 0;
  bool operator==(const FileIdentity&) const = default;
};

// What open() checks before it migrates or writes anything.
enum class OpenCheck {
  kNone,
  // PRAGMA quick_check over the whole file: it reads every page, about 1 s
  // per GB from the page cache, the disk's read time otherwise
  // (docs/storage.md). The daemon's start.
  kQuick,
};

// One connection. The stores (base classes) hold no data: their methods
// reach the connection through the Database they are part of.
class Database : public RunStore,
                 public DutStore,
                 public QueueStore,
                 public EventStore,
                 public ResultStore,
                 public SampleStore,
                 public ExportStore,
                 public OutboxStore {
 public:
  // Opens or creates `path`, sets WAL and busy_timeout, migrates to
  // kSchemaVersion. Errors name the file. A file with a newer schema than this
  // build knows is a permanent error (never downgraded). The UTC times it
  // stamps (a run's start and end, events, statistics, fits, exports, queue
  // entries) come from `wall` (not owned; outlives the connection).
  // With OpenCheck::kQuick a file quick_check finds damaged is refused (a
  // permanent error naming the file and the first problems) before anything
  // is written to it.
  //
  // The connection records the file's identity (device, inode) and commits
  // nothing once its path names another file or none (check_file()): every
  // write transaction is then rolled back with an error saying so.
  static Result<Database> open(const std::string& path, const WallClock& wall = system_wall_clock(),
                               OpenCheck check = OpenCheck::kNone);
  // Opens an existing database read-only (for the CLI and HTTP readers); no
  // migration. Error if it does not exist or its schema is unknown.
  static Result<Database> open_read_only(const std::string& path);

  Database(Database&& other) noexcept;
  Database& operator=(Database&& other) noexcept;
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;
  ~Database();

  Result<int> schema_version();

  // Runs `body` (calls of this Database) in one transaction: all of its
  // writes commit together, or none when it returns an error (that error is
  // returned). For what must not be seen half done after a crash: a step's
  // end, the next step's start and the checkpoint that says so.
  Status atomically(const std::function<Status()>& body);
  // Runs `body` (reads of this Database) in one read transaction: every
  // read sees the same committed state, whatever other connections commit
  // meanwhile, so an answer made of several reads never shows half of a
  // write (a run's scale-factor fits without their points).
  Status read_consistently(const std::function<Status()>& body);

  // PRAGMA integrity_check (quick: PRAGMA quick_check, which skips the
  // index contents): its rows, exactly {"ok"} when the file is sound, one
  // problem per row otherwise. An error when the check could not run (the
  // file is too damaged to read, I/O error).
  Result<std::vector<std::string>> integrity_check(bool quick = false);
  // Ok when quick_check answers "ok"; else a permanent error naming the file
  // and its first problems (what OpenCheck::kQuick refuses).
  Status verify_quick();

  // Whether the path still names the file this connection opened (one
  // stat(), microseconds). A permanent error naming the path when the file
  // was deleted, or another was put in its place (renamed over it); such a
  // connection commits nothing any more. Ok for an in-memory or temporary
  // database.
  Status check_file() const;
  // The file's identity when the connection opened it; nullopt without a
  // file (":memory:", "").
  std::optional<FileIdentity> file_identity() const;
  // Once check_file() failed: moves what the write-ahead log holds into the
  // file this connection has open (which nobody reads any more) and empties
  // the log, so the `-wal` beside the path is not replayed into the file
  // now there (or a new one) when it is next opened. Does not wait for other
  // connections: busy, it can be tried again later.
  Status release_wal();

  // Direct SQL for statements the API above does not cover (tests, tools).
  // Result rows are discarded: a check that answers in rows (integrity_check,
  // foreign_key_check, wal_checkpoint) needs its own reader.
  Status exec(std::string_view sql);
  sqlite3* handle() { return db_; }
  const std::string& path() const { return path_; }
  // Now, from the wall clock the connection was opened with, as ISO-8601
  // UTC: what it stamps rows with (and what callers stamp records with).
  std::string utc_now() const;

 private:
  // The stores reach the connection: db_, path_, utc_or_now().
  friend class RunStore;
  friend class DutStore;
  friend class QueueStore;
  friend class EventStore;
  friend class ResultStore;
  friend class SampleStore;
  friend class ExportStore;
  friend class OutboxStore;

  Database(sqlite3* db, std::string path, const WallClock& wall);
  // `utc` itself when it is set, else utc_now().
  std::string utc_or_now(const std::string& utc) const { return utc.empty() ? utc_now() : utc; }

  sqlite3* db_ = nullptr;  // owned
  std::string path_;
  const WallClock* wall_;
  // The file's identity, for the commit hook (heap: stays put when moved);
  // nullptr without a file.
  std::unique_ptr<internal::FileGuard> guard_;
};

}  // namespace gyrotherm::storage

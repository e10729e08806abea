// The database file under a running program: deleted, or replaced by another
// file renamed over it, a connection notices (check_file) and commits nothing
// into the file it has open; a damaged file is refused at open
// (OpenCheck::kQuick) before anything is written to it.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/stat.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <string>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using testing::integrity_ok;
using testing::open_ok;
using testing::query_int;
using testing::TempDir;

namespace fs = std::filesystem;

EventRecord info(const std::string& message) {
  EventRecord e;
  e.kind = "info";
  e.message = message;
  return e;
}

std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

GyroSample gyro_at(double t_s) {
  GyroSample g;
  g.t_s = t_s;
  g.rate_dph = 1.5;
  return g;
}

TEST(FileIdentity, RecordedAtOpenAndOkWhileTheFileStays) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const auto id = db.file_identity();
  ASSERT_TRUE(id.has_value());
  struct stat st {};
  ASSERT_EQ(::stat(path.c_str(), &st), 0);
  EXPECT_EQ(id->ino, static_cast<uint64_t>(st.st_ino));
  EXPECT_EQ(id->dev, static_cast<uint64_t>(st.st_dev));
  EXPECT_TRUE(db.check_file().ok());
  ASSERT_TRUE(db.add_event(info("written")).ok());
}

TEST(FileIdentity, InMemoryDatabaseHasNoFileToLose) {
  auto db = Database::open(":memory:");
  ASSERT_TRUE(db.ok()) << db.error().message;
  EXPECT_FALSE(db->file_identity().has_value());
  EXPECT_TRUE(db->check_file().ok());
  EXPECT_TRUE(db->add_event(info("in memory")).ok());
}

TEST(FileIdentity, DeletedFileIsNoticedAndNothingIsCommittedToIt) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  ASSERT_TRUE(db.add_event(info("before")).ok());
  ASSERT_EQ(std::remove(path.c_str()), 0);

  const Status checked = db.check_file();
  ASSERT_FALSE(checked.ok());
  EXPECT_NE(checked.error().message.find(path), std::string::npos) << checked.error().message;
  EXPECT_NE(checked.error().message.find("was deleted while open"), std::string::npos)
      << checked.error().message;

  auto refused = db.add_event(info("after"));
  ASSERT_FALSE(refused.ok()) << "committed into a deleted file";
  EXPECT_NE(refused.error().message.find("not committed: the database file was deleted"),
            std::string::npos)
      << refused.error().message;
  EXPECT_EQ(query_int(db.handle(), "SELECT count(*) FROM events"), 1) << "rolled back";
}

// `mv copy.db station.db` while a connection has station.db open: the old
// file's write-ahead log (the -wal beside the path) must not end up in the
// copy.
TEST(FileIdentity, ReplacedByACopyIsNoticedAndTheCopyIsLeftIntact) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  const std::string copy = dir.file("copy.db");
  std::optional<Database> db(open_ok(path));
  // A second connection keeps the log from being checkpointed and removed.
  std::optional<Database> reader(open_ok(path));
  for (int i = 0; i < 50; ++i) ASSERT_TRUE(db->add_event(info(fmt::format("old {}", i))).ok());
  {
    Database c = open_ok(copy);
    ASSERT_TRUE(c.add_event(info("the copy's own")).ok());
  }  // checkpointed: the copy is one file
  // More commits into the old file's log: they belong to it, not to the copy.
  for (int i = 0; i < 200; ++i) {
    ASSERT_TRUE(db->exec(fmt::format("INSERT INTO meta(key, value) VALUES('k{}', '{}')", i,
                                     std::string(500, 'x')))
                    .ok());
  }
  ASSERT_GT(fs::file_size(path + "-wal"), 0u);
  const std::string copy_bytes = read_bytes(copy);
  fs::rename(copy, path);

  const Status checked = db->check_file();
  ASSERT_FALSE(checked.ok());
  EXPECT_NE(checked.error().message.find("replaced by another file"), std::string::npos)
      << checked.error().message;
  auto refused = db->add_event(info("after"));
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find("replaced by another file"), std::string::npos)
      << refused.error().message;
  EXPECT_FALSE(reader->add_event(info("after, other connection")).ok());

  const Status released = db->release_wal();
  ASSERT_TRUE(released.ok()) << released.error().message;
  EXPECT_EQ(read_bytes(path), copy_bytes) << "nothing went into the copy";
  reader.reset();
  db.reset();

  Database now = open_ok(path);
  EXPECT_TRUE(integrity_ok(now));
  EXPECT_EQ(query_int(now.handle(), "SELECT count(*) FROM events"), 1);
  EXPECT_EQ(query_int(now.handle(), "SELECT count(*) FROM meta WHERE key LIKE 'k%'"), 0);
}

TEST(FileIdentity, SampleWriterCommitsNothingIntoADeletedFile) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = testing::start_ok(path, {.commit_interval = std::chrono::hours(1)});
  GyroSample g = gyro_at(0.0);
  writer->push_gyro(1, std::span(&g, 1));
  ASSERT_TRUE(writer->flush().ok());
  ASSERT_EQ(std::remove(path.c_str()), 0);
  g = gyro_at(0.1);
  writer->push_gyro(1, std::span(&g, 1));
  const Status s = writer->flush();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find("deleted"), std::string::npos) << s.error().message;
  const SampleWriterStats stats = writer->stats();
  EXPECT_EQ(stats.consecutive_failures, 1u);
  EXPECT_EQ(stats.pending, 1u) << "held, as on a full disk";
  EXPECT_NE(stats.last_error.find(path), std::string::npos) << stats.last_error;
}

// A page of the queue table overwritten: the damaged file is refused at
// open, naming it and what quick_check found, and left as it was.
TEST(QuickCheck, DamagedQueuePageIsRefusedAtOpenAndNotWritten) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  int64_t root = 0, page_size = 0;
  {
    Database db = open_ok(path);
    for (int i = 0; i < 20; ++i) {
      ASSERT_TRUE(db.queue_add(fmt::format("s{}", i), "s.toml", "[[step]]\n", false).ok());
    }
    root = query_int(db.handle(), "SELECT rootpage FROM sqlite_master WHERE name = 'queue'");
    page_size = query_int(db.handle(), "PRAGMA page_size");
  }  // the last connection checkpoints: everything is in the file
  ASSERT_GT(root, 1);
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp((root - 1) * page_size + 8);  // the cell pointers of the page
    const std::string garbage(64, '\xff');
    f.write(garbage.data(), static_cast<std::streamsize>(garbage.size()));
  }
  const std::string before = read_bytes(path);

  auto db = Database::open(path, system_wall_clock(), OpenCheck::kQuick);
  ASSERT_FALSE(db.ok()) << "a damaged file opened";
  const std::string& m = db.error().message;
  EXPECT_NE(m.find(path), std::string::npos) << m;
  EXPECT_NE(m.find("the database is damaged: PRAGMA quick_check found"), std::string::npos) << m;
  EXPECT_NE(m.find(fmt::format("On tree page {} cell", root)), std::string::npos) << m;
  EXPECT_FALSE(db.error().transient);
  EXPECT_EQ(read_bytes(path), before);
}

TEST(QuickCheck, SoundAndNewFilesOpen) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  {
    auto fresh = Database::open(path, system_wall_clock(), OpenCheck::kQuick);
    ASSERT_TRUE(fresh.ok()) << fresh.error().message;
    ASSERT_TRUE(fresh->add_event(info("x")).ok());
  }
  auto again = Database::open(path, system_wall_clock(), OpenCheck::kQuick);
  ASSERT_TRUE(again.ok()) << again.error().message;
  EXPECT_TRUE(again->verify_quick().ok());
}

}  // namespace
}  // namespace gyrotherm::storage

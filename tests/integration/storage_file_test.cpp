// gyrothermd and its database file, end to end: the file deleted under the
// running daemon, a damaged file at start, a database directory that does
// not exist.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <iterator>
#include <string>

#include "station_fixture.h"

namespace gyrotherm::testing {
namespace {

using ::testing::HasSubstr;

TEST_F(StationTest, DatabaseDeletedUnderTheDaemonTripsStorageFailing) {
  write(dir_ / "schedule.toml", soak_schedule("long", 23.0, 120));
  start_sim();
  start_daemon();
  std::optional<nlohmann::json> live;
  ASSERT_TRUE(wait_until(
      [&] {
        live = status();
        return live && live->value("state", "") == "acquiring";
      },
      std::chrono::seconds(60)))
      << daemon_->log();
  const fs::path db = dir_ / "station.db";
  ASSERT_TRUE(fs::remove(db));
  const auto tripped = [&] {
    live = status();
    if (!live) return false;
    for (const auto& i : live->value("interlocks", nlohmann::json::array())) {
      if (i.value("kind", "") == "storage_failing") return true;
    }
    return false;
  };
  ASSERT_TRUE(wait_until(tripped, std::chrono::seconds(30))) << daemon_->log();
  EXPECT_EQ(live->value("state", ""), "suspended");
  EXPECT_THAT(live->dump(), HasSubstr("the database file was deleted while open"));
  EXPECT_THAT(daemon_->log(),
              HasSubstr(db.string() + ": the database file was deleted while open"));
  EXPECT_FALSE(fs::exists(db)) << "nothing made a new file in its place";
}

// A page of the file overwritten while the daemon was stopped: the next start
// refuses it, naming the file and what quick_check found.
TEST_F(StationTest, DamagedDatabaseIsRefusedAtStart) {
  const fs::path db = dir_ / "station.db";
  int64_t root = 0, page_size = 0;
  {
    auto d = storage::Database::open(db.string());
    ASSERT_TRUE(d.ok()) << d.error().message;
    for (int i = 0; i < 20; ++i) ASSERT_TRUE(d->queue_add("s", "s.toml", "[[step]]\n", false).ok());
    root = storage::testing::query_int(d->handle(),
                                       "SELECT rootpage FROM sqlite_master WHERE name = 'queue'");
    page_size = storage::testing::query_int(d->handle(), "PRAGMA page_size");
  }
  {
    std::fstream f(db, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp((root - 1) * page_size + 8);
    const std::string garbage(64, '\xff');
    f.write(garbage.data(), static_cast<std::streamsize>(garbage.size()));
  }
  start_sim();
  start_daemon({}, /*with_schedule=*/false);
  const auto code = daemon_->wait(std::chrono::seconds(30));
  ASSERT_TRUE(code.has_value()) << "the daemon kept running on a damaged file";
  EXPECT_EQ(*code, 1);
  EXPECT_THAT(daemon_->log(),
              HasSubstr(db.string() + ": the database is damaged: PRAGMA quick_check"));
}

TEST_F(StationTest, DatabaseDirectoryMissingIsAConfigError) {
  std::string text;
  {
    std::ifstream in(dir_ / "station.toml");
    text.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  const std::string db_line = fmt::format("db = \"{}/station.db\"", dir_.string());
  const std::size_t at = text.find(db_line);
  ASSERT_NE(at, std::string::npos);
  const int line = static_cast<int>(std::count(text.begin(), text.begin() + at, '\n')) + 1;
  text.replace(at, db_line.size(), fmt::format("db = \"{}/typo/station.db\"", dir_.string()));
  write(dir_ / "station.toml", text);
  ChildProcess d({bin("gyrothermd"), "--config", (dir_ / "station.toml").string()},
                 (dir_ / "daemon.log").string());
  const auto code = d.wait(std::chrono::seconds(10));
  ASSERT_TRUE(code.has_value());
  EXPECT_EQ(*code, 2);
  EXPECT_THAT(d.log(), HasSubstr(fmt::format("station.toml:{}: storage.db: the database's "
                                             "directory {}/typo does not exist",
                                             line, dir_.string())));
  EXPECT_FALSE(fs::exists(dir_ / "typo")) << "the daemon made the directory";
}

}  // namespace
}  // namespace gyrotherm::testing

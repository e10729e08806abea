#include "gyrotherm/storage/sample_writer.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <thread>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "test_time.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using namespace std::chrono_literals;
using testing::query_int;
using testing::query_text;
using testing::start_ok;
using testing::TempDir;

constexpr int64_t kRun = 1;

// Deterministic sample i: t = i ms, a rate that uses the full double.
GyroSample gyro_sample(int i) {
  GyroSample g;
  g.t_s = i * 0.001;
  g.rate_dph = 7.95 + std::sin(i * 0.37) / 3.0;
  g.seq = static_cast<uint8_t>(i % 128);
  g.status = 0x77;
  g.temp_c = static_cast<int16_t>(20 + i % 7 - 3);
  return g;
}

TemperatureSample temperature_sample(int j) {
  return {.t_s = j * 1.0,
          .setpoint_c = 20.0,
          .chamber_c = 19.5 + j * 0.01,
          .top_c = 19.25 + j / 3.0,
          .side_c = 19.125 - j / 7.0};
}

// Polls `pred` until it holds or `timeout` (stretched by
// GYROTHERM_TEST_TIME_FACTOR) passes; true if it held.
template <class Pred>
bool wait_for(Pred pred, std::chrono::milliseconds timeout) {
  return gyrotherm::testing::wait_for_condition(pred, timeout);
}

TEST(SampleWriter, TwoThreadsPushFlushAndReadBackExactly) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 50ms});
  constexpr int kGyro = 100'000;
  constexpr int kTemps = 100;

  // Each thread its own run (a DUT's frames come from one reader thread, in
  // time order: a frame at or before the last stored one is a duplicate).
  auto producer = [&](int parity) {
    std::vector<GyroSample> chunk;
    for (int i = 0; i < kGyro; ++i) {
      chunk.push_back(gyro_sample(i));
      if (chunk.size() == 250) {
        writer->push_gyro(kRun + parity, chunk);
        chunk.clear();
      }
    }
    writer->push_gyro(kRun + parity, chunk);
    for (int j = parity; j < kTemps; j += 2) writer->push_temperature(kRun, temperature_sample(j));
  };
  std::thread a(producer, 0), b(producer, 1);
  a.join();
  b.join();
  Status s = writer->flush();
  ASSERT_TRUE(s.ok()) << s.error().message;

  auto db = Database::open_read_only(path);
  ASSERT_TRUE(db.ok()) << db.error().message;
  EXPECT_EQ(*db->count_gyro_samples(kRun), kGyro);
  EXPECT_EQ(*db->count_gyro_samples(kRun + 1), kGyro);
  auto gyro = db->gyro_samples(kRun + 1, 0.0, 1e9);
  ASSERT_TRUE(gyro.ok()) << gyro.error().message;
  ASSERT_EQ(gyro->size(), static_cast<std::size_t>(kGyro));
  for (int i = 0; i < kGyro; ++i) {
    const GyroSample want = gyro_sample(i);
    const GyroSample& got = (*gyro)[i];
    // Time stamps are implicit (t0 + i * period): exact to rounding.
    ASSERT_NEAR(got.t_s, want.t_s, 1e-9) << i;
    ASSERT_EQ(got.rate_dph, want.rate_dph) << i;
    ASSERT_EQ(got.seq, want.seq) << i;
    ASSERT_EQ(got.status, want.status) << i;
    ASSERT_EQ(got.temp_c, want.temp_c) << i;
  }
  // A window is half-open [from, to).
  auto window = db->gyro_samples(kRun, 10.0, 20.0);
  ASSERT_TRUE(window.ok());
  ASSERT_EQ(window->size(), 10'000u);
  EXPECT_EQ(window->front().t_s, gyro_sample(10'000).t_s);
  EXPECT_EQ(window->back().t_s, gyro_sample(19'999).t_s);

  auto temps = db->temperature_samples(kRun, 0.0, 1e9);
  ASSERT_TRUE(temps.ok()) << temps.error().message;
  ASSERT_EQ(temps->size(), static_cast<std::size_t>(kTemps));
  for (int j = 0; j < kTemps; ++j) {
    const TemperatureSample want = temperature_sample(j);
    const TemperatureSample& got = (*temps)[j];
    ASSERT_EQ(got.t_s, want.t_s);
    ASSERT_EQ(got.setpoint_c, want.setpoint_c);
    ASSERT_EQ(got.chamber_c, want.chamber_c);
    ASSERT_EQ(got.top_c, want.top_c);
    ASSERT_EQ(got.side_c, want.side_c);
  }

  // Stopping packs the closed chunks still waiting (a commit packs a few).
  writer->stop();
  const SampleWriterStats stats = writer->stats();
  EXPECT_EQ(stats.gyro_rows, static_cast<uint64_t>(2 * kGyro));
  EXPECT_EQ(stats.channel_samples, static_cast<uint64_t>(2 * kGyro * 3));  // rate, status, temp_c
  // 4096 samples a chunk at most, 3 channels; written in pieces at commits.
  EXPECT_GE(stats.chunks, 2u * 3u * ((kGyro + 4095) / 4096));
  EXPECT_EQ(query_int(db->handle(), "SELECT count(*) FROM sample_chunks"),
            2 * 3 * ((kGyro + 4095) / 4096))
      << "chunk sizes do not depend on the commits";
  EXPECT_EQ(stats.temperature_rows, static_cast<uint64_t>(kTemps));
  EXPECT_EQ(stats.dropped, 0u);
  EXPECT_EQ(stats.pending, 0u);
  EXPECT_GE(stats.commits, 1u);
  EXPECT_EQ(stats.commit_failures, 0u);
}

TEST(SampleWriter, NanValuesRoundTripAsNull) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {});
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  GyroSample g = gyro_sample(5);
  g.rate_dph = kNaN;
  writer->push_gyro(kRun, std::span(&g, 1));
  TemperatureSample t = temperature_sample(1);
  t.side_c = kNaN;  // a stalled probe
  writer->push_temperature(kRun, t);
  GyroSample no_time = gyro_sample(6);
  no_time.t_s = kNaN;  // not storable: refused
  writer->push_gyro(kRun, std::span(&no_time, 1));
  ASSERT_TRUE(writer->flush().ok());
  EXPECT_EQ(writer->stats().rejected, 1u);

  auto db = Database::open_read_only(path);
  ASSERT_TRUE(db.ok());
  auto gyro = db->gyro_samples(kRun, 0, 1);
  ASSERT_EQ(gyro->size(), 1u);
  EXPECT_TRUE(std::isnan((*gyro)[0].rate_dph));
  auto temps = db->temperature_samples(kRun, 0, 10);
  ASSERT_EQ(temps->size(), 1u);
  EXPECT_TRUE(std::isnan((*temps)[0].side_c));
  EXPECT_EQ((*temps)[0].top_c, t.top_c);
  // Stored as NaN in a float chunk.
  EXPECT_EQ(query_text(db->handle(),
                       "SELECT substr(encoding, 1, 1) FROM sample_chunks c JOIN "
                       "channels h ON h.id = c.channel_id WHERE h.name = 'rate'"),
            "f");
}

TEST(SampleWriter, ReaderSeesCommittedRowsWhileWriterRuns) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h});
  auto reader = Database::open_read_only(path);
  ASSERT_TRUE(reader.ok()) << reader.error().message;

  std::vector<GyroSample> batch;
  for (int i = 0; i < 5000; ++i) batch.push_back(gyro_sample(i));
  writer->push_gyro(kRun, batch);
  EXPECT_EQ(*reader->count_gyro_samples(kRun), 0);  // not committed yet
  ASSERT_TRUE(writer->flush().ok());
  EXPECT_EQ(*reader->count_gyro_samples(kRun), 5000);

  batch.clear();
  for (int i = 5000; i < 8000; ++i) batch.push_back(gyro_sample(i));
  writer->push_gyro(kRun, batch);
  ASSERT_TRUE(writer->flush().ok());
  EXPECT_EQ(*reader->count_gyro_samples(kRun), 8000);
  auto tail = reader->gyro_samples(kRun, gyro_sample(7990).t_s, 1e9);
  ASSERT_TRUE(tail.ok());
  EXPECT_EQ(tail->size(), 10u);
}

TEST(SampleWriter, CommitsWithinTheIntervalWithoutFlush) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 100ms});
  auto reader = Database::open_read_only(path);
  ASSERT_TRUE(reader.ok());

  // The writer commits every interval, data or not. A batch pushed just
  // after a commit (the previous one, seen by the 2 ms polling) waits up to
  // one interval, plus the commit of 200 rows (milliseconds). The median of
  // five stands for the writer rather than for a loaded machine's worst
  // moment: 100 ms of slack over the interval, where a writer on its
  // default 500 ms, or one waiting for flush(), is far beyond.
  std::vector<std::chrono::steady_clock::duration> delays;
  int pushed_rows = 0;
  for (int round = 0; round < 5; ++round) {
    std::vector<GyroSample> batch;
    for (int i = 0; i < 200; ++i) batch.push_back(gyro_sample(pushed_rows + i));
    const auto pushed = std::chrono::steady_clock::now();
    writer->push_gyro(kRun, batch);
    pushed_rows += 200;
    ASSERT_TRUE(wait_for([&] { return *reader->count_gyro_samples(kRun) == pushed_rows; }, 5s))
        << "rows not committed within 5 s";
    delays.push_back(std::chrono::steady_clock::now() - pushed);
  }
  std::sort(delays.begin(), delays.end());
  EXPECT_LT(delays[2], gyrotherm::testing::scaled(100ms + 100ms))
      << "median " << std::chrono::duration_cast<std::chrono::milliseconds>(delays[2]).count()
      << " ms";
  // The count is raised after the commit a reader already sees: waited for.
  EXPECT_TRUE(wait_for([&] { return writer->stats().commits >= 5u; }, 5s))
      << "commits " << writer->stats().commits;
}

TEST(SampleWriter, DropsOldestBeyondMaxPendingAndCounts) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  // No timed commit during the test: only flush() commits.
  auto writer = start_ok(path, {.commit_interval = 1h, .max_pending = 1000});
  std::vector<GyroSample> batch;
  for (int i = 0; i < 1500; ++i) batch.push_back(gyro_sample(i));
  writer->push_gyro(kRun, std::span(batch).first(700));
  writer->push_gyro(kRun, std::span(batch).subspan(700));
  writer->push_temperature(kRun, temperature_sample(0));

  SampleWriterStats stats = writer->stats();
  EXPECT_EQ(stats.dropped, 501u);  // 500 gyro for the overflow, 1 more for the temperature
  EXPECT_EQ(stats.pending, 1000u);

  ASSERT_TRUE(writer->flush().ok());
  auto db = Database::open_read_only(path);
  ASSERT_TRUE(db.ok());
  auto gyro = db->gyro_samples(kRun, 0, 1e9);
  ASSERT_TRUE(gyro.ok());
  ASSERT_EQ(gyro->size(), 999u);
  EXPECT_EQ(gyro->front().t_s, gyro_sample(501).t_s);  // the oldest went first
  EXPECT_EQ(gyro->back().t_s, gyro_sample(1499).t_s);
  EXPECT_EQ(db->temperature_samples(kRun, 0, 1e9)->size(), 1u);
  stats = writer->stats();
  EXPECT_EQ(stats.gyro_rows, 999u);
  EXPECT_EQ(stats.pending, 0u);
}

TEST(SampleWriter, FailedCommitKeepsRowsForRetry) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h});
  auto admin = Database::open(path);
  ASSERT_TRUE(admin.ok());
  ASSERT_TRUE(admin
                  ->exec("CREATE TRIGGER fail_inserts BEFORE INSERT ON sample_chunks "
                         "BEGIN SELECT RAISE(ABORT, 'injected failure'); END")
                  .ok());

  std::vector<GyroSample> batch;
  for (int i = 0; i < 10; ++i) batch.push_back(gyro_sample(i));
  writer->push_gyro(kRun, batch);
  writer->push_temperature(kRun, temperature_sample(0));
  Status s = writer->flush();
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.error().message.find(path), std::string::npos) << s.error().message;
  EXPECT_NE(s.error().message.find("injected failure"), std::string::npos) << s.error().message;
  SampleWriterStats stats = writer->stats();
  EXPECT_EQ(stats.commit_failures, 1u);
  EXPECT_EQ(stats.consecutive_failures, 1u);
  EXPECT_EQ(stats.pending, 11u);
  EXPECT_EQ(stats.gyro_rows, 0u);
  EXPECT_NE(stats.last_error.find("injected failure"), std::string::npos);
  EXPECT_EQ(*admin->count_gyro_samples(kRun), 0);
  // The transaction was rolled back: the temperature row is not there either.
  EXPECT_EQ(query_int(admin->handle(), "SELECT count(*) FROM temperature_samples"), 0);

  ASSERT_FALSE(writer->flush().ok());
  EXPECT_EQ(writer->stats().consecutive_failures, 2u);

  ASSERT_TRUE(admin->exec("DROP TRIGGER fail_inserts").ok());
  s = writer->flush();
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ(writer->stats().consecutive_failures, 0u) << "a success ends the failing spell";
  EXPECT_EQ(*admin->count_gyro_samples(kRun), 10);
  EXPECT_EQ(query_int(admin->handle(), "SELECT count(*) FROM temperature_samples"), 1);
  stats = writer->stats();
  EXPECT_EQ(stats.pending, 0u);
  EXPECT_EQ(stats.gyro_rows, 10u);
  EXPECT_EQ(stats.dropped, 0u);
}

TEST(SampleWriter, DuplicateTimesAreIgnoredAndCounted) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h});
  GyroSample g = gyro_sample(42);
  writer->push_gyro(kRun, std::span(&g, 1));
  ASSERT_TRUE(writer->flush().ok());
  GyroSample again = g;
  again.rate_dph = -1.0;
  writer->push_gyro(kRun, std::span(&again, 1));
  writer->push_gyro(2, std::span(&again, 1));  // same time, another run: kept
  ASSERT_TRUE(writer->flush().ok());
  EXPECT_EQ(writer->stats().duplicates, 1u);
  auto db = Database::open_read_only(path);
  EXPECT_EQ(*db->count_gyro_samples(kRun), 1);
  EXPECT_EQ((*db->gyro_samples(kRun, 0, 1))[0].rate_dph, g.rate_dph);  // the first one stays
  EXPECT_EQ(*db->count_gyro_samples(2), 1);
}

TEST(SampleWriter, StopCommitsPendingIsIdempotentAndRejectsLaterPushes) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto writer = start_ok(path, {.commit_interval = 1h});
  std::vector<GyroSample> batch;
  for (int i = 0; i < 100; ++i) batch.push_back(gyro_sample(i));
  writer->push_gyro(kRun, batch);
  writer->stop();
  writer->stop();
  auto db = Database::open_read_only(path);
  EXPECT_EQ(*db->count_gyro_samples(kRun), 100);

  writer->push_gyro(kRun, batch);
  EXPECT_EQ(writer->stats().rejected, 100u);
  EXPECT_TRUE(writer->flush().ok());  // nothing pending
}

// The writer thread stops on an exception (here its commit callback's): it
// shows as failing for good, and a flush says so even with nothing pending.
TEST(SampleWriter, DeadWriterThreadShowsAsFailing) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  auto w = SampleWriter::start(path, {.commit_interval = 1h},
                               [](double) { throw std::runtime_error("histogram exploded"); });
  ASSERT_TRUE(w.ok()) << w.error().message;
  auto& writer = *w;
  GyroSample g = gyro_sample(0);
  writer->push_gyro(kRun, std::span(&g, 1));
  Status s = writer->flush();
  ASSERT_FALSE(s.ok()) << "the thread died in that round";
  SampleWriterStats stats = writer->stats();
  EXPECT_TRUE(stats.thread_failed);
  EXPECT_GE(stats.consecutive_failures, 1u) << "counts as failing commits";
  EXPECT_NE(stats.last_error.find("sample writer stopped: histogram exploded"), std::string::npos)
      << stats.last_error;
  EXPECT_NE(stats.last_error.find(path), std::string::npos) << stats.last_error;

  g = gyro_sample(1);
  writer->push_gyro(kRun, std::span(&g, 1));
  EXPECT_EQ(writer->stats().rejected, 1u);
  s = writer->flush();
  ASSERT_FALSE(s.ok()) << "nothing pending, but nothing is committed any more either";
  EXPECT_NE(s.error().message.find("histogram exploded"), std::string::npos) << s.error().message;
  EXPECT_TRUE(writer->stats().thread_failed);
}

TEST(SampleWriter, RejectsBadOptions) {
  TempDir dir;
  auto w = SampleWriter::start(dir.file("station.db"), {.commit_interval = 0ms});
  ASSERT_FALSE(w.ok());
  EXPECT_NE(w.error().message.find("commit_interval"), std::string::npos);
  w = SampleWriter::start(dir.file("station.db"), {.max_pending = 0});
  ASSERT_FALSE(w.ok());
  EXPECT_NE(w.error().message.find("sample writer options: max_pending"), std::string::npos)
      << w.error().message;
}

TEST(SampleWriterOptions, Validity) {
  std::string why;
  EXPECT_TRUE(SampleWriterOptions{}.is_valid(&why)) << why;
  EXPECT_FALSE(SampleWriterOptions{.commit_interval = -1ms}.is_valid(&why));
  EXPECT_NE(why.find("commit_interval = -1 ms must be > 0"), std::string::npos) << why;
  EXPECT_FALSE(SampleWriterOptions{.commit_interval = 0ms}.is_valid(nullptr));
  EXPECT_FALSE(SampleWriterOptions{.max_pending = 0}.is_valid(&why));
  EXPECT_NE(why.find("max_pending"), std::string::npos) << why;
}

// A writer process that dies without stop(): committed rows survive and the
// file is consistent.
TEST(SampleWriter, DatabaseLeftByAKilledWriterIsConsistent) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  constexpr int kFlushed = 20'000;
  const pid_t pid = fork();
  ASSERT_NE(pid, -1);
  if (pid == 0) {
    auto w = SampleWriter::start(path, {.commit_interval = 20ms});
    if (!w) _exit(2);
    std::vector<GyroSample> batch;
    for (int i = 0; i < kFlushed; ++i) batch.push_back(gyro_sample(i));
    (*w)->push_gyro(kRun, batch);
    if (!(*w)->flush().ok()) _exit(3);
    for (int round = 0; round < 20; ++round) {
      batch.clear();
      for (int i = 0; i < 5000; ++i) batch.push_back(gyro_sample(kFlushed + round * 5000 + i));
      (*w)->push_gyro(kRun, batch);
    }
    _exit(0);  // no stop(), no destructors: the writer thread dies mid-flight
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);

  auto db = Database::open(path);
  ASSERT_TRUE(db.ok()) << db.error().message;
  EXPECT_TRUE(testing::integrity_ok(*db));
  const int64_t n = *db->count_gyro_samples(kRun);
  EXPECT_GE(n, kFlushed);
  EXPECT_LE(n, kFlushed + 100'000);
  auto rows = db->gyro_samples(kRun, 0, gyro_sample(kFlushed).t_s);
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), static_cast<std::size_t>(kFlushed));
  EXPECT_EQ(rows->back().rate_dph, gyro_sample(kFlushed - 1).rate_dph);
}

}  // namespace
}  // namespace gyrotherm::storage

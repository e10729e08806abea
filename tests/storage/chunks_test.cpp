// Chunked sample storage (schema v9): the value codec, chunk boundaries
// (gaps, lost frames, the cap), push_frames of a multi-channel DUT, a
// restarted writer, and the v9 migration of a schema-5 database with data.
#include "chunks.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "migrations.h"
#include "numbers.h"
#include "test_time.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using namespace std::chrono_literals;
using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

using gyrotherm::testing::kNaN;

internal::Encoding encoding_of(std::vector<double> v) {
  internal::EncodingNeed need;
  for (double x : v) need.add(x);
  return need.encoding();
}

TEST(ChunkCodec, NarrowestExactEncoding) {
  using internal::Encoding;
  EXPECT_EQ(encoding_of({0, 119, 255}), Encoding::kU8);
  EXPECT_EQ(encoding_of({-3, 21, 127}), Encoding::kI8);
  EXPECT_EQ(encoding_of({256, 1}), Encoding::kU16);
  EXPECT_EQ(encoding_of({-129, 1}), Encoding::kI16);
  EXPECT_EQ(encoding_of({70000}), Encoding::kU32);
  EXPECT_EQ(encoding_of({-70000}), Encoding::kI32);
  EXPECT_EQ(encoding_of({0.5, static_cast<double>(1.1f), kNaN}), Encoding::kF32);
  EXPECT_EQ(encoding_of({1, kNaN}), Encoding::kF32) << "NaN needs a float";
  EXPECT_EQ(encoding_of({-0.0}), Encoding::kF32) << "-0 is not an integer";
  EXPECT_EQ(encoding_of({0.1}), Encoding::kF64);
  EXPECT_EQ(encoding_of({5e9}), Encoding::kF32);  // integral, beyond u32, a float
  // Round trips are exact, NaN included.
  for (std::vector<double> v : {std::vector<double>{0, 119, 255},
                                {-3, 21, 127},
                                {-129, 1, 32767},
                                {0.5, static_cast<double>(1.1f), kNaN, -0.0},
                                {0.1, 1e300, kNaN}}) {
    const Encoding e = encoding_of(v);
    std::string blob;
    internal::encode(e, v, blob);
    ASSERT_EQ(blob.size(), v.size() * internal::encoded_size(e));
    std::vector<double> back(v.size());
    ASSERT_TRUE(internal::decode(e, blob.data(), blob.size(), v.size(), back.data()));
    for (std::size_t i = 0; i < v.size(); ++i) {
      if (std::isnan(v[i])) {
        EXPECT_TRUE(std::isnan(back[i]));
      } else {
        EXPECT_EQ(back[i], v[i]);
        EXPECT_EQ(std::signbit(back[i]), std::signbit(v[i]));
      }
    }
    EXPECT_FALSE(internal::decode(e, blob.data(), blob.size() - 1, v.size(), back.data()));
  }
}

TEST(ChunkClock, EndsAtGapsLostFramesAndNeverMidSample) {
  internal::ChunkClock c;
  const double period = 0.001;
  // Late in an 80-h run: time stamps of the order of 288 000 s.
  const double t0 = 288'000.123;
  for (int i = 0; i < 1000; ++i) {
    const double t = t0 + i * period;
    ASSERT_TRUE(c.continues(t, static_cast<uint32_t>(i % 128), period, 128)) << i;
    c.add(t, static_cast<uint32_t>(i % 128));
  }
  const double next = t0 + 1000 * period;
  EXPECT_TRUE(c.continues(next, 1000 % 128, period, 128));
  EXPECT_FALSE(c.continues(next, 1001 % 128, period, 128)) << "a lost frame";
  EXPECT_FALSE(c.continues(next + period, 1000 % 128, period, 128)) << "a gap";
  EXPECT_FALSE(c.continues(next + 2e-9, 1000 % 128, period, 128)) << "off the clock by 2e-6 period";
  EXPECT_TRUE(c.continues(next + 0.5e-9, 1000 % 128, period, 0)) << "within 1e-6 period";
  for (int i = 0; i < 1000; ++i) {
    EXPECT_NEAR(c.t0_s + i * c.period_s, t0 + i * period, 1e-9);
  }
  // The second sample must be a step of the nominal clock.
  internal::ChunkClock d;
  d.add(1.0, 0);
  EXPECT_FALSE(d.continues(1.0 + 10 * period, 1, period, 0));
  EXPECT_TRUE(d.continues(1.0 + period, 1, period, 0));
}

// A KVH-1750-like DUT registered by hand (as add_run_dut does).
RunDutRecord register_kvh(Database& db, int64_t run_id, const std::string& serial) {
  RunDutRecord r;
  r.run_id = run_id;
  r.dut.serial = serial;
  r.primary_axis = "z";
  r.rate_hz = 1000;
  r.seq_modulo = 128;
  EXPECT_TRUE(db.exec(fmt::format("INSERT OR IGNORE INTO runs(id, schedule_name, state, "
                                  "started_utc) VALUES({}, 's', 'completed', 'x');"
                                  "INSERT INTO duts(serial, model, first_seen_utc) VALUES('{}', "
                                  "'KVH 1750', 'x')",
                                  run_id, serial))
                  .ok());
  r.dut.id = sqlite3_last_insert_rowid(db.handle());
  EXPECT_TRUE(db.exec(fmt::format("INSERT INTO run_duts(run_id, dut_id, position, primary_axis, "
                                  "rate_hz, seq_modulo) VALUES({}, {}, 0, 'z', 1000, 128)",
                                  run_id, r.dut.id))
                  .ok());
  const double rad_to_dph = 180.0 / M_PI * 3600.0;
  const ChannelSpec specs[] = {{"gyro_x", "deg/h", ChannelKind::kRate, "x", rad_to_dph},
                               {"gyro_y", "deg/h", ChannelKind::kRate, "y", rad_to_dph},
                               {"gyro_z", "deg/h", ChannelKind::kRate, "z", rad_to_dph},
                               {"accel_x", "g", ChannelKind::kAccel, "x", 1},
                               {"accel_y", "g", ChannelKind::kAccel, "y", 1},
                               {"accel_z", "g", ChannelKind::kAccel, "z", 1},
                               {"status", "", ChannelKind::kStatus, "", 1},
                               {"temp_c", "degC", ChannelKind::kTemperature, "", 1}};
  int idx = 0;
  for (const ChannelSpec& s : specs) {
    EXPECT_TRUE(
        db.exec(fmt::format("INSERT INTO channels(run_id, dut_id, idx, name, unit, kind, "
                            "axis, scale) VALUES({}, {}, {}, '{}', '{}', '{}', '{}', {:.17g})",
                            run_id, r.dut.id, idx, s.name, s.unit, to_string(s.kind), s.axis,
                            s.scale))
            .ok());
    r.channels.push_back({sqlite3_last_insert_rowid(db.handle()), run_id, r.dut.id, idx, s});
    ++idx;
  }
  return r;
}

DutFrame kvh_frame(int i, double t_s) {
  DutFrame f;
  f.t_s = t_s;
  f.seq = static_cast<uint32_t>(i % 128);
  for (int c = 0; c < 6; ++c) f.raw[c] = static_cast<float>(1e-5 * std::sin(i * 0.01 + c));
  f.raw[6] = 0x77;
  f.raw[7] = 20 + i / 5000;
  if (i % 1001 == 0) f.raw[1] = kNaN;  // flagged invalid
  return f;
}

TEST(ChunkedWriter, KvhFramesStoredExactlyInTheNarrowestEncodings) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  RunDutRecord dut;
  {
    Database db = open_ok(path);
    dut = register_kvh(db, 1, "17-0042");
  }
  std::vector<DutFrame> frames;
  for (int i = 0; i < 10'000; ++i) {
    frames.push_back(kvh_frame(i, 100.0 + i * 0.001 + (i >= 6000 ? 0.5 : 0)));  // gap at 6000
  }
  frames.erase(frames.begin() + 3000);  // a lost frame: the counter skips
  auto writer = testing::start_ok(path, {.commit_interval = 20ms});
  for (std::size_t i = 0; i < frames.size(); i += 97) {
    writer->push_frames(dut,
                        std::span(frames).subspan(i, std::min<std::size_t>(97, frames.size() - i)));
  }
  ASSERT_TRUE(writer->flush().ok());
  writer->stop();
  EXPECT_EQ(writer->stats().channel_samples, frames.size() * 8);
  EXPECT_EQ(writer->stats().gyro_rows, frames.size());

  Database db = open_ok(path);
  // Chunks: [0, 3000), [3001, 6000), [6000, 10000) capped at 4096.
  const int64_t gyro_z = dut.channels[2].id;
  EXPECT_EQ(
      query_text(db.handle(), fmt::format("SELECT group_concat(n) FROM (SELECT n FROM "
                                          "sample_chunks WHERE channel_id = {} ORDER BY t0_s)",
                                          gyro_z)),
      "3000,2999,4000");
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(DISTINCT encoding) FROM sample_chunks c "
                       "JOIN channels h ON h.id = c.channel_id WHERE h.kind != 'status' "
                       "AND h.kind != 'temperature'"),
            "f32+shuffle+zstd")
      << "closed chunks are packed (the writer stopped: every chunk is closed)";
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(DISTINCT encoding) FROM sample_chunks c "
                       "JOIN channels h ON h.id = c.channel_id WHERE h.name = 'status'"),
            "u8+shuffle+zstd");
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(DISTINCT encoding) FROM sample_chunks c "
                       "JOIN channels h ON h.id = c.channel_id WHERE h.name = 'temp_c'"),
            "u8+shuffle+zstd");
  // Every channel back exactly: physical = raw * scale, NaN kept.
  for (const ChannelRecord& ch : dut.channels) {
    std::size_t k = 0;
    ASSERT_TRUE(db.for_each_channel_block(ch.id, -1e9, 1e9,
                                          [&](std::span<const double> t, std::span<const double> v,
                                              std::span<const uint32_t> seq) {
                                            for (std::size_t i = 0; i < t.size(); ++i, ++k) {
                                              const DutFrame& f = frames[k];
                                              EXPECT_NEAR(t[i], f.t_s, 1e-9);
                                              EXPECT_EQ(seq[i], f.seq);
                                              const double want = f.raw[ch.index] * ch.spec.scale;
                                              if (std::isnan(want)) {
                                                EXPECT_TRUE(std::isnan(v[i]))
                                                    << ch.spec.name << " " << k;
                                              } else {
                                                EXPECT_EQ(v[i], want) << ch.spec.name << " " << k;
                                              }
                                            }
                                            return true;
                                          })
                    .ok());
    EXPECT_EQ(k, frames.size()) << ch.spec.name;
    EXPECT_EQ(*db.count_channel_samples(ch.id), static_cast<int64_t>(frames.size()));
  }
  // Chunk statistics are of the finite physical values.
  EXPECT_EQ(query_int(db.handle(), fmt::format("SELECT sum(vn) FROM sample_chunks WHERE "
                                               "channel_id = {}",
                                               dut.channels[1].id)),
            static_cast<long long>(frames.size()) - 10);
  // The old API reads the first DUT's primary axis.
  auto g = db.gyro_samples(1, 100.0, 100.01);
  ASSERT_TRUE(g.ok()) << g.error().message;
  ASSERT_EQ(g->size(), 10u);
  EXPECT_EQ((*g)[3].rate_dph, frames[3].raw[2] * dut.channels[2].spec.scale);
  EXPECT_EQ((*g)[3].status, 0x77);
  EXPECT_EQ((*g)[3].temp_c, 20);
  auto y = db.gyro_samples(1, StreamKey{"17-0042", "y"}, 100.0, 100.01);
  ASSERT_TRUE(y.ok());
  EXPECT_EQ((*y)[3].rate_dph, frames[3].raw[1] * dut.channels[1].spec.scale);
  auto bad = db.gyro_samples(1, StreamKey{"nope", ""}, 0, 1);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("'nope'"), std::string::npos) << bad.error().message;
  auto d = db.decimated_samples(1, StreamKey{"17-0042", ""}, "accel_y", 0, std::nullopt, 20);
  ASSERT_TRUE(d.ok()) << d.error().message;
  EXPECT_EQ(d->channel, "accel_y");
  EXPECT_EQ(d->unit, "g");
  auto no_channel = db.decimated_samples(1, StreamKey{}, "bogus", 0, std::nullopt, 20);
  ASSERT_FALSE(no_channel.ok());
  EXPECT_NE(no_channel.error().message.find("'bogus'"), std::string::npos);
}

TEST(ChunkedWriter, RestartedWriterStartsNewChunksAndIgnoresDuplicates) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  RunDutRecord dut;
  {
    Database db = open_ok(path);
    dut = register_kvh(db, 1, "A");
  }
  std::vector<DutFrame> frames;
  for (int i = 0; i < 3000; ++i) frames.push_back(kvh_frame(i, i * 0.001));
  {
    auto w = testing::start_ok(path, {.commit_interval = 1h});
    w->push_frames(dut, std::span(frames).first(1000));
    ASSERT_TRUE(w->flush().ok());
    w->push_frames(dut, std::span(frames).subspan(1000, 500));
    ASSERT_TRUE(w->flush().ok());
  }  // a restart
  auto w = testing::start_ok(path, {.commit_interval = 1h});
  w->push_frames(dut, std::span(frames).subspan(1400));  // 100 already stored
  ASSERT_TRUE(w->flush().ok());
  EXPECT_EQ(w->stats().duplicates, 100u);
  Database db = open_ok(path);
  EXPECT_EQ(
      query_text(db.handle(), fmt::format("SELECT group_concat(n) FROM (SELECT n FROM "
                                          "sample_chunks WHERE channel_id = {} ORDER BY t0_s)",
                                          dut.channels[0].id)),
      "1500,1500")
      << "extended in place across commits, a new chunk after the restart";
  EXPECT_EQ(*db.count_channel_samples(dut.channels[7].id), 3000);
}

// Each run's state (its DUTs' open chunks) goes once the run is closed and
// its samples committed: many runs, bounded state. A closed run's late
// samples are still stored, in a chunk of their own.
TEST(ChunkedWriter, ClosedRunsReleaseTheirState) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  constexpr int kRuns = 40;
  std::vector<RunDutRecord> duts;
  {
    Database db = open_ok(path);
    for (int run = 1; run <= kRuns; ++run) {
      duts.push_back(register_kvh(db, run, fmt::format("17-{:04}", run)));
    }
  }
  std::vector<DutFrame> frames;
  for (int i = 0; i < 2000; ++i) frames.push_back(kvh_frame(i, i * 0.001));
  auto writer = testing::start_ok(path, {.commit_interval = 1h});
  std::size_t most_held = 0;
  for (const RunDutRecord& dut : duts) {
    writer->push_frames(dut, std::span(frames).first(1500));
    ASSERT_TRUE(writer->flush().ok());
    most_held = std::max(most_held, writer->stats().runs_held);
    writer->close_run(dut.run_id);
  }
  ASSERT_TRUE(gyrotherm::testing::wait_for_condition([&] { return writer->stats().runs_held == 0; },
                                                     std::chrono::seconds(5)))
      << writer->stats().runs_held << " runs still held after " << kRuns << " closed";
  EXPECT_LE(most_held, 2u);

  writer->push_frames(duts.front(), std::span(frames).subspan(1500));  // late
  ASSERT_TRUE(writer->flush().ok());
  writer->stop();
  Database db = open_ok(path);
  EXPECT_EQ(
      query_text(db.handle(), fmt::format("SELECT group_concat(n) FROM (SELECT n FROM "
                                          "sample_chunks WHERE channel_id = {} ORDER BY t0_s)",
                                          duts.front().channels[2].id)),
      "1500,500");
  EXPECT_EQ(*db.count_channel_samples(duts.back().channels[7].id), 1500);
}

// A schema-5 database with gyro samples (the old DDL, from the migration
// list) migrates to chunks with every sample intact and the old tables gone.
TEST(ChunkMigration, Schema5DatabaseKeepsEverySample) {
  TempDir dir;
  const std::string path = dir.file("v5.db");
  struct Row {
    int64_t run;
    double t_s;
    int seq;
    double rate;  // NaN: NULL
    int status;
    int temp;
  };
  std::vector<Row> rows;
  std::mt19937_64 rng(5);
  std::normal_distribution<double> noise(0, 3);
  // Run 1: 1 kHz late in a long run, with a gap, a lost frame and NULL rates.
  double t = 250'000.0004;
  for (int i = 0; i < 20'000; ++i) {
    if (i == 7000) t += 2.5;      // a gap
    if (i == 12'000) t += 0.001;  // a lost frame (seq continues below: skip)
    const int seq = (i + (i >= 12'000 ? 1 : 0)) % 128;
    rows.push_back({1, t, seq, i % 501 == 0 ? kNaN : 7.9 + noise(rng), 0x77, 20 + i / 7000});
    t += 0.001;
  }
  // Run 2: irregular times (a text gyro timestamped on arrival).
  double t2 = -3.0;
  for (int i = 0; i < 500; ++i) {
    t2 += 0.01 + 0.003 * std::abs(noise(rng));
    rows.push_back({2, t2, 0, noise(rng), 1, -5});
  }
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    std::string sql = "CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);";
    for (int v = 0; v < 5; ++v) sql += internal::migrations()[v].sql;
    sql +=
        "INSERT INTO meta VALUES('schema_version', '5');"
        "INSERT INTO runs(id, schedule_name, state, started_utc, config_json) VALUES"
        "(1, 'a', 'completed', 'x', '{\"gyro\":{\"axis\":\"x\"}}'), "
        "(2, 'b', 'completed', 'y', NULL);";
    ASSERT_EQ(sqlite3_exec(raw, sql.c_str(), nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(raw);
    ASSERT_EQ(sqlite3_exec(raw, "BEGIN", nullptr, nullptr, nullptr), SQLITE_OK);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(sqlite3_prepare_v2(raw, "INSERT INTO gyro_samples VALUES(?, ?, ?, ?, ?, ?)", -1, &st,
                                 nullptr),
              SQLITE_OK);
    for (const Row& r : rows) {
      sqlite3_bind_int64(st, 1, r.run);
      sqlite3_bind_double(st, 2, r.t_s);
      sqlite3_bind_int(st, 3, r.seq);
      if (std::isnan(r.rate)) {
        sqlite3_bind_null(st, 4);
      } else {
        sqlite3_bind_double(st, 4, r.rate);
      }
      sqlite3_bind_int(st, 5, r.status);
      sqlite3_bind_int(st, 6, r.temp);
      ASSERT_EQ(sqlite3_step(st), SQLITE_DONE) << sqlite3_errmsg(raw);
      sqlite3_reset(st);
    }
    sqlite3_finalize(st);
    ASSERT_EQ(sqlite3_exec(raw, "COMMIT", nullptr, nullptr, nullptr), SQLITE_OK);
    sqlite3_close(raw);
  }
  Database db = open_ok(path);
  EXPECT_EQ(*db.schema_version(), kSchemaVersion);
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM sqlite_master WHERE name IN "
                      "('gyro_samples', 'gyro_rollup')"),
            0);
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(serial || ':' || primary_axis) FROM "
                       "run_duts r JOIN duts d ON d.id = r.dut_id"),
            ":x,:z");
  for (int64_t run : {1, 2}) {
    auto got = db.gyro_samples(run, -1e12, 1e12);
    ASSERT_TRUE(got.ok()) << got.error().message;
    std::vector<Row> want;
    for (const Row& r : rows) {
      if (r.run == run) want.push_back(r);
    }
    ASSERT_EQ(got->size(), want.size()) << "run " << run;
    for (std::size_t i = 0; i < want.size(); ++i) {
      const GyroSample& g = (*got)[i];
      ASSERT_NEAR(g.t_s, want[i].t_s, 1e-9) << run << " " << i;
      if (std::isnan(want[i].rate)) {
        ASSERT_TRUE(std::isnan(g.rate_dph)) << run << " " << i;
      } else {
        ASSERT_EQ(g.rate_dph, want[i].rate) << run << " " << i;
      }
      ASSERT_EQ(g.seq, want[i].seq) << run << " " << i;
      ASSERT_EQ(g.status, want[i].status) << run << " " << i;
      ASSERT_EQ(g.temp_c, want[i].temp) << run << " " << i;
    }
  }
  // Run 1 in few chunks: broken at the gap and the lost frame, capped at 4096.
  EXPECT_EQ(query_int(db.handle(),
                      "SELECT count(*) FROM sample_chunks c JOIN channels h ON "
                      "h.id = c.channel_id WHERE h.run_id = 1 AND h.name = 'rate'"),
            2 + 2 + 2);
  // Every chunk is closed and packed, the run's last one too (status 0x77
  // throughout: packed is far smaller than plain u8).
  EXPECT_EQ(query_text(db.handle(),
                       "SELECT group_concat(DISTINCT encoding) FROM sample_chunks c JOIN "
                       "channels h ON h.id = c.channel_id WHERE h.run_id = 1 AND h.name = "
                       "'status'"),
            "u8+shuffle+zstd");
  EXPECT_TRUE(testing::integrity_ok(db));
}

}  // namespace
}  // namespace gyrotherm::storage

// The encodings of closed chunks (docs/storage.md "Encodings"): names,
// decimals, shuffle+zstd round trips bit for bit over awkward inputs, a
// chunk written in pieces and rewritten whole when it closes, files with
// plain encodings still read, a damaged BLOB is an error.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <bit>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "chunks.h"
#include "gyrotherm/storage/database.h"
#include "gyrotherm/storage/sample_writer.h"
#include "migrations.h"
#include "numbers.h"
#include "test_util.h"

namespace gyrotherm::storage {
namespace {

using namespace std::chrono_literals;
using internal::ChunkEncoding;
using internal::Encoding;
using testing::open_ok;
using testing::query_int;
using testing::query_text;
using testing::TempDir;

using gyrotherm::testing::kNaN;

uint64_t bits(double v) { return std::bit_cast<uint64_t>(v); }

// encode_closed, then decode: every value back bit for bit (a NaN as a NaN).
ChunkEncoding round_trip(const std::vector<double>& v, const std::string& what) {
  internal::EncodingNeed need;
  for (double x : v) need.add(x);
  std::string blob;
  const ChunkEncoding e = internal::encode_closed(need.encoding(), v, blob);
  std::vector<double> back(v.size(), 12345.0);
  EXPECT_TRUE(internal::decode(e, blob.data(), blob.size(), v.size(), back.data()))
      << what << ": " << internal::to_string(e);
  for (std::size_t i = 0; i < v.size(); ++i) {
    if (std::isnan(v[i])) {
      EXPECT_TRUE(std::isnan(back[i])) << what << " [" << i << "]";
    } else {
      EXPECT_EQ(bits(back[i]), bits(v[i]))
          << what << " [" << i << "] " << fmt::format("{} read back as {}", v[i], back[i]) << " in "
          << internal::to_string(e);
    }
  }
  // Never larger than the plain encoding.
  EXPECT_LE(blob.size(), v.size() * internal::encoded_size(need.encoding())) << what;
  // The name reads back as the same encoding.
  EXPECT_EQ(internal::chunk_encoding_from_string(internal::to_string(e)), e) << what;
  return e;
}

std::vector<double> f32_noise(std::size_t n, double mean, double sigma, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> d(mean, sigma);
  std::vector<double> v(n);
  for (double& x : v) x = static_cast<float>(d(rng));
  return v;
}

TEST(ChunkEncoding, NamesParseAndPrint) {
  for (const char* name : {"u8", "i8", "u16", "i16", "u32", "i32", "f32", "f64", "u8+shuffle+zstd",
                           "f32+shuffle+zstd", "f64+shuffle+zstd", "i32/1e2", "i64/1e15",
                           "i32/1e3+shuffle+zstd", "i64/1e9+shuffle+zstd"}) {
    const auto e = internal::chunk_encoding_from_string(name);
    ASSERT_TRUE(e) << name;
    EXPECT_EQ(internal::to_string(*e), name);
  }
  const auto d = internal::chunk_encoding_from_string("i32/1e3+shuffle+zstd");
  EXPECT_EQ(d->base, Encoding::kI32);
  EXPECT_EQ(d->decimals, 3);
  EXPECT_TRUE(d->zstd);
  for (const char* bad : {"", "f16", "i64", "i64+shuffle+zstd", "f32/1e3", "u16/1e2", "i32/1e0",
                          "i32/1e16", "i32/1e03", "i32/1e", "i32/1ex", "f32+zstd", "+shuffle+zstd",
                          "f32+shuffle+zstd+shuffle+zstd"}) {
    EXPECT_FALSE(internal::chunk_encoding_from_string(bad)) << "'" << bad << "'";
  }
}

TEST(ChunkEncoding, DecimalPlaces) {
  using internal::decimal_places;
  EXPECT_EQ(decimal_places(std::vector<double>{23.05, 23.1, 22.99}), 2);
  EXPECT_EQ(decimal_places(std::vector<double>{0.1, 7}), 1);
  EXPECT_EQ(decimal_places(std::vector<double>{-0.000123, 4.5}), 6);
  EXPECT_EQ(decimal_places(std::vector<double>{1e-15}), 15);
  EXPECT_EQ(decimal_places(std::vector<double>{0.5, kNaN, 0.25}), 2) << "the NaN of a flag";
  EXPECT_EQ(decimal_places(std::vector<double>{1, 2, 3}), std::nullopt) << "integers";
  EXPECT_EQ(decimal_places(std::vector<double>{0.1 + 0.2}), std::nullopt)
      << "0.30000000000000004: 17 decimals";
  EXPECT_EQ(decimal_places(std::vector<double>{0.1, -0.0}), std::nullopt) << "-0";
  EXPECT_EQ(decimal_places(std::vector<double>{0.1, INFINITY}), std::nullopt);
  EXPECT_EQ(decimal_places(std::vector<double>{1e-16}), std::nullopt);
  EXPECT_EQ(decimal_places(std::vector<double>{123456789.123456789}), std::nullopt)
      << "beyond 2^53 at the decimals it needs";
  EXPECT_EQ(decimal_places(std::vector<double>{0.1, -std::numeric_limits<double>::quiet_NaN()}),
            std::nullopt)
      << "a NaN of another sign";
  EXPECT_EQ(decimal_places(std::vector<double>{std::numeric_limits<double>::denorm_min()}),
            std::nullopt);
}

TEST(ChunkEncoding, ClosedChunksRoundTripBitForBit) {
  // One sample (too short to pack: stays plain).
  EXPECT_EQ(round_trip({static_cast<float>(1.25e-4)}, "one f32"), (ChunkEncoding{Encoding::kF32}));
  round_trip({0.1}, "one f64");
  round_trip({kNaN}, "one NaN");
  // 4096 of f32 noise: packed, smaller.
  const auto noise = f32_noise(4096, 7e-5, 1.5e-4, 1);
  EXPECT_EQ(round_trip(noise, "f32 noise"), (ChunkEncoding{Encoding::kF32, 0, true}));
  // With NaNs for invalid samples, negative zero, denormals, infinities.
  auto awkward = noise;
  for (std::size_t i = 0; i < awkward.size(); i += 97) awkward[i] = kNaN;
  awkward[5] = -0.0;
  awkward[6] = static_cast<double>(std::numeric_limits<float>::denorm_min());
  awkward[7] = -static_cast<double>(std::numeric_limits<float>::denorm_min()) * 3;
  awkward[8] = INFINITY;
  awkward[9] = -INFINITY;
  awkward[10] = std::numeric_limits<float>::max();
  round_trip(awkward, "f32 with NaN, -0, denormals, infinities");
  // A constant series packs to next to nothing.
  {
    internal::EncodingNeed need;
    const std::vector<double> constant(4096, static_cast<float>(0.98765));
    for (double x : constant) need.add(x);
    std::string blob;
    internal::encode_closed(need.encoding(), constant, blob);
    EXPECT_LT(blob.size(), 100u);
    round_trip(constant, "constant f32");
    round_trip(std::vector<double>(4096, 0x77), "constant u8");
    round_trip(std::vector<double>(4096, -0.0), "constant -0");
    round_trip(std::vector<double>(4096, kNaN), "all NaN");
  }
  // Doubles: random bits (no exact decimal, barely packable), f64
  // denormals, and every integer type.
  {
    std::mt19937_64 rng(2);
    std::vector<double> random(4096);
    for (double& x : random) {
      do {
        x = std::bit_cast<double>(rng());
      } while (std::isnan(x));
    }
    round_trip(random, "random f64 bits");
    std::vector<double> denormals(4096);
    for (std::size_t i = 0; i < denormals.size(); ++i) {
      denormals[i] = std::numeric_limits<double>::denorm_min() * static_cast<double>(i % 7 + 1) *
                     (i % 2 ? -1 : 1);
    }
    round_trip(denormals, "f64 denormals");
    std::vector<double> ints(4096);
    for (std::size_t i = 0; i < ints.size(); ++i)
      ints[i] = static_cast<double>(rng() % 70000) - 35000;
    EXPECT_EQ(round_trip(ints, "i32 noise").base, Encoding::kI32);
  }
  // The ASCII DUT's decimals: exact decimals, the same double as parsing.
  {
    std::mt19937_64 rng(3);
    std::vector<double> temps(4096);
    for (std::size_t i = 0; i < temps.size(); ++i) {
      temps[i] = std::strtod(fmt::format("{:.2f}", 23.0 + 0.3 * std::sin(i * 1e-3) +
                                                       0.01 * static_cast<double>(rng() % 5))
                                 .c_str(),
                             nullptr);
    }
    temps[100] = kNaN;
    const ChunkEncoding t = round_trip(temps, "temperatures with 2 decimals");
    EXPECT_EQ(t, (ChunkEncoding{Encoding::kI32, 2, true}));
    std::vector<double> rates(4096);
    std::normal_distribution<double> d(0.0021, 0.0004);
    for (double& x : rates) x = std::strtod(fmt::format("{:.7f}", d(rng)).c_str(), nullptr);
    EXPECT_EQ(round_trip(rates, "rates with 7 decimals"), (ChunkEncoding{Encoding::kI32, 7, true}));
    std::vector<double> wide(4096);
    for (double& x : wide) x = std::strtod(fmt::format("{:.9f}", d(rng) * 1e6).c_str(), nullptr);
    round_trip(wide, "wide decimals");
    // Shortest round-trip doubles (what the simulator prints): no decimal.
    std::vector<double> shortest(4096);
    for (double& x : shortest) x = d(rng);
    EXPECT_EQ(round_trip(shortest, "shortest doubles").decimals, 0);
  }
}

TEST(ChunkEncoding, DamagedDataIsNotDecoded) {
  const auto noise = f32_noise(4096, 0, 1, 4);
  std::string blob;
  const ChunkEncoding e = internal::encode_closed(Encoding::kF32, noise, blob);
  ASSERT_TRUE(e.zstd);
  std::vector<double> back(noise.size());
  EXPECT_TRUE(internal::decode(e, blob.data(), blob.size(), noise.size(), back.data()));
  EXPECT_FALSE(internal::decode(e, blob.data(), blob.size() - 1, noise.size(), back.data()));
  EXPECT_FALSE(internal::decode(e, blob.data(), blob.size(), noise.size() - 1, back.data()))
      << "n does not match the frame's content";
  std::string junk(blob.size(), 'x');
  EXPECT_FALSE(internal::decode(e, junk.data(), junk.size(), noise.size(), back.data()));
}

// A two-channel DUT: an f32 rate and a temperature with two decimals.
RunDutRecord register_dut(Database& db, int64_t run_id) {
  RunDutRecord r;
  r.run_id = run_id;
  r.dut.serial = "TS-1";
  r.primary_axis = "z";
  r.rate_hz = 1000;
  r.seq_modulo = 65536;
  EXPECT_TRUE(db.exec(fmt::format("INSERT INTO runs(id, schedule_name, state, started_utc) "
                                  "VALUES({}, 's', 'completed', 'x');"
                                  "INSERT INTO duts(serial, model, first_seen_utc) VALUES('TS-1', "
                                  "'test set', 'x')",
                                  run_id))
                  .ok());
  r.dut.id = sqlite3_last_insert_rowid(db.handle());
  EXPECT_TRUE(db.exec(fmt::format("INSERT INTO run_duts(run_id, dut_id, position, primary_axis, "
                                  "rate_hz, seq_modulo) VALUES({}, {}, 0, 'z', 1000, 65536)",
                                  run_id, r.dut.id))
                  .ok());
  const ChannelSpec specs[] = {{"rate_z", "deg/s", ChannelKind::kRate, "z", 1},
                               {"temp_c", "degC", ChannelKind::kTemperature, "", 1}};
  int idx = 0;
  for (const ChannelSpec& s : specs) {
    EXPECT_TRUE(
        db.exec(fmt::format("INSERT INTO channels(run_id, dut_id, idx, name, unit, kind, "
                            "axis, scale) VALUES({}, {}, {}, '{}', '{}', '{}', '{}', 1)",
                            run_id, r.dut.id, idx, s.name, s.unit, to_string(s.kind), s.axis))
            .ok());
    r.channels.push_back({sqlite3_last_insert_rowid(db.handle()), run_id, r.dut.id, idx, s});
    ++idx;
  }
  return r;
}

std::vector<DutFrame> frames_of(int n) {
  const auto rate = f32_noise(static_cast<std::size_t>(n), 7e-5, 1.5e-4, 5);
  std::vector<DutFrame> frames(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    DutFrame& f = frames[static_cast<std::size_t>(i)];
    f.t_s = 10.0 + i * 0.001;
    f.seq = static_cast<uint32_t>(i);
    f.raw[0] = i % 500 == 7 ? kNaN : rate[static_cast<std::size_t>(i)];
    f.raw[1] = std::strtod(fmt::format("{:.2f}", 23 + i * 1e-4).c_str(), nullptr);
  }
  return frames;
}

// Every channel of `dut` reads back as `frames` sent it, bit for bit.
void expect_stored(Database& db, const RunDutRecord& dut, const std::vector<DutFrame>& frames,
                   std::size_t count) {
  for (const ChannelRecord& ch : dut.channels) {
    std::size_t k = 0;
    ASSERT_TRUE(db.for_each_channel_block(ch.id, -1e9, 1e9,
                                          [&](std::span<const double> t, std::span<const double> v,
                                              std::span<const uint32_t>) {
                                            for (std::size_t i = 0; i < t.size(); ++i, ++k) {
                                              const DutFrame& f = frames[k];
                                              EXPECT_NEAR(t[i], f.t_s, 1e-9);
                                              const double want = f.raw[ch.index];
                                              if (std::isnan(want)) {
                                                EXPECT_TRUE(std::isnan(v[i]));
                                              } else {
                                                EXPECT_EQ(bits(v[i]), bits(want))
                                                    << ch.spec.name << " " << k;
                                              }
                                            }
                                            return true;
                                          })
                    .ok());
    EXPECT_EQ(k, count) << ch.spec.name;
  }
}

std::string chunks_of(Database& db, int64_t channel_id) {
  return query_text(db.handle(),
                    fmt::format("SELECT group_concat(n || ':' || encoding, ' ') FROM (SELECT n, "
                                "encoding FROM sample_chunks WHERE channel_id = {} ORDER BY t0_s)",
                                channel_id));
}

// Each commit writes a piece; the chunk that closes (at 4096 samples)
// replaces its pieces in its packed encoding; stopping closes the open one.
TEST(ChunkEncoding, ChunksAreWrittenInPiecesAndRewrittenWholeWhenTheyClose) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  RunDutRecord dut;
  {
    Database db = open_ok(path);
    dut = register_dut(db, 1);
  }
  const auto frames = frames_of(5000);
  auto writer = testing::start_ok(path, {.commit_interval = 1h});
  writer->push_frames(dut, std::span(frames).first(1000));
  ASSERT_TRUE(writer->flush().ok());
  writer->push_frames(dut, std::span(frames).subspan(1000, 1000));
  ASSERT_TRUE(writer->flush().ok());
  {
    Database db = open_ok(path);
    EXPECT_EQ(chunks_of(db, dut.channels[0].id), "1000:f32 1000:f32") << "two commits, two pieces";
    EXPECT_EQ(chunks_of(db, dut.channels[1].id), "1000:f64 1000:f64");
    expect_stored(db, dut, frames, 2000);
  }
  writer->push_frames(dut, std::span(frames).subspan(2000, 2500));  // past 4096
  ASSERT_TRUE(writer->flush().ok());
  {
    Database db = open_ok(path);
    EXPECT_EQ(chunks_of(db, dut.channels[0].id), "4096:f32+shuffle+zstd 404:f32");
    EXPECT_EQ(chunks_of(db, dut.channels[1].id), "4096:i32/1e2+shuffle+zstd 404:f64");
    expect_stored(db, dut, frames, 4500);
  }
  writer->push_frames(dut, std::span(frames).subspan(4500));
  writer->stop();
  Database db = open_ok(path);
  EXPECT_EQ(chunks_of(db, dut.channels[0].id), "4096:f32+shuffle+zstd 904:f32+shuffle+zstd")
      << "stopping closes the open chunk";
  EXPECT_EQ(chunks_of(db, dut.channels[1].id),
            "4096:i32/1e2+shuffle+zstd 904:i32/1e2+shuffle+zstd");
  expect_stored(db, dut, frames, 5000);
  // The chunk statistics are those of the whole chunk.
  EXPECT_EQ(query_int(db.handle(), fmt::format("SELECT vn FROM sample_chunks WHERE channel_id = {} "
                                               "ORDER BY t0_s LIMIT 1",
                                               dut.channels[0].id)),
            4096 - 9);
  // The decimated route reads the packed chunks (raw buckets and rollups).
  auto fine = db.decimated_samples(1, StreamKey{"TS-1", ""}, "temp_c", 10.0, 11.0, 2000);
  ASSERT_TRUE(fine.ok()) << fine.error().message;
  auto coarse = db.decimated_samples(1, StreamKey{"TS-1", ""}, "rate_z", 0, std::nullopt, 3);
  ASSERT_TRUE(coarse.ok()) << coarse.error().message;
}

// Chunks in the plain encodings (every file before schema v12, and open
// chunks' pieces) read as before, beside packed ones; a damaged packed
// BLOB is an error naming the chunk, not wrong numbers.
TEST(ChunkEncoding, PlainChunksStillReadAndDamageIsAnError) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  Database db = open_ok(path);
  const RunDutRecord dut = register_dut(db, 1);
  const int64_t ch = dut.channels[0].id;
  std::string f64, u16;
  internal::encode(Encoding::kF64, std::vector<double>{0.1, kNaN, -2.5}, f64);
  internal::encode(Encoding::kU16, std::vector<double>{7, 65535}, u16);
  std::string packed;
  const auto noise = f32_noise(1000, 0, 1e-4, 6);
  ASSERT_TRUE(internal::encode_closed(Encoding::kF32, noise, packed).zstd);
  sqlite3_stmt* st = nullptr;
  ASSERT_EQ(sqlite3_prepare_v2(db.handle(),
                               "INSERT INTO sample_chunks(channel_id, t0_s, period_s, n, seq0, "
                               "encoding, vn, data) VALUES(?1, ?2, 0.001, ?3, 0, ?4, 0, ?5)",
                               -1, &st, nullptr),
            SQLITE_OK);
  auto insert = [&](double t0, int n, const char* enc, const std::string& data) {
    sqlite3_bind_int64(st, 1, ch);
    sqlite3_bind_double(st, 2, t0);
    sqlite3_bind_int(st, 3, n);
    sqlite3_bind_text(st, 4, enc, -1, SQLITE_TRANSIENT);
    sqlite3_bind_blob(st, 5, data.data(), static_cast<int>(data.size()), SQLITE_TRANSIENT);
    EXPECT_EQ(sqlite3_step(st), SQLITE_DONE);
    sqlite3_reset(st);
  };
  insert(0.0, 3, "f64", f64);
  insert(1.0, 2, "u16", u16);
  insert(2.0, 1000, "f32+shuffle+zstd", packed);
  std::string i64(24, '\0');
  const int64_t ms[] = {12345, std::numeric_limits<int64_t>::min(), -7};
  std::memcpy(i64.data(), ms, sizeof ms);
  insert(3.5, 3, "i64/1e3", i64);
  std::vector<double> got;
  ASSERT_TRUE(db.for_each_channel_block(ch, -1, 4.9,
                                        [&](std::span<const double>, std::span<const double> v,
                                            std::span<const uint32_t>) {
                                          got.insert(got.end(), v.begin(), v.end());
                                          return true;
                                        })
                  .ok());
  ASSERT_EQ(got.size(), 1008u);
  EXPECT_EQ(got[1005], 12.345);
  EXPECT_TRUE(std::isnan(got[1006]));
  EXPECT_EQ(bits(got[1007]), bits(-0.007));
  EXPECT_EQ(got[0], 0.1);
  EXPECT_TRUE(std::isnan(got[1]));
  EXPECT_EQ(got[2], -2.5);
  EXPECT_EQ(got[3], 7);
  EXPECT_EQ(got[4], 65535);
  for (std::size_t i = 0; i < noise.size(); ++i) EXPECT_EQ(bits(got[5 + i]), bits(noise[i]));

  packed[packed.size() / 2] = static_cast<char>(packed[packed.size() / 2] ^ 0x55);
  insert(5.0, 1000, "f32+shuffle+zstd", packed);
  auto s = db.for_each_channel_block(ch, 4.0, 10,
                                     [&](std::span<const double>, std::span<const double>,
                                         std::span<const uint32_t>) { return true; });
  ASSERT_FALSE(s.ok()) << "a damaged chunk read as numbers";
  EXPECT_NE(s.error().message.find("f32+shuffle+zstd"), std::string::npos) << s.error().message;
  sqlite3_finalize(st);
}

// A schema-11 file (4 KiB pages, plain chunks, an open chunk's row grown
// in place) migrates to v12 with its chunks as they were, reads them, and a
// writer appends packed chunks after them.
TEST(ChunkEncoding, Schema11FileMigratesAndReadsBesidePackedChunks) {
  TempDir dir;
  const std::string path = dir.file("v11.db");
  std::string f32;
  const auto old_values = f32_noise(3000, 7e-5, 1.5e-4, 7);
  internal::encode(Encoding::kF32, old_values, f32);
  {
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    ASSERT_EQ(sqlite3_exec(raw,
                           "PRAGMA page_size=4096; CREATE TABLE meta(key TEXT PRIMARY KEY, "
                           "value TEXT NOT NULL);",
                           nullptr, nullptr, nullptr),
              SQLITE_OK);
    for (const auto& m : internal::migrations()) {
      if (m.version > 11) break;
      ASSERT_EQ(sqlite3_exec(raw, m.sql, nullptr, nullptr, nullptr), SQLITE_OK)
          << m.version << ": " << sqlite3_errmsg(raw);
      if (m.data_step != nullptr) {
        ASSERT_TRUE(m.data_step(raw, path, "2026-01-01T00:00:00.000Z").ok()) << m.version;
      }
    }
    ASSERT_EQ(sqlite3_exec(raw, "INSERT INTO meta VALUES('schema_version', '11')", nullptr, nullptr,
                           nullptr),
              SQLITE_OK);
    sqlite3_close(raw);
  }
  RunDutRecord dut;
  {
    Database db = open_ok(path);
    EXPECT_EQ(*db.schema_version(), kSchemaVersion);
    EXPECT_EQ(query_int(db.handle(), "PRAGMA page_size"), 4096) << "an old file keeps its pages";
    dut = register_dut(db, 1);
    sqlite3_stmt* st = nullptr;
    ASSERT_EQ(
        sqlite3_prepare_v2(db.handle(),
                           "INSERT INTO sample_chunks(channel_id, t0_s, period_s, n, seq0, "
                           "encoding, vn, data) VALUES(?1, 0, 0.001, 3000, 0, 'f32', 3000, ?2)",
                           -1, &st, nullptr),
        SQLITE_OK);
    sqlite3_bind_int64(st, 1, dut.channels[0].id);
    sqlite3_bind_blob(st, 2, f32.data(), static_cast<int>(f32.size()), SQLITE_STATIC);
    EXPECT_EQ(sqlite3_step(st), SQLITE_DONE);
    sqlite3_finalize(st);
  }
  auto frames = frames_of(5000);
  for (DutFrame& f : frames) f.t_s += 10;  // after the old chunk
  auto writer = testing::start_ok(path, {.commit_interval = 1h});
  writer->push_frames(dut, frames);
  writer->stop();
  Database db = open_ok(path);
  EXPECT_EQ(chunks_of(db, dut.channels[0].id),
            "3000:f32 4096:f32+shuffle+zstd 904:f32+shuffle+zstd");
  std::vector<double> got;
  ASSERT_TRUE(db.for_each_channel_block(dut.channels[0].id, -1, 1e9,
                                        [&](std::span<const double>, std::span<const double> v,
                                            std::span<const uint32_t>) {
                                          got.insert(got.end(), v.begin(), v.end());
                                          return true;
                                        })
                  .ok());
  ASSERT_EQ(got.size(), 8000u);
  for (std::size_t i = 0; i < old_values.size(); ++i) {
    EXPECT_EQ(bits(got[i]), bits(old_values[i])) << i;
  }
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const double want = frames[i].raw[0];
    if (std::isnan(want)) {
      EXPECT_TRUE(std::isnan(got[3000 + i]));
    } else {
      EXPECT_EQ(bits(got[3000 + i]), bits(want)) << i;
    }
  }
}

// Polls `done` until it holds or `limit` passes (the writer's rounds are on
// its own clock: there is nothing else to wait on from outside).
template <class F>
bool eventually(F done, std::chrono::milliseconds limit = 30s) {
  const auto deadline = std::chrono::steady_clock::now() + limit;
  while (!done()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(5ms);
  }
  return true;
}

// A writer killed with a chunk open leaves its pieces; the next writer on
// the file (the restarted daemon) merges them into one packed chunk, in a
// transaction. The samples read the same before (pieces) and after
// (packed), and the new writer's samples go into chunks of their own.
TEST(ChunkEncoding, PiecesLeftByAKilledWriterArePackedByTheNextWriter) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  RunDutRecord dut;
  {
    Database db = open_ok(path);
    dut = register_dut(db, 1);
  }
  const auto frames = frames_of(5000);
  const pid_t pid = fork();
  ASSERT_NE(pid, -1);
  if (pid == 0) {
    auto w = SampleWriter::start(path, {.commit_interval = std::chrono::hours(1)});
    if (!w) _exit(2);
    for (int part = 0; part < 3; ++part) {
      (*w)->push_frames(dut,
                        std::span(frames).subspan(static_cast<std::size_t>(part) * 1000, 1000));
      if (!(*w)->flush().ok()) _exit(3);
    }
    _exit(0);  // no stop(), no destructors: as kill -9 after the third commit
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  ASSERT_EQ(WEXITSTATUS(status), 0);
  {
    Database db = open_ok(path);
    EXPECT_EQ(chunks_of(db, dut.channels[0].id), "1000:f32 1000:f32 1000:f32");
    expect_stored(db, dut, frames, 3000);  // read as pieces
  }
  auto writer = testing::start_ok(path, {.commit_interval = 20ms});
  {
    Database db = open_ok(path);
    const int64_t ch0 = dut.channels[0].id;
    const int64_t ch1 = dut.channels[1].id;
    EXPECT_TRUE(eventually([&] {
      return chunks_of(db, ch0) == "3000:f32+shuffle+zstd" &&
             chunks_of(db, ch1) == "3000:i32/1e2+shuffle+zstd";
    })) << chunks_of(db, ch0)
        << " / " << chunks_of(db, ch1);
    expect_stored(db, dut, frames, 3000);  // read packed
    EXPECT_EQ(query_int(db.handle(), fmt::format("SELECT vn FROM sample_chunks WHERE channel_id = "
                                                 "{}",
                                                 ch0)),
              3000 - 6)
        << "the merged chunk's statistics are the whole chunk's";
  }
  writer->push_frames(dut, std::span(frames).subspan(3000));
  writer->stop();
  Database db = open_ok(path);
  EXPECT_EQ(chunks_of(db, dut.channels[0].id), "3000:f32+shuffle+zstd 2000:f32+shuffle+zstd");
  expect_stored(db, dut, frames, 5000);
  EXPECT_TRUE(testing::integrity_ok(db));
}

// A DUT with eight f32 channels (their chunks all close at the same frame).
RunDutRecord register_wide_dut(Database& db, int64_t run_id) {
  RunDutRecord r;
  r.run_id = run_id;
  r.dut.serial = "W-1";
  r.primary_axis = "x";
  r.rate_hz = 1000;
  r.seq_modulo = 65536;
  EXPECT_TRUE(db.exec(fmt::format("INSERT INTO runs(id, schedule_name, state, started_utc) "
                                  "VALUES({}, 's', 'completed', 'x');"
                                  "INSERT INTO duts(serial, model, first_seen_utc) VALUES('W-1', "
                                  "'wide', 'x')",
                                  run_id))
                  .ok());
  r.dut.id = sqlite3_last_insert_rowid(db.handle());
  EXPECT_TRUE(db.exec(fmt::format("INSERT INTO run_duts(run_id, dut_id, position, primary_axis, "
                                  "rate_hz, seq_modulo) VALUES({}, {}, 0, 'x', 1000, 65536)",
                                  run_id, r.dut.id))
                  .ok());
  for (int idx = 0; idx < 8; ++idx) {
    const ChannelSpec s{fmt::format("ch{}", idx), "deg/s", ChannelKind::kOther, "", 1};
    EXPECT_TRUE(db.exec(fmt::format("INSERT INTO channels(run_id, dut_id, idx, name, unit, kind, "
                                    "axis, scale) VALUES({}, {}, {}, '{}', '{}', '{}', '', 1)",
                                    run_id, r.dut.id, idx, s.name, s.unit, to_string(s.kind)))
                    .ok());
    r.channels.push_back({sqlite3_last_insert_rowid(db.handle()), run_id, r.dut.id, idx, s});
  }
  return r;
}

// Chunks that close together (every channel of a DUT at 4096 samples) are
// not all packed by the commit in which they close: each commit packs a
// few and leaves the rest as pieces for the next ones, so no commit packs
// them all. Every state between reads the same samples.
TEST(ChunkEncoding, ChunksClosingTogetherArePackedOverSeveralCommits) {
  TempDir dir;
  const std::string path = dir.file("station.db");
  RunDutRecord dut;
  {
    Database db = open_ok(path);
    dut = register_wide_dut(db, 1);
  }
  std::vector<DutFrame> frames(4600);
  for (std::size_t c = 0; c < 8; ++c) {
    const auto v = f32_noise(frames.size(), 1e-3 * static_cast<double>(c), 1e-4,
                             static_cast<unsigned>(c + 11));
    for (std::size_t i = 0; i < frames.size(); ++i) {
      frames[i].t_s = 5.0 + static_cast<double>(i) * 0.001;
      frames[i].seq = static_cast<uint32_t>(i);
      frames[i].raw[c] = v[i];
    }
  }
  const auto packed = [&](Database& db) {
    return query_int(db.handle(),
                     "SELECT count(*) FROM sample_chunks WHERE n = 4096 AND "
                     "encoding LIKE '%zstd'");
  };
  const auto rows = [&](Database& db) {
    return query_int(db.handle(), "SELECT count(*) FROM sample_chunks");
  };
  auto writer = testing::start_ok(path, {.commit_interval = std::chrono::hours(1)});
  writer->push_frames(dut, std::span(frames).first(2000));
  ASSERT_TRUE(writer->flush().ok());
  writer->push_frames(dut, std::span(frames).subspan(2000, 2500));  // every chunk closes at 4096
  ASSERT_TRUE(writer->flush().ok());
  {
    Database db = open_ok(path);
    const int64_t first = packed(db);
    EXPECT_GT(first, 0) << "the commit in which they close packs some";
    EXPECT_LT(first, 8) << "but not all eight";
    expect_stored(db, dut, frames, 4500);
  }
  // The next commits (one frame each) pack the rest.
  int commits = 0;
  for (std::size_t i = 4500; i < frames.size(); ++i) {
    writer->push_frames(dut, std::span(frames).subspan(i, 1));
    ASSERT_TRUE(writer->flush().ok());
    ++commits;
    Database db = open_ok(path);
    expect_stored(db, dut, frames, i + 1);
    if (packed(db) == 8) break;
  }
  EXPECT_LE(commits, 7) << "every chunk packed within a few commits";
  writer->push_frames(dut, std::span(frames).subspan(4500 + static_cast<std::size_t>(commits)));
  writer->stop();
  Database db = open_ok(path);
  EXPECT_EQ(packed(db), 8);
  EXPECT_EQ(rows(db), 16) << "eight packed chunks of 4096 and eight of 504";
  expect_stored(db, dut, frames, frames.size());
  EXPECT_TRUE(testing::integrity_ok(db));
}

TEST(ChunkEncoding, NewFilesHaveTwoKibPages) {
  TempDir dir;
  Database db = open_ok(dir.file("new.db"));
  EXPECT_EQ(query_int(db.handle(), "PRAGMA page_size"), 2048);
}

}  // namespace
}  // namespace gyrotherm::storage

// The Allan deviation of a streamed series (allan.h, sample_source.h): in
// memory it is exactly the span form's result; spilled to a scratch file it
// differs by rounding only, with the same noise identified; the exact median
// spacing survives thousands of distinct spacings; bad input is named.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/analysis/allan.h"
#include "gyrotherm/analysis/sample_source.h"

namespace gyrotherm::analysis {
namespace {

struct Series {
  std::vector<double> t_s, rate_dph;
};

enum class Noise { kWhite, kWalk, kWhiteAndWalk };

// n samples at 100 Hz on an offset of 1e4 °/h (digits a careless sum
// loses); `jitter_s` adds a uniform jitter to each time stamp.
Series make(std::size_t n, Noise noise, uint64_t seed, double jitter_s = 0) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(-jitter_s, jitter_s);
  Series s;
  double walk = 0;
  for (std::size_t i = 0; i < n; ++i) {
    s.t_s.push_back(100.0 + static_cast<double>(i) * 0.01 + (jitter_s > 0 ? u(rng) : 0.0));
    walk += 0.05 * g(rng);
    const double white = g(rng);
    double v = 1e4;
    if (noise != Noise::kWalk) v += 3.0 * white;
    if (noise != Noise::kWhite) v += walk;
    s.rate_dph.push_back(v);
  }
  return s;
}

void expect_same_curve(const AllanResult& a, const AllanResult& b, double rel_tol,
                       const std::string& what) {
  SCOPED_TRACE(what);
  EXPECT_EQ(a.n_samples, b.n_samples);
  EXPECT_EQ(a.tau0_s, b.tau0_s);
  ASSERT_EQ(a.m, b.m);
  ASSERT_EQ(a.adev_dph.size(), b.adev_dph.size());
  for (std::size_t j = 0; j < a.m.size(); ++j) {
    if (rel_tol == 0) {
      EXPECT_EQ(a.adev_dph[j], b.adev_dph[j]) << "m = " << a.m[j];
    } else {
      EXPECT_NEAR(a.adev_dph[j], b.adev_dph[j], rel_tol * a.adev_dph[j]) << "m = " << a.m[j];
    }
    EXPECT_EQ(a.noise_alpha[j], b.noise_alpha[j]) << "m = " << a.m[j];
    EXPECT_EQ(a.edf[j], b.edf[j]) << "m = " << a.m[j];
  }
}

TEST(AllanStreamed, InMemoryIsExactlyTheSpanResult) {
  // Lengths around the prefix sums' 4096-sample blocks and a two-thread
  // sweep (>= 2^18); blocks of the source that cut across them.
  const std::vector<std::size_t> lengths = {2, 3, 31, 4095, 4096, 4097, 65536, 65537, 300001};
  for (const std::size_t n : lengths) {
    for (const Noise noise : {Noise::kWhite, Noise::kWhiteAndWalk}) {
      const Series s = make(n, noise, n);
      auto span_result = allan_deviation(s.t_s, s.rate_dph);
      ASSERT_TRUE(span_result) << span_result.error().message;
      for (const std::size_t block : {std::size_t{1}, std::size_t{1000}, std::size_t{70000}}) {
        auto streamed = allan_deviation(span_source(s.t_s, s.rate_dph, block));
        ASSERT_TRUE(streamed) << streamed.error().message;
        expect_same_curve(*span_result, *streamed, 0.0,
                          "n = " + std::to_string(n) + ", block = " + std::to_string(block));
      }
    }
  }
}

TEST(AllanStreamed, SpilledDiffersByRoundingOnly) {
  // Prefix sums in the scratch file, swept in windows of 4096: lengths
  // 2^k and 2^k +- 1 across window edges, m both below and above the window.
  const StreamLimits spill{.prefix_in_memory = 2, .window = 4096, .scratch_dir = ""};
  for (const std::size_t n :
       {std::size_t{4095}, std::size_t{4097}, std::size_t{1} << 16, (std::size_t{1} << 16) + 1,
        (std::size_t{1} << 17) - 1, std::size_t{200003}}) {
    for (const Noise noise : {Noise::kWhite, Noise::kWalk, Noise::kWhiteAndWalk}) {
      const Series s = make(n, noise, 7 * n + static_cast<int>(noise));
      auto in_memory = allan_deviation(s.t_s, s.rate_dph);
      ASSERT_TRUE(in_memory) << in_memory.error().message;
      auto spilled = allan_deviation(span_source(s.t_s, s.rate_dph, 3001), {}, spill);
      ASSERT_TRUE(spilled) << spilled.error().message;
      expect_same_curve(*in_memory, *spilled, 1e-12, "n = " + std::to_string(n));
      EXPECT_EQ(in_memory->noise.angle_random_walk_dprh.kind,
                spilled->noise.angle_random_walk_dprh.kind);
    }
  }
}

TEST(AllanStreamed, TheNoiseIsIdentifiedAsInMemory) {
  // White noise, a random walk, and both: the running sums' alpha is the
  // in-memory one's at every tau with enough block means (this is what
  // sets each point's edf).
  const StreamLimits spill{.prefix_in_memory = 2, .window = 4096, .scratch_dir = ""};
  int identified = 0;
  for (uint64_t seed = 1; seed <= 6; ++seed) {
    for (const Noise noise : {Noise::kWhite, Noise::kWalk, Noise::kWhiteAndWalk}) {
      const Series s = make(40000, noise, seed * 31 + static_cast<int>(noise));
      auto a = allan_deviation(s.t_s, s.rate_dph);
      auto b = allan_deviation(span_source(s.t_s, s.rate_dph), {}, spill);
      ASSERT_TRUE(a && b);
      EXPECT_EQ(a->noise_alpha, b->noise_alpha) << "seed " << seed;
      for (std::size_t j = 0; j < a->m.size(); ++j) {
        identified += 40000 / a->m[j] >= kMinNoiseIdAverages ? 1 : 0;
      }
    }
  }
  EXPECT_GT(identified, 100);  // the comparison covered many taus
}

TEST(AllanStreamed, TheMedianSpacingIsExactWithThousandsOfDistinctSpacings) {
  // Jittered stamps: every spacing differs, so the median is selected by
  // passes over the bits of the spacings; odd and even counts of spacings.
  for (const std::size_t n : {std::size_t{20001}, std::size_t{20002}}) {
    const Series s = make(n, Noise::kWhite, n, 0.002);
    auto a = allan_deviation(s.t_s, s.rate_dph);
    auto b = allan_deviation(span_source(s.t_s, s.rate_dph, 999));
    ASSERT_TRUE(a && b);
    EXPECT_EQ(a->tau0_s, b->tau0_s) << "n = " << n;
    std::vector<double> d;
    for (std::size_t i = 1; i < n; ++i) d.push_back(s.t_s[i] - s.t_s[i - 1]);
    std::sort(d.begin(), d.end());
    const double median = d.size() % 2 == 1
                              ? d[d.size() / 2]
                              : d[d.size() / 2 - 1] + (d[d.size() / 2] - d[d.size() / 2 - 1]) / 2;
    EXPECT_EQ(b->tau0_s, median);
    auto scan = scan_series(span_source(s.t_s, s.rate_dph));
    ASSERT_TRUE(scan);
    EXPECT_EQ(scan->n, n);
    EXPECT_EQ(scan->t_first_s, s.t_s.front());
    EXPECT_EQ(scan->t_last_s, s.t_s.back());
  }
}

TEST(AllanStreamed, BadInputIsNamedAndNothingIsComputed) {
  Series s = make(10000, Noise::kWhite, 3);
  const StreamLimits spill{.prefix_in_memory = 2, .window = 4096, .scratch_dir = ""};
  s.rate_dph[5000] = NAN;
  auto r = allan_deviation(span_source(s.t_s, s.rate_dph, 777), {}, spill);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("sample 5000"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("not finite"), std::string::npos) << r.error().message;
  s.rate_dph[5000] = 1.0;
  s.t_s[7000] = s.t_s[6999];
  r = allan_deviation(span_source(s.t_s, s.rate_dph), {}, spill);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("sample 7000"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("does not increase"), std::string::npos) << r.error().message;
  s.t_s[7000] = s.t_s[6999] + 0.01;

  const SampleSource failing = [](const SampleBlock&) -> Status {
    return Error::Transient("database is locked");
  };
  r = allan_deviation(failing);
  ASSERT_FALSE(r);
  EXPECT_TRUE(r.error().transient);
  EXPECT_NE(r.error().message.find("database is locked"), std::string::npos);

  const StreamLimits nowhere{
      .prefix_in_memory = 2, .window = 4096, .scratch_dir = "/nonexistent/gyrotherm-scratch"};
  r = allan_deviation(span_source(s.t_s, s.rate_dph), {}, nowhere);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("/nonexistent/gyrotherm-scratch"), std::string::npos)
      << r.error().message;

  r = allan_deviation(span_source(s.t_s, s.rate_dph), {.taus = TauSet::kAll}, spill);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("'all'"), std::string::npos) << r.error().message;

  r = allan_deviation(span_source(std::span(s.t_s).first(1), std::span(s.rate_dph).first(1)));
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("1 sample(s)"), std::string::npos) << r.error().message;

  const StreamLimits tiny_window{.prefix_in_memory = 2, .window = 100, .scratch_dir = ""};
  r = allan_deviation(span_source(s.t_s, s.rate_dph), {}, tiny_window);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("window = 100"), std::string::npos) << r.error().message;
}

TEST(AllanStreamed, ASourceThatChangesBetweenPassesIsAnError) {
  // A soak still being written: the second pass sees more samples than the
  // first. The analysis takes the first pass's n; fewer is an error.
  const Series s = make(9000, Noise::kWhite, 5);
  int calls = 0;
  const SampleSource shrinking = [&](const SampleBlock& block) -> Status {
    const std::size_t n = ++calls == 1 ? s.t_s.size() : s.t_s.size() - 10;
    block(std::span(s.t_s).first(n), std::span(s.rate_dph).first(n));
    return Status::Ok();
  };
  auto r = allan_deviation(shrinking);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("changed between two passes"), std::string::npos)
      << r.error().message;
  calls = 0;
  const SampleSource growing = [&](const SampleBlock& block) -> Status {
    const std::size_t n = ++calls == 1 ? s.t_s.size() - 10 : s.t_s.size();
    block(std::span(s.t_s).first(n), std::span(s.rate_dph).first(n));
    return Status::Ok();
  };
  auto g = allan_deviation(growing);
  ASSERT_TRUE(g) << g.error().message;
  auto first = allan_deviation(std::span(s.t_s).first(s.t_s.size() - 10),
                               std::span(s.rate_dph).first(s.t_s.size() - 10));
  ASSERT_TRUE(first);
  expect_same_curve(*first, *g, 0.0, "growing source");
}

TEST(SampleSourcePrefetched, GivesTheSameBlocksStopsWhenAskedAndPassesErrors) {
  const Series s = make(50000, Noise::kWhiteAndWalk, 11);
  auto a = allan_deviation(s.t_s, s.rate_dph);
  const StreamLimits spill{.prefix_in_memory = 2, .window = 4096, .scratch_dir = ""};
  for (const StreamLimits& limits : {StreamLimits{}, spill}) {
    auto b = allan_deviation(prefetched(span_source(s.t_s, s.rate_dph, 1000), 2), {}, limits);
    ASSERT_TRUE(a && b) << (b ? "" : b.error().message);
    expect_same_curve(*a, *b, limits.prefix_in_memory == 2 ? 1e-12 : 0.0, "prefetched");
  }
  // A pass stopped after 3 blocks: 3 blocks seen, the reader stopped.
  int seen = 0;
  std::size_t read = 0;
  const SampleSource counting = [&](const SampleBlock& block) -> Status {
    for (std::size_t b = 0; b < s.t_s.size(); b += 100) {
      ++read;
      if (!block(std::span(s.t_s).subspan(b, 100), std::span(s.rate_dph).subspan(b, 100))) break;
    }
    return Status::Ok();
  };
  Status st = prefetched(counting, 4)([&](std::span<const double> t, std::span<const double>) {
    EXPECT_EQ(t.front(), s.t_s[100 * static_cast<std::size_t>(seen)]);
    return ++seen < 3;
  });
  EXPECT_TRUE(st.ok());
  EXPECT_EQ(seen, 3);
  EXPECT_LE(read, 3u + 4u + 1u);  // at most max_blocks ahead
  const SampleSource failing = [&](const SampleBlock& block) -> Status {
    block(std::span(s.t_s).first(10), std::span(s.rate_dph).first(10));
    return Error::Transient("database is locked");
  };
  int blocks = 0;
  st = prefetched(failing)([&](std::span<const double>, std::span<const double>) {
    ++blocks;
    return true;
  });
  ASSERT_FALSE(st.ok());
  EXPECT_EQ(st.error().message, "database is locked");
  EXPECT_EQ(blocks, 1);
}

}  // namespace
}  // namespace gyrotherm::analysis

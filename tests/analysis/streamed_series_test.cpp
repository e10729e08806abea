// The analysis series of a streamed window (table1.h): exactly the span
// form's on the same samples, binned or used as is, with gaps, jitter, a
// partial last bin and a single sample; bad samples named.
#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "gyrotherm/analysis/sample_source.h"
#include "gyrotherm/analysis/table1.h"

namespace gyrotherm::analysis {
namespace {

struct Window {
  std::vector<GyroSample> gyro;
  std::vector<TemperatureSample> temps;
  std::vector<double> t_s, rate_dph;  // the gyro's columns, for the source
  void columns() {
    t_s.clear();
    rate_dph.clear();
    for (const GyroSample& g : gyro) {
      t_s.push_back(g.t_s);
      rate_dph.push_back(g.rate_dph);
    }
  }
};

// `rate_hz` gyro samples over `span_s`, a gap [gap_from_s, gap_to_s), time
// stamps jittered by up to `jitter_s`; temperatures at 1 Hz from 0.3 s.
Window make(double rate_hz, double span_s, uint64_t seed, double jitter_s = 0,
            double gap_from_s = -1, double gap_to_s = -1) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(-jitter_s, jitter_s);
  Window w;
  const auto n = static_cast<std::size_t>(span_s * rate_hz);
  for (std::size_t i = 0; i < n; ++i) {
    const double t = 10.0 + static_cast<double>(i) / rate_hz + (jitter_s > 0 ? u(rng) : 0.0);
    if (t >= gap_from_s && t < gap_to_s) continue;
    w.gyro.push_back({t, 0.8 + 0.01 * t + g(rng), 0, 0, 0});
  }
  for (double t = 10.3; t < 10.0 + span_s; t += 1.0) {
    w.temps.push_back({t, 20.0, 20.0, 20.0 + 0.001 * t, 19.9 + 0.001 * t});
  }
  w.columns();
  return w;
}

void expect_same_series(const AnalysisSeries& a, const AnalysisSeries& b, const std::string& what) {
  SCOPED_TRACE(what);
  EXPECT_EQ(a.binned, b.binned);
  EXPECT_EQ(a.bin_s, b.bin_s);
  EXPECT_EQ(a.t_s, b.t_s);
  EXPECT_EQ(a.rate_dph, b.rate_dph);
  EXPECT_EQ(a.top_c, b.top_c);
  EXPECT_EQ(a.side_c, b.side_c);
}

TEST(AnalysisSeriesStreamed, IsExactlyTheSpanSeries) {
  struct Case {
    std::string name;
    Window w;
    double bin_s;
  };
  std::vector<Case> cases;
  cases.push_back({"10 Hz", make(10, 1200, 1), 1.0});
  cases.push_back({"1 kHz, partial last bin", make(1000, 120.4567, 2), 1.0});
  cases.push_back({"100 Hz with a gap", make(100, 600, 3, 0, 200.5, 260.25), 1.0});
  cases.push_back({"100 Hz jittered", make(100, 300, 4, 0.003), 1.0});
  cases.push_back({"1 Hz, used as is", make(1, 500, 5), 1.0});
  cases.push_back({"10 Hz in 0.5 s bins", make(10, 333, 6), 0.5});
  cases.push_back({"one sample", make(1, 1, 7), 1.0});
  // A burst at 100 Hz, then 0.5 Hz: used as is (median spacing 2 s), the
  // burst too dense for the first pass to have kept the samples.
  Window burst = make(100, 0.5, 8);
  const Window sparse = make(0.5, 800, 9);
  for (const GyroSample& g : sparse.gyro) burst.gyro.push_back({g.t_s + 1.0, g.rate_dph, 0, 0, 0});
  burst.temps = sparse.temps;
  burst.columns();
  cases.push_back({"a burst, then sparse", burst, 1.0});
  int compared = 0;
  for (const Case& c : cases) {
    auto span = make_analysis_series(c.w.gyro, c.w.temps, c.bin_s);
    ASSERT_TRUE(span) << c.name << ": " << span.error().message;
    for (const std::size_t block : {std::size_t{1}, std::size_t{7}, std::size_t{4096}}) {
      std::optional<SeriesScan> scan;
      auto streamed = make_analysis_series(span_source(c.w.t_s, c.w.rate_dph, block), c.w.temps,
                                           c.bin_s, &scan);
      ASSERT_TRUE(streamed) << c.name << ": " << streamed.error().message;
      expect_same_series(*span, *streamed, c.name + ", block " + std::to_string(block));
      auto ahead = make_analysis_series(prefetched(span_source(c.w.t_s, c.w.rate_dph, block), 3),
                                        c.w.temps, c.bin_s);
      ASSERT_TRUE(ahead) << c.name << ": " << ahead.error().message;
      expect_same_series(*span, *ahead, c.name + ", prefetched, block " + std::to_string(block));
      ASSERT_TRUE(scan);
      EXPECT_EQ(scan->n, c.w.gyro.size());
      ++compared;
    }
    EXPECT_FALSE(span->rate_dph.empty()) << c.name;
  }
  EXPECT_EQ(compared, 24);
}

TEST(AnalysisSeriesStreamed, BadSamplesAreNamed) {
  Window w = make(10, 60, 8);
  w.rate_dph[12] = INFINITY;
  auto r = make_analysis_series(span_source(w.t_s, w.rate_dph, 5), w.temps, 1.0);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("gyro sample 12"), std::string::npos) << r.error().message;
  w.rate_dph[12] = 0;
  w.t_s[30] = w.t_s[29];
  r = make_analysis_series(span_source(w.t_s, w.rate_dph, 5), w.temps, 1.0);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("gyro sample 30"), std::string::npos) << r.error().message;
  EXPECT_NE(r.error().message.find("does not increase"), std::string::npos) << r.error().message;

  r = make_analysis_series(span_source({}, {}), w.temps, 1.0);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("no gyro samples"), std::string::npos);
  w.t_s[30] = w.t_s[29] + 0.1;
  r = make_analysis_series(span_source(w.t_s, w.rate_dph), {}, 1.0);
  ASSERT_FALSE(r);
  EXPECT_NE(r.error().message.find("no temperature samples"), std::string::npos);
  const SampleSource failing = [](const SampleBlock&) -> Status {
    return Error::Transient("disk I/O error");
  };
  r = make_analysis_series(failing, w.temps, 1.0);
  ASSERT_FALSE(r);
  EXPECT_TRUE(r.error().transient);
  EXPECT_NE(r.error().message.find("disk I/O error"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm::analysis

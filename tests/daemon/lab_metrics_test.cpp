// The metrics of issue 19 (docs/api.md "Metrics"): interlocks tripped and
// the database's file system on every station; the gyrotherm_lab_* series
// only on a station with a [lab] (its status has a `lab` object).
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <optional>
#include <sstream>
#include <string>

#include "gyrotherm/api/metrics.h"

namespace gyrotherm::api {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

// The value of the sample `series` (name and labels exactly as exposed).
std::optional<double> sample(const std::string& text, const std::string& series) {
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) {
    if (line.rfind(series + " ", 0) == 0) return std::stod(line.substr(series.size() + 1));
  }
  return std::nullopt;
}

station::StatusSnapshot station() {
  station::StatusSnapshot s;
  s.state = "acquiring";
  s.interlocks.push_back({"probe_disagreement", "top and side differ"});
  s.interlocks.push_back({"chamber_alarm", "alarm"});
  s.storage_free_bytes = int64_t{5} << 30;
  s.storage_size_bytes = int64_t{100} << 30;
  return s;
}

TEST(LabMetrics, EveryStationHasInterlocksAndStorageSpace) {
  const Metrics metrics;
  const std::string text = metrics.scrape(station(), {});
  EXPECT_EQ(sample(text, "gyrotherm_interlocks_tripped"), 2.0);
  EXPECT_EQ(sample(text, "gyrotherm_storage_free_bytes"), 5.0 * (1 << 30));
  EXPECT_EQ(sample(text, "gyrotherm_storage_size_bytes"), 100.0 * (1 << 30));
  EXPECT_THAT(text, Not(HasSubstr("gyrotherm_lab_")));

  // Unknown space (statvfs failed): no sample rather than a made-up 0.
  station::StatusSnapshot unknown = station();
  unknown.storage_free_bytes.reset();
  unknown.interlocks.clear();
  const std::string t2 = metrics.scrape(unknown, {});
  EXPECT_EQ(sample(t2, "gyrotherm_storage_free_bytes"), std::nullopt);
  EXPECT_EQ(sample(t2, "gyrotherm_interlocks_tripped"), 0.0);
}

TEST(LabMetrics, LabSeriesOnlyWithALab) {
  const Metrics metrics;
  station::StatusSnapshot s = station();
  lab::RelayStatus r;
  r.station_id = "st-07";
  r.state = "connected";
  r.pending = 12;
  r.pending_bytes = 3400;
  r.oldest_pending_age_s = 2.5;
  r.sent_total = 1000;
  r.batches_total = 4;
  r.redelivered_total = 7;
  r.errors_total = 2;
  r.last_lag_s = 0.75;
  s.lab = r;
  const std::string text = metrics.scrape(s, {});
  for (const char* state : {"disabled", "connecting", "backoff", "refused", "stopped"}) {
    EXPECT_EQ(sample(text, std::string("gyrotherm_lab_relay_state{state=\"") + state + "\"}"), 0.0)
        << state;
  }
  EXPECT_EQ(sample(text, "gyrotherm_lab_relay_state{state=\"connected\"}"), 1.0);
  EXPECT_EQ(sample(text, "gyrotherm_lab_outbox_pending_records"), 12.0);
  EXPECT_EQ(sample(text, "gyrotherm_lab_outbox_pending_bytes"), 3400.0);
  EXPECT_EQ(sample(text, "gyrotherm_lab_outbox_oldest_age_seconds"), 2.5);
  EXPECT_EQ(sample(text, "gyrotherm_lab_relay_sent_records_total"), 1000.0);
  EXPECT_EQ(sample(text, "gyrotherm_lab_relay_batches_total"), 4.0);
  EXPECT_EQ(sample(text, "gyrotherm_lab_relay_redelivered_records_total"), 7.0);
  EXPECT_EQ(sample(text, "gyrotherm_lab_relay_errors_total"), 2.0);
  EXPECT_EQ(sample(text, "gyrotherm_lab_relay_lag_seconds"), 0.75);
  EXPECT_THAT(text, HasSubstr("# TYPE gyrotherm_lab_relay_sent_records_total counter"));
  EXPECT_THAT(text, HasSubstr("# TYPE gyrotherm_lab_relay_lag_seconds gauge"));

  // Nothing pending: the oldest age is 0; no batch yet: no lag sample.
  r.state = "disabled";
  r.pending = 0;
  r.oldest_pending_age_s.reset();
  r.last_lag_s.reset();
  s.lab = r;
  const std::string t2 = metrics.scrape(s, {});
  EXPECT_EQ(sample(t2, "gyrotherm_lab_relay_state{state=\"disabled\"}"), 1.0);
  EXPECT_EQ(sample(t2, "gyrotherm_lab_relay_state{state=\"connected\"}"), 0.0);
  EXPECT_EQ(sample(t2, "gyrotherm_lab_outbox_oldest_age_seconds"), 0.0);
  EXPECT_EQ(sample(t2, "gyrotherm_lab_relay_lag_seconds"), std::nullopt);
}

}  // namespace
}  // namespace gyrotherm::api

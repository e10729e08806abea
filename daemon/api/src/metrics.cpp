#include "gyrotherm/api/metrics.h"

#include <prometheus/histogram.h>
#include <prometheus/metric_family.h>
#include <prometheus/registry.h>
#include <prometheus/text_serializer.h>

#include <cmath>
#include <vector>

namespace gyrotherm::api {

namespace {

using prometheus::ClientMetric;
using prometheus::MetricFamily;
using prometheus::MetricType;

// Builds the families read from the status at scrape time.
class Families {
 public:
  std::vector<MetricFamily>& all() { return families_; }

  void counter(std::string name, std::string help, double value,
               std::vector<ClientMetric::Label> labels = {}) {
    ClientMetric m;
    m.label = std::move(labels);
    m.counter.value = value;
    add(std::move(name), std::move(help), MetricType::Counter, std::move(m));
  }
  void gauge(std::string name, std::string help, double value,
             std::vector<ClientMetric::Label> labels = {}) {
    ClientMetric m;
    m.label = std::move(labels);
    m.gauge.value = value;
    add(std::move(name), std::move(help), MetricType::Gauge, std::move(m));
  }
  // A gauge that is absent (no sample) while the value is unknown.
  void gauge(std::string name, std::string help, const std::optional<double>& value,
             std::vector<ClientMetric::Label> labels = {}) {
    if (value && std::isfinite(*value)) {
      gauge(std::move(name), std::move(help), *value, std::move(labels));
    } else {
      family(std::move(name), std::move(help), MetricType::Gauge);
    }
  }

 private:
  MetricFamily& family(std::string name, std::string help, MetricType type) {
    for (auto& f : families_) {
      if (f.name == name) return f;
    }
    families_.push_back(MetricFamily{std::move(name), std::move(help), type, {}});
    return families_.back();
  }
  void add(std::string name, std::string help, MetricType type, ClientMetric m) {
    family(std::move(name), std::move(help), type).metric.push_back(std::move(m));
  }
  std::vector<MetricFamily> families_;
};

const prometheus::Histogram::BucketBoundaries kModbusBuckets = {
    0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5};
const prometheus::Histogram::BucketBoundaries kCommitBuckets = {
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0};

}  // namespace

Metrics::Metrics() : registry_(std::make_shared<prometheus::Registry>()) {
  auto& modbus = prometheus::BuildHistogram()
                     .Name("gyrotherm_modbus_request_seconds")
                     .Help("Wall time of each Modbus request that reached a device")
                     .Register(*registry_);
  modbus_chamber_s_ = &modbus.Add({{"device", "chamber"}}, kModbusBuckets);
  modbus_probes_s_ = &modbus.Add({{"device", "probes"}}, kModbusBuckets);
  commit_s_ = &prometheus::BuildHistogram()
                   .Name("gyrotherm_db_commit_seconds")
                   .Help("Wall time of each sample-writer commit (one transaction)")
                   .Register(*registry_)
                   .Add({}, kCommitBuckets);
}

Metrics::~Metrics() = default;

void Metrics::observe_modbus(std::string_view device, double seconds) {
  (device == "chamber" ? modbus_chamber_s_ : modbus_probes_s_)->Observe(seconds);
}

void Metrics::observe_commit(double seconds) { commit_s_->Observe(seconds); }

std::string Metrics::scrape(const station::StatusSnapshot& s, const ServerFigures& server) const {
  Families f;
  f.gauge("gyrotherm_up", "1 while the daemon serves", 1.0);
  f.gauge("gyrotherm_uptime_seconds", "Wall seconds since the daemon started", s.uptime_s);
  f.gauge("gyrotherm_time_scale", "Station seconds per wall second (1 on a real station)",
          s.time_scale);
  for (std::string_view state : kStatesForMetrics) {
    f.gauge("gyrotherm_state", "1 for the station's current state, 0 for the others",
            state == s.state ? 1.0 : 0.0, {{"state", std::string(state)}});
  }
  f.gauge("gyrotherm_interlocks_tripped", "Interlocks tripped now",
          static_cast<double>(s.interlocks.size()));
  f.gauge("gyrotherm_queue_length", "Queue entries waiting", s.queue_length);
  f.gauge("gyrotherm_queue_held", "1 while the queue is held (stop, abort, failed run)",
          s.queue_held ? 1.0 : 0.0);
  const auto temp = [&](const char* sensor, const std::optional<double>& v) {
    f.gauge("gyrotherm_temperature_celsius", "Latest temperature, degC", v, {{"sensor", sensor}});
  };
  temp("setpoint", s.setpoint_c);
  temp("chamber", s.chamber_c);
  temp("top", s.top_c);
  temp("side", s.side_c);
  f.gauge("gyrotherm_gradient_celsius", "Shell gradient top - side, degC", s.gradient_c);
  f.gauge("gyrotherm_gyro_rate_dph", "Gyro rate, mean of the last full station second, deg/h",
          s.gyro_rate_dph);
  f.gauge("gyrotherm_gyro_samples_per_second", "Gyro samples per station second",
          s.gyro_samples_per_s);

  const auto& g = s.gyro;
  f.gauge("gyrotherm_gyro_connected", "1 while the gyro's serial port is open",
          g.connected ? 1.0 : 0.0);
  f.counter("gyrotherm_gyro_samples_total", "Gyro samples ingested",
            static_cast<double>(g.samples));
  f.counter("gyrotherm_gyro_crc_failures_total", "Gyro frames rejected by their CRC",
            static_cast<double>(g.parser.crc_failures));
  f.counter("gyrotherm_gyro_sequence_gaps_total", "Breaks in the gyro frames' sequence counter",
            static_cast<double>(g.parser.sequence_gaps));
  f.counter("gyrotherm_gyro_frames_missed_total", "Gyro frames missing from the sequence",
            static_cast<double>(g.parser.frames_missed));
  f.counter("gyrotherm_gyro_bytes_skipped_total", "Serial bytes skipped while resynchronising",
            static_cast<double>(g.parser.bytes_skipped));

  // Every DUT, labelled by serial (and axis for rates): the gyro_* families
  // above are the first DUT's primary axis, kept for older dashboards.
  for (const station::DutStatus& d : s.duts) {
    const std::string serial = d.serial.empty() ? "(no serial)" : d.serial;
    for (const auto& [axis, rate] : d.rates_dph) {
      f.gauge("gyrotherm_dut_rate_dph",
              "DUT rate per axis, mean of the last full station second, deg/h", rate,
              {{"serial", serial}, {"axis", axis}});
    }
    f.gauge("gyrotherm_dut_temperature_celsius", "DUT internal temperature, last frame, degC",
            d.temp_c, {{"serial", serial}});
    f.gauge("gyrotherm_dut_frames_per_second", "DUT frames per station second", d.samples_per_s,
            {{"serial", serial}});
    f.gauge("gyrotherm_dut_connected", "1 while the DUT's serial line is open",
            d.health.connected ? 1.0 : 0.0, {{"serial", serial}});
    f.counter("gyrotherm_dut_frames_total", "DUT frames ingested",
              static_cast<double>(d.health.samples), {{"serial", serial}});
    f.counter("gyrotherm_dut_integrity_failures_total",
              "DUT frames or lines rejected by their CRC or checksum",
              static_cast<double>(d.health.parser.crc_failures), {{"serial", serial}});
    f.counter("gyrotherm_dut_frames_missed_total", "DUT frames missing from the sequence",
              static_cast<double>(d.health.parser.frames_missed), {{"serial", serial}});
  }

  for (const auto& [name, h] : {std::pair{"chamber", &s.chamber}, std::pair{"probes", &s.probes}}) {
    f.gauge("gyrotherm_modbus_connected", "1 while the Modbus device is connected",
            h->connected ? 1.0 : 0.0, {{"device", name}});
    f.counter("gyrotherm_modbus_requests_total", "Modbus requests attempted",
              static_cast<double>(h->requests), {{"device", name}});
    f.counter("gyrotherm_modbus_errors_total", "Modbus requests that failed",
              static_cast<double>(h->errors), {{"device", name}});
  }

  if (const auto& t = s.table) {
    // Present only on a station with a [table].
    f.gauge("gyrotherm_table_connected", "1 while the rate table's controller answers",
            t->connected ? 1.0 : 0.0);
    std::optional<double> rate, position;
    if (t->state) {
      rate = t->state->rate_dps;
      position = t->state->position_deg;
    }
    f.gauge("gyrotherm_table_rate_dps", "Rate table's measured rate, deg/s", rate);
    f.gauge("gyrotherm_table_position_deg", "Rate table's measured position, deg", position);
    f.gauge("gyrotherm_table_demand_rate_dps", "Rate the station demands of the table, deg/s",
            t->demand.mode == schedules::TableDemandMode::kRate ? t->demand.rate_dps : 0.0);
    for (auto state : {drivers::TableInterlock::kOpen, drivers::TableInterlock::kClosed,
                       drivers::TableInterlock::kFault}) {
      f.gauge("gyrotherm_table_interlock",
              "1 for the table interlock's current state (open, closed, fault), 0 for the others",
              t->state && t->state->interlock == state ? 1.0 : 0.0,
              {{"state", std::string(drivers::to_string(state))}});
    }
    f.counter("gyrotherm_table_requests_total", "Requests sent to the rate table's controller",
              static_cast<double>(t->health.requests));
    f.counter("gyrotherm_table_errors_total", "Rate-table requests that failed",
              static_cast<double>(t->health.errors));
  }

  const auto& st = s.storage;
  f.counter("gyrotherm_db_rows_committed_total", "Sample rows committed to the database",
            static_cast<double>(st.gyro_rows), {{"table", "gyro_samples"}});
  f.counter("gyrotherm_db_rows_committed_total", "Sample rows committed to the database",
            static_cast<double>(st.temperature_rows), {{"table", "temperature_samples"}});
  f.counter("gyrotherm_db_rows_committed_total", "Sample rows committed to the database",
            static_cast<double>(st.table_rows), {{"table", "table_samples"}});
  f.counter("gyrotherm_db_commits_total", "Sample-writer commits", static_cast<double>(st.commits));
  f.counter("gyrotherm_db_commit_failures_total", "Sample-writer commits that failed (retried)",
            static_cast<double>(st.commit_failures));
  f.counter("gyrotherm_db_samples_dropped_total",
            "Samples dropped because the writer fell too far behind",
            static_cast<double>(st.dropped));
  f.gauge("gyrotherm_db_pending_samples", "Samples waiting for the next commit",
          static_cast<double>(st.pending));
  const auto bytes = [](const std::optional<int64_t>& v) {
    return v ? std::optional<double>(static_cast<double>(*v)) : std::nullopt;
  };
  f.gauge("gyrotherm_storage_free_bytes",
          "Bytes available to the daemon on the database's file system (statvfs)",
          bytes(s.storage_free_bytes));
  f.gauge("gyrotherm_storage_size_bytes", "Size of the database's file system, bytes (statvfs)",
          bytes(s.storage_size_bytes));

  if (const auto& lab = s.lab) {
    // Present only on a station with a [lab] (docs/lab.md).
    for (std::string_view state : kLabRelayStates) {
      f.gauge("gyrotherm_lab_relay_state", "1 for the lab relay's current state, 0 for the others",
              state == lab->state ? 1.0 : 0.0, {{"state", std::string(state)}});
    }
    f.gauge("gyrotherm_lab_outbox_pending_records",
            "Outbox records not yet acknowledged by the lab", static_cast<double>(lab->pending));
    f.gauge("gyrotherm_lab_outbox_pending_bytes", "Payload bytes of the pending outbox records",
            static_cast<double>(lab->pending_bytes));
    f.gauge("gyrotherm_lab_outbox_oldest_age_seconds",
            "Wall seconds since the oldest pending outbox record was committed (0 when none)",
            lab->oldest_pending_age_s.value_or(0.0));
    f.counter("gyrotherm_lab_relay_sent_records_total",
              "Outbox records the lab committed (since the daemon started)",
              static_cast<double>(lab->sent_total));
    f.counter("gyrotherm_lab_relay_batches_total", "Batches the lab committed",
              static_cast<double>(lab->batches_total));
    f.counter("gyrotherm_lab_relay_redelivered_records_total",
              "Records the lab already had (replays after a crash or a lost connection)",
              static_cast<double>(lab->redelivered_total));
    f.counter("gyrotherm_lab_relay_errors_total", "Failed relay attempts (connect or batch)",
              static_cast<double>(lab->errors_total));
    f.gauge("gyrotherm_lab_relay_lag_seconds",
            "Last batch: wall seconds from the newest record's local commit to the lab's commit",
            lab->last_lag_s);
  }

  f.counter("gyrotherm_http_requests_total", "HTTP requests read",
            static_cast<double>(server.http_requests));
  f.counter("gyrotherm_http_refused_connections_total",
            "Connections closed at accept (over [api] max_connections)",
            static_cast<double>(server.http_refused_connections));
  f.counter("gyrotherm_http_bad_requests_total", "Malformed or oversized HTTP requests",
            static_cast<double>(server.http_bad_requests));
  f.gauge("gyrotherm_http_connections", "Open HTTP connections", server.http_connections);
  f.gauge("gyrotherm_stream_clients", "Clients of /api/v1/stream", server.stream_clients);
  f.counter("gyrotherm_stream_clients_dropped_total",
            "Stream clients disconnected for falling too far behind",
            static_cast<double>(server.stream_clients_dropped));

  auto families = registry_->Collect();
  for (auto& family : f.all()) families.push_back(std::move(family));
  return prometheus::TextSerializer().Serialize(families);
}

}  // namespace gyrotherm::api

// What AcutrolTable and AeroTable share about the state of their link (the
// bytes go through a ByteLink, byte_link.h): the reconnect backoff and the
// health counters. Not thread-safe: the tables hold their own mutex around
// it.
#pragma once

#include <fmt/format.h>

#include <algorithm>
#include <string>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/drivers/byte_link.h"
#include "gyrotherm/drivers/devices.h"

namespace gyrotherm::drivers {

class LinkHealth {
 public:
  static constexpr double kMinBackoffS = 0.5;
  static constexpr double kMaxBackoffS = 10.0;

  explicit LinkHealth(const WallClock& clock) : clock_(clock) {}

  // Seconds before the next connection attempt is allowed; 0: now.
  double wait_s() const {
    if (!failed_) return 0;
    return std::max(0.0, next_attempt_s_ - clock_.monotonic_s());
  }
  void on_connected() {
    if (ever_connected_) ++health_.reconnects;
    ever_connected_ = true;
    health_.connected = true;
  }
  // A request answered. `reset_backoff`: false for the connection's own
  // handshake, so a controller that accepts and then drops every request
  // is retried ever more slowly.
  void on_success(double latency_ms, bool reset_backoff = true) {
    ++health_.requests;
    health_.last_latency_ms = latency_ms;
    health_.last_success_utc = wall_time_utc_iso();
    if (reset_backoff) backoff_s_ = kMinBackoffS;
    failed_ = false;
  }
  // The link is lost or could not be made: the next attempt waits.
  void on_link_failure(const std::string& message) {
    ++health_.requests;
    ++health_.errors;
    health_.last_error = message;
    health_.connected = false;
    failed_ = true;
    next_attempt_s_ = clock_.monotonic_s() + backoff_s_;
    backoff_s_ = std::min(backoff_s_ * 2, kMaxBackoffS);
  }
  // The connection was closed on purpose (to resynchronise after a reply
  // that may still come): not a failure, the next call reconnects at once.
  void on_closed() { health_.connected = false; }
  // The controller answered, with a refusal: the link is fine.
  void on_refusal(const std::string& message) {
    ++health_.requests;
    ++health_.errors;
    health_.last_error = message;
  }
  // A call refused locally (beyond limits, backoff pending): counted as an
  // error, not as a request.
  void on_local_error(const std::string& message) {
    ++health_.errors;
    health_.last_error = message;
  }
  // Opens `link` by `deadline`, unless a backoff is pending (and not
  // `ignore_backoff`): then a transient error saying when the next attempt
  // is. A failure to open is counted and backed off from when transient; a
  // link that cannot work (no permission, an unsupported baud rate) is no
  // failure to back off from, and every call says so at once. `name` is the
  // device's, `where` the link's description for the messages.
  Status open_link(ByteLink& link, ByteLink::Deadline deadline, const std::string& name,
                   const std::string& where, bool ignore_backoff) {
    if (!ignore_backoff) {
      if (const double wait = wait_s(); wait > 0) {
        return Error::Transient(
            fmt::format("{}: not connected (last error: {}); next attempt in {:.1f} s", name,
                        health_.last_error, wait));
      }
    }
    if (auto st = link.open(deadline); !st) {
      Error e{fmt::format("{}: {}", where, st.error().message), st.error().transient};
      if (e.transient) on_link_failure(e.message);
      return e;
    }
    on_connected();
    return Status::Ok();
  }
  double backoff_s() const { return backoff_s_; }
  double now_s() const { return clock_.monotonic_s(); }
  const DeviceHealth& health() const { return health_; }

 private:
  const WallClock& clock_;
  DeviceHealth health_;
  bool ever_connected_ = false;
  bool failed_ = false;
  double next_attempt_s_ = 0;
  double backoff_s_ = kMinBackoffS;
};

}  // namespace gyrotherm::drivers

// Failed-authentication throttling for the REST API (docs/api.md, "Access").
//
// Counts, per peer address, the requests that presented a token the station
// does not know. Once a peer has max_failures of them within `window` (wall
// time), it is locked out for `window` from that last failure: every request
// of that peer that needs a token is answered 429 with Retry-After, even one
// with a good token, and is not compared with the tokens at all. When the
// lock-out ends the peer starts with a clean count. Requests without a token
// are not failures (a dashboard's first fetch in token mode is one).
//
// Time comes from a Clock read as wall seconds (a ScaledClock at scale 1 in
// the daemon, a ManualClock in tests). The table of peers is bounded
// (max_peers): expired entries go first, then the peer whose last failure is
// oldest. Thread-safe.
#pragma once

#include <chrono>
#include <cstddef>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/clock.h"
#include "gyrotherm/core/result.h"

namespace gyrotherm::api {

struct AuthLimiterOptions {
  int max_failures = 10;   // [api] max_auth_failures
  double window_s = 60.0;  // wall seconds
  std::size_t max_peers = 4096;

  // False with a message naming the field when max_failures or max_peers is
  // below 1 or window_s is not positive and finite.
  bool is_valid(std::string* why) const;
};

class AuthLimiter {
 public:
  // Error (permanent) when the options are not valid (is_valid).
  // `wall_clock` (not owned, outlives the limiter) gives wall seconds;
  // nullptr: a ScaledClock at scale 1 of the limiter's own.
  static Result<std::unique_ptr<AuthLimiter>> create(AuthLimiterOptions options = {},
                                                     const Clock* wall_clock = nullptr);

  // Whole seconds (rounded up, >= 1) until `peer` may present a token
  // again; 0 when it is not locked out.
  int retry_after_s(std::string_view peer);
  // Counts a bad token from `peer`. True when this failure locked it out.
  bool record_failure(std::string_view peer);

  const AuthLimiterOptions& options() const { return options_; }
  std::size_t peers() const;

 private:
  AuthLimiter(AuthLimiterOptions options, const Clock* wall_clock);

  struct Peer {
    std::vector<double> failures_s;  // within the window, oldest first
    double locked_until_s = 0;       // 0: not locked
    double last_s = 0;
  };
  bool expired(const Peer& p, double now_s) const;
  void make_room(double now_s);

  AuthLimiterOptions options_;
  std::unique_ptr<Clock> own_clock_;
  const Clock* clock_;
  mutable std::mutex mu_;
  std::map<std::string, Peer, std::less<>> peers_;
};

}  // namespace gyrotherm::api

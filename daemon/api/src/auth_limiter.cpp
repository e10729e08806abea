#include "gyrotherm/api/auth_limiter.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <utility>

namespace gyrotherm::api {

bool AuthLimiterOptions::is_valid(std::string* why) const {
  const auto fail = [why](std::string msg) {
    if (why) *why = std::move(msg);
    return false;
  };
  if (max_failures < 1) return fail(fmt::format("max_failures = {} must be >= 1", max_failures));
  if (!(window_s > 0) || !std::isfinite(window_s)) {
    return fail(fmt::format("window_s = {} must be finite and > 0", window_s));
  }
  // make_room() needs room for the peer it adds.
  if (max_peers < 1) return fail(fmt::format("max_peers = {} must be >= 1", max_peers));
  return true;
}

Result<std::unique_ptr<AuthLimiter>> AuthLimiter::create(AuthLimiterOptions options,
                                                         const Clock* wall_clock) {
  if (std::string why; !options.is_valid(&why)) {
    return Error::Permanent("invalid auth limiter options: " + why);
  }
  return std::unique_ptr<AuthLimiter>(new AuthLimiter(options, wall_clock));
}

AuthLimiter::AuthLimiter(AuthLimiterOptions options, const Clock* wall_clock) : options_(options) {
  if (!wall_clock) own_clock_ = std::make_unique<ScaledClock>(1.0);
  clock_ = wall_clock ? wall_clock : own_clock_.get();
}

bool AuthLimiter::expired(const Peer& p, double now_s) const {
  return now_s >= p.locked_until_s && now_s - p.last_s >= options_.window_s;
}

int AuthLimiter::retry_after_s(std::string_view peer) {
  const double now_s = clock_->now_s();
  std::lock_guard lock(mu_);
  const auto it = peers_.find(peer);
  if (it == peers_.end()) return 0;
  Peer& p = it->second;
  if (now_s < p.locked_until_s) {
    return std::max(1, static_cast<int>(std::ceil(p.locked_until_s - now_s)));
  }
  if (p.locked_until_s > 0) peers_.erase(it);  // the lock-out is over: a clean count
  return 0;
}

bool AuthLimiter::record_failure(std::string_view peer) {
  const double now_s = clock_->now_s();
  std::lock_guard lock(mu_);
  auto it = peers_.find(peer);
  if (it == peers_.end()) {
    make_room(now_s);
    it = peers_.emplace(std::string(peer), Peer{}).first;
  }
  Peer& p = it->second;
  if (now_s < p.locked_until_s) return false;  // already locked (not reached via the API)
  p.last_s = now_s;
  std::erase_if(p.failures_s, [&](double t_s) { return now_s - t_s >= options_.window_s; });
  p.failures_s.push_back(now_s);
  if (static_cast<int>(p.failures_s.size()) < options_.max_failures) return false;
  p.failures_s.clear();
  p.locked_until_s = now_s + options_.window_s;
  return true;
}

std::size_t AuthLimiter::peers() const {
  std::lock_guard lock(mu_);
  return peers_.size();
}

void AuthLimiter::make_room(double now_s) {
  if (peers_.size() < options_.max_peers) return;
  std::erase_if(peers_, [&](const auto& entry) { return expired(entry.second, now_s); });
  while (peers_.size() >= options_.max_peers) {
    const auto oldest = std::min_element(
        peers_.begin(), peers_.end(),
        [](const auto& a, const auto& b) { return a.second.last_s < b.second.last_s; });
    peers_.erase(oldest);
  }
}

}  // namespace gyrotherm::api

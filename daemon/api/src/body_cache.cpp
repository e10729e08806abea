#include "gyrotherm/api/body_cache.h"

#include <utility>

namespace gyrotherm::api {

BodyCache::BodyCache(std::function<std::string()> render, double max_age_s, const WallClock& wall)
    : render_(std::move(render)), max_age_s_(max_age_s), wall_(wall) {}

bool BodyCache::fresh() const {
  return body_ && body_generation_ == generation_ &&
         wall_.monotonic_s() - rendered_at_s_ < max_age_s_;
}

std::shared_ptr<const std::string> BodyCache::get() {
  {
    std::lock_guard lock(mu_);
    if (fresh()) return body_;
    // Merely aged, and another reader is rendering its successor: this one
    // is good enough for now.
    if (rendering_ && body_ && body_generation_ == generation_) return body_;
  }
  std::lock_guard render_lock(render_mu_);
  uint64_t generation = 0;
  {
    std::lock_guard lock(mu_);
    // Rendered by the reader this one waited for.
    if (fresh()) return body_;
    generation = generation_;
    rendering_ = true;
  }
  const double started_s = wall_.monotonic_s();
  std::shared_ptr<const std::string> body;
  try {
    body = std::make_shared<const std::string>(render_());
  } catch (...) {
    std::lock_guard lock(mu_);
    rendering_ = false;
    throw;
  }
  std::lock_guard lock(mu_);
  ++renders_;
  rendering_ = false;
  // Renderings are one at a time, so this one is the newest; if invalidate()
  // came during it, its generation is already behind and the next get()
  // renders again.
  body_ = body;
  body_generation_ = generation;
  rendered_at_s_ = started_s;
  return body;
}

void BodyCache::invalidate() {
  std::lock_guard lock(mu_);
  ++generation_;
}

uint64_t BodyCache::renders() const {
  std::lock_guard lock(mu_);
  return renders_;
}

}  // namespace gyrotherm::api

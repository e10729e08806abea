#include "gyrotherm/api/body_cache.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <future>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>

#include "gyrotherm/core/clock.h"

namespace gyrotherm::api {
namespace {

using namespace std::chrono_literals;

// Wall time that only the test moves.
class FakeWall final : public WallClock {
 public:
  double unix_now_s() const override { return now_s.load(); }
  std::atomic<double> now_s{1000.0};
};

// A renderer that numbers its bodies, and can be held inside a rendering
// until the test lets it go.
class Renderer {
 public:
  std::string operator()() {
    std::unique_lock lock(mu_);
    const int n = ++started_;
    cv_.notify_all();
    cv_.wait(lock, [&] { return !hold_; });
    if (fail_) throw std::runtime_error("render failed");
    return "body " + std::to_string(n);
  }
  void hold() {
    std::lock_guard lock(mu_);
    hold_ = true;
  }
  void release() {
    {
      std::lock_guard lock(mu_);
      hold_ = false;
    }
    cv_.notify_all();
  }
  void fail(bool f) {
    std::lock_guard lock(mu_);
    fail_ = f;
  }
  // Waits (bounded) until `n` renderings have started.
  bool started(int n) {
    std::unique_lock lock(mu_);
    return cv_.wait_for(lock, 10s, [&] { return started_ >= n; });
  }

 private:
  std::mutex mu_;
  std::condition_variable cv_;
  int started_ = 0;
  bool hold_ = false;
  bool fail_ = false;
};

TEST(BodyCache, ServesOneBodyUntilItAgesThenRendersAnew) {
  FakeWall wall;
  Renderer r;
  BodyCache cache([&] { return r(); }, 0.05, wall);
  const auto first = cache.get();
  EXPECT_EQ(*first, "body 1");
  wall.now_s = wall.now_s + 0.049;
  EXPECT_EQ(cache.get(), first) << "the same body, not a copy";
  EXPECT_EQ(cache.renders(), 1u);
  wall.now_s = wall.now_s + 0.002;
  EXPECT_EQ(*cache.get(), "body 2");
  EXPECT_EQ(cache.renders(), 2u);
}

TEST(BodyCache, InvalidateMakesTheNextGetRender) {
  FakeWall wall;
  Renderer r;
  BodyCache cache([&] { return r(); }, 3600, wall);
  EXPECT_EQ(*cache.get(), "body 1");
  cache.invalidate();
  EXPECT_EQ(*cache.get(), "body 2");
  EXPECT_EQ(*cache.get(), "body 2");
  EXPECT_EQ(cache.renders(), 2u);
}

// While one reader renders the successor of an aged body, another gets the
// aged one at once instead of waiting.
TEST(BodyCache, AReaderDoesNotWaitOnAnotherOnesRenderingOfAnAgedBody) {
  FakeWall wall;
  Renderer r;
  BodyCache cache([&] { return r(); }, 0.05, wall);
  ASSERT_EQ(*cache.get(), "body 1");
  wall.now_s = wall.now_s + 1;
  r.hold();
  auto renderer = std::async(std::launch::async, [&] { return *cache.get(); });
  ASSERT_TRUE(r.started(2));
  auto reader = std::async(std::launch::async, [&] { return *cache.get(); });
  ASSERT_EQ(reader.wait_for(10s), std::future_status::ready) << "the reader waited";
  EXPECT_EQ(reader.get(), "body 1");
  r.release();
  EXPECT_EQ(renderer.get(), "body 2");
  EXPECT_EQ(*cache.get(), "body 2");
}

// After invalidate(), nobody gets a body rendered before it: a reader waits
// for the rendering that follows the change.
TEST(BodyCache, AfterInvalidateNoReaderGetsTheOldBody) {
  FakeWall wall;
  Renderer r;
  BodyCache cache([&] { return r(); }, 3600, wall);
  ASSERT_EQ(*cache.get(), "body 1");
  cache.invalidate();
  r.hold();
  auto renderer = std::async(std::launch::async, [&] { return *cache.get(); });
  ASSERT_TRUE(r.started(2));
  auto reader = std::async(std::launch::async, [&] { return *cache.get(); });
  // The reader may not answer with body 1; it waits for body 2.
  EXPECT_EQ(reader.wait_for(50ms), std::future_status::timeout);
  r.release();
  EXPECT_EQ(renderer.get(), "body 2");
  EXPECT_EQ(reader.get(), "body 2");
  EXPECT_EQ(cache.renders(), 2u) << "the waiting reader took the body rendered meanwhile";
}

// An invalidate() during a rendering: that body is still handed to its
// reader, but the next get() renders again.
TEST(BodyCache, AChangeDuringARenderingIsInTheNextBody) {
  FakeWall wall;
  Renderer r;
  BodyCache cache([&] { return r(); }, 3600, wall);
  r.hold();
  auto renderer = std::async(std::launch::async, [&] { return *cache.get(); });
  ASSERT_TRUE(r.started(1));
  cache.invalidate();
  r.release();
  EXPECT_EQ(renderer.get(), "body 1");
  EXPECT_EQ(*cache.get(), "body 2");
}

TEST(BodyCache, AFailedRenderingIsThrownAndTheNextGetTriesAgain) {
  FakeWall wall;
  Renderer r;
  BodyCache cache([&] { return r(); }, 3600, wall);
  r.fail(true);
  EXPECT_THROW(cache.get(), std::runtime_error);
  r.fail(false);
  EXPECT_EQ(*cache.get(), "body 2");
}

}  // namespace
}  // namespace gyrotherm::api

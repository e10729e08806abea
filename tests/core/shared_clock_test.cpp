// The simulator's shared station clock (core/shared_clock.h): one file, an
// owner that publishes and consumers that hold it back. Both sides map a
// real file; the dead-consumer case uses a real child process.
#include "gyrotherm/core/shared_clock.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <thread>

namespace gyrotherm {
namespace {

class SharedClockTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("gyrotherm-shared-clock-" + std::to_string(::getpid()) + "-" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::create_directories(dir_);
    path_ = (dir_ / "sim.clock").string();
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::unique_ptr<SharedClockOwner> make_owner(double scale = 100.0) {
    auto map = SharedClockMap::create(path_, scale, 0.0);
    EXPECT_TRUE(map.ok()) << (map.ok() ? "" : map.error().message);
    return std::make_unique<SharedClockOwner>(std::move(map).value());
  }
  std::unique_ptr<SharedStationClock> make_consumer(double lead_s) {
    auto map = SharedClockMap::open(path_);
    EXPECT_TRUE(map.ok()) << (map.ok() ? "" : map.error().message);
    return std::make_unique<SharedStationClock>(std::move(map).value(), lead_s);
  }

  std::filesystem::path dir_;
  std::string path_;
};

TEST_F(SharedClockTest, ConsumerReadsWhatTheOwnerPublishes) {
  auto owner = make_owner(250.0);
  auto clock = make_consumer(1.0);
  EXPECT_EQ(clock->now_s(), 0.0);
  EXPECT_EQ(clock->time_scale(), 250.0);
  owner->publish(12.5);
  EXPECT_DOUBLE_EQ(clock->now_s(), 12.5);
  owner->publish(3.0);  // never back
  EXPECT_DOUBLE_EQ(clock->now_s(), 12.5);
  EXPECT_NE(clock->epoch(), 0U);
  EXPECT_EQ(as_paced(*clock), clock.get());
}

TEST_F(SharedClockTest, WithoutAConsumerTheOwnerRunsFree) {
  auto owner = make_owner();
  EXPECT_TRUE(std::isinf(owner->limit_s()));
  EXPECT_FALSE(owner->consumer_attached());
}

TEST_F(SharedClockTest, AnAttachedConsumerHoldsTheOwnerToItsSlowestMarkPlusTheLead) {
  auto owner = make_owner();
  owner->publish(10.0);
  auto clock = make_consumer(1.0);
  // Attached, no slot yet (the daemon starting up): held where it attached.
  EXPECT_DOUBLE_EQ(owner->limit_s(), 11.0);
  auto control = clock->consumer("control loop");
  auto reader = clock->consumer("dut /dev/pts/3");
  ASSERT_TRUE(control && reader);
  EXPECT_DOUBLE_EQ(owner->limit_s(), 11.0);  // a new slot starts at the present
  owner->publish(11.0);
  control->consumed(11.0);
  EXPECT_DOUBLE_EQ(owner->limit_s(), 11.0);  // the reader still at 10
  reader->consumed(10.5);
  EXPECT_DOUBLE_EQ(owner->limit_s(), 11.5);
  reader->consumed(11.0);
  EXPECT_DOUBLE_EQ(owner->limit_s(), 12.0);
  const SharedClockReading r = clock->reading();
  EXPECT_DOUBLE_EQ(r.consumed_s, 11.0);
  EXPECT_EQ(r.consumer_pid, static_cast<long>(::getpid()));
  // A released slot no longer holds; with none left the owner runs free.
  reader.reset();
  control->consumed(20.0);
  EXPECT_DOUBLE_EQ(owner->limit_s(), 21.0);
  control.reset();
  EXPECT_TRUE(std::isinf(owner->limit_s()));
  clock.reset();  // detaches
  EXPECT_FALSE(owner->consumer_attached());
}

TEST_F(SharedClockTest, WaitUntilReturnsWhenTheOwnerPublishesThatTime) {
  auto owner = make_owner();
  auto clock = make_consumer(1.0);
  EXPECT_FALSE(clock->wait_until(5.0, std::chrono::milliseconds(5)));
  std::atomic<bool> reached{false};
  std::thread waiter([&] { reached = clock->wait_until(5.0, std::chrono::seconds(30)); });
  owner->publish(4.0);
  owner->publish(5.0);
  waiter.join();
  EXPECT_TRUE(reached.load());
}

TEST_F(SharedClockTest, OwnerWaitsForAMarkAndWakesOnIt) {
  auto owner = make_owner();
  auto clock = make_consumer(1.0);
  auto control = clock->consumer("control loop");
  owner->publish(1.0);
  const double limit_before = owner->limit_s();
  std::thread marker([&] { control->consumed(1.0); });
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (owner->limit_s() <= limit_before && std::chrono::steady_clock::now() < deadline) {
    owner->wait_for_consumers(std::chrono::milliseconds(50));
  }
  marker.join();
  EXPECT_DOUBLE_EQ(owner->limit_s(), 2.0);
}

// A mark that lands between limit_s() and the wait is not missed: the
// owner does not sleep out its timeout (which throttled a campaign to a
// tick per timeout).
TEST_F(SharedClockTest, AMarkBetweenTheLimitAndTheWaitWakesTheOwnerAtOnce) {
  auto owner = make_owner();
  auto clock = make_consumer(1.0);
  auto control = clock->consumer("control loop");
  owner->publish(1.0);
  EXPECT_DOUBLE_EQ(owner->limit_s(), 1.0);
  control->consumed(1.0);
  const auto before = std::chrono::steady_clock::now();
  owner->wait_for_consumers(std::chrono::seconds(20));
  EXPECT_LT(std::chrono::steady_clock::now() - before, std::chrono::seconds(10));
  EXPECT_DOUBLE_EQ(owner->limit_s(), 2.0);
}

TEST_F(SharedClockTest, AConsumerWhoseProcessDiedIsDetached) {
  auto owner = make_owner();
  owner->publish(7.0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    // Attaches, takes a slot and dies without detaching (as kill -9 would).
    auto map = SharedClockMap::open(path_);
    if (!map.ok()) ::_exit(2);
    auto* clock = new SharedStationClock(std::move(map).value(), 1.0);
    auto* slot = clock->consumer("control loop").release();
    (void)slot;
    ::_exit(0);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  EXPECT_TRUE(owner->consumer_attached());
  EXPECT_TRUE(std::isinf(owner->limit_s()));  // its pid is gone
  EXPECT_FALSE(owner->consumer_attached());
}

// The simulator gone (killed: its pid is gone; or stopped: it leaves the
// page): the daemon's clock runs on from the last published time at the
// owner's scale instead of freezing, so the daemon notices its devices gone.
TEST_F(SharedClockTest, AnOwnerThatDiedLeavesTheClockRunningAtItsScale) {
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    auto map = SharedClockMap::create(path_, 100.0, 0.0);
    if (!map.ok()) ::_exit(2);
    auto* owner = new SharedClockOwner(std::move(map).value());
    owner->publish(50.0);
    ::_exit(0);  // no destructor: as kill -9
  }
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  auto clock = make_consumer(1.0);
  const double t0_s = clock->now_s();
  EXPECT_TRUE(clock->orphaned());
  EXPECT_GE(t0_s, 50.0);
  EXPECT_LT(t0_s, 50.0 + 100.0 * 5.0) << "scaled from where the owner left it";
  // 10 station s at 100x: 0.1 wall s.
  const auto wall0 = std::chrono::steady_clock::now();
  ASSERT_TRUE(clock->wait_until(t0_s + 10.0, std::chrono::seconds(5)));
  EXPECT_GE(clock->now_s(), t0_s + 10.0);
  EXPECT_GE(std::chrono::steady_clock::now() - wall0, std::chrono::milliseconds(99))
      << "not faster than the owner's scale";
}

TEST_F(SharedClockTest, AnOwnerThatLeftLeavesTheClockRunning) {
  auto owner = make_owner(100.0);
  owner->publish(20.0);
  auto clock = make_consumer(1.0);
  EXPECT_FALSE(clock->orphaned());
  EXPECT_EQ(clock->now_s(), 20.0);
  EXPECT_FALSE(clock->wait_until(21.0, std::chrono::milliseconds(150)))
      << "held while the owner lives and publishes nothing";
  owner.reset();
  ASSERT_TRUE(clock->wait_until(25.0, std::chrono::seconds(5)));
  EXPECT_TRUE(clock->orphaned());
}

TEST_F(SharedClockTest, OpenRefusesWhatIsNotAClockFile) {
  {
    std::ofstream f(path_);
    f << "not a clock";
  }
  auto map = SharedClockMap::open(path_);
  ASSERT_FALSE(map.ok());
  EXPECT_NE(map.error().message.find(path_), std::string::npos) << map.error().message;
  auto missing = SharedClockMap::open(path_ + ".missing");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find(".missing"), std::string::npos);
}

}  // namespace
}  // namespace gyrotherm

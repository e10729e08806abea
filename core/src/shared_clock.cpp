#include "gyrotherm/core/shared_clock.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <linux/futex.h>
#include <signal.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <time.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <limits>
#include <mutex>
#include <random>
#include <thread>

namespace gyrotherm {

// The file's layout. Only lock-free atomics are shared between processes.
struct SharedClockPage {
  uint64_t magic;
  uint32_t version;
  uint32_t size;
  uint64_t epoch;
  double time_scale;
  std::atomic<int64_t> owner_pid;
  std::atomic<int64_t> published_ns;
  std::atomic<uint32_t> owner_seq;     // futex word: bumped on every publish
  std::atomic<uint32_t> consumer_seq;  // futex word: bumped on every mark, attach, release
  std::atomic<int64_t> consumer_pid;   // 0: none attached
  std::atomic<int64_t> lead_ns;
  // Until a consumer's first slot is taken, the clock holds where it
  // attached (its start-up); afterwards no slot means no hold (its shutdown).
  std::atomic<int64_t> attach_ns;
  std::atomic<uint32_t> slots_taken;  // bit i: slot i in use
  std::atomic<uint32_t> slots_ever;   // non-zero once any slot was taken since attach
  std::atomic<int64_t> slot_ns[kSharedClockSlots];
  char slot_name[kSharedClockSlots][48];
};

namespace {

constexpr uint64_t kMagic = 0x0131304b4c435447ULL;  // "GTCLK01\1"
constexpr uint32_t kVersion = 1;

static_assert(std::atomic<int64_t>::is_always_lock_free);
static_assert(std::atomic<uint32_t>::is_always_lock_free);

int64_t to_ns(double t_s) {
  if (!std::isfinite(t_s)) return t_s > 0 ? std::numeric_limits<int64_t>::max() : 0;
  return static_cast<int64_t>(std::llround(t_s * 1e9));
}
double to_s(int64_t ns) { return static_cast<double>(ns) * 1e-9; }

void futex_wait(const std::atomic<uint32_t>& word, uint32_t seen, std::chrono::nanoseconds max) {
  if (max <= std::chrono::nanoseconds::zero()) return;
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(max.count() / 1'000'000'000);
  ts.tv_nsec = static_cast<long>(max.count() % 1'000'000'000);
  // Not FUTEX_PRIVATE: the word is shared between processes.
  (void)syscall(SYS_futex, const_cast<std::atomic<uint32_t>*>(&word), FUTEX_WAIT, seen, &ts,
                nullptr, 0);
}

void futex_wake(std::atomic<uint32_t>& word) {
  word.fetch_add(1, std::memory_order_acq_rel);
  (void)syscall(SYS_futex, &word, FUTEX_WAKE, std::numeric_limits<int>::max(), nullptr, nullptr, 0);
}

bool pid_alive(int64_t pid) {
  if (pid <= 0) return false;
  return ::kill(static_cast<pid_t>(pid), 0) == 0 || errno != ESRCH;
}

Result<SharedClockPage*> map_fd(int fd, const std::string& path) {
  void* p = ::mmap(nullptr, sizeof(SharedClockPage), PROT_READ | PROT_WRITE, MAP_SHARED, fd, 0);
  if (p == MAP_FAILED) {
    return Error::Permanent(
        fmt::format("cannot map the clock file {}: {}", path, std::strerror(errno)));
  }
  return static_cast<SharedClockPage*>(p);
}

void clear_consumer(SharedClockPage& page) {
  page.slots_taken.store(0);
  page.slots_ever.store(0);
  for (auto& s : page.slot_ns) s.store(0);
  page.consumer_pid.store(0);
}

}  // namespace

SharedClockMap::~SharedClockMap() { ::munmap(page_, sizeof(SharedClockPage)); }

Result<std::unique_ptr<SharedClockMap>> SharedClockMap::create(const std::string& path,
                                                               double time_scale, double start_s) {
  // A new file (not the old one truncated): a daemon still mapping an old
  // clock keeps its own page and sees its owner gone.
  const std::string tmp = path + ".tmp";
  const int fd = ::open(tmp.c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) {
    return Error::Permanent(
        fmt::format("cannot create the clock file {}: {}", tmp, std::strerror(errno)));
  }
  if (::ftruncate(fd, sizeof(SharedClockPage)) != 0) {
    const int e = errno;
    ::close(fd);
    return Error::Permanent(
        fmt::format("cannot size the clock file {}: {}", tmp, std::strerror(e)));
  }
  auto page = map_fd(fd, tmp);
  ::close(fd);
  if (!page.ok()) return page.error();
  SharedClockPage& pg = **page;
  std::random_device rd;
  pg.magic = kMagic;
  pg.version = kVersion;
  pg.size = sizeof(SharedClockPage);
  pg.epoch = (static_cast<uint64_t>(rd()) << 32) ^ rd() ^ static_cast<uint64_t>(::getpid());
  pg.time_scale = time_scale;
  pg.owner_pid.store(::getpid());
  pg.published_ns.store(to_ns(start_s));
  clear_consumer(pg);
  std::memset(pg.slot_name, 0, sizeof pg.slot_name);
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const int e = errno;
    ::munmap(*page, sizeof(SharedClockPage));
    return Error::Permanent(
        fmt::format("cannot move the clock file into place at {}: {}", path, std::strerror(e)));
  }
  return std::unique_ptr<SharedClockMap>(new SharedClockMap(path, *page));
}

Result<std::unique_ptr<SharedClockMap>> SharedClockMap::open(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDWR | O_CLOEXEC);
  if (fd < 0) {
    return Error::Permanent(
        fmt::format("cannot open the simulator's clock file {}: {}", path, std::strerror(errno)));
  }
  struct stat st {};
  if (::fstat(fd, &st) != 0 || st.st_size < static_cast<off_t>(sizeof(SharedClockPage))) {
    ::close(fd);
    return Error::Permanent(
        fmt::format("{} is not a gyrotherm-sim clock file ({} bytes, expected {})", path,
                    static_cast<long long>(st.st_size), sizeof(SharedClockPage)));
  }
  auto page = map_fd(fd, path);
  ::close(fd);
  if (!page.ok()) return page.error();
  if ((*page)->magic != kMagic || (*page)->version != kVersion) {
    ::munmap(*page, sizeof(SharedClockPage));
    return Error::Permanent(fmt::format(
        "{} is not a gyrotherm-sim clock file of version {} (a simulator of another version?)",
        path, kVersion));
  }
  return std::unique_ptr<SharedClockMap>(new SharedClockMap(path, *page));
}

SharedClockReading read_shared_clock(const SharedClockMap& map) {
  const SharedClockPage& pg = map.page();
  SharedClockReading r;
  r.t_s = to_s(pg.published_ns.load(std::memory_order_acquire));
  r.time_scale = pg.time_scale;
  r.epoch = pg.epoch;
  r.owner_pid = static_cast<long>(pg.owner_pid.load());
  r.consumer_pid = static_cast<long>(pg.consumer_pid.load());
  r.lead_s = to_s(pg.lead_ns.load());
  r.consumed_s = std::numeric_limits<double>::quiet_NaN();
  const uint32_t taken = pg.slots_taken.load();
  for (int i = 0; i < kSharedClockSlots; ++i) {
    if ((taken >> i & 1U) == 0) continue;
    const double s = to_s(pg.slot_ns[i].load());
    if (std::isnan(r.consumed_s) || s < r.consumed_s) r.consumed_s = s;
  }
  return r;
}

// --- owner ---

SharedClockOwner::SharedClockOwner(std::unique_ptr<SharedClockMap> map) : map_(std::move(map)) {}

SharedClockOwner::~SharedClockOwner() {
  map_->page().owner_pid.store(0);
  futex_wake(map_->page().owner_seq);
}

void SharedClockOwner::publish(double t_s) {
  SharedClockPage& pg = map_->page();
  const int64_t ns = to_ns(t_s);
  if (ns <= pg.published_ns.load(std::memory_order_relaxed)) return;
  pg.published_ns.store(ns, std::memory_order_release);
  futex_wake(pg.owner_seq);
}

double SharedClockOwner::published_s() const {
  return to_s(map_->page().published_ns.load(std::memory_order_acquire));
}

bool SharedClockOwner::consumer_attached() const { return map_->page().consumer_pid.load() != 0; }

double SharedClockOwner::limit_s() {
  SharedClockPage& pg = map_->page();
  // Taken before the marks are read: a mark made after it wakes
  // wait_for_consumers() at once.
  seen_consumer_seq_ = pg.consumer_seq.load(std::memory_order_acquire);
  const int64_t pid = pg.consumer_pid.load();
  if (pid == 0) return std::numeric_limits<double>::infinity();
  if (!pid_alive(pid)) {
    // Killed: it cannot detach itself. The plant runs on, as a real one would.
    int64_t expected = pid;
    if (pg.consumer_pid.compare_exchange_strong(expected, 0)) clear_consumer(pg);
    return std::numeric_limits<double>::infinity();
  }
  const double lead_s = to_s(pg.lead_ns.load());
  const uint32_t taken = pg.slots_taken.load(std::memory_order_acquire);
  if (taken == 0) {
    if (pg.slots_ever.load() != 0) return std::numeric_limits<double>::infinity();
    return to_s(pg.attach_ns.load()) + lead_s;
  }
  int64_t slowest = std::numeric_limits<int64_t>::max();
  for (int i = 0; i < kSharedClockSlots; ++i) {
    if (taken >> i & 1U) slowest = std::min(slowest, pg.slot_ns[i].load(std::memory_order_acquire));
  }
  return to_s(slowest) + lead_s;
}

void SharedClockOwner::wait_for_consumers(std::chrono::nanoseconds max_wall) const {
  futex_wait(map_->page().consumer_seq, seen_consumer_seq_, max_wall);
}

// --- consumer ---

namespace {

class SharedSlot final : public ClockConsumer {
 public:
  SharedSlot(SharedClockPage& page, int index) : page_(page), index_(index) {}
  ~SharedSlot() override {
    page_.slots_taken.fetch_and(~(1U << index_), std::memory_order_acq_rel);
    futex_wake(page_.consumer_seq);
  }
  void consumed(double t_s) override {
    const int64_t ns = to_ns(t_s);
    if (ns <= page_.slot_ns[index_].load(std::memory_order_relaxed)) return;
    page_.slot_ns[index_].store(ns, std::memory_order_release);
    futex_wake(page_.consumer_seq);
  }

 private:
  SharedClockPage& page_;
  int index_;
};

}  // namespace

SharedStationClock::SharedStationClock(std::unique_ptr<SharedClockMap> map, double lead_s)
    : map_(std::move(map)) {
  SharedClockPage& pg = map_->page();
  clear_consumer(pg);
  pg.lead_ns.store(to_ns(lead_s));
  pg.attach_ns.store(pg.published_ns.load());
  pg.consumer_pid.store(::getpid(), std::memory_order_release);
  futex_wake(pg.consumer_seq);
}

SharedStationClock::~SharedStationClock() {
  SharedClockPage& pg = map_->page();
  int64_t self = ::getpid();
  if (pg.consumer_pid.compare_exchange_strong(self, 0)) clear_consumer(pg);
  futex_wake(pg.consumer_seq);
}

double SharedStationClock::now_s() const {
  const SharedClockPage& pg = map_->page();
  const double published_s = to_s(pg.published_ns.load(std::memory_order_acquire));
  const auto now = std::chrono::steady_clock::now();
  std::lock_guard lock(orphan_mu_);
  if (!orphaned_ && now >= next_owner_check_) {
    // A kill(pid, 0) at most every 100 ms: now_s() is called from every
    // reader at every sample.
    next_owner_check_ = now + std::chrono::milliseconds(100);
    const int64_t pid = pg.owner_pid.load();
    if (!pid_alive(pid)) {
      // Read again after the pid: a last publish before it left counts.
      orphaned_ = Orphaned{to_s(pg.published_ns.load(std::memory_order_acquire)), now};
    }
  }
  if (!orphaned_) return published_s;
  return orphaned_->t_s +
         std::chrono::duration<double>(now - orphaned_->at).count() * pg.time_scale;
}

bool SharedStationClock::orphaned() const {
  (void)now_s();
  std::lock_guard lock(orphan_mu_);
  return orphaned_.has_value();
}

double SharedStationClock::time_scale() const { return map_->page().time_scale; }

uint64_t SharedStationClock::epoch() const { return map_->page().epoch; }

std::unique_ptr<ClockConsumer> SharedStationClock::consumer(std::string_view name) const {
  std::lock_guard lock(slots_mu_);  // one allocator per process; one consumer process
  SharedClockPage& pg = map_->page();
  uint32_t taken = pg.slots_taken.load();
  for (int i = 0; i < kSharedClockSlots; ++i) {
    if (taken >> i & 1U) continue;
    // Marked at the present before the bit is set: it never holds the clock
    // behind what was published when it was taken.
    pg.slot_ns[i].store(pg.published_ns.load(std::memory_order_acquire));
    std::snprintf(pg.slot_name[i], sizeof pg.slot_name[i], "%.*s",
                  static_cast<int>(std::min<std::size_t>(name.size(), 47)), name.data());
    if (pg.slots_taken.compare_exchange_strong(taken, taken | (1U << i))) {
      pg.slots_ever.store(1);
      futex_wake(pg.consumer_seq);
      return std::make_unique<SharedSlot>(pg, i);
    }
    i = -1;  // a slot was released meanwhile: look again
  }
  return nullptr;
}

bool SharedStationClock::wait_until(double t_s, std::chrono::nanoseconds max_wall) const {
  const SharedClockPage& pg = map_->page();
  const auto deadline = std::chrono::steady_clock::now() + max_wall;
  for (;;) {
    const uint32_t seen = pg.owner_seq.load(std::memory_order_acquire);
    const double now_station_s = now_s();
    if (now_station_s >= t_s) return true;
    const auto left = deadline - std::chrono::steady_clock::now();
    if (left <= std::chrono::nanoseconds::zero()) return false;
    // Waits at most 100 ms at a time: an owner that dies publishes nothing
    // more, and its death is noticed by now_s().
    auto wait = std::min<std::chrono::nanoseconds>(
        std::chrono::duration_cast<std::chrono::nanoseconds>(left), std::chrono::milliseconds(100));
    if (orphaned()) {
      const double scale = pg.time_scale > 0 ? pg.time_scale : 1.0;
      wait = std::min(wait, std::chrono::duration_cast<std::chrono::nanoseconds>(
                                std::chrono::duration<double>((t_s - now_station_s) / scale)));
      std::this_thread::sleep_for(std::max(wait, std::chrono::nanoseconds(1000)));
      continue;
    }
    futex_wait(pg.owner_seq, seen, wait);
  }
}

}  // namespace gyrotherm

// gyrothermd under a stand-in service manager: the test listens on the
// datagram socket systemd would pass in NOTIFY_SOCKET, asks for a watchdog
// with WATCHDOG_USEC, and checks what the daemon sends and from which
// process — READY=1 once the API answers, WATCHDOG=1 at half the interval
// while the simulated station runs, STOPPING=1 on SIGTERM.
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include "station_fixture.h"

namespace gyrotherm::testing {
namespace {

using namespace std::chrono_literals;
using steady = std::chrono::steady_clock;

// One datagram: its text and the sender's pid (SCM_CREDENTIALS).
struct Notification {
  std::string text;
  pid_t pid = 0;
  steady::time_point at;
  bool has(const std::string& line) const {
    return ("\n" + text + "\n").find("\n" + line + "\n") != std::string::npos;
  }
};

// The receiving end of NOTIFY_SOCKET.
class NotifySocket {
 public:
  explicit NotifySocket(const std::string& path) : path_(path) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    std::strncpy(addr.sun_path, path.c_str(), sizeof addr.sun_path - 1);
    bound_ = fd_ >= 0 && path.size() < sizeof addr.sun_path &&
             ::bind(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
    const int on = 1;
    bound_ = bound_ && ::setsockopt(fd_, SOL_SOCKET, SO_PASSCRED, &on, sizeof on) == 0;
  }
  ~NotifySocket() {
    if (fd_ >= 0) ::close(fd_);
    ::unlink(path_.c_str());
  }
  bool ok() const { return bound_; }

  // Receives until a notification satisfies `pred` or `timeout` passes;
  // every one received is kept in received().
  template <class Pred>
  std::optional<Notification> wait_for(Pred pred, std::chrono::milliseconds timeout) {
    const auto deadline = steady::now() + timeout;
    for (;;) {
      const auto left =
          std::chrono::duration_cast<std::chrono::milliseconds>(deadline - steady::now());
      if (left.count() <= 0) return std::nullopt;
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, static_cast<int>(left.count())) <= 0) continue;
      char buf[4096];
      alignas(cmsghdr) char control[CMSG_SPACE(sizeof(ucred))];
      iovec iov{buf, sizeof buf};
      msghdr msg{};
      msg.msg_iov = &iov;
      msg.msg_iovlen = 1;
      msg.msg_control = control;
      msg.msg_controllen = sizeof control;
      const ssize_t n = ::recvmsg(fd_, &msg, 0);
      if (n < 0) continue;
      Notification note{std::string(buf, static_cast<std::size_t>(n)), 0, steady::now()};
      for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c; c = CMSG_NXTHDR(&msg, c)) {
        if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_CREDENTIALS) {
          ucred cred;
          std::memcpy(&cred, CMSG_DATA(c), sizeof cred);
          note.pid = cred.pid;
        }
      }
      received_.push_back(note);
      if (pred(note)) return note;
    }
  }
  const std::vector<Notification>& received() const { return received_; }

 private:
  std::string path_;
  int fd_ = -1;
  bool bound_ = false;
  std::vector<Notification> received_;
};

// Sets environment variables for the children started in its lifetime.
class ScopedEnv {
 public:
  explicit ScopedEnv(std::vector<std::pair<std::string, std::string>> vars)
      : vars_(std::move(vars)) {
    for (const auto& [name, value] : vars_) ::setenv(name.c_str(), value.c_str(), 1);
  }
  ~ScopedEnv() {
    for (const auto& [name, value] : vars_) ::unsetenv(name.c_str());
  }

 private:
  std::vector<std::pair<std::string, std::string>> vars_;
};

class SystemdNotifyTest : public StationTest {};

TEST_F(SystemdNotifyTest, ReadyThenWatchdogWhileRunningThenStopping) {
  start_sim();
  NotifySocket notify((dir_ / "notify.sock").string());
  ASSERT_TRUE(notify.ok()) << std::strerror(errno);
  constexpr auto kWatchdog = 2000ms;
  {
    ScopedEnv env({{"NOTIFY_SOCKET", (dir_ / "notify.sock").string()},
                   {"WATCHDOG_USEC", std::to_string(kWatchdog.count() * 1000)}});
    start_daemon();
  }
  auto is = [](const char* line) { return [line](const Notification& n) { return n.has(line); }; };

  const auto ready = notify.wait_for(is("READY=1"), 30s);
  ASSERT_TRUE(ready) << daemon_->log();
  EXPECT_EQ(ready->pid, daemon_->pid());
  EXPECT_NE(ready->text.find("STATUS=station \"integration\""), std::string::npos) << ready->text;
  for (const auto& n : notify.received()) EXPECT_FALSE(n.has("WATCHDOG=1")) << "before READY";
  // READY means the API answers.
  EXPECT_TRUE(status().has_value());

  // Three pings, half the interval apart at least, while the run goes on.
  std::vector<Notification> pings;
  for (int i = 0; i < 3; ++i) {
    const auto ping = notify.wait_for(is("WATCHDOG=1"), 10s);
    ASSERT_TRUE(ping) << "watchdog ping " << i + 1 << " missing\n" << daemon_->log();
    EXPECT_EQ(ping->pid, daemon_->pid());
    pings.push_back(*ping);
  }
  EXPECT_GE(pings.back().at - pings.front().at, kWatchdog - 50ms);  // two half intervals
  const auto s = status();
  ASSERT_TRUE(s);
  EXPECT_NE((*s)["state"], "idle") << s->dump();

  daemon_->signal(SIGTERM);
  const auto stopping = notify.wait_for(is("STOPPING=1"), 20s);
  ASSERT_TRUE(stopping) << daemon_->log();
  EXPECT_EQ(stopping->pid, daemon_->pid());
  EXPECT_EQ(daemon_->wait(30s), 0) << daemon_->log();
}

}  // namespace
}  // namespace gyrotherm::testing

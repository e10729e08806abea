// Child processes for integration tests: spawn with output to files, wait
// with a deadline, signal, and always reap in the destructor.
#pragma once

#include <sys/types.h>

#include <chrono>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "test_files.h"
#include "test_time.h"

namespace gyrotherm::testing {

class ChildProcess {
 public:
  // Starts `argv[0]` with stdout and stderr appended to `log_path`.
  ChildProcess(std::vector<std::string> argv, const std::string& log_path);
  ~ChildProcess();  // SIGKILL + reap if still running
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  pid_t pid() const { return pid_; }
  bool running();
  void signal(int sig);
  // Waits for exit up to `timeout`; returns the exit status (or 128 + signal),
  // nullopt on timeout.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  std::string log() const;

 private:
  pid_t pid_ = -1;
  std::optional<int> status_;
  std::string log_path_;
};

// Polls `pred` every 20 ms until it holds or `timeout` passes. `timeout` is
// stretched by the factor in GYROTHERM_TEST_TIME_FACTOR (default 1), which
// scripts/test-sanitizers sets: sanitized processes are several times slower.
bool wait_until(const std::function<bool()>& pred, std::chrono::milliseconds timeout);

// A TCP port that was free a moment ago (bind port 0, read it, close).
int free_tcp_port();

// The absolute path of `program` on PATH, "" when there is none.
std::string find_program(const std::string& program);

// What the browser tests (tests/browser/*.mjs) need: node on PATH, Debian's
// /usr/bin/chromium and playwright-core in <source_dir>/node_modules.
struct BrowserTools {
  std::string node;     // node's path
  std::string missing;  // "" when all is there, else what and how to get it
};
BrowserTools browser_tools(const std::string& source_dir);

}  // namespace gyrotherm::testing

// Busy processes beside the station for the life of the object: a loaded
// 2-core machine (the two `yes > /dev/null` of docs/testing.md), for the
// end-to-end tests whose numbers must not change under load.
#pragma once

#include <fmt/format.h>
#include <signal.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "process.h"

namespace gyrotherm::testing {

class Hogs {
 public:
  Hogs(int n, const std::filesystem::path& dir) {
    for (int i = 0; i < n; ++i) {
      hogs_.push_back(std::make_unique<ChildProcess>(
          std::vector<std::string>{"/bin/sh", "-c", "exec yes > /dev/null"},
          (dir / fmt::format("hog{}.log", i)).string()));
    }
  }
  ~Hogs() {
    for (auto& h : hogs_) {
      h->signal(SIGKILL);
      (void)h->wait(std::chrono::seconds(10));
    }
  }
  Hogs(const Hogs&) = delete;
  Hogs& operator=(const Hogs&) = delete;

 private:
  std::vector<std::unique_ptr<ChildProcess>> hogs_;
};

}  // namespace gyrotherm::testing

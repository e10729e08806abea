// Reading a file whole in tests: config files to edit, logs and the files a
// run wrote, to compare or search.
#pragma once

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

namespace gyrotherm::testing {

// The whole file at `path`, byte for byte. When it cannot be opened or read:
// a test failure naming the path, and "".
inline std::string read_text(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  if (in) ss << in.rdbuf();
  std::error_code ec;
  if (!in || in.bad() || std::filesystem::is_directory(path, ec)) {
    ADD_FAILURE() << "cannot read " << path.string();
    return {};
  }
  return std::move(ss).str();
}

}  // namespace gyrotherm::testing

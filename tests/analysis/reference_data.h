// Shared by the tests that read numpy reference files (tests/analysis/data,
// written by tools/reference/*.py): the files' line format and the
// scripts' deterministic noise generator, operation for operation.
#pragma once

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace gyrotherm::analysis::testing {

using Tokens = std::vector<std::string>;

// The whitespace-separated words of every non-empty, non-comment line of
// tests/analysis/data/<file>. A missing file is a test failure naming the
// script that writes it.
inline std::vector<Tokens> read_reference_lines(const std::string& file,
                                                const std::string& script) {
  const std::string path = std::string(GYROTHERM_TEST_DATA_DIR) + "/analysis/data/" + file;
  std::ifstream in(path);
  EXPECT_TRUE(in) << "cannot open " << path << " (regenerate with /usr/bin/python3 " << script
                  << ")";
  std::vector<Tokens> lines;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    Tokens t;
    for (std::string w; ls >> w;) t.push_back(w);
    if (!t.empty()) lines.push_back(std::move(t));
  }
  return lines;
}

// Draw `draw` (1, 2, ...) of the counter-based splitmix64 stream of `seed`
// (tools/reference/refgen.py: splitmix64).
inline uint64_t splitmix64(uint64_t seed, uint64_t draw) {
  uint64_t z = seed + draw * 0x9E3779B97F4A7C15ULL;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
  return z ^ (z >> 31);
}

// Value i of an approximately normal sequence of std `sigma` (sum of four
// uniforms; refgen.py: noise).
inline double noise(uint64_t seed, std::size_t i, double sigma) {
  double u[4];
  for (int j = 0; j < 4; ++j) {
    u[j] = static_cast<double>(splitmix64(seed, 4 * i + j + 1) >> 11) * 0x1p-53;
  }
  const double s = ((u[0] + u[1]) + u[2]) + u[3];
  return sigma * std::sqrt(3.0) * (s - 2.0);
}

}  // namespace gyrotherm::analysis::testing

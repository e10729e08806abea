// The bad-schedule corpus: every tests/schedules/bad/NAME.toml must be refused
// with exactly the lines of NAME.expected (parsed as "NAME.toml" against the
// station limits -20 ... 60 °C, 2 °C/min).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "gyrotherm/schedules/schedule.h"

namespace gyrotherm::schedules {
namespace {

namespace fs = std::filesystem;

const StationLimits kLimits{-20.0, 60.0, 2.0};

fs::path corpus_dir() { return fs::path(GYROTHERM_SOURCE_DIR) / "tests/schedules/bad"; }

std::string read_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream ss(text);
  for (std::string line; std::getline(ss, line);) lines.push_back(line);
  return lines;
}

std::vector<fs::path> corpus_files(const std::string& extension) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::directory_iterator(corpus_dir())) {
    if (entry.path().extension() == extension) files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

TEST(BadSchedules, CorpusIsComplete) {
  const auto schedules = corpus_files(".toml");
  EXPECT_GE(schedules.size(), 20u);
  for (const auto& path : schedules) {
    EXPECT_TRUE(fs::exists(fs::path(path).replace_extension(".expected")))
        << path.filename() << " has no .expected file";
  }
  for (const auto& path : corpus_files(".expected")) {
    EXPECT_TRUE(fs::exists(fs::path(path).replace_extension(".toml")))
        << path.filename() << " has no .toml file";
  }
}

TEST(BadSchedules, EachIsRefusedWithExactlyTheExpectedErrors) {
  for (const auto& path : corpus_files(".toml")) {
    const std::string name = path.filename().string();
    SCOPED_TRACE(name);
    const auto expected = lines_of(read_text(fs::path(path).replace_extension(".expected")));
    EXPECT_FALSE(expected.empty());
    auto plan = parse_schedule(read_text(path), name, kLimits);
    if (plan.ok()) {
      ADD_FAILURE() << "accepted, " << plan->steps.size() << " steps";
      continue;
    }
    EXPECT_EQ(lines_of(plan.error().message), expected) << "got:\n" << plan.error().message;
    EXPECT_FALSE(plan.error().transient);
  }
}

// load_schedule names the file by the path it was given.
TEST(BadSchedules, LoadNamesThePath) {
  const fs::path path = corpus_dir() / "ramp-rate.toml";
  auto plan = load_schedule(path.string(), kLimits);
  ASSERT_FALSE(plan.ok());
  const auto lines = lines_of(plan.error().message);
  ASSERT_FALSE(lines.empty());
  EXPECT_EQ(lines[0].rfind(path.string() + ":", 0), 0u) << lines[0];
}

TEST(BadSchedules, MissingFileIsAnError) {
  auto plan = load_schedule((corpus_dir() / "no-such-file.toml").string(), kLimits);
  ASSERT_FALSE(plan.ok());
  EXPECT_NE(plan.error().message.find("cannot open file"), std::string::npos)
      << plan.error().message;
}

}  // namespace
}  // namespace gyrotherm::schedules

// The bad-schedule corpus: every tests/schedules/bad/NAME.toml must be refused
// with exactly the lines of NAME.expected (parsed as "NAME.toml" against the
// station limits -20 ... 60 °C, 2 °C/min, a rate table of 500 °/s and
// 100 °/s²; a file named no-table-*.toml against the same station without a
// table).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "gyrotherm/schedules/schedule.h"
#include "test_files.h"

namespace gyrotherm::schedules {
namespace {

namespace fs = std::filesystem;
using testing::read_text;

const StationLimits kLimitsWithTable{-20.0, 60.0, 2.0, StationLimits::Table{500.0, 100.0}};
const StationLimits kNoTableLimits{-20.0, 60.0, 2.0};

fs::path corpus_dir() { return fs::path(GYROTHERM_SOURCE_DIR) / "tests/schedules/bad"; }

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
    const bool no_table = name.rfind("no-table-", 0) == 0;
    auto plan = parse_schedule(read_text(path), name, no_table ? kNoTableLimits : kLimitsWithTable);
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
  auto plan = load_schedule(path.string(), kLimitsWithTable);
  ASSERT_FALSE(plan.ok());
  const auto lines = lines_of(plan.error().message);
  ASSERT_FALSE(lines.empty());
  EXPECT_EQ(lines[0].rfind(path.string() + ":", 0), 0u) << lines[0];
}

TEST(BadSchedules, MissingFileIsAnError) {
  auto plan = load_schedule((corpus_dir() / "no-such-file.toml").string(), kLimitsWithTable);
  ASSERT_FALSE(plan.ok());
  EXPECT_NE(plan.error().message.find("cannot open file"), std::string::npos)
      << plan.error().message;
}

// Input that is not a schedule file is refused by what it is, never read
// without bound (/dev/zero used to be read forever, a directory was "missing
// [[step]]").
TEST(BadSchedules, DirectoryIsRefusedAsADirectory) {
  auto plan = load_schedule(corpus_dir().string(), kLimitsWithTable);
  ASSERT_FALSE(plan.ok());
  EXPECT_NE(plan.error().message.find("is a directory, not a file"), std::string::npos)
      << plan.error().message;
  EXPECT_EQ(plan.error().message.find("[[step]]"), std::string::npos) << plan.error().message;
}

TEST(BadSchedules, DeviceAndFifoAreRefusedWithoutReading) {
  auto zero = load_schedule("/dev/zero", kLimitsWithTable);
  ASSERT_FALSE(zero.ok());
  EXPECT_NE(zero.error().message.find("/dev/zero: is a character device, not a regular file"),
            std::string::npos)
      << zero.error().message;

  const fs::path fifo = fs::temp_directory_path() / fmt::format("gyrotherm-fifo-{}", ::getpid());
  fs::remove(fifo);
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  auto piped =
      load_schedule(fifo.string(), kLimitsWithTable);  // no writer: a plain open would block
  fs::remove(fifo);
  ASSERT_FALSE(piped.ok());
  EXPECT_NE(piped.error().message.find("is a FIFO (named pipe), not a regular file"),
            std::string::npos)
      << piped.error().message;
}

TEST(BadSchedules, FileOverTheSizeLimitIsRefused) {
  const fs::path big = fs::temp_directory_path() / fmt::format("gyrotherm-big-{}.toml", ::getpid());
  {
    std::ofstream out(big, std::ios::binary);
    const std::string comment = "# " + std::string(1021, 'x') + "\n";  // 1 KiB a line
    for (int i = 0; i < 1025; ++i) out << comment;
  }
  auto plan = load_schedule(big.string(), kLimitsWithTable);
  fs::remove(big);
  ASSERT_FALSE(plan.ok());
  EXPECT_NE(plan.error().message.find("is 1049600 bytes, over the limit of 1 MiB"),
            std::string::npos)
      << plan.error().message;
}

// A schedule with twenty thousand errors: the report holds the first ones
// in file order and says how many more there are (it used to print every
// one, de-duplicated in quadratic time: 42 s for 190 000 lines).
TEST(BadSchedules, ManyErrorsAreReportedUpToACap) {
  std::string text;
  constexpr int kSteps = 5000;  // 4 errors each, 20000 in all
  for (int i = 0; i < kSteps; ++i) {
    text += "[[step]]\ntype = \"soak\"\nsetpoint_c = 99\nacquire_min = -1\nbogus = 1\n";
    text += "tolerance_c = 50\n";
  }
  auto plan = parse_schedule(text, "many.toml", kLimitsWithTable);
  ASSERT_FALSE(plan.ok());
  const auto lines = lines_of(plan.error().message);
  ASSERT_EQ(lines.size(), 51u) << plan.error().message.substr(0, 2000);
  EXPECT_EQ(lines[0].rfind("many.toml:3: step[0].setpoint_c: 99 °C is outside", 0), 0u) << lines[0];
  EXPECT_EQ(lines[49].rfind("many.toml:", 0), 0u) << lines[49];
  // 4 errors a step; 10000 kept, 50 shown, the rest counted.
  EXPECT_EQ(lines[50], fmt::format("... and {} more errors", 4 * kSteps - 50));
}

// Control characters in the file never reach a terminal: the name is
// refused with its line, and keys (a quoted key may hold anything) are
// shown escaped.
TEST(BadSchedules, ControlCharactersAreRefusedAndEscaped) {
  const std::string text =
      "name = \"\\u001b[2J\\u001b[31mowned\"\n"
      "[[step]]\ntype = \"hold\"\nsetpoint_c = 20\nduration_min = 5\n"
      "\"\\u001b]0;title\\u0007\" = 1\n";
  auto plan = parse_schedule(text, "ctl.toml", kLimitsWithTable);
  ASSERT_FALSE(plan.ok());
  const std::string& m = plan.error().message;
  EXPECT_EQ(m.find('\x1b'), std::string::npos) << m;
  EXPECT_EQ(m.find('\x07'), std::string::npos) << m;
  const auto lines = lines_of(m);
  ASSERT_EQ(lines.size(), 2u) << m;
  EXPECT_EQ(lines[0],
            "ctl.toml:1: name: \"\\x1B[2J\\x1B[31mowned\" holds control characters (shown "
            "escaped); a name is one line of printable text");
  EXPECT_EQ(lines[1].rfind("ctl.toml:6: step[0].\\x1B]0;title\\x07: unknown key", 0), 0u)
      << lines[1];

  // A description may have lines and tabs, nothing else.
  auto described = parse_schedule(
      "description = \"two\\nlines\\tand a tab\"\n[[step]]\ntype = \"hold\"\n"
      "setpoint_c = 20\nduration_min = 5\n",
      "desc.toml", kLimitsWithTable);
  EXPECT_TRUE(described.ok()) << described.error().message;
}

}  // namespace
}  // namespace gyrotherm::schedules

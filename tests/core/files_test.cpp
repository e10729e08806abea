// Bounded reading of input files and the TOML error list: what is not a
// regular file is refused without being read, a file over the limit is
// refused after at most limit + 1 bytes, and error lists stay linear in time
// and bounded in memory whatever the input.
#include "gyrotherm/core/files.h"

#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>

#include "gyrotherm/core/toml_reader.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;

class BoundedFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / fmt::format("gyrotherm-files-{}", ::getpid());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(BoundedFileTest, ReadsARegularFileUpToTheLimit) {
  const fs::path path = dir_ / "a.toml";
  std::ofstream(path) << "name = \"x\"\n";
  auto text = read_bounded_file(path.string(), 11);
  ASSERT_TRUE(text.ok()) << text.error().message;
  EXPECT_EQ(*text, "name = \"x\"\n");
  auto over = read_bounded_file(path.string(), 10);
  ASSERT_FALSE(over.ok());
  EXPECT_EQ(over.error().message, path.string() + ": is 11 bytes, over the limit of 10 bytes");
}

TEST_F(BoundedFileTest, RefusesWhatIsNotARegularFile) {
  auto dir = read_bounded_file(dir_.string(), 1024);
  ASSERT_FALSE(dir.ok());
  EXPECT_EQ(dir.error().message, dir_.string() + ": is a directory, not a file");
  auto zero = read_bounded_file("/dev/zero", 1024);
  ASSERT_FALSE(zero.ok());
  EXPECT_EQ(zero.error().message,
            "/dev/zero: is a character device, not a regular file; give a file");
  const fs::path fifo = dir_ / "fifo";
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  auto piped = read_bounded_file(fifo.string(), 1024);  // no writer: must not block
  ASSERT_FALSE(piped.ok());
  EXPECT_NE(piped.error().message.find("is a FIFO (named pipe)"), std::string::npos);
  auto missing = read_bounded_file((dir_ / "none").string(), 1024);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("none: cannot open file: No such file"), std::string::npos)
      << missing.error().message;
}

// The simulator's endpoints and truth files may name folders that do not
// exist yet; a folder that cannot be made is an error naming it.
TEST_F(BoundedFileTest, WriteCreatingFoldersMakesTheFoldersFirst) {
  const fs::path path = dir_ / "run" / "sim" / "endpoints.toml";
  ASSERT_TRUE(write_file_creating_folders(path.string(), "x = 1\n").ok());
  auto text = read_bounded_file(path.string(), 100);
  ASSERT_TRUE(text.ok()) << text.error().message;
  EXPECT_EQ(*text, "x = 1\n");
  std::ofstream(dir_ / "plain") << "a file";
  const auto blocked = write_file_creating_folders((dir_ / "plain" / "f.toml").string(), "x");
  ASSERT_FALSE(blocked.ok());
  EXPECT_NE(blocked.error().message.find("cannot create the folder"), std::string::npos)
      << blocked.error().message;
}

TEST(FormatBytes, UsesBinaryUnitsWhenExact) {
  EXPECT_EQ(format_bytes(1 << 20), "1 MiB");
  EXPECT_EQ(format_bytes(64 * 1024), "64 KiB");
  EXPECT_EQ(format_bytes(1000), "1000 bytes");
}

TEST(TomlErrors, RepeatsAreDroppedAndTheStoreIsBounded) {
  TomlErrors errors("f.toml");
  errors.add(3, "a", "bad");
  errors.add(3, "a", "bad");
  errors.add(4, "b", "bad");
  EXPECT_EQ(errors.messages().size(), 2u);
  for (std::size_t i = 0; i < TomlErrors::kMaxStored + 500; ++i) {
    errors.add(static_cast<int>(i + 10), "k", "bad");
  }
  EXPECT_EQ(errors.messages().size(), TomlErrors::kMaxStored);
  EXPECT_EQ(errors.dropped(), 502u);
  const std::string joined = errors.joined(3);
  EXPECT_EQ(joined, fmt::format("f.toml:3: a: bad\nf.toml:4: b: bad\nf.toml:10: k: bad\n"
                                "... and {} more errors\n",
                                TomlErrors::kMaxStored - 3 + 502));
}

TEST(TomlErrors, ControlCharactersAreEscaped) {
  TomlErrors errors("f.toml");
  errors.add(1, "\x1b[2J", "bell \x07, C1 \xc2\x9b, tab\t, é");
  ASSERT_EQ(errors.messages().size(), 1u);
  EXPECT_EQ(errors.messages()[0], "f.toml:1: \\x1B[2J: bell \\x07, C1 \\u{9B}, tab\\x09, é");
  EXPECT_TRUE(has_control_characters("a\nb"));
  EXPECT_FALSE(has_control_characters("20 °C, é"));
  EXPECT_EQ(escape_control_characters("a\x7f"), "a\\x7F");
}

TEST(TomlFile, DevZeroAndDirectoriesAreErrorsNotHangs) {
  TomlErrors errors("/dev/zero");
  EXPECT_FALSE(parse_toml_file("/dev/zero", errors).has_value());
  EXPECT_EQ(errors.joined(), "/dev/zero: is a character device, not a regular file; give a file\n");
}

}  // namespace
}  // namespace gyrotherm

// The repository stands alone: no file refers to a design document or a
// shared folder outside it (the docs used to cite one that is not in the
// repository), and every relative link in docs/ and the README reaches a
// file that is there.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <regex>
#include <string>
#include <vector>

#include "test_files.h"

namespace gyrotherm {
namespace {

namespace fs = std::filesystem;
using testing::read_text;

const fs::path kSource(GYROTHERM_SOURCE_DIR);

// The files git tracks, or (no git) every file outside build trees,
// node_modules and .git.
std::vector<fs::path> repository_files() {
  std::vector<fs::path> files;
  const std::string cmd = "git -C '" + kSource.string() + "' ls-files -z 2>/dev/null";
  if (FILE* p = ::popen(cmd.c_str(), "r")) {
    std::string out;
    char buf[65536];
    while (const std::size_t n = std::fread(buf, 1, sizeof buf, p)) out.append(buf, n);
    ::pclose(p);
    for (std::size_t start = 0; start < out.size();) {
      const std::size_t end = out.find('\0', start);
      files.push_back(kSource / out.substr(start, end - start));
      if (end == std::string::npos) break;
      start = end + 1;
    }
  }
  if (!files.empty()) return files;
  for (auto it = fs::recursive_directory_iterator(kSource);
       it != fs::recursive_directory_iterator(); ++it) {
    const std::string name = it->path().filename().string();
    if (it->is_directory() &&
        (name == ".git" || name == "node_modules" || name.rfind("build", 0) == 0)) {
      it.disable_recursion_pending();
    } else if (it->is_regular_file()) {
      files.push_back(it->path());
    }
  }
  return files;
}

TEST(Docs, NoFileRefersToADocumentOutsideTheRepository) {
  // Spelt in pieces so that this file does not name them itself.
  const std::string design = std::string("DESIGN") + ".md";
  const std::string shared = std::string("../") + "shared";
  // The design document cited by section (the name, then "§7" or "section 7")
  // without the extension.
  const std::regex design_section(std::string("DESIGN") + R"((\.md)?\s*(§|section))");
  const auto files = repository_files();
  ASSERT_GT(files.size(), 100u) << "the source tree was not found at " << kSource;
  int checked = 0;
  for (const auto& path : files) {
    if (!fs::is_regular_file(path)) continue;
    const std::string text = read_text(path);
    if (text.find('\0') != std::string::npos) continue;  // binary
    ++checked;
    const std::string name = fs::relative(path, kSource).string();
    EXPECT_EQ(text.find(design), std::string::npos) << name << " refers to " << design;
    EXPECT_EQ(text.find(shared), std::string::npos) << name << " refers to " << shared;
    EXPECT_FALSE(std::regex_search(text, design_section)) << name << " cites a design section";
  }
  EXPECT_GT(checked, 100);
}

TEST(Docs, RelativeLinksReachFilesOfTheRepository) {
  std::vector<fs::path> pages = {kSource / "README.md"};
  for (const auto& entry : fs::directory_iterator(kSource / "docs")) {
    if (entry.path().extension() == ".md") pages.push_back(entry.path());
  }
  // [text](target) with a target that is not a URL or an anchor alone.
  const std::regex link(R"(\]\(([^)#:\s]+)(#[^)\s]*)?\))");
  for (const auto& page : pages) {
    const std::string text = read_text(page);
    for (std::sregex_iterator it(text.begin(), text.end(), link), end; it != end; ++it) {
      const fs::path target = page.parent_path() / (*it)[1].str();
      EXPECT_TRUE(fs::exists(target)) << fs::relative(page, kSource).string() << " links to "
                                      << (*it)[1].str() << ", which is not there";
    }
  }
}

}  // namespace
}  // namespace gyrotherm

// The dashboard's files (index.html, scripts, styles, the chart library),
// read once at start-up from [api] web_root. The daemon serves only these:
// no part of a request path ever reaches the file system.
#pragma once

#include <cstddef>
#include <functional>
#include <map>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"

namespace gyrotherm::api {

// The largest dashboard file read (the chart library is about 50 KiB).
inline constexpr std::size_t kMaxWebFileBytes = 4 << 20;

class WebAssets {
 public:
  struct File {
    std::string content_type;
    std::string body;
  };

  // Reads the regular files of `dir` (not recursive) with a known type
  // (.html .js .css .svg .png .json .map .ico). Error when `dir` or one of
  // those files cannot be read (naming it), a file is over kMaxWebFileBytes,
  // or there is no index.html.
  static Result<WebAssets> load(const std::string& dir);

  const File* find(std::string_view name) const;
  std::size_t size() const { return files_.size(); }
  const std::string& dir() const { return dir_; }

 private:
  std::string dir_;
  std::map<std::string, File, std::less<>> files_;
};

// <directory of the running gyrothermd>/../share/gyrotherm/web: where the
// build and `cmake --install` put the dashboard.
std::string default_web_root();

}  // namespace gyrotherm::api

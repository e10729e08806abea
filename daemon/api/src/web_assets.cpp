#include "gyrotherm/api/web_assets.h"

#include <fmt/format.h>

#include <filesystem>

#include "gyrotherm/core/files.h"

namespace gyrotherm::api {

namespace fs = std::filesystem;

namespace {

const char* content_type_of(const fs::path& p) {
  const std::string ext = p.extension().string();
  if (ext == ".html") return "text/html; charset=utf-8";
  if (ext == ".js") return "text/javascript; charset=utf-8";
  if (ext == ".css") return "text/css; charset=utf-8";
  if (ext == ".svg") return "image/svg+xml";
  if (ext == ".png") return "image/png";
  if (ext == ".json" || ext == ".map") return "application/json";
  if (ext == ".ico") return "image/x-icon";
  return nullptr;
}

}  // namespace

Result<WebAssets> WebAssets::load(const std::string& dir) {
  WebAssets assets;
  assets.dir_ = dir;
  std::error_code ec;
  fs::directory_iterator it(dir, ec);
  if (ec) return Error::Permanent(fmt::format("web files: cannot read {}: {}", dir, ec.message()));
  for (const auto& entry : it) {
    if (!entry.is_regular_file(ec)) continue;
    const char* type = content_type_of(entry.path());
    if (!type) continue;
    auto body = read_bounded_file(entry.path().string(), kMaxWebFileBytes);
    if (!body) return Error::Permanent("web files: " + body.error().message);
    assets.files_[entry.path().filename().string()] = File{type, std::move(*body)};
  }
  if (!assets.find("index.html")) {
    return Error::Permanent(fmt::format("web files: no index.html in {}", dir));
  }
  return assets;
}

const WebAssets::File* WebAssets::find(std::string_view name) const {
  const auto it = files_.find(name);
  return it == files_.end() ? nullptr : &it->second;
}

std::string default_web_root() {
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (ec) return "share/gyrotherm/web";
  return (exe.parent_path().parent_path() / "share" / "gyrotherm" / "web").string();
}

}  // namespace gyrotherm::api

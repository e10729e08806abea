// Files written so that a reader (or a crash) never sees half of one.
#pragma once

#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"

namespace gyrotherm {

// Writes `content` to a temporary file in the same directory, syncs it, then
// renames it over `path`, so a reader never sees a half-written file. Errors
// name the path and the system's reason; the temporary file is removed on
// failure.
Status write_file_atomically(const std::string& path, std::string_view content);

// Renames directory `from` to `to` (same file system) after syncing it, then
// syncs the parent of `to`, so the directory appears whole or not at all.
// `to` must not exist. Errors name both paths and the reason.
Status rename_directory_durably(const std::string& from, const std::string& to);

}  // namespace gyrotherm

// Files written so that a reader (or a crash) never sees half of one, and
// input files read with bounds.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

#include "gyrotherm/core/result.h"

namespace gyrotherm {

// Writes `content` to a temporary file in the same directory, syncs it, then
// renames it over `path`, so a reader never sees a half-written file. Errors
// name the path and the system's reason; the temporary file is removed on
// failure.
Status write_file_atomically(const std::string& path, std::string_view content);

// write_file_atomically after creating the folders `path` lies in, for files
// whose folder may not exist yet (the simulator's endpoints and truth files).
Status write_file_creating_folders(const std::string& path, std::string_view content);

// Renames directory `from` to `to` (same file system) after syncing it, then
// syncs the parent of `to`, so the directory appears whole or not at all.
// `to` must not exist. Errors name both paths and the reason.
Status rename_directory_durably(const std::string& from, const std::string& to);

// Reads a whole regular file of at most `max_bytes` bytes. Refuses, with a
// message that names the path, what is not a regular file (a directory, a
// device such as /dev/zero, a FIFO: never read, so never a hang) and a file
// over the limit (only max_bytes + 1 bytes are ever read, so a file growing
// while read is caught too).
Result<std::string> read_bounded_file(const std::string& path, std::size_t max_bytes);

// "1 MiB", "64 KiB", "100 bytes": a byte count for messages.
std::string format_bytes(std::size_t bytes);

}  // namespace gyrotherm

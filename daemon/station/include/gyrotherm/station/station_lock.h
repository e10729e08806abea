// The station lock: which process runs the station.
//
// gyrothermd holds an exclusive flock on "<database>.lock" (beside the
// station database) for as long as it runs, with its pid written inside.
// Commissioning commands of the CLI that talk to the devices directly
// (`gyrotherm devices`, `gyrotherm chamber set-point`) look at it first and
// refuse while a daemon owns the station: a second Modbus master would move
// the chamber under a run, a second gyro reader would take its frames. The
// lock dies with its holder (flock), so a crashed daemon leaves nothing to
// clean up; the file itself stays.
#pragma once

#include <optional>
#include <string>

#include "gyrotherm/core/result.h"

namespace gyrotherm::station {

// "<db_path>.lock", db_path resolved (symlinks, "..", relative): one lock
// per database file whatever path names it.
std::string station_lock_path(const std::string& db_path);

class StationLock {
 public:
  // Takes the lock, waiting up to `wait_s` (wall) for a stopping daemon to
  // let go; an error names the holder's pid when another process keeps it.
  static Result<StationLock> acquire(const std::string& db_path, double wait_s = 5.0);
  StationLock(StationLock&& other) noexcept;
  StationLock& operator=(StationLock&&) = delete;
  StationLock(const StationLock&) = delete;
  ~StationLock();  // releases the lock

  // Adds "api URL" to the lock file (for the CLI's message).
  void note_api(const std::string& url);
  const std::string& path() const { return path_; }

 private:
  StationLock(int fd, std::string path) : fd_(fd), path_(std::move(path)) {}
  int fd_ = -1;
  std::string path_;
};

struct StationOwner {
  long pid = 0;         // 0 when the file names none
  std::string api_url;  // "" when the file names none
};
// The process holding the station lock of `db_path`, if any.
std::optional<StationOwner> station_owner(const std::string& db_path);

}  // namespace gyrotherm::station

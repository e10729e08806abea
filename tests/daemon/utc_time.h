// Unix seconds of a UTC calendar time, for the nightly-export tests.
#pragma once

#include <ctime>

namespace gyrotherm::test {

inline double utc(int y, int mo, int d, int h, int mi = 0) {
  std::tm tm{};
  tm.tm_year = y - 1900;
  tm.tm_mon = mo - 1;
  tm.tm_mday = d;
  tm.tm_hour = h;
  tm.tm_min = mi;
  return static_cast<double>(timegm(&tm));
}

}  // namespace gyrotherm::test

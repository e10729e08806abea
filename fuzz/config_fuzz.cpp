// Fuzzes the station config parser (daemon/config.h, parse_station_config).
// A refused config is fine, with a message; an accepted one must respect the
// basic relations the daemon relies on (limits ordered, timeouts positive).
#include <cmath>
#include <string>
#include <string_view>

#include "fuzz_check.h"
#include "gyrotherm/config/config.h"

using namespace gyrotherm::config;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const auto config = parse_station_config(text, "fuzz.toml");
  if (!config.ok()) {
    FUZZ_CHECK(!config.error().message.empty());
    return 0;
  }
  const StationSection& st = config->station;
  FUZZ_CHECK(std::isfinite(st.min_temp_c) && std::isfinite(st.max_temp_c));
  FUZZ_CHECK(st.min_temp_c < st.max_temp_c);
  FUZZ_CHECK(st.max_ramp_c_per_min > 0);
  FUZZ_CHECK(st.safe_setpoint_c >= st.min_temp_c && st.safe_setpoint_c <= st.max_temp_c);
  FUZZ_CHECK(config->chamber.silent_timeout_s > 0);
  FUZZ_CHECK(config->probes.silent_timeout_s > 0);
  FUZZ_CHECK(config->gyro.silent_timeout_s > 0);
  FUZZ_CHECK(config->control.tick_s > 0);
  return 0;
}

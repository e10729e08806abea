// gyrotherm samples: a run's exact samples as CSV (docs/storage.md).
#pragma once

#include <iosfwd>
#include <optional>
#include <string>

namespace gyrotherm::cli {

struct SamplesArgs {
  std::string db_path;
  int64_t run_id = 0;
  std::string dut_serial;  // "" = the run's first DUT
  std::string channel;     // "" = every channel of the DUT
  std::optional<double> from_s, to_s;
};

// Writes `t_s,<channel> (<unit>),...` then one line per frame to `out`,
// streamed one chunk at a time. Returns the exit code; errors (unknown run,
// DUT or channel, a bad range) go to stderr, naming what was unknown.
int cmd_samples(const SamplesArgs& args, std::ostream& out);

}  // namespace gyrotherm::cli

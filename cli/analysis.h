// Offline analysis from the command line (docs/analysis.md): `stats`,
// `allan`, `fit`, `compare` and `start-model` on a station database
// (`--db FILE [--run ID | --runs LIST]`, the same code path as the daemon's
// stored results, daemon/run_analysis.h) or on CSV files (`--csv FILE`, one
// window or run each, analysis/csv_window.h). Every command prints a table,
// or with --json a JSON document; a number that cannot be computed is
// JSON null / "—", never NaN.
//
// Exit codes: 0 done; 2 bad usage or bad input (an unreadable database, an
// unknown run, a bad run list or model spec, a CSV error naming file, line and
// column); 1 the analysis failed (the message names the run or window and
// why, e.g. a fit on constant temperature).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

namespace CLI {
class App;
}

namespace gyrotherm::cli {

// Registers the analysis subcommands on `app`; after parsing, run() executes
// the one chosen. Holds the parsed values, so it must outlive parsing.
class AnalysisCommands {
 public:
  explicit AnalysisCommands(CLI::App& app);
  ~AnalysisCommands();
  AnalysisCommands(const AnalysisCommands&) = delete;
  AnalysisCommands& operator=(const AnalysisCommands&) = delete;

  // The exit code when one of these subcommands was chosen, nullopt
  // otherwise. `json` is the top-level --json flag.
  std::optional<int> run(bool json);

 private:
  struct Parsed;
  std::unique_ptr<Parsed> parsed_;
};

// "1,2,5" and ranges "3-7" (inclusive), spaces around items allowed, in the
// order given. Errors name the bad item: empty, not a positive integer, a
// range whose end is below its start or longer than 100000, an id repeated.
Result<std::vector<int64_t>> parse_run_list(std::string_view list);

}  // namespace gyrotherm::cli

// `gyrotherm export`: the calibration reports of stored runs on demand
// (docs/reports.md; the nightly job's code, daemon/exporter.h), written
// atomically into --out and recorded in the database as a manual export.
//
//   gyrotherm export --db FILE --out DIR [--since DATE | --runs LIST] [--json]
//
// Without --since or --runs: the completed runs no nightly export has taken
// yet (what the next nightly export will contain; a manual export does not
// take them from it). Exit codes: 0 written (or nothing to export); 2 bad
// input (database, run list, date, an output directory that exists and is
// not empty, a run still going); 1 the export could not be written.
#pragma once

#include <memory>
#include <optional>

namespace CLI {
class App;
}

namespace gyrotherm::cli {

class ExportCommand {
 public:
  explicit ExportCommand(CLI::App& app);
  ~ExportCommand();
  ExportCommand(const ExportCommand&) = delete;
  ExportCommand& operator=(const ExportCommand&) = delete;

  // The exit code when `export` was chosen, nullopt otherwise.
  std::optional<int> run(bool json);

 private:
  struct Parsed;
  std::unique_ptr<Parsed> parsed_;
};

}  // namespace gyrotherm::cli

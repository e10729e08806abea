// `gyrotherm lab`: the lab database (PostgreSQL; docs/lab.md) from the
// command line (docs/cli.md, "The lab database"):
//
//   gyrotherm lab stations [--json]
//   gyrotherm lab runs [--station ID] [--dut SERIAL] [--since UTC] [--limit N] [--json]
//   gyrotherm lab run (UUID | STATION/LOCAL_ID) [--json]
//   gyrotherm lab dut SERIAL [--json]
//   gyrotherm lab summary [--since UTC] [-o FILE.html]
//   gyrotherm lab migrate                         (administrator)
//   gyrotherm lab add-station ID --role ROLE [--description TEXT]
//   gyrotherm lab add-reader ROLE
//
// Each takes --pg URL (a libpq URI or conninfo), or --pg @FILE (the URL is
// the file's first line), else the environment's GYROTHERM_LAB_URL: no
// password has to be on the command line, and none is ever printed.
//
// Exit codes: 0 done; 1 the lab could not be reached, refused, or has no
// such run or DUT; 2 usage (no URL, an unreadable @FILE, a bad date).
#pragma once

#include <memory>
#include <nlohmann/json_fwd.hpp>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gyrotherm/core/result.h"

namespace CLI {
class App;
}

namespace gyrotherm::lab {
struct LabStation;
struct LabRun;
}  // namespace gyrotherm::lab

namespace gyrotherm::cli {

inline constexpr const char* kLabUrlEnv = "GYROTHERM_LAB_URL";

class LabCommands {
 public:
  explicit LabCommands(CLI::App& app);
  ~LabCommands();
  LabCommands(const LabCommands&) = delete;
  LabCommands& operator=(const LabCommands&) = delete;

  // The exit code when `lab ...` was chosen, nullopt otherwise. `json` is
  // the top-level --json flag.
  std::optional<int> run(bool json);

 private:
  struct Parsed;
  std::unique_ptr<Parsed> parsed_;
};

// The lab's connection string: `given` (--pg) when not empty, "@FILE" read
// from FILE (its first line, blanks trimmed), else GYROTHERM_LAB_URL.
// Permanent error when there is none or the file cannot be read.
Result<std::string> lab_url(const std::string& given);

// The passwords a connection string holds (URI user:password@, ?password=,
// and password=... of a conninfo), raw and percent-decoded.
std::vector<std::string> conninfo_passwords(std::string_view conninfo);

// `text` with every password of the lab URLs the user may have given
// blanked out: those of GYROTHERM_LAB_URL and of the argument after (or `=`
// part of) "--pg" in `args`.
std::string redact_lab_passwords(std::string text, const std::vector<std::string>& args);

// ---- formatters: pure (rows or the library's JSON in, text out).
std::string format_lab_stations(const std::vector<lab::LabStation>& stations);
std::string format_lab_runs(const std::vector<lab::LabRun>& runs);
// lab_run_json's answer.
std::string format_lab_run(const nlohmann::json& run);
// lab_dut_json's answer: read like `gyrotherm dut SERIAL`, each run named
// STATION/LOCAL_ID, then the Allan noise terms.
std::string format_lab_dut(const nlohmann::json& history);

}  // namespace gyrotherm::cli
